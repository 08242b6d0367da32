"""Competitor first-contact solvers for ``bench_core.py`` and
``bench/accuracy_vs_time.py`` (not used in production).

All take the same arguments as ``time_to_collision`` with 2-D/3-D row arrays
``(n, D)`` / ``(n,)`` and a scalar horizon, and return float64 ``(n,)``.
They expand the contact quartic in power basis and filter roots with an
``|imag| < tol`` test -- the power-basis approaches whose loss of digits
the accuracy benchmark shows:

* ``ttc_numpy_roots_loop``, ``ttc_companion_eigvals``, ``ttc_ferrari``: the
  quartic in *relative* coordinates (to be fair), overlap at t = 0 -> 0;
* ``ttc_lecture``: the seed lecture's formulation verbatim (coefficients
  expanded from *absolute* coordinates, 1e-6 tolerances, no overlap case).
"""

from __future__ import annotations

import math

import numpy as np

IMAG_TOL = 1e-9


def quartic_coefficients(p_a, v_a, a_a, r_a, p_b, v_b, a_b, r_b):
    """Power-basis coefficients (c4, c3, c2, c1, c0), each shape (n,)."""
    dp = np.asarray(p_a, float) - p_b
    dv = np.asarray(v_a, float) - v_b
    da = np.asarray(a_a, float) - a_b
    R = np.asarray(r_a, float) + r_b
    c4 = 0.25 * np.einsum("ij,ij->i", da, da)
    c3 = np.einsum("ij,ij->i", da, dv)
    c2 = np.einsum("ij,ij->i", dv, dv) + np.einsum("ij,ij->i", da, dp)
    c1 = 2.0 * np.einsum("ij,ij->i", dp, dv)
    c0 = np.einsum("ij,ij->i", dp, dp) - R * R
    return c4, c3, c2, c1, c0


def _first_root(roots: np.ndarray, c0: float, horizon: float) -> float:
    if c0 <= 0.0:
        return 0.0
    r = roots[np.abs(roots.imag) <= IMAG_TOL * (1.0 + np.abs(roots.real))].real
    r = r[(r >= 0.0) & (r <= horizon)]
    return float(r.min()) if r.size else math.inf


def ttc_numpy_roots_loop(p_a, v_a, a_a, r_a, p_b, v_b, a_b, r_b, horizon=math.inf):
    """Python loop over ``numpy.roots`` (companion eigenvalues per pair)."""
    C = np.stack(quartic_coefficients(p_a, v_a, a_a, r_a, p_b, v_b, a_b, r_b), axis=1)
    out = np.empty(C.shape[0])
    for i in range(C.shape[0]):
        out[i] = _first_root(np.roots(C[i]), C[i, 4], horizon)  # np.roots strips leading zeros
    return out


def ttc_companion_eigvals(p_a, v_a, a_a, r_a, p_b, v_b, a_b, r_b, horizon=math.inf):
    """Batched ``numpy.linalg.eigvals`` on stacked 4x4 companion matrices.

    Rows with a zero leading coefficient (no relative acceleration) are
    sent to the ``numpy.roots`` loop, which handles the lower degree.
    """
    c4, c3, c2, c1, c0 = quartic_coefficients(p_a, v_a, a_a, r_a, p_b, v_b, a_b, r_b)
    n = c4.shape[0]
    out = np.empty(n)
    quart = c4 != 0.0
    idx = np.nonzero(quart)[0]
    M = np.zeros((idx.size, 4, 4))
    M[:, 1, 0] = M[:, 2, 1] = M[:, 3, 2] = 1.0
    lead = c4[idx]
    M[:, 0, 0] = -c3[idx] / lead
    M[:, 0, 1] = -c2[idx] / lead
    M[:, 0, 2] = -c1[idx] / lead
    M[:, 0, 3] = -c0[idx] / lead
    ev = np.linalg.eigvals(M)
    real = np.abs(ev.imag) <= IMAG_TOL * (1.0 + np.abs(ev.real))
    ok = real & (ev.real >= 0.0) & (ev.real <= horizon)
    t = np.where(ok, ev.real, np.inf).min(axis=1)
    t[c0[idx] <= 0.0] = 0.0
    out[idx] = t
    rest = np.nonzero(~quart)[0]
    for i in rest:
        out[i] = _first_root(np.roots([c4[i], c3[i], c2[i], c1[i], c0[i]]), c0[i], horizon)
    return out


