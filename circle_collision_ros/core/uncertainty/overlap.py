"""Instantaneous overlap probability P(|X| <= R) for a Gaussian X in 2-D or 3-D.

Method (docs/uncertainty.md has the derivation and the measurements).  In the
eigenbasis of the covariance S the components y_i of X are independent,
y_i ~ N(m_i, s_i^2) with s_1 <= s_2 (<= s_3).  First Ruben's chi-square
mixture (``ruben_probability``: a rigorous bracket, the cheapest) where it closes
within a few hundred terms; otherwise, and as the inner level of the 3-D
quadrature, the probability is a 1-D integral over the *narrowest* component,

    P = int phi(u) F(w(x)) du,   x = m_1 + s_1 u,   w(x) = sqrt(R^2 - x^2),

with F(w) = P(|y_2| <= w) in 2-D (a difference of erfc values) and F(w) = the
2-D disc probability of (y_2, y_3) with radius w in 3-D (the same integral
one level down).  Choices, each for a reason:

* u in [-9, 9] only: the mass outside is 2 Phi(-9) = 2.3e-19 per level.
* integrating over the narrowest direction keeps the integrand a smooth bump
  of width ~1 in u (the other factor varies on the scale s_2 >= s_1);
* w is formed as sqrt((R - x)(R + x)) with R - m_1 and R + m_1 computed once,
  so sigma << R loses no digits; where the window reaches the disc's edge
  x = +-R, a piece of at most one sigma next to the edge uses the
  substitution u = u_end -+ v^2, which removes the sqrt singularity of w;
* the window is split at u = 0 (the density's peak) so every panel of the
  adaptive Gauss-Kronrod rule sees the peak at an end.

Quadrature error: truncation 2.3e-19 per level plus the quadrature's estimates
(|K15 - G7|, or |P31 - K15| on a panel extended to Patterson's rule), held
below ``TOL`` = 1e-10 per level (they over-estimate the error of the accepted
rule by orders of magnitude on these smooth integrands);
tests/core/uncertainty/test_uncertainty_overlap.py checks
1e-9 absolute against mpmath on random cases (anisotropic, singular,
sigma << R, sigma >> R, mean far outside).

Degenerate covariances: eigenvalues are clamped at 0 (rounding can make them
slightly negative); a zero s_i makes that component exact (no integral).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from circle_collision_ros.core.special import eig_sym, unit_across
from circle_collision_ros.core.uncertainty.quadrature import make_adaptive

__all__ = ["overlap_probability", "overlap_probability_2d", "overlap_probability_tol",
           "interval_mass", "disc_probability", "disc_probability_tol", "ball_probability",
           "ball_probability_tol", "WINDOW_SIGMAS", "BALL_ERR_PER_TOL", "DISC_ERR_PER_TOL",
           "overlap_probability_2d_tol", "ruben_probability", "RUBEN_MAX_TERMS_2D",
           "RUBEN_MAX_TERMS_3D", "RUBEN_ROUNDING", "TOL", "ball_gauss_hermite", "narrow3"]

WINDOW_SIGMAS = 9.0  # integration window [-9, 9] sigma of each integrated component
TOL = 1e-10  # quadrature tolerance per 1-D integral (absolute, on a probability)
# a 3-D probability at tolerance tol per piece is within BALL_ERR_PER_TOL * tol (by the
# estimates): 4 pieces per level, two levels; at TOL: 8e-10 <= 1e-9
BALL_ERR_PER_TOL = 8.0
# a 2-D probability at tolerance tol per piece is within DISC_ERR_PER_TOL * tol (by the
# estimates; a dropped edge piece counts its whole mass, <= tol): 4 pieces, one level
DISC_ERR_PER_TOL = 4.0
_RS2 = 1.0 / math.sqrt(2.0)
_RS2PI = 1.0 / math.sqrt(2.0 * math.pi)


@njit(cache=True, error_model="numpy")
def interval_mass(lo, hi, m, s):
    """P(lo <= Y <= hi) for Y ~ N(m, s^2), s > 0 (lo <= hi), without
    cancellation in either tail."""
    a = (lo - m) / s
    b = (hi - m) / s
    if a >= 0.0:
        return 0.5 * (math.erfc(a * _RS2) - math.erfc(b * _RS2))
    if b <= 0.0:
        return 0.5 * (math.erfc(-b * _RS2) - math.erfc(-a * _RS2))
    return 1.0 - 0.5 * (math.erfc(-a * _RS2) + math.erfc(b * _RS2))


# ---- Ruben's chi-square mixture: the fast path ------------------------------
# For y_i ~ N(m_i, s_i^2) independent, s_1 <= s_i, and beta = s_1^2, Ruben
# (1962) writes Q = sum y_i^2 as beta times a chi-square of n + 2K degrees of
# freedom with a random K >= 0: P(Q <= R^2) = sum_k a_k F_{n+2k}(R^2 / beta).
# With g_i = 1 - beta / s_i^2 in [0, 1) and b_i = m_i / s_i, the weights' pgf is
#     G(z) = prod_i (1 - g_i)^(1/2) (1 - g_i z)^(-1/2) exp(-b_i^2 / 2 (1 - z) / (1 - g_i z)),
# (match the moment generating functions), whose power series has nonnegative
# coefficients summing to G(1) = 1: a probability mixture.  Hence after K terms
#     S_K <= P <= S_K + (1 - A_K) F_{n+2K}(x),   A_K = a_0 + ... + a_{K-1},
# because every F is in [0, 1] and F_{n+2k} falls with k: a *rigorous* bracket
# (no estimate), closed once x / 2 is passed (F -> 0) or the weights are used up
# (A -> 1).  S_K is returned, with the bracket's width as its error: a lower
# estimate, so a tiny P never comes out above an analytic upper bound of it.
# G' = G h with h(z) = sum_k h_k z^k gives the weights by
#     (k + 1) a_{k+1} = sum_{r <= k} a_r h_{k-r},
#     h_k = sum_i g_i^(k+1) / 2 + b_i^2 (1 - g_i) (k + 1) g_i^k / 2:
# sums and products of nonnegative numbers only, so each a_k carries a relative
# rounding error of a few k ulps (no cancellation).  F_v(x) = sum_{j >= 0}
# T_{v+2j} with T_v = (x/2)^(v/2) e^(-x/2) / Gamma(v/2 + 1), T_{v+2} = T_v x / (v + 2)
# (the lower incomplete gamma's series): the stopping rule uses F from
# F_1 = erf(sqrt(x / 2)) or F_2 = -expm1(-x / 2) downwards by F_{v+2} = F_v - T_v
# (absolute rounding ~k ulps, enough to decide); the sum S_K recomputes them
# upwards from the last one, F_v = F_{v+2} + T_v (positive terms: relatively
# accurate even where P ~ 1e-15), the last one by its series where that
# converges fast.  RUBEN_ROUNDING covers the rest (measured ~1e-15:
# test_ruben_mixture_rounding_is_far_below_its_allowance).
# Cost: ~K^2 / 2 multiply-adds, K ~ x / 2 + a few sqrt(x) or the weights'
# spread; the quadrature below does ~60 (2-D) to ~4,000 (3-D) erfc evaluations.
# It is tried first and gives way to the quadrature when it would need more
# than max_terms terms (sigma << R: x huge; very unequal s_i: g_i -> 1, a slow
# geometric tail; means far out in sigmas: a far-off Poisson bulk).
RUBEN_MAX_TERMS_2D = 64
RUBEN_MAX_TERMS_3D = 256
RUBEN_ROUNDING = 1e-12
_SQRT_2_OVER_PI = math.sqrt(2.0 / math.pi)


@njit(cache=True, error_model="numpy")
def ruben_probability(R, m1, s1, m2, s2, m3, s3, tol, max_terms):
    """(P(y1^2 + y2^2 (+ y3^2) <= R^2), error) by Ruben's mixture, 0 < s1 <= s2 (<= s3);
    s3 < 0 means 2-D.  The value is the bracket's lower end (never above P but
    for rounding), the error its width (<= tol) plus RUBEN_ROUNDING: a rigorous
    bound.  (nan, -1.0) when max_terms terms would not close the bracket to tol
    (the caller integrates instead)."""
    three = s3 >= 0.0
    x = (R / s1) * (R / s1)
    b1 = m1 / s1
    b2 = m2 / s2
    q2 = (s1 / s2) * (s1 / s2)  # 1 - g2 = beta / s2^2
    g2 = (s2 - s1) * (s2 + s1) / (s2 * s2)  # no cancellation when s2 ~ s1
    c1 = 0.5 * b1 * b1
    c2 = 0.5 * b2 * b2 * q2
    half_delta = 0.5 * (b1 * b1 + b2 * b2)
    log_a0 = 0.5 * math.log(q2)
    # E[K] of the weights: sum_i (1 + b_i^2) / (2 q_i) - n / 2 (q_1 = 1)
    mean_k = 0.5 * (1.0 + b1 * b1) + 0.5 * (1.0 + b2 * b2) / q2 - 1.0
    q3 = 1.0
    g3 = 0.0
    c3 = 0.0
    if three:
        b3 = m3 / s3
        q3 = (s1 / s3) * (s1 / s3)
        g3 = (s3 - s1) * (s3 + s1) / (s3 * s3)
        c3 = 0.5 * b3 * b3 * q3
        half_delta += 0.5 * b3 * b3
        log_a0 += 0.5 * math.log(q3)
        mean_k += 0.5 * (1.0 + b3 * b3) / q3 - 0.5
    # the bracket closes near min(x / 2, the weights' bulk) at the earliest: give
    # way at once when that lies beyond half the budget (no wasted terms)
    if not (min(0.5 * x, mean_k) <= 0.5 * max_terms) or not (log_a0 - half_delta > -700.0):
        return math.nan, -1.0
    if three:
        T = _SQRT_2_OVER_PI * math.sqrt(x) * math.exp(-0.5 * x)  # T_1
        F = math.erf(math.sqrt(0.5 * x)) - T  # F_3
        T *= x / 3.0
        v = 3.0
    else:
        F = -math.expm1(-0.5 * x)  # F_2
        T = 0.5 * x * math.exp(-0.5 * x)
        v = 2.0
    a = np.empty(max_terms)
    h = np.empty(max_terms)
    tk = np.empty(max_terms)  # T_{n+2k}
    a[0] = math.exp(log_a0 - half_delta)
    used = 0.0
    gk2 = 1.0  # g2^k
    gk3 = 1.0
    for k in range(max_terms):
        if k > 0:
            acc = 0.0
            for r in range(k):
                acc += a[r] * h[k - 1 - r]
            a[k] = acc / k
        h[k] = (
            0.5 * (gk2 * g2 + gk3 * g3) + (k + 1) * (c2 * gk2 + c3 * gk3) + (c1 if k == 0 else 0.0)
        )
        gk2 *= g2
        gk3 *= g3
        used += a[k]
        tk[k] = T
        F = max(F - T, 0.0)  # F_{v+2}, v = n + 2k
        T *= x / (v + 2.0)
        v += 2.0
        tail = max(1.0 - used, 0.0) * F
        if tail <= tol:
            if x < 0.75 * (v + 2.0):
                # F_v by its series (ratio <= 0.75 per term: <= ~130 terms)
                F = 0.0
                w = v
                for _ in range(400):
                    F += T
                    w += 2.0
                    T *= x / w
                    if not (T > 1e-17 * F):
                        break
            total = 0.0
            for j in range(k, -1, -1):
                F += tk[j]  # F_{n+2j}
                total += a[j] * min(F, 1.0)
            return min(1.0, total), tail + RUBEN_ROUNDING
    return math.nan, -1.0


# ---- the narrow-direction integral, shared by 2-D and 3-D -------------------
# prm = (kind, R, ehi0, elo0, s1, uend, m2, s2, m3, s3, tol)
#   x = m1 + s1 u; R - x = ehi0 - s1 u; R + x = elo0 + s1 u
#   kind 0: plain u; kind 1: u = uend - v^2 (upper end at x = R);
#   kind 2: u = uend + v^2 (lower end at x = -R)
# inner(w, prm): the factor F(w) -- one chain of functions per dimension
# (numba compiles no recursion through first-class functions).


def _make_narrow(inner):
    """The narrow-direction integral with inner factor ``inner`` (an njit fn)."""

    @njit(cache=True, error_model="numpy")
    def integrand(v, prm):
        kind = prm[0]
        s1 = prm[4]
        if kind == 0.0:
            u = v
            jac = 1.0
            ehi = prm[2] - s1 * u
            elo = prm[3] + s1 * u
        elif kind == 1.0:
            u = prm[5] - v * v
            jac = 2.0 * v
            ehi = s1 * v * v
            elo = prm[3] + s1 * u
        else:
            u = prm[5] + v * v
            jac = 2.0 * v
            ehi = prm[2] - s1 * u
            elo = s1 * v * v
        e = ehi * elo
        if not (e > 0.0):
            return 0.0
        return jac * _RS2PI * math.exp(-0.5 * u * u) * inner(math.sqrt(e), prm)

    adaptive = make_adaptive(integrand)

    @njit(cache=True, error_model="numpy")
    def piece(R, ehi0, elo0, s1, ua, ub, lo_edge, hi_edge, m2, s2, m3, s3, tol):
        """(value, err) over u in [ua, ub]; hi_edge: ub is x = R, lo_edge: ua
        is x = -R (never both: the caller splits the window)."""
        if not (ub > ua):
            return 0.0, 0.0
        if hi_edge:  # u = ub - v^2, v in [0, sqrt(ub - ua)]
            prm = (1.0, R, ehi0, elo0, s1, ub, m2, s2, m3, s3, tol)
            return adaptive(prm, 0.0, math.sqrt(ub - ua), tol)
        if lo_edge:
            prm = (2.0, R, ehi0, elo0, s1, ua, m2, s2, m3, s3, tol)
            return adaptive(prm, 0.0, math.sqrt(ub - ua), tol)
        prm = (0.0, R, ehi0, elo0, s1, 0.0, m2, s2, m3, s3, tol)
        return adaptive(prm, ua, ub, tol)

    @njit(cache=True, error_model="numpy")
    def narrow(R, m1, s1, m2, s2, m3, s3, tol):
        """(value, err): integral over the narrow component y1 ~ N(m1, s1^2), s1 > 0,
        each piece to ``tol`` (the inner factor gets the same tolerance)."""
        ehi0 = R - m1
        elo0 = R + m1
        ua = -WINDOW_SIGMAS
        ub = WINDOW_SIGMAS
        lo_edge = False
        hi_edge = False
        if ehi0 / s1 <= ub:  # the window reaches x = R
            ub = ehi0 / s1
            hi_edge = True
        if -elo0 / s1 >= ua:  # ... and/or x = -R
            ua = -elo0 / s1
            lo_edge = True
        if not (ub > ua):
            return 0.0, 0.0
        if s3 >= 0.0 and tol > TOL and 9.0 * s2 * s2 >= R * s1:
            # the 3-D outer level at a looser tolerance than the proven TOL (the
            # plausible-time walk's): here the inner factor F(w(x)) = G(R^2 - x^2)
            # is smooth up to the edges (a disc probability is a smooth function
            # of w^2: no sqrt singularity); its one sharp feature, G's rise over
            # w <~ 3 s2, i.e. x within ~4.5 s2^2 / R of an edge, is at least half
            # a sigma of u wide when 9 s2^2 >= R s1, which the plain rule
            # resolves: no substitution pieces (half the inner evaluations)
            lo_edge = False
            hi_edge = False
        c = 0.0 if (ua < 0.0 < ub) else 0.5 * (ua + ub)
        # the substitution only on a short piece at an edge (at most 1 sigma):
        # it removes the sqrt singularity there, while the density's bump
        # stays in plain u where it is smooth
        ca = ua + min(1.0, 0.5 * (c - ua)) if lo_edge else ua
        cb = ub - min(1.0, 0.5 * (ub - c)) if hi_edge else ub
        # 2-D at a looser tolerance than the proven TOL (the plausible-time
        # walk's): an edge piece whose whole density mass is <= tol is not
        # integrated: value 0, error that mass (the integrand is phi(u) F, 0 <= F
        # <= 1), so the piece still stays within tol and DISC_ERR_PER_TOL holds.
        # The neighbouring plain piece ends a sigma (or half the way to the
        # peak) short of the edge, where the sqrt singularity is, so it stays
        # smooth.  Typical of the walk: means a few sigma outside the disc,
        # whose far edge lies >= 5 sigma away (one K15 of 4 saved)
        drop = s3 < 0.0 and tol > TOL
        mass0 = interval_mass(ua, ca, 0.0, 1.0) if (drop and lo_edge) else math.inf
        if mass0 <= tol:
            v0, e0 = 0.0, mass0
        else:
            v0, e0 = piece(R, ehi0, elo0, s1, ua, ca, lo_edge, False, m2, s2, m3, s3, tol)
        v1, e1 = piece(R, ehi0, elo0, s1, ca, c, False, False, m2, s2, m3, s3, tol)
        v2, e2 = piece(R, ehi0, elo0, s1, c, cb, False, False, m2, s2, m3, s3, tol)
        mass3 = interval_mass(cb, ub, 0.0, 1.0) if (drop and hi_edge) else math.inf
        if mass3 <= tol:
            v3, e3 = 0.0, mass3
        else:
            v3, e3 = piece(R, ehi0, elo0, s1, cb, ub, False, hi_edge, m2, s2, m3, s3, tol)
        return (v0 + v1) + (v2 + v3), (e0 + e1) + (e2 + e3)

    return narrow


@njit(cache=True, error_model="numpy")
def _segment_factor(w, prm):
    """2-D inner factor: P(|y2| <= w)."""
    return interval_mass(-w, w, prm[6], prm[7])


_narrow2 = _make_narrow(_segment_factor)


@njit(cache=True, error_model="numpy")
def disc_probability(R, m1, s1, m2, s2):
    """P(y1^2 + y2^2 <= R^2) for independent y_i ~ N(m_i, s_i^2), s_i >= 0."""
    return disc_probability_tol(R, m1, s1, m2, s2, TOL)


@njit(cache=True, error_model="numpy")
def disc_probability_tol(R, m1, s1, m2, s2, tol):
    """disc_probability with the tolerance ``tol`` per piece (Ruben's mixture within
    tol + RUBEN_ROUNDING where it closes in RUBEN_MAX_TERMS_2D terms, else the
    quadrature)."""
    return _disc(R, m1, s1, m2, s2, tol, RUBEN_MAX_TERMS_2D)


@njit(cache=True, error_model="numpy")
def _disc(R, m1, s1, m2, s2, tol, max_terms):
    """disc_probability_tol, Ruben's mixture tried with max_terms terms (0: the
    quadrature only)."""
    if s1 > s2:
        m1, s1, m2, s2 = m2, s2, m1, s1
    if not (R > 0.0):
        return 1.0 if (R == 0.0 and s2 == 0.0 and m1 == 0.0 and m2 == 0.0) else 0.0
    if s2 == 0.0:
        return 1.0 if m1 * m1 + m2 * m2 <= R * R else 0.0
    if s1 == 0.0:
        e = (R - m1) * (R + m1)
        if not (e > 0.0):
            return 0.0
        w = math.sqrt(e)
        return interval_mass(-w, w, m2, s2)
    if max_terms > 0:
        v, err = ruben_probability(R, m1, s1, m2, s2, 0.0, -1.0, tol, max_terms)
        if err >= 0.0:
            return v
    v, _ = _narrow2(R, m1, s1, m2, s2, 0.0, -1.0, tol)
    return min(1.0, max(0.0, v))


@njit(cache=True, error_model="numpy")
def _disc_factor(w, prm):
    """3-D inner factor: the disc probability of (y2, y3) with radius w (by the
    quadrature only: a smooth function of w for the outer rule's error estimate)."""
    return _disc(w, prm[6], prm[7], prm[8], prm[9], prm[10], 0)


narrow3 = _make_narrow(_disc_factor)


# ---- narrow balls: the chord along the mean's direction, Gauss-Hermite across ----
# Where Ruben's mixture needs too many terms because sigma << R (x = R^2 / s1^2
# huge), the ball is nearly flat across the Gaussian: with u = m / |m| and y =
# y_u u + y_perp, y_u given y_perp is Gaussian with a constant conditional
# standard deviation sc and a mean linear in y_perp, and the ball's chord along u
# at y_perp is |y_u| <= sqrt(R^2 - |y_perp|^2): a Phi-difference, analytic in the
# whitened y_perp while |y_perp| stays well inside R.  So P = E[chord mass] is a
# 2-D Gauss-Hermite integral of an analytic function (tensor rules of 12 and 20
# nodes per axis; the 20-point value, |GH20 - GH12| its error estimate, accepted
# only within the caller's tolerance, else the quadrature below runs).  Applies
# when s3 <= R / _GH_NARROW: the rule's outermost nodes (7.62 sd) stay within
# 0.95 R of the axis, short of the chord's branch point at R.  Measured far
# faster than the nested quadrature (see bench/bench_uncertainty.py).
_GH12_X, _GH12_W = np.polynomial.hermite_e.hermegauss(12)
_GH12_W = _GH12_W / _GH12_W.sum()
_GH20_X, _GH20_W = np.polynomial.hermite_e.hermegauss(20)
_GH20_W = _GH20_W / _GH20_W.sum()
_GH_NARROW = 8.0
_GH_STEEP = 2.0


@njit(cache=True, error_model="numpy")
def _chord_rule(R, mn, l11, l21, l22, b1, b2, sc, X, W):
    """E[P(|y_u| <= sqrt(R^2 - |y_perp|^2))] by the tensor Gauss-Hermite rule (X, W)
    over the whitened y_perp = (l11 z1, l21 z1 + l22 z2), y_u ~ N(mn + b1 z1 + b2 z2, sc^2),
    sc > 0 (the caller's steepness guard)."""
    tot = 0.0
    for i in range(X.shape[0]):
        z1 = X[i]
        y1 = l11 * z1
        row = 0.0
        for j in range(X.shape[0]):
            z2 = X[j]
            y2 = l21 * z1 + l22 * z2
            h = math.sqrt(max(R * R - y1 * y1 - y2 * y2, 0.0))
            row += W[j] * interval_mass(-h, h, mn + b1 * z1 + b2 * z2, sc)
        tot += W[i] * row
    return tot


@njit(cache=True, error_model="numpy")
def ball_gauss_hermite(R, m1, s1, m2, s2, m3, s3):
    """(P(|y| <= R), error estimate) for independent y_i ~ N(m_i, s_i^2), s1 <= s2 <= s3
    <= R / _GH_NARROW, by the chord rule above; (nan, -1.0) when s3 is wider."""
    if not (s3 * _GH_NARROW <= R):
        return math.nan, -1.0
    mn = math.sqrt(m1 * m1 + m2 * m2 + m3 * m3)
    u0, u1, u2 = 0.0, 0.0, 1.0
    if mn > 0.0:
        u0, u1, u2 = m1 / mn, m2 / mn, m3 / mn
    # v1 across u, v2 = u x v1: (u, v1, v2) orthonormal
    v10, v11, v12 = unit_across(u0, u1, u2)
    v20 = u1 * v12 - u2 * v11
    v21 = u2 * v10 - u0 * v12
    v22 = u0 * v11 - u1 * v10
    q0, q1, q2 = s1 * s1, s2 * s2, s3 * s3
    # the covariance in the frame (u, v1, v2) (diagonal Sigma in the eigenbasis)
    cuu = q0 * u0 * u0 + q1 * u1 * u1 + q2 * u2 * u2
    cu1 = q0 * u0 * v10 + q1 * u1 * v11 + q2 * u2 * v12
    cu2 = q0 * u0 * v20 + q1 * u1 * v21 + q2 * u2 * v22
    c11 = q0 * v10 * v10 + q1 * v11 * v11 + q2 * v12 * v12
    c12 = q0 * v10 * v20 + q1 * v11 * v21 + q2 * v12 * v22
    c22 = q0 * v20 * v20 + q1 * v21 * v21 + q2 * v22 * v22
    # y_perp = L z (Cholesky of its 2x2 covariance, mean 0: u is the mean's direction);
    # y_u given z: mean mn + b.z, b = L^-1 C_perp,u, variance cuu - |b|^2
    l11 = math.sqrt(c11)
    if not (l11 > 0.0):
        return math.nan, -1.0
    l21 = c12 / l11
    l22 = math.sqrt(max(c22 - l21 * l21, 0.0))
    b1 = cu1 / l11
    b2 = (cu2 - l21 * b1) / l22 if l22 > 0.0 else 0.0
    sc = math.sqrt(max(cuu - b1 * b1 - b2 * b2, 0.0))
    # the integrand Phi((+-h(z) - mu(z)) / sc) must vary on the nodes' scale in z:
    # its slope |b| / sc and its curvature ~ s3^2 / (R sc) (h = R - |y_perp|^2 / 2R
    # + ...) at most _GH_STEEP.  A steeper one (the conditional deviation small
    # against the spread of its mean: y_u nearly a function of y_perp) is a near
    # step in z, where both rules can agree on a wrong value (symmetric nodes
    # about a step at the centre both give 1/2)
    if not (math.sqrt(b1 * b1 + b2 * b2) <= _GH_STEEP * sc and s3 * s3 <= _GH_STEEP * R * sc):
        return math.nan, -1.0
    coarse = _chord_rule(R, mn, l11, l21, l22, b1, b2, sc, _GH12_X, _GH12_W)
    fine = _chord_rule(R, mn, l11, l21, l22, b1, b2, sc, _GH20_X, _GH20_W)
    return min(1.0, max(0.0, fine)), abs(fine - coarse)


@njit(cache=True, error_model="numpy")
def ball_probability(R, m1, s1, m2, s2, m3, s3):
    """P(|y| <= R) for independent y_i ~ N(m_i, s_i^2), s_i >= 0 (3-D)."""
    return ball_probability_tol(R, m1, s1, m2, s2, m3, s3, TOL)


@njit(cache=True, error_model="numpy")
def ball_probability_tol(R, m1, s1, m2, s2, m3, s3, tol):
    """ball_probability with the tolerance ``tol`` per piece and level: Ruben's mixture
    (within tol + RUBEN_ROUNDING) where it closes in RUBEN_MAX_TERMS_3D terms, else
    the narrow balls' Gauss-Hermite chord rule where its estimate is within tol, else
    the quadrature; the stated error is <= BALL_ERR_PER_TOL * tol either way (the
    quadrature's: 4 pieces per level, each within tol, the inner level's errors
    weighted by a density of total mass <= 1)."""
    # sort so that s1 <= s2 <= s3
    if s1 > s2:
        m1, s1, m2, s2 = m2, s2, m1, s1
    if s2 > s3:
        m2, s2, m3, s3 = m3, s3, m2, s2
    if s1 > s2:
        m1, s1, m2, s2 = m2, s2, m1, s1
    if not (R > 0.0):
        return 1.0 if (R == 0.0 and s3 == 0.0 and m1 == 0.0 and m2 == 0.0 and m3 == 0.0) else 0.0
    if s1 == 0.0:
        e = (R - m1) * (R + m1)
        if not (e > 0.0):
            return 0.0
        return disc_probability_tol(math.sqrt(e), m2, s2, m3, s3, tol)
    v, err = ruben_probability(R, m1, s1, m2, s2, m3, s3, tol, RUBEN_MAX_TERMS_3D)
    if err >= 0.0:
        return v
    v, err = ball_gauss_hermite(R, m1, s1, m2, s2, m3, s3)
    if 0.0 <= err <= tol:
        return v
    v, _ = narrow3(R, m1, s1, m2, s2, m3, s3, tol)
    return min(1.0, max(0.0, v))


@njit(cache=True, error_model="numpy")
def overlap_probability_2d(g0, g1, s00, s01, s11, R):
    """P(|X| <= R) for X ~ N((g0, g1), [[s00, s01], [s01, s11]]) (PSD): overlap_probability
    in scalars (no temporaries: the plausible-time search calls it per step)."""
    return overlap_probability_2d_tol(g0, g1, s00, s01, s11, R, TOL)


@njit(cache=True, error_model="numpy")
def overlap_probability_2d_tol(g0, g1, s00, s01, s11, R, tol):
    """overlap_probability_2d with the quadrature tolerance ``tol`` per piece (stated
    error <= DISC_ERR_PER_TOL * tol).  The eigenbasis is eig_sym's single Jacobi
    rotation (Rutishauser's form: the eigenvalues s00 - t s01, s11 + t s01 lose no
    digits to cancellation)."""
    if s01 == 0.0:
        c = 1.0
        sn = 0.0
        l0 = s00
        l1 = s11
    else:
        theta = (s11 - s00) / (2.0 * s01)
        t = (1.0 if theta >= 0.0 else -1.0) / (abs(theta) + math.sqrt(theta * theta + 1.0))
        c = 1.0 / math.sqrt(t * t + 1.0)
        sn = t * c
        l0 = s00 - t * s01
        l1 = s11 + t * s01
    # eigenvectors (c, -sn) for l0 and (sn, c) for l1; clamp rounding below 0
    m0 = c * g0 - sn * g1
    m1 = sn * g0 + c * g1
    return disc_probability_tol(R, m0, math.sqrt(max(l0, 0.0)), m1, math.sqrt(max(l1, 0.0)), tol)


@njit(cache=True, error_model="numpy")
def overlap_probability(mean, S, R):
    """P(|X| <= R) for X ~ N(mean, S) in 2-D or 3-D (mean (D,), S (D, D) PSD).

    1e-9 absolute (tests/core/uncertainty/test_uncertainty_overlap.py)."""
    return overlap_probability_tol(mean, S, R, TOL)


@njit(cache=True, error_model="numpy")
def overlap_probability_tol(mean, S, R, tol):
    """overlap_probability with the quadrature tolerance ``tol`` per piece and level
    (stated error <= DISC_ERR_PER_TOL * tol in 2-D, BALL_ERR_PER_TOL * tol in 3-D)."""
    D = mean.shape[0]
    if D == 2:
        return overlap_probability_2d_tol(
            mean[0], mean[1], S[0, 0], 0.5 * (S[0, 1] + S[1, 0]), S[1, 1], R, tol
        )
    lam, Q = eig_sym(S)
    mu = np.zeros(D)
    for j in range(D):
        for k in range(D):
            mu[j] += Q[k, j] * mean[k]
    return ball_probability_tol(
        R, mu[0], math.sqrt(lam[0]), mu[1], math.sqrt(lam[1]), mu[2], math.sqrt(lam[2]), tol
    )
