"""Exact edge-interior contact (``core.static.edge_exact``): hand cases, reference, properties.

The seeded families are checked bit for bit against ``reference_static`` (quartic roots
at high precision, a different method); rows the reference flags ambiguous (an answer
hinging on a quantity within 1e-30 relative of zero) are exempt, counted, and must stay
rare.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from circle_collision_ros.core.static.edge_exact import exact_edge_contact
from tests.core.static.edge_rows import endpoint_rows, graze_rows, make_row, random_rows
from tests.core.static.reference_static import reference_edge

INF = math.inf
A0, B0 = (0.0, 0.0), (10.0, 0.0)  # the x-axis segment of the hand cases; left = y > 0
Z = (0.0, 0.0)


def _check_family(rows, min_hits: int) -> None:
    """Every non-ambiguous row equals the reference bit for bit; ambiguous rows are rare."""
    bad, ambiguous, hits = [], 0, 0
    for row in rows:
        got = exact_edge_contact(*row)
        want, amb = reference_edge(*row)
        ambiguous += amb
        hits += 0.0 < got < INF
        if not amb and got != want:
            bad.append((row, got, want))
    assert not bad, f"{len(bad)} mismatches, first: {bad[:3]}"
    assert ambiguous <= len(rows) // 100, ambiguous
    assert hits >= min_hits, hits  # the family exercises positive contact times


# --- seeded families against the reference -------------------------------------------------

def test_straight_lines_match_reference():
    _check_family(random_rows(101, 2000, accelerate=False), min_hits=500)


def test_accelerating_match_reference():
    _check_family(random_rows(202, 2000, accelerate=True), min_hits=500)


def test_near_grazing_match_reference():
    def gaps(rng, r):
        return rng.choice([-1, 1]) * r * 10 ** rng.uniform(-13, -11)

    rows = graze_rows(303, 2000, gaps)
    _check_family(rows, min_hits=700)
    misses = sum(exact_edge_contact(*row) == INF for row in rows)
    assert misses >= 700  # both outcomes of the 1e-12 graze occur


def test_map_scale_match_reference():
    # coordinates ~1e4 m, radii ~0.2-2 m, closest approach within 1 um - 10 mm of r
    def gaps(rng, r):
        return rng.choice([-1, 1]) * 10 ** rng.uniform(-6, -2)

    rows = graze_rows(404, 1000, gaps, offset=1e4)
    rows += random_rows(405, 1000, accelerate=True, offset=1.2e4)
    _check_family(rows, min_hits=700)


def test_foot_point_near_an_endpoint_match_reference():
    rows = endpoint_rows(505, 2000)
    _check_family(rows, min_hits=500)


# --- hand cases ----------------------------------------------------------------------------

def test_straight_approach():
    assert exact_edge_contact((5, 5), (0, -1), Z, 1.0, A0, B0, 0) == 4.0  # s = 5 - t = 1
    assert exact_edge_contact((5, -5), (0, 1), Z, 1.0, A0, B0, 0) == 4.0  # from the right
    assert exact_edge_contact((5, 5), (0, -1), Z, 1.0, A0, B0, 0, 4.0) == 4.0  # t == H counts
    assert exact_edge_contact((5, 5), (0, -1), Z, 1.0, A0, B0, 0, 3.9) == INF
    assert exact_edge_contact((5, 0.5), (0, 1), Z, 1.0, A0, B0, 0) == 0.0  # overlap at 0
    assert exact_edge_contact((5, 0.5), (0, 1), Z, 1.0, A0, B0, 0, 0.0) == 0.0


def test_sliding_along_the_wall_at_exactly_the_radius():
    assert exact_edge_contact((1, 1), (1, 0), Z, 1.0, A0, B0, 0) == INF
    assert exact_edge_contact((1, -1), (2, 0), (0.5, 0), 1.0, A0, B0, 1) == INF
    assert exact_edge_contact((5, 1), Z, Z, 1.0, A0, B0, 0) == INF  # resting on it


def test_touching_at_zero_moving_away():
    assert exact_edge_contact((5, 1), (0, 1), Z, 1.0, A0, B0, 0) == INF
    # s = 1 + t - t^2/2 comes back to 1 at t = 2 (foot still at x = 5)
    assert exact_edge_contact((5, 1), (0, 1), (0, -1), 1.0, A0, B0, 0) == 2.0
    # separating at second order (s = 1 + t^2/2): never back
    assert exact_edge_contact((5, 1), (1, 0), (0, 1), 1.0, A0, B0, 0) == INF


def test_touching_at_zero_approaching():
    assert exact_edge_contact((5, 1), (0, -1), Z, 1.0, A0, B0, 0) == 0.0
    assert exact_edge_contact((5, -1), (3, 1), Z, 1.0, A0, B0, 0) == 0.0
    assert exact_edge_contact((5, 1), (1, 0), (0, -1), 1.0, A0, B0, 0) == 0.0  # 2nd order
    # foot point at A moving into the segment: contact; moving away from it: the endpoint's
    assert exact_edge_contact((0, 1), (1, -1), Z, 1.0, A0, B0, 0) == 0.0
    assert exact_edge_contact((0, 1), (-1, -1), Z, 1.0, A0, B0, 0) == INF
    assert exact_edge_contact((10, 1), (-1, -1), Z, 1.0, A0, B0, 0) == 0.0
    assert exact_edge_contact((-1, 1), (0, -1), Z, 1.0, A0, B0, 0) == INF  # foot outside
    assert exact_edge_contact((0, 1), (0, -1), Z, 1.0, A0, B0, 0) == INF  # foot stays at A


def test_tangent_graze_at_exactly_r():
    # s(t) = 1 + (t - 1)^2: touches r = 1 at t = 1 from outside
    assert exact_edge_contact((5, 2), (0, -2), (0, 2), 1.0, A0, B0, 0) == 1.0
    # s(t) = 1 + (t - 0.75)^2 = 1.5625 - 1.5 t + t^2
    assert exact_edge_contact((5, 1.5625), (0, -1.5), (0, 2), 1.0, A0, B0, 0) == 0.75
    # a 3-4-5 wall (L = 5): c(t) = (2, 1.5) + (t^2 - 2t + 2)(-3, 4), distance 5 (t^2 - 2t + 2)
    A, B = (0.0, 0.0), (4.0, 3.0)
    p, v, a = (-4.0, 9.5), (6.0, -8.0), (-6.0, 8.0)
    assert exact_edge_contact(p, v, a, 5.0, A, B, 0) == 1.0
    assert exact_edge_contact(p, v, a, math.nextafter(5.0, 0.0), A, B, 0) == INF  # misses
    # r = 5 (1 + 2^-50): (t - 1)^2 = 2^-50, entering at t = 1 - 2^-25 exactly
    assert exact_edge_contact(p, v, a, 5.0 * (1 + 2.0 ** -50), A, B, 0) == 1 - 2.0 ** -25
    # touching from inside (s(t) = 1 - (t-1)^2 <= r = 1) is not an entering root
    assert exact_edge_contact((5, 0), (0, 2), (0, -2), 1.0, A0, B0, 0, 1.5) == 0.0  # overlap
    assert exact_edge_contact((-5, 0), (10, 2), (0, -2), 1.0, A0, B0, 0, 1.5) == INF


def test_crossing_the_line_at_an_endpoint_foot():
    # reaches distance 1 at t = 2 exactly above A (pr == 0): the endpoint's contact
    assert exact_edge_contact((-2, 3), (1, -1), Z, 1.0, A0, B0, 0) == INF
    assert exact_edge_contact((12, 3), (-1, -1), Z, 1.0, A0, B0, 0) == INF  # above B
    assert exact_edge_contact((-1.5, 3), (1, -1), Z, 1.0, A0, B0, 0) == 2.0  # x = 0.5 inside
    assert exact_edge_contact((-2, 2), (1, -1), Z, 0.0, A0, B0, 0) == INF  # point through A


def test_point_crossing_a_two_sided_wall():
    assert exact_edge_contact((5, 2), (0, -1), Z, 0.0, A0, B0, 0) == 2.0
    assert exact_edge_contact((5, -2), (0, 1), Z, 0.0, A0, B0, 0) == 2.0
    assert exact_edge_contact((5, -2), (0, 1), Z, 0.0, A0, B0, 1) == 2.0  # side irrelevant t > 0
    # starting on the wall: a bare wall is never entered at t = 0
    assert exact_edge_contact((5, 0), (0, 1), Z, 0.0, A0, B0, 0) == INF
    assert exact_edge_contact((5, 0), (0, 1), (0, -1), 0.0, A0, B0, 0) == 2.0  # back at t = 2


def test_point_on_a_solid_edge():
    # solid on the left (y > 0): moving into it is contact at once
    assert exact_edge_contact((5, 0), (0, 1), Z, 0.0, A0, B0, 1) == 0.0
    assert exact_edge_contact((5, 0), (1, 0), (0, 1), 0.0, A0, B0, 1) == 0.0  # 2nd order
    assert exact_edge_contact((5, 0), (0, -1), Z, 0.0, A0, B0, -1) == 0.0  # solid on the right
    # moving out of it: no contact at 0, the re-crossing counts (s = -t + t^2/2: t = 2)
    assert exact_edge_contact((5, 0), (0, -1), Z, 0.0, A0, B0, 1) == INF
    assert exact_edge_contact((5, 0), (0, -1), (0, 1), 0.0, A0, B0, 1) == 2.0
    assert exact_edge_contact((5, 0), (1, 0), Z, 0.0, A0, B0, 1) == INF  # along the edge
    # at an endpoint: into the solid with the foot entering, or leaving the segment
    assert exact_edge_contact((0, 0), (1, 1), Z, 0.0, A0, B0, 1) == 0.0
    assert exact_edge_contact((0, 0), (-1, 1), Z, 0.0, A0, B0, 1) == INF


def test_round_to_nearest_ties_to_even():
    # s = p_y - t reaches r at t = p_y - r exactly (a rational time)
    t = exact_edge_contact((5, 1 + 2.0 ** -52), (0, -1), Z, 2.0 ** -53, A0, B0, 0)
    assert t == 1.0  # 1 + 2^-53: halfway, to the even 1.0
    t = exact_edge_contact((5, 1 + 2.0 ** -51), (0, -1), Z, 2.0 ** -53, A0, B0, 0)
    assert t == 1 + 2.0 ** -51  # 1 + 3 2^-53: halfway, to the even 1 + 2^-51
    t = exact_edge_contact((5, 1 + 2.0 ** -51), (0, -1), Z, 2.0 ** -54, A0, B0, 0)
    assert t == 1 + 2.0 ** -51  # 1 + 7 2^-54: nearest
    # an irrational time on a slanted wall: L = sqrt(10), t = (8 - sqrt(10) / 2) / 3
    t = exact_edge_contact((1, 3), (0, -1), Z, 0.5, (0, 0), (3, 1), 0)
    assert t == reference_edge((1, 3), (0, -1), Z, 0.5, (0, 0), (3, 1), 0)[0]
    assert abs(t - (8 - math.sqrt(10) / 2) / 3) <= 2 * math.ulp(t)


def test_tiny_and_huge_times():
    # a positive time below the smallest subnormal is not reported as 0 (that means overlap)
    assert exact_edge_contact((5, 1 + 2.0 ** -52), (0, -1.7e308), Z, 1.0, A0, B0, 0) == 5e-324
    # beyond the largest float64: inf
    assert exact_edge_contact((5, 1e300), (0, -1e-300), Z, 1.0, A0, B0, 0) == INF


def test_numpy_inputs():
    # the batch query passes numpy rows and scalars
    args = (np.array([5.0, 5.0]), np.array([0.0, -1.0]), np.zeros(2), np.float64(1.0),
            np.array(A0), np.array(B0), np.int64(1), np.float64(10.0))
    assert exact_edge_contact(*args) == 4.0


@pytest.mark.parametrize("bad", [
    dict(r=-1.0), dict(r=math.nan), dict(p=(math.inf, 0.0)), dict(horizon=-1.0),
    dict(horizon=math.nan), dict(B=A0), dict(solid_side=2), dict(a=(0.0, math.nan)),
])
def test_invalid_input_is_nan(bad):
    args = dict(p=(5.0, 5.0), v=(0.0, -1.0), a=Z, r=1.0, A=A0, B=B0, solid_side=0,
                horizon=INF)
    args.update(bad)
    assert math.isnan(exact_edge_contact(**args))


# --- properties ----------------------------------------------------------------------------

def _grid_rows(seed: int, n: int):
    """Rows on the grid 2^-30 within +-16 (translation by 1024 stays exact).

    Every tenth row is a point body starting exactly on the segment's line.
    """
    rng = np.random.default_rng(seed)

    def g(k):
        return rng.integers(-(2 ** 34), 2 ** 34, k) * 2.0 ** -30

    rows = []
    for i in range(n):
        A, B = g(2), g(2)
        p = (A + B) / 2 if i % 10 == 0 else g(2)  # exact midpoint: on the line
        target = A + rng.uniform(0, 1) * (B - A)
        v = np.round(((target - p) * rng.uniform(0.2, 2) + rng.normal(0, 0.3, 2)) * 2 ** 20)
        a = np.round(rng.normal(0, 1, 2) * 2 ** 20) if i % 2 else np.zeros(2)
        r = 0.0 if i % 10 == 0 else abs(g(1)[0]) / 8
        rows.append(make_row(p, v * 2.0 ** -20, a * 2.0 ** -20, r, A, B, rng.integers(-1, 2),
                              INF if i % 3 else rng.uniform(0, 3)))
    return rows


def test_swapping_the_ends_and_the_solid_side():
    for p, v, a, r, A, B, side, H in _grid_rows(606, 500):
        assert (exact_edge_contact(p, v, a, r, A, B, side, H)
                == exact_edge_contact(p, v, a, r, B, A, -side, H))


def test_translation_by_an_exact_offset():
    for p, v, a, r, A, B, side, H in _grid_rows(707, 500):
        moved = [[x + 1024.0 for x in pt] for pt in (p, A, B)]
        assert all(m - 1024.0 == x for pt, mv in zip((p, A, B), moved) for x, m in zip(pt, mv))
        assert (exact_edge_contact(p, v, a, r, A, B, side, H)
                == exact_edge_contact(moved[0], v, a, r, moved[1], moved[2], side, H))


@pytest.mark.parametrize("k", [-40, -3, 7, 60])
def test_scaling_all_lengths_by_a_power_of_two(k):
    s = 2.0 ** k
    for p, v, a, r, A, B, side, H in _grid_rows(808 + k, 200):
        scaled = [[x * s for x in pt] for pt in (p, v, a, A, B)]
        assert (exact_edge_contact(p, v, a, r, A, B, side, H)
                == exact_edge_contact(scaled[0], scaled[1], scaled[2], r * s, scaled[3],
                                      scaled[4], side, H))
