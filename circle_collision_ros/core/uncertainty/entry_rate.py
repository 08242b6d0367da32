"""Expected rate of entries into the disc/ball (Rice's formula) and its integral.

For X(t) = dp + dv t + da t^2/2 with (dp, dv) Gaussian, (X(t), Xdot(t)) is
jointly Gaussian.  The expected number of entries of X into the ball
|x| <= R per unit time is (Rice)

    nu+(t) = int_{|x| = R} f_t(x) E[(-n.Xdot)^+ | X(t) = x] dS(x),

n = x / R the outward normal; given X(t) = x, n.Xdot is N(m, s^2) with
m = n.(gd + K (x - g)), s^2 = n^T (Svv - C^T S^-1 C) n, K = C^T S^-1,
C = Cov(X, Xdot) = Spv + t Svv, and E[(-Y)^+] = s phi(m/s) - m Phi(-m/s).

Exactness (docs/uncertainty.md): a straight path (da = 0) enters a convex
set at most once, and contact in [0, H] happens iff the path is inside at 0
or enters in (0, H], so P(contact) = P(|X(0)| <= R) + int_0^H nu+ exactly;
with da != 0 a path enters at most twice and the same sum is an upper bound.
Also, for any a < b, sup_{t in [a, b]} P(|X(t)| <= R) <= P(|X(a)| <= R) +
int_a^b nu+ (a path inside at some t in (a, b] is inside at a or entered in
between): core.uncertainty.walk uses it to certify that a threshold
crossing was not skipped.

Localisation (the only approximation besides quadrature): on the event
|z| <= k of the whitened (dp, dv) (probability >= 1 - TUBE_TAIL) every t
has |X(t) - g(t)| <= k sqrt(lambda_max(S(t))) <= k sqrt(tr S(t)) =: rho(t).
Entries at (t, x) with |x - g(t)| > rho(t) therefore belong to paths with
|z| > k; dropping them drops at most E[N 1{|z| > k}] <= 2 TUBE_TAIL.  So
the t-integral runs over the tube's ambiguous intervals only
(``core.uncertainty.tube.tube_intervals``) and the surface integral over the
arc/cap |x - g(t)| <= rho(t).

Degenerate S(t) (smallest/largest eigenvalue ratio < 1e-12 at a quadrature
node, e.g. a covariance of rank < D: no density on the sphere; or a density
ridge so thin that the arc or ring scan would need more than _SCAN_MAX steps to
keep its step within sigma_min): the node is flagged and the caller falls back
to randomized QMC on the exact solver.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from circle_collision_ros.core.special import (cody_erf_small, cody_erfcx_mid, cody_r3, inv_sym,
                                               mat_mul)
from circle_collision_ros.core.uncertainty.panel_map import map_to_t
from circle_collision_ros.core.uncertainty.quadrature import (G7_WEIGHTS, K15_NODES, K15_WEIGHTS,
                                                              P31_K15_WEIGHTS, P31_NEW_NODES,
                                                              P31_NEW_WEIGHTS, make_adaptive,
                                                              make_adaptive_angle,
                                                              make_adaptive_nested)

__all__ = ["entry_rate_integral", "entry_rate_k15", "entry_rate_p31", "entry_rate_gauss3",
           "rate_factor", "DEGENERATE_RATIO"]

DEGENERATE_RATIO = 1e-12
_RS2 = 1.0 / math.sqrt(2.0)
_RS2PI = 1.0 / math.sqrt(2.0 * math.pi)
BROAD_K = 7.5  # BROAD_PHASE_SIGMAS (core.uncertainty.tube asserts they agree)
BROAD_K2 = BROAD_K**2
_SCAN = 16  # arc scan steps for the density's local maxima (panel ends), at least
_SCAN_MAX = 4096  # at most (a step >= 2 alpha R / 4096 > sigma_min: S(t) degenerate)
_SCAN_ANCHOR = 64  # scan directions re-anchored by cos/sin every this many steps
_RING_ISOTROPIC = 4.0  # 3-D rings keep two fixed halves while sigma_min >= sqrt(tr S) / this


_RATE_TAIL_NEGLIGIBLE = 8.5
# A nu+ value whose arc window the rigorous bound of _window_bound puts below this
# fraction of its tolerance is taken as 0 with that bound as its error estimate
_WINDOW_NEGLIGIBLE = 1e-3


@njit(cache=True, error_model="numpy")
def rate_factor(q, m, s):
    """exp(-q/2) E[(-Y)^+] for Y ~ N(m, s^2), s >= 0: the density's exponential
    times Rice's rate factor, the surface integrand's only transcendental part.

    E[(-Y)^+] = s phi(r) - m Phi(-r), r = m / s.  Off |r| < 0.66 it is written as
    [-m if m < 0] + exp(-r^2/2) (s / sqrt(2 pi) - |m| erfcx(|r| / sqrt 2) / 2)
    with Cody's erfcx, so the two exponentials merge: one exp (m > 0) or two
    (m < 0) and a rational function, measured faster than exp, exp and erfc (see
    bench/bench_uncertainty.py).
    The bracket is s r3 / sqrt 2 for |r| > 4 sqrt 2, free of the cancellation of
    the direct form (its two terms agree to ~1 / r^2 there); for smaller |r| it
    keeps >= 3 % of s / sqrt(2 pi) (sqrt(pi) 4 erfcx(4) = 0.971), so no
    cancellation beyond ~1.5 digits.  Entering fast (r < -8.5, the common case
    where the velocity is well known) the tail is dropped: one exp.  Relative
    error ~1e-13 at worst (the rounding of exp's argument ~700; the test allows
    1e-12)."""
    if not (s > 0.0):
        return math.exp(-0.5 * q) * max(-m, 0.0)
    r = m / s
    if r < -_RATE_TAIL_NEGLIGIBLE:
        # entering fast: the tail is below e^(-r^2/2) / (sqrt(2 pi) |r|) < 1e-17 of -m
        # (bracket <= s / sqrt(2 pi)): below half an ulp of the sum, one exp instead of two
        return math.exp(-0.5 * q) * (-m)
    x = r * _RS2
    ax = abs(x)
    if ax < 0.46875:
        return math.exp(-0.5 * q) * (
            s * _RS2PI * math.exp(-0.5 * r * r) - 0.5 * m * (1.0 - cody_erf_small(x))
        )
    if ax <= 4.0:
        bracket = s * _RS2PI - 0.5 * abs(m) * cody_erfcx_mid(ax)
    else:
        bracket = s * _RS2 * cody_r3(ax)
    tail = math.exp(-0.5 * (q + r * r)) * bracket
    if m > 0.0:
        return tail
    return math.exp(-0.5 * q) * (-m) + tail


@njit(cache=True, error_model="numpy")
def _state(dp, dv, da, Sigma, t):
    """(g, gd, A = S^-1, norm = density factor, K, Vc, rho^2, degenerate) at t."""
    D = dp.shape[0]
    g = np.empty(D)
    gd = np.empty(D)
    S = np.empty((D, D))
    C = np.empty((D, D))
    Svv = np.empty((D, D))
    tr = 0.0
    for i in range(D):
        g[i] = dp[i] + t * (dv[i] + 0.5 * t * da[i])
        gd[i] = dv[i] + t * da[i]
        for j in range(D):
            S[i, j] = (
                Sigma[i, j] + t * (Sigma[i, D + j] + Sigma[D + i, j]) + t * t * Sigma[D + i, D + j]
            )
            C[i, j] = Sigma[i, D + j] + t * Sigma[D + i, D + j]
            Svv[i, j] = Sigma[D + i, D + j]
        tr += S[i, i]
    A, det = inv_sym(S)
    # det / (tr/D)^D ~ (product of eigenvalue ratios): tiny means (near) singular
    degenerate = not (det > DEGENERATE_RATIO * (tr / D) ** D) or not (tr > 0.0)
    norm = 1.0 / ((2.0 * math.pi) ** (0.5 * D) * math.sqrt(abs(det))) if not degenerate else 0.0
    # K = C^T A; Vc = Svv - C^T A C (explicit loops: numba's @ needs scipy's BLAS)
    K = mat_mul(C.T, A)
    Vc = Svv - mat_mul(K, C)
    rho2 = BROAD_K2 * tr
    return g, gd, A, norm, K, Vc, rho2, degenerate


@njit(cache=True, error_model="numpy")
def _surface_integrand(n0, n1, n2, R, g, gd, A, norm, K, Vc):
    """f_t(x) E[(-n.Xdot)^+ | X = x] at the sphere point x = R n, n = (n0, n1, n2):
    scalar code (no temporaries: this is the innermost loop of the 3-D cap)."""
    d0 = R * n0 - g[0]
    d1 = R * n1 - g[1]
    d2 = R * n2 - g[2]
    q = 0.0
    m = 0.0
    s2 = 0.0
    for i in range(3):
        Ad = A[i, 0] * d0 + A[i, 1] * d1 + A[i, 2] * d2
        Kd = K[i, 0] * d0 + K[i, 1] * d1 + K[i, 2] * d2
        Vn = Vc[i, 0] * n0 + Vc[i, 1] * n1 + Vc[i, 2] * n2
        di = d0 if i == 0 else (d1 if i == 1 else d2)
        ni = n0 if i == 0 else (n1 if i == 1 else n2)
        q += di * Ad
        m += ni * (gd[i] + Kd)
        s2 += ni * Vn
    if not (q < 1400.0):
        return 0.0
    return norm * rate_factor(q, m, math.sqrt(max(s2, 0.0)))


# ---- 2-D: the arc integral at one t ---------------------------------------------
# prm: a flat tuple of floats (no arrays: the 2-D path allocates nothing per
# evaluation, see _state2):
# _P_CG, _P_SG: cos, sin of g's direction
_P_R, _P_CG, _P_G0, _P_G1, _P_GD0, _P_GD1 = 0, 1, 2, 3, 4, 5
_P_A00, _P_A01, _P_A11, _P_NORM = 6, 7, 8, 9  # _P_A01: A[0, 1] + A[1, 0]
_P_K00, _P_K01, _P_K10, _P_K11 = 10, 11, 12, 13
_P_V00, _P_V01, _P_V11 = 14, 15, 16  # _P_V01: Vc[0, 1] + Vc[1, 0]
_P_SG = 17


@njit(cache=True, error_model="numpy")
def _arc_integrand(cp, sp, prm):
    """R f_t(x) E[(-n.Xdot)^+ | x] at x = R (cos, sin)(phig + psi), given cp, sp =
    cos, sin of psi (quadrature.make_adaptive_angle): scalar code (no
    temporaries: this is the innermost loop)."""
    R = prm[_P_R]
    n0 = prm[_P_CG] * cp - prm[_P_SG] * sp
    n1 = prm[_P_SG] * cp + prm[_P_CG] * sp
    d0 = R * n0 - prm[_P_G0]
    d1 = R * n1 - prm[_P_G1]
    q = prm[_P_A00] * d0 * d0 + prm[_P_A01] * d0 * d1 + prm[_P_A11] * d1 * d1
    if not (q < 1400.0):
        return 0.0
    m = n0 * (prm[_P_GD0] + prm[_P_K00] * d0 + prm[_P_K01] * d1) + n1 * (
        prm[_P_GD1] + prm[_P_K10] * d0 + prm[_P_K11] * d1
    )
    s2 = prm[_P_V00] * n0 * n0 + prm[_P_V01] * n0 * n1 + prm[_P_V11] * n1 * n1
    return R * prm[_P_NORM] * rate_factor(q, m, math.sqrt(max(s2, 0.0)))


_arc_adaptive = make_adaptive_angle(_arc_integrand)


@njit(cache=True, error_model="numpy")
def _arc_half_angle(R, gn, rho2):
    """Half-angle of the arc {|x| = R, |x - g| <= rho} about g's direction
    (-1: empty; pi: whole circle/sphere)."""
    if gn == 0.0:
        return math.pi if R * R <= rho2 else -1.0
    c = (R * R + gn * gn - rho2) / (2.0 * R * gn)
    if c > 1.0:
        return -1.0
    if c <= -1.0:
        return math.pi
    return math.acos(c)


@njit(cache=True, error_model="numpy")
def _scan_runs(qs, n, reach2, jmin, ra, rb):
    """The integration window of a scan qs[0..n] of q along an arc: each run of
    scan points with q <= reach2, widened by one step each side (runs that then
    touch merge), as index ranges [ra[r], rb[r]]; the narrowest window about the
    minimum jmin when no point qualifies.  Returns the number of runs.  Between
    runs no arc point has sqrt(q) <= k (nu_plus_2d: the scan's Lipschitz step),
    and a run is ~2 reach widths of its density peak, which a Kronrod piece with
    the peak at its end resolves (one window spanning both crossings of a thin
    ridge put them at the ends of one long piece whose nodes all missed them)."""
    nr = 0
    j = 0
    while j <= n:
        if qs[j] <= reach2:
            k = j
            while k < n and qs[k + 1] <= reach2:
                k += 1
            a = max(j - 1, 0)
            b = min(k + 1, n)
            if nr > 0 and a <= rb[nr - 1]:
                rb[nr - 1] = b
            else:
                ra[nr] = a
                rb[nr] = b
                nr += 1
            j = k + 1
        else:
            j += 1
    if nr == 0:
        ra[0] = max(jmin - 1, 0)
        rb[0] = min(jmin + 1, n)
        nr = 1
    return nr


@njit(cache=True, error_model="numpy", inline="always")
def _piece_end(qs, j, end):
    """Whether scan point j ends a piece of a run ending at end: the run's end, or a
    local minimum of q (a density peak: Kronrod nodes cluster at piece ends)."""
    return j == end or (qs[j] <= qs[j - 1] and qs[j] < qs[j + 1])


@njit(cache=True, error_model="numpy")
def _scan_pieces(qs, n, reach2, jmin):
    """The integration pieces of a scan qs[0..n]: the window's runs (_scan_runs)
    cut at their local minima of q, as (count, ia, ib), the scan-index pairs
    [ia[i], ib[i]].  One index allocation for the runs and the pieces (slices of
    it: this runs at every nu+ value)."""
    idx = np.empty(4 * (n + 1), dtype=np.int64)
    ra = idx[: n + 1]
    rb = idx[n + 1 : 2 * (n + 1)]
    ia = idx[2 * (n + 1) : 3 * (n + 1)]
    ib = idx[3 * (n + 1) :]
    nr = _scan_runs(qs, n, reach2, jmin, ra, rb)
    m = 0
    for r in range(nr):
        start = ra[r]
        for j in range(ra[r] + 1, rb[r] + 1):
            if _piece_end(qs, j, rb[r]):
                ia[m] = start
                ib[m] = j
                m += 1
                start = j
    return m, ia, ib


@njit(cache=True, error_model="numpy", inline="always")
def _window_steps(ia, ib, npieces):
    """The scan steps the window's pieces span."""
    n = 0
    for i in range(npieces):
        n += ib[i] - ia[i]
    return n


@njit(cache=True, error_model="numpy")
def _window_bound(qmin, c, length, norm, gd_norm, k_norm, d_max, vc_bound):
    """An upper bound of the arc integral over a window of arc length `length`,
    with no integrand value: qmin the smallest q of the arc's scan, c its step's
    Lipschitz constant of sqrt(q) (R step / sigma_min), norm the density factor,
    gd_norm = |gd|, k_norm = |K|_F, d_max >= |x - g| on the arc (R + |g|),
    vc_bound >= n^T Vc n for every unit n.

    Every arc point lies within half a step of a scan point, so sqrt(q) >= r =
    max(sqrt(qmin) - c / 2, 0) there (nu_plus_2d's scan) and the density is at
    most norm exp(-r^2 / 2).  E[(-Y)^+] <= max(-m, 0) + s / sqrt(2 pi) (the
    positive part is subadditive), with |m| = |n.(gd + K (x - g))| <= |gd| +
    |K|_F |x - g| and s^2 = n^T Vc n <= vc_bound."""
    r = max(math.sqrt(qmin) - 0.5 * c, 0.0)
    rate = gd_norm + k_norm * d_max + math.sqrt(max(vc_bound, 0.0)) * _RS2PI
    return length * norm * math.exp(-0.5 * r * r) * rate


@njit(cache=True, error_model="numpy")
def nu_plus_2d(dp, dv, da, R, Sigma, t, tol, acc):
    """nu+(t) in 2-D over the tube's arc; acc[2] = this value's error
    estimate (the arc rule's; or, where _window_bound puts the window's
    integral below _WINDOW_NEGLIGIBLE tol, 0 with that bound), acc[1] = 1 when
    S(t) is degenerate.  The state at t as in _state, in scalars (this runs at
    every t node of every pair)."""
    acc[2] = 0.0
    g0 = dp[0] + t * (dv[0] + 0.5 * t * da[0])
    g1 = dp[1] + t * (dv[1] + 0.5 * t * da[1])
    gd0 = dv[0] + t * da[0]
    gd1 = dv[1] + t * da[1]
    s00 = Sigma[0, 0] + t * (Sigma[0, 2] + Sigma[2, 0]) + t * t * Sigma[2, 2]
    s01 = Sigma[0, 1] + t * (Sigma[0, 3] + Sigma[2, 1]) + t * t * Sigma[2, 3]
    s10 = Sigma[1, 0] + t * (Sigma[1, 2] + Sigma[3, 0]) + t * t * Sigma[3, 2]
    s11 = Sigma[1, 1] + t * (Sigma[1, 3] + Sigma[3, 1]) + t * t * Sigma[3, 3]
    tr = s00 + s11
    det = s00 * s11 - s01 * s10
    # det / (tr/D)^D ~ (product of eigenvalue ratios): tiny means (near) singular
    if not (det > DEGENERATE_RATIO * (0.5 * tr) ** 2) or not (tr > 0.0):
        acc[1] = 1.0
        return 0.0
    a00 = s11 / det
    a01 = -s01 / det
    a10 = -s10 / det
    a11 = s00 / det
    norm = 1.0 / (2.0 * math.pi * math.sqrt(abs(det)))
    # C = Spv + t Svv; K = C^T A; Vc = Svv - K C
    c00 = Sigma[0, 2] + t * Sigma[2, 2]
    c01 = Sigma[0, 3] + t * Sigma[2, 3]
    c10 = Sigma[1, 2] + t * Sigma[3, 2]
    c11 = Sigma[1, 3] + t * Sigma[3, 3]
    k00 = c00 * a00 + c10 * a10
    k01 = c00 * a01 + c10 * a11
    k10 = c01 * a00 + c11 * a10
    k11 = c01 * a01 + c11 * a11
    v00 = Sigma[2, 2] - (k00 * c00 + k01 * c10)
    v01 = Sigma[2, 3] - (k00 * c01 + k01 * c11)
    v10 = Sigma[3, 2] - (k10 * c00 + k11 * c10)
    v11 = Sigma[3, 3] - (k10 * c01 + k11 * c11)
    rho2 = BROAD_K2 * tr
    gn = math.sqrt(g0 * g0 + g1 * g1)
    alpha = _arc_half_angle(R, gn, rho2)
    if alpha < 0.0:
        return 0.0
    phig = math.atan2(g1, g0) if gn > 0.0 else 0.0
    a01s = a01 + a10
    # Only arc points with Mahalanobis distance q(x) <= k^2 matter: a path
    # through x at time t has |z| >= sqrt(q(x)) (the whitened (dp, dv)
    # projects onto X(t) - g(t) without growing), so entries at q > k^2 belong
    # to paths outside the tube (already counted in the tail).  A scan of the
    # arc finds that window and the local minima of q (the density's peaks:
    # piece ends).  sqrt(q(x)) = |S^(-1/2) (x - g)| is Lipschitz in x with
    # constant 1 / sigma_min (sigma_min^2 = lambda_min(S)), so along the arc it
    # changes by at most c = R step / sigma_min between scan points: every arc
    # point with sqrt(q) <= k lies within half a step of a scan point with
    # sqrt(q) <= k + c / 2, and the window (those scan points, plus one step of
    # margin each side) contains it.  The step is at most sigma_min / R (c <= 1)
    # where _SCAN steps would be coarser: a thin density ridge (nearly
    # singular S(t), e.g. a rank-deficient covariance near the time its
    # position part is singular) is then never stepped over.  Beyond
    # _SCAN_MAX steps S(t) counts as degenerate (the caller samples instead).
    lam_max = 0.5 * tr + math.sqrt(0.25 * (s00 - s11) ** 2 + 0.25 * (s01 + s10) ** 2)
    sig_min = math.sqrt(max(det / lam_max, 0.0))  # det / lambda_max: no cancellation
    nscan = _SCAN
    if 2.0 * alpha * R > _SCAN * sig_min:
        nscan = int(math.ceil(2.0 * alpha * R / sig_min))
        if nscan > _SCAN_MAX:
            acc[1] = 1.0
            return 0.0
    step = 2.0 * alpha / nscan
    reach = BROAD_K + 0.5 * R * step / sig_min  # sig_min > 0: det > 0 passed the degenerate test
    # The scan's directions by rotation (one cos/sin pair per _SCAN_ANCHOR points
    # instead of one per point: this runs at every nu+ node).  Re-anchored every
    # _SCAN_ANCHOR points, the accumulated rounding stays ~_SCAN_ANCHOR ulps: it
    # moves q by ~1e-14 relative, so it can flip a scan point's membership of
    # the window only within that of the threshold, and the window keeps one
    # scan step of margin each side.
    qs = np.empty(nscan + 1)
    jmin = 0
    cd = math.cos(step)
    sd = math.sin(step)
    cr = 0.0
    sr = 0.0
    for j in range(nscan + 1):
        if j % _SCAN_ANCHOR == 0:
            cr = math.cos(phig - alpha + j * step)
            sr = math.sin(phig - alpha + j * step)
        d0 = R * cr - g0
        d1 = R * sr - g1
        qs[j] = a00 * d0 * d0 + a01s * d0 * d1 + a11 * d1 * d1
        if qs[j] < qs[jmin]:
            jmin = j
        cr, sr = cr * cd - sr * sd, sr * cd + cr * sd
    # the window's runs, cut into pieces at the density's peaks
    npieces, ia, ib = _scan_pieces(qs, nscan, reach * reach, jmin)
    # Many of a Rice panel's nodes sit where nu+ is a tiny fraction of the
    # tolerance (the tube's interval is far wider than nu+'s bump): a bound of the
    # window's integral that needs no integrand value settles them.  Its velocity
    # term |v00| + |v11| + |v01 + v10| / 2 >= |n^T Vc n| holds even where rounding
    # leaves Vc slightly indefinite
    bound = _window_bound(qs[jmin], R * step / sig_min, step * R * _window_steps(ia, ib, npieces),
                          norm, math.sqrt(gd0 * gd0 + gd1 * gd1),
                          math.sqrt(k00 * k00 + k01 * k01 + k10 * k10 + k11 * k11), R + gn,
                          abs(v00) + abs(v11) + 0.5 * abs(v01 + v10))
    if bound <= _WINDOW_NEGLIGIBLE * tol:
        acc[2] = bound
        return 0.0
    prm = (R, math.cos(phig), g0, g1, gd0, gd1, a00, a01s, a11, norm, k00, k01, k10, k11, v00,
           v01 + v10, v11, math.sin(phig))
    ptol = tol / npieces
    total = 0.0
    err = 0.0
    for i in range(npieces):
        v, e = _arc_adaptive(prm, -alpha + step * ia[i], -alpha + step * ib[i], ptol)
        total += v
        err += e
    acc[2] = err
    return total


# ---- 3-D: the cap integral at one t ---------------------------------------------
# prm = (R, cos theta, sin theta, u, e1, e2, g, gd, A, norm, K, Vc)


@njit(cache=True, error_model="numpy")
def _ring_integrand(cp, sp, prm):
    """The surface integrand at polar angle theta (its cos/sin in prm, computed once
    per ring) and azimuth psi, given cp, sp = cos, sin of psi
    (quadrature.make_adaptive_angle)."""
    R = prm[0]
    ct = prm[1]
    st = prm[2]
    u = prm[3]
    e1 = prm[4]
    e2 = prm[5]
    n0 = ct * u[0] + st * (cp * e1[0] + sp * e2[0])
    n1 = ct * u[1] + st * (cp * e1[1] + sp * e2[1])
    n2 = ct * u[2] + st * (cp * e1[2] + sp * e2[2])
    return _surface_integrand(n0, n1, n2, R, prm[6], prm[7], prm[8], prm[9], prm[10], prm[11])


_ring_adaptive = make_adaptive_angle(_ring_integrand)


@njit(cache=True, error_model="numpy")
def _cap_integrand(th, prm):
    """R^2 sin(theta) * ring integral at polar angle theta.  The ring as two
    halves where its circumference is at most _SCAN lower bounds of sigma_min
    (the density varies slowly along it) or S(t) is within _RING_ISOTROPIC of
    isotropic (sigma_min >= sigma_lb >= sqrt(tr S) / _RING_ISOTROPIC >=
    sigma_max / _RING_ISOTROPIC: no feature narrower than a quarter of the
    density's extent, which the halves' nodes resolve, as the entry-rate and
    horizon tests show); else scanned like nu_plus_2d's arc,
    with a step of at most sigma_min / R along the ring (q is Lipschitz with
    constant 1 / sigma_min), integrated over the scan's runs cut at their
    peaks: a thin density band (nearly singular S(t)) crosses a ring in two
    spikes that two fixed halves' nodes can miss."""
    R = prm[0]
    sth = math.sin(th)
    cth = math.cos(th)
    p2 = (R, cth, sth, prm[1], prm[2], prm[3], prm[4], prm[5], prm[6], prm[7], prm[8], prm[9])
    tol = prm[10]
    acc = prm[11]
    sig_lb = prm[12]
    st = R * R * sth
    ring = 2.0 * math.pi * R * sth
    if not (ring > _SCAN * sig_lb) or sig_lb >= prm[13]:
        v1, e1 = _ring_adaptive(p2, 0.0, math.pi, tol)
        v2, e2 = _ring_adaptive(p2, math.pi, 2.0 * math.pi, tol)
        acc[0] = max(acc[0], (e1 + e2) * st)
        return (v1 + v2) * st
    n = int(math.ceil(ring / sig_lb))
    if n > _SCAN_MAX:
        acc[1] = 1.0
        return 0.0
    step = 2.0 * math.pi / n
    reach = BROAD_K + 0.5 * R * sth * step / sig_lb
    # q(psi) = |A^(1/2) (w0 + R sin(theta) (cos psi e1 + sin psi e2))|^2, w0 = R cos(theta) u - g
    u, e1, e2, g, A = prm[1], prm[2], prm[3], prm[4], prm[6]
    w0 = np.empty(3)
    for i in range(3):
        w0[i] = R * cth * u[i] - g[i]
    c00 = 0.0
    c1 = 0.0
    c2 = 0.0
    d11 = 0.0
    d12 = 0.0
    d22 = 0.0
    for i in range(3):
        for k in range(3):
            c00 += w0[i] * A[i, k] * w0[k]
            c1 += w0[i] * A[i, k] * e1[k]
            c2 += w0[i] * A[i, k] * e2[k]
            d11 += e1[i] * A[i, k] * e1[k]
            d12 += e1[i] * A[i, k] * e2[k]
            d22 += e2[i] * A[i, k] * e2[k]
    rs = R * sth
    qs = np.empty(n + 1)
    jmin = 0
    for j in range(n + 1):
        cp = math.cos(j * step)
        sp = math.sin(j * step)
        qs[j] = (
            c00
            + 2.0 * rs * (cp * c1 + sp * c2)
            + rs * rs * (cp * cp * d11 + 2.0 * cp * sp * d12 + sp * sp * d22)
        )
        if qs[j] < qs[jmin]:
            jmin = j
    npieces, ia, ib = _scan_pieces(qs, n, reach * reach, jmin)
    ptol = 2.0 * tol / npieces  # the two halves' total
    total = 0.0
    err = 0.0
    for i in range(npieces):
        v, e = _ring_adaptive(p2, step * ia[i], step * ib[i], ptol)
        total += v
        err += e
    acc[0] = max(acc[0], err * st)
    return total * st


_cap_adaptive = make_adaptive(_cap_integrand)


@njit(cache=True, error_model="numpy")
def nu_plus_3d(dp, dv, da, R, Sigma, t, tol, acc):
    """nu+(t) in 3-D over the tube's cap (same conventions as nu_plus_2d; the
    error estimate in acc[2] is the polar rule's plus the polar width times
    the largest azimuthal estimate; acc[0] is scratch)."""
    acc[2] = 0.0
    g, gd, A, norm, K, Vc, rho2, degenerate = _state(dp, dv, da, Sigma, t)
    if degenerate:
        acc[1] = 1.0
        return 0.0
    gn = math.sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2])
    alpha = _arc_half_angle(R, gn, rho2)
    if alpha < 0.0:
        return 0.0
    u = np.empty(3)
    if gn > 0.0:
        u[:] = g / gn
    else:
        u[0] = 0.0
        u[1] = 0.0
        u[2] = 1.0
    # e1, e2: an orthonormal basis of u's complement
    w = np.zeros(3)
    w[np.argmin(np.abs(u))] = 1.0
    e1 = np.empty(3)
    e1[0] = u[1] * w[2] - u[2] * w[1]
    e1[1] = u[2] * w[0] - u[0] * w[2]
    e1[2] = u[0] * w[1] - u[1] * w[0]
    e1 /= math.sqrt(e1[0] ** 2 + e1[1] ** 2 + e1[2] ** 2)
    e2 = np.empty(3)
    e2[0] = u[1] * e1[2] - u[2] * e1[1]
    e2[1] = u[2] * e1[0] - u[0] * e1[2]
    e2[2] = u[0] * e1[1] - u[1] * e1[0]
    inner_tol = tol / (2.0 * math.pi * R * R + 1e-300)
    # sigma_min >= 1 / sqrt(|A|_F) (|A|_F >= lambda_max(A) = 1 / sigma_min^2): a lower
    # bound that keeps the rings' scan steps within sigma_min / R, without eigenvalues
    af = 0.0
    for i in range(3):
        for k in range(3):
            af += A[i, k] * A[i, k]
    sig_lb = 1.0 / math.sqrt(math.sqrt(af))
    sig_iso = math.sqrt(rho2 / BROAD_K2) / _RING_ISOTROPIC  # sqrt(tr S) / _RING_ISOTROPIC
    prm = (R, u, e1, e2, g, gd, A, norm, K, Vc, inner_tol, acc, sig_lb, sig_iso)
    acc[0] = 0.0  # the largest ring error (times R^2 sin theta) of this cap
    v, e = _cap_adaptive(prm, 0.0, alpha, tol)
    acc[2] = e + alpha * acc[0]
    return v


