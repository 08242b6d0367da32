"""Occupancy grid -> merged boundary edges (circle_collision_ros/core/static/occupancy.py).

Guarantees proved here (each next to its test):
* the merged edges cover exactly the brute-force set of unit boundary sides,
  same orientation (occupied cell on the left), without overlap, and no two
  could be merged -- test_edges_match_brute_force_*.
* walls, blocks, holes (clockwise) and checkerboard corners give the expected
  few edges -- test_long_wall ... test_checkerboard_*.
* the origin pose is honoured (exactly for yaw = 0 and a dyadic resolution)
  and the occupied side stays on the left in the map frame -- test_frame_*.
* thresholds, unknown cells and input validation of `occupied_cells` and
  `GridFrame` -- test_occupied_cells_*, test_*_errors.
"""
from __future__ import annotations

import array
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis.extra import numpy as hnp

from circle_collision_ros.core.static.occupancy import (GridEdges, GridFrame, boundary_edges,
                                                        cell_occupied_at, occupied_cells)

UNIT = GridFrame(1.0)


# --- reference -------------------------------------------------------------------------------

def brute_unit_edges(occ: np.ndarray) -> set:
    """Unit sides of occupied cells whose neighbour is free or outside, cell on the left."""
    h, w = occ.shape

    def free(ix, iy):
        return not (0 <= ix < w and 0 <= iy < h and occ[iy, ix])

    out = set()
    for iy, ix in zip(*np.nonzero(occ)):
        ix, iy = int(ix), int(iy)
        if free(ix, iy - 1):
            out.add(((ix, iy), (ix + 1, iy)))
        if free(ix + 1, iy):
            out.add(((ix + 1, iy), (ix + 1, iy + 1)))
        if free(ix, iy + 1):
            out.add(((ix + 1, iy + 1), (ix, iy + 1)))
        if free(ix - 1, iy):
            out.add(((ix, iy + 1), (ix, iy)))
    return out


def unit_pieces(e: GridEdges) -> list:
    """The unit sides each merged edge covers, in the edge's direction (with repeats)."""
    pieces = []
    for (x0, y0), (x1, y1) in zip(e.start_cell.tolist(), e.end_cell.tolist()):
        n = abs(x1 - x0) + abs(y1 - y0)
        assert n >= 1 and (x0 == x1 or y0 == y1), "edges are axis-aligned, non-empty"
        dx, dy = (x1 - x0) // n, (y1 - y0) // n
        pieces += [((x0 + k * dx, y0 + k * dy), (x0 + (k + 1) * dx, y0 + (k + 1) * dy))
                   for k in range(n)]
    return pieces


def check_edges(occ: np.ndarray, frame: GridFrame = UNIT) -> GridEdges:
    e = boundary_edges(occ, frame)
    E = len(e.start)
    for a in e:
        assert a.shape == (E, 2)
    assert e.start.dtype == np.float64 and e.start_cell.dtype == np.int64
    pieces = unit_pieces(e)
    assert len(pieces) == len(set(pieces)), "merged edges overlap"
    assert set(pieces) == brute_unit_edges(occ)
    # maximal: no edge ends where a collinear edge of the same direction starts
    direction = np.sign(e.end_cell - e.start_cell)
    ends = {(tuple(p), tuple(d)) for p, d in zip(e.end_cell.tolist(), direction.tolist())}
    starts = {(tuple(p), tuple(d)) for p, d in zip(e.start_cell.tolist(), direction.tolist())}
    assert not ends & starts, "two edges could be merged"
    # map coordinates are the corners through the frame
    for cells, xy in ((e.start_cell, e.start), (e.end_cell, e.end)):
        np.testing.assert_array_equal(np.stack(frame.cell_to_map(cells[:, 0], cells[:, 1]), 1),
                                      xy)
    return e


def as_sets(e: GridEdges) -> set:
    return {(tuple(s), tuple(t)) for s, t in zip(e.start_cell.tolist(), e.end_cell.tolist())}


