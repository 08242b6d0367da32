"""Competitor first-contact solvers for ``bench_core.py`` (not used in production).

All take the same arguments as ``time_to_collision`` with 2-D/3-D row arrays
``(n, D)`` / ``(n,)`` and a scalar horizon, and return float64 ``(n,)``.
They expand the contact quartic in power basis (in *relative* coordinates,
to be fair) and filter roots with an ``|imag| < tol`` test -- exactly the
approaches issue #3 warns about; they are here for speed comparison only.
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
