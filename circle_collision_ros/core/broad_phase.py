"""Broad phase: cull body pairs that provably cannot touch within a time window.

Every body moves on a parabola ``p(t) = p + v t + a t^2 / 2``.  Over a window
``[t0, t1]`` its centre stays inside the exact axis-aligned box of that arc
(per axis the extremes are at the window ends or where ``v_k + a_k t`` crosses
zero).  Inflating the box by the radius gives a swept bound of the body; two
bodies whose swept bounds are disjoint cannot touch in the window.

Surviving pairs then pass a second, tighter test on the *relative* motion
``d(t) = p_b(t) - p_a(t)``: the box of ``d`` over the window must come within
``r_a + r_b`` of the origin.  This also removes apart pairs that do not move
relative to each other (static, or identical motion: ``d`` is a point).

Guarantee (the "never lose a contact" property): a pair is dropped only if its
exact centre distance stays above ``r_a + r_b`` by more than a safety margin
over the whole window.  The margin (``_REL_MARGIN`` times the pair's motion
scale, plus ``_COORD_MARGIN`` times the absolute coordinates, plus
``_ABS_MARGIN``) absorbs the rounding of the float64 box arithmetic here
(propagation to the window start, the per-axis extremes, the sums: a few
ulps of the motion scale and of the coordinates) many times over; the narrow
phase decides the surviving pairs exactly, so the margin need not cover any
narrow-phase error.  It enlarges bounds by micrometres per metre of motion,
which costs nothing in cull rate.

Two pair generators are provided, both producing exactly the set of pairs with
overlapping bounds that pass the relative test: sort-and-sweep along the axis
of largest centre spread (default) and a uniform grid (cell = mean bound
extent).  ``bench/bench_scene.py`` chose the sweep: equal on uniform scenes
(10k bodies / 1 km^2: ~6 ms each), 1.2-1.7x faster on corridors, mixed sizes
and dense clusters; the grid wins only when bodies crowd two perpendicular
strips (~1.7x).  Per-body incremental queries (``Scene``) use a hashed grid
(:func:`cell_keys`), since a sweep cannot answer a single query cheaply.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit, prange
from numba.extending import register_jitable

from circle_collision_ros.core.kinematics import arc_position, arc_velocity
from circle_collision_ros.core.parallel_policy import threads_pay

__all__ = [
    "swept_bounds",
    "candidate_pairs",
    "propagate",
]

#: Relative safety margin on the motion scale (metres per metre of motion).
_REL_MARGIN = 4e-6
#: Relative safety margin on absolute coordinates (covers p_b - p_a rounding, ~4500 ulp).
_COORD_MARGIN = 1e-12
#: Absolute safety margin in metres (keeps the test non-strict for all-zero input).
_ABS_MARGIN = 1e-12
#: A body whose bound covers more grid cells than this is checked against all bodies instead.
_MAX_CELLS_PER_BODY = 64


def propagate(p: np.ndarray, v: np.ndarray, a: np.ndarray, dt) -> tuple[np.ndarray, np.ndarray]:
    """State after ``dt`` seconds under constant acceleration.

    ``p + v dt + a dt^2 / 2`` and ``v + a dt``; rows with ``dt == 0`` are
    returned bit-for-bit unchanged (so a state is never re-rounded when it is
    already at the requested time).  ``dt`` is a scalar or shape ``(N,)``.
    """
    p = np.asarray(p, dtype=np.float64)
    v = np.asarray(v, dtype=np.float64)
    a = np.asarray(a, dtype=np.float64)
    dt = np.asarray(dt, dtype=np.float64)
    dtc = dt[..., None] if dt.ndim else dt
    p2 = arc_position(p, v, a, dtc)
    v2 = arc_velocity(v, a, dtc)
    same = np.broadcast_to(dtc == 0.0, p2.shape)
    return np.where(same, p, p2), np.where(same, v, v2)


def swept_bounds(p: np.ndarray, v: np.ndarray, a: np.ndarray, r: np.ndarray,
                 t0, t1) -> tuple[np.ndarray, np.ndarray]:
    """Exact AABB of each body over ``[t0, t1]``, inflated by radius + margin.

    Parameters
    ----------
    p, v, a : (N, D) arrays, m, m/s, m/s^2, given at time 0.
    r : (N,) radii, m.
    t0, t1 : scalars or (N,) window bounds in s relative to the state time, t0 <= t1.

    Returns
    -------
    lo, hi : (N, D) float64 arrays, m.
    """
    p = np.ascontiguousarray(p, dtype=np.float64)
    v = np.ascontiguousarray(v, dtype=np.float64)
    a = np.ascontiguousarray(a, dtype=np.float64)
    r = np.ascontiguousarray(r, dtype=np.float64)
    t0 = np.ascontiguousarray(np.broadcast_to(np.asarray(t0, dtype=np.float64), r.shape))
    t1 = np.ascontiguousarray(np.broadcast_to(np.asarray(t1, dtype=np.float64), r.shape))
    return _swept_bounds_kernel(p, v, a, r, t0, t1)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def swept_bound_row(p, v, a, r, i, ta, tb, lo, hi, out):
    """Swept bounds of body ``i`` over the window [ta, tb] into lo/hi[out]: the one
    per-row rule behind `swept_bounds` and the scene's few-body updates."""
    D = p.shape[1]
    tm = max(abs(ta), abs(tb))
    motion = 0.0
    coord = 0.0
    for k in range(D):
        pk = p[i, k]
        vk = v[i, k]
        ak = a[i, k]
        x0 = arc_position(pk, vk, ak, ta)
        x1 = arc_position(pk, vk, ak, tb)
        # the arc's turning point -v/a where inside the window (a = 0:
        # inf or NaN, never inside)
        ts = -vk / ak
        xs = arc_position(pk, vk, ak, ts if (ts > ta) & (ts < tb) else ta)
        lo[out, k] = _fmin(_fmin(x0, x1), xs)
        hi[out, k] = _fmax(_fmax(x0, x1), xs)
        motion += abs(vk) * tm + 0.5 * abs(ak) * tm * tm
        coord = _fmax(coord, abs(pk))
    coord += motion
    pad = r[i] + _REL_MARGIN * (r[i] + motion) + _COORD_MARGIN * coord + _ABS_MARGIN
    for k in range(D):
        lo[out, k] -= pad
        hi[out, k] += pad


