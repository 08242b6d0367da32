"""The projection bound of the screen (core.uncertainty.projection, docs/uncertainty.md,
"Screening").

Guarantees proved here:
* ``projection_bound`` is an upper bound of P(contact within [0, H]): on random pairs of every
  kind (near misses, head-on, crossing; straight and accelerating; correlated, position-only,
  velocity-only and rank-deficient covariances; sigma from 0.05 to 3 x the contact radius;
  2-D and 3-D) it is never below the full evaluation's probability minus its stated bound,
  nor below seeded Monte Carlo on the exact solver minus 4 standard errors;
* it is exactly symmetric under swapping the bodies (X -> -X) and monotone in the radius;
* its window, the tube walk stopped at a smaller depth (``tube_window``), covers every
  ambiguous interval of the full walk and finds the tube wholly inside no earlier;
* it clears what the tube cannot: tracker-like near misses, passing 4 to 6 relative sigmas
  apart, whose 3.85-sigma screening tube reaches the ball, are bounded below threshold / 2
  (such pairs were deferred, and listed with wide intervals, before the projection screen).
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from circle_collision_ros.core import time_to_collision
from circle_collision_ros.core.uncertainty import uncertain_pairs
from circle_collision_ros.core.uncertainty.projection import projection_bound, projection_rows
from circle_collision_ros.core.uncertainty.tube import (TUBE_DEPTH, screen_rows, screen_sigmas,
                                                        tube_intervals, tube_window)
from tests.stress import examples

H, THR = 5.0, 0.01


def _cov(rng, D: int, kind: str, sp: float, sv: float) -> np.ndarray:
    B = rng.normal(size=(2 * D, 2 * D))
    B[:D] *= sp
    B[D:] *= sv
    C = B @ B.T / (2 * D)
    if kind == "position":
        C[D:, :] = C[:, D:] = 0.0
    elif kind == "velocity":
        C[:D, :] = C[:, :D] = 0.0
    elif kind == "rank":
        w, V = np.linalg.eigh(C)
        w[: D - 1] = 0.0
        C = (V * w) @ V.T
        C = 0.5 * (C + C.T)
    elif kind == "diagonal":
        C = np.diag([sp**2] * D + [sv**2] * D)
    return C


def _pair(rng, D: int, it: int):
    """(dp, dv, da, R, Sigma): the relative state of a pair of kind it % 6."""
    R = float(rng.uniform(0.6, 3.0))
    sp = R * 10 ** rng.uniform(-1.3, 0.5)
    sv = sp * rng.uniform(0.2, 1.0)
    kind = ("diagonal", "full", "position", "velocity", "rank", "full")[it % 6]
    speed = rng.uniform(0.3, 3.0)
    direction = rng.normal(size=D)
    direction /= np.linalg.norm(direction)
    side = rng.normal(size=D)
    side -= side @ direction * direction
    side /= np.linalg.norm(side)
    miss = R + rng.uniform(-0.5, 4.0) * sp * math.sqrt(2)
    meet = rng.uniform(0.5, H)
    dv = -speed * direction
    dp = speed * meet * direction + miss * side
    da = np.zeros(D) if it % 3 == 0 else rng.normal(size=D) * rng.uniform(0.05, 0.8)
    return dp, dv, da, R, _cov(rng, D, kind, sp, sv)


def _mc(dp, dv, da, R, Sigma, m, seed):
    D = dp.shape[0]
    g = np.random.default_rng(seed)
    lam, V = np.linalg.eigh(Sigma)
    y = g.standard_normal((m, 2 * D)) @ (V * np.sqrt(np.clip(lam, 0, None))).T
    z = np.zeros((m, D))
    t = time_to_collision(dp + y[:, :D], dv + y[:, D:], np.broadcast_to(da, (m, D)),
                          np.full(m, R), z, z, z, np.zeros(m), H)
    p = np.count_nonzero(t <= H) / m
    return p, math.sqrt(max(p * (1 - p), 1 / m) / m)


@pytest.mark.parametrize("D", [2, 3])
def test_projection_bound_is_an_upper_bound(D):
    rng = np.random.default_rng(500 + D)
    z = np.zeros(D)
    checked = tight = 0
    for it in range(examples(60, 240) if D == 2 else examples(24, 96)):
        dp, dv, da, R, S = _pair(rng, D, it)
        ub = projection_bound(dp, dv, da, R, S, H)
        assert 0.0 < ub <= 1.0
        if ub >= 0.999:
            continue
        tight += ub < 0.5
        res = uncertain_pairs(*(np.asarray(x, dtype=np.float64)[None] for x in (
            dp, dv, da, R / 2, S, z, z, z, R / 2, np.zeros_like(S))), H, THR)
        p, b = float(res.collision_probability[0]), float(res.collision_probability_bound[0])
        assert p - b <= ub, (it, p, b, ub)
        if checked < examples(8, 30):
            q, se = _mc(dp, dv, da, R, S, 100_000, seed=700 + it)
            assert q - 4 * se <= ub, (it, q, se, ub)
            checked += 1
    assert tight >= 10  # the bound is informative on most of these pairs


def test_projection_bound_is_swap_symmetric_and_monotone_in_radius():
    rng = np.random.default_rng(9)
    for it in range(60):
        dp, dv, da, R, S = _pair(rng, 2, it)
        ub = projection_bound(dp, dv, da, R, S, H)
        assert projection_bound(-dp, -dv, -da, R, S, H) == ub
        assert projection_bound(dp, dv, da, 0.8 * R, S, H) <= ub
    rows = [_pair(rng, 3, it) for it in range(12)]
    dp, dv, da = (np.array([r[k] for r in rows]) for k in range(3))
    rad = np.array([r[3] for r in rows])
    sig = np.array([r[4] for r in rows])
    want = [projection_bound(dp[j], dv[j], da[j], rad[j], sig[j], H) for j in range(12)]
    assert projection_rows(dp, dv, da, rad, sig, H).tolist() == want


def test_tube_window_covers_the_full_walk():
    rng = np.random.default_rng(5)
    full, coarse = np.empty((1 << TUBE_DEPTH, 2)), np.empty((1 << TUBE_DEPTH, 2))
    seen = 0
    for it in range(200):
        D = 2 + it % 2
        dp, dv, da, R, S = _pair(rng, D, it)
        for k in (3.0, 5.5, 7.5):
            n, inside = tube_intervals(dp, dv, da, R, S, H, full, k)
            for depth in (3, 5):
                m, inside_w = tube_window(dp, dv, da, R, S, H, coarse, k, depth)
                assert inside_w >= inside
                for a, b in full[:n]:
                    assert any(c <= a and b <= d for c, d in coarse[:m]), (it, k, depth, a, b)
                seen += n > 0
    assert seen > 100


def test_projection_screens_near_misses_the_tube_cannot():
    """Tracker-like pairs (the node benchmark's bodies: speeds up to 3 m/s, accelerations up to
    0.5 m/s^2, radii 0.3 to 2 m; diagonal covariance, 0.3 m and 0.2 m/s per body) within 15 m
    of each other: of the pairs whose screening tube reaches the ball and whose probability is
    clearly below the threshold (full evaluation + bound < threshold / 4), the projection
    bound clears at least half, and every row it clears holds against the full evaluation."""
    rng = np.random.default_rng(31)
    k, _ = screen_sigmas(THR, 4)
    n = 600
    cov = np.diag([0.09, 0.09, 0.04, 0.04])

    def vectors(scale):
        v = rng.normal(size=(n, 2))
        return v / np.linalg.norm(v, axis=1)[:, None] * rng.uniform(0, scale, (n, 1))

    pa, pb = np.zeros((n, 2)), vectors(15.0)
    va, vb, aa, ab = vectors(3.0), vectors(3.0), vectors(0.5), vectors(0.5)
    ra, rb = rng.uniform(0.3, 2.0, n), rng.uniform(0.3, 2.0, n)
    ca = cb = np.tile(cov, (n, 1, 1))
    clear, first = np.zeros(n, dtype=bool), np.empty(n)
    screen_rows(pa - pb, va - vb, aa - ab, ra + rb, ca + cb, H, k, clear, first)
    scr = uncertain_pairs(pa, va, aa, ra, ca, pb, vb, ab, rb, cb, H, THR, screen=True)
    full = uncertain_pairs(pa, va, aa, ra, ca, pb, vb, ab, rb, cb, H, THR)
    cleared = (scr.collision_probability == 0.0) & (scr.collision_probability_bound <= THR / 2)
    assert np.all(full.collision_probability[cleared] - full.collision_probability_bound[cleared]
                  <= scr.collision_probability_bound[cleared])
    low = ~clear & (full.collision_probability + full.collision_probability_bound < THR / 4)
    assert np.count_nonzero(low) >= 20
    assert np.count_nonzero(cleared & low) >= np.count_nonzero(low) // 2
