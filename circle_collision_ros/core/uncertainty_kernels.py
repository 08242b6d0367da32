"""Numba kernels of core.uncertainty: covariance propagation, the k-sigma tube,
randomized QMC on the exact solver, the per-pair orchestration.

See docs/uncertainty.md for the mathematics; each guarantee is stated where
it is made.
"""
from __future__ import annotations

import functools
import math
from statistics import NormalDist

import numpy as np
from numba import njit

from circle_collision_ros.core.entry_rate import (BROAD_K, entry_rate_gauss3, entry_rate_integral, entry_rate_k15,
                                                 entry_rate_p31)
from circle_collision_ros.core.line_sampling import PHI_ERR, cylinder_control, line_factor, line_replicates
from circle_collision_ros.core.narrow_phase import _ttc_kernel_h
from circle_collision_ros.core.overlap_probability import (BALL_ERR_PER_TOL, DISC_ERR_PER_TOL, eig_sym,
                                                           overlap_probability, overlap_probability_2d,
                                                           overlap_probability_2d_tol, overlap_probability_tol)
from circle_collision_ros.core.quadrature import P31_K15_POS, P31_NEW_POS, push_halves, subinterval_integral
from circle_collision_ros.core.sobol import scrambled_directions, sobol_points

__all__ = ["BROAD_PHASE_SIGMAS", "TUBE_TAIL", "chi2_tail_even", "S_at", "max_sigma_over",
           "pair_probability", "relative_rows", "evaluate_uncertain_rows", "finish_row", "OUT_SIZE", "factor",
           "overcount_replicates",
           "QMC_REPLICATES", "QMC_POINTS", "QMC_T"]