# --------------------------------------------------------------------------
# Closed-form quartic (Ferrari, resolvent cubic by Cardano), numpy-vectorised
# --------------------------------------------------------------------------

_SQRT2 = math.sqrt(2.0)


def _cbrt_c(z: np.ndarray) -> np.ndarray:
    """Principal complex cube root."""
    return np.where(z == 0, 0.0 + 0.0j, np.exp(np.log(np.where(z == 0, 1.0, z)) / 3.0))


def quartic_roots_ferrari(a, b, c, d, e) -> np.ndarray:
    """All four complex roots of ``a x^4 + b x^3 + c x^2 + d x + e`` (rows, ``a != 0``).

    Textbook Ferrari: depress (``x = y - b/4a``), solve the resolvent cubic
    ``m^3 + p m^2 + (p^2/4 - r) m - q^2/8 = 0`` by Cardano in complex
    arithmetic, take its root of largest real part, and split the quartic into
    two quadratics ``y^2 +- sqrt(2m) y + (p/2 + m -+ q/(2 sqrt(2m)))``.
    Biquadratic rows (``q == 0``) are solved as a quadratic in ``y^2``.
    Returns shape ``(n, 4)`` complex.
    """
    a, b, c, d, e = (np.asarray(x, dtype=np.float64) for x in (a, b, c, d, e))
    with np.errstate(all="ignore"):
        B, C, D, E = b / a, c / a, d / a, e / a
        p = C - 0.375 * B * B
        q = D - 0.5 * B * C + 0.125 * B**3
        r = E - 0.25 * B * D + 0.0625 * B * B * C - 3.0 / 256.0 * B**4
        # resolvent cubic m^3 + p m^2 + (p^2/4 - r) m - q^2/8, depressed by m = z - p/3
        k1 = 0.25 * p * p - r
        P = k1 - p * p / 3.0
        Q = 2.0 * p**3 / 27.0 - p * k1 / 3.0 - q * q / 8.0
        disc = (0.25 * Q * Q + P**3 / 27.0).astype(np.complex128)
        u = _cbrt_c(-0.5 * Q + np.sqrt(disc))
        u = np.where(u == 0, _cbrt_c((-Q).astype(np.complex128)), u)
        w = np.exp(2j * np.pi / 3.0)
        zs = []
        for k in range(3):
            uk = u * w**k
            zs.append(np.where(uk == 0, 0.0, uk - P / (3.0 * np.where(uk == 0, 1.0, uk))))
        m = np.stack(zs, axis=1) - (p / 3.0)[:, None]
        m = m[np.arange(m.shape[0]), np.argmax(m.real, axis=1)]
        s = np.sqrt(2.0 * m)
        s_safe = np.where(s == 0, 1.0, s)
        half = 0.5 * p + m
        qq = q / (2.0 * s_safe)
        # y^2 + s y + (half - qq) = 0 and y^2 - s y + (half + qq) = 0
        d1 = np.sqrt(s * s - 4.0 * (half - qq))
        d2 = np.sqrt(s * s - 4.0 * (half + qq))
        y = np.stack([(-s + d1) / 2, (-s - d1) / 2, (s + d2) / 2, (s - d2) / 2], axis=1)
        # biquadratic (q == 0): y^2 = (-p +- sqrt(p^2 - 4r)) / 2
        bq = q == 0
        if np.any(bq):
            sd = np.sqrt((p[bq] * p[bq] - 4.0 * r[bq]).astype(np.complex128))
            y1 = np.sqrt((-p[bq] + sd) / 2)
            y2 = np.sqrt((-p[bq] - sd) / 2)
            y[bq] = np.stack([y1, -y1, y2, -y2], axis=1)
        return y - (0.25 * B)[:, None]


