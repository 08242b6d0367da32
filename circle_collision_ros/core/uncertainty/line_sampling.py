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

Control variate (``cylinder_control``).  For most pairs the path touches iff its
miss vector is shorter than R.  With u the mean relative velocity's direction,
f = u x e and t* = -dp.dv / |dv|^2 the closest-approach time, that vector is
about the projection onto the plane (e, f) of W = dp + t* (dv - mean dv).
Linearise t* about the mean path's: t* ~ tbar + tau, tau = a.(dp - mean dp,
dv - mean dv) (its gradient; a's dp part is along u, so tau does not depend on
x).  The same line gives the chord of {x : (w.e + x)^2 + (w.f)^2 <= R^2},
w = c + (tbar + tau) (v - mean dv), in closed form, and its Phi-difference Y has
an exact mean: given tau, W is Gaussian, so E[Y | tau] is a 2-D Gaussian disc
probability, and E[Y] = E[E[Y | tau]] a smooth 1-D Gauss-Hermite integral.  The
estimate F - beta (Y - E[Y]) is exact for any beta; beta comes from the
replicates (regression: ``core.uncertainty.qmc.controlled_stats``), so a control
that correlates badly (slow pairs, closest approach outside [0, H], where tau
is 0) costs only its own evaluation.  Without velocity noise Y is the infinite
cylinder's chord and F - Y only the capsule's ends; with it, the bilinear term
tau (dv - mean dv) that a fixed time would leave out is in Y (measured: the
replicates' standard error ~10x below a fixed-time control's, ~30x below none).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from circle_collision_ros.core.special import eig_sym, mat_mul, unit_across
from circle_collision_ros.core.uncertainty.overlap import overlap_probability_2d

__all__ = ["line_factor", "line_replicates", "capsule_interval", "cylinder_control",
           "disc_given_tau", "PHI_ERR"]

# semi-definite Cholesky: a pivot <= _PIVOT_RTOL x the largest diagonal entry is a
# variable that is (to rounding) a function of the previous ones: its column is 0
_PIVOT_RTOL = 1e-14
# Phi on [-9, 9] for the innermost loop: a table of (Phi, h phi) at spacing
# h = 1/64 and cubic Hermite interpolation between nodes, whose error is at most
# h^4 / 384 max|Phi^(4)| = h^4 / 384 max|(x^3 - 3x) phi(x)| = 8.54e-11 (the
# table's rounding adds ~1e-16).  Measured faster than two erfc with their range
# branches (see bench/bench_uncertainty.py); the estimate's stated bound adds the resulting bias
# (PHI_ERR per
# Phi: two per chord).  tests/core/uncertainty/test_uncertainty_line_sampling.py checks
# PHI_ERR against mpmath.
_PHI_INV_H = 64.0
_PHI_X0 = -9.0
_PHI_LAST = 18.0 * _PHI_INV_H - 1e-9  # u below the last node: i + 1 stays in the table
_PHI_NODES = _PHI_X0 + np.arange(int(18.0 * _PHI_INV_H) + 1) / _PHI_INV_H
_PHI_TABLE = np.array(
    [
        [
            0.5 * math.erfc(-x / math.sqrt(2.0)),
            math.exp(-0.5 * x * x) / math.sqrt(2.0 * math.pi) / _PHI_INV_H,
        ]
        for x in _PHI_NODES
    ]
)
PHI_ERR = 1e-10


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
def disc_given_tau(dp, Sigma, e, f, tbar, a, Sa, sig2, tau, R):
    """E[Y | tau]: P(|(W.e, W.f)| <= R) for W = dp + (tbar + tau) (dv - mean dv)
    given a.(dp - mean dp, dv - mean dv) = tau (Gaussian conditioning: mean
    Sa tau / sig2, covariance Sigma - Sa Sa^T / sig2; sig2 = 0: unconditioned)."""
    tt = tbar + tau
    k = tau / sig2 if sig2 > 0.0 else 0.0
    me = 0.0
    mf = 0.0
    for i in range(3):
        w = dp[i] + k * (Sa[i] + tt * Sa[3 + i])
        me += e[i] * w
        mf += f[i] * w
    # the projections' rows: pe = e^T [I, tt I], pf = f^T [I, tt I] (6-vectors)
    pe = np.empty(6)
    pf = np.empty(6)
    for i in range(3):
        pe[i] = e[i]
        pf[i] = f[i]
        pe[3 + i] = tt * e[i]
        pf[3 + i] = tt * f[i]
    see = 0.0
    sef = 0.0
    sff = 0.0
    pe_sa = 0.0
    pf_sa = 0.0
    for i in range(6):
        pe_sa += pe[i] * Sa[i]
        pf_sa += pf[i] * Sa[i]
        for j in range(6):
            sij = 0.5 * (Sigma[i, j] + Sigma[j, i])
            see += pe[i] * sij * pe[j]
            sef += pe[i] * sij * pf[j]
            sff += pf[i] * sij * pf[j]
    if sig2 > 0.0:
        see -= pe_sa * pe_sa / sig2
        sef -= pe_sa * pf_sa / sig2
        sff -= pf_sa * pf_sa / sig2
    return overlap_probability_2d(me, mf, max(see, 0.0), sef, max(sff, 0.0), R)


