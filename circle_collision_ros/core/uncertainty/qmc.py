"""Randomized quasi-Monte Carlo on the exact solver and its statistics.

The fallbacks of the per-pair evaluation: scrambled Sobol replicates turned
into standard normals (``normal_table``), the contact indicator through the
exact solver (``qmc_probability``), the over-count of accelerating pairs
(``overcount_counts``, with the quartic's crossings) and line sampling of
straight 3-D pairs with its control variate (``line_sampled_probability``).
The stated bound is a Student t multiple of the replicates' standard error,
never below the rule of three.

See docs/uncertainty.md for the mathematics; each guarantee is stated where
it is made.
"""
from __future__ import annotations

import math
from statistics import NormalDist

import numpy as np
from numba import njit

from circle_collision_ros.core.narrow.batch import ttc_kernel_h
from circle_collision_ros.core.special import eig_sym
from circle_collision_ros.core.uncertainty.line_sampling import (PHI_ERR, cylinder_control,
                                                                 line_factor, line_replicates)
from circle_collision_ros.core.uncertainty.sobol import scrambled_directions, sobol_points

__all__ = ["QMC_REPLICATES", "QMC_POINTS", "QMC_T", "QMC_CV_POINTS", "QMC_CV_TARGET",
           "QMC_LINE_POINTS", "QMC_LINE_TARGET", "QMC_T_CONTROLLED", "normal_table", "factor",
           "replicate_stats", "qmc_probability", "controlled_stats", "quartic_crossings",
           "overcount_counts", "line_sampled", "line_sampled_probability"]


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
# Line sampling of straight 3-D pairs (core.uncertainty.line_sampling): QMC_LINE_POINTS points
# per replicate, then twice as many, then all QMC_POINTS while the stated bound
# exceeds QMC_LINE_TARGET (each stage adds points to the previous one's).  The
# first stage is the fewest points per replicate, a multiple of 32 (Sobol's
# balance in 2^5 blocks), whose 3 / N floor is within the target: 3 / (16 x 96)
# = 1.95e-3; with the control variate the statistical part is then ~10x smaller,
# so the floor decides (a randomised Sobol replicate is unbiased at any length).  The
# control variate's coefficient is fitted to the replicates (regression with one
# covariate: QMC_REPLICATES - 2 = 14 dof, two-sided 99.9 % Student t quantile
# 4.140; mpmath: tests/core/uncertainty/test_uncertainty_line_sampling.py)
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
def replicate_stats(est):
    """(mean, standard error of the mean) of the replicate estimates est (r >= 2):
    compiled: measured faster than numpy's mean and std on 16 values (see
    bench/bench_uncertainty.py)."""
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
        Y += Zf[:, j : j + 1] * L[:, j]
    n = r * m
    zeros = np.zeros((n, D))
    t = np.empty(n)
    ttc_kernel_h(np.ascontiguousarray(dp + Y[:, :D]), np.ascontiguousarray(dv + Y[:, D:]),
                 np.ascontiguousarray(np.broadcast_to(da, (n, D))), np.full(n, R), zeros, zeros,
                 zeros, np.zeros(n), H, t)
    est = (t <= H).reshape(r, m).mean(axis=1)
    return replicate_stats(est)


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
        mean, se = replicate_stats(est)
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
    """(c4, c3, c2, c1, |p|^2) of |p + v t + a t^2 / 2|^2
    = c4 t^4 + c3 t^3 + c2 t^2 + c1 t + |p|^2."""
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
def quartic_crossings(p, v, a, R, H):
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


@njit(cache=True, error_model="numpy", nogil=True)
def overcount_counts(dp, dv, da, R, H, L, Z, start, stop, t0, t1, k2, tot):
    """tot[r] += the over-count O = (1{inside at 0} + #entries in (0, H] - 1)^+ summed
    over points start .. stop - 1 of replicate r of Z (r, M, 2D standard normals), each
    the path (dp, dv) + L z: the amount by which P0 + E[entries] exceeds P(contact) for
    that path (docs/uncertainty.md, "Accelerating").  Integer sums, so a later stage adds
    its points to an earlier one's with the same bits as one pass over all of them.

    [t0, t1]: the hull of the pair's k-sigma tube intervals (k2 = k^2), where every sphere
    crossing of a path with |z|^2 <= k2 lies (core.uncertainty.tube); (0, H, 0) when
    unknown."""
    D = dp.shape[0]
    n = 2 * D
    p = np.empty(D)
    v = np.empty(D)
    # over-counting needs an exit followed by an entry, so a local maximum of
    # f = |X|^2 - R^2 between two crossings: impossible where f''/2 = |Xdot|^2 + X.da =
    # |v|^2 + p.da + 3 t v.da + 1.5 t^2 |da|^2 > 0 (a quadratic in t: its minimum over the
    # interval is checked).  The crossings of a tube path lie in [t0, t1], so the test
    # covers [t0, t1] there and all of [0, H] for any other path.  p.da and v.da are
    # linear in z (weights L^T da, formed once), so the test needs v and two dot
    # products; p, the quartic and its crossings only for the paths that fail it
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
        tot_r = 0
        for i in range(start, stop):
            pda = pa0
            vda = va0
            zz = 0.0
            for j in range(n):
                z = Z[r, i, j]
                pda += wp[j] * z
                vda += wv[j] * z
                zz += z * z
            vv = 0.0
            for k in range(D):
                yv = dv[k]
                for j in range(n):
                    yv += L[D + k, j] * Z[r, i, j]
                v[k] = yv
                vv += yv * yv
            lo, hi = (t0, t1) if zz <= k2 else (0.0, H)
            b1 = 3.0 * vda
            tm = min(max(-b1 / (2.0 * a2), lo), hi) if a2 > 0.0 else (lo if b1 >= 0.0 else hi)
            if vv + pda + (b1 + a2 * tm) * tm > 0.0:
                continue
            for k in range(D):
                yp = dp[k]
                for j in range(n):
                    yp += L[k, j] * Z[r, i, j]
                p[k] = yp
            inside0, entries = quartic_crossings(p, v, da, R, H)
            o = (1 if inside0 else 0) + entries - 1
            if o > 0:
                tot_r += o
        tot[r] += tot_r


@njit(cache=True, error_model="numpy")
def line_sampled(dp, dv, da, Sigma):
    """True for the pairs whose probability is computed by line sampling: 3-D,
    straight (da = 0: the contact set of dp is the capsule), and a non-zero
    conditional standard deviation along the sampling direction."""
    if dp.shape[0] != 3:
        return False
    for k in range(3):
        if da[k] != 0.0:
            return False
    return line_factor(dp, dv, Sigma)[4]


@njit(cache=True, error_model="numpy", nogil=True)
def line_sampled_probability(dp, dv, Sigma, R, H, Z):
    """(estimate, stated bound) of P(contact within [0, H]) of a straight 3-D pair
    by line sampling with its control variate (core.uncertainty.line_sampling), Z =
    normal_table(5): QMC_LINE_POINTS per replicate first, more (up to
    QMC_POINTS) while the bound exceeds QMC_LINE_TARGET (compiled as one call:
    measured faster than dispatching its five kernels from Python)."""
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
        stat = (
            max(half, 3.0 / (QMC_REPLICATES * m))
            + 2.0 * PHI_ERR
            + abs(beta) * (2.0 * PHI_ERR + ctl_err)
        )
        if stat <= QMC_LINE_TARGET:
            break
    return mean, stat