# ---- the t integral ------------------------------------------------------------
# prm = (dp, dv, da, R, Sigma, inner_tol, acc)


@njit(cache=True, error_model="numpy")
def _nu_2d(t, prm):
    return nu_plus_2d(prm[0], prm[1], prm[2], prm[3], prm[4], t, prm[5], prm[6])


@njit(cache=True, error_model="numpy")
def _nu_3d(t, prm):
    return nu_plus_3d(prm[0], prm[1], prm[2], prm[3], prm[4], t, prm[5], prm[6])


@njit(cache=True, error_model="numpy")
def _nu_error(prm):
    """The error estimate of the latest nu+ value (acc[2])."""
    return prm[6][2]


_t_adaptive_2d = make_adaptive_nested(_nu_2d, _nu_error)
_t_adaptive_3d = make_adaptive_nested(_nu_3d, _nu_error)

# Each nu+ value's own (arc/cap) rule accepts at INNER_TOL_FACTOR * tol / (tb - ta).
# Safe for the stated bound because the bound adds the t-rule's weighted sum of
# the nu+ estimates actually made, not that tolerance: the worst case adds
# INNER_TOL_FACTOR * tol, but an inner estimate exceeds its share only near
# the peak of nu+ (the arc rule's |K15 - G7| is ~1e-4 of the value there), so
# the sum stays well below tol (test_uncertainty_horizon checks the bound).
# A share of 1 splits many more arc pieces (see bench/bench_uncertainty.py).
INNER_TOL_FACTOR = 4.0