# --- merged edges == brute force ---------------------------------------------------------------

@pytest.mark.parametrize("seed", range(40))
def test_edges_match_brute_force_random(seed):
    rng = np.random.default_rng(seed)
    h, w = rng.integers(1, 25, size=2)
    occ = rng.random((h, w)) < rng.choice([0.1, 0.3, 0.5, 0.7, 0.95])
    # some rectangles too, so long runs and holes occur
    for _ in range(rng.integers(0, 4)):
        y0, x0 = rng.integers(0, h), rng.integers(0, w)
        occ[y0:y0 + rng.integers(1, 10), x0:x0 + rng.integers(1, 10)] = rng.random() < 0.7
    check_edges(occ)


@settings(max_examples=300, deadline=None)
@given(occ=hnp.arrays(np.bool_, hnp.array_shapes(min_dims=2, max_dims=2, min_side=1,
                                                   max_side=9)))
def test_edges_match_brute_force_hypothesis(occ):
    check_edges(occ)


def test_empty_and_full_grids():
    e = check_edges(np.zeros((7, 5), dtype=bool))
    assert len(e.start) == 0 and e.start.shape == (0, 2)
    # cells outside count as free: a full grid is outlined along its border, CCW
    e = check_edges(np.ones((7, 5), dtype=bool))
    assert as_sets(e) == {((0, 0), (5, 0)), ((5, 0), (5, 7)), ((5, 7), (0, 7)), ((0, 7), (0, 0))}
    assert len(boundary_edges(np.zeros((0, 3), dtype=bool), UNIT).start) == 0


# --- shapes ----------------------------------------------------------------------------------

def test_long_wall():
    """1000 cells in a row (2 thick): 4 edges, none for the interior."""
    occ = np.zeros((10, 1010), dtype=bool)
    occ[4:6, 5:1005] = True
    e = check_edges(occ)
    assert as_sets(e) == {((5, 4), (1005, 4)), ((1005, 4), (1005, 6)),
                          ((1005, 6), (5, 6)), ((5, 6), (5, 4))}


def test_filled_block():
    occ = np.zeros((60, 60), dtype=bool)
    occ[3:53, 7:57] = True
    e = check_edges(occ)
    assert as_sets(e) == {((7, 3), (57, 3)), ((57, 3), (57, 53)),
                          ((57, 53), (7, 53)), ((7, 53), (7, 3))}


def test_one_cell_wide_wall():
    occ = np.zeros((3, 30), dtype=bool)
    occ[1, 2:27] = True
    e = check_edges(occ)
    assert as_sets(e) == {((2, 1), (27, 1)), ((27, 1), (27, 2)),
                          ((27, 2), (2, 2)), ((2, 2), (2, 1))}
    lengths = sorted(np.abs(e.end_cell - e.start_cell).sum(axis=1).tolist())
    assert lengths == [1, 1, 25, 25]
    # vertical one-cell wall, lying along the grid border (outside is free)
    occ = np.zeros((20, 4), dtype=bool)
    occ[:, 0] = True
    assert as_sets(check_edges(occ)) == {((0, 0), (1, 0)), ((1, 0), (1, 20)),
                                         ((1, 20), (0, 20)), ((0, 20), (0, 0))}


def signed_area(e: GridEdges) -> int:
    """Shoelace sum over all edges: + for CCW loops, - for CW loops."""
    s, t = e.start_cell, e.end_cell
    return int(np.sum(s[:, 0] * t[:, 1] - t[:, 0] * s[:, 1])) // 2


