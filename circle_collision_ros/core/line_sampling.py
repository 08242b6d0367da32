"""Line sampling: P(contact within [0, H]) of a straight 3-D pair by randomized QMC
with one Gaussian coordinate integrated in closed form (docs/uncertainty.md,
"Straight 3-D pairs: line sampling").

For straight relative motion (da = 0) the path X(t) = dp + dv t touches the
ball |x| <= R within [0, H] iff dp lies in the capsule

    K(dv) = {x : dist(x, segment from 0 to -dv H) <= R}

(convex: the R-neighbourhood of a segment).  Fix a unit direction e and write
dp = c + x e.  Conditional on dv and on the two coordinates of dp orthogonal
to e, x is Gaussian, N(0, s^2) after moving its conditional mean into c, with
s constant (a Gaussian conditional variance does not depend on the values
conditioned on), and the contact set of x is the interval K(dv) n (c + R e) (a
line meets a convex set in an interval), found in closed form as the hull of
the line's intersections with the two end balls and the finite cylinder (their
union is K, and a union of pieces covering an interval is its hull).  Hence

    P(contact) = E[ Phi(x_hi / s) - Phi(x_lo / s) ]

over the other five Gaussian coordinates: a continuous integrand (the indicator
has been integrated out along e), so scrambled Sobol replicates converge much
faster than on the indicator.  Exact but for the sampling: no tube truncation,
no quadrature.

e is the direction orthogonal to the mean relative velocity with the largest
conditional variance of dp given dv (the capsule is narrow across its axis, so
the contact interval along e is short relative to s and the integrand smooth);
when that variance is 0 the largest conditional variance overall.  ``line_factor``
reports ok = False when the conditional standard deviation along e is 0 (dp a
function of dv, e.g. velocity-only uncertainty): the caller keeps its other
method there.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from circle_collision_ros.core.entry_rate import mat_mul
from circle_collision_ros.core.overlap_probability import eig_sym, interval_mass

__all__ = ["line_factor", "line_replicates", "capsule_interval"]

# semi-definite Cholesky: a pivot <= _PIVOT_RTOL x the largest diagonal entry is a
# variable that is (to rounding) a function of the previous ones: its column is 0
_PIVOT_RTOL = 1e-14
_CUT = 9.0  # |x| / s beyond which the conditional normal mass is dropped (< 1.2e-19 per point)


@njit(cache=True, error_model="numpy")
def _psd_cholesky(M):
    """Lower-triangular L with L L^T = M for a symmetric PSD M (zero columns
    where a pivot is <= _PIVOT_RTOL x max diag: a semi-definite factor)."""
    n = M.shape[0]
    L = np.zeros((n, n))
    scale = 0.0
    for i in range(n):
        scale = max(scale, M[i, i])
    for j in range(n):
        d = M[j, j]
        for k in range(j):
            d -= L[j, k] * L[j, k]
        if not (d > _PIVOT_RTOL * scale):
            continue
        L[j, j] = math.sqrt(d)
        for i in range(j + 1, n):
            s = M[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            L[i, j] = s / L[j, j]
    return L


@njit(cache=True, error_model="numpy")
def _rotated_factor(M, Q):
    """The semi-definite factor of the covariance of (dv, Q^T dp), M being that of
    (dv, dp): with Q's columns (f1, f2, e), dp.e is last, so its pivot is its
    conditional standard deviation given everything else."""
    T = np.zeros((6, 6))  # (dv, dp) -> (dv, Q^T dp)
    for i in range(3):
        T[i, i] = 1.0
        for j in range(3):
            T[3 + i, 3 + j] = Q[j, i]
    return _psd_cholesky(mat_mul(mat_mul(T, M), T.T.copy()))


@njit(cache=True, error_model="numpy")
def line_factor(dp, dv, Sigma):
    """(G (6, 5), mu (6,), e (3,), s, ok) for a 3-D pair: with z 5 standard normals,
    (c, v) = mu[:3] + G[:3] z, mu[3:] + G[3:] z is (the dp base point, dv), and
    dp = c + x e with x ~ N(0, s^2) independent of z.  ok = False when s is 0
    (the caller keeps another method)."""
    # (dv, dp) order: the lower-right block of its factor is the conditional
    # covariance of dp given dv
    M = np.empty((6, 6))
    for i in range(6):
        ii = i + 3 if i < 3 else i - 3
        for j in range(6):
            jj = j + 3 if j < 3 else j - 3
            M[i, j] = 0.5 * (Sigma[ii, jj] + Sigma[jj, ii])
    L = _psd_cholesky(M)
    C = np.zeros((3, 3))
    for i in range(3):
        for j in range(3):
            for k in range(3, 6):
                C[i, j] += L[3 + i, k] * L[3 + j, k]
    # the part of C across the mean relative velocity (P C P, P = I - u u^T)
    vn = math.sqrt(dv[0] * dv[0] + dv[1] * dv[1] + dv[2] * dv[2])
    Cp = C.copy()
    if vn > 0.0:
        u = dv / vn
        P = np.eye(3)
        for i in range(3):
            for j in range(3):
                P[i, j] -= u[i] * u[j]
        Cp = mat_mul(mat_mul(P, C), P)
    lam, Q = eig_sym(Cp)
    if not (lam[2] > 0.0):
        lam, Q = eig_sym(C)
    L2 = _rotated_factor(M, Q)
    if not (L2[5, 5] > 0.0):
        # dp.e is a function of the rest (a singular Sigma whose null vector has a
        # component along e): the largest conditional variance overall lies in
        # the range of C, where dp.e given dv and the rest keeps some variance
        lam, Q = eig_sym(C)
        L2 = _rotated_factor(M, Q)
    s = L2[5, 5]
    G = np.zeros((6, 5))
    for j in range(5):
        for k in range(3):
            G[3 + k, j] = L2[k, j]  # v
            G[k, j] = Q[k, 0] * L2[3, j] + Q[k, 1] * L2[4, j] + Q[k, 2] * L2[5, j]  # c
    mu = np.empty(6)
    for k in range(3):
        mu[k] = dp[k]
        mu[3 + k] = dv[k]
    e = np.empty(3)
    for k in range(3):
        e[k] = Q[k, 2]
    return G, mu, e, s, s > 0.0


@njit(cache=True, error_model="numpy", inline="always")
def _ball_chord(c0, c1, c2, e0, e1, e2, R):
    """{x : |c + x e| <= R} for unit e as (lo, hi) (lo > hi: empty); the
    discriminant R^2 - |c x e|^2 loses no digits when the line passes close."""
    b = c0 * e0 + c1 * e1 + c2 * e2
    x0 = c1 * e2 - c2 * e1
    x1 = c2 * e0 - c0 * e2
    x2 = c0 * e1 - c1 * e0
    disc = R * R - (x0 * x0 + x1 * x1 + x2 * x2)
    if disc < 0.0:
        return 1.0, -1.0
    r = math.sqrt(disc)
    return -b - r, -b + r


@njit(cache=True, error_model="numpy")
def capsule_interval(c0, c1, c2, e0, e1, e2, v0, v1, v2, R, H):
    """(lo, hi): the x with min over t in [0, H] of |c + x e + v t| <= R (lo > hi:
    none), e a unit vector.  The set is the line's intersection with the capsule
    around the segment from 0 to -v H: the hull of its chords through the two
    end balls and the finite cylinder.  Each end ball lies inside the infinite
    cylinder (its points are within R of the axis), so where the infinite
    cylinder's chord lies within the slab 0 <= p.u <= |v| H it is the hull
    itself and the balls' chords are not computed (most lines)."""
    w0 = v0 * H
    w1 = v1 * H
    w2 = v2 * H
    wn = math.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
    lo = math.inf
    hi = -math.inf
    if wn > 0.0:
        # axis u = -v / |v| (the segment 0 .. -v H): the slab 0 <= p.u <= |v| H
        u0 = -w0 / wn
        u1 = -w1 / wn
        u2 = -w2 / wn
        cu = c0 * u0 + c1 * u1 + c2 * u2
        eu = e0 * u0 + e1 * u1 + e2 * u2
        if eu != 0.0:
            s1 = -cu / eu
            s2 = (wn - cu) / eu
            sl = min(s1, s2)
            sh = max(s1, s2)
        elif 0.0 <= cu <= wn:
            sl = -math.inf
            sh = math.inf
        else:
            sl = 1.0
            sh = -1.0
        # across the axis: |c_perp + x e_perp| <= R (discriminant via the cross product)
        cp0 = c0 - cu * u0
        cp1 = c1 - cu * u1
        cp2 = c2 - cu * u2
        ep0 = e0 - eu * u0
        ep1 = e1 - eu * u1
        ep2 = e2 - eu * u2
        aa = ep0 * ep0 + ep1 * ep1 + ep2 * ep2
        if aa > 0.0:
            bb = cp0 * ep0 + cp1 * ep1 + cp2 * ep2
            x0 = cp1 * ep2 - cp2 * ep1
            x1 = cp2 * ep0 - cp0 * ep2
            x2 = cp0 * ep1 - cp1 * ep0
            disc = aa * R * R - (x0 * x0 + x1 * x1 + x2 * x2)
            if disc >= 0.0:
                r = math.sqrt(disc)
                pl = (-bb - r) / aa
                ph = (-bb + r) / aa
            else:
                pl = 1.0
                ph = -1.0
        elif cp0 * cp0 + cp1 * cp1 + cp2 * cp2 <= R * R:
            pl = -math.inf
            ph = math.inf
        else:
            pl = 1.0
            ph = -1.0
        if not pl <= ph:
            return 1.0, -1.0  # the line misses the infinite cylinder, hence the balls
        if sl <= pl and ph <= sh:
            return pl, ph
        a = max(sl, pl)
        b = min(sh, ph)
        if a <= b:
            lo = a
            hi = b
    a, b = _ball_chord(c0, c1, c2, e0, e1, e2, R)
    if a <= b:
        lo = min(lo, a)
        hi = max(hi, b)
    a, b = _ball_chord(c0 + w0, c1 + w1, c2 + w2, e0, e1, e2, R)
    if a <= b:
        lo = min(lo, a)
        hi = max(hi, b)
    return lo, hi