# Gauss-Hermite rules (probabilists', weights summing to 1) for E[E[Y | tau]]:
# the 16-point value, with |GH16 - GH8| as its error estimate (E[Y | tau] is
# analytic in tau: on the benchmark's pairs GH16 - GH32 <= 3e-9 where that
# estimate is up to 2e-6)
_GH8_X, _GH8_W = np.polynomial.hermite_e.hermegauss(8)
_GH8_W = _GH8_W / _GH8_W.sum()
_GH16_X, _GH16_W = np.polynomial.hermite_e.hermegauss(16)
_GH16_W = _GH16_W / _GH16_W.sum()


@njit(cache=True, error_model="numpy")
def cylinder_control(dp, dv, Sigma, e, R, H):
    """(f, tbar, a, E[Y], error of E[Y]) of the control variate (module
    docstring): f the unit vector across e and the mean relative velocity (any
    unit vector across e when dv = 0); tbar the mean path's closest-approach
    time clipped to [0, H]; a (6,) the gradient of t* at the mean (0 when dv = 0,
    tbar was clipped or tau's standard deviation is 0 or above H), its dp part
    made orthogonal to e; E[Y] by 16-point
    Gauss-Hermite over tau, error |GH16 - GH8| + the disc probabilities' 1e-9."""
    vv = dv[0] * dv[0] + dv[1] * dv[1] + dv[2] * dv[2]
    pv = dp[0] * dv[0] + dp[1] * dv[1] + dp[2] * dv[2]
    tbar = 0.0
    a = np.zeros(6)
    if vv > 0.0:
        tbar = -pv / vv
        if 0.0 < tbar < H:
            # t* = -dp.dv / |dv|^2: d/ddp = -dv / |dv|^2, d/ddv = -dp / |dv|^2 + 2 (dp.dv) dv /
            # |dv|^4
            for k in range(3):
                a[k] = -dv[k] / vv
                a[3 + k] = -dp[k] / vv + 2.0 * pv * dv[k] / (vv * vv)
        tbar = min(max(tbar, 0.0), H)
    # f = dv x e (any unit vector across e when dv = 0), orthogonalised against e
    # and normalised: the estimator needs only an orthonormal (e, f), and a's dp
    # part orthogonal to e (tau free of x)
    f = np.empty(3)
    if vv > 0.0:
        f[0] = dv[1] * e[2] - dv[2] * e[1]
        f[1] = dv[2] * e[0] - dv[0] * e[2]
        f[2] = dv[0] * e[1] - dv[1] * e[0]
    else:
        f[0], f[1], f[2] = unit_across(e[0], e[1], e[2])
    fe = f[0] * e[0] + f[1] * e[1] + f[2] * e[2]
    ae = a[0] * e[0] + a[1] * e[1] + a[2] * e[2]
    for k in range(3):
        f[k] -= fe * e[k]
        a[k] -= ae * e[k]
    fn = math.sqrt(f[0] * f[0] + f[1] * f[1] + f[2] * f[2])
    for k in range(3):
        f[k] /= fn
    Sa = np.zeros(6)
    for i in range(6):
        for j in range(6):
            Sa[i] += 0.5 * (Sigma[i, j] + Sigma[j, i]) * a[j]
    sig2 = 0.0
    for i in range(6):
        sig2 += a[i] * Sa[i]
    if not (0.0 < sig2 <= H * H):
        # no spread of t*, or one beyond the horizon (a linearisation that says
        # nothing; also a non-finite gradient when |dv| is tiny): the fixed time tbar
        for i in range(6):
            a[i] = 0.0
            Sa[i] = 0.0
        return f, tbar, a, disc_given_tau(dp, Sigma, e, f, tbar, a, Sa, 0.0, 0.0, R), 1e-9
    g8 = _mean_over_tau(dp, Sigma, e, f, tbar, a, Sa, sig2, R, _GH8_X, _GH8_W)
    g16 = _mean_over_tau(dp, Sigma, e, f, tbar, a, Sa, sig2, R, _GH16_X, _GH16_W)
    return f, tbar, a, g16, abs(g16 - g8) + 1e-9


