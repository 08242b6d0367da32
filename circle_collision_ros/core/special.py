"""Special functions and small linear algebra shared by the numba kernels.

* W. J. Cody's rational Chebyshev approximations of erf and erfcx
  (``cody_erf_small``, ``cody_erfcx_mid``, ``cody_r3``), ~1e-16 relative on
  their ranges;
* ``inv_sym`` and ``mat_mul``: the inverse (adjugate) and products of 2x2 / 3x3
  matrices in explicit loops (numba's ``@`` and ``inv`` need scipy's BLAS/LAPACK,
  which is not a dependency);
* ``eig_sym``: the eigendecomposition of a small symmetric matrix (cyclic
  Jacobi), ``unit_across``: a unit vector orthogonal to a given one.

Compiled with the same options as their callers (``cache=True``,
``error_model="numpy"``), so results do not depend on where they are defined.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["cody_erf_small", "cody_erfcx_mid", "cody_r3", "inv_sym", "mat_mul", "eig_sym",
           "unit_across"]


# W. J. Cody's rational Chebyshev approximations of erf and erfc (Math. Comp. 23,
# 631-638, 1969; Netlib SPECFUN CALERF), ~1e-16 relative on their ranges:
# erf(x) = x A(x^2) / B(x^2) for |x| < 0.46875; erfcx(x) = exp(x^2) erfc(x) =
# C(x) / D(x) for 0.46875 <= x <= 4 and (1 / sqrt(pi) - r3(x)) / x, r3 = z P(z) / Q(z),
# z = 1 / x^2, for x > 4.  (tests/core/uncertainty/test_uncertainty_entry_rate.py checks the
# rate factor built on them against 40-digit mpmath.)
_CODY_A = (3.16112374387056560e0, 1.13864154151050156e2, 3.77485237685302021e2,
           3.20937758913846947e3, 1.85777706184603153e-1)
_CODY_B = (2.36012909523441209e1, 2.44024637934444173e2, 1.28261652607737228e3,
           2.84423683343917062e3)
_CODY_C = (5.64188496988670089e-1, 8.88314979438837594e0, 6.61191906371416295e1,
           2.98635138197400131e2, 8.81952221241769090e2, 1.71204761263407058e3,
           2.05107837782607147e3, 1.23033935479799725e3, 2.15311535474403846e-8)
_CODY_D = (1.57449261107098347e1, 1.17693950891312499e2, 5.37181101862009858e2,
           1.62138957456669019e3, 3.29079923573345963e3, 4.36261909014324716e3,
           3.43936767414372164e3, 1.23033935480374942e3)
_CODY_P = (3.05326634961232344e-1, 3.60344899949804439e-1, 1.25781726111229246e-1,
           1.60837851487422766e-2, 6.58749161529837803e-4, 1.63153871373020978e-2)
_CODY_Q = (2.56852019228982242e0, 1.87295284992346047e0, 5.27905102951428412e-1,
           6.05183413124413191e-2, 2.33520497626869185e-3)


@njit(cache=True, error_model="numpy", inline="always")
def cody_erf_small(x):
    """erf(x) for |x| < 0.46875 (Cody's first range)."""
    a, b = _CODY_A, _CODY_B
    z = x * x
    num = (((a[4] * z + a[0]) * z + a[1]) * z + a[2]) * z + a[3]
    den = (((z + b[0]) * z + b[1]) * z + b[2]) * z + b[3]
    return x * num / den


@njit(cache=True, error_model="numpy", inline="always")
def cody_erfcx_mid(x):
    """exp(x^2) erfc(x) for 0.46875 <= x <= 4 (Cody's second range)."""
    c, d = _CODY_C, _CODY_D
    num = c[8] * x
    den = x
    for i in range(7):
        num = (num + c[i]) * x
        den = (den + d[i]) * x
    return (num + c[7]) / (den + d[7])


@njit(cache=True, error_model="numpy", inline="always")
def cody_r3(x):
    """r3(x) of Cody's third range (x > 4): exp(x^2) erfc(x) = (1 / sqrt(pi) - r3) / x, r3 > 0."""
    p, qq = _CODY_P, _CODY_Q
    z = 1.0 / (x * x)
    num = ((((p[5] * z + p[0]) * z + p[1]) * z + p[2]) * z + p[3]) * z + p[4]
    den = ((((z + qq[0]) * z + qq[1]) * z + qq[2]) * z + qq[3]) * z + qq[4]
    return z * num / den


@njit(cache=True, error_model="numpy")
def inv_sym(S):
    """(inverse, determinant) of a symmetric 2x2 or 3x3 matrix (adjugate)."""
    D = S.shape[0]
    A = np.empty((D, D))
    if D == 2:
        det = S[0, 0] * S[1, 1] - S[0, 1] * S[1, 0]
        A[0, 0] = S[1, 1] / det
        A[1, 1] = S[0, 0] / det
        A[0, 1] = -S[0, 1] / det
        A[1, 0] = -S[1, 0] / det
        return A, det
    c00 = S[1, 1] * S[2, 2] - S[1, 2] * S[2, 1]
    c01 = S[1, 2] * S[2, 0] - S[1, 0] * S[2, 2]
    c02 = S[1, 0] * S[2, 1] - S[1, 1] * S[2, 0]
    det = S[0, 0] * c00 + S[0, 1] * c01 + S[0, 2] * c02
    A[0, 0] = c00 / det
    A[1, 0] = c01 / det
    A[2, 0] = c02 / det
    A[0, 1] = (S[0, 2] * S[2, 1] - S[0, 1] * S[2, 2]) / det
    A[1, 1] = (S[0, 0] * S[2, 2] - S[0, 2] * S[2, 0]) / det
    A[2, 1] = (S[0, 1] * S[2, 0] - S[0, 0] * S[2, 1]) / det
    A[0, 2] = (S[0, 1] * S[1, 2] - S[0, 2] * S[1, 1]) / det
    A[1, 2] = (S[0, 2] * S[1, 0] - S[0, 0] * S[1, 2]) / det
    A[2, 2] = (S[0, 0] * S[1, 1] - S[0, 1] * S[1, 0]) / det
    return A, det


@njit(cache=True, error_model="numpy")
def mat_mul(X, Y):
    """X Y for small square matrices (explicit loops: numba's @ needs scipy's BLAS)."""
    D = X.shape[0]
    out = np.zeros((D, D))
    for i in range(D):
        for j in range(D):
            acc = 0.0
            for k in range(D):
                acc += X[i, k] * Y[k, j]
            out[i, j] = acc
    return out


@njit(cache=True, error_model="numpy", inline="always")
def unit_across(u0, u1, u2):
    """A unit vector orthogonal to the unit vector u: u x (the axis u is least
    aligned with), normalised (never near-parallel to u, so no cancellation)."""
    if abs(u0) <= abs(u1) and abs(u0) <= abs(u2):
        a0, a1, a2 = 0.0, u2, -u1
    elif abs(u1) <= abs(u2):
        a0, a1, a2 = -u2, 0.0, u0
    else:
        a0, a1, a2 = u1, -u0, 0.0
    an = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
    return a0 / an, a1 / an, a2 / an


@njit(cache=True, error_model="numpy")
def eig_sym(S):
    """(eigenvalues ascending, clamped at >= 0; eigenvectors as columns) of
    the symmetric part of a small (n, n) matrix (cyclic Jacobi rotations:
    numba's eigh needs scipy's LAPACK, which is not a dependency; Jacobi is
    backward stable and deterministic).  Converges when every off-diagonal
    element is below 1e-18 times the Frobenius norm (at most 50 sweeps)."""
    n = S.shape[0]
    A = 0.5 * (S + S.T)
    V = np.eye(n)
    fro = math.sqrt(np.sum(A * A))
    for _sweep in range(50):
        off = 0.0
        for p in range(n - 1):
            for q in range(p + 1, n):
                off = max(off, abs(A[p, q]))
        if not (off > 1e-18 * fro):
            break
        for p in range(n - 1):
            for q in range(p + 1, n):
                apq = A[p, q]
                if apq == 0.0:
                    continue
                theta = (A[q, q] - A[p, p]) / (2.0 * apq)
                t = (1.0 if theta >= 0.0 else -1.0) / (abs(theta) + math.sqrt(theta * theta + 1.0))
                c = 1.0 / math.sqrt(t * t + 1.0)
                sn = t * c
                for k in range(n):  # A <- A J (columns p, q)
                    akp = A[k, p]
                    akq = A[k, q]
                    A[k, p] = c * akp - sn * akq
                    A[k, q] = sn * akp + c * akq
                for k in range(n):  # A <- J^T A (rows p, q)
                    apk = A[p, k]
                    aqk = A[q, k]
                    A[p, k] = c * apk - sn * aqk
                    A[q, k] = sn * apk + c * aqk
                A[p, q] = 0.0
                A[q, p] = 0.0
                for k in range(n):
                    vkp = V[k, p]
                    vkq = V[k, q]
                    V[k, p] = c * vkp - sn * vkq
                    V[k, q] = sn * vkp + c * vkq
    lam = np.empty(n)
    for i in range(n):
        lam[i] = A[i, i] if A[i, i] > 0.0 else 0.0
    order = np.argsort(lam)
    lam2 = np.empty(n)
    V2 = np.empty((n, n))
    for j in range(n):
        lam2[j] = lam[order[j]]
        for k in range(n):
            V2[k, j] = V[k, order[j]]
    return lam2, V2