@njit(cache=True, nogil=True, error_model="numpy")
def _swept_bounds_kernel(p, v, a, r, t0, t1):
    n, D = p.shape
    lo = np.empty((n, D))
    hi = np.empty((n, D))
    for i in range(n):
        swept_bound_row(p, v, a, r, i, t0[i], t1[i], lo, hi, i)
    return lo, hi


# ---------------------------------------------------------------------------
# numba kernels
# ---------------------------------------------------------------------------

@njit(cache=True, error_model="numpy", inline="always")
def _rel_keep(p, v, a, r, tref, i, j, t_start, t_end, D):
    """True unless the pair provably cannot touch in [max(t_start, tref_i, tref_j), t_end].

    D = p.shape[1] passed as a constant 2 or 3 (see ``_rel_mask``), so the
    loop over axes unrolls.  Selects instead of branches where the outcome is
    data-dependent (mispredicted about every other pair); the values are
    those of the branching form bit for bit: a vertex time -dv/da that is not
    inside (0, W) (da = 0: inf or NaN) is replaced by 0, where the arc is at
    dp, already one end of its range.  (Whether a body is propagated, dt != 0,
    is the same for most pairs of a call: a branch.)"""
    tp = _fmax(t_start, _fmax(tref[i], tref[j]))
    W = _fmax(t_end - tp, 0.0)
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
        lo = _fmin(_fmin(dp, x1), xs)
        hi = _fmax(_fmax(dp, x1), xs)
        g = lo if lo > 0.0 else (hi if hi < 0.0 else 0.0)
        dist2 += g * g
        scale += abs(dp) + abs(dv) * W + 0.5 * abs(da) * W * W
        coord = _fmax(coord, _fmax(abs(pi), abs(pj)))
    m = _REL_MARGIN * scale + _COORD_MARGIN * coord + _ABS_MARGIN
    lim = R + m
    return dist2 <= lim * lim


