"""First contact with static worlds: hard cases decided, the exact reference, properties.

Guarantees proved here (docs/static.md):

* 0 and inf are exact decisions, including sliding along a wall at exactly the radius (no
  contact, also at the wall's end), grazing a corner at exactly the radius (a contact),
  touching at t = 0 and moving away, and a path through a vertex.
* A finite time is within one ulp of the exact time: rows are compared with an exact
  reference that uses no index and no certified kernel (every edge by ``exact_edge_contact``,
  every corner by ``exact_first_contact``, solids by an exact rational inside test).
* The answer does not depend on the order of edges, the index's cell size, an exact
  translation, or whether a polygon's boundary is given as a polygon or as segments (for
  bodies outside it).
"""
from __future__ import annotations

import math
import warnings
from fractions import Fraction

import numpy as np
import pytest

from circle_collision_ros.core.narrow.exact import exact_first_contact
from circle_collision_ros.core.static import (
    GridFrame,
    OccupancyMap,
    Polygon,
    Segments,
    StaticIndex,
    StaticWorld,
    time_to_static,
)
from circle_collision_ros.core.static.edge_exact import exact_edge_contact
from circle_collision_ros.core.static.query import KIND_EDGE, KIND_INSIDE, KIND_POINT


def _one(world, p, v, a, r, H=30.0):
    c = time_to_static([p], [v], [a], r, StaticIndex.build(world), H)
    return float(c.time[0]), int(c.kind[0])


BOX = StaticWorld.build([Polygon("box", np.array([[-10.0, -1], [10, -1], [10, 0], [-10, 0]]))])
WALL = StaticWorld.build([Segments("wall", np.array([[-10.0, 0]]), np.array([[10.0, 0]]))])
TRIANGLE = StaticWorld.build([Polygon("tri", np.array([[9.0, -2], [11, -2], [10, 0]]))])


# --- hard cases, each with its exact answer built by hand ------------------------------------

@pytest.mark.parametrize("world", [BOX, WALL], ids=["box", "wall"])
@pytest.mark.parametrize("a", [(0.0, 0.0), (0.25, 0.0), (-0.01, 0.0)])
def test_sliding_along_a_wall_at_exactly_the_radius_is_no_contact(world, a):
    # the distance stays r, then grows past the wall's end: never below r, and the touch of
    # the end corner is not isolated (a per-feature answer would report the corner at t = 10)
    assert _one(world, (0.0, 0.5), (1.0, 0.0), a, 0.5) == (math.inf, 0)


def test_sliding_into_a_concave_corner_is_a_contact():
    world = StaticWorld.build([Segments("L", np.array([[-10.0, 0], [10, 0]]),
                                        np.array([[10.0, 0], [10, 5]]))])
    assert _one(world, (0.0, 0.5), (1.0, 0.0), (0.0, 0.0), 0.5) == (9.5, KIND_EDGE)


def test_grazing_a_corner_at_exactly_the_radius_is_a_contact():
    assert _one(TRIANGLE, (0.0, 1.0), (1.0, 0.0), (0.0, 0.0), 1.0) == (10.0, KIND_POINT)
    assert _one(TRIANGLE, (0.0, 1.0 + 2.0 ** -40), (1.0, 0.0), (0.0, 0.0), 1.0)[0] == math.inf
    t, kind = _one(TRIANGLE, (0.0, 1.0 - 2.0 ** -40), (1.0, 0.0), (0.0, 0.0), 1.0)
    assert kind == KIND_POINT and t < 10.0
    # exact: 10 - sqrt(1 - (1 - 2^-40)^2) rounded to nearest
    ref = exact_first_contact((0.0, 1.0 - 2.0 ** -40), (1.0, 0.0), (0.0, 0.0), 1.0,
                              (10.0, 0.0), (0.0, 0.0), (0.0, 0.0), 0.0, 30.0)
    assert abs(t - ref) <= math.ulp(ref)


