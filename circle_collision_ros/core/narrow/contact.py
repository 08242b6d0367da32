"""Contact geometry at a known contact time (point, normal, closing speed).

One formula, compiled once (``contact_row``), behind every caller: the public
``contact_details`` (any broadcastable shapes), ``details_on_rows`` (pair rows,
e.g. the scene's) and ``details_on_index_pairs`` (pairs of a body table without
gathering their rows first).  The same row gives the same bits whichever path
computed it.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from circle_collision_ros.core.parallel_policy import threads_pay

__all__ = ["contact_details", "contact_row", "details_on_rows", "details_on_index_pairs"]


@njit(cache=True, nogil=True, error_model="numpy")
def contact_row(pa, va, aa, i, ra, pb, vb, ab, j, t, point, normal, k, g, w):
    """Contact point and normal of a pair at ``t`` into row ``k`` of
    ``point``/``normal`` (D = their width); returns the closing speed.

    Body a is row ``i`` of ``pa, va, aa`` (radius ``ra``), body b row ``j``
    of ``pb, vb, ab`` (2-D arrays indexed in place: row views would cost more
    than the formula).  ``g``, ``w``: scratch of length D.  Relative centre and
    velocity are formed first (``p_b - p_a``), so large map-frame coordinates
    do not cancel digits of the normal.  Sums over the axis run x0 + x1 (+ x2),
    left to right.  A non-finite ``t``, point or closing speed, or a negative
    or NaN radius, gives NaN in all outputs.
    """
    D = point.shape[1]
    h = 0.5 * t
    for d in range(D):
        g[d] = (pb[j, d] - pa[i, d]) + t * ((vb[j, d] - va[i, d]) + h * (ab[j, d] - aa[i, d]))
        w[d] = (va[i, d] - vb[j, d]) + t * (aa[i, d] - ab[j, d])
    sg = g[0] * g[0]
    sw = w[0] * w[0]
    for d in range(1, D):
        sg += g[d] * g[d]
        sw += w[d] * w[d]
    ng = math.sqrt(sg)
    nw = math.sqrt(sw)
    for d in range(D):
        if ng > 0:
            normal[k, d] = g[d] / ng
        elif nw > 0:  # coincident centres: along the relative velocity
            normal[k, d] = w[d] / nw
        else:
            normal[k, d] = 1.0 if d == 0 else 0.0
    finite = True
    for d in range(D):
        point[k, d] = (pa[i, d] + t * (va[i, d] + h * aa[i, d])) + ra * normal[k, d]
        finite = finite and math.isfinite(point[k, d])
    closing = w[0] * normal[k, 0]
    for d in range(1, D):
        closing += w[d] * normal[k, d]
    if not (math.isfinite(t) and math.isfinite(closing) and finite and ra >= 0):
        for d in range(D):
            point[k, d] = np.nan
            normal[k, d] = np.nan
        closing = np.nan
    return closing


@njit(cache=True, nogil=True, error_model="numpy")
def _rows_kernel(pa, va, aa, ra, pb, vb, ab, t, point, normal, closing):
    D = point.shape[1]
    g = np.empty(D)
    w = np.empty(D)
    for k in range(t.shape[0]):
        closing[k] = contact_row(pa, va, aa, k, ra[k], pb, vb, ab, k, t[k], point, normal, k, g, w)


@njit(cache=True, nogil=True, error_model="numpy")
def _index_kernel(p, v, a, r, I, J, t, point, normal, closing):
    D = point.shape[1]
    g = np.empty(D)
    w = np.empty(D)
    for k in range(t.shape[0]):
        i = I[k]
        closing[k] = contact_row(p, v, a, i, r[i], p, v, a, J[k], t[k], point, normal, k, g, w)


#: Contacts from which details_on_index_pairs may run on numba's threads (when
#: a core is free: parallel_policy).
PARALLEL_MIN_CONTACTS = 4096
_BLOCK = 512  #: rows per parallel task (one pair of scratch vectors each)


@njit(cache=True, error_model="numpy", parallel=True)
def _index_kernel_par(p, v, a, r, I, J, t, point, normal, closing):
    """``_index_kernel`` in blocks over numba's threads: every row is computed by the same
    compiled ``contact_row`` from its own inputs alone, so the bits do not depend on
    the split."""
    D = point.shape[1]
    n = t.shape[0]
    nb = (n + _BLOCK - 1) // _BLOCK
    for b in prange(nb):
        g = np.empty(D)
        w = np.empty(D)
        for k in range(b * _BLOCK, min(n, (b + 1) * _BLOCK)):
            i = I[k]
            closing[k] = contact_row(p, v, a, i, r[i], p, v, a, J[k], t[k], point, normal, k, g, w)


def _f64(x) -> np.ndarray:
    return np.ascontiguousarray(x, dtype=np.float64)


def details_on_rows(pa, va, aa, ra, pb, vb, ab, t):
    """``contact_details`` on row-aligned pair arrays: (n, D) states, (n,) ra and t."""
    n, D = np.shape(pa)
    point, normal, closing = np.empty((n, D)), np.empty((n, D)), np.empty(n)
    _rows_kernel(_f64(pa), _f64(va), _f64(aa), _f64(ra), _f64(pb), _f64(vb), _f64(ab), _f64(t),
                 point, normal, closing)
    return point, normal, closing


def details_on_index_pairs(p, v, a, r, I, J, t):
    """``contact_details`` of pairs ``(I[k], J[k])`` of the bodies (p, v, a, r) at ``t[k]``."""
    n, D = I.shape[0], np.shape(p)[1]
    point, normal, closing = np.empty((n, D)), np.empty((n, D)), np.empty(n)
    kernel = _index_kernel_par if threads_pay(n, PARALLEL_MIN_CONTACTS) else _index_kernel
    kernel(_f64(p), _f64(v), _f64(a), _f64(r), np.ascontiguousarray(I, dtype=np.int64),
           np.ascontiguousarray(J, dtype=np.int64), _f64(t), point, normal, closing)
    return point, normal, closing


def contact_details(p_a, v_a, a_a, r_a, p_b, v_b, a_b, r_b, t):
    """Contact point, unit normal and closing speed of a pair at time ``t``.

    Parameters
    ----------
    p_a, v_a, a_a, p_b, v_b, a_b : array_like, shape (..., D), D = 2 or 3
        Centre position [m], velocity [m/s], acceleration [m/s^2] at t = 0.
    r_a, r_b : array_like, shape (...)
        Radii [m] (``r_b`` is accepted for a symmetric signature; the
        contact point is defined from body a).
    t : array_like, shape (...)
        Contact time [s], e.g. from ``time_to_collision``.

    Returns
    -------
    point : ndarray (..., D)
        Point on the centre line at distance ``r_a`` from a's centre at ``t``
        (for an overlap at t = 0 the same formula is used).  [m]
    normal : ndarray (..., D)
        Unit vector from a's centre towards b's centre at ``t``.  For
        coincident centres: the direction of the relative velocity
        ``v_a(t) - v_b(t)`` (a is moving towards b along it), else +x.
    closing_speed : ndarray (...)
        ``(v_a(t) - v_b(t)) . normal`` [m/s], > 0 when approaching.

    Elements with non-finite ``t`` (e.g. ``inf`` = no contact) or invalid
    inputs give NaN in all three outputs.  The centre line is formed from
    relative quantities (``p_b - p_a`` first), so map-frame offsets do not
    cancel digits of the normal.
    """
    vecs = [np.asarray(x, dtype=np.float64) for x in (p_a, v_a, a_a, p_b, v_b, a_b)]
    ra = np.asarray(r_a, dtype=np.float64)
    np.asarray(r_b, dtype=np.float64)
    tt = np.asarray(t, dtype=np.float64)
    shape = np.broadcast_shapes(*(x.shape for x in vecs), ra.shape + (1,), tt.shape + (1,))
    lead, D = shape[:-1], shape[-1]
    m = math.prod(lead)
    pa, va, aa, pb, vb, ab = (np.broadcast_to(x, shape).reshape(m, D) for x in vecs)
    point, normal, closing = details_on_rows(pa, va, aa, np.broadcast_to(ra, lead).reshape(m),
                                             pb, vb, ab, np.broadcast_to(tt, lead).reshape(m))
    return point.reshape(shape), normal.reshape(shape), closing.reshape(lead)