@register_jitable
def _fmin(x, y):
    # a select (numba's min/max builtins branch)
    return x if x < y else y


@register_jitable
def _fmax(x, y):
    return x if x > y else y


@njit(cache=True, inline="always")
def _boxes_overlap(lo, hi, i, j):
    for k in range(lo.shape[1]):
        if lo[j, k] > hi[i, k] or lo[i, k] > hi[j, k]:
            return False
    return True


@njit(cache=True)
def _grow(arr, k):
    out = np.empty(max(16, 2 * arr.shape[0]), dtype=arr.dtype)
    out[:k] = arr[:k]
    return out


@njit(cache=True, inline="always")
def _next_cell(idx, first, last):
    """Odometer step of cell index `idx` over the box [first, last]; False after the last cell."""
    for k in range(idx.shape[0]):
        idx[k] += 1
        if idx[k] <= last[k]:
            return True
        idx[k] = first[k]
    return False


@njit(cache=True, inline="always")
def _push(I, J, k, i, j):
    """Append pair (i, j) at k, growing the buffers as needed; returns (I, J, k + 1)."""
    if k == I.shape[0]:
        I = _grow(I, k)
        J = _grow(J, k)
    I[k] = i
    J[k] = j
    return I, J, k + 1


@njit(cache=True, inline="always")
def _consider(I, J, k, n_box, i, j, lo, hi, p, v, a, r, tref, t_start, t_end, use_rel):
    """Keep pair (i, j) if its boxes overlap (counted) and, with use_rel, the relative test passes."""
    if not _boxes_overlap(lo, hi, i, j):
        return I, J, k, n_box
    a_ = min(i, j)
    b_ = max(i, j)
    if use_rel and not _rel_keep(p, v, a, r, tref, a_, b_, t_start, t_end, p.shape[1]):
        return I, J, k, n_box + 1
    I, J, k = _push(I, J, k, a_, b_)
    return I, J, k, n_box + 1


# Sort-and-sweep in strips.  A plain sweep along one axis tests every pair
# whose intervals overlap on that axis: ~N^2 w / L pairs for bounds of extent w
# in a scene of side L (20,000 bodies at 30k/km^2, H = 5 s: 3.7 million tests
# for 70,000 overlapping boxes).  Cutting the scene into strips of height ~2w
# along a second axis and sweeping each strip separately tests only pairs that
# are close on both axes (~N^2 w^2 / L^2, 10-40x fewer on the scale bench).  A
# body enters every strip its bound covers; a pair is reported only in the
# strip holding the larger of the two lower bounds on the strip axis (a strip
# both bounds cover), so exactly once.  The entries of a strip are stored
# contiguously in sweep order (structure of arrays), so the inner loop reads
# memory sequentially.
_STRIP_EXTENTS = 2.0  #: strip height in mean bound extents along the strip axis
_MAX_STRIPS_PER_BODY = 4  #: fewer, taller strips if bodies would cover more on average


@njit(cache=True, nogil=True)
def _strips(lo, hi, ay):
    """(y0, sh, first, last): strip k covers [y0 + k sh, y0 + (k+1) sh) on axis ay;
    body i lies in strips first[i]..last[i] (floor((x - y0) / sh) of its bounds:
    monotone in x, so a pair of overlapping bounds shares the strip of the larger
    lower bound)."""
    n = lo.shape[0]
    y0 = np.inf
    y1 = -np.inf
    ext = 0.0
    for i in range(n):
        y0 = min(y0, lo[i, ay])
        y1 = max(y1, hi[i, ay])
        ext += hi[i, ay] - lo[i, ay]
    sh = _STRIP_EXTENTS * ext / n
    span = y1 - y0
    # at most ~n strips, and on average at most _MAX_STRIPS_PER_BODY per body
    sh = max(sh, span / n, ext / (n * (_MAX_STRIPS_PER_BODY - 1)))
    if not (sh > 0.0 and sh < np.inf and span < np.inf):
        sh = np.inf  # one strip (degenerate or non-finite bounds)
    first = np.empty(n, dtype=np.int64)
    last = np.empty(n, dtype=np.int64)
    for i in range(n):
        if sh < np.inf:
            first[i] = np.int64(math.floor((lo[i, ay] - y0) / sh))
            last[i] = np.int64(math.floor((hi[i, ay] - y0) / sh))
        else:
            first[i] = 0
            last[i] = 0
    return first, last