@njit(cache=True, error_model="numpy")
def line_replicates(G, mu, e, s, R, H, Z, m0, m1, tot):
    """tot[r] += the sum over the points m0 <= i < m1 of replicate r of Z (r, M,
    >= 5 standard normals) of P(contact | z) = Phi(hi / s) - Phi(lo / s), with
    [lo, hi] the capsule interval of the line through the point's (c, v) along e."""
    for r in range(Z.shape[0]):
        acc = 0.0
        for i in range(m0, m1):
            c0 = mu[0]
            c1 = mu[1]
            c2 = mu[2]
            v0 = mu[3]
            v1 = mu[4]
            v2 = mu[5]
            for j in range(5):
                z = Z[r, i, j]
                c0 += G[0, j] * z
                c1 += G[1, j] * z
                c2 += G[2, j] * z
                v0 += G[3, j] * z
                v1 += G[4, j] * z
                v2 += G[5, j] * z
            lo, hi = capsule_interval(c0, c1, c2, e[0], e[1], e[2], v0, v1, v2, R, H)
            # beyond 9 s the normal mass is < 1.2e-19 (2 Phi(-9) for both ends):
            # the point contributes 0 or 1 without an erfc
            if lo <= hi and lo < _CUT * s and hi > -_CUT * s:
                if lo <= -_CUT * s and hi >= _CUT * s:
                    acc += 1.0
                else:
                    acc += interval_mass(lo, hi, 0.0, s)
        tot[r] += acc
