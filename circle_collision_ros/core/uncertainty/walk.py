"""The plausible-time walk: the first time P(|X(t)| <= R) reaches the threshold.

Instantaneous probabilities (``instant_probability``), their analytic upper
bound without quadrature (``instant_bound``), and the certified walk over the
tube's ambiguous panels (``first_crossing``): each step is proved free of a
crossing by sup_[lo, c] P <= P(lo) + int_lo^c nu+ + errors < threshold (the
Rice panel integrals, cached per pair, or the swept ball's bound), so the
reported time is never later than the true first crossing.  Degenerate
covariances take ``plausible_time_grid``.

See docs/uncertainty.md for the mathematics; each guarantee is stated where
it is made.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from circle_collision_ros.core.special import eig_sym
from circle_collision_ros.core.uncertainty.entry_rate import (entry_rate_gauss3,
                                                              entry_rate_integral, entry_rate_k15,
                                                              entry_rate_p31)
from circle_collision_ros.core.uncertainty.overlap import (overlap_probability,
                                                           overlap_probability_2d,
                                                           overlap_probability_2d_tol,
                                                           overlap_probability_tol)
from circle_collision_ros.core.uncertainty.panel_map import (MAX_BUMPS, bump_cuts, bump_map,
                                                             map_to_s)
from circle_collision_ros.core.uncertainty.quadrature import (P31_K15_POS, P31_NEW_POS, k15_error,
                                                              push_halves, subinterval_integral)
from circle_collision_ros.core.uncertainty.tube import TUBE_TAIL, S_at, max_sigma_over, mean_range

__all__ = ["instant_probability", "instant_probability_tol", "instant_bound", "det_lower", "PANELS",
           "P0_ERR", "P0_SKIP", "PLAUSIBLE_RTOL", "walk_panels", "ST_PMAX", "ST_DEGENERATE",
           "ST_PTOL", "ST_PERR", "ST_SWEEP_DV", "ST_SIZE", "WALK_TOL_REL", "WALK_TOL_2D_REL",
           "WALK_TOL_2D", "prob_at", "CACHE_COLUMNS", "velocity_sigma", "swept_ball_bound",
           "swept_ball_split", "rice_panel", "clear_prefix", "first_crossing",
           "plausible_time_grid"]


@njit(cache=True, error_model="numpy")
def instant_probability(dp, dv, da, R, Sigma, t):
    """P(|X(t)| <= R) (1e-9 absolute, see overlap_probability)."""
    return instant_probability_tol(dp, dv, da, R, Sigma, t, 0.0)


@njit(cache=True, error_model="numpy")
def instant_probability_tol(dp, dv, da, R, Sigma, t, tol):
    """instant_probability with the quadrature tolerance ``tol`` per piece and
    level (0.0: the standard one; see overlap_probability_tol)."""
    D = dp.shape[0]
    if D == 2:  # scalars, as S_at
        s00 = Sigma[0, 0] + t * (Sigma[0, 2] + Sigma[2, 0]) + t * t * Sigma[2, 2]
        s01 = Sigma[0, 1] + t * (Sigma[0, 3] + Sigma[2, 1]) + t * t * Sigma[2, 3]
        s10 = Sigma[1, 0] + t * (Sigma[1, 2] + Sigma[3, 0]) + t * t * Sigma[3, 2]
        s11 = Sigma[1, 1] + t * (Sigma[1, 3] + Sigma[3, 1]) + t * t * Sigma[3, 3]
        g0 = dp[0] + t * (dv[0] + 0.5 * t * da[0])
        g1 = dp[1] + t * (dv[1] + 0.5 * t * da[1])
        if tol > 0.0:
            return overlap_probability_2d_tol(g0, g1, s00, 0.5 * (s01 + s10), s11, R, tol)
        return overlap_probability_2d(g0, g1, s00, 0.5 * (s01 + s10), s11, R)
    g = np.empty(D)
    for k in range(D):
        g[k] = dp[k] + t * (dv[k] + 0.5 * t * da[k])
    if tol > 0.0:
        return overlap_probability_tol(g, S_at(Sigma, t), R, tol)
    return overlap_probability(g, S_at(Sigma, t), R)


# Ambiguous tube intervals are cut into panels, one per bump of the entry rate
# (at most PANELS; core.uncertainty.panel_map), each panel's nodes mapped onto its
# bump: two equal halves saw a bump with a few nodes each and took P31 on a third
# of them (bench/bench_uncertainty_scene.py --completion).  The plausible-time
# search certifies panel by panel.
PANELS = MAX_BUMPS
_PANEL_TOL = 2e-3  # quadrature tolerance of the entry-rate integral per panel
_RICE_TOL = 1e-3  # of the walk's 3-point steps (entry_rate_gauss3)
P0_ERR = 1e-9  # error of one instantaneous probability (overlap_probability)
P0_SKIP = 1e-12  # P(0) is taken as 0 where instant_bound certifies it below this
PLAUSIBLE_RTOL = 1e-6  # the plausible time's bracket width, relative to H


@njit(cache=True, error_model="numpy")
def walk_panels(dp, dv, da, R, Sigma, leaves, cnt, t_end, pa, pb):
    """Panel ends of the ambiguous intervals before t_end into pa, pb (each
    interval cut between its bumps, panel_map.bump_cuts; at most PANELS
    panels each); returns the count."""
    m = 0
    cuts = np.empty(PANELS)
    for j in range(cnt):
        a = leaves[j, 0]
        b = min(leaves[j, 1], t_end)
        if not a < b:
            continue
        k = bump_cuts(dp, dv, da, R, Sigma, a, b, cuts)
        start = a
        for q in range(k + 1):
            end = b if q == k else cuts[q]
            if start < end:
                pa[m] = start
                pb[m] = end
                m += 1
            start = end
    return m


# Per-pair scratch of the compiled orchestration (float64 array st):
ST_PMAX = 0  # largest instantaneous probability computed (a lower bound of P(contact))
ST_DEGENERATE = 1  # 1.0 once S(t) was degenerate at a quadrature node: the Rice values are unusable
ST_PTOL = 2  # quadrature tolerance of the walk's instantaneous probabilities (0.0: the standard)
ST_PERR = 3  # stated error of one of them (P0_ERR at the standard tolerance; >= P0_ERR)
# the walk's certificate: < 0 the Rice integral; >= 0 the swept ball (swept_ball_bound), k sigma_v
ST_SWEEP_DV = 4
ST_SIZE = 5
# Straight 3-D pairs (line sampling) use the instantaneous probability only in the
# plausible-time walk, where it is compared with the threshold: tolerance
# WALK_TOL_REL x threshold per piece and level (stated error 8e-7 x threshold,
# far inside the certificate's margins): measured cheaper (see bench/bench_uncertainty.py)
WALK_TOL_REL = 1e-7
# 2-D walk: tolerance min(WALK_TOL_2D_REL x threshold, WALK_TOL_2D) per piece,
# stated error 4 x that (<= 1e-7 absolute, <= 1e-5 x threshold): far inside the
# certificate's margins (the Rice step's integral + estimate ~1e-3), and the
# walk's answers within 1e-7 of the threshold where the 1e-9 ones were within
# 1e-9 (its tests allow 1e-6).  The splits of the standard tolerance come from
# |K15 - G7| over-estimating K15's error (actual errors ~1e-14): at this
# tolerance the benchmark's walk probabilities take one K15 per piece, ~60
# segment evaluations instead of ~60-120
WALK_TOL_2D_REL = 2.5e-6
WALK_TOL_2D = 2.5e-8


@njit(cache=True, error_model="numpy")
def prob_at(dp, dv, da, R, Sigma, t, st):
    p = instant_probability_tol(dp, dv, da, R, Sigma, t, st[ST_PTOL])
    if p > st[ST_PMAX]:
        st[ST_PMAX] = p
    return p


# The per-pair cache of panel integrals (one row per panel): computed flag,
# value, error estimate; the panel's node map (panel_map.bump_map: c, w, alpha,
# h); then, when the panel's single K15 or its P31 extension was accepted (no
# split), the number of kept values (15 or 31; 0: none), the largest of the
# nodes' own (arc/cap) error estimates and the values nu+(t(s)) dt/ds at the
# rule's nodes s, ascending (the walk's short steps integrate their
# interpolant instead of evaluating nu+ again).
_C_DONE, _C_VALUE, _C_ERR, _C_MAP, _C_NODES_OK, _C_INNER_MAX, _C_NODES = 0, 1, 2, 3, 7, 8, 9
CACHE_COLUMNS = _C_NODES + 31


@njit(cache=True, error_model="numpy")
def _rice_short(dp, dv, da, R, Sigma, a, b, pa, pb, j, cache, plo, thr, acc, st):
    """Entry-rate integral over a short interval [a, b] of panel j and its error
    estimate: from the panel's kept nu+ values where they certify the step
    (plo + value + estimate + P's error < thr: no new nu+ evaluation), else by
    the 3-point Gauss rule."""
    nk = int(cache[j, _C_NODES_OK])
    if nk != 0:
        mp = (cache[j, _C_MAP], cache[j, _C_MAP + 1], cache[j, _C_MAP + 2], cache[j, _C_MAP + 3])
        v, e = subinterval_integral(cache[j, _C_NODES : _C_NODES + nk], map_to_s(mp, a),
                                    map_to_s(mp, b))
        v = max(v, 0.0)  # nu+ >= 0: a negative interpolant integral is rounding or ringing
        # the nodes' own estimates as the adaptive rule of entry_rate_integral
        # counted them before it weighted them: width times the largest
        e = e + (b - a) * cache[j, _C_INNER_MAX]
        if plo + v + e + st[ST_PERR] < thr:
            return v, e
    acc[1] = 0.0
    v, e = entry_rate_gauss3(dp, dv, da, R, Sigma, a, b, _RICE_TOL, acc)
    if acc[1] != 0.0:
        st[ST_DEGENERATE] = 1.0
    return v, e


@njit(cache=True, error_model="numpy")
def velocity_sigma(Sigma):
    """Upper bound of sqrt(lambda_max(Svv)) (the factor 1 + 1e-9 covers the
    eigenvalues' rounding, as max_sigma_over)."""
    D = Sigma.shape[0] // 2
    lam, _ = eig_sym(np.ascontiguousarray(Sigma[D:, D:]))
    return math.sqrt(max(lam[D - 1], 0.0) * (1.0 + 1e-9))


@njit(cache=True, error_model="numpy")
def swept_ball_bound(dp, dv, da, R, Sigma, a, b, st):
    """Upper bound of P(the path touches the ball within [a, b]) >= sup over
    [a, b] of P(|X(t)| <= R), but for the velocity tail TUBE_TAIL that the
    caller adds: a single ball probability, no entry-rate integral.

    With m the midpoint, h the half-width and tau = t - m, X(t) = X(m) +
    Xdot(m) tau + da tau^2 / 2 and Xdot(m) - gd(m) = dv - E[dv] = L_v w
    (L_v L_v^T = Svv, w standard normal of rank <= D), so off the event
    |w| > k (probability P(chi^2_D > k^2) <= TUBE_TAIL) |Xdot(m)| <= |gd(m)| +
    k sqrt(lambda_max(Svv)) = |gd(m)| + st[ST_SWEEP_DV], and a path within R of
    the origin at some t in [a, b] has |X(m)| <= R' = R + h (|gd(m)| +
    st[ST_SWEEP_DV]) + |da| h^2 / 2.  Returns P(|X(m)| <= R') (at the walk's
    tolerance: within st[ST_PERR]); R' is rounded up by 1e-12 relative."""
    D = dp.shape[0]
    m = 0.5 * (a + b)
    h = 0.5 * (b - a)
    speed = 0.0
    acc2 = 0.0
    for i in range(D):
        g = dv[i] + da[i] * m
        speed += g * g
        acc2 += da[i] * da[i]
    reach = R + h * (math.sqrt(speed) + st[ST_SWEEP_DV]) + 0.5 * math.sqrt(acc2) * h * h
    return instant_probability_tol(dp, dv, da, reach * (1.0 + 1e-12), Sigma, m, st[ST_PTOL])


# The end game's swept ball: [lo, lo + dt] in this many sub-steps, one ball each
# (the inflation h (|gd| + k sigma_v) shrinks with h)
_ENDGAME_SPLIT = 8


@njit(cache=True, error_model="numpy")
def swept_ball_split(dp, dv, da, R, Sigma, a, b, st, stop):
    """The largest ``swept_ball_bound`` over _ENDGAME_SPLIT equal sub-steps of
    [a, b]: an upper bound of sup over [a, b] of P(|X(t)| <= R) (each t lies in a
    sub-step), as that function's is but for TUBE_TAIL.  Returns as soon as one
    sub-step's reaches ``stop`` (the caller's certificate fails anyway)."""
    w = (b - a) / _ENDGAME_SPLIT
    worst = 0.0
    for i in range(_ENDGAME_SPLIT):
        ta = a + i * w
        tb = b if i == _ENDGAME_SPLIT - 1 else a + (i + 1) * w
        worst = max(worst, swept_ball_bound(dp, dv, da, R, Sigma, ta, tb, st))
        if worst >= stop:
            break
    return worst


@njit(cache=True, error_model="numpy")
def rice_panel(dp, dv, da, R, Sigma, pa, pb, j, cache, acc, st):
    """Entry-rate integral over panel j and its error estimate, computed once
    per pair (cache row j, see CACHE_COLUMNS).  The same panels as
    ``entry_rate_integral`` over [pa[j], pb[j]]: its whole-interval K15 first
    (values kept), else that K15's Patterson extension P31, else its two halves
    with half the tolerance each, which is where the adaptive rule goes next."""
    if cache[j, _C_DONE] == 0.0:
        acc[1] = 0.0
        f15 = np.empty(15)
        fe = np.empty(15)
        mp = bump_map(dp, dv, da, R, Sigma, pa[j], pb[j])
        for i in range(4):
            cache[j, _C_MAP + i] = mp[i]
        v, e, inner, inner_max = entry_rate_k15(
            dp, dv, da, R, Sigma, pa[j], pb[j], _PANEL_TOL, acc, f15, fe, mp
        )
        # the whole panel is one K15 (in s: half-width 1): QUADPACK's estimate, not
        # |K15 - G7| alone, which can understate a peak between the nodes (k15_error);
        # the halves below use the adaptive rule's own estimates
        e = k15_error(f15, 1.0, v, e)
        if not (e > _PANEL_TOL):  # (a NaN estimate is accepted, as by the adaptive rule)
            cache[j, _C_NODES_OK] = 15.0
            cache[j, _C_INNER_MAX] = inner_max
            cache[j, _C_NODES : _C_NODES + 15] = f15
            e += inner
        else:
            # Patterson's extension first: a K15 fails on a panel much wider than
            # nu+'s peak (one clipped at 0 or H, the peak inside), where |K15 - G7|
            # is ~100x K15's error and P31 settles it with 16 more values
            fnew = np.empty(16)
            v, e, inner, new_max = entry_rate_p31(
                dp, dv, da, R, Sigma, pa[j], pb[j], _PANEL_TOL, acc, f15, fe, fnew, mp
            )
            if not (e > _PANEL_TOL):
                cache[j, _C_NODES_OK] = 31.0
                cache[j, _C_INNER_MAX] = max(inner_max, new_max)
                for i in range(15):
                    cache[j, _C_NODES + P31_K15_POS[i]] = f15[i]
                for i in range(16):
                    cache[j, _C_NODES + P31_NEW_POS[i]] = fnew[i]
                e += inner
            else:  # the adaptive rule's next panels: the halves, half the tolerance each
                m = 0.5 * (pa[j] + pb[j])
                v, e = entry_rate_integral(dp, dv, da, R, Sigma, pa[j], m, 0.5 * _PANEL_TOL, acc)
                v2, e2 = entry_rate_integral(dp, dv, da, R, Sigma, m, pb[j], 0.5 * _PANEL_TOL,
                                             acc)
                v += v2
                e += e2
        if acc[1] != 0.0:
            st[ST_DEGENERATE] = 1.0
        cache[j, _C_DONE] = 1.0
        cache[j, _C_VALUE] = v
        cache[j, _C_ERR] = e
    return cache[j, _C_VALUE], cache[j, _C_ERR]


_SEARCH_STEPS = 64  # certified steps per panel before the conservative exit


@njit(cache=True, error_model="numpy")
def det_lower(Sigma, ta, tb):
    """A lower bound of det S(t) over [ta, tb] (<= 0 when none is found): det S(m + h)
    is a polynomial in h (degree 2D; S(m + h) = A + B h + C h^2 entrywise, m the
    midpoint), so for |h| <= r it is >= c_0 - sum_k |c_k| r^k; the rounding of the
    coefficients (a few ulps of products of entries <= M) is covered by 1e-12 M^D."""
    D = Sigma.shape[0] // 2
    m = 0.5 * (ta + tb)
    r = 0.5 * (tb - ta)
    P = np.zeros((3, 3, 3))  # P[i, j] = (A, B, C) of the symmetrised S_ij
    M = 0.0
    for i in range(D):
        for j in range(D):
            c = 0.5 * (Sigma[D + i, D + j] + Sigma[D + j, D + i])
            bb = 0.5 * ((Sigma[i, D + j] + Sigma[D + i, j]) + (Sigma[j, D + i] + Sigma[D + j, i]))
            aa = 0.5 * (Sigma[i, j] + Sigma[j, i])
            P[i, j, 0] = aa + m * (bb + m * c)
            P[i, j, 1] = bb + 2.0 * m * c
            P[i, j, 2] = c
            M += abs(P[i, j, 0]) + r * (abs(P[i, j, 1]) + r * abs(P[i, j, 2]))
    coef = np.zeros(7)
    if D == 2:
        for u in range(3):
            for v in range(3):
                coef[u + v] += P[0, 0, u] * P[1, 1, v] - P[0, 1, u] * P[0, 1, v]
    else:
        # det = s00 (s11 s22 - s12^2) - s01 (s01 s22 - s12 s02) + s02 (s01 s12 - s11 s02)
        for u in range(3):
            for v in range(3):
                for w in range(3):
                    coef[u + v + w] += (
                        P[0, 0, u] * (P[1, 1, v] * P[2, 2, w] - P[1, 2, v] * P[1, 2, w])
                        - P[0, 1, u] * (P[0, 1, v] * P[2, 2, w] - P[1, 2, v] * P[0, 2, w])
                        + P[0, 2, u] * (P[0, 1, v] * P[1, 2, w] - P[1, 1, v] * P[0, 2, w])
                    )
    low = coef[0]
    rk = 1.0
    for k in range(1, 2 * D + 1):
        rk *= r
        low -= abs(coef[k]) * rk
    return low - 1e-12 * M**D


@njit(cache=True, error_model="numpy")
def instant_bound(dp, dv, da, R, Sigma, ta, tb):
    """A rigorous upper bound of P(|X(t)| <= R) for every t in [ta, tb] (no quadrature).

    With d = (min |g(t)| - R)^+ (box bound, mean_range) and lam >= lambda_max(S(t))
    (max_sigma_over): every point of the ball is >= d from g(t), so its Mahalanobis
    distance is >= q = d^2 / lam.  Then (i) P <= P(chi^2_D >= q) (X - g = S^(1/2) w,
    |X - g| <= sqrt(lam) |w|), and (ii) P <= vol(ball) * max density on the ball
    <= vol / ((2 pi)^(D/2) sqrt(det_min)) e^(-q/2), det_min a lower bound of
    det S(t) (det_lower).  Returns min of (i), (ii) and 1.  (ii) is the tight one
    when sigma >> R, (i) in the tails when sigma << distance."""
    D = dp.shape[0]
    lam = max_sigma_over(Sigma, ta, tb) ** 2
    gmin, _ = mean_range(dp, dv, da, ta, tb)
    d = gmin - R
    if d > 0.0:
        if not (lam > 0.0):
            return 0.0
        q = d * d / lam
    else:
        q = 0.0
    if D == 2:
        bound = math.exp(-0.5 * q)
    else:
        bound = math.erfc(math.sqrt(0.5 * q)) + math.sqrt(2.0 * q / math.pi) * math.exp(-0.5 * q)
    det = det_lower(Sigma, ta, tb)
    if det > 0.0:
        if D == 2:
            dens = R * R / (2.0 * math.sqrt(det)) * math.exp(-0.5 * q)
        else:
            dens = (
                (4.0 / 3.0)
                * math.pi
                * R**3
                / ((2.0 * math.pi) ** 1.5 * math.sqrt(det))
                * math.exp(-0.5 * q)
            )
        bound = min(bound, dens)
    # rounding of the exp/erfc/sqrt chain (a few ulps) is far inside this factor
    return min(1.0, bound * (1.0 + 1e-9))


_CLEAR_DEPTH = 6  # the analytic certificate's finest piece: 1/64 of a panel


@njit(cache=True, error_model="numpy")
def clear_prefix(dp, dv, da, R, Sigma, a, b, thr):
    """The largest c in [a, b] on the dyadic grid of depth _CLEAR_DEPTH such that
    instant_bound < thr on pieces covering [a, c]: then P(|X(t)| <= R) < thr on
    [a, c] is certified with no quadrature (pieces visited left to right; the
    first piece of the finest depth that fails ends the prefix)."""
    sa = np.empty(_CLEAR_DEPTH + 2)
    sb = np.empty(_CLEAR_DEPTH + 2)
    sd = np.empty(_CLEAR_DEPTH + 2, dtype=np.int64)
    sa[0] = a
    sb[0] = b
    sd[0] = 0
    top = 1
    c = a
    while top > 0:
        top -= 1
        ta = sa[top]
        tb = sb[top]
        d = sd[top]
        if instant_bound(dp, dv, da, R, Sigma, ta, tb) < thr:
            c = tb
            continue
        m = 0.5 * (ta + tb)
        if d >= _CLEAR_DEPTH or not (ta < m < tb):
            return c
        top = push_halves(sa, sb, sd, top, ta, m, tb, d)
    return c


@njit(cache=True, error_model="numpy")
def first_crossing(
    dp, dv, da, R, Sigma, pa, pb, j, a0, p_start, thr, dt, cache, acc, st, panel_free
):
    """First t in panel j = [a, b] with P(|X(t)| <= R) >= thr given that P < thr
    is certified on [a, a0] and P(a0) = p_start < thr, or +inf when certified
    absent (also +inf when S(t) turned out degenerate: the caller checks
    st[ST_DEGENERATE]).

    Invariant: P < thr on [a, lo] is certified (each step by
    sup_[lo, c] P <= P(lo) + int_lo^c nu+ + errors < thr).  Until a point
    with P >= thr is known the candidate c walks right with a step that
    doubles after a certified step and halves after a failed one; once
    P(hi) >= thr is known, the first crossing lies in (lo, hi] and c is the
    root of log P interpolated between lo and hi, aimed short by the last
    certified step's over-count (bisection when the bracket did not halve in
    two updates).  Returns hi once hi - lo <= dt.  Conservative exits (an
    earlier time than the true first crossing, never a later one): lo when
    the step model shrinks below dt and [lo, lo + dt] cannot be certified
    either, or after _SEARCH_STEPS steps (P within the certificate's resolution of
    the threshold over a long stretch).

    Each candidate's P(c) is computed before its entry-rate step: P(c) >= thr
    makes c the new hi with no quadrature (a certified step needs P(c) anyway,
    as the next P(lo)).  Only the panel's first candidate c = b with
    panel_free (the caller computes the panel integral for the probability
    anyway: t_inside > H) tries the certificate first, which proves the whole
    panel clear without P(b)."""
    b = pb[j]
    perr = st[ST_PERR]  # error of one instantaneous probability
    lo = a0
    plo = p_start
    hi = math.inf
    phi = -1.0
    step = b - a0
    c = b
    over = 0.25  # the last certified step's over-count (exits + errors) / (integral + error)
    w1 = math.inf  # the bracket's width one and two updates ago (bisection safeguard)
    w2 = math.inf
    probed = -math.inf  # the lo whose [lo, lo + dt] was last tried
    first = True
    for _ in range(_SEARCH_STEPS):
        if hi - lo <= dt:
            return hi
        pc = -1.0  # P(c), not computed yet
        endgame = c - lo <= dt
        if endgame:
            # the step model says the certificate cannot step further (P(lo)
            # within its resolution of thr): one probe at lo + dt; at or above
            # thr the crossing is in (lo, lo + dt], which is answered like a
            # bracket; else one attempt to certify [lo, lo + dt] (the model's
            # rate is that of the last step: the certificate may still pass),
            # and the conservative exit when that fails
            if not (lo + dt < hi and lo + dt <= b) or probed == lo:
                return lo
            probed = lo
            if st[ST_PTOL] > 0.0 and dp.shape[0] == 2:
                # the end game at the standard tolerance: the looser 2-D
                # probabilities' stated error is comparable with the Rice
                # integral over one dt, so the certificate of [lo, lo + dt]
                # would fail on it (a conservative exit a few 1e-7 below thr
                # where the 1e-9 ones bracket the crossing).  P(lo) is
                # recomputed (it only starts the next certificate: the invariant
                # on [a, lo] stands); the rest of the pair's walk keeps the
                # standard tolerance (a cheap 2-D evaluation: 3-D keeps its own)
                st[ST_PTOL] = 0.0
                st[ST_PERR] = P0_ERR
                perr = P0_ERR
                plo = prob_at(dp, dv, da, R, Sigma, lo, st)
            c = lo + dt
            pc = prob_at(dp, dv, da, R, Sigma, c, st)
            if pc >= thr:
                return c
        whole = first and c == b
        first = False
        if pc < 0.0 and not (whole and panel_free):
            pc = prob_at(dp, dv, da, R, Sigma, c, st)
        certified = False
        if pc < thr:
            if st[ST_SWEEP_DV] >= 0.0:
                # the swept ball's bound U of sup_[lo, c] P (+ TUBE_TAIL), written
                # as the Rice step's increment over P(lo): the certificate below
                # reads U + TUBE_TAIL + perr < thr
                v = swept_ball_bound(dp, dv, da, R, Sigma, lo, c, st) - plo
                e = TUBE_TAIL
                width = c - lo
                if endgame and not plo + v + e + perr < thr:
                    # its resolution over [lo, lo + dt] (the ball inflated by
                    # dt / 2 (|gd| + k sigma_v)) is coarser than the Rice
                    # integral's: first the same bound over _ENDGAME_SPLIT
                    # sub-steps (8 balls); then the last attempt before
                    # a conservative exit takes the 3-point Rice rule (3 cap
                    # integrals, far costlier), so that such exits land within the
                    # Rice certificate's resolution below thr
                    v = swept_ball_split(dp, dv, da, R, Sigma, lo, c, st, thr - e - perr) - plo
                    if not plo + v + e + perr < thr:
                        v, e = _rice_short(
                            dp, dv, da, R, Sigma, lo, c, pa, pb, j, cache, plo, thr, acc, st
                        )
            elif whole:
                # the panel's own integral (computed once per pair; nu+ >= 0, so
                # over [a, b] it bounds the one over [lo, b])
                v, e = rice_panel(dp, dv, da, R, Sigma, pa, pb, j, cache, acc, st)
                width = b - pa[j]
            else:
                v, e = _rice_short(dp, dv, da, R, Sigma, lo, c, pa, pb, j, cache, plo, thr, acc, st)
                width = c - lo
            if st[ST_DEGENERATE] != 0.0:
                return math.inf
            # entry-rate model of the step that the certificate would still pass
            rate = (v + e) / width
            certified = plo + v + e + perr < thr
            if certified:  # no crossing in [lo, c]
                if c == b:
                    return math.inf
                if pc < 0.0:
                    pc = prob_at(dp, dv, da, R, Sigma, c, st)
                if pc > plo + v + e + 2.0 * perr:
                    # P(c) <= P(lo) + int nu+ is a theorem (each P within perr), so the 3-point rule
                    # under-estimated the integral (a step across a steep rise of
                    # nu+): the step proves nothing; retry a shorter one
                    step = 0.25 * (c - lo)
                    c = lo + step
                    continue
                over = min(max((plo + v + e - pc) / (v + e), 0.0), 1.0) if v + e > 0.0 else 0.0
                lo = c
                plo = pc
                step = 2.0 * step if hi == math.inf else math.inf
                if rate > 0.0:
                    step = min(step, 0.9 * (thr - plo - perr) / rate)
            else:
                if pc < 0.0:
                    pc = prob_at(dp, dv, da, R, Sigma, c, st)
                if pc < thr:  # neither certified nor above: a shorter step
                    over = max(over, 0.25)
                    step = 0.5 * (c - lo)
                    if rate > 0.0:
                        step = min(step, 0.9 * (thr - plo - perr) / rate)
                    c = lo + max(step, 0.0)
                    continue
        if not certified:  # P(c) >= thr: c is the new hi
            hi = c
            phi = pc
        if hi == math.inf:
            c = min(lo + step, b)
            continue
        w = hi - lo
        if w > 0.5 * w2 or not (phi > plo):
            # the bracket did not halve in two updates: bisection
            c = 0.5 * (lo + hi)
        else:
            # the root of log P interpolated linearly between lo and hi (P rises
            # like a Gaussian tail below the threshold: the plain secant creeps),
            # the plain secant where P(lo) = 0; then aimed short of that root by
            # twice the last certified step's over-count, so that the
            # certificate can pass it
            if plo > 0.0:
                f = math.log(thr / plo) / math.log(phi / plo)
            else:
                f = (thr - plo) / (phi - plo)
            f = min(max(f, 1e-3), 1.0 - 1e-3)
            c = lo + max(0.5, 1.0 - 2.0 * over) * f * w
        w2 = w1
        w1 = w
        if hi - c > dt and c - lo > step:  # not beyond what the certificate is expected to pass
            c = lo + step
    return lo


_GRID = 64


@njit(cache=True, error_model="numpy")
def plausible_time_grid(dp, dv, da, R, Sigma, H, thr):
    """(first t with P(|X(t)| <= R) >= thr, max P seen) for degenerate
    covariances (no entry-rate certificate): a grid of _GRID steps, then
    bisection of the first step that ends at or above thr to 1e-12 H (a
    crossing and recrossing inside one grid step is not detected)."""
    p0 = instant_probability(dp, dv, da, R, Sigma, 0.0)
    pmax = p0
    if p0 >= thr:
        return 0.0, pmax
    ta = 0.0
    for i in range(1, _GRID + 1):
        tb = H * i / _GRID
        pb = instant_probability(dp, dv, da, R, Sigma, tb)
        pmax = max(pmax, pb)
        if pb >= thr:
            lo = ta
            hi = tb
            for _ in range(80):
                m = 0.5 * (lo + hi)
                if not (lo < m < hi) or hi - lo <= 1e-12 * H:
                    break
                pm = instant_probability(dp, dv, da, R, Sigma, m)
                pmax = max(pmax, pm)
                if pm >= thr:
                    hi = m
                else:
                    lo = m
            return hi, pmax
        ta = tb
    return math.inf, pmax
