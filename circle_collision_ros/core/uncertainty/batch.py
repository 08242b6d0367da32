"""Collision probability of Gaussian-uncertain pairs, ROS-free.

Model.  Each body's (position, velocity) at t = 0 is Gaussian with a joint
covariance (order x, y[, z], vx, vy[, vz]); accelerations are exact; bodies
are independent.  The relative centre X(t) = dp + dv t + da t^2/2 is then
Gaussian, X(t) ~ N(g(t), S(t)) with S(t) = Spp + t (Spv + Svp) + t^2 Svv
(Sigma = cov_a + cov_b).  docs/uncertainty.md has the methods, the error
bounds and why they hold.

Public API:

* ``uncertain_pairs(...) -> UncertainPairs``: per row the probability of
  contact within [0, H], a stated bound on its error, and the earliest
  plausible contact time (first t with P(|X(t)| <= R) >= threshold).
* ``BROAD_PHASE_SIGMAS`` and ``inflation_radius``: the broad-phase
  inflation that drops probability mass < 1e-9 per pair.
* ``covariance_problem(cov)`` (core.uncertainty.covariance): why a covariance
  is unusable, or None.

Zero covariance rows (Sigma = 0 exactly) take the exact solver's answer:
probability 1.0 if ``time_to_collision(...) <= H`` else 0.0, bound 0.0,
plausible time = that time or +inf.  Every row's result depends only on the
row (deterministic; sampling, where used, is seeded).
"""
from __future__ import annotations

import math
from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from circle_collision_ros.core.narrow import time_to_collision
from circle_collision_ros.core.uncertainty.interval import cheap_intervals
from circle_collision_ros.core.uncertainty.pair import (OUT_HI, OUT_QMC, OUT_SIZE, OUT_T1,
                                                        evaluate_uncertain_rows, finish_row,
                                                        overcount_answer, relative_rows)
from circle_collision_ros.core.uncertainty.projection import projection_rows, projection_rows_at
from circle_collision_ros.core.uncertainty.qmc import (line_sampled_probability, normal_table,
                                                       qmc_probability)
from circle_collision_ros.core.uncertainty.tube import (BROAD_PHASE_SIGMAS, TUBE_TAIL,
                                                        max_sigma_rows, row_classes, screen_rows_at,
                                                        screen_sigmas)

__all__ = ["UncertainPairs", "uncertain_pairs", "deferred_count", "BROAD_PHASE_SIGMAS",
           "TUBE_TAIL", "inflation_radius", "load_fallback_kernels"]


class UncertainPairs(NamedTuple):
    """Per-row results of ``uncertain_pairs``: three (n,) float64 columns and a (n,) bool."""

    collision_probability: np.ndarray  # P(contact within [0, H])
    collision_probability_bound: np.ndarray  # stated bound on |reported - true|
    # s: first t in [0, H] with P(|X(t)| <= R) >= threshold; +inf if none
    plausible_time: np.ndarray
    # (n,) bool: rows the budget left without the full evaluation (max_evaluated): their
    # probability and bound are the cheap certified interval's (interval.cheap_intervals)
    deferred: np.ndarray


def _rows(x, n, D, name):
    a = np.ascontiguousarray(np.asarray(x, dtype=np.float64))
    shape = (n, D) if D else (n,)
    if a.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {a.shape}")
    return a


