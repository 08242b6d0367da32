"""mpmath references for the uncertainty tests (independent of the core's code paths).

* ``overlap_reference(mean, S, R)``: P(|X| <= R) for X ~ N(mean, S), S as the
  float matrix given (its eigen-decomposition in 40-digit arithmetic), then
  tanh-sinh quadrature (mpmath.quad) over the narrow eigen-direction with
  break points at the density's peak and at the inner factor's transitions.
* ``independent_reference(R, m, s)``: the same for independent components
  (no rotation), e.g. for Ruben's mixture, which takes them in that form.
* ``isotropic_reference(m, s, R, D)``: the noncentral chi-square CDF by its
  Poisson series (a second, quadrature-free formula for S = s^2 I).
"""
from __future__ import annotations

import mpmath as mp


def _interval(lo, hi, m, s):
    """P(lo <= N(m, s^2) <= hi) in mpmath."""
    r2 = mp.sqrt(2)
    return (mp.erf((hi - m) / (s * r2)) - mp.erf((lo - m) / (s * r2))) / 2


def _disc(R, m1, s1, m2, s2):
    """P(y1^2 + y2^2 <= R^2), independent normals (mpmath numbers, s >= 0)."""
    if s1 > s2:
        m1, s1, m2, s2 = m2, s2, m1, s1
    if R <= 0:
        return mp.mpf(0)
    if s2 == 0:
        return mp.mpf(1) if m1 ** 2 + m2 ** 2 <= R ** 2 else mp.mpf(0)
    if s1 == 0:
        if abs(m1) >= R:
            return mp.mpf(0)
        w = mp.sqrt(R ** 2 - m1 ** 2)
        return _interval(-w, w, m2, s2)
    lo = max(-R, m1 - 14 * s1)
    hi = min(R, m1 + 14 * s1)
    if lo >= hi:
        return mp.mpf(0)
    pts = {lo, hi}
    if lo < m1 < hi:
        pts.add(m1)
    for c in (abs(m2) - 3 * s2, abs(m2), abs(m2) + 3 * s2):
        if 0 < c < R:
            x = mp.sqrt(R ** 2 - c ** 2)
            for y in (x, -x):
                if lo < y < hi:
                    pts.add(y)
    pts = sorted(pts)

    def f(x):
        w = mp.sqrt(max(R ** 2 - x ** 2, 0))
        return mp.npdf(x, m1, s1) * _interval(-w, w, m2, s2)

    return mp.quad(f, pts)


def _ball(R, m, s):
    order = sorted(range(3), key=lambda i: s[i])
    (m1, s1), (m2, s2), (m3, s3) = [(m[i], s[i]) for i in order]
    if R <= 0:
        return mp.mpf(0)
    if s1 == 0:
        if abs(m1) >= R:
            return mp.mpf(0)
        return _disc(mp.sqrt(R ** 2 - m1 ** 2), m2, s2, m3, s3)
    lo = max(-R, m1 - 14 * s1)
    hi = min(R, m1 + 14 * s1)
    if lo >= hi:
        return mp.mpf(0)
    pts = sorted({lo, hi} | ({m1} if lo < m1 < hi else set()))

    def f(x):
        w = mp.sqrt(max(R ** 2 - x ** 2, 0))
        return mp.npdf(x, m1, s1) * _disc(w, m2, s2, m3, s3)

    return mp.quad(f, pts)


def overlap_reference(mean, S, R, dps: int = 40) -> float:
    """P(|X| <= R), X ~ N(mean, S): mean (D,), S (D, D) floats as given."""
    with mp.workdps(dps):
        D = len(mean)
        A = mp.matrix([[mp.mpf(float(S[i][j])) for j in range(D)] for i in range(D)])
        A = (A + A.T) / 2
        lam, Q = mp.eigsy(A)
        mu = [sum(Q[k, j] * mp.mpf(float(mean[k])) for k in range(D)) for j in range(D)]
        s = [mp.sqrt(max(lam[j], 0)) for j in range(D)]
        return float(_independent(mp.mpf(float(R)), mu, s))


def _independent(R, m, s):
    """P(sum y_i^2 <= R^2), independent y_i ~ N(m_i, s_i^2), 2 or 3 components (mpmath numbers)."""
    if len(m) == 2:
        return _disc(R, m[0], s[0], m[1], s[1])
    return _ball(R, m, s)


def independent_reference(R: float, m, s, dps: int = 30) -> float:
    """P(sum y_i^2 <= R^2) for independent y_i ~ N(m_i, s_i^2) (2 or 3 components,
    floats as given): the quadrature above, without an eigen-decomposition."""
    with mp.workdps(dps):
        return float(_independent(mp.mpf(float(R)), [mp.mpf(float(v)) for v in m],
                                  [mp.mpf(float(v)) for v in s]))


def isotropic_reference(m: float, s: float, R: float, D: int, dps: int = 40) -> float:
    """P(|X| <= R) for X ~ N(mean, s^2 I), |mean| = m: noncentral chi-square
    CDF with D dof and noncentrality (m/s)^2 at (R/s)^2, Poisson series."""
    with mp.workdps(dps):
        lam = (mp.mpf(m) / s) ** 2 / 2
        x = (mp.mpf(R) / s) ** 2 / 2
        # Poisson weights beyond 14 standard deviations of the mode are < 1e-40
        sd = mp.sqrt(lam)
        j_lo = max(0, int(lam - 14 * sd - 30))
        j_hi = int(lam + 14 * sd + 60)
        total = mp.mpf(0)
        for j in range(j_lo, j_hi + 1):
            w = mp.exp(-lam + j * mp.log(lam) - mp.loggamma(j + 1)) if lam > 0 else mp.mpf(j == 0)
            total += w * mp.gammainc(mp.mpf(D) / 2 + j, 0, x, regularized=True)
        return float(total)