@pytest.mark.parametrize("v, a, expected", [
    ((0.0, 1.0), (0.0, 0.0), math.inf),   # touching, moving away
    ((0.0, -1.0), (0.0, 0.0), 0.0),       # touching, approaching
    ((0.0, 1.0), (0.0, -1.0), 2.0),       # away, then back: the next contact
    ((1.0, 0.0), (0.0, -0.5), 0.0),       # tangential, accelerating into the wall
    ((1.0, 0.0), (0.0, 0.5), math.inf),   # tangential, accelerating away
])
def test_touching_at_t0(v, a, expected):
    assert _one(WALL, (0.0, 0.5), v, a, 0.5)[0] == expected


def test_a_path_exactly_through_a_vertex():
    assert _one(BOX, (11.0, 1.0), (-1.0, -1.0), (0.0, 0.0), 0.0) == (1.0, KIND_POINT)
    # a small body on the same path touches the corner earlier, by its radius
    t, kind = _one(BOX, (11.0, 1.0), (-1.0, -1.0), (0.0, 0.0), 0.25)
    assert kind == KIND_POINT and abs(t - (1.0 - 0.25 / math.sqrt(2))) < 1e-15


def test_thin_wall_one_cell_wide_is_not_tunnelled():
    occ = np.zeros((10, 10), bool)
    occ[:, 5] = True
    world = StaticWorld.build([OccupancyMap("map", occ, GridFrame(0.0625))])
    # 1 km/s across a 6 cm wall: a 0.1 s fixed step would jump it
    t, kind = _one(world, (0.0, 0.3), (1000.0, 0.0), (0.0, 0.0), 0.0078125, 1.0)
    assert kind == KIND_EDGE and t == (5 * 0.0625 - 0.0078125) / 1000.0


def test_map_sized_coordinates_with_millimetre_gaps():
    world = StaticWorld.build([Segments("w", np.array([[10000.0, 5000.0]]),
                                        np.array([[10010.0, 5000.0]]))])
    # 1 mm above the wall at 1e4 m: the gap is exact in the relative state
    t, _ = _one(world, (10005.0, 5000.1 + 0.001), (0.0, -1.0), (0.0, 0.0), 0.1)
    ref = exact_edge_contact((10005.0, 5000.1 + 0.001), (0.0, -1.0), (0.0, 0.0), 0.1,
                             (10000.0, 5000.0), (10010.0, 5000.0), 0, 30.0)
    assert t == pytest.approx(ref, rel=0, abs=math.ulp(ref)) and 0.0009 < t < 0.0011
    # passing 1 mm beyond the wall's end does not touch it
    assert _one(world, (10010.101, 5001.0), (0.0, -1.0), (0.0, 0.0), 0.1, 3.0)[0] == math.inf


def test_inside_a_solid_overlaps():
    assert _one(BOX, (0.0, -0.5), (0.0, 0.0), (0.0, 0.0), 0.1) == (0.0, KIND_INSIDE)
    assert _one(BOX, (0.0, -0.95), (0.0, 0.0), (0.0, 0.0), 0.1) == (0.0, KIND_EDGE)
    occ = np.zeros((40, 40), bool)
    occ[10:30, 10:30] = True
    world = StaticWorld.build([OccupancyMap("map", occ, GridFrame(0.5))])
    assert _one(world, (10.0, 10.0), (1.0, 0.0), (0.0, 0.0), 0.1) == (0.0, KIND_INSIDE)
    big = StaticWorld.build([Polygon("big", np.array([[0.0, 0], [100, 0], [100, 100],
                                                      [0, 100]]))])
    assert _one(big, (50.0, 50.0), (0.0, 0.0), (0.0, 0.0), 0.5) == (0.0, KIND_INSIDE)


# --- the exact reference ---------------------------------------------------------------------

def _inside_exact(pt, loop) -> bool:
    """Even-odd rule in rationals (the point is off the boundary whenever this matters)."""
    x, y = Fraction(pt[0]), Fraction(pt[1])
    inside = False
    n = len(loop)
    for i in range(n):
        x1, y1 = map(Fraction, loop[i])
        x2, y2 = map(Fraction, loop[(i + 1) % n])
        if (y1 > y) != (y2 > y) and x < x1 + (y - y1) * (x2 - x1) / (y2 - y1):
            inside = not inside
    return inside