def uncertain_pairs(pa, va, aa, ra, cov_a, pb, vb, ab, rb, cov_b, horizon: float, threshold: float,
                    *, screen: bool = False, max_evaluated: int | None = None,
                    priority: Callable[[np.ndarray], np.ndarray] | None = None,
                    memo: dict | None = None,
                    screened_first: np.ndarray | None = None,
                    deferred_answer: tuple[np.ndarray, np.ndarray] | None = None,
                    tolerance: float = 0.0) -> UncertainPairs:
    """Collision probability, its bound and the earliest plausible contact of n pairs.

    pa, va, aa, pb, vb, ab: (n, D) float64, D in {2, 3} [m, m/s, m/s^2];
    ra, rb: (n,) radii [m]; cov_a, cov_b: (n, 2D, 2D) joint covariance of
    (position, velocity) of each body (order x, y[, z], vx, vy[, vz]) [m^2,
    m^2/s, m^2/s^2]; horizon H [s] (finite, >= 0); threshold in (0, 1].
    The caller validates covariances (``covariance_problem``); tiny negative
    eigenvalues from rounding are clamped here.  A row with a non-finite value
    or a negative radius gets NaN in all three outputs.

    screen=True: an uncertain row whose certified upper bound U on
    P(contact within [0, H]) is below threshold / 2 (the k-sigma tube with
    P(chi^2_2D > k^2) = U never reaches the ball, or else, for a row whose screen
    is not known, ``projection.projection_bound`` = U) is answered (0.0, U, +inf)
    without the full evaluation: still |reported - true| <= bound, and the
    plausible time is certified absent (sup_t P(|X(t)| <= R) <= U < threshold).
    Such rows are never published (probability < threshold); the scene
    screens, callers wanting the best estimate of small probabilities do not.

    max_evaluated=m (with screen=True): at most m uncertain rows get the full
    evaluation, those whose screening tube may reach the ball first (ties:
    row order; deterministic, no clock); every other unscreened row is
    *deferred*: answered from a cheap certified interval [lo, hi] of this call's
    states (``interval.cheap_intervals``) as ((lo + hi) / 2, a bound reaching lo and hi,
    t_first): still |reported - true| <= bound, and t_first (where the screening
    tube first may reach the ball) is never later than the true plausible time.
    ``result.deferred`` marks them; ``deferred_count(result)`` counts them.

    priority (with max_evaluated): called once, only when more than
    max_evaluated rows need the full evaluation, with those rows' indices
    (ascending); returns an integer per row, smaller first (then t_first, then
    row order).  The scene passes how long each pair has waited (FIFO, see
    ``Scene.uncertain_pairs``).

    screened_first (with screen=True): (n,) float64, NaN where unknown; elsewhere
    the t_first of an earlier call's screening of the row's bitwise same inputs
    (H and threshold included) that did not clear it, e.g. the plausible time
    that call reported for the row it deferred.  Such rows skip the screen (its
    outcome is a function of those inputs: the same answer, without the
    tube walk); the scene passes its waiting pairs whose bodies did not change.

    deferred_answer (with screened_first): (probability, bound), (n,) float64 each, the
    deferred answer that earlier call gave where screened_first is known (NaN elsewhere):
    deferred again, such a row takes it instead of computing its interval anew (the same
    bits: a function of the same inputs).

    tolerance: the stated bound a fully evaluated row may reach where that saves work
    (``pair.finish_row``: accelerating pairs' bracket and over-count sampling), e.g. 0.005;
    0 (default): every row at the per-pair accuracy.

    memo: a dict the caller keeps between calls.  A row whose relative inputs
    (dp, dv, da, R, Sigma after the sign canonicalisation, with H, the threshold
    and the tolerance) equal those of a row fully evaluated by the previous call
    takes that row's answer bit for bit (the answer is a function of exactly these
    inputs), without counting against max_evaluated; on return the memo holds
    exactly this call's fully evaluated and reused rows.
    """
    pa = np.asarray(pa, dtype=np.float64)
    if pa.ndim != 2 or pa.shape[1] not in (2, 3):
        raise ValueError(f"pa must have shape (n, 2) or (n, 3), got {pa.shape}")
    n, D = pa.shape
    pa = _rows(pa, n, D, "pa")
    va, aa, pb, vb, ab = (
        _rows(x, n, D, name)
        for x, name in ((va, "va"), (aa, "aa"), (pb, "pb"), (vb, "vb"), (ab, "ab"))
    )
    ra, rb = _rows(ra, n, 0, "ra"), _rows(rb, n, 0, "rb")
    cov_a = np.asarray(cov_a, dtype=np.float64)
    cov_b = np.asarray(cov_b, dtype=np.float64)
    for c, name in ((cov_a, "cov_a"), (cov_b, "cov_b")):
        if c.shape != (n, 2 * D, 2 * D):
            raise ValueError(f"{name} must have shape {(n, 2 * D, 2 * D)}, got {c.shape}")
    H = float(horizon)
    if not (H >= 0.0 and math.isfinite(H)):
        raise ValueError(f"horizon must be finite and >= 0, got {horizon!r}")
    thr = float(threshold)
    if not (0.0 < thr <= 1.0):
        raise ValueError(f"threshold must be in (0, 1], got {threshold!r}")
    tol = float(tolerance)
    if not (0.0 <= tol < 1.0):
        raise ValueError(f"tolerance must be in [0, 1), got {tolerance!r}")

    prob = np.zeros(n)
    bound = np.zeros(n)
    deferred = np.zeros(n, dtype=np.bool_)
    tpl = np.empty(n)
    tpl.fill(np.inf)  # (np.full costs more than the rest of a one-row call's set-up)
    sigma = cov_a + cov_b
    exact = np.empty(n, dtype=np.bool_)
    finite = np.empty(n, dtype=np.bool_)
    # the counts spare the array reductions of the common case: all usable
    n_exact, n_bad = row_classes(pa, va, aa, ra, pb, vb, ab, rb, sigma, exact, finite)
    if n_exact:
        ix = np.flatnonzero(exact)
        t = time_to_collision(pa[ix], va[ix], aa[ix], ra[ix], pb[ix], vb[ix], ab[ix], rb[ix], H)
        hit = t <= H
        nan = np.isnan(t)  # invalid input: NaN as time_to_collision
        prob[ix] = np.where(nan, np.nan, np.where(hit, 1.0, 0.0))
        bound[ix] = np.where(nan, np.nan, 0.0)
        tpl[ix] = np.where(hit | nan, t, np.inf)
    # rows with a non-finite value or a negative radius: NaN in all three
    # outputs (as time_to_collision), never a hang or an exception
    if n_bad:
        bad = ~finite & ~exact
        prob[bad] = bound[bad] = tpl[bad] = np.nan
    todo = np.flatnonzero(finite & ~exact) if (n_exact or n_bad) else np.arange(n)
    if max_evaluated is not None and not screen:
        raise ValueError("max_evaluated needs screen=True (deferred rows take the screen's times)")
    if screen and todo.size:
        k, tail = screen_sigmas(thr, 2 * D)
        if not math.isfinite(k):  # threshold too small to screen: tube of k = 40 for the times
            k, tail = 40.0, 0.0
        clear = np.zeros(todo.size, dtype=np.bool_)
        t_first = np.empty(todo.size)
        unknown = np.ones(todo.size, dtype=np.bool_)
        if screened_first is not None:
            known_first = np.asarray(screened_first, dtype=np.float64)[todo]
            unknown = np.isnan(known_first)
            t_first[~unknown] = known_first[~unknown]
        # relative state as below (the tube test is exactly symmetric under X -> -X)
        if unknown.all():
            screen_rows_at(pa, va, aa, ra, pb, vb, ab, rb, sigma, todo, H, k, clear, t_first)
        elif unknown.any():
            c, f = np.zeros(int(unknown.sum()), dtype=np.bool_), np.empty(int(unknown.sum()))
            screen_rows_at(pa, va, aa, ra, pb, vb, ab, rb, sigma, todo[unknown], H, k, c, f)
            clear[unknown], t_first[unknown] = c, f
        projected = np.full(todo.size, np.nan)  # projection bounds computed here
        if tail > 0.0:
            cleared = np.full(todo.size, tail)
            # rows the tube leaves and whose screen is not known: the projection bound (a
            # near miss along one direction, which the tube bounds through all 2D
            # coordinates' tail), the same rule at threshold / 2
            probe = np.flatnonzero(~clear & unknown)
            if probe.size:
                ub = np.empty(probe.size)
                projection_rows_at(pa, va, aa, ra, pb, vb, ab, rb, sigma, todo[probe], H, ub)
                low = ub <= 0.5 * thr
                clear[probe[low]] = True
                cleared[probe[low]] = ub[low]
                projected[probe] = ub
            done = todo[clear]
            prob[done], bound[done], tpl[done] = 0.0, cleared[clear], np.inf
            todo, t_first, projected = todo[~clear], t_first[~clear], projected[~clear]
        todo_first = t_first  # where each remaining row's screening tube may first reach the ball
        todo_projected = projected
    else:
        todo_first = np.empty(todo.size)
        todo_first.fill(np.inf)
        todo_projected = np.full(todo.size, np.nan)
    # relative state from relative quantities (map offsets cancel first);
    # X -> -X leaves the problem unchanged (the ball and S are symmetric): one
    # sign per pair, so swapping a and b gives bitwise the same result
    # (one compiled pass: measured faster than per-row numpy indexing; see
    # bench/bench_uncertainty.py)
    dp = np.empty((todo.size, D))
    dv = np.empty((todo.size, D))
    da = np.empty((todo.size, D))
    rad = np.empty(todo.size)
    sig = np.empty((todo.size, 2 * D, 2 * D))
    relative_rows(pa, va, aa, ra, pb, vb, ab, rb, sigma, todo, dp, dv, da, rad, sig)
    fresh = {}

    def key(j):  # everything a row's answer depends on (pair_probability's arguments)
        return np.concatenate(
            (dp[j], dv[j], da[j], rad[j : j + 1], sig[j].ravel(), (H, thr, tol))
        ).tobytes()

    if memo and todo.size:  # (an empty memo, e.g. after a new reference time: no look-ups)
        keys = [key(j) for j in range(todo.size)]
        hit = np.fromiter((k in memo for k in keys), dtype=np.bool_, count=todo.size)
        for j in np.flatnonzero(hit).tolist():
            prob[todo[j]], bound[todo[j]], tpl[todo[j]] = fresh[keys[j]] = memo[keys[j]]
        if hit.any():
            keep = ~hit
            todo, dp, dv, da, rad, sig = (todo[keep], dp[keep], dv[keep], da[keep], rad[keep],
                                          sig[keep])
            todo_first, todo_projected = todo_first[keep], todo_projected[keep]
    if max_evaluated is not None and todo.size > max_evaluated:
        m = max(int(max_evaluated), 0)
        rank = (
            np.zeros(todo.size, dtype=np.int64)
            if priority is None
            else np.asarray(priority(todo), dtype=np.int64)
        )
        # waited longest, earliest possible contact, row
        order = np.lexsort((todo, todo_first, rank))
        later = np.sort(order[m:])
        rows = todo[later]
        new = np.ones(rows.size, dtype=np.bool_)
        if deferred_answer is not None:  # waiting with the same inputs: the same answer
            known_p, known_b = (np.asarray(x, dtype=np.float64)[rows] for x in deferred_answer)
            new = np.isnan(known_p)
            prob[rows[~new]], bound[rows[~new]] = known_p[~new], known_b[~new]
        anew = later[new]
        # on the sign-canonicalised relative rows: a swapped pair gets the same bits
        lo, hi = cheap_intervals(dp[anew], dv[anew], da[anew], rad[anew], sig[anew], H)
        # the projection bound is an upper bound too (the screen's, or computed here: the same
        # bits, the bound being symmetric under X -> -X)
        ub = todo_projected[anew]
        missing = np.flatnonzero(np.isnan(ub))
        if missing.size:
            m_rows = anew[missing]
            ub[missing] = projection_rows(dp[m_rows], dv[m_rows], da[m_rows], rad[m_rows],
                                          sig[m_rows], H)
        hi = np.minimum(hi, ub)
        lo = np.minimum(lo, hi)
        mid = 0.5 * (lo + hi)
        # hi - mid is exact (Sterbenz: mid >= hi / 2), so mid + bound reaches hi itself
        prob[rows[new]], bound[rows[new]] = mid, np.maximum(hi - mid, mid - lo)
        tpl[rows] = todo_first[later]
        deferred[rows] = True
        now = np.sort(order[:m])
        todo, dp, dv, da, rad, sig = todo[now], dp[now], dv[now], da[now], rad[now], sig[now]
    out = np.empty((todo.size, OUT_SIZE))
    # (the normal table: the accelerating rows' over-count runs inside the compiled pass)
    evaluate_uncertain_rows(dp, dv, da, rad, sig, H, thr, out, tol, normal_table(2 * D))
    for j, i in enumerate(todo.tolist()):
        prob[i], bound[i], tpl[i] = r = finish_row(
            dp[j], dv[j], da[j], float(rad[j]), sig[j], H, out[j], tol
        )
        if memo is not None:
            fresh[key(j)] = r
    if memo is not None:
        memo.clear()
        memo.update(fresh)
    return UncertainPairs(prob, bound, tpl, deferred)