@njit(cache=True, error_model="numpy")
def _mean_over_tau(dp, Sigma, e, f, tbar, a, Sa, sig2, R, X, W):
    """E[E[Y | tau]] by the Gauss-Hermite rule (X, W), tau ~ N(0, sig2)."""
    sig = math.sqrt(sig2)
    total = 0.0
    for i in range(X.shape[0]):
        total += W[i] * disc_given_tau(dp, Sigma, e, f, tbar, a, Sa, sig2, sig * X[i], R)
    return total


@njit(cache=True, error_model="numpy", inline="always")
def _phi(x):
    """Phi(x) from _PHI_TABLE by cubic Hermite interpolation (x clamped to the
    table's [-9, 9]: the mass beyond is < 1.2e-19), absolute error <= PHI_ERR."""
    u = (x - _PHI_X0) * _PHI_INV_H
    if not (u > 0.0):  # also NaN: never an index outside the table
        u = 0.0
    elif u > _PHI_LAST:
        u = _PHI_LAST
    i = int(u)
    t = u - i
    y0 = _PHI_TABLE[i, 0]
    d0 = _PHI_TABLE[i, 1]
    y1 = _PHI_TABLE[i + 1, 0]
    d1 = _PHI_TABLE[i + 1, 1]
    return y0 + t * (d0 + t * (3.0 * (y1 - y0) - 2.0 * d0 - d1 + t * (2.0 * (y0 - y1) + d0 + d1)))


@njit(cache=True, error_model="numpy", inline="always")
def _chord_mass(lo, hi, s_inv):
    """P(lo <= x <= hi) for x ~ N(0, 1 / s_inv^2), 0 for an empty chord
    (lo > hi), within 2 PHI_ERR; no branch (innermost loop: a mispredicted
    branch costs as much as the arithmetic)."""
    hi = max(hi, lo)
    return _phi(hi * s_inv) - _phi(lo * s_inv)


@njit(cache=True, error_model="numpy")
def line_replicates(G, mu, e, s, f, tbar, a, R, H, Z, m0, m1, tot, ctot):
    """tot[r] += the sum over the points m0 <= i < m1 of replicate r of Z (r, M,
    >= 5 standard normals) of P(contact | z) = Phi(hi / s) - Phi(lo / s), with
    [lo, hi] the capsule interval of the line through the point's (c, v) along e;
    ctot[r] += the same sum of the control variate Y (``cylinder_control``'s f,
    tbar, a)."""
    s_inv = 1.0 / s
    for r in range(Z.shape[0]):
        acc = 0.0
        acy = 0.0
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
            acc += _chord_mass(lo, hi, s_inv)
            # the control: w = c + (tbar + tau) (v - mean v), chord of (w.e + x)^2 + (w.f)^2 <= R^2
            d0 = v0 - mu[3]
            d1 = v1 - mu[4]
            d2 = v2 - mu[5]
            tt = tbar + (
                a[0] * (c0 - mu[0])
                + a[1] * (c1 - mu[1])
                + a[2] * (c2 - mu[2])
                + a[3] * d0
                + a[4] * d1
                + a[5] * d2
            )
            w0 = c0 + tt * d0
            w1 = c1 + tt * d1
            w2 = c2 + tt * d2
            we = w0 * e[0] + w1 * e[1] + w2 * e[2]
            wf = w0 * f[0] + w1 * f[1] + w2 * f[2]
            rr = math.sqrt(max(R * R - wf * wf, 0.0))
            acy += _chord_mass(-we - rr, -we + rr, s_inv)
        tot[r] += acc
        ctot[r] += acy