def chi2_tail_even(x: float, dof: int) -> float:
    """P(chi^2_dof > x) for even dof (closed form: e^{-x/2} sum_{j < dof/2} (x/2)^j / j!)."""
    h = 0.5 * x
    term, s = 1.0, 0.0
    for j in range(dof // 2):
        s += term
        term *= h / (j + 1)
    return math.exp(-h) * s


# k of the k-sigma tube: with z the whitened (dp, dv) (2D <= 6 standard
# normals), P(|z| > k) = P(chi^2_6 > k^2) <= TUBE_TAIL (fewer dof: smaller),
# and on |z| <= k every t has |X(t) - g(t)| <= k sqrt(lambda_max(S(t)))
# (Cauchy-Schwarz).  Two bodies: 2 * TUBE_TAIL = 5.2e-10 < 1e-9.
BROAD_PHASE_SIGMAS = 7.5
TUBE_TAIL = chi2_tail_even(BROAD_PHASE_SIGMAS ** 2, 6)  # 2.6e-10
assert BROAD_K == BROAD_PHASE_SIGMAS

# Randomized QMC: QMC_REPLICATES independent scrambles of QMC_POINTS Sobol
# points; stated bound QMC_T standard errors of the replicate mean (Student t
# with 15 dof: two-sided 99.9 % quantile 4.07) and never below 3 / N.
QMC_REPLICATES = 16
QMC_POINTS = 512
QMC_T = 4.1
# The over-count estimator of accelerating pairs: QMC_CV_POINTS points per
# replicate, all QMC_POINTS when QMC_T standard errors exceed QMC_CV_TARGET
QMC_CV_POINTS = 128
QMC_CV_TARGET = 2e-3  # ~4 standard errors: an error ~5e-4, a third of 1e5-sample MC's at P ~ 0.5
_QMC_SEED = 18_2026
# Line sampling of straight 3-D pairs (core.line_sampling): QMC_LINE_POINTS points
# per replicate, then twice as many, then all QMC_POINTS while the stated bound
# exceeds QMC_LINE_TARGET (each stage adds points to the previous one's).  The
# first stage is the fewest points per replicate, a multiple of 32 (Sobol's
# balance in 2^5 blocks), whose 3 / N floor is within the target: 3 / (16 x 96)
# = 1.95e-3; with the control variate the statistical part is then ~10x smaller,
# so the floor decides (a randomised Sobol replicate is unbiased at any length).  The
# control variate's coefficient is fitted to the replicates (regression with one
# covariate: QMC_REPLICATES - 2 = 14 dof, two-sided 99.9 % Student t quantile
# 4.140; mpmath: tests/core/test_uncertainty_line_sampling.py)
QMC_LINE_POINTS = 96
QMC_LINE_TARGET = 2e-3
QMC_T_CONTROLLED = 4.15


def _normal_table(dim: int) -> np.ndarray:
    """(QMC_REPLICATES, QMC_POINTS, dim) standard normals from the scrambled
    Sobol replicates (inverse CDF: statistics.NormalDist, Wichura AS241)."""
    inv = NormalDist().inv_cdf
    out = np.empty((QMC_REPLICATES, QMC_POINTS, dim))
    for r in range(QMC_REPLICATES):
        dirs, shift = scrambled_directions(dim, _QMC_SEED + 1000 * dim + r)
        u = sobol_points(dirs, shift, QMC_POINTS)
        out[r] = np.vectorize(inv)(u)
    return out


_TABLES: dict[int, np.ndarray] = {}


def normal_table(dim: int) -> np.ndarray:
    if dim not in _TABLES:
        _TABLES[dim] = _normal_table(dim)
    return _TABLES[dim]


@njit(cache=True, error_model="numpy")
def S_at(Sigma, t):
    """Position covariance S(t) = Spp + t (Spv + Svp) + t^2 Svv of (D, D)."""
    D = Sigma.shape[0] // 2
    S = np.empty((D, D))
    for i in range(D):
        for j in range(D):
            S[i, j] = Sigma[i, j] + t * (Sigma[i, D + j] + Sigma[D + i, j]) + t * t * Sigma[D + i, D + j]
    return S


@njit(cache=True, error_model="numpy")
def _lam_max(Sigma, t):
    """Largest eigenvalue of S(t) (closed form in 2-D, Jacobi in 3-D)."""
    if Sigma.shape[0] == 4:  # scalar (no temporaries: the tube calls this per node); as S_at
        s00 = Sigma[0, 0] + t * (Sigma[0, 2] + Sigma[2, 0]) + t * t * Sigma[2, 2]
        s11 = Sigma[1, 1] + t * (Sigma[1, 3] + Sigma[3, 1]) + t * t * Sigma[3, 3]
        s01 = Sigma[0, 1] + t * (Sigma[0, 3] + Sigma[2, 1]) + t * t * Sigma[2, 3]
        s10 = Sigma[1, 0] + t * (Sigma[1, 2] + Sigma[3, 0]) + t * t * Sigma[3, 2]
        h = 0.5 * (s00 + s11)
        d = 0.5 * (s00 - s11)
        o = 0.5 * (s01 + s10)
        return h + math.sqrt(d * d + o * o)
    # 3-D: the symmetric part of S(t) entry by entry, as S_at
    return lam_max_sym3(_s_sym(Sigma, t, 0, 0), _s_sym(Sigma, t, 1, 1), _s_sym(Sigma, t, 2, 2),
                        _s_sym(Sigma, t, 0, 1), _s_sym(Sigma, t, 0, 2), _s_sym(Sigma, t, 1, 2))


@njit(cache=True, error_model="numpy", inline="always")
def _s_sym(Sigma, t, i, j):
    """Entry (i, j) of the symmetric part of S(t) in 3-D."""
    return 0.5 * ((Sigma[i, j] + Sigma[j, i]) + t * ((Sigma[i, 3 + j] + Sigma[3 + i, j])
                                                     + (Sigma[j, 3 + i] + Sigma[3 + j, i]))
                  + t * t * (Sigma[3 + i, 3 + j] + Sigma[3 + j, 3 + i]))


@njit(cache=True, error_model="numpy")
def lam_max_sym3(s00, s11, s22, s01, s02, s12):
    """Upper bound of the largest eigenvalue of the symmetric PSD 3x3 matrix
    [[s00, s01, s02], [s01, s11, s12], [s02, s12, s22]] in closed form (the
    trigonometric solution of the characteristic cubic: ~30 flops instead of a
    Jacobi eigendecomposition, ~3 us with its temporaries).  With q = tr / 3 and
    p = |S - q I|_F / sqrt 6, lambda_max = q + 2 p cos(acos(det((S - q I) / p) / 2) / 3).
    Its rounding error is a few hundred ulps of |q| + p <= 2 tr at worst (acos
    is ill-conditioned only at r = +-1, where a change dr moves lambda_max by at
    most 2 p dr / 9); the 1e-12 tr added covers it, and the result is never below
    the largest diagonal entry (a lower bound of lambda_max)."""
    tr = s00 + s11 + s22
    q = tr / 3.0
    a = s00 - q
    b = s11 - q
    c = s22 - q
    off = s01 * s01 + s02 * s02 + s12 * s12
    p = math.sqrt((a * a + b * b + c * c + 2.0 * off) / 6.0)
    lam = q
    if p > 0.0:
        det = a * (b * c - s12 * s12) - s01 * (s01 * c - s12 * s02) + s02 * (s01 * s12 - b * s02)
        r = min(max(0.5 * det / (p * p * p), -1.0), 1.0)
        lam = q + 2.0 * p * math.cos(math.acos(r) / 3.0)
    return max(lam, s00, s11, s22) + 1e-12 * abs(tr)


@njit(cache=True, error_model="numpy")
def max_sigma_over(Sigma, ta, tb):
    """Upper bound of sqrt(lambda_max(S(t))) over t in [ta, tb]: lambda_max
    of S(t) is convex in t, so its maximum is at an end; the factor
    (1 + 1e-9) covers the rounding of S and of the eigenvalues
    (relative error ~1e-15 of the largest eigenvalue)."""
    lm = max(_lam_max(Sigma, ta), _lam_max(Sigma, tb))
    return math.sqrt(lm * (1.0 + 1e-9))


@njit(cache=True, error_model="numpy")
def _axis_range(p, v, a, ta, tb):
    """[lo, hi] of p + v t + a t^2 / 2 over [ta, tb], widened by the rounding."""
    ga = p + ta * (v + 0.5 * ta * a)
    gb = p + tb * (v + 0.5 * tb * a)
    lo = min(ga, gb)
    hi = max(ga, gb)
    if a != 0.0:
        ts = -v / a
        if ta < ts < tb:
            gv = p + ts * (v + 0.5 * ts * a)
            lo = min(lo, gv)
            hi = max(hi, gv)
    m = 8.0 * 2.220446049250313e-16 * (abs(p) + tb * (abs(v) + 0.5 * tb * abs(a)))
    return lo - m, hi + m


@njit(cache=True, error_model="numpy")
def _mean_range(dp, dv, da, ta, tb):
    """(min |g|, max |g|) bounds over [ta, tb] (per-axis boxes)."""
    dmin = 0.0
    dmax = 0.0
    for k in range(dp.shape[0]):
        lo, hi = _axis_range(dp[k], dv[k], da[k], ta, tb)
        if lo > 0.0:
            dmin += lo * lo
        elif hi < 0.0:
            dmin += hi * hi
        m = max(abs(lo), abs(hi))
        dmax += m * m
    return math.sqrt(dmin), math.sqrt(dmax)


@njit(cache=True, error_model="numpy")
def max_sigma_rows(cov, ta, tb, out):
    """out[i] = max_sigma_over(cov[i], ta, tb) for a C-contiguous (n, 2D, 2D) stack."""
    for i in range(cov.shape[0]):
        out[i] = max_sigma_over(cov[i], ta, tb)


_TUBE_DEPTH = 8  # leaves of width >= H / 256


@njit(cache=True, error_model="numpy")
def _ambiguous_through(dp, dv, da, R, Sigma, ta, tb, k):
    """True when refining the ambiguous node [ta, tb] cannot change what the tube
    walk reports but the shape of the merged ambiguous run: (i) the tube is not
    outside at the points ta and tb (zero-width nodes: the leaves holding them have
    a smaller box bound of |g| and a larger radius, so they are ambiguous too), and
    (ii) no sub-node can be wholly inside (its radius k sqrt(lambda_max) >=
    k sqrt(tr S(t) / D) >= R on all of [ta, tb]: gmax + rho < R is impossible).
    Then [ta, tb] is the hull of its ambiguous leaves and holds no inside leaf, so
    reporting it whole leaves t_inside and "some interval is ambiguous" unchanged
    and only adds leaves where the tube is outside (integrating the entry rate
    there adds true entries of tail paths: the integral moves towards the
    untruncated one).  Saves most of the 2 x 256 nodes of a wide tube."""
    D = dp.shape[0]
    # (ii) tr S(t) = c0 + c1 t + c2 t^2 (c2 = tr Svv >= 0): its minimum over [ta, tb]
    c0 = 0.0
    c1 = 0.0
    c2 = 0.0
    for i in range(D):
        c0 += Sigma[i, i]
        c1 += Sigma[i, D + i] + Sigma[D + i, i]
        c2 += Sigma[D + i, D + i]
    trmin = min(c0 + ta * (c1 + ta * c2), c0 + tb * (c1 + tb * c2))
    if c2 > 0.0:
        tv = -c1 / (2.0 * c2)
        if ta < tv < tb:
            trmin = min(trmin, c0 + tv * (c1 + tv * c2))
    # 1e-6 relative: far above the rounding of tr, lambda_max and the 1e-9 widening
    if not (k * k * trmin >= D * R * R * (1.0 + 1e-6)):
        return False
    # (i) not outside at ta nor at tb (the walk's own test on zero-width nodes)
    for t in (ta, tb):
        gmin, _ = _mean_range(dp, dv, da, t, t)
        if gmin - k * max_sigma_over(Sigma, t, t) > R:
            return False
    return True


@njit(cache=True, error_model="numpy")
def _tube_walk(dp, dv, da, R, Sigma, H, out, k, first_only):
    """The k-sigma tube's interval tree over [0, H], nodes visited depth first, left
    to right.  Returns (count of ambiguous leaves written to out, t_inside); with
    first_only it stops at the first terminal node that is not outside and returns
    (0, its start): by the visiting order, the smallest start of any such node."""
    sa = np.empty(_TUBE_DEPTH + 2)
    sb = np.empty(_TUBE_DEPTH + 2)
    sd = np.empty(_TUBE_DEPTH + 2, dtype=np.int64)
    sa[0] = 0.0
    sb[0] = H
    sd[0] = 0
    top = 1
    cnt = 0
    t_inside = math.inf
    while top > 0:
        top -= 1
        ta = sa[top]
        tb = sb[top]
        d = sd[top]
        rho = k * max_sigma_over(Sigma, ta, tb)
        gmin, gmax = _mean_range(dp, dv, da, ta, tb)
        if gmin - rho > R:
            continue
        if gmax + rho < R:
            if first_only:
                return 0, ta
            t_inside = min(t_inside, ta)
            continue
        m = 0.5 * (ta + tb)
        if d >= _TUBE_DEPTH or not (ta < m < tb) or (not first_only and _ambiguous_through(
                dp, dv, da, R, Sigma, ta, tb, k)):
            if first_only:
                return 0, ta
            if cnt > 0 and out[cnt - 1, 1] == ta:
                out[cnt - 1, 1] = tb
            else:
                out[cnt, 0] = ta
                out[cnt, 1] = tb
                cnt += 1
            continue
        top = push_halves(sa, sb, sd, top, ta, m, tb, d)
    return cnt, t_inside


@njit(cache=True, error_model="numpy")
def tube_intervals(dp, dv, da, R, Sigma, H, out, k):
    """Classify [0, H] with the k-sigma tube (pair_probability: k = BROAD_PHASE_SIGMAS).

    Writes the ambiguous leaf intervals [out[j, 0], out[j, 1]] (merged when
    adjacent; out has >= 2^_TUBE_DEPTH rows) and returns (count, inside):
    inside is True when some interval has the whole tube inside the ball (then
    P(contact) >= 1 - TUBE_TAIL).  Outside the ambiguous intervals, no path of
    the tube touches the sphere |x| = R."""
    return _tube_walk(dp, dv, da, R, Sigma, H, out, k, False)


@njit(cache=True, error_model="numpy")
def screen_rows(dp, dv, da, R, Sigma, H, k, clear, t_first):
    """clear[i] = True when the k-sigma tube of row i never reaches the ball
    within [0, H] (no ambiguous interval, never wholly inside): then
    P(contact within [0, H]) <= P(chi^2_{2D} > k^2) for that row (a contact
    path has |z| > k, docs/uncertainty.md "Screening").  t_first[i] = the
    first t where the tube may reach the ball (start of the first ambiguous
    interval, or where it lies wholly inside; +inf if never): before it
    P(|X(t)| <= R) <= P(chi^2_{2D} > k^2).  Rows (n, D), Sigma (n, 2D, 2D)
    C-contiguous; each row is decided from itself alone."""
    unused = np.empty((0, 2))
    for i in range(dp.shape[0]):
        _, t_first[i] = _tube_walk(dp[i], dv[i], da[i], R[i], Sigma[i], H, unused, k, True)
        clear[i] = not (t_first[i] <= H)


@njit(cache=True, error_model="numpy")
def screen_rows_at(pa, va, aa, ra, pb, vb, ab, rb, sigma, rows, H, k, clear, t_first):
    """screen_rows on the rows ``rows`` of the per-body arrays (relative state formed
    here as a - b, Sigma = sigma[row]): the same tube test without gathering the rows
    into new arrays first (a scene screens ~1,000 rows per prediction)."""
    D = pa.shape[1]
    dp = np.empty(D)
    dv = np.empty(D)
    da = np.empty(D)
    unused = np.empty((0, 2))
    for j in range(rows.shape[0]):
        i = rows[j]
        for c in range(D):
            dp[c] = pa[i, c] - pb[i, c]
            dv[c] = va[i, c] - vb[i, c]
            da[c] = aa[i, c] - ab[i, c]
        _, t_first[j] = _tube_walk(dp, dv, da, ra[i] + rb[i], sigma[i], H, unused, k, True)
        clear[j] = not (t_first[j] <= H)


@njit(cache=True, error_model="numpy")
def row_classes(pa, va, aa, ra, pb, vb, ab, rb, sigma, exact, finite):
    """Per row: exact[i] = Sigma all zero (a NaN is not zero); finite[i] = every
    position, velocity, acceleration and Sigma entry finite and both radii >= 0
    (one pass instead of a dozen array reductions).  Returns (count of exact rows,
    count of rows neither finite nor exact)."""
    n = pa.shape[0]
    n_exact = 0
    n_bad = 0
    D = pa.shape[1]
    m = sigma.shape[1]
    for i in range(n):
        ex = True
        fin = ra[i] >= 0.0 and rb[i] >= 0.0
        for r in range(m):
            for c in range(m):
                x = sigma[i, r, c]
                if x != 0.0:
                    ex = False
                if not math.isfinite(x):
                    fin = False
        for c in range(D):
            if not (math.isfinite(pa[i, c]) and math.isfinite(va[i, c]) and math.isfinite(aa[i, c])
                    and math.isfinite(pb[i, c]) and math.isfinite(vb[i, c]) and math.isfinite(ab[i, c])):
                fin = False
        exact[i] = ex
        finite[i] = fin
        if ex:
            n_exact += 1
        elif not fin:
            n_bad += 1
    return n_exact, n_bad


@functools.lru_cache(maxsize=16)  # a pure function of (threshold, dof): ~50 tail evaluations, once
def screen_sigmas(threshold: float, dof: int) -> tuple[float, float]:
    """(k, U): the smallest k (to 1e-12) with U = P(chi^2_dof > k^2) <= threshold / 2,
    dof even; (inf, 0.0) when no k <= 40 qualifies (a threshold below ~1e-300)."""
    target = 0.5 * threshold
    lo, hi = 0.0, 40.0
    if chi2_tail_even(hi * hi, dof) > target:
        return math.inf, 0.0
    while hi - lo > 1e-12:
        m = 0.5 * (lo + hi)
        if chi2_tail_even(m * m, dof) <= target:
            hi = m
        else:
            lo = m
    return hi, chi2_tail_even(hi * hi, dof)


@njit(cache=True, error_model="numpy")
def factor(Sigma):
    """L (2D, 2D) with L L^T = Sigma (eigen factor; PSD after clamping)."""
    lam, V = eig_sym(Sigma)
    n = Sigma.shape[0]
    L = np.empty((n, n))
    for j in range(n):
        s = math.sqrt(lam[j])
        for i in range(n):
            L[i, j] = V[i, j] * s
    return L


@njit(cache=True, error_model="numpy")
def _replicate_stats(est):
    """(mean, standard error of the mean) of the replicate estimates est (r >= 2):
    compiled, as numpy's mean and std cost ~14 us per 16 values, a tenth of a pair."""
    n = est.shape[0]
    mean = 0.0
    for x in est:
        mean += x
    mean /= n
    ss = 0.0
    for x in est:
        ss += (x - mean) * (x - mean)
    return mean, math.sqrt(ss / (n - 1) / n)


def qmc_probability(dp, dv, da, R, Sigma, H, Z):
    """(mean, standard error) of P(contact within [0, H]) over the randomized
    QMC replicates Z (r, m, 2D): each sample's (dp, dv) = mean + L z goes
    through the exact solver's serial batch kernel (same contract and bits as
    ``time_to_collision``; rows are independent, so the answer does not
    depend on anything but this pair)."""
    D = dp.shape[0]
    r, m, _ = Z.shape
    L = factor(np.ascontiguousarray(Sigma))
    Zf = Z.reshape(r * m, 2 * D)
    Y = np.zeros((r * m, 2 * D))
    for j in range(2 * D):  # elementwise, not BLAS: the same bits on every machine/thread count
        Y += Zf[:, j:j + 1] * L[:, j]
    n = r * m
    zeros = np.zeros((n, D))
    t = np.empty(n)
    _ttc_kernel_h(np.ascontiguousarray(dp + Y[:, :D]), np.ascontiguousarray(dv + Y[:, D:]),
                  np.ascontiguousarray(np.broadcast_to(da, (n, D))), np.full(n, R),
                  zeros, zeros, zeros, np.zeros(n), H, t)
    est = (t <= H).reshape(r, m).mean(axis=1)
    return _replicate_stats(est)


@njit(cache=True, error_model="numpy")
def controlled_stats(est, ctl, ctl_mean):
    """(estimate, statistical bound, beta) of the replicate estimates est (r >= 4)
    with the control variate's replicate values ctl, whose exact mean is
    ctl_mean: est's mean minus beta (ctl's mean - ctl_mean), beta fitted by
    least squares, the bound QMC_T_CONTROLLED standard errors of that fitted
    value at ctl_mean (normal linear model: s^2 (1 / r + (ctl's mean -
    ctl_mean)^2 / Sxx) with s^2 = the residual sum of squares / (r - 2),
    Student t with r - 2 dof; the replicate values are means of >= 96 points
    each).  A control without spread (Sxx = 0) leaves the plain mean, with
    QMC_T standard errors and beta = 0."""
    n = est.shape[0]
    my = 0.0
    mx = 0.0
    for i in range(n):
        my += est[i]
        mx += ctl[i]
    my /= n
    mx /= n
    sxx = 0.0
    sxy = 0.0
    syy = 0.0
    for i in range(n):
        dx = ctl[i] - mx
        dy = est[i] - my
        sxx += dx * dx
        sxy += dx * dy
        syy += dy * dy
    if not (sxx > 0.0):
        mean, se = _replicate_stats(est)
        return mean, QMC_T * se, 0.0
    beta = sxy / sxx
    res = max(syy - beta * sxy, 0.0)
    d = mx - ctl_mean
    se = math.sqrt(res / (n - 2) * (1.0 / n + d * d / sxx))
    return my - beta * d, QMC_T_CONTROLLED * se, beta


@njit(cache=True, error_model="numpy", inline="always")
def _dquartic(c4, c3, c2, c1, t):
    """f'(t) of f = c4 t^4 + c3 t^3 + c2 t^2 + c1 t + c0."""
    return ((4.0 * c4 * t + 3.0 * c3) * t + 2.0 * c2) * t + c1


@njit(cache=True, error_model="numpy")
def _crit_in(c4, c3, c2, c1, lo, hi):
    """The root of f' in [lo, hi] where f' is monotone, or NaN when f' keeps its
    sign there (safeguarded Newton: bisection whenever a step leaves the bracket)."""
    flo = _dquartic(c4, c3, c2, c1, lo)
    fhi = _dquartic(c4, c3, c2, c1, hi)
    if (flo < 0.0) == (fhi < 0.0):
        return math.nan
    neg_lo = flo < 0.0
    t = 0.5 * (lo + hi)
    for _ in range(60):
        f = _dquartic(c4, c3, c2, c1, t)
        if (f < 0.0) == neg_lo:
            lo = t
        else:
            hi = t
        d2 = (12.0 * c4 * t + 6.0 * c3) * t + 2.0 * c2
        tn = t - f / d2 if d2 != 0.0 else 0.5 * (lo + hi)
        if not (lo < tn < hi):
            tn = 0.5 * (lo + hi)
        if abs(tn - t) <= 1e-12 * (hi + lo) or not (lo < tn < hi):
            return tn if lo < tn < hi else t
        t = tn
    return t


@njit(cache=True, error_model="numpy", inline="always")
def _quartic_coefficients(p, v, a):
    """(c4, c3, c2, c1, |p|^2) of |p + v t + a t^2 / 2|^2 = c4 t^4 + c3 t^3 + c2 t^2 + c1 t + |p|^2."""
    c4 = 0.0
    c3 = 0.0
    c2 = 0.0
    c1 = 0.0
    pp = 0.0
    for k in range(p.shape[0]):
        c4 += 0.25 * a[k] * a[k]
        c3 += v[k] * a[k]
        c2 += v[k] * v[k] + p[k] * a[k]
        c1 += 2.0 * p[k] * v[k]
        pp += p[k] * p[k]
    return c4, c3, c2, c1, pp


@njit(cache=True, error_model="numpy")
def _quartic_crossings(p, v, a, R, H):
    """(inside at 0, number of entries in (0, H]) of the path X(t) = p + v t + a t^2 / 2
    into the ball |x| <= R.  f(t) = |X(t)|^2 - R^2 is a quartic; between consecutive
    roots of f' (on the monotone pieces of f', split at the roots of f'') it is
    monotone, so an entry is a piece with f > 0 at its start and f <= 0 at its
    end.  (Only a graze, f touching 0, can be miscounted: a null event for a
    Gaussian state.)  Scalars only: this runs once per RQMC sample."""
    c4, c3, c2, c1, pp = _quartic_coefficients(p, v, a)
    pn = math.sqrt(pp)
    c0 = (pn - R) * (pn + R)
    # roots of f'' = 12 c4 t^2 + 6 c3 t + 2 c2 in (0, H): the ends of f''s monotone pieces
    s1 = math.nan
    s2 = math.nan
    qa = 12.0 * c4
    qb = 6.0 * c3
    qc = 2.0 * c2
    if qa == 0.0:
        if qb != 0.0:
            s1 = -qc / qb
    else:
        disc = qb * qb - 4.0 * qa * qc
        if disc >= 0.0:
            q = -0.5 * (qb + math.copysign(math.sqrt(disc), qb))  # no cancellation
            r1 = q / qa
            r2 = qc / q if q != 0.0 else r1
            s1 = min(r1, r2)
            s2 = max(r1, r2)
    if not (0.0 < s1 < H):
        s1, s2 = s2, math.nan
    if not (0.0 < s1 < H):
        s1 = math.nan
    if not (0.0 < s2 < H) or s2 == s1:
        s2 = math.nan
    # the critical points of f, ascending: one per monotone piece of f' with a sign change
    b0 = 0.0
    b1 = s1 if s1 == s1 else H
    b2 = s2 if s2 == s2 else H
    k1 = _crit_in(c4, c3, c2, c1, b0, b1)
    k2 = _crit_in(c4, c3, c2, c1, b1, b2) if b1 < H else math.nan
    k3 = _crit_in(c4, c3, c2, c1, b2, H) if b2 < H else math.nan
    inside0 = c0 <= 0.0
    entries = 0
    f_prev = c0
    for i in range(4):
        t = k1 if i == 0 else (k2 if i == 1 else (k3 if i == 2 else H))
        if t != t:
            continue
        f = (((c4 * t + c3) * t + c2) * t + c1) * t + c0
        if f_prev > 0.0 and f <= 0.0:
            entries += 1
        f_prev = f
    return inside0, entries


@njit(cache=True, error_model="numpy")
def overcount_replicates(dp, dv, da, R, H, L, Z, m, est):
    """est[r] = mean over the first m points of replicate r of Z (r, M, 2D standard
    normals) of the over-count O = (1{inside at 0} + #entries in (0, H] - 1)^+ of the
    sampled path (dp, dv) + L z: the amount by which P0 + E[entries] exceeds
    P(contact) for that path (docs/uncertainty.md, "Accelerating")."""
    D = dp.shape[0]
    n = 2 * D
    p = np.empty(D)
    v = np.empty(D)
    # over-counting needs an exit followed by an entry, so a local maximum of
    # f = |X|^2 - R^2 inside (0, H): impossible where f''/2 = |Xdot|^2 + X.da =
    # |v|^2 + p.da + 3 t v.da + 1.5 t^2 |da|^2 > 0 on all of [0, H] (its minimum
    # over [0, H] is checked), which is most paths.  p.da and v.da are linear in
    # z (weights L^T da, formed once), so the test needs v and two dot products;
    # p, the quartic and its crossings only for the paths that fail it
    wp = np.zeros(n)
    wv = np.zeros(n)
    pa0 = 0.0
    va0 = 0.0
    aa = 0.0
    for k in range(D):
        pa0 += dp[k] * da[k]
        va0 += dv[k] * da[k]
        aa += da[k] * da[k]
        for j in range(n):
            wp[j] += L[k, j] * da[k]
            wv[j] += L[D + k, j] * da[k]
    a2 = 1.5 * aa
    for r in range(Z.shape[0]):
        tot = 0
        for i in range(m):
            pda = pa0
            vda = va0
            for j in range(n):
                pda += wp[j] * Z[r, i, j]
                vda += wv[j] * Z[r, i, j]
            vv = 0.0
            for k in range(D):
                yv = dv[k]
                for j in range(n):
                    yv += L[D + k, j] * Z[r, i, j]
                v[k] = yv
                vv += yv * yv
            b1 = 3.0 * vda
            tm = min(max(-b1 / (2.0 * a2), 0.0), H) if a2 > 0.0 else (0.0 if b1 >= 0.0 else H)
            if vv + pda + (b1 + a2 * tm) * tm > 0.0:
                continue
            for k in range(D):
                yp = dp[k]
                for j in range(n):
                    yp += L[k, j] * Z[r, i, j]
                p[k] = yp
            inside0, entries = _quartic_crossings(p, v, da, R, H)
            o = (1 if inside0 else 0) + entries - 1
            if o > 0:
                tot += o
        est[r] = tot / m


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


# Ambiguous tube intervals are cut into _PANELS panels for the entry-rate
# integral; the plausible-time search certifies panel by panel.
_PANELS = 2
_RICE_TOL = 1e-3  # quadrature tolerance of the entry-rate integral per panel
_P0_ERR = 1e-9  # error of one instantaneous probability (overlap_probability)
_P0_SKIP = 1e-12  # P(0) is taken as 0 where instant_bound certifies it below this
PLAUSIBLE_RTOL = 1e-6  # the plausible time's bracket width, relative to H


@njit(cache=True, error_model="numpy")
def _panels(leaves, cnt, t_end, pa, pb):
    """Panel ends of the ambiguous intervals before t_end into pa, pb (each
    interval cut into _PANELS equal panels); returns the count."""
    m = 0
    for j in range(cnt):
        a = leaves[j, 0]
        b = min(leaves[j, 1], t_end)
        if not a < b:
            continue
        for q in range(_PANELS):
            pa[m] = a + (b - a) * q / _PANELS
            pb[m] = b if q == _PANELS - 1 else a + (b - a) * (q + 1) / _PANELS
            m += 1
    return m


# Per-pair scratch of the compiled orchestration (float64 array st):
_ST_PMAX = 0  # largest instantaneous probability computed (a lower bound of P(contact))
_ST_DEGENERATE = 1  # 1.0 once S(t) was degenerate at a quadrature node: the Rice values are unusable
_ST_PTOL = 2  # quadrature tolerance of the walk's instantaneous probabilities (0.0: the standard)
_ST_PERR = 3  # stated error of one of them (_P0_ERR at the standard tolerance; >= _P0_ERR)
_ST_SWEEP_DV = 4  # the walk's certificate: < 0 the Rice integral; >= 0 the swept ball (_swept_ball_bound), k sigma_v
_ST_SIZE = 5
# Straight 3-D pairs (line sampling) use the instantaneous probability only in the
# plausible-time walk, where it is compared with the threshold: tolerance
# _WALK_TOL_REL x threshold per piece and level (stated error 8e-7 x threshold,
# far inside the certificate's margins): ~2-3x cheaper on the benchmark's pairs
_WALK_TOL_REL = 1e-7
# 2-D walk: tolerance min(_WALK_TOL_2D_REL x threshold, _WALK_TOL_2D) per piece,
# stated error 4 x that (<= 1e-7 absolute, <= 1e-5 x threshold): far inside the
# certificate's margins (the Rice step's integral + estimate ~1e-3), and the
# walk's answers within 1e-7 of the threshold where the 1e-9 ones were within
# 1e-9 (its tests allow 1e-6).  The splits of the standard tolerance come from
# |K15 - G7| over-estimating K15's error (actual errors ~1e-14): at this
# tolerance the benchmark's walk probabilities take one K15 per piece, ~60
# segment evaluations instead of ~60-120
_WALK_TOL_2D_REL = 2.5e-6
_WALK_TOL_2D = 2.5e-8


@njit(cache=True, error_model="numpy")
def _prob_at(dp, dv, da, R, Sigma, t, st):
    p = instant_probability_tol(dp, dv, da, R, Sigma, t, st[_ST_PTOL])
    if p > st[_ST_PMAX]:
        st[_ST_PMAX] = p
    return p


# The per-pair cache of panel integrals (one row per panel): computed flag,
# value, error estimate; then, when the panel's single K15 or its P31 extension
# was accepted (no split), the number of kept values (15 or 31; 0: none), the
# largest of the nodes' own (arc/cap) error estimates and the values of nu+ at
# the rule's nodes, ascending (the walk's short steps integrate their
# interpolant instead of evaluating nu+ again).
_C_DONE, _C_VALUE, _C_ERR, _C_NODES_OK, _C_INNER_MAX, _C_NODES = 0, 1, 2, 3, 4, 5
CACHE_COLUMNS = _C_NODES + 31


@njit(cache=True, error_model="numpy")
def _rice_short(dp, dv, da, R, Sigma, a, b, pa, pb, j, cache, plo, thr, acc, st):
    """Entry-rate integral over a short interval [a, b] of panel j and its error
    estimate: from the panel's kept nu+ values where they certify the step
    (plo + value + estimate + P's error < thr: no new nu+ evaluation), else by
    the 3-point Gauss rule."""
    nk = int(cache[j, _C_NODES_OK])
    if nk != 0:
        h = 0.5 * (pb[j] - pa[j])
        m = pa[j] + h
        xl = min(max((a - m) / h, -1.0), 1.0)
        xr = min(max((b - m) / h, -1.0), 1.0)
        v, e = subinterval_integral(cache[j, _C_NODES:_C_NODES + nk], xl, xr)
        v = max(v * h, 0.0)  # nu+ >= 0: a negative interpolant integral is rounding or ringing
        # the nodes' own estimates as the adaptive rule of entry_rate_integral
        # counted them before it weighted them: width times the largest
        e = e * h + (b - a) * cache[j, _C_INNER_MAX]
        if plo + v + e + st[_ST_PERR] < thr:
            return v, e
    acc[1] = 0.0
    v, e = entry_rate_gauss3(dp, dv, da, R, Sigma, a, b, _RICE_TOL, acc)
    if acc[1] != 0.0:
        st[_ST_DEGENERATE] = 1.0
    return v, e


@njit(cache=True, error_model="numpy")
def _velocity_sigma(Sigma):
    """Upper bound of sqrt(lambda_max(Svv)) (the factor 1 + 1e-9 covers the
    eigenvalues' rounding, as max_sigma_over)."""
    D = Sigma.shape[0] // 2
    lam, _ = eig_sym(np.ascontiguousarray(Sigma[D:, D:]))
    return math.sqrt(max(lam[D - 1], 0.0) * (1.0 + 1e-9))


@njit(cache=True, error_model="numpy")
def _swept_ball_bound(dp, dv, da, R, Sigma, a, b, st):
    """Upper bound of P(the path touches the ball within [a, b]) >= sup over
    [a, b] of P(|X(t)| <= R), but for the velocity tail TUBE_TAIL that the
    caller adds: a single ball probability, no entry-rate integral.

    With m the midpoint, h the half-width and tau = t - m, X(t) = X(m) +
    Xdot(m) tau + da tau^2 / 2 and Xdot(m) - gd(m) = dv - E[dv] = L_v w
    (L_v L_v^T = Svv, w standard normal of rank <= D), so off the event
    |w| > k (probability P(chi^2_D > k^2) <= TUBE_TAIL) |Xdot(m)| <= |gd(m)| +
    k sqrt(lambda_max(Svv)) = |gd(m)| + st[_ST_SWEEP_DV], and a path within R of
    the origin at some t in [a, b] has |X(m)| <= R' = R + h (|gd(m)| +
    st[_ST_SWEEP_DV]) + |da| h^2 / 2.  Returns P(|X(m)| <= R') (at the walk's
    tolerance: within st[_ST_PERR]); R' is rounded up by 1e-12 relative."""
    D = dp.shape[0]
    m = 0.5 * (a + b)
    h = 0.5 * (b - a)
    speed = 0.0
    acc2 = 0.0
    for i in range(D):
        g = dv[i] + da[i] * m
        speed += g * g
        acc2 += da[i] * da[i]
    reach = R + h * (math.sqrt(speed) + st[_ST_SWEEP_DV]) + 0.5 * math.sqrt(acc2) * h * h
    return instant_probability_tol(dp, dv, da, reach * (1.0 + 1e-12), Sigma, m, st[_ST_PTOL])


# The end game's swept ball: [lo, lo + dt] in this many sub-steps, one ball each
# (the inflation h (|gd| + k sigma_v) shrinks with h)
_ENDGAME_SPLIT = 8


@njit(cache=True, error_model="numpy")
def _swept_ball_split(dp, dv, da, R, Sigma, a, b, st, stop):
    """The largest ``_swept_ball_bound`` over _ENDGAME_SPLIT equal sub-steps of
    [a, b]: an upper bound of sup over [a, b] of P(|X(t)| <= R) (each t lies in a
    sub-step), as that function's is but for TUBE_TAIL.  Returns as soon as one
    sub-step's reaches ``stop`` (the caller's certificate fails anyway)."""
    w = (b - a) / _ENDGAME_SPLIT
    worst = 0.0
    for i in range(_ENDGAME_SPLIT):
        ta = a + i * w
        tb = b if i == _ENDGAME_SPLIT - 1 else a + (i + 1) * w
        worst = max(worst, _swept_ball_bound(dp, dv, da, R, Sigma, ta, tb, st))
        if worst >= stop:
            break
    return worst


@njit(cache=True, error_model="numpy")
def _rice_panel(dp, dv, da, R, Sigma, pa, pb, j, cache, acc, st):
    """Entry-rate integral over panel j and its error estimate, computed once
    per pair (cache row j, see CACHE_COLUMNS).  The same panels as
    ``entry_rate_integral`` over [pa[j], pb[j]]: its whole-interval K15 first
    (values kept), else that K15's Patterson extension P31, else its two halves
    with half the tolerance each, which is where the adaptive rule goes next."""
    if cache[j, _C_DONE] == 0.0:
        acc[1] = 0.0
        f15 = np.empty(15)
        fe = np.empty(15)
        v, e, inner, inner_max = entry_rate_k15(dp, dv, da, R, Sigma, pa[j], pb[j], _RICE_TOL, acc, f15, fe)
        if not (e > _RICE_TOL):  # (a NaN estimate is accepted, as by the adaptive rule)
            cache[j, _C_NODES_OK] = 15.0
            cache[j, _C_INNER_MAX] = inner_max
            cache[j, _C_NODES:_C_NODES + 15] = f15
            e += inner
        else:
            # Patterson's extension first: a K15 fails on a panel much wider than
            # nu+'s peak (one clipped at 0 or H, the peak inside), where |K15 - G7|
            # is ~100x K15's error and P31 settles it with 16 more values
            fnew = np.empty(16)
            v, e, inner, new_max = entry_rate_p31(dp, dv, da, R, Sigma, pa[j], pb[j], _RICE_TOL, acc,
                                                  f15, fe, fnew)
            if not (e > _RICE_TOL):
                cache[j, _C_NODES_OK] = 31.0
                cache[j, _C_INNER_MAX] = max(inner_max, new_max)
                for i in range(15):
                    cache[j, _C_NODES + P31_K15_POS[i]] = f15[i]
                for i in range(16):
                    cache[j, _C_NODES + P31_NEW_POS[i]] = fnew[i]
                e += inner
            else:  # the adaptive rule's next panels: the halves, half the tolerance each
                m = 0.5 * (pa[j] + pb[j])
                v, e = entry_rate_integral(dp, dv, da, R, Sigma, pa[j], m, 0.5 * _RICE_TOL, acc)
                v2, e2 = entry_rate_integral(dp, dv, da, R, Sigma, m, pb[j], 0.5 * _RICE_TOL, acc)
                v += v2
                e += e2
        if acc[1] != 0.0:
            st[_ST_DEGENERATE] = 1.0
        cache[j, _C_DONE] = 1.0
        cache[j, _C_VALUE] = v
        cache[j, _C_ERR] = e
    return cache[j, _C_VALUE], cache[j, _C_ERR]


_SEARCH_STEPS = 64  # certified steps per panel before the conservative exit


@njit(cache=True, error_model="numpy")
def _det_lower(Sigma, ta, tb):
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
                    coef[u + v + w] += (P[0, 0, u] * (P[1, 1, v] * P[2, 2, w] - P[1, 2, v] * P[1, 2, w])
                                        - P[0, 1, u] * (P[0, 1, v] * P[2, 2, w] - P[1, 2, v] * P[0, 2, w])
                                        + P[0, 2, u] * (P[0, 1, v] * P[1, 2, w] - P[1, 1, v] * P[0, 2, w]))
    low = coef[0]
    rk = 1.0
    for k in range(1, 2 * D + 1):
        rk *= r
        low -= abs(coef[k]) * rk
    return low - 1e-12 * M ** D


@njit(cache=True, error_model="numpy")
def instant_bound(dp, dv, da, R, Sigma, ta, tb):
    """A rigorous upper bound of P(|X(t)| <= R) for every t in [ta, tb] (no quadrature).

    With d = (min |g(t)| - R)^+ (box bound, _mean_range) and lam >= lambda_max(S(t))
    (max_sigma_over): every point of the ball is >= d from g(t), so its Mahalanobis
    distance is >= q = d^2 / lam.  Then (i) P <= P(chi^2_D >= q) (X - g = S^(1/2) w,
    |X - g| <= sqrt(lam) |w|), and (ii) P <= vol(ball) * max density on the ball
    <= vol / ((2 pi)^(D/2) sqrt(det_min)) e^(-q/2), det_min a lower bound of
    det S(t) (_det_lower).  Returns min of (i), (ii) and 1.  (ii) is the tight one
    when sigma >> R, (i) in the tails when sigma << distance."""
    D = dp.shape[0]
    lam = max_sigma_over(Sigma, ta, tb) ** 2
    gmin, _ = _mean_range(dp, dv, da, ta, tb)
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
    det = _det_lower(Sigma, ta, tb)
    if det > 0.0:
        if D == 2:
            dens = R * R / (2.0 * math.sqrt(det)) * math.exp(-0.5 * q)
        else:
            dens = (4.0 / 3.0) * math.pi * R ** 3 / ((2.0 * math.pi) ** 1.5 * math.sqrt(det)) * math.exp(-0.5 * q)
        bound = min(bound, dens)
    # rounding of the exp/erfc/sqrt chain (a few ulps) is far inside this factor
    return min(1.0, bound * (1.0 + 1e-9))


_CLEAR_DEPTH = 6  # the analytic certificate's finest piece: 1/64 of a panel


@njit(cache=True, error_model="numpy")
def _clear_prefix(dp, dv, da, R, Sigma, a, b, thr):
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
def _first_crossing(dp, dv, da, R, Sigma, pa, pb, j, a0, p_start, thr, dt, cache, acc, st, panel_free):
    """First t in panel j = [a, b] with P(|X(t)| <= R) >= thr given that P < thr
    is certified on [a, a0] and P(a0) = p_start < thr, or +inf when certified
    absent (also +inf when S(t) turned out degenerate: the caller checks
    st[_ST_DEGENERATE]).

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
    perr = st[_ST_PERR]  # error of one instantaneous probability
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
            if st[_ST_PTOL] > 0.0 and dp.shape[0] == 2:
                # the end game at the standard tolerance: the looser 2-D
                # probabilities' stated error is comparable with the Rice
                # integral over one dt, so the certificate of [lo, lo + dt]
                # would fail on it (a conservative exit a few 1e-7 below thr
                # where the 1e-9 ones bracket the crossing).  P(lo) is
                # recomputed (it only starts the next certificate: the invariant
                # on [a, lo] stands); the rest of the pair's walk keeps the
                # standard tolerance (a cheap 2-D evaluation: 3-D keeps its own)
                st[_ST_PTOL] = 0.0
                st[_ST_PERR] = _P0_ERR
                perr = _P0_ERR
                plo = _prob_at(dp, dv, da, R, Sigma, lo, st)
            c = lo + dt
            pc = _prob_at(dp, dv, da, R, Sigma, c, st)
            if pc >= thr:
                return c
        whole = first and c == b
        first = False
        if pc < 0.0 and not (whole and panel_free):
            pc = _prob_at(dp, dv, da, R, Sigma, c, st)
        certified = False
        if pc < thr:
            if st[_ST_SWEEP_DV] >= 0.0:
                # the swept ball's bound U of sup_[lo, c] P (+ TUBE_TAIL), written
                # as the Rice step's increment over P(lo): the certificate below
                # reads U + TUBE_TAIL + perr < thr
                v = _swept_ball_bound(dp, dv, da, R, Sigma, lo, c, st) - plo
                e = TUBE_TAIL
                width = c - lo
                if endgame and not plo + v + e + perr < thr:
                    # its resolution over [lo, lo + dt] (the ball inflated by
                    # dt / 2 (|gd| + k sigma_v)) is coarser than the Rice
                    # integral's: first the same bound over _ENDGAME_SPLIT
                    # sub-steps (8 balls, ~20 us); then the last attempt before
                    # a conservative exit takes the 3-point Rice rule (3 cap
                    # integrals, ~150 us), so that such exits land within the
                    # Rice certificate's resolution below thr
                    v = _swept_ball_split(dp, dv, da, R, Sigma, lo, c, st, thr - e - perr) - plo
                    if not plo + v + e + perr < thr:
                        v, e = _rice_short(dp, dv, da, R, Sigma, lo, c, pa, pb, j, cache, plo, thr, acc, st)
            elif whole:
                # the panel's own integral (computed once per pair; nu+ >= 0, so
                # over [a, b] it bounds the one over [lo, b])
                v, e = _rice_panel(dp, dv, da, R, Sigma, pa, pb, j, cache, acc, st)
                width = b - pa[j]
            else:
                v, e = _rice_short(dp, dv, da, R, Sigma, lo, c, pa, pb, j, cache, plo, thr, acc, st)
                width = c - lo
            if st[_ST_DEGENERATE] != 0.0:
                return math.inf
            # entry-rate model of the step that the certificate would still pass
            rate = (v + e) / width
            certified = plo + v + e + perr < thr
            if certified:  # no crossing in [lo, c]
                if c == b:
                    return math.inf
                if pc < 0.0:
                    pc = _prob_at(dp, dv, da, R, Sigma, c, st)
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
                    pc = _prob_at(dp, dv, da, R, Sigma, c, st)
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


# _pair_kernel's out: probability, bound, plausible time, then for the RQMC
# fallback (needs_qmc = 1.0) the bracket [lo, hi] the RQMC mean is clipped to
# (1.0: on the contact indicator; 2.0: on the over-count of an accelerating pair,
# _OUT_HI then is the computed upper = P0 + E[entries] and _OUT_ERR its bound;
# 3.0: line sampling of a straight 3-D pair, core.line_sampling)
_OUT_P, _OUT_BOUND, _OUT_TPL, _OUT_QMC, _OUT_LO, _OUT_HI, _OUT_ERR = 0, 1, 2, 3, 4, 5, 6


@njit(cache=True, error_model="numpy")
def _pair_kernel(dp, dv, da, R, Sigma, H, thr, out):
    """Everything of pair_probability but the RQMC fallback (compiled: the
    orchestration makes hundreds of kernel calls per pair, whose dispatch from
    Python cost as much as the quadrature itself)."""
    out[_OUT_QMC] = 0.0
    leaves = np.empty((1 << _TUBE_DEPTH, 2))
    cnt, t_inside = tube_intervals(dp, dv, da, R, Sigma, H, leaves, BROAD_PHASE_SIGMAS)
    if cnt == 0 and thr > TUBE_TAIL and thr <= 1.0 - TUBE_TAIL:
        # the tube alone decides (far pairs, tiny sigma): P <= TUBE_TAIL < thr
        # wherever it is outside, >= 1 - TUBE_TAIL >= thr from t_inside on
        out[_OUT_BOUND] = TUBE_TAIL
        if t_inside <= H:
            out[_OUT_P] = 1.0
            out[_OUT_TPL] = t_inside
        else:
            out[_OUT_P] = 0.0
            out[_OUT_TPL] = math.inf
        return
    st = np.zeros(_ST_SIZE)
    st[_ST_PERR] = _P0_ERR
    st[_ST_SWEEP_DV] = -1.0
    acc = np.zeros(3)  # entry_rate's scratch
    # straight 3-D pairs: the probability by line sampling (finish_row), not by
    # the Rice panels, so the walk does not get them for free; their
    # instantaneous probabilities serve the walk only (looser tolerance)
    sampled = _line_sampled(dp, dv, da, Sigma)
    if sampled:
        st[_ST_PTOL] = max(_WALK_TOL_REL * thr, 1e-10)
        st[_ST_PERR] = BALL_ERR_PER_TOL * st[_ST_PTOL]
        # no Rice panels for the probability: the walk certifies its steps with
        # the swept ball (one ball probability per step instead of ~450 cap
        # integrand points per nu+ value)
        st[_ST_SWEEP_DV] = BROAD_PHASE_SIGMAS * _velocity_sigma(Sigma)
    elif dp.shape[0] == 2:
        # 2-D: the walk's probabilities only meet the threshold (its certificate
        # and comparisons, each with st[_ST_PERR]), so they take a looser
        # tolerance (_WALK_TOL_2D; 4 pieces, one level: stated error 4 x tol,
        # never below the standard one's 1e-9); P(0), which enters the reported
        # probability, stays at the standard tolerance (below)
        st[_ST_PTOL] = max(min(_WALK_TOL_2D_REL * thr, _WALK_TOL_2D), 1e-10)
        st[_ST_PERR] = max(DISC_ERR_PER_TOL * st[_ST_PTOL], _P0_ERR)
    # the largest error of any probability in st[_ST_PMAX] (the walk may switch
    # to the standard tolerance at its end, _first_crossing)
    pmax_err = st[_ST_PERR]
    if sampled and instant_bound(dp, dv, da, R, Sigma, 0.0, 0.0) < thr:
        # P(0) < thr is certified and only the walk would use P(0) (as its start
        # value, computed below if the walk starts at 0)
        p0 = -1.0
    elif sampled:
        p0 = _prob_at(dp, dv, da, R, Sigma, 0.0, st)
    elif instant_bound(dp, dv, da, R, Sigma, 0.0, 0.0) <= _P0_SKIP:
        # P(0) <= 1e-12 is certified without quadrature (bodies that start
        # apart): 0 is within the _P0_ERR = 1e-9 that the bound already states
        # for P(0), and within the walk's st[_ST_PERR] (>= 1e-9) as its start
        p0 = 0.0
    else:
        # P(0) is part of the reported probability (upper = P0 + the Rice
        # integral, with _P0_ERR in the bound): always the standard tolerance
        p0 = instant_probability(dp, dv, da, R, Sigma, 0.0)
        st[_ST_PMAX] = max(st[_ST_PMAX], p0)
    dt = PLAUSIBLE_RTOL * H
    pa = np.empty(_PANELS * cnt + 1)
    pb = np.empty(_PANELS * cnt + 1)
    # the walk's panels end at t_inside; the Rice integral below runs only
    # when t_inside is +inf, where they are the full panels (cache shared)
    npan = _panels(leaves, cnt, t_inside, pa, pb)
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
            a0 = _clear_prefix(dp, dv, da, R, Sigma, pa[j], pb[j], thr)
            if a0 >= pb[j]:
                continue
            p_start = p0 if (a0 == 0.0 and p0 >= 0.0) else _prob_at(dp, dv, da, R, Sigma, a0, st)
            if p_start >= thr:
                tpl = a0
                found = True
                break
            r = _first_crossing(dp, dv, da, R, Sigma, pa, pb, j, a0, p_start, thr, dt, cache, acc, st,
                                t_inside > H and not sampled)
            if st[_ST_DEGENERATE] != 0.0:
                found = True
                break
            if r != math.inf:
                tpl = r
                found = True
                break
        if not found:
            tpl = t_inside  # +inf when the tube never lies inside
    degenerate = st[_ST_DEGENERATE] != 0.0
    if degenerate:
        tpl, pm = plausible_time_grid(dp, dv, da, R, Sigma, H, thr)
    out[_OUT_TPL] = tpl

    if t_inside <= H:
        out[_OUT_P] = 1.0
        out[_OUT_BOUND] = TUBE_TAIL
        return
    if cnt == 0:
        out[_OUT_P] = 0.0
        out[_OUT_BOUND] = TUBE_TAIL
        return
    if sampled:
        # line sampling: unbiased, no tube truncation; clipped below by the
        # largest instantaneous probability seen
        out[_OUT_QMC] = 3.0
        out[_OUT_LO] = st[_ST_PMAX] - pmax_err
        out[_OUT_HI] = 1.0
        return
    total = 0.0
    err = 0.0
    if not degenerate:
        for j in range(npan):
            v, e = _rice_panel(dp, dv, da, R, Sigma, pa, pb, j, cache, acc, st)
            total += v
            err += e
            if st[_ST_DEGENERATE] != 0.0:
                degenerate = True
                break
    upper = p0 + total
    straight = True
    for k in range(da.shape[0]):
        if da[k] != 0.0:
            straight = False
    if not degenerate:
        if straight:
            out[_OUT_P] = min(1.0, max(0.0, upper))
            out[_OUT_BOUND] = err + _P0_ERR + TUBE_TAIL
            return
        # da != 0: a path enters at most twice, so upper = P0 + E[entries]
        # over-counts exactly the re-entries: P = upper - E[O] with the
        # per-path over-count O (overcount_replicates), whose mean the RQMC
        # estimates with far less variance than that of the contact indicator
        # (O is 0 but for the few paths that exit and come back)
        # a tube path crosses the sphere only within the ambiguous intervals (sorted:
        # the tube walk visits [0, H] left to right), so an exit, the maximum
        # of f after it and the re-entry all lie within their hull
        t0, t1 = leaves[0, 0], leaves[cnt - 1, 1]
        if _no_reentry(dp, dv, da, Sigma, t0, t1, BROAD_PHASE_SIGMAS):
            # no path of the tube can come back (O = 0 on it): upper is P but
            # for the tail paths, each off by at most 2 (<= 3 counted, contact
            # 0 or 1), which the 2 TUBE_TAIL of the bound covers
            out[_OUT_P] = min(1.0, max(0.0, upper))
            out[_OUT_BOUND] = err + _P0_ERR + 2 * TUBE_TAIL
            return
        # the bracket [lo, hi] of P without sampling: P >= every instantaneous
        # probability (st[_ST_PMAX], each within pmax_err); P <= upper + its bound;
        # and where a narrower tube (k' sigmas) is certified, O = 0 on it and
        # O <= 2 off it: E[O] <= 2 P(chi^2_2D > k'^2) (_overcount_tail)
        slack = err + _P0_ERR + 2 * TUBE_TAIL
        hi = upper + slack
        lo = max(st[_ST_PMAX] - pmax_err, upper - slack - _overcount_tail(dp, dv, da, Sigma, t0, t1))
        if lo <= hi and 0.5 * (hi - lo) <= BRACKET_HALF_WIDTH + slack:
            # no wider than the tightest bound the RQMC could state (its floor + the
            # same slack): the midpoint, bounded without sampling
            mid = 0.5 * (lo + hi)
            out[_OUT_P] = min(1.0, max(0.0, mid))
            out[_OUT_BOUND] = 0.5 * (hi - lo)
            return
        out[_OUT_QMC] = 2.0
        out[_OUT_LO] = lo
        out[_OUT_HI] = upper
        out[_OUT_ERR] = slack
        return
    out[_OUT_QMC] = 1.0
    out[_OUT_LO] = st[_ST_PMAX] - pmax_err
    out[_OUT_HI] = 1.0 if degenerate else upper + err + _P0_ERR + 2 * TUBE_TAIL


OUT_SIZE = 7

_REENTRY_PIECES = 16  # pieces of the interval for _no_reentry's bounds


_DUAL_LAMBDAS = (1.0, 0.5, 0.25, 0.125, 0.0625)  # multiples of the linear bound's optimum sqrt(Q) / (2 k)


@njit(cache=True, error_model="numpy")
def _no_reentry(dp, dv, da, Sigma, t0, t1, k):
    """True when no path of the k-sigma tube has a local maximum of f = |X|^2 - R^2
    in [t0, t1] (a certificate; False says nothing): with every sphere crossing of
    a tube path inside [t0, t1], none can exit the ball and come back.

    A re-entry needs a local maximum of f inside (0, H), impossible where
    f'' / 2 = |Xdot|^2 + X.da > 0.  With X = g + dX, Xdot = gd + dV (deviations
    linear in z; acceleration is exact),

        f'' / 2 = P(t) + l + |dV|^2,  P(t) = |gd|^2 + g.da = |dv|^2 + dp.da + 3 (dv.da) t + 1.5 |da|^2 t^2,

    l = u(t).(dp_dev, dv_dev), u(t) = (da, 2 dv + 3 t da).  For every lam > 0 and
    |z| <= k: l + |dV|^2 >= l + |dV|^2 + lam (|z|^2 - k^2) >= -lam k^2 - W(t) /
    (4 lam), the last step the minimum over all z of that convex quadratic, with
    (Woodbury) W(t) = u^T Sigma u - r^T (lam I + Svv)^-1 r, r = (Sigma u)_v: a
    quadratic in t.  So f'' / 2 >= P(t) - lam k^2 - W(t) / (4 lam) =: b(t), a
    quadratic whose minimum over each of _REENTRY_PIECES pieces of [t0, t1] is
    exact (vertex or ends), less rounding margins; lam from a few multiples of
    sqrt(u^T Sigma u) / (2 k) at the piece's midpoint (the optimum without the
    |dV|^2 term; any lam > 0 is valid).  It keeps the correlations, the sign of
    g.da and the |dV|^2 that cruder bounds drop: on 6,000 random cases it
    certified every case that (min |gd| - k sigma_v)^2 > (max |g| + k sigma_x) |da|
    (the bound used before) did, and 434 more.  Typical of moving bodies with
    modest accelerations: the over-count RQMC is then not needed."""
    D = dp.shape[0]
    an = 0.0
    for i in range(D):
        an += da[i] * da[i]
    if an == 0.0:
        return True
    n2 = 2 * D
    Sig = np.empty((n2, n2))
    for i in range(n2):
        for j in range(n2):
            Sig[i, j] = 0.5 * (Sigma[i, j] + Sigma[j, i])
    mu, V = eig_sym(np.ascontiguousarray(Sig[D:, D:]))
    u0 = np.zeros(n2)  # coefficients of l on (dp_dev, dv_dev): u0 + t u1
    u1 = np.zeros(n2)
    p0 = 0.0
    p1 = 0.0
    p2 = 0.0
    pscale = 0.0
    smax = 0.0
    for i in range(D):
        u0[i] = da[i]
        u0[D + i] = 2.0 * dv[i]
        u1[D + i] = 3.0 * da[i]
        p0 += dv[i] * dv[i] + dp[i] * da[i]
        p1 += 3.0 * dv[i] * da[i]
        p2 += 1.5 * da[i] * da[i]
        pscale += dv[i] * dv[i] + abs(dp[i] * da[i]) + 3.0 * abs(dv[i] * da[i]) + 1.5 * da[i] * da[i]
    for i in range(n2):
        smax = max(smax, abs(Sig[i, i]))
    su0 = np.zeros(n2)  # Sigma u0, Sigma u1 (loops: numba's @ needs scipy's BLAS)
    su1 = np.zeros(n2)
    for i in range(n2):
        for j in range(n2):
            su0[i] += Sig[i, j] * u0[j]
            su1[i] += Sig[i, j] * u1[j]
    q00 = 0.0  # u^T Sigma u = q00 + 2 t q01 + t^2 q11
    q01 = 0.0
    q11 = 0.0
    for i in range(n2):
        q00 += u0[i] * su0[i]
        q01 += u0[i] * su1[i]
        q11 += u1[i] * su1[i]
    # r = (Sigma u)_v in Svv's eigenbasis: r0 + t r1
    r0 = np.zeros(D)
    r1 = np.zeros(D)
    for a in range(D):
        for i in range(D):
            r0[a] += V[i, a] * su0[D + i]
            r1[a] += V[i, a] * su1[D + i]
    tmax = max(abs(t0), abs(t1), 1.0)
    usz = 0.0
    for i in range(n2):
        usz += abs(u0[i]) + tmax * abs(u1[i])
    # rounding: a few ulps per term of sums bounded by these scales (W <= u^T Sigma u <= 2D smax |u|^2)
    perr = 1e-12 * pscale * tmax * tmax
    werr = 1e-12 * n2 * smax * usz * usz
    for q in range(_REENTRY_PIECES):
        ta = t0 + (t1 - t0) * q / _REENTRY_PIECES
        tb = t1 if q == _REENTRY_PIECES - 1 else t0 + (t1 - t0) * (q + 1) / _REENTRY_PIECES
        tm = 0.5 * (ta + tb)
        qm = max(q00 + tm * (2.0 * q01 + tm * q11), 0.0)
        # (floored where l has ~no variance: lam k^2 <= 1e-9 of P's scale, and
        # 1 / (4 lam) stays finite, multiplying the rounding margin werr)
        lam0 = max(math.sqrt(qm) / (2.0 * k), 1e-9 * pscale / (k * k))
        best = -math.inf
        for c in _DUAL_LAMBDAS:
            lam = lam0 * c
            # W(t) = w0 + 2 t w1 + t^2 w2 = u^T Sigma u - r^T (lam I + Svv)^-1 r
            w0 = q00
            w1 = q01
            w2 = q11
            for a in range(D):
                inv = 1.0 / (lam + max(mu[a], 0.0))
                w0 -= r0[a] * r0[a] * inv
                w1 -= r0[a] * r1[a] * inv
                w2 -= r1[a] * r1[a] * inv
            # f'' / 2 >= b0 + b1 t + b2 t^2 on the piece, minus the rounding margins
            f = 0.25 / lam
            b0 = p0 - lam * k * k - f * w0
            b1 = p1 - 2.0 * f * w1
            b2 = p2 - f * w2
            low = min(b0 + ta * (b1 + ta * b2), b0 + tb * (b1 + tb * b2))
            if b2 > 0.0:
                tv = -b1 / (2.0 * b2)
                if ta < tv < tb:
                    low = min(low, b0 + tv * (b1 + tv * b2))
            low -= perr + f * werr
            best = max(best, low)
            if best > 0.0:
                break
        if not (best > 0.0):
            return False
    return True


# The narrower tubes _overcount_tail tries (sigmas), widest first: 2 P(chi^2_4 > k'^2)
# = 5.8e-7, 1.0e-4, 8.9e-4 in 2-D (chi^2_6: 5.5e-6, 6.8e-4, 5.0e-3); narrower ones
# would cost more than the bracket below can carry
REENTRY_SIGMAS = (6.0, 5.0, 4.5)
# An uncertified accelerating pair is answered by its bracket when the bracket's
# half-width is at most the smallest bound the over-count RQMC can state: U's
# slack plus 3 / (QMC_REPLICATES * QMC_CV_POINTS) = 1.5e-3 (the rule of three at
# its first stage); never a looser answer than the sampling would give
BRACKET_HALF_WIDTH = 3.0 / (QMC_REPLICATES * QMC_CV_POINTS)
_REENTRY_TAILS = np.array([[2.0 * chi2_tail_even(k * k, 2 * D) for k in REENTRY_SIGMAS] for D in (2, 3)])


@njit(cache=True, error_model="numpy")
def _overcount_tail(dp, dv, da, Sigma, t0, t1):
    """An upper bound of E[O], the over-count of an accelerating pair whose tube
    paths cross the sphere only within [t0, t1] (1.0: none found): 2 P(chi^2_2D >
    k'^2) for the widest k' of REENTRY_SIGMAS that ``_no_reentry`` certifies (no
    path of the k'-tube comes back: O = 0 there; O <= 2 on every path)."""
    row = dp.shape[0] - 2
    for j in range(len(REENTRY_SIGMAS)):
        if _no_reentry(dp, dv, da, Sigma, t0, t1, REENTRY_SIGMAS[j]):
            return _REENTRY_TAILS[row, j]
    return 1.0


@njit(cache=True, error_model="numpy")
def _line_sampled(dp, dv, da, Sigma):
    """True for the pairs whose probability is computed by line sampling: 3-D,
    straight (da = 0: the contact set of dp is the capsule), and a non-zero
    conditional standard deviation along the sampling direction."""
    if dp.shape[0] != 3:
        return False
    for k in range(3):
        if da[k] != 0.0:
            return False
    return line_factor(dp, dv, Sigma)[4]


@njit(cache=True, error_model="numpy")
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


@njit(cache=True, error_model="numpy")
def evaluate_uncertain_rows(dp, dv, da, rad, sig, H, thr, out):
    """_pair_kernel on every row (out (n, OUT_SIZE)), serially: on numba's threads the
    node's tail latency suffered (docs/uncertainty.md, "Not guaranteed / weak");
    rows with out[j, _OUT_QMC] != 0 still need ``finish_row``'s sampling."""
    for j in range(dp.shape[0]):
        _pair_kernel(dp[j], dv[j], da[j], rad[j], sig[j], H, thr, out[j])


@njit(cache=True, error_model="numpy")
def line_sampled_probability(dp, dv, Sigma, R, H, Z):
    """(estimate, stated bound) of P(contact within [0, H]) of a straight 3-D pair
    by line sampling with its control variate (core.line_sampling), Z =
    normal_table(5): QMC_LINE_POINTS per replicate first, more (up to
    QMC_POINTS) while the bound exceeds QMC_LINE_TARGET (compiled as one call:
    from Python its five kernels' dispatch cost ~10 us a pair)."""
    G, mu, e, s, _ = line_factor(dp, dv, Sigma)
    f, tbar, a, ctl_mean, ctl_err = cylinder_control(dp, dv, Sigma, e, R, H)
    tot = np.zeros(QMC_REPLICATES)
    ctot = np.zeros(QMC_REPLICATES)
    m0 = 0
    mean = 0.0
    stat = 1.0
    for m in (QMC_LINE_POINTS, 2 * QMC_LINE_POINTS, QMC_POINTS):
        # the first m points of each replicate (the earlier stages' are reused)
        line_replicates(G, mu, e, s, f, tbar, a, R, H, Z, m0, m, tot, ctot)
        m0 = m
        mean, half, beta = controlled_stats(tot / m, ctot / m, ctl_mean)
        # + the deterministic part: each chord's mass within 2 PHI_ERR (the
        # Phi table), the control's mean within ctl_err (its quadrature)
        stat = (max(half, 3.0 / (QMC_REPLICATES * m))
                + 2.0 * PHI_ERR + abs(beta) * (2.0 * PHI_ERR + ctl_err))
        if stat <= QMC_LINE_TARGET:
            break
    return mean, stat


def finish_row(dp, dv, da, R, Sigma, H, out):
    """(probability, bound, plausible time) of one row from _pair_kernel's out,
    running the RQMC fallback when the kernel asked for it."""
    if out[_OUT_QMC] == 0.0:
        return float(out[_OUT_P]), float(out[_OUT_BOUND]), float(out[_OUT_TPL])
    D = dp.shape[0]
    if out[_OUT_QMC] == 2.0:
        # accelerating: P = upper - E[O]; QMC_CV_POINTS per replicate first, all
        # QMC_POINTS when the stated bound would exceed QMC_CV_TARGET
        Z = normal_table(2 * D)
        L = factor(np.ascontiguousarray(Sigma))
        est = np.empty(QMC_REPLICATES)
        for m in (QMC_CV_POINTS, QMC_POINTS):
            overcount_replicates(dp, dv, da, float(R), float(H), L, Z, m, est)
            mean, se = _replicate_stats(est)
            stat = max(QMC_T * se, 3.0 / (QMC_REPLICATES * m))
            if stat <= QMC_CV_TARGET:
                break
        upper = float(out[_OUT_HI])
        p = min(1.0, max(0.0, min(max(upper - mean, float(out[_OUT_LO])), upper)))
        return p, stat + float(out[_OUT_ERR]), float(out[_OUT_TPL])
    if out[_OUT_QMC] == 3.0:
        mean, stat = line_sampled_probability(dp, dv, np.ascontiguousarray(Sigma), float(R), float(H),
                                              normal_table(5))
        p = min(1.0, max(0.0, max(mean, float(out[_OUT_LO]))))
        return p, stat, float(out[_OUT_TPL])
    mean, se = qmc_probability(dp, dv, da, R, Sigma, H, normal_table(2 * D))
    n = QMC_REPLICATES * QMC_POINTS
    p = min(1.0, max(0.0, min(max(mean, float(out[_OUT_LO])), float(out[_OUT_HI]))))
    return p, max(QMC_T * se, 3.0 / n) + TUBE_TAIL, float(out[_OUT_TPL])


def pair_probability(dp, dv, da, R, Sigma, H, thr):
    """(probability, bound, plausible time) of one uncertain pair (relative state).

    See docs/uncertainty.md for the method and why each bound holds."""
    out = np.empty(OUT_SIZE)
    _pair_kernel(dp, dv, da, float(R), Sigma, float(H), float(thr), out)
    return finish_row(dp, dv, da, R, Sigma, H, out)


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