def deferred_count(result: UncertainPairs) -> int:
    """Rows of ``result`` deferred by ``max_evaluated`` (answered by the cheap interval)."""
    return int(np.count_nonzero(result.deferred))


def inflation_radius(cov, horizon: float) -> np.ndarray:
    """(n,) m: ``BROAD_PHASE_SIGMAS * max over t in [0, H] of
    sqrt(lambda_max(Spp + t (Spv + Svp) + t^2 Svv))`` of each body's own
    covariance cov (n, 2D, 2D).  lambda_max(S(t)) is convex in t (a maximum of
    the convex quadratics n^T S(t) n), so the maximum is at t = 0 or t = H.
    Add it to the body's radius in the broad phase only: a pair both of whose
    bodies stay within their inflated paths drops at most 2 * TUBE_TAIL < 1e-9
    of probability (docs/uncertainty.md)."""
    cov = np.asarray(cov, dtype=np.float64)
    if cov.ndim != 3 or cov.shape[1] != cov.shape[2] or cov.shape[1] not in (4, 6):
        raise ValueError(f"cov must have shape (n, 4, 4) or (n, 6, 6), got {cov.shape}")
    H = float(horizon)
    out = np.empty(cov.shape[0])
    max_sigma_rows(np.ascontiguousarray(cov), 0.0, H, out)
    return BROAD_PHASE_SIGMAS * out


def load_fallback_kernels(dimensions: int) -> None:
    """Compile (or load from numba's cache) the RQMC kernels for `dimensions`: the contact
    indicator's (degenerate covariances), the over-count's (accelerating pairs) and, in
    3-D, line sampling's (straight pairs).

    A warm-up scene may reach neither; called directly, a node's first such pair waits
    for no compile."""
    z = np.zeros(dimensions)
    cov = np.eye(2 * dimensions) * 0.01
    Z = normal_table(2 * dimensions)
    qmc_probability(z + 1.5, z, z + 0.1, 1.0, cov, 1.0, Z)
    out = np.zeros(OUT_SIZE)
    out[OUT_QMC], out[OUT_HI], out[OUT_T1] = 2.0, 1.0, 1.0
    overcount_answer(z + 1.5, z, z + 0.1, 1.0, cov, 1.0, out, 0.0, Z)
    if dimensions == 3:
        line_sampled_probability(z + 1.5, z + 1.0, cov, 1.0, 1.0, normal_table(5))