@njit(cache=True, error_model="numpy")
def entry_rate_integral(dp, dv, da, R, Sigma, ta, tb, tol, acc):
    """(int_ta^tb nu+ dt over the tube's arc/cap, error estimate).

    acc (3,) float64 scratch: acc[1] is set to 1 if S(t) was degenerate at a
    node (the value is then not usable).  The error estimate is the sum of the
    t-rule's panel estimates (``quadrature.k15_error``, or |P31 - K15|) plus its
    weighted sum of the nodes' own (arc/cap) estimates
    (``quadrature.make_adaptive_nested``)."""
    prm = (dp, dv, da, R, Sigma, INNER_TOL_FACTOR * tol / max(tb - ta, 1e-300), acc)
    if dp.shape[0] == 2:
        v, e, inner = _t_adaptive_2d(prm, ta, tb, tol)
    else:
        v, e, inner = _t_adaptive_3d(prm, ta, tb, tol)
    return v, e + inner


@njit(cache=True, error_model="numpy")
def entry_rate_k15(dp, dv, da, R, Sigma, ta, tb, tol, acc, f, fe, mp):
    """(K15 of nu+ over [ta, tb], |K15 - G7|, K15 of the nodes' own
    estimates, the largest of those) in the mapped variable s of
    ``panel_map`` (mp = (c, w, alpha, h), t(s) onto [ta, tb]): the values
    nu+(t(s)) dt/ds at K15_NODES (ascending) kept in f, for
    ``quadrature.subinterval_integral`` (unit half-width) and
    ``entry_rate_p31``; the nodes' own estimates (per unit t) in fe.  Each nu+
    value takes the inner tolerance of ``entry_rate_integral`` over [ta, tb]."""
    itol = INNER_TOL_FACTOR * tol / max(tb - ta, 1e-300)
    k = 0.0
    g = 0.0
    ie = 0.0
    ie_max = 0.0
    for i in range(15):
        t, jac = map_to_t(mp, K15_NODES[i])
        f[i] = _nu(dp, dv, da, R, Sigma, t, itol, acc) * jac
        fe[i] = acc[2]
        k += K15_WEIGHTS[i] * f[i]
        g += G7_WEIGHTS[i] * f[i]
        ie += K15_WEIGHTS[i] * acc[2] * jac
        ie_max = max(ie_max, acc[2])
    return k, abs(k - g), ie, ie_max


