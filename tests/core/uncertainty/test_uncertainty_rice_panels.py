"""The Rice panel integrals (``walk.rice_panel``) against a dense reference, swept in speed.

Guarantee checked here (docs/uncertainty.md, "Not guaranteed / weak"): the integral of
the entry rate nu+ over the panels of a pair's tube interval, as ``pair_kernel`` computes it
(K15, then P31, then halves), lies within the error it states of the integral itself.

The failure this guards against is narrow in the pair's parameters. The entry rate is a
bump that moves across the K15 nodes as the pair's speed changes. One equal-width panel per
tube interval put it between the nodes of every rule for speeds 2.872 to 2.876 of
``BUMP_AT_START_PAIR`` only: the integral came out 0.029 low, against a stated error of
6e-4, and the pair read 0.967 +- 0.007 where contact is 0.9988. One panel mapped onto the
first bump (core.uncertainty.panel_map) without the cuts between bumps missed the pair's
second bump at x3.02 (6e-3 off, 1.8e-3 stated). A Monte Carlo test at 21 speeds meets such
a window only by chance. This sweep takes thousands of speeds, because its reference needs
no sampling.

The reference is composite Simpson over each panel, on n and 2n intervals, of
``nu_plus_2d`` / ``nu_plus_3d`` at a tight tolerance (1e-10 / 1e-9 per value). nu+
itself is checked against an independent integral in test_uncertainty_entry_rate.py; what
is tested here is the t-quadrature and its estimate. The two Simpson sums must agree to a
tenth of the stated error (n is raised until they do), so the reference is known to be
better than the bound it checks.
"""
from __future__ import annotations

import numpy as np
import pytest
from numba import njit

from circle_collision_ros.core.uncertainty.entry_rate import nu_plus_2d, nu_plus_3d
from circle_collision_ros.core.uncertainty.tube import (BROAD_PHASE_SIGMAS, TUBE_DEPTH,
                                                        tube_intervals)
from circle_collision_ros.core.uncertainty.walk import (CACHE_COLUMNS, PANELS, ST_SIZE,
                                                        rice_panel, walk_panels)
from tests.core.uncertainty.test_uncertainty_horizon import (BUMP_AT_START_PAIR,
                                                             PEAK_BETWEEN_NODES_PAIR, random_pair)
from tests.stress import STRESS

H = 5.0


