"""Static broad phase: a uniform grid over a world's edges and corner points.

Built once per world (``StaticIndex.build``, off the prediction path); a query visits only
the cells a body's swept box over [0, H] covers, so its cost does not grow with the size of
the map.  Items are stored in compressed rows (``ptr``, ``items``) per cell; an edge is
listed in every cell its bounding box touches.  Cell coordinates are computed in float64
and every box is widened by one cell, so rounding can only add candidates, never drop one.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from circle_collision_ros.core.static.world import StaticWorld

__all__ = ["StaticIndex"]

# A grid of at most this many cells per axis: 4 M cells of int64 pointers, 32 MB at most.
MAX_CELLS_PER_AXIS = 2048


@njit(cache=True, nogil=True, error_model="numpy")
def cell_range(lo, hi, x0, y0, inv_h, nx, ny):
    """Inclusive cell range of a box, widened by one cell and clipped to the grid."""
    i0 = int(math.floor((lo[0] - x0) * inv_h)) - 1
    j0 = int(math.floor((lo[1] - y0) * inv_h)) - 1
    i1 = int(math.floor((hi[0] - x0) * inv_h)) + 1
    j1 = int(math.floor((hi[1] - y0) * inv_h)) + 1
    return max(i0, 0), max(j0, 0), min(i1, nx - 1), min(j1, ny - 1)


# nogil: the node builds an index on a worker thread while its executor predicts
@njit(cache=True, nogil=True, error_model="numpy")
def _fill(lo, hi, x0, y0, inv_h, nx, ny):
    """CSR rows (ptr, items) listing item k in every cell its box [lo[k], hi[k]] touches."""
    n = lo.shape[0]
    count = np.zeros(nx * ny + 1, np.int64)
    for k in range(n):
        i0, j0, i1, j1 = cell_range(lo[k], hi[k], x0, y0, inv_h, nx, ny)
        for j in range(j0, j1 + 1):
            for i in range(i0, i1 + 1):
                count[j * nx + i + 1] += 1
    ptr = np.cumsum(count)
    fill = ptr[:-1].copy()
    items = np.empty(ptr[-1], np.int32)
    for k in range(n):
        i0, j0, i1, j1 = cell_range(lo[k], hi[k], x0, y0, inv_h, nx, ny)
        for j in range(j0, j1 + 1):
            for i in range(i0, i1 + 1):
                c = j * nx + i
                items[fill[c]] = k
                fill[c] += 1
    return ptr, items


@dataclass(frozen=True)
class StaticIndex:
    """A world and its grid: origin ``(x0, y0)``, cell side ``h`` (m), ``nx`` x ``ny`` cells;
    ``edge_ptr``/``edge_items`` and ``point_ptr``/``point_items`` per cell (row-major)."""

    world: StaticWorld
    x0: float
    y0: float
    h: float
    nx: int
    ny: int
    edge_ptr: np.ndarray
    edge_items: np.ndarray
    point_ptr: np.ndarray
    point_items: np.ndarray

    @classmethod
    def build(cls, world: StaticWorld) -> "StaticIndex":
        """Index ``world``: cells of 0.3 of the mean area per edge, no smaller than the
        median edge (see the measurement at the choice)."""
        s, e, p = world.starts, world.ends, world.points
        if world.empty:
            one = np.zeros(2, np.int64)
            none = np.empty(0, np.int32)
            return cls(world, 0.0, 0.0, 1.0, 1, 1, one, none, one.copy(), none.copy())
        lo = np.minimum(s, e) if len(s) else np.empty((0, 2))
        hi = np.maximum(s, e) if len(s) else np.empty((0, 2))
        all_lo = np.concatenate([lo, p]).min(axis=0)
        all_hi = np.concatenate([hi, p]).max(axis=0)
        ext = np.maximum(all_hi - all_lo, 1e-9)
        n = max(len(s), len(p), 1)
        # cells of ~0.3 of the mean area per edge: on bench_static_node's 200 m map a
        # 1,000-body frame took 23, 13, 5.3 and 10 ms at factors 1, 0.5, 0.3 and 0.15
        # (fewer candidates per body against more cells visited)
        h = 0.3 * math.sqrt(float(ext[0] * ext[1]) / n)
        if len(s):
            h = max(h, float(np.median(np.abs(e - s).max(axis=1))))
        h = max(h, float(ext.max()) / MAX_CELLS_PER_AXIS)
        nx = int(min(MAX_CELLS_PER_AXIS, math.floor(ext[0] / h) + 1))
        ny = int(min(MAX_CELLS_PER_AXIS, math.floor(ext[1] / h) + 1))
        x0, y0 = float(all_lo[0]), float(all_lo[1])
        inv = 1.0 / h
        eptr, eitems = _fill(np.ascontiguousarray(lo), np.ascontiguousarray(hi), x0, y0, inv,
                             nx, ny)
        pptr, pitems = _fill(p, p, x0, y0, inv, nx, ny)
        return cls(world, x0, y0, h, nx, ny, eptr, eitems, pptr, pitems)