def _slides(p, v, a, r, s, e, c) -> bool:
    F = Fraction
    ex, ey = F(e[0]) - F(s[0]), F(e[1]) - F(s[1])
    cx, cy = F(c[0]) - F(s[0]), F(c[1]) - F(s[1])
    gx, gy = F(p[0]) - F(s[0]), F(p[1]) - F(s[1])
    return (ex * F(v[1]) == ey * F(v[0]) and ex * F(a[1]) == ey * F(a[0])
            and ex * cy == ey * cx and 0 <= ex * cx + ey * cy <= ex * ex + ey * ey
            and (ex * gy - ey * gx) ** 2 == F(r) ** 2 * (ex * ex + ey * ey))


def reference(world: StaticWorld, p, v, a, r, H) -> float:
    """The first contact by the exact solvers over every feature, no index, no kernels."""
    best = math.inf
    for k in range(len(world.starts)):
        best = min(best, exact_edge_contact(p, v, a, r, world.starts[k], world.ends[k],
                                            int(world.solid_side[k]), H))
    for k, c in enumerate(world.points):
        t = exact_first_contact(p, v, a, r, c, (0.0, 0.0), (0.0, 0.0), 0.0, H)
        if t < best and not any(_slides(p, v, a, r, world.starts[j], world.ends[j], c)
                                for j in range(len(world.starts))):
            best = t
    for _, first, count in world.polygons:
        if _inside_exact(p, world.starts[first:first + count]):
            return 0.0
    for _, occ, frame in world.maps:
        fx, fy = frame.map_to_cell(p[0], p[1])
        ix, iy = math.floor(fx), math.floor(fy)
        if 0 <= iy < occ.shape[0] and 0 <= ix < occ.shape[1] and occ[iy, ix]:
            return 0.0
    return best


def _room() -> StaticWorld:
    occ = np.zeros((48, 64), bool)
    occ[0, :] = occ[-1, :] = occ[:, 0] = occ[:, -1] = True
    occ[20:28, 30] = True
    occ[5:9, 5:12] = True
    return StaticWorld.build([
        OccupancyMap("map", occ, GridFrame(0.0625, -2.0, -1.5)),
        Polygon("crate", np.array([[0.5, 0.25], [1.25, 0.5], [0.75, 1.0], [0.25, 0.75]])),
        Polygon("ell", np.array([[-1.0, 0.0], [-0.5, 0.0], [-0.5, 0.25], [-0.75, 0.25],
                                 [-0.75, 0.75], [-1.0, 0.75]])),
        Segments("rail", np.array([[-1.5, -1.0], [0.0, -1.0]]),
                 np.array([[-0.25, -1.25], [1.0, -0.5]])),
    ])


@pytest.mark.parametrize("seed", [0, 1])
def test_random_bodies_match_the_exact_reference(seed):
    world = _room()
    index = StaticIndex.build(world)
    rng = np.random.default_rng(seed)
    n = 150
    P = rng.uniform([-1.9, -1.4], [1.9, 1.4], size=(n, 2))
    V = rng.normal(size=(n, 2))
    A = rng.normal(size=(n, 2)) * 0.5 * (np.arange(n) % 2)[:, None]
    R = rng.uniform(0.0, 0.15, n)
    H = 2.5
    got = time_to_static(P, V, A, R, index, H)
    contacts = 0
    for b in range(n):
        ref = reference(world, P[b], V[b], A[b], R[b], H)
        t = got.time[b]
        if ref in (0.0, math.inf):
            assert t == ref, (b, t, ref)
        else:
            contacts += 1
            assert abs(t - ref) <= math.ulp(ref), (b, t, ref)
    assert contacts > n // 3


def _room_bodies(seed: int, n: int):
    """(P, V, A, R) of n bodies inside the room, accelerating, radii up to 0.15 m."""
    rng = np.random.default_rng(seed)
    return (rng.uniform([-1.9, -1.4], [1.9, 1.4], size=(n, 2)), rng.normal(size=(n, 2)),
            rng.normal(size=(n, 2)) * 0.3, rng.uniform(0.0, 0.15, n))