@njit(cache=True, nogil=True)
def _strip_entries(order, first, last):
    """Entries of every strip in sweep order: (start (nstrips + 1,), body (E,))."""
    n = order.shape[0]
    ns = 0
    for i in range(n):
        ns = max(ns, last[i] + 1)
    start = np.zeros(ns + 1, dtype=np.int64)
    for i in range(n):
        for k in range(first[i], last[i] + 1):
            start[k + 1] += 1
    for k in range(ns):
        start[k + 1] += start[k]
    pos = start[:-1].copy()
    body = np.empty(start[ns], dtype=np.int64)
    for s in range(n):
        i = order[s]
        for k in range(first[i], last[i] + 1):
            body[pos[k]] = i
            pos[k] += 1
    return start, body


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _sweep_strip_range(lx, hx, elo, ehi, fs, start, k0, k1, S, T, n_box):
    """Append to S, T (from n_box) the overlapping entry pairs of strips k0..k1-1;
    returns the new count, or -1 if S, T are too short (nothing is grown here:
    the caller decides).

    Tests without branches (a data-dependent branch there mispredicts about
    every other pair): every visited pair is written, the count advances only
    for a kept one.  A pair is reported in the strip of the larger first strip
    only."""
    D = elo.shape[1]
    for k in range(k0, k1):
        s1 = start[k + 1]
        for s in range(start[k], s1):
            if n_box + (s1 - s) > S.shape[0]:
                return -1
            h = hx[s]
            fk = fs[s]
            for t in range(s + 1, s1):
                if lx[t] > h:
                    break
                ok = max(fk, fs[t]) == k
                for d in range(D):
                    ok &= (elo[t, d] <= ehi[s, d]) & (elo[s, d] <= ehi[t, d])
                S[n_box] = s
                T[n_box] = t
                n_box += ok
    return n_box


@njit(cache=True, nogil=True)
def _entry_bounds(lo, hi, ax, first, body):
    """Per-entry copies of the bounds in sweep order (lx, hx, elo, ehi, fs): the
    sweep then reads memory sequentially, not bodies scattered over the scene."""
    D = lo.shape[1]
    m = body.shape[0]
    lx = np.empty(m)
    hx = np.empty(m)
    elo = np.empty((m, D))
    ehi = np.empty((m, D))
    fs = np.empty(m, dtype=np.int64)
    for e in range(m):
        i = body[e]
        lx[e] = lo[i, ax]
        hx[e] = hi[i, ax]
        fs[e] = first[i]
        for k in range(D):
            elo[e, k] = lo[i, k]
            ehi[e, k] = hi[i, k]
    return lx, hx, elo, ehi, fs


@njit(cache=True, nogil=True)
def _lower_body_first(S, T, body):
    # body a of the relative test is the lower index (as relative_filter)
    for q in range(S.shape[0]):
        if body[S[q]] > body[T[q]]:
            S[q], T[q] = T[q], S[q]


@njit(cache=True, nogil=True, error_model="numpy")
def _sweep_strips(lo, hi, ax, first, start, body):
    """Entry pairs (S, T) of all strips whose bounds overlap, body[S] < body[T]."""
    lx, hx, elo, ehi, fs = _entry_bounds(lo, hi, ax, first, body)
    cap = max(16, 4 * body.shape[0])
    S = np.empty(cap, dtype=np.int64)
    T = np.empty(cap, dtype=np.int64)
    n_box = 0
    k = 0
    ns = start.shape[0] - 1
    while k < ns:
        # one strip at a time, growing the buffers when a strip might not fit
        got = _sweep_strip_range(lx, hx, elo, ehi, fs, start, k, k + 1, S, T, n_box)
        if got < 0:
            S = _grow(S, n_box)
            T = _grow(T, n_box)
            continue
        n_box = got
        k += 1
    S, T = S[:n_box], T[:n_box]
    _lower_body_first(S, T, body)
    return S, T


