"""The sweep: candidate pairs of a whole scene by sort-and-sweep, and ``candidate_pairs``.

Two pair generators are provided, both producing exactly the set of pairs with
overlapping bounds that pass the relative test (relative.py): sort-and-sweep
along the axis of largest centre spread (default, here) and a uniform grid
(grid.py).  The sweep is the default, measured faster: bench/bench_scene.py
(equal on uniform scenes, faster on corridors, mixed sizes and dense clusters;
the grid wins only when bodies crowd two perpendicular strips).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from circle_collision_ros.core.broad.grid import (MAX_CELLS_PER_BODY, choose_cell_size, grid_kernel,
                                                  grow)
from circle_collision_ros.core.broad.relative import (PARALLEL_MIN_PAIRS, gather_states, rel_mask,
                                                      rel_mask_par)
from circle_collision_ros.core.parallel_policy import threads_pay

__all__ = ["candidate_pairs", "PARALLEL_MIN_BODIES"]


# Sort-and-sweep in strips.  A plain sweep along one axis tests every pair
# whose intervals overlap on that axis: ~N^2 w / L pairs for bounds of extent w
# in a scene of side L.  Cutting the scene into strips of height ~2w along a
# second axis and sweeping each strip separately tests only pairs that are
# close on both axes (~N^2 w^2 / L^2; measured: bench/scale.py).  A body enters
# every strip its bound covers; a pair is reported only in the strip holding
# the larger of the two lower bounds on the strip axis (a strip both bounds
# cover), so exactly once.  The entries of a strip are stored contiguously in
# sweep order (structure of arrays), so the inner loop reads memory
# sequentially.
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
            S = grow(S, n_box)
            T = grow(T, n_box)
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
                                    S[off[g] : off[g + 1]], T[off[g] : off[g + 1]], 0)
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
#: parallel_policy; below it a parallel launch saves about nothing: measured,
#: bench/bench_scene.py).
PARALLEL_MIN_BODIES = 4096


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
    order = np.argsort(lo[:, ax])  # numpy's sort: measured faster than numba's
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
        mask = rel_mask_par if threads_pay(n_box, PARALLEL_MIN_PAIRS) else rel_mask
        keep = mask(*states, S, T, t_start, t_end)
        S = S[keep]
        T = T[keep]
    return body[S], body[T], n_box


def candidate_pairs(lo: np.ndarray, hi: np.ndarray, *, p=None, v=None, a=None, r=None, tref=None,
                    t_start: float = 0.0, t_end: float = 0.0,
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
        return grid_kernel(lo, hi, cell, origin, p, v, a, r, tref, float(t_start), float(t_end),
                           use_rel, MAX_CELLS_PER_BODY)
    raise ValueError(f"unknown broad-phase method {method!r}")
