"""The grid: uniform cells of the swept bounds, and the hashed grid of the incremental scene.

``grid_kernel`` generates the candidate pairs of a whole scene on a uniform grid
(cell = mean bound extent, see ``choose_cell_size``); it produces exactly the
pairs of the sweep (sweep.py).  Per-body incremental queries (``Scene``) use a
hashed grid (:func:`cell_keys`), since a sweep cannot answer a single query
cheaply.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from circle_collision_ros.core.broad.relative import rel_keep

__all__ = ["grid_kernel", "choose_cell_size", "cell_keys", "grow", "MAX_CELLS_PER_BODY"]

#: A body whose bound covers more grid cells than this is checked against all bodies instead.
MAX_CELLS_PER_BODY = 64


@njit(cache=True, inline="always")
def _boxes_overlap(lo, hi, i, j):
    for k in range(lo.shape[1]):
        if lo[j, k] > hi[i, k] or lo[i, k] > hi[j, k]:
            return False
    return True


@njit(cache=True)
def grow(arr, k):
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
        I = grow(I, k)
        J = grow(J, k)
    I[k] = i
    J[k] = j
    return I, J, k + 1


@njit(cache=True, inline="always")
def _consider(I, J, k, n_box, i, j, lo, hi, p, v, a, r, tref, t_start, t_end, use_rel):
    """Keep (i, j) if its boxes overlap (counted) and, with use_rel, the relative test passes."""
    if not _boxes_overlap(lo, hi, i, j):
        return I, J, k, n_box
    a_ = min(i, j)
    b_ = max(i, j)
    if use_rel and not rel_keep(p, v, a, r, tref, a_, b_, t_start, t_end, p.shape[1]):
        return I, J, k, n_box + 1
    I, J, k = _push(I, J, k, a_, b_)
    return I, J, k, n_box + 1


@njit(cache=True, error_model="numpy")
def grid_kernel(lo, hi, cell, origin, p, v, a, r, tref, t_start, t_end, use_rel, max_cells):
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
            c *= h_ - l_ + 1
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
                    I, J, k_out, n_box = _consider(
                        I, J, k_out, n_box, i, j, lo, hi, p, v, a, r, tref, t_start, t_end, use_rel
                    )
        s = t
    # bodies too large for the grid: test against everyone
    for i in range(n):
        if not big[i]:
            continue
        for j in range(n):
            if j == i or (big[j] and j < i):
                continue
            I, J, k_out, n_box = _consider(
                I, J, k_out, n_box, i, j, lo, hi, p, v, a, r, tref, t_start, t_end, use_rel
            )
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
            c *= chi[i, k] - clo[i, k] + 1
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