#: Strip groups of the threaded sweep (a fixed number, so the output order --
#: strip order -- does not depend on the thread count).
_SWEEP_GROUPS = 16
#: Room per entry for a group's pairs in the threaded sweep (never touched
#: beyond what is written: np.empty leaves the rest unmapped).
_PAIRS_PER_ENTRY = 8


@njit(cache=True, error_model="numpy", parallel=True)
def _sweep_strips_par(lo, hi, ax, first, start, body):
    """``_sweep_strips`` over numba's threads, the same pairs in the same order.

    The strips are cut into _SWEEP_GROUPS runs of about equal entry count;
    each is swept into its own slice of one buffer (_PAIRS_PER_ENTRY pairs per
    entry), then the slices are moved together in strip order.  If a group
    would overflow its slice (a cluster with more than _PAIRS_PER_ENTRY
    overlaps per entry), the serial sweep, which grows its buffers, answers
    instead."""
    m = body.shape[0]
    ns = start.shape[0] - 1
    lx, hx, elo, ehi, fs = _entry_bounds(lo, hi, ax, first, body)
    G = _SWEEP_GROUPS
    kcut = np.empty(G + 1, dtype=np.int64)  # group g holds strips kcut[g]..kcut[g+1]-1
    kcut[0] = 0
    k = 0
    for g in range(1, G):
        while k < ns and start[k] < (m * g) // G:
            k += 1
        kcut[g] = k
    kcut[G] = ns
    off = np.empty(G + 1, dtype=np.int64)
    off[0] = 0
    for g in range(G):
        off[g + 1] = off[g] + _PAIRS_PER_ENTRY * (start[kcut[g + 1]] - start[kcut[g]]) + 16
    S = np.empty(off[G], dtype=np.int64)
    T = np.empty(off[G], dtype=np.int64)
    cnt = np.empty(G, dtype=np.int64)
    for g in prange(G):
        cnt[g] = _sweep_strip_range(lx, hx, elo, ehi, fs, start, kcut[g], kcut[g + 1],
                                    S[off[g]:off[g + 1]], T[off[g]:off[g + 1]], 0)
    for g in range(G):
        if cnt[g] < 0:
            return _sweep_strips(lo, hi, ax, first, start, body)
    total = 0
    for g in range(G):
        if off[g] != total:  # off[g] >= total: a forward move
            for q in range(cnt[g]):
                S[total + q] = S[off[g] + q]
                T[total + q] = T[off[g] + q]
        total += cnt[g]
    S, T = S[:total], T[:total]
    _lower_body_first(S, T, body)
    return S, T


#: Bodies from which the sweep may run on numba's threads (when a core is free:
#: parallel_policy; at 5,000 bodies the serial sweep takes ~0.2 ms, about
#: what a parallel launch can save on an idle core).
PARALLEL_MIN_BODIES = 4096


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


@njit(cache=True, nogil=True, error_model="numpy")
def _rel_mask(p, v, a, r, tref, I, J, t_start, t_end):
    """``_rel_keep`` of pairs (I[q], J[q])."""
    out = np.empty(I.shape[0], dtype=np.bool_)
    if p.shape[1] == 2:
        for q in range(I.shape[0]):
            out[q] = _rel_keep(p, v, a, r, tref, I[q], J[q], t_start, t_end, 2)
    else:
        for q in range(I.shape[0]):
            out[q] = _rel_keep(p, v, a, r, tref, I[q], J[q], t_start, t_end, 3)
    return out


