"""A cheap certified interval for P(contact within [0, H]), for rows without the full evaluation.

When the per-prediction budget leaves a pair unevaluated, its row still states an interval
[lo, hi] that contains the true probability, computed from this call's states in a few
microseconds:

* hi: the k-sigma tube screen (``tube.screen_rows``) on a ladder of k, by bisection: the
  largest k found whose tube never reaches the ball gives hi = P(chi^2_2D > k^2), since
  every contact path has |z| > k (docs/uncertainty.md, "Screening"); 1 where none does.
* lo: P(contact within [0, H]) >= P(|X(t)| <= R) at any t in [0, H] (a body overlapping
  at t has touched by t), at the t of the mean path's closest approach on a grid,
  less the stated error of ``overlap_probability`` (P0_ERR); 0 at worst.

The row then reads probability (lo + hi) / 2 with a bound reaching both ends: the same
meaning as a fully evaluated row's, |reported - true| <= bound.  An interval as wide as [0, 1] reads
0.5 +- 0.5, which says "unknown", never "certain contact".

References
----------
.. [1] docs/uncertainty.md, "Screening" (the tube and the chi-square tail) and
   "Screening and the per-prediction budget".
"""
from __future__ import annotations

import functools

import numpy as np
from numba import njit

from circle_collision_ros.core.uncertainty.overlap import overlap_probability
from circle_collision_ros.core.uncertainty.tube import S_at, screen_rows, screen_sigmas
from circle_collision_ros.core.uncertainty.walk import P0_ERR

__all__ = ["INTERVAL_TAILS", "CLOSEST_GRID", "cheap_intervals", "lower_bound", "lower_bounds",
           "upper_bounds"]

#: Upper bounds tried, smallest first (each P(chi^2_2D > k^2) of its k): ten steps up to
#: 0.5, then 0.8; a row that no tube of these clears gets hi = 1.
INTERVAL_TAILS = (0.001, 0.002, 0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.35, 0.5, 0.8)
#: Grid points on [0, H] where the mean relative distance is compared for the lower bound.
CLOSEST_GRID = 64


@njit(cache=True, error_model="numpy")
def lower_bound(dp, dv, da, R, Sigma, H):
    """max(0, P(|X(t*)| <= R) - P0_ERR) for one relative row (dp, dv, da (D,), Sigma (2D, 2D)),
    t* the point of a CLOSEST_GRID-step grid on [0, H] nearest the ball along the mean path
    m(t) = dp + dv t + da t^2 / 2 (X(t) ~ N(m(t), S(t)), S_at).  A lower bound on
    P(contact within [0, H]) whatever t* is; the grid only makes it tight."""
    D = dp.shape[0]
    best_t, best = 0.0, np.inf
    for g in range(CLOSEST_GRID + 1):
        t = H * g / CLOSEST_GRID
        d2 = 0.0
        for c in range(D):
            m = dp[c] + dv[c] * t + 0.5 * da[c] * t * t
            d2 += m * m
        if d2 < best:
            best, best_t = d2, t
    t = best_t
    mean = np.empty(D)
    for c in range(D):
        mean[c] = dp[c] + dv[c] * t + 0.5 * da[c] * t * t
    p = overlap_probability(mean, S_at(Sigma, t), R)
    # P0_ERR: overlap_probability's stated absolute error; 0 below it, and where S(t*)
    # is indefinite by rounding (NaN fails the comparison): 0 is always a bound
    return p - P0_ERR if p - P0_ERR > 0.0 else 0.0


@njit(cache=True, error_model="numpy")
def lower_bounds(dp, dv, da, R, Sigma, H, lo):
    """lo[j] = lower_bound of relative row j (dp, dv, da (n, D), R (n,), Sigma (n, 2D, 2D))."""
    for j in range(dp.shape[0]):
        lo[j] = lower_bound(dp[j], dv[j], da[j], R[j], Sigma[j], H)


@njit(cache=True, error_model="numpy")
def upper_bounds(dp, dv, da, R, Sigma, H, ks, tails, hi):
    """hi[j] = the smallest of ``tails`` whose tube (k = ks[level], tails ascending, ks
    descending) the screen finds never reaching the ball for relative row j, by bisection
    over the levels; 1 where the largest tail's tube reaches it.  Every level the screen
    clears bounds the probability (tube.screen_rows), so the answer is certified even where
    clearing were not monotone in k; bisection only makes it the smallest in ~log2 screens."""
    clear = np.empty(1, dtype=np.bool_)
    t_first = np.empty(1)
    top = ks.shape[0] - 1
    for j in range(dp.shape[0]):
        row = (dp[j:j + 1], dv[j:j + 1], da[j:j + 1], R[j:j + 1], Sigma[j:j + 1])
        screen_rows(*row, H, ks[top], clear, t_first)
        if not clear[0]:
            hi[j] = 1.0
            continue
        good, bad = top, -1  # levels: good cleared; none at or below bad is known cleared
        while good - bad > 1:
            mid = (good + bad) // 2
            screen_rows(*row, H, ks[mid], clear, t_first)
            if clear[0]:
                good = mid
            else:
                bad = mid
        hi[j] = tails[good]


def cheap_intervals(dp: np.ndarray, dv: np.ndarray, da: np.ndarray, R: np.ndarray,
                    Sigma: np.ndarray, H: float) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi): (n,) certified bounds on P(contact within [0, H]) of n relative rows
    (dp, dv, da (n, D) [m, m/s, m/s^2], R (n,) [m], Sigma (n, 2D, 2D) C-contiguous float64,
    as ``pair.relative_rows`` gives them).  Deterministic: a function of each row's inputs and
    H only, so sign-canonicalised rows give swapped pairs the same bits."""
    n = dp.shape[0]
    ks, tails = _ladder(2 * dp.shape[1])
    hi = np.empty(n)
    upper_bounds(dp, dv, da, R, Sigma, H, ks, tails, hi)
    lo = np.empty(n)
    lower_bounds(dp, dv, da, R, Sigma, H, lo)
    # both are bounds on one number, so lo <= hi up to the stated errors; keep the order
    return np.minimum(lo, hi), hi


@functools.lru_cache(maxsize=4)
def _ladder(dof: int) -> tuple[np.ndarray, np.ndarray]:
    """(ks, tails) of INTERVAL_TAILS: P(chi^2_dof > ks[i]^2) = tails[i] <= INTERVAL_TAILS[i]."""
    pairs = [screen_sigmas(2.0 * tail, dof) for tail in INTERVAL_TAILS]
    return np.array([k for k, _ in pairs]), np.array([u for _, u in pairs])