def _quadratic_roots(b, c, d):
    """Roots of ``b x^2 + c x + d`` per row (textbook formula), shape (n, 2) complex.

    ``b == 0`` rows become linear (root twice); ``b == c == 0`` rows have none (NaN).
    """
    with np.errstate(all="ignore"):
        sq = np.sqrt((c * c - 4.0 * b * d).astype(np.complex128))
        r = np.stack([(-c - sq) / (2.0 * b), (-c + sq) / (2.0 * b)], axis=1)
        lin = b == 0
        r[lin] = (-d[lin] / c[lin])[:, None]
    return r


def ttc_ferrari(p_a, v_a, a_a, r_a, p_b, v_b, a_b, r_b, horizon=math.inf):
    """Closed-form Ferrari/Cardano on the power-basis quartic (relative coordinates).

    Same contract adapters as the other baselines: ``c0 <= 0`` (overlap) -> 0,
    real roots by ``|imag| <= IMAG_TOL (1 + |real|)``, first root in
    ``[0, horizon]``.  Rows without relative acceleration (``c4 == 0``, hence
    ``c3 == 0``) use the textbook quadratic formula.
    """
    c4, c3, c2, c1, c0 = quartic_coefficients(p_a, v_a, a_a, r_a, p_b, v_b, a_b, r_b)
    n = c4.shape[0]
    roots = np.full((n, 4), np.nan + 0j)
    quart = c4 != 0.0
    if np.any(quart):
        roots[quart] = quartic_roots_ferrari(c4[quart], c3[quart], c2[quart], c1[quart], c0[quart])
    if np.any(~quart):
        roots[~quart, :2] = _quadratic_roots(c2[~quart], c1[~quart], c0[~quart])
    with np.errstate(invalid="ignore"):
        real = np.abs(roots.imag) <= IMAG_TOL * (1.0 + np.abs(roots.real))
        ok = real & (roots.real >= 0.0) & (roots.real <= horizon)
    t = np.where(ok, roots.real, np.inf).min(axis=1)
    t[c0 <= 0.0] = 0.0
    return t


# --------------------------------------------------------------------------
# The seed lecture's formulation (absolute coordinates, maxima coefficients)
# --------------------------------------------------------------------------

LECTURE_TOL = 1e-6  # the lecture's absolute tolerance for "real" and for "t > 0"