@njit(cache=True, error_model="numpy", parallel=True)
def _rel_mask_par(p, v, a, r, tref, I, J, t_start, t_end):
    """``_rel_mask`` over numba's threads (each pair independent: the same mask)."""
    out = np.empty(I.shape[0], dtype=np.bool_)
    if p.shape[1] == 2:
        for q in prange(I.shape[0]):
            out[q] = _rel_keep(p, v, a, r, tref, I[q], J[q], t_start, t_end, 2)
    else:
        for q in prange(I.shape[0]):
            out[q] = _rel_keep(p, v, a, r, tref, I[q], J[q], t_start, t_end, 3)
    return out


#: Bound-overlapping pairs from which the relative test may run on numba's
#: threads (when a core is free: parallel_policy; ~40 ns per pair serial).
PARALLEL_MIN_PAIRS = 16384


@njit(cache=True, nogil=True)
def _sweep_axes(lo, hi):
    """(ax, ay): the axes of largest and second largest centre spread (variance)."""
    n, D = lo.shape
    spread = np.empty(D)
    for k in range(D):
        m = 0.0
        for i in range(n):
            m += 0.5 * (lo[i, k] + hi[i, k])
        m /= n
        q = 0.0
        for i in range(n):
            c = 0.5 * (lo[i, k] + hi[i, k]) - m
            q += c * c
        spread[k] = q
    ax = 0
    for k in range(D):
        if spread[k] > spread[ax]:
            ax = k
    ay = 1 if ax == 0 else 0
    for k in range(D):
        if k != ax and spread[k] > spread[ay]:
            ay = k
    return ax, ay


def _sweep(lo, hi, p, v, a, r, tref, t_start, t_end, use_rel):
    """The sweep generator: (I, J, n_box) as ``candidate_pairs``."""
    ax, ay = _sweep_axes(lo, hi)
    order = np.argsort(lo[:, ax])  # numpy's sort: ~3x faster than numba's
    # sort-and-sweep in strips: sweep along axis ax, strips across axis ay
    first, last = _strips(lo, hi, ay)
    start, body = _strip_entries(order, first, last)
    sweep = _sweep_strips_par if threads_pay(lo.shape[0], PARALLEL_MIN_BODIES) else _sweep_strips
    S, T = sweep(lo, hi, ax, first, start, body)
    n_box = S.shape[0]
    if use_rel and n_box:
        # the entries' states as contiguous rows: the relative test then reads
        # neighbouring memory, not bodies scattered over the scene
        states = gather_states(body, p, v, a, r) + (tref[body],)
        mask = _rel_mask_par if threads_pay(n_box, PARALLEL_MIN_PAIRS) else _rel_mask
        keep = mask(*states, S, T, t_start, t_end)
        S = S[keep]
        T = T[keep]
    return body[S], body[T], n_box