@njit(cache=True, error_model="numpy")
def entry_rate_p31(dp, dv, da, R, Sigma, ta, tb, tol, acc, f, fe, fnew, mp):
    """(P31 of nu+ over [ta, tb], |P31 - K15|, P31 of the nodes' own estimates,
    the largest of the new nodes' estimates): Patterson's extension of
    ``entry_rate_k15``'s rule in the same mapped variable and tolerance, from
    its 15 values f and estimates fe and 16 new values nu+(t(s)) dt/ds, kept
    in fnew (at P31_NEW_NODES; the two K15 halves the adaptive rule would take
    next cost 30).  |P31 - K15| is the estimate as |K15 - G7| is K15's: P31 is
    exact to degree 46, K15 to 22."""
    itol = INNER_TOL_FACTOR * tol / max(tb - ta, 1e-300)
    p = 0.0
    k = 0.0
    ie = 0.0
    ie_max = 0.0
    for i in range(15):
        p += P31_K15_WEIGHTS[i] * f[i]
        k += K15_WEIGHTS[i] * f[i]
        ie += P31_K15_WEIGHTS[i] * fe[i] * map_to_t(mp, K15_NODES[i])[1]
    for i in range(16):
        t, jac = map_to_t(mp, P31_NEW_NODES[i])
        fnew[i] = _nu(dp, dv, da, R, Sigma, t, itol, acc) * jac
        p += P31_NEW_WEIGHTS[i] * fnew[i]
        ie += P31_NEW_WEIGHTS[i] * acc[2] * jac
        ie_max = max(ie_max, acc[2])
    return p, abs(p - k), ie, ie_max