@njit(cache=False)
def _panels_against_simpson(dp, dv, da, R, Sigma, n, out):
    """Per row r: out[r] = (the panels' integral, its stated error, Simpson on n intervals
    per panel, Simpson on 2n); all 0 where the tube leaves nothing to integrate (no
    ambiguous interval, or the tube wholly inside within [0, H])."""
    for r in range(dp.shape[0]):
        out[r, :] = 0.0
        leaves = np.empty((1 << TUBE_DEPTH, 2))
        cnt, t_inside = tube_intervals(dp[r], dv[r], da[r], R[r], Sigma[r], H, leaves,
                                       BROAD_PHASE_SIGMAS)
        if cnt == 0 or t_inside <= H:
            continue
        st = np.zeros(ST_SIZE)
        acc = np.zeros(3)
        pa = np.empty(PANELS * cnt + 1)
        pb = np.empty(PANELS * cnt + 1)
        npan = walk_panels(dp[r], dv[r], da[r], R[r], Sigma[r], leaves, cnt, t_inside, pa, pb)
        cache = np.zeros((npan + 1, CACHE_COLUMNS))
        for j in range(npan):
            v, e = rice_panel(dp[r], dv[r], da[r], R[r], Sigma[r], pa, pb, j, cache, acc, st)
            out[r, 0] += v
            out[r, 1] += e
            h = (pb[j] - pa[j]) / (2 * n)
            coarse = 0.0
            fine = 0.0
            for i in range(2 * n + 1):
                t = pa[j] + i * h
                if dp.shape[1] == 2:
                    f = nu_plus_2d(dp[r], dv[r], da[r], R[r], Sigma[r], t, 1e-10, acc)
                else:
                    f = nu_plus_3d(dp[r], dv[r], da[r], R[r], Sigma[r], t, 1e-9, acc)
                # Simpson's weights 1 4 2 ... 4 1 on the 2n intervals, and on the n
                # intervals of the even points
                end = i == 0 or i == 2 * n
                fine += f * (1.0 if end else (4.0 if i % 2 == 1 else 2.0))
                if i % 2 == 0:
                    coarse += f * (1.0 if end else (4.0 if (i // 2) % 2 == 1 else 2.0))
            out[r, 2] += coarse * 2.0 * h / 3.0
            out[r, 3] += fine * h / 3.0


def _speed_sweep(pair: dict, speeds: np.ndarray) -> tuple[np.ndarray, ...]:
    """The pair's relative rows at each speed: velocities x s, accelerations x s^2, the
    velocity covariance x s^2 (times in [0, H] scale by 1 / s)."""
    k = speeds.size
    dp = np.tile(np.asarray(pair["dp"], dtype=np.float64), (k, 1))
    dv = speeds[:, None] * np.asarray(pair["dv"], dtype=np.float64)
    da = (speeds**2)[:, None] * np.asarray(pair["da"], dtype=np.float64)
    T = np.ones((k, 4))
    T[:, 2:] = speeds[:, None]
    Sigma = np.ascontiguousarray(T[:, :, None] * np.asarray(pair["Sigma"]) * T[:, None, :])
    return dp, dv, da, np.full(k, float(pair["R"])), Sigma


def _assert_within_stated_error(rows: tuple[np.ndarray, ...], labels) -> int:
    """Every row's panel integral within its stated error of the reference; returns the
    number of rows that had panels. The reference starts at 500 Simpson intervals per panel
    and takes 8x more where its two sums do not yet agree to a tenth of the stated error
    (a spike of nu+ where S(t) is nearly singular, e.g. velocity-only covariances near
    t = 0), up to 32,000."""
    def unsettled(out: np.ndarray) -> np.ndarray:
        """Rows whose two Simpson sums differ by more than a tenth of the stated error."""
        return np.flatnonzero(np.abs(out[:, 3] - out[:, 2]) > 0.1 * out[:, 1] + 1e-12)

    out = np.zeros((rows[0].shape[0], 4))
    _panels_against_simpson(*rows, 500, out)
    for n in (4000, 32000):
        redo = unsettled(out)
        if redo.size == 0:
            break
        part = np.zeros((redo.size, 4))
        _panels_against_simpson(*(np.ascontiguousarray(x[redo]) for x in rows), n, part)
        out[redo] = part
    # the reference converged well inside the bound it checks
    left = unsettled(out)
    assert left.size == 0, [labels[i] for i in left[:5]]
    value, stated, _, fine = out.T
    has = fine > 0.0
    bad = np.flatnonzero(np.abs(value - fine) > stated)
    assert bad.size == 0, [(labels[i], value[i], fine[i], stated[i]) for i in bad[:5]]
    return int(np.count_nonzero(has))


# Quick: a coarse grid of speeds; stress: every 0.002 (the PANELS = 1 window above is
# 0.004 wide), up to 6x, where the bump spans ~0.05 s of the 5 s panel
_STEP = 0.002 if STRESS else 0.02


@pytest.mark.parametrize("name,pair", [("bump at start", BUMP_AT_START_PAIR),
                                       ("peak between nodes", PEAK_BETWEEN_NODES_PAIR)])
def test_rice_panels_within_their_stated_error_at_every_speed(name: str, pair: dict) -> None:
    speeds = np.arange(0.3, 6.0, _STEP)
    checked = _assert_within_stated_error(_speed_sweep(pair, speeds),
                                          [f"{name} x{s:.3f}" for s in speeds])
    assert checked == speeds.size


def _random_rows(D: int, kind: str, count: int, seed: int) -> tuple[np.ndarray, ...]:
    """Relative rows of test_uncertainty_horizon's random pairs of one family."""
    rng = np.random.default_rng(seed)
    rows = []
    for _ in range(count):
        pa, va, aa, ra, ca, pb, vb, ab, rb, cb = random_pair(rng, D, kind)
        rows.append((pa - pb, va - vb, aa - ab, ra + rb, ca + cb))
    return tuple(np.ascontiguousarray(np.array([r[i] for r in rows])) for i in range(5))


@pytest.mark.parametrize("kind", ["correlated", "accelerating", "accelerating-wide",
                                  "position-only", "velocity-only"])
def test_rice_panels_within_their_stated_error_on_random_pairs(kind: str) -> None:
    """test_uncertainty_horizon's 2-D families (rank-deficient ones take the sampling
    fallback: no Rice panels)."""
    count = 400 if STRESS else 80
    checked = _assert_within_stated_error(_random_rows(2, kind, count, 71),
                                          [f"{kind} #{i}" for i in range(count)])
    assert checked > 0


@pytest.mark.stress
@pytest.mark.parametrize("kind", ["correlated", "accelerating", "accelerating-wide"])
def test_rice_panels_within_their_stated_error_on_random_3d_pairs(kind: str) -> None:
    """The 3-D cap's t panels on the same families (a dense reference costs ~1 s per row
    in 3-D; position- and velocity-only covariances, whose rate factor has a kink, take
    minutes per row at the reference's tolerance and are left out)."""
    checked = _assert_within_stated_error(_random_rows(3, kind, 12, 72),
                                          [f"3-D {kind} #{i}" for i in range(12)])
    assert checked > 0