@njit(cache=True, error_model="numpy")
def _grid_kernel(lo, hi, cell, origin, p, v, a, r, tref, t_start, t_end, use_rel, max_cells):
    n, D = lo.shape
    clo = np.empty((n, D), dtype=np.int64)
    chi = np.empty((n, D), dtype=np.int64)
    span = np.zeros(D, dtype=np.int64)
    big = np.zeros(n, dtype=np.bool_)
    total = 0
    for i in range(n):
        c = 1
        for k in range(D):
            l_ = np.int64(math.floor((lo[i, k] - origin[k]) / cell))
            h_ = np.int64(math.floor((hi[i, k] - origin[k]) / cell))
            clo[i, k] = l_
            chi[i, k] = h_
            c *= (h_ - l_ + 1)
            if c > max_cells:
                c = max_cells + 1
            span[k] = max(span[k], h_ + 1)
        if c > max_cells:
            big[i] = True
        else:
            total += c
    # linear cell key; the caller picks `cell` so that the product fits in int64
    mult = np.ones(D, dtype=np.int64)
    for k in range(1, D):
        mult[k] = mult[k - 1] * (span[k - 1] + 1)
    keys = np.empty(total, dtype=np.int64)
    body = np.empty(total, dtype=np.int64)
    e = 0
    idx = np.zeros(D, dtype=np.int64)
    for i in range(n):
        if big[i]:
            continue
        for k in range(D):
            idx[k] = clo[i, k]
        while True:
            key = 0
            for k in range(D):
                key += idx[k] * mult[k]
            keys[e] = key
            body[e] = i
            e += 1
            if not _next_cell(idx, clo[i], chi[i]):
                break
    order = np.argsort(keys, kind="mergesort")
    cap = max(16, 4 * n)
    I = np.empty(cap, dtype=np.int64)
    J = np.empty(cap, dtype=np.int64)
    k_out = 0
    n_box = 0
    s = 0
    while s < total:
        key = keys[order[s]]
        t = s
        while t < total and keys[order[t]] == key:
            t += 1
        # decode this cell's integer coordinates
        rem = key
        for kk in range(D - 1, -1, -1):
            idx[kk] = rem // mult[kk]
            rem -= idx[kk] * mult[kk]
        for u in range(s, t):
            i = body[order[u]]
            for w in range(u + 1, t):
                j = body[order[w]]
                # report the pair only from the cell holding the low corner of the
                # boxes' intersection, so each pair is produced exactly once
                mine = True
                for kk in range(D):
                    if max(clo[i, kk], clo[j, kk]) != idx[kk]:
                        mine = False
                        break
                if mine:
                    I, J, k_out, n_box = _consider(I, J, k_out, n_box, i, j, lo, hi, p, v, a, r,
                                                   tref, t_start, t_end, use_rel)
        s = t
    # bodies too large for the grid: test against everyone
    for i in range(n):
        if not big[i]:
            continue
        for j in range(n):
            if j == i or (big[j] and j < i):
                continue
            I, J, k_out, n_box = _consider(I, J, k_out, n_box, i, j, lo, hi, p, v, a, r, tref,
                                           t_start, t_end, use_rel)
    return I[:k_out].copy(), J[:k_out].copy(), n_box


