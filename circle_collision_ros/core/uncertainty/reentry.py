"""Re-entry bounds of accelerating pairs.

With da != 0 a path may exit the ball and come back, so P(0) + E[entries]
over-counts P(contact) by the re-entries.  ``no_reentry`` certifies that no path
of a k-sigma tube has a local maximum of |X|^2 - R^2 where it could cross the
sphere (then the sum is P but for the tail paths); ``overcount_tail`` bounds
the over-count's mean through the widest narrower tube so certified.

See docs/uncertainty.md ("Accelerating") for the mathematics; each guarantee
is stated where it is made.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from circle_collision_ros.core.special import eig_sym
from circle_collision_ros.core.uncertainty.qmc import QMC_CV_POINTS, QMC_REPLICATES
from circle_collision_ros.core.uncertainty.tube import chi2_tail_even

__all__ = ["no_reentry", "overcount_tail", "REENTRY_SIGMAS", "BRACKET_HALF_WIDTH"]


_REENTRY_PIECES = 16  # pieces of the interval for no_reentry's bounds


# multiples of the linear bound's optimum sqrt(Q) / (2 k)
_DUAL_LAMBDAS = (1.0, 0.5, 0.25, 0.125, 0.0625)


@njit(cache=True, error_model="numpy")
def no_reentry(dp, dv, da, Sigma, t0, t1, k):
    """True when no path of the k-sigma tube has a local maximum of f = |X|^2 - R^2
    in [t0, t1] (a certificate; False says nothing): with every sphere crossing of
    a tube path inside [t0, t1], none can exit the ball and come back.

    A re-entry needs a local maximum of f inside (0, H), impossible where
    f'' / 2 = |Xdot|^2 + X.da > 0.  With X = g + dX, Xdot = gd + dV (deviations
    linear in z; acceleration is exact),

        f'' / 2 = P(t) + l + |dV|^2,  P(t) = |gd|^2 + g.da = |dv|^2 + dp.da + 3 (dv.da) t + 1.5
        |da|^2 t^2,

    l = u(t).(dp_dev, dv_dev), u(t) = (da, 2 dv + 3 t da).  For every lam > 0 and
    |z| <= k: l + |dV|^2 >= l + |dV|^2 + lam (|z|^2 - k^2) >= -lam k^2 - W(t) /
    (4 lam), the last step the minimum over all z of that convex quadratic, with
    (Woodbury) W(t) = u^T Sigma u - r^T (lam I + Svv)^-1 r, r = (Sigma u)_v: a
    quadratic in t.  So f'' / 2 >= P(t) - lam k^2 - W(t) / (4 lam) =: b(t), a
    quadratic whose minimum over each of _REENTRY_PIECES pieces of [t0, t1] is
    exact (vertex or ends), less rounding margins; lam from a few multiples of
    sqrt(u^T Sigma u) / (2 k) at the piece's midpoint (the optimum without the
    |dV|^2 term; any lam > 0 is valid).  It keeps the correlations, the sign of
    g.da and the |dV|^2 that cruder bounds drop: on random cases it
    certified every case that (min |gd| - k sigma_v)^2 > (max |g| + k sigma_x) |da|
    (a cruder bound) does, and more.  Typical of moving bodies with
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
        pscale += (
            dv[i] * dv[i] + abs(dp[i] * da[i]) + 3.0 * abs(dv[i] * da[i]) + 1.5 * da[i] * da[i]
        )
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
    # rounding: a few ulps per term of sums bounded by these scales (W <= u^T Sigma u <= 2D smax
    # |u|^2)
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


# The narrower tubes overcount_tail tries (sigmas), widest first: 2 P(chi^2_4 > k'^2)
# = 5.8e-7, 1.0e-4, 8.9e-4 in 2-D (chi^2_6: 5.5e-6, 6.8e-4, 5.0e-3); narrower ones
# would cost more than the bracket below can carry
REENTRY_SIGMAS = (6.0, 5.0, 4.5)
# An uncertified accelerating pair is answered by its bracket when the bracket's
# half-width is at most the smallest bound the over-count RQMC can state: U's
# slack plus 3 / (QMC_REPLICATES * QMC_CV_POINTS) = 1.5e-3 (the rule of three at
# its first stage); never a looser answer than the sampling would give
BRACKET_HALF_WIDTH = 3.0 / (QMC_REPLICATES * QMC_CV_POINTS)
_REENTRY_TAILS = np.array(
    [[2.0 * chi2_tail_even(k * k, 2 * D) for k in REENTRY_SIGMAS] for D in (2, 3)]
)


@njit(cache=True, error_model="numpy")
def overcount_tail(dp, dv, da, Sigma, t0, t1):
    """An upper bound of E[O], the over-count of an accelerating pair whose tube
    paths cross the sphere only within [t0, t1] (1.0: none found): 2 P(chi^2_2D >
    k'^2) for the widest k' of REENTRY_SIGMAS that ``no_reentry`` certifies (no
    path of the k'-tube comes back: O = 0 there; O <= 2 on every path)."""
    row = dp.shape[0] - 2
    for j in range(len(REENTRY_SIGMAS)):
        if no_reentry(dp, dv, da, Sigma, t0, t1, REENTRY_SIGMAS[j]):
            return _REENTRY_TAILS[row, j]
    return 1.0