def test_the_answer_does_not_depend_on_edge_order_cells_or_translation():
    world = _room()
    n = 300
    P, V, A, R = _room_bodies(5, n)
    base = time_to_static(P, V, A, R, StaticIndex.build(world), 2.0)
    # permuted segments and reversed polygon vertices
    perm = StaticWorld.build([
        OccupancyMap("map", world.maps[0][1], world.maps[0][2]),
        Polygon("crate", np.array([[0.5, 0.25], [1.25, 0.5], [0.75, 1.0], [0.25, 0.75]])[::-1]),
        Polygon("ell", np.roll(np.array([[-1.0, 0.0], [-0.5, 0.0], [-0.5, 0.25], [-0.75, 0.25],
                                         [-0.75, 0.75], [-1.0, 0.75]]), 2, axis=0)),
        Segments("rail", np.array([[1.0, -0.5], [-1.5, -1.0]]),
                 np.array([[0.0, -1.0], [-0.25, -1.25]])),
    ])
    got = time_to_static(P, V, A, R, StaticIndex.build(perm), 2.0)
    np.testing.assert_array_equal(got.time, base.time)
    np.testing.assert_array_equal(got.obstacle, base.obstacle)
    # one cell: every feature is a candidate of every body
    from circle_collision_ros.core.static import index as index_module
    old = index_module.MAX_CELLS_PER_AXIS
    try:
        index_module.MAX_CELLS_PER_AXIS = 1
        one_cell = StaticIndex.build(world)
    finally:
        index_module.MAX_CELLS_PER_AXIS = old
    assert one_cell.nx == one_cell.ny == 1
    np.testing.assert_array_equal(time_to_static(P, V, A, R, one_cell, 2.0).time, base.time)


def _crate_and_rail(shift) -> StaticWorld:
    return StaticWorld.build([
        Polygon("crate", np.array([[0.5, 0.25], [1.25, 0.5], [0.75, 1.0], [0.25, 0.75]]) + shift),
        Segments("rail", np.array([[-1.5, -1.0], [0.0, -1.0]]) + shift,
                 np.array([[-0.25, -1.25], [1.0, -0.5]]) + shift),
    ])


def test_an_exact_translation_changes_nothing():
    n = 300
    P, V, A, R = _room_bodies(6, n)
    P = np.round(P * 2.0 ** 30) / 2.0 ** 30  # 30 fraction bits: P + shift is exact
    shift = np.array([1024.0, -2048.0])
    a = time_to_static(P + shift, V, A, R, StaticIndex.build(_crate_and_rail(shift)), 2.0)
    b = time_to_static(P, V, A, R, StaticIndex.build(_crate_and_rail(0.0)), 2.0)
    np.testing.assert_array_equal(a.time, b.time)
    assert np.isfinite(b.time).sum() > 20


def test_a_polygon_and_its_boundary_as_segments_agree_outside_it():
    verts = np.array([[0.5, 0.25], [1.25, 0.5], [0.75, 1.0], [1.0, 1.5], [0.25, 0.75]])
    solid = StaticWorld.build([Polygon("p", verts)])
    walls = StaticWorld.build([Segments("p", verts, np.roll(verts, -1, axis=0))])
    rng = np.random.default_rng(9)
    n = 400
    P = rng.uniform(-1.0, 2.5, size=(n, 2))
    V = rng.normal(size=(n, 2))
    A = rng.normal(size=(n, 2)) * 0.3
    R = rng.uniform(0.0, 0.1, n)
    a = time_to_static(P, V, A, R, StaticIndex.build(solid), 3.0)
    b = time_to_static(P, V, A, R, StaticIndex.build(walls), 3.0)
    outside = a.kind != KIND_INSIDE
    assert outside.sum() > n // 2
    np.testing.assert_array_equal(a.time[outside], b.time[outside])