def test_block_with_hole_is_ccw_outside_cw_inside():
    occ = np.zeros((12, 12), dtype=bool)
    occ[1:11, 1:11] = True
    occ[4:7, 3:9] = False
    e = check_edges(occ)
    outer = {((1, 1), (11, 1)), ((11, 1), (11, 11)), ((11, 11), (1, 11)), ((1, 11), (1, 1))}
    hole = {((3, 4), (3, 7)), ((3, 7), (9, 7)), ((9, 7), (9, 4)), ((9, 4), (3, 4))}
    assert as_sets(e) == outer | hole
    # occupied area = CCW outer area minus the CW hole's area
    assert signed_area(e) == 100 - 18 == int(occ.sum())
    in_hole = np.array([(tuple(a), tuple(b)) in hole
                        for a, b in zip(e.start_cell.tolist(), e.end_cell.tolist())])
    assert signed_area(GridEdges(*(a[in_hole] for a in e))) == -18


def test_checkerboard_two_cells():
    """Cells touching only at a corner: each is a separate CCW square, all ending at (1, 1)."""
    occ = np.array([[True, False], [False, True]])
    e = check_edges(occ)
    sq00 = {((0, 0), (1, 0)), ((1, 0), (1, 1)), ((1, 1), (0, 1)), ((0, 1), (0, 0))}
    sq11 = {((1, 1), (2, 1)), ((2, 1), (2, 2)), ((2, 2), (1, 2)), ((1, 2), (1, 1))}
    assert as_sets(e) == sq00 | sq11
    # the other diagonal
    e = check_edges(occ[::-1].copy())
    assert as_sets(e) == {((1, 0), (2, 0)), ((2, 0), (2, 1)), ((2, 1), (1, 1)), ((1, 1), (1, 0)),
                          ((0, 1), (1, 1)), ((1, 1), (1, 2)), ((1, 2), (0, 2)), ((0, 2), (0, 1))}


def test_checkerboard_runs_break_at_pinch():
    """Two blocks meeting at a corner: no edge passes through the pinch point (3, 3)."""
    occ = np.zeros((6, 6), dtype=bool)
    occ[0:3, 0:3] = True
    occ[3:6, 3:6] = True
    e = check_edges(occ)
    assert len(e.start) == 8
    for s, t in as_sets(e):
        lo, hi = np.minimum(s, t), np.maximum(s, t)
        strictly_inside = ((lo[0] < 3 < hi[0]) and lo[1] == 3) or ((lo[1] < 3 < hi[1])
                                                                     and lo[0] == 3)
        assert not strictly_inside
    # four edges meet at the pinch: two end there and two start there
    assert sum(t == (3, 3) for _, t in as_sets(e)) == 2
    assert sum(s == (3, 3) for s, _ in as_sets(e)) == 2
    # a full checkerboard: every occupied cell is its own square
    board = (np.add.outer(np.arange(7), np.arange(9)) % 2).astype(bool)
    e = check_edges(board)
    assert len(e.start) == 4 * int(board.sum())


# --- frame -----------------------------------------------------------------------------------

def test_frame_exact_for_yaw_zero_dyadic_resolution():
    frame = GridFrame(0.0625, origin_x=-10.5, origin_y=3.25)
    occ = np.zeros((8, 9), dtype=bool)
    occ[2:5, 1:7] = True
    e = check_edges(occ, frame)
    expected = np.array([-10.5, 3.25]) + e.start_cell * 0.0625
    np.testing.assert_array_equal(e.start, expected)
    np.testing.assert_array_equal(e.end, np.array([-10.5, 3.25]) + e.end_cell * 0.0625)
    assert tuple(frame.cell_to_map(1, 2)) == (-10.4375, 3.375)


def test_frame_rotated_quarter_turn():
    frame = GridFrame(0.5, origin_x=2.0, origin_y=3.0, yaw=math.pi / 2)
    x, y = frame.cell_to_map(np.array([0, 1, 0, 2]), np.array([0, 0, 1, 3]))
    # +x of the grid is +y of the map, +y of the grid is -x of the map
    np.testing.assert_allclose(x, [2.0, 2.0, 1.5, 0.5], atol=1e-12)
    np.testing.assert_allclose(y, [3.0, 3.5, 3.0, 4.0], atol=1e-12)
    occ = np.zeros((3, 3), dtype=bool)
    occ[1, 1] = True
    e = check_edges(occ, frame)
    # the cell's corners (1, 1)..(2, 2) map to the square x in [1.0, 1.5], y in [3.5, 4.0]
    np.testing.assert_allclose(np.sort(e.start, axis=0), [[1.0, 3.5], [1.0, 3.5], [1.5, 4.0],
                                                          [1.5, 4.0]], atol=1e-12)


