"""The relative filter: a second, tighter test on the pairs whose swept bounds overlap.

The test is on the *relative* motion ``d(t) = p_b(t) - p_a(t)``: the box of
``d`` over the window must come within ``r_a + r_b`` (+ the margin of
bounds.py) of the origin.  This also removes apart pairs that do not move
relative to each other (static, or identical motion: ``d`` is a point).
"""
from __future__ import annotations

import numpy as np
from numba import njit, prange

from circle_collision_ros.core.broad.bounds import ABS_MARGIN, COORD_MARGIN, REL_MARGIN, fmax, fmin
from circle_collision_ros.core.kinematics import arc_position, arc_velocity

__all__ = ["rel_keep", "rel_mask", "rel_mask_par", "relative_filter", "gather_states",
           "PARALLEL_MIN_PAIRS"]


@njit(cache=True, error_model="numpy", inline="always")
def rel_keep(p, v, a, r, tref, i, j, t_start, t_end, D):
    """True unless the pair provably cannot touch in [max(t_start, tref_i, tref_j), t_end].

    D = p.shape[1] passed as a constant 2 or 3 (see ``rel_mask``), so the
    loop over axes unrolls.  Selects instead of branches where the outcome is
    data-dependent (mispredicted about every other pair); the values are
    those of the branching form bit for bit: a vertex time -dv/da that is not
    inside (0, W) (da = 0: inf or NaN) is replaced by 0, where the arc is at
    dp, already one end of its range.  (Whether a body is propagated, dt != 0,
    is the same for most pairs of a call: a branch.)"""
    tp = fmax(t_start, fmax(tref[i], tref[j]))
    W = fmax(t_end - tp, 0.0)
    dti = tp - tref[i]
    dtj = tp - tref[j]
    R = r[i] + r[j]
    dist2 = 0.0
    scale = R
    coord = 0.0
    for k in range(D):
        pi = p[i, k]
        vi = v[i, k]
        ai = a[i, k]
        pj = p[j, k]
        vj = v[j, k]
        aj = a[j, k]
        if dti != 0.0:
            pi = arc_position(p[i, k], vi, ai, dti)
            vi = arc_velocity(vi, ai, dti)
        if dtj != 0.0:
            pj = arc_position(p[j, k], vj, aj, dtj)
            vj = arc_velocity(vj, aj, dtj)
        dp = pj - pi
        dv = vj - vi
        da = aj - ai
        x1 = arc_position(dp, dv, da, W)
        ts = -dv / da
        ts = ts if (ts > 0.0) & (ts < W) else 0.0
        xs = arc_position(dp, dv, da, ts)
        lo = fmin(fmin(dp, x1), xs)
        hi = fmax(fmax(dp, x1), xs)
        g = lo if lo > 0.0 else (hi if hi < 0.0 else 0.0)
        dist2 += g * g
        scale += abs(dp) + abs(dv) * W + 0.5 * abs(da) * W * W
        coord = fmax(coord, fmax(abs(pi), abs(pj)))
    m = REL_MARGIN * scale + COORD_MARGIN * coord + ABS_MARGIN
    lim = R + m
    return dist2 <= lim * lim


@njit(cache=True, nogil=True, error_model="numpy")
def rel_mask(p, v, a, r, tref, I, J, t_start, t_end):
    """``rel_keep`` of pairs (I[q], J[q])."""
    out = np.empty(I.shape[0], dtype=np.bool_)
    if p.shape[1] == 2:
        for q in range(I.shape[0]):
            out[q] = rel_keep(p, v, a, r, tref, I[q], J[q], t_start, t_end, 2)
    else:
        for q in range(I.shape[0]):
            out[q] = rel_keep(p, v, a, r, tref, I[q], J[q], t_start, t_end, 3)
    return out


@njit(cache=True, error_model="numpy", parallel=True)
def rel_mask_par(p, v, a, r, tref, I, J, t_start, t_end):
    """``rel_mask`` over numba's threads (each pair independent: the same mask)."""
    out = np.empty(I.shape[0], dtype=np.bool_)
    if p.shape[1] == 2:
        for q in prange(I.shape[0]):
            out[q] = rel_keep(p, v, a, r, tref, I[q], J[q], t_start, t_end, 2)
    else:
        for q in prange(I.shape[0]):
            out[q] = rel_keep(p, v, a, r, tref, I[q], J[q], t_start, t_end, 3)
    return out


#: Bound-overlapping pairs from which the relative test may run on numba's
#: threads (when a core is free: parallel_policy).
PARALLEL_MIN_PAIRS = 16384


def relative_filter(p, v, a, r, tref, I, J, t_start: float, t_end: float) -> np.ndarray:
    """Boolean mask: pair ``(I[k], J[k])`` may touch within ``[max(t_start, tref), t_end]``.

    The same test (and margin) as the one fused into :func:`candidate_pairs`;
    ``I[k]`` plays body a (the narrow phase's ``p_a``).
    """
    return rel_mask(
        np.ascontiguousarray(p, dtype=np.float64), np.ascontiguousarray(v, dtype=np.float64),
        np.ascontiguousarray(a, dtype=np.float64), np.ascontiguousarray(r, dtype=np.float64),
        np.ascontiguousarray(tref, dtype=np.float64), np.ascontiguousarray(I, dtype=np.int64),
        np.ascontiguousarray(J, dtype=np.int64), float(t_start), float(t_end))


@njit(cache=True, nogil=True)
def gather_states(idx, p, v, a, r):
    """(p[idx], v[idx], a[idx], r[idx]) in one pass (contiguous rows)."""
    m = idx.shape[0]
    D = p.shape[1]
    q = np.empty((m, D))
    w = np.empty((m, D))
    e = np.empty((m, D))
    s = np.empty(m)
    for k in range(m):
        i = idx[k]
        s[k] = r[i]
        for d in range(D):
            q[k, d] = p[i, d]
            w[k, d] = v[i, d]
            e[k, d] = a[i, d]
    return q, w, e, s
