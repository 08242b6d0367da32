"""An upper bound on P(contact within [0, H]) from one direction: the projection screen.

Contact means |X(t)| <= R for some t in [0, H]; for any unit vector u that implies
Y(t) = u.X(t) <= R.  Y is a scalar process of two Gaussians and an exact term,

    Y(t) = alpha + beta t + c t^2,   alpha = u.dp, beta = u.dv, c = u.da / 2,

and a path of the k-sigma tube (|z| <= k of the whitened (dp, dv), core.uncertainty.tube)
touches the ball only within the tube's ambiguous intervals, whose hull is [t0, t1].  So with
m(beta) = min over t in [t0, t1] of (beta t + c t^2),

    P(contact) <= P(|z| > k) + P(alpha <= R - m(beta)),
    P(alpha <= R - m(beta)) = E over beta of Phi(h(beta)),
    h = (R - m(beta) - E[alpha | beta]) / sd(alpha | beta).

(Without the window, the velocity's spread along u over the whole horizon would count paths
that drift sideways long after the bodies have passed each other.)  k = ``_TUBE_SIGMAS``.

m is a minimum of functions linear in beta, so concave; E[alpha | beta] is linear in beta: h
is convex in beta.  On each of ``PROJECTION_BINS`` equal bins of the standardised beta, w, over
[-8, 8] the largest h is therefore at one of the bin's ends, and

    P(...) <= sum over bins of P(w in bin) Phi(max(h(end), h(other end))) + P(|w| > 8)

is an upper bound, not an estimate (an upper Riemann sum of a monotone function of a convex
one; the bin probabilities are fixed constants).  u points from the origin to the mean path's
nearest point in [0, H] (sampled on a grid of t: any unit u gives a valid bound, this one a
tight one for pairs that pass each other): a near miss projects onto u as a miss distance,
which the k-sigma tube bounds only through the chi-square tail of all 2D whitened
coordinates.

References
----------
.. [1] S. O. Rice, "Mathematical analysis of random noise", Bell Syst. Tech. J. 23 (1944):
   the process view; here only the marginal of a linear functional is used.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from circle_collision_ros.core.uncertainty.tube import chi2_tail_even, row_state, tube_window

__all__ = ["projection_bound", "projection_rows", "projection_rows_at", "PROJECTION_BINS"]

#: Bins of the standardised u.dv over [-_Z, _Z] (the upper sum's resolution)
PROJECTION_BINS = 64
_Z = 8.0
_GRID = 33  # t samples for the mean path's nearest point (any u is valid)
# The tube whose ambiguous intervals bound the contact times: P(chi^2_2D > k^2) = 4.4e-6 in
# 2-D, 4.0e-5 in 3-D, against the threshold / 2 (5e-3 by default) the screen compares with
_TUBE_SIGMAS = 5.5
_TUBE_TAILS = np.array([chi2_tail_even(_TUBE_SIGMAS**2, 2 * D) for D in (2, 3)])
# Its walk stops at leaves of H / 32 (the window is then a little wider, never narrower)
_WINDOW_DEPTH = 5
# Phi(-8.5) < 1e-17: a bin whose h stays below -8.5 adds its mass times 1e-17, no erfc
_PHI_FLOOR_AT = -8.5
_PHI_FLOOR = 1e-17
# P(|z| > _Z) plus the rounding of the 65 erfc values and the bin sums (each ~1e-16)
_SLACK = math.erfc(_Z / math.sqrt(2.0)) + 1e-12


def _bin_masses() -> np.ndarray:
    z = np.linspace(-_Z, _Z, PROJECTION_BINS + 1)
    cdf = np.array([0.5 * math.erfc(-x / math.sqrt(2.0)) for x in z])
    return np.diff(cdf)


_MASS = _bin_masses()
_ZS = np.linspace(-_Z, _Z, PROJECTION_BINS + 1)


@njit(cache=True, error_model="numpy", inline="always")
def _min_path(beta, c, t0, t1):
    """min over t in [t0, t1] of beta t + c t^2 (ends, and the vertex when c > 0)."""
    m = min(beta * t0 + c * t0 * t0, beta * t1 + c * t1 * t1)
    if c > 0.0:
        tv = -beta / (2.0 * c)
        if t0 < tv < t1:
            m = min(m, beta * tv + c * tv * tv)
    return m


@njit(cache=True, error_model="numpy")
def projection_bound(dp, dv, da, R, Sigma, H):
    """An upper bound on P(contact within [0, H]) of the relative state (dp, dv, da) with
    joint covariance Sigma (2D, 2D) and contact radius R [m]: 1.0 where the mean path
    reaches the ball, the tube lies wholly inside it or the projection is degenerate (no
    bound then).  Exactly symmetric
    under X -> -X (u turns with X), monotone in R.  The module doc gives the argument."""
    D = dp.shape[0]
    leaves = np.empty((1 << _WINDOW_DEPTH, 2))
    cnt, t_inside = tube_window(dp, dv, da, R, Sigma, H, leaves, _TUBE_SIGMAS, _WINDOW_DEPTH)
    tail = _TUBE_TAILS[D - 2]
    if t_inside <= H:
        return 1.0
    if cnt == 0:
        return min(1.0, tail + _SLACK)
    t0 = leaves[0, 0]
    t1 = leaves[cnt - 1, 1]
    best = math.inf
    tbest = 0.0
    # u from the whole horizon, not the window: the window shrinks with R (a node outside
    # the tube for R is outside for every smaller R), u does not move, so the bound is
    # monotone in R
    for i in range(_GRID):
        t = H * i / (_GRID - 1)
        q = 0.0
        for k in range(D):
            g = dp[k] + t * (dv[k] + 0.5 * t * da[k])
            q += g * g
        if q < best:
            best = q
            tbest = t
    gn = math.sqrt(best)
    if not (gn > R):
        return 1.0
    u = np.empty(D)
    for k in range(D):
        u[k] = (dp[k] + tbest * (dv[k] + 0.5 * tbest * da[k])) / gn
    ma = 0.0
    mb = 0.0
    c = 0.0
    for k in range(D):
        ma += u[k] * dp[k]
        mb += u[k] * dv[k]
        c += 0.5 * u[k] * da[k]
    saa = 0.0
    sab = 0.0
    sbb = 0.0
    for i in range(D):
        for j in range(D):
            saa += u[i] * Sigma[i, j] * u[j]
            sab += u[i] * 0.5 * (Sigma[i, D + j] + Sigma[D + j, i]) * u[j]
            sbb += u[i] * Sigma[D + i, D + j] * u[j]
    if not (sbb > 0.0 and saa > 0.0):
        return 1.0  # beta or alpha exact: the one-dimensional integral does not apply
    s2 = saa - sab * sab / sbb
    if not (s2 > 1e-12 * saa):
        return 1.0  # alpha (nearly) a function of beta
    s = math.sqrt(s2)
    sb = math.sqrt(sbb)
    rho = sab / sbb
    # rounding: u is unit to ~1e-16 (|u.X| <= |u| R) and each term below carries a few ulps
    # of its scale, far inside this margin on R
    scale = R + abs(ma) + (abs(mb) + 8.0 * sb) * H + abs(c) * H * H
    reach = R + 1e-12 * scale
    total = 0.0
    h_prev = 0.0
    for i in range(PROJECTION_BINS + 1):
        z = _ZS[i]
        beta = mb + sb * z
        h = (reach - _min_path(beta, c, t0, t1) - (ma + rho * sb * z)) / s
        if i > 0:
            hm = max(h, h_prev)
            phi = _PHI_FLOOR if hm < _PHI_FLOOR_AT else 0.5 * math.erfc(-hm / math.sqrt(2.0))
            total += _MASS[i - 1] * phi
        h_prev = h
    return min(1.0, total + tail + _SLACK)


@njit(cache=True, error_model="numpy", nogil=True)
def projection_rows_at(pa, va, aa, ra, pb, vb, ab, rb, sigma, rows, H, out):
    """out[j] = projection_bound of row rows[j] of the per-body arrays (relative state
    a - b, Sigma = sigma[row])."""
    D = pa.shape[1]
    dp = np.empty(D)
    dv = np.empty(D)
    da = np.empty(D)
    for j in range(rows.shape[0]):
        i = rows[j]
        row_state(pa, va, aa, pb, vb, ab, i, dp, dv, da)
        out[j] = projection_bound(dp, dv, da, ra[i] + rb[i], sigma[i], H)


@njit(cache=True, error_model="numpy", nogil=True)
def _projection_rows(dp, dv, da, rad, sig, H, out):
    for j in range(dp.shape[0]):
        out[j] = projection_bound(dp[j], dv[j], da[j], rad[j], sig[j], H)


def projection_rows(dp, dv, da, rad, sig, H: float) -> np.ndarray:
    """(n,) projection_bound of relative rows dp, dv, da (n, D), rad (n,), sig (n, 2D, 2D)."""
    out = np.empty(dp.shape[0])
    _projection_rows(np.ascontiguousarray(dp), np.ascontiguousarray(dv), np.ascontiguousarray(da),
                     np.ascontiguousarray(rad), np.ascontiguousarray(sig), float(H), out)
    return out