def choose_cell_size(lo: np.ndarray, hi: np.ndarray) -> tuple[float, np.ndarray]:
    """Grid cell edge (m) and origin for the given bounds.

    The edge is the mean bound extent (so a typical body covers about 2^D
    cells), enlarged if needed so that linear cell keys fit in int64.
    """
    D = lo.shape[1]
    d = hi - lo
    ext = d[:, 0].copy()
    for k in range(1, D):  # the row maximum, exactly np.max(d, axis=1), without its per-row loop
        np.maximum(ext, d[:, k], out=ext)
    cell = float(np.mean(ext)) if ext.size else 1.0
    origin = lo.min(axis=0) if lo.size else np.zeros(D)
    span = float(np.max(hi.max(axis=0) - origin)) if lo.size else 0.0
    per_dim = 2.0 ** (60 // D - 1)
    cell = max(cell, span / per_dim, 1e-9 * max(1.0, span))
    if not math.isfinite(cell) or cell <= 0.0:
        cell = 1.0
    return cell, origin


def candidate_pairs(lo: np.ndarray, hi: np.ndarray, *, p=None, v=None, a=None, r=None,
                    tref=None, t_start: float = 0.0, t_end: float = 0.0,
                    method: str = "sweep") -> tuple[np.ndarray, np.ndarray, int]:
    """Pairs ``(i, j)``, ``i < j``, whose bounds overlap (and that pass the relative test).

    Parameters
    ----------
    lo, hi : (N, D) bounds from :func:`swept_bounds`.
    p, v, a, r, tref : optional body states (given at times ``tref``, s). When
        given, a pair is kept only if its relative motion can come within
        ``r_i + r_j`` (+ margin) of contact over ``[max(t_start, tref_i, tref_j), t_end]``.
    method : ``"sweep"`` (default) or ``"grid"``; both return the same pair set.

    Returns
    -------
    i, j : int64 arrays, unordered; n_box : number of bound-overlapping pairs.
    """
    lo = np.ascontiguousarray(lo, dtype=np.float64)
    hi = np.ascontiguousarray(hi, dtype=np.float64)
    n, D = lo.shape
    use_rel = p is not None
    if not use_rel:
        p = v = a = np.zeros((n, D))
        r = tref = np.zeros(n)
    p = np.ascontiguousarray(p, dtype=np.float64)
    v = np.ascontiguousarray(v, dtype=np.float64)
    a = np.ascontiguousarray(a, dtype=np.float64)
    r = np.ascontiguousarray(r, dtype=np.float64)
    tref = np.zeros(n) if tref is None else np.ascontiguousarray(tref, dtype=np.float64)
    if n < 2:
        e = np.empty(0, dtype=np.int64)
        return e, e.copy(), 0
    if method == "sweep":
        return _sweep(lo, hi, p, v, a, r, tref, float(t_start), float(t_end), use_rel)
    if method == "grid":
        cell, origin = choose_cell_size(lo, hi)
        return _grid_kernel(lo, hi, cell, origin, p, v, a, r, tref, float(t_start), float(t_end),
                            use_rel, _MAX_CELLS_PER_BODY)
    raise ValueError(f"unknown broad-phase method {method!r}")


def relative_filter(p, v, a, r, tref, I, J, t_start: float, t_end: float) -> np.ndarray:
    """Boolean mask: pair ``(I[k], J[k])`` may touch within ``[max(t_start, tref), t_end]``.

    The same test (and margin) as the one fused into :func:`candidate_pairs`;
    ``I[k]`` plays body a (the narrow phase's ``p_a``).
    """
    return _rel_mask(
        np.ascontiguousarray(p, dtype=np.float64), np.ascontiguousarray(v, dtype=np.float64),
        np.ascontiguousarray(a, dtype=np.float64), np.ascontiguousarray(r, dtype=np.float64),
        np.ascontiguousarray(tref, dtype=np.float64), np.ascontiguousarray(I, dtype=np.int64),
        np.ascontiguousarray(J, dtype=np.int64), float(t_start), float(t_end))


# ---------------------------------------------------------------------------
# hashed grid for incremental (per body) neighbour queries
# ---------------------------------------------------------------------------

@njit(cache=True, inline="always")
def _hash_cell(idx):
    # wrap-around int64 hash of integer cell coordinates; collisions only add
    # candidates (every candidate still passes the exact bound-overlap test)
    h = np.int64(0)
    for k in range(idx.shape[0]):
        h = h * np.int64(-7046029254386353131) + idx[k] + np.int64(0x9E3779B97F4A7C15 - (1 << 64))
    return h


@njit(cache=True)
def cell_keys(lo, hi, cell, max_cells):
    """Hashed keys of the grid cells covered by each bound, flattened.

    Returns ``(keys, owner, big)``: ``keys[e]`` is a cell of body ``owner[e]``;
    bodies covering more than ``max_cells`` cells get no keys and ``big=True``.
    """
    n, D = lo.shape
    clo = np.empty((n, D), dtype=np.int64)
    chi = np.empty((n, D), dtype=np.int64)
    big = np.zeros(n, dtype=np.bool_)
    total = 0
    for i in range(n):
        c = 1
        for k in range(D):
            l_ = math.floor(lo[i, k] / cell)
            h_ = math.floor(hi[i, k] / cell)
            if h_ - l_ >= max_cells:
                c = max_cells + 1
                l_ = 0.0
                h_ = 0.0
            clo[i, k] = np.int64(l_)
            chi[i, k] = np.int64(h_)
            c *= (chi[i, k] - clo[i, k] + 1)
            if c > max_cells:
                c = max_cells + 1
        if c > max_cells:
            big[i] = True
        else:
            total += c
    keys = np.empty(total, dtype=np.int64)
    owner = np.empty(total, dtype=np.int64)
    idx = np.empty(D, dtype=np.int64)
    e = 0
    for i in range(n):
        if big[i]:
            continue
        for k in range(D):
            idx[k] = clo[i, k]
        while True:
            keys[e] = _hash_cell(idx)
            owner[e] = i
            e += 1
            if not _next_cell(idx, clo[i], chi[i]):
                break
    return keys, owner, big