@pytest.mark.parametrize("frame", [GridFrame(0.05, -7.3, 12.1, 0.0),
                                   GridFrame(0.1, 1.0, -2.0, math.pi / 2),
                                   GridFrame(0.25, 100.0, 50.0, -2.2),
                                   GridFrame(1.7, 0.0, 0.0, 3.0)])
def test_frame_round_trip_and_left_side_occupied(frame):
    rng = np.random.default_rng(3)
    ix, iy = rng.uniform(-50, 50, 200), rng.uniform(-50, 50, 200)
    fx, fy = frame.map_to_cell(*frame.cell_to_map(ix, iy))
    np.testing.assert_allclose(fx, ix, rtol=0, atol=1e-9)
    np.testing.assert_allclose(fy, iy, rtol=0, atol=1e-9)
    # rotation + translation keep the orientation: the occupied cell is left of every edge
    occ = rng.random((15, 11)) < 0.4
    e = check_edges(occ, frame)
    mid = 0.5 * (e.start + e.end)
    d = e.end - e.start
    normal_left = np.stack([-d[:, 1], d[:, 0]], 1) / np.linalg.norm(d, axis=1)[:, None]
    eps = 0.25 * frame.resolution
    left, right = mid + eps * normal_left, mid - eps * normal_left
    assert cell_occupied_at(occ, frame, left[:, 0], left[:, 1]).all()
    assert not cell_occupied_at(occ, frame, right[:, 0], right[:, 1]).any()


def test_cell_occupied_at():
    frame = GridFrame(0.5, origin_x=-1.0, origin_y=2.0, yaw=0.4)
    rng = np.random.default_rng(5)
    occ = rng.random((6, 8)) < 0.5
    iy, ix = np.mgrid[0:6, 0:8]
    cx, cy = frame.cell_to_map(ix + 0.5, iy + 0.5)
    np.testing.assert_array_equal(cell_occupied_at(occ, frame, cx, cy), occ)
    # outside the grid and NaN are free; scalars broadcast
    full = np.ones((6, 8), dtype=bool)
    ox, oy = frame.cell_to_map(np.array([-0.5, 8.5, 3.0, 3.0]), np.array([3.0, 3.0, -0.5, 6.5]))
    assert not cell_occupied_at(full, frame, ox, oy).any()
    assert not cell_occupied_at(full, frame, math.nan, 2.5)
    assert cell_occupied_at(full, frame, *frame.cell_to_map(0.5, 0.5)).shape == ()
    # cells are half-open: a corner point (exact for yaw = 0) belongs to the larger index
    f0 = GridFrame(0.25, 1.0, 1.0)
    occ = np.zeros((2, 2), dtype=bool)
    occ[1, 1] = True
    assert cell_occupied_at(occ, f0, 1.25, 1.25)
    assert not cell_occupied_at(occ, f0, 1.5, 1.5)


# --- occupied_cells --------------------------------------------------------------------------

def test_occupied_cells_threshold_and_unknown():
    data = [0, 64, 65, 100, -1, 30, 101, -1]
    np.testing.assert_array_equal(occupied_cells(data, 4, 2),
                                  [[False, False, True, True], [False, False, True, False]])
    np.testing.assert_array_equal(occupied_cells(data, 4, 2, unknown_is_occupied=True),
                                  [[False, False, True, True], [True, False, True, True]])
    np.testing.assert_array_equal(occupied_cells(data, 2, 4, threshold=30),
                                  [[False, True], [True, True], [False, True], [True, False]])
    # threshold 0: every known cell; 100: only certain ones; unknown never by threshold
    assert occupied_cells(data, 8, 1, threshold=0).tolist() == [[True, True, True, True, False,
                                                                 True, True, False]]
    assert occupied_cells(data, 8, 1, threshold=100).sum() == 2