def test_contact_details_point_normal_and_speed():
    c = time_to_static([[0.0, 0.0]], [[1.0, 0.0]], [[0.0, 0.0]], 0.5,
                       StaticIndex.build(StaticWorld.build([Segments(
                           "w", np.array([[3.0, -5.0]]), np.array([[3.0, 5.0]]))])), 10.0)
    assert c.time[0] == 2.5
    np.testing.assert_allclose(c.point[0], [3.0, 0.0])
    np.testing.assert_allclose(c.normal[0], [1.0, 0.0])
    assert c.closing_speed[0] == pytest.approx(1.0)
    assert c.obstacle[0] == 0


def test_bad_input_rows_are_nan_and_bad_obstacles_are_refused():
    idx = StaticIndex.build(WALL)
    c = time_to_static([[0.0, 1.0], [math.nan, 0.0]], [[0.0, -1.0], [0.0, 0.0]],
                       [[0.0, 0.0]], [0.5, 0.5], idx, 5.0)
    assert c.time[0] == 0.5 and math.isnan(c.time[1]) and c.obstacle[1] == -1
    with pytest.raises(ValueError, match="horizon"):
        time_to_static([[0.0, 0.0]], [[0.0, 0.0]], [[0.0, 0.0]], 0.1, idx, -1.0)
    with pytest.raises(ValueError, match="collinear"):
        StaticWorld.build([Polygon("flat", np.array([[0.0, 0], [1, 0], [2, 0]]))])
    with pytest.raises(ValueError, match="used twice"):
        StaticWorld.build([WALL_SEGMENTS, WALL_SEGMENTS])
    with pytest.raises(ValueError, match="non-finite"):
        StaticWorld.build([Polygon("nan", np.array([[0.0, 0], [1, math.nan], [2, 1]]))])


WALL_SEGMENTS = Segments("wall", np.array([[-10.0, 0]]), np.array([[10.0, 0]]))


def _inside_edges_reference(px: float, py: float, starts, ends) -> bool:
    """Even-odd crossings over closed edge loops, all in rationals; on an edge: False."""
    x, y, inside = Fraction(px), Fraction(py), False
    for (x1, y1), (x2, y2) in zip(starts.tolist(), ends.tolist()):
        x1, y1, x2, y2 = Fraction(x1), Fraction(y1), Fraction(x2), Fraction(y2)
        o = (x2 - x1) * (y - y1) - (y2 - y1) * (x - x1)
        if o == 0 and min(x1, x2) <= x <= max(x1, x2) and min(y1, y2) <= y <= max(y1, y2):
            return False
        if (y1 > y) != (y2 > y) and (o > 0) == (y2 > y1):
            inside = not inside
    return inside


@pytest.mark.parametrize("seed", range(4))
def test_a_point_within_rounding_of_a_rotated_map_cell_line_is_decided_exactly(seed):
    """A rotated map's region is bounded by its edges between corners rounded once; a point
    body resting at a corner, one ulp off it, or at an edge's midpoint is inside exactly
    when it lies in that region's interior (rationals, every edge).  A float lookup got
    about one in ten of these wrong."""
    rng = np.random.default_rng(seed)
    occ = rng.random((6, 7)) < 0.6
    frame = GridFrame(float(rng.choice([0.05, 0.3, 0.5])), float(rng.uniform(-20, 20)),
                      float(rng.uniform(-20, 20)), float(rng.uniform(-3, 3)))
    world = StaticWorld.build([OccupancyMap("m", occ, frame)])
    ii, jj = np.meshgrid(np.arange(8), np.arange(7))
    cx, cy = frame.cell_to_map(ii.ravel(), jj.ravel())
    pts = list(zip(cx.tolist(), cy.tolist()))
    pts += [(math.nextafter(a, s * math.inf), math.nextafter(b, t * math.inf))
            for a, b in zip(cx.tolist(), cy.tolist()) for s in (-1, 1) for t in (-1, 1)]
    pts += [((a + c) / 2, (b + d) / 2)
            for (a, b), (c, d) in zip(world.starts.tolist(), world.ends.tolist())]
    n = len(pts)
    c = time_to_static(np.array(pts), np.zeros((n, 2)), np.zeros((n, 2)), 0.0,
                       StaticIndex.build(world), 1.0)
    want = [_inside_edges_reference(x, y, world.starts, world.ends) for x, y in pts]
    got = (c.kind == KIND_INSIDE).tolist()
    wrong = [pts[k] for k in range(n) if got[k] != want[k]]
    assert not wrong, (len(wrong), n, wrong[:3])
    assert sum(want) >= 20 and n - sum(want) >= 20


