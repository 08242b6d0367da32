"""The per-pair evaluation of core.uncertainty: probability, bound, plausible time.

``pair_kernel`` (compiled) runs the tube, P(0), the plausible-time walk and
the Rice panel integrals of one relative state, and either answers or hands
``finish_row`` the bracket its RQMC fallback (contact indicator, over-count or
line sampling) is clipped to.  ``relative_rows`` and
``evaluate_uncertain_rows`` run it on rows of per-body arrays.

See docs/uncertainty.md for the mathematics; each guarantee is stated where
it is made.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from circle_collision_ros.core.uncertainty.interval import lower_bound
from circle_collision_ros.core.uncertainty.overlap import BALL_ERR_PER_TOL, DISC_ERR_PER_TOL
from circle_collision_ros.core.uncertainty.qmc import (QMC_CV_POINTS, QMC_CV_TARGET, QMC_POINTS,
                                                       QMC_REPLICATES, QMC_T, factor, line_sampled,
                                                       line_sampled_probability, normal_table,
                                                       overcount_counts, qmc_probability,
                                                       replicate_stats)
from circle_collision_ros.core.uncertainty.reentry import (BRACKET_HALF_WIDTH, no_reentry,
                                                           overcount_tail)
from circle_collision_ros.core.uncertainty.tube import (BROAD_PHASE_SIGMAS, TUBE_DEPTH, TUBE_TAIL,
                                                        tube_intervals)
from circle_collision_ros.core.uncertainty.walk import (CACHE_COLUMNS, P0_ERR, P0_SKIP, PANELS,
                                                        PLAUSIBLE_RTOL, ST_DEGENERATE, ST_PERR,
                                                        ST_PMAX, ST_PTOL, ST_SIZE, ST_SWEEP_DV,
                                                        WALK_TOL_2D, WALK_TOL_2D_REL, WALK_TOL_REL,
                                                        clear_prefix, first_crossing, instant_bound,
                                                        instant_probability, plausible_time_grid,
                                                        prob_at, rice_panel, velocity_sigma,
                                                        walk_panels)

__all__ = ["pair_kernel", "pair_probability", "relative_rows", "evaluate_uncertain_rows",
           "certified_lower_bound",
           "finish_row", "overcount_answer", "QMC_TOL_POINTS", "OUT_SIZE", "OUT_P", "OUT_BOUND",
           "OUT_TPL", "OUT_QMC", "OUT_LO", "OUT_HI", "OUT_ERR", "OUT_T0", "OUT_T1"]


# pair_kernel's out: probability, bound, plausible time, then for the RQMC
# fallback (needs_qmc = 1.0) the bracket [lo, hi] the RQMC mean is clipped to
# (1.0: on the contact indicator; 2.0: on the over-count of an accelerating pair,
# OUT_HI then is the computed upper = P0 + E[entries] and OUT_ERR its bound;
# 3.0: line sampling of a straight 3-D pair, core.uncertainty.line_sampling); for the
# over-count, [OUT_T0, OUT_T1] is the hull of the tube's ambiguous intervals
OUT_P, OUT_BOUND, OUT_TPL, OUT_QMC, OUT_LO, OUT_HI, OUT_ERR, OUT_T0, OUT_T1 = range(9)


@njit(cache=True, error_model="numpy")
def pair_kernel(dp, dv, da, R, Sigma, H, thr, out):
    """Everything of pair_probability but the RQMC fallback (compiled: the
    orchestration makes hundreds of kernel calls per pair, whose dispatch from
    Python cost as much as the quadrature itself)."""
    out[OUT_QMC] = 0.0
    leaves = np.empty((1 << TUBE_DEPTH, 2))
    cnt, t_inside = tube_intervals(dp, dv, da, R, Sigma, H, leaves, BROAD_PHASE_SIGMAS)
    if cnt == 0 and thr > TUBE_TAIL and thr <= 1.0 - TUBE_TAIL:
        # the tube alone decides (far pairs, tiny sigma): P <= TUBE_TAIL < thr
        # wherever it is outside, >= 1 - TUBE_TAIL >= thr from t_inside on
        out[OUT_BOUND] = TUBE_TAIL
        if t_inside <= H:
            out[OUT_P] = 1.0
            out[OUT_TPL] = t_inside
        else:
            out[OUT_P] = 0.0
            out[OUT_TPL] = math.inf
        return
    st = np.zeros(ST_SIZE)
    st[ST_PERR] = P0_ERR
    st[ST_SWEEP_DV] = -1.0
    acc = np.zeros(3)  # entry_rate's scratch
    # straight 3-D pairs: the probability by line sampling (finish_row), not by
    # the Rice panels, so the walk does not get them for free; their
    # instantaneous probabilities serve the walk only (looser tolerance)
    sampled = line_sampled(dp, dv, da, Sigma)
    if sampled:
        st[ST_PTOL] = max(WALK_TOL_REL * thr, 1e-10)
        st[ST_PERR] = BALL_ERR_PER_TOL * st[ST_PTOL]
        # no Rice panels for the probability: the walk certifies its steps with
        # the swept ball (one ball probability per step instead of ~450 cap
        # integrand points per nu+ value)
        st[ST_SWEEP_DV] = BROAD_PHASE_SIGMAS * velocity_sigma(Sigma)
    elif dp.shape[0] == 2:
        # 2-D: the walk's probabilities only meet the threshold (its certificate
        # and comparisons, each with st[ST_PERR]), so they take a looser
        # tolerance (WALK_TOL_2D; 4 pieces, one level: stated error 4 x tol,
        # never below the standard one's 1e-9); P(0), which enters the reported
        # probability, stays at the standard tolerance (below)
        st[ST_PTOL] = max(min(WALK_TOL_2D_REL * thr, WALK_TOL_2D), 1e-10)
        st[ST_PERR] = max(DISC_ERR_PER_TOL * st[ST_PTOL], P0_ERR)
    # the largest error of any probability in st[ST_PMAX] (the walk may switch
    # to the standard tolerance at its end, first_crossing)
    pmax_err = st[ST_PERR]
    if sampled and instant_bound(dp, dv, da, R, Sigma, 0.0, 0.0) < thr:
        # P(0) < thr is certified and only the walk would use P(0) (as its start
        # value, computed below if the walk starts at 0)
        p0 = -1.0
    elif sampled:
        p0 = prob_at(dp, dv, da, R, Sigma, 0.0, st)
    elif instant_bound(dp, dv, da, R, Sigma, 0.0, 0.0) <= P0_SKIP:
        # P(0) <= 1e-12 is certified without quadrature (bodies that start
        # apart): 0 is within the P0_ERR = 1e-9 that the bound already states
        # for P(0), and within the walk's st[ST_PERR] (>= 1e-9) as its start
        p0 = 0.0
    else:
        # P(0) is part of the reported probability (upper = P0 + the Rice
        # integral, with P0_ERR in the bound): always the standard tolerance
        p0 = instant_probability(dp, dv, da, R, Sigma, 0.0)
        st[ST_PMAX] = max(st[ST_PMAX], p0)
    dt = PLAUSIBLE_RTOL * H
    pa = np.empty(PANELS * cnt + 1)
    pb = np.empty(PANELS * cnt + 1)
    # the walk's panels end at t_inside; the Rice integral below runs only
    # when t_inside is +inf, where they are the full panels (cache shared)
    npan = walk_panels(dp, dv, da, R, Sigma, leaves, cnt, t_inside, pa, pb)
    cache = np.zeros((npan + 1, CACHE_COLUMNS))

    # plausible time: certified walk over the ambiguous panels before t_inside
    tpl = math.inf
    if p0 >= thr:
        tpl = 0.0
    else:
        found = False
        for j in range(npan):
            # the analytic bound certifies the start of the panel without
            # quadrature (P < thr on [pa[j], a0]); the walk starts at a0
            a0 = clear_prefix(dp, dv, da, R, Sigma, pa[j], pb[j], thr)
            if a0 >= pb[j]:
                continue
            p_start = p0 if (a0 == 0.0 and p0 >= 0.0) else prob_at(dp, dv, da, R, Sigma, a0, st)
            if p_start >= thr:
                tpl = a0
                found = True
                break
            r = first_crossing(dp, dv, da, R, Sigma, pa, pb, j, a0, p_start, thr, dt, cache, acc,
                               st, t_inside > H and not sampled)
            if st[ST_DEGENERATE] != 0.0:
                found = True
                break
            if r != math.inf:
                tpl = r
                found = True
                break
        if not found:
            tpl = t_inside  # +inf when the tube never lies inside
    degenerate = st[ST_DEGENERATE] != 0.0
    if degenerate:
        tpl, pm = plausible_time_grid(dp, dv, da, R, Sigma, H, thr)
    out[OUT_TPL] = tpl

    if t_inside <= H:
        out[OUT_P] = 1.0
        out[OUT_BOUND] = TUBE_TAIL
        return
    if cnt == 0:
        out[OUT_P] = 0.0
        out[OUT_BOUND] = TUBE_TAIL
        return
    if sampled:
        # line sampling: unbiased, no tube truncation; clipped below by the
        # largest instantaneous probability seen
        out[OUT_QMC] = 3.0
        out[OUT_LO] = st[ST_PMAX] - pmax_err
        out[OUT_HI] = 1.0
        return
    total = 0.0
    err = 0.0
    if not degenerate:
        for j in range(npan):
            v, e = rice_panel(dp, dv, da, R, Sigma, pa, pb, j, cache, acc, st)
            total += v
            err += e
            if st[ST_DEGENERATE] != 0.0:
                degenerate = True
                break
    upper = p0 + total
    straight = True
    for k in range(da.shape[0]):
        if da[k] != 0.0:
            straight = False
    lower = st[ST_PMAX] - pmax_err
    if not degenerate:
        stated = upper + err + P0_ERR + 2 * TUBE_TAIL
        lower = certified_lower_bound(dp, dv, da, R, Sigma, H, lower, stated)
        if lower > stated:
            # P is at least any certified lower bound, so an upper bound below one proves
            # that the quadrature missed part of nu+ (its estimates did not show it): the
            # pair is answered as a degenerate one, by the contact indicator's RQMC clipped
            # below by that bound, and its plausible time by the grid (the walk certified
            # its steps with the same integrals)
            degenerate = True
            tpl, pm = plausible_time_grid(dp, dv, da, R, Sigma, H, thr)
            out[OUT_TPL] = tpl
    if not degenerate:
        if straight:
            out[OUT_P] = min(1.0, max(0.0, upper))
            out[OUT_BOUND] = err + P0_ERR + TUBE_TAIL
            return
        # da != 0: a path enters at most twice, so upper = P0 + E[entries]
        # over-counts exactly the re-entries: P = upper - E[O] with the
        # per-path over-count O (overcount_answer), whose mean the RQMC
        # estimates with far less variance than that of the contact indicator
        # (O is 0 but for the few paths that exit and come back)
        # a tube path crosses the sphere only within the ambiguous intervals (sorted:
        # the tube walk visits [0, H] left to right), so an exit, the maximum
        # of f after it and the re-entry all lie within their hull
        t0, t1 = leaves[0, 0], leaves[cnt - 1, 1]
        if no_reentry(dp, dv, da, Sigma, t0, t1, BROAD_PHASE_SIGMAS):
            # no path of the tube can come back (O = 0 on it): upper is P but
            # for the tail paths, each off by at most 2 (<= 3 counted, contact
            # 0 or 1), which the 2 TUBE_TAIL of the bound covers
            out[OUT_P] = min(1.0, max(0.0, upper))
            out[OUT_BOUND] = err + P0_ERR + 2 * TUBE_TAIL
            return
        # the bracket [lo, hi] of P without sampling: P >= every instantaneous
        # probability (st[ST_PMAX], each within pmax_err); P <= upper + its bound;
        # and where a narrower tube (k' sigmas) is certified, O = 0 on it and
        # O <= 2 off it: E[O] <= 2 P(chi^2_2D > k'^2) (overcount_tail)
        slack = err + P0_ERR + 2 * TUBE_TAIL
        hi = upper + slack
        lo = max(st[ST_PMAX] - pmax_err, upper - slack - overcount_tail(dp, dv, da, Sigma, t0, t1))
        if lo <= hi and 0.5 * (hi - lo) <= BRACKET_HALF_WIDTH + slack:
            # no wider than the tightest bound the RQMC could state (its floor + the
            # same slack): the midpoint, bounded without sampling
            mid = 0.5 * (lo + hi)
            out[OUT_P] = min(1.0, max(0.0, mid))
            out[OUT_BOUND] = 0.5 * (hi - lo)
            return
        out[OUT_QMC] = 2.0
        out[OUT_LO] = lo
        out[OUT_HI] = upper
        out[OUT_ERR] = slack
        out[OUT_T0] = t0
        out[OUT_T1] = t1
        return
    out[OUT_QMC] = 1.0
    out[OUT_LO] = max(st[ST_PMAX] - pmax_err, lower)
    out[OUT_HI] = 1.0 if degenerate else upper + err + P0_ERR + 2 * TUBE_TAIL


OUT_SIZE = 9


@njit(cache=True, error_model="numpy")
def certified_lower_bound(dp, dv, da, R, Sigma, H, known, cap):
    """A certified lower bound of P(contact within [0, H]) for one relative state: the larger
    of `known` (one the caller holds, e.g. its largest instantaneous probability less its
    error) and the instantaneous probability at the mean path's closest approach on a grid,
    less its error (``interval.lower_bound``, the cheap interval's).  The latter is skipped
    where it cannot matter to a caller comparing with `cap`: `known` already exceeds it, or
    it is >= 1."""
    if known > cap or cap >= 1.0:
        return known
    return max(known, lower_bound(dp, dv, da, R, Sigma, H))


@njit(cache=True, error_model="numpy", nogil=True)
def relative_rows(pa, va, aa, ra, pb, vb, ab, rb, sigma, rows, dp, dv, da, rad, sig):
    """Relative state of the rows ``rows`` of the per-body arrays into dp, dv, da
    (a - b), rad (ra + rb), sig (sigma[row]); each row's sign canonicalised:
    X -> -X leaves the problem unchanged, so the row is negated when the first
    non-zero of (dp, dv, da) is negative (swapping a and b gives the same bits)."""
    D = pa.shape[1]
    for j in range(rows.shape[0]):
        i = rows[j]
        for c in range(D):
            dp[j, c] = pa[i, c] - pb[i, c]
            dv[j, c] = va[i, c] - vb[i, c]
            da[j, c] = aa[i, c] - ab[i, c]
        rad[j] = ra[i] + rb[i]
        first = 0.0
        for c in range(3 * D):
            x = dp[j, c] if c < D else (dv[j, c - D] if c < 2 * D else da[j, c - 2 * D])
            if x != 0.0:
                first = x
                break
        if first < 0.0:
            for c in range(D):
                dp[j, c] = -dp[j, c]
                dv[j, c] = -dv[j, c]
                da[j, c] = -da[j, c]
        for r in range(2 * D):
            for c in range(2 * D):
                sig[j, r, c] = sigma[i, r, c]


# With a tolerance (overcount_answer): the over-count's first stages, points per replicate,
# each tried when its floor 3 / (QMC_REPLICATES m) (5.9e-3, 2.9e-3) is within the tolerance,
# before QMC_CV_POINTS and QMC_POINTS
QMC_TOL_POINTS = (32, 64)
_OVERCOUNT_STAGES = QMC_TOL_POINTS + (QMC_CV_POINTS, QMC_POINTS)


@njit(cache=True, error_model="numpy", nogil=True)
def overcount_answer(dp, dv, da, R, Sigma, H, out, tolerance, Z):
    """(probability, bound) of an accelerating row that pair_kernel left to the over-count
    (out[OUT_QMC] == 2): P = upper - E[O], E[O] by the RQMC replicates Z.

    QMC_CV_POINTS per replicate first, all QMC_POINTS when the stated bound would exceed
    QMC_CV_TARGET.  tolerance > 0 (a scene's ``probability_tolerance``): the certified
    bracket is taken when its half-width is within it (the kernel's bracket rule, the same
    operations: the same bits where the kernel accepts it), and the stages start at
    QMC_TOL_POINTS (those whose floor is within it) and stop at the first whose stated
    bound is within it.  The stated bound holds either way.  Each stage adds its points
    to the previous ones' (integer counts: the same bits as one pass)."""
    upper = out[OUT_HI]
    lo = out[OUT_LO]
    err = out[OUT_ERR]
    if tolerance > 0.0:
        hi = upper + err
        if lo <= hi and 0.5 * (hi - lo) <= tolerance:
            return min(1.0, max(0.0, 0.5 * (lo + hi))), 0.5 * (hi - lo)
    L = factor(np.ascontiguousarray(Sigma))
    reps = Z.shape[0]
    tot = np.zeros(reps, dtype=np.int64)
    est = np.empty(reps)
    k2 = BROAD_PHASE_SIGMAS * BROAD_PHASE_SIGMAS
    done = 0
    mean = 0.0
    stat = 0.0
    for s in range(len(_OVERCOUNT_STAGES)):
        m = _OVERCOUNT_STAGES[s]
        if s < len(QMC_TOL_POINTS) and not (tolerance > 0.0 and
                                            3.0 / (QMC_REPLICATES * m) <= tolerance):
            continue
        overcount_counts(dp, dv, da, R, H, L, Z, done, m, out[OUT_T0], out[OUT_T1], k2, tot)
        done = m
        for r in range(reps):
            est[r] = tot[r] / m
        mean, se = replicate_stats(est)
        stat = max(QMC_T * se, 3.0 / (QMC_REPLICATES * m))
        if stat <= QMC_CV_TARGET or stat + err <= tolerance:
            break
    return min(1.0, max(0.0, min(max(upper - mean, lo), upper))), stat + err


@njit(cache=True, error_model="numpy", nogil=True)
def evaluate_uncertain_rows(dp, dv, da, rad, sig, H, thr, out, tolerance, Z):
    """pair_kernel on every row (out (n, OUT_SIZE)), serially (on numba's threads the
    node's tail latency suffered, docs/uncertainty.md "Not guaranteed / weak"), and the
    over-count of the accelerating rows that need it (overcount_answer with `tolerance`
    and the normal table Z of their dimension; out[j, OUT_QMC] then reads 0).  Rows with
    out[j, OUT_QMC] != 0 still need ``finish_row``'s sampling.  Releases the interpreter
    lock (nogil): the node completes deferred rows on threads beside its prediction path
    (node/probabilities.py)."""
    for j in range(dp.shape[0]):
        pair_kernel(dp[j], dv[j], da[j], rad[j], sig[j], H, thr, out[j])
        if out[j, OUT_QMC] == 2.0:
            p, b = overcount_answer(dp[j], dv[j], da[j], rad[j], sig[j], H, out[j], tolerance, Z)
            out[j, OUT_P] = p
            out[j, OUT_BOUND] = b
            out[j, OUT_QMC] = 0.0


def finish_row(dp, dv, da, R, Sigma, H, out, tolerance: float = 0.0):
    """(probability, bound, plausible time) of one row from pair_kernel's out,
    running the RQMC fallback when the kernel asked for it.

    tolerance > 0 (a scene's ``probability_tolerance``): an accelerating pair whose
    certified bracket is within it takes the bracket's midpoint without sampling, and its
    over-count RQMC stops at the first stage (QMC_TOL_POINTS, then 4x) whose stated bound
    is within it.  The stated bound holds either way; 0 gives each pair the per-pair
    accuracy (the bracket only when no wider than sampling's floor, QMC_CV_TARGET)."""
    if out[OUT_QMC] == 0.0:
        return float(out[OUT_P]), float(out[OUT_BOUND]), float(out[OUT_TPL])
    D = dp.shape[0]
    if out[OUT_QMC] == 2.0:
        p, b = overcount_answer(dp, dv, da, float(R), np.ascontiguousarray(Sigma), float(H), out,
                                float(tolerance), normal_table(2 * D))
        return float(p), float(b), float(out[OUT_TPL])
    if out[OUT_QMC] == 3.0:
        mean, stat = line_sampled_probability(
            dp, dv, np.ascontiguousarray(Sigma), float(R), float(H), normal_table(5)
        )
        p = min(1.0, max(0.0, max(mean, float(out[OUT_LO]))))
        return p, stat, float(out[OUT_TPL])
    mean, se = qmc_probability(dp, dv, da, R, Sigma, H, normal_table(2 * D))
    n = QMC_REPLICATES * QMC_POINTS
    p = min(1.0, max(0.0, min(max(mean, float(out[OUT_LO])), float(out[OUT_HI]))))
    return p, max(QMC_T * se, 3.0 / n) + TUBE_TAIL, float(out[OUT_TPL])


def pair_probability(dp, dv, da, R, Sigma, H, thr):
    """(probability, bound, plausible time) of one uncertain pair (relative state).

    See docs/uncertainty.md for the method and why each bound holds."""
    out = np.empty(OUT_SIZE)
    pair_kernel(dp, dv, da, float(R), Sigma, float(H), float(thr), out)
    return finish_row(dp, dv, da, R, Sigma, H, out)