@njit(cache=True, error_model="numpy", inline="always")
def _nu(dp, dv, da, R, Sigma, t, tol, acc):
    """nu+(t) in 2-D or 3-D (acc as nu_plus_2d's)."""
    if dp.shape[0] == 2:
        return nu_plus_2d(dp, dv, da, R, Sigma, t, tol, acc)
    return nu_plus_3d(dp, dv, da, R, Sigma, t, tol, acc)


@njit(cache=True, error_model="numpy")
def entry_rate_gauss3(dp, dv, da, R, Sigma, ta, tb, tol, acc):
    """(int_ta^tb nu+ dt by the 3-point Gauss rule, error estimate) for short
    intervals (the plausible-time search): the estimate is |G3 - midpoint
    rule| (the midpoint is G3's centre node, so no extra evaluation; for a
    smooth nu+ a large over-estimate of G3's error) plus the G3-weighted sum
    of the nodes' own estimates.  acc as in ``entry_rate_integral``."""
    h = 0.5 * (tb - ta)
    c = ta + h
    x = h * math.sqrt(0.6)
    itol = INNER_TOL_FACTOR * tol / max(tb - ta, 1e-300)
    if dp.shape[0] == 2:
        f0 = nu_plus_2d(dp, dv, da, R, Sigma, c - x, itol, acc)
        e0 = acc[2]
        f1 = nu_plus_2d(dp, dv, da, R, Sigma, c, itol, acc)
        e1 = acc[2]
        f2 = nu_plus_2d(dp, dv, da, R, Sigma, c + x, itol, acc)
    else:
        f0 = nu_plus_3d(dp, dv, da, R, Sigma, c - x, itol, acc)
        e0 = acc[2]
        f1 = nu_plus_3d(dp, dv, da, R, Sigma, c, itol, acc)
        e1 = acc[2]
        f2 = nu_plus_3d(dp, dv, da, R, Sigma, c + x, itol, acc)
    e2 = acc[2]
    g3 = h * (5.0 * f0 + 8.0 * f1 + 5.0 * f2) / 9.0
    g1 = 2.0 * h * f1
    return g3, abs(g3 - g1) + h * (5.0 * e0 + 8.0 * e1 + 5.0 * e2) / 9.0
