"""Contact geometry at a known contact time (point, normal, closing speed)."""
from __future__ import annotations

import numpy as np


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
    p_a, v_a, a_a, p_b, v_b, a_b = (np.asarray(x, dtype=np.float64)
                                    for x in (p_a, v_a, a_a, p_b, v_b, a_b))
    r_a = np.asarray(r_a, dtype=np.float64)[..., None]
    np.asarray(r_b, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)[..., None]
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        h = 0.5 * t
        # relative centre b - a at t, from relative quantities (no cancellation
        # of large absolute coordinates)
        g = (p_b - p_a) + t * ((v_b - v_a) + h * (a_b - a_a))
        w = (v_a - v_b) + t * (a_a - a_b)  # relative velocity of a w.r.t. b
        ng = np.sqrt(np.sum(g * g, axis=-1, keepdims=True))
        nw = np.sqrt(np.sum(w * w, axis=-1, keepdims=True))
        ex = np.zeros_like(g)
        ex[..., 0] = 1.0
        fallback = np.where(nw > 0, w / np.where(nw > 0, nw, 1.0), ex)
        n = np.where(ng > 0, g / np.where(ng > 0, ng, 1.0), fallback)
        pa_t = p_a + t * (v_a + h * a_a)
        point = pa_t + r_a * n
        closing = np.sum(w * n, axis=-1)
        bad = ~np.isfinite(t[..., 0]) | ~np.isfinite(closing) | ~np.all(np.isfinite(point), axis=-1)
        bad = bad | ~(r_a[..., 0] >= 0)
    point = np.where(bad[..., None], np.nan, point)
    n = np.where(bad[..., None], np.nan, n)
    closing = np.where(bad, np.nan, closing)
    return point, n, closing