def test_bodies_far_beyond_a_map_are_outside_it_without_an_invalid_cast():
    """The map's inside test never converts an out-of-range cell index to an integer (numpy
    warned 'invalid value encountered in cast' and relied on the platform's garbage)."""
    occ = np.ones((4, 4), bool)
    p = [[1e300, 1.0], [1.0, -1e300], [-3e299, 2e299], [1e17, 3.0], [1.0, 1.0]]
    for yaw in (0.0, 0.3):  # a rotated map also stays out of its exact pass for them
        world = StaticWorld.build([OccupancyMap("map", occ, GridFrame(0.5, yaw=yaw))])
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            c = time_to_static(p, [[0.0, 0.0]] * 5, [[0.0, 0.0]] * 5, 0.0,
                               StaticIndex.build(world), 1.0)
        assert c.time.tolist() == [math.inf] * 4 + [0.0], yaw
        assert c.kind[4] == KIND_INSIDE


@pytest.mark.parametrize("v, expected", [((0.0, 1.0), 0.0), ((0.0, -1.0), math.inf),
                                         ((1.0, 0.0), math.inf)])
def test_a_point_on_a_solid_boundary_is_decided_by_its_motion(v, expected):
    """r = 0 on the boundary with the solid above it: touching, not inside; moving in is a
    contact at 0, moving out or along is none. (A half-open inside test puts these points
    inside: time 0 for every row.)"""
    # the box's bottom edge, y = -1
    assert _one(BOX, (0.0, -1.0), v, (0.0, 0.0), 0.0, 5.0)[0] == expected
    occ = np.zeros((8, 8), bool)
    occ[4:, :] = True  # solid above y = 0 (res 0.0625 from origin -0.25)
    grid = StaticWorld.build([OccupancyMap("map", occ, GridFrame(0.0625, -0.25, -0.25))])
    assert _one(grid, (0.0, 0.0), v, (0.0, 0.0), 0.0, 5.0)[0] == expected


def test_a_point_a_rounding_error_inside_a_polygon_overlaps():
    # 2^-60 below the box's top edge, r tiny: inside, so overlapping at 0
    p = (0.0, -(2.0 ** -60))
    assert _one(BOX, p, (0.0, 1.0), (0.0, 0.0), 1e-30, 5.0) == (0.0, KIND_INSIDE)


def test_a_point_body_sliding_along_a_map_wall_past_its_corner_is_no_contact():
    """Found by bench_static: r = 0 sliding along a block's side past its corner got the
    corner as a contact (the slide filter read the direction of a rounding-size vector)."""
    occ = np.zeros((6, 6), bool)
    occ[1:3, 1:4] = True
    occ[4, 4] = True
    world = StaticWorld.build([OccupancyMap("map", occ, GridFrame(0.125, 10.0, -1.0))])
    p = (float.fromhex("0x1.315p+3"), float.fromhex("-0x1.cp-1"))
    v = (float.fromhex("0x1.7p+0"), 0.0)
    assert _one(world, p, v, (0.0, 0.0), 0.0, 5.0)[0] == math.inf


def test_the_threaded_query_equals_the_serial_one():
    from circle_collision_ros.core.parallel_policy import threads_forced

    world = _room()
    index = StaticIndex.build(world)
    n = 700
    P, V, A, R = _room_bodies(12, n)
    R[::50] = 0.0  # point bodies: some take the exact path
    out = []
    for threaded in (False, True):
        with threads_forced(threaded):
            out.append(time_to_static(P, V, A, R, index, 2.0))
    for a, b in zip(*out):
        np.testing.assert_array_equal(a, b)
    assert np.isfinite(out[0].time).sum() > n // 3