def test_occupied_cells_input_types():
    values = [-1, 0, 80, 100, 50, -1]
    expected = occupied_cells(values, 3, 2)
    assert expected.shape == (2, 3) and expected.dtype == np.bool_
    raw = np.array(values, dtype=np.int8)
    for data in (array.array("b", values), raw, raw.tobytes(), raw.view(np.uint8)):
        np.testing.assert_array_equal(occupied_cells(data, 3, 2), expected)
        np.testing.assert_array_equal(occupied_cells(data, 3, 2, unknown_is_occupied=True),
                                      occupied_cells(values, 3, 2, unknown_is_occupied=True))


@pytest.mark.parametrize("kwargs, message", [
    (dict(data=[0] * 12, width=4, height=4), "data has 12 values, width*height = 16"),
    (dict(data=[0] * 4, width=0, height=4), "width must be > 0, got 0"),
    (dict(data=[0] * 4, width=4, height=-1), "height must be > 0, got -1"),
    (dict(data=[0] * 4, width=2.0, height=2), "width must be an integer"),
    (dict(data=[0] * 4, width=2, height=2, threshold=101), "threshold must be in 0..100, got 101"),
    (dict(data=[0] * 4, width=2, height=2, threshold=-1), "threshold must be in 0..100, got -1"),
    (dict(data=[0] * 4, width=2, height=2, threshold=0.5), "threshold must be an integer"),
    (dict(data=np.zeros((2, 2), np.int8), width=2, height=2), "data must be 1-D"),
    (dict(data=[0.0] * 4, width=2, height=2), "data must hold integers, got dtype float64"),
])
def test_occupied_cells_errors(kwargs, message):
    with pytest.raises(ValueError, match=message.replace("*", r"\*").replace(".", r"\.")):
        occupied_cells(**kwargs)


@pytest.mark.parametrize("kwargs, message", [
    (dict(resolution=0.0), "GridFrame.resolution must be > 0, got 0.0"),
    (dict(resolution=-0.05), "GridFrame.resolution must be > 0, got -0.05"),
    (dict(resolution=math.nan), "GridFrame.resolution must be finite, got nan"),
    (dict(resolution=math.inf), "GridFrame.resolution must be finite, got inf"),
    (dict(resolution=0.05, origin_x=math.nan), "GridFrame.origin_x must be finite"),
    (dict(resolution=0.05, origin_y=-math.inf), "GridFrame.origin_y must be finite"),
    (dict(resolution=0.05, yaw=math.nan), "GridFrame.yaw must be finite"),
    (dict(resolution="a"), "GridFrame.resolution must be a real number"),
])
def test_grid_frame_errors(kwargs, message):
    with pytest.raises(ValueError, match=message.replace(".", r"\.")):
        GridFrame(**kwargs)


def test_grid_frame_coerces_and_is_frozen():
    f = GridFrame(1, 2, 3, 0)
    assert (f.resolution, f.origin_x, f.origin_y, f.yaw) == (1.0, 2.0, 3.0, 0.0)
    assert all(type(v) is float for v in (f.resolution, f.origin_x, f.origin_y, f.yaw))
    with pytest.raises(AttributeError):
        f.resolution = 2.0


def test_boundary_edges_errors():
    with pytest.raises(ValueError, match="occupied must be a bool array .* got dtype int8"):
        boundary_edges(np.array([[0, -1], [100, 0]], dtype=np.int8), UNIT)
    with pytest.raises(ValueError, match=r"occupied must be 2-D \(height, width\), got shape"):
        boundary_edges(np.zeros(4, dtype=bool), UNIT)
    with pytest.raises(ValueError, match="occupied must be a bool array"):
        cell_occupied_at(np.zeros((2, 2)), UNIT, 0.5, 0.5)