def lecture_coefficients(p_a, v_a, a_a, r_a, p_b, v_b, a_b, r_b):
    """The lecture's A..E (``At^4 + Bt^3 + Ct^2 + Dt + E``) from absolute coordinates.

    Written out as printed (wxmaxima output; the lecture's variable ``l`` is
    printed as the digit ``1``): a=xi, b=xj, c=vxi, d=vxj, e=aix, f=ajx, g=yi,
    h=yj, k=vyi, l=vyj, m=aiy, n=ajy, o=ri, p=rj.  These are 4x our
    ``quartic_coefficients`` (the roots are the same).  The lecture is 2-D;
    for 3-D rows the z terms are added by the same pattern as the y terms.
    """
    P_a, V_a, A_a, P_b, V_b, A_b = (
        np.asarray(x, dtype=np.float64) for x in (p_a, v_a, a_a, p_b, v_b, a_b)
    )
    o = np.asarray(r_a, dtype=np.float64)
    p = np.asarray(r_b, dtype=np.float64)
    sqr = np.square
    a, b, c, d, e, f = P_a[:, 0], P_b[:, 0], V_a[:, 0], V_b[:, 0], A_a[:, 0], A_b[:, 0]
    g, h, k, l, m, n = P_a[:, 1], P_b[:, 1], V_a[:, 1], V_b[:, 1], A_a[:, 1], A_b[:, 1]  # noqa: E741
    # verbatim from the lecture (same evaluation order), "1" read as l
    A = sqr(n) - 2.0 * m * n + sqr(m) + sqr(f) - 2.0 * e * f + sqr(e)
    B = (
        (4.0 * l - 4.0 * k) * n
        + (4.0 * k - 4.0 * l) * m
        + (4.0 * d - 4.0 * c) * f
        + (4.0 * c - 4.0 * d) * e
    )
    C = (
        (4.0 * h - 4.0 * g) * n
        + (4.0 * g - 4.0 * h) * m
        + 4.0 * sqr(l)
        - 8.0 * k * l
        + 4.0 * sqr(k)
        + (4.0 * b - 4.0 * a) * f
        + (4.0 * a - 4.0 * b) * e
        + 4.0 * sqr(d)
        - 8.0 * c * d
        + 4.0 * sqr(c)
    )
    D = (
        (8.0 * h - 8.0 * g) * l
        + (8.0 * g - 8.0 * h) * k
        + (8.0 * b - 8.0 * a) * d
        + (8.0 * a - 8.0 * b) * c
    )
    E = (
        4.0 * sqr(h)
        - 8.0 * g * h
        + 4.0 * sqr(g)
        + 4.0 * sqr(b)
        - 8.0 * a * b
        + 4.0 * sqr(a)
        - sqr(2.0 * (p + o))
    )
    if P_a.shape[1] == 3:  # not in the lecture: z terms by the same pattern as y
        g, h, k, l, m, n = P_a[:, 2], P_b[:, 2], V_a[:, 2], V_b[:, 2], A_a[:, 2], A_b[:, 2]  # noqa: E741
        A = A + (sqr(n) - 2.0 * m * n + sqr(m))
        B = B + ((4.0 * l - 4.0 * k) * n + (4.0 * k - 4.0 * l) * m)
        C = C + (
            (4.0 * h - 4.0 * g) * n
            + (4.0 * g - 4.0 * h) * m
            + 4.0 * sqr(l)
            - 8.0 * k * l
            + 4.0 * sqr(k)
        )
        D = D + ((8.0 * h - 8.0 * g) * l + (8.0 * g - 8.0 * h) * k)
        E = E + (4.0 * sqr(h) - 8.0 * g * h + 4.0 * sqr(g))
    return A, B, C, D, E


def ttc_lecture(p_a, v_a, a_a, r_a, p_b, v_b, a_b, r_b, horizon=math.inf):
    """The seed lecture's method: expanded absolute-coordinate quartic, closed-form
    roots (Ferrari as above; textbook quadratic when ``A == 0``), a root is real
    if ``|imag| < 1e-6`` and counts if ``t > 1e-6``; the smallest such root is
    the collision time (then limited to the horizon).  No special case for
    bodies that already overlap at t = 0 (the lecture has none).
    """
    A, B, C, D, E = lecture_coefficients(p_a, v_a, a_a, r_a, p_b, v_b, a_b, r_b)
    n = E.shape[0]
    roots = np.full((n, 4), np.nan + 0j)
    quart = A != 0.0
    if np.any(quart):
        roots[quart] = quartic_roots_ferrari(A[quart], B[quart], C[quart], D[quart], E[quart])
    if np.any(~quart):
        roots[~quart, :2] = _quadratic_roots(C[~quart], D[~quart], E[~quart])
    with np.errstate(invalid="ignore"):
        ok = (
            (np.abs(roots.imag) < LECTURE_TOL)
            & (roots.real > LECTURE_TOL)
            & (roots.real <= horizon)
        )
    return np.where(ok, roots.real, np.inf).min(axis=1)
