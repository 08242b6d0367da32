"""An occupancy grid as static geometry: the merged boundary edges of its occupied cells.

A ``nav_msgs/OccupancyGrid`` (row-major ``data[iy * width + ix]``, values 0..100
or -1 unknown, ``resolution`` metres per cell, ``origin`` the pose of cell
(0, 0)'s corner) becomes a small set of segments for the collision predictor:
the boundary between occupied and free cells, with unit cell sides merged into
maximal straight runs, so a long wall is four segments and interior cells give
none.

Conventions (the tests check each against a brute-force reference):

* Cell ``(ix, iy)`` is the square between grid corners ``(ix, iy)`` and
  ``(ix + 1, iy + 1)``; ``occupied[iy, ix]`` is its state.  Cells outside the
  grid are free, so the grid border is a boundary where occupied cells touch it.
* Every edge has an occupied cell on its LEFT and a free cell on its right
  (seen along start -> end): boundaries run counter-clockwise around occupied
  regions and clockwise around holes.  The map frame is a rotation plus a
  translation of the grid frame, so this holds in metres as well.
* An edge is a maximal run of unit sides on one grid line with the same
  occupied side.  Runs break where the boundary turns and where the occupied
  side flips.  At a checkerboard corner (two occupied cells touching only
  diagonally) all four boundary pieces end at the shared corner and none passes
  through it: both occupied cells are solid squares and the two free cells are
  free, so the corner is a pinch point of the boundary, and every edge is a
  straight piece of the true boundary.  (On a grid line through such a corner
  the two sides have opposite occupied sides, so the break falls out of the
  merging rule itself.)
* Map coordinates of a corner: ``origin + R(yaw) @ (corner * resolution)``
  in float64.  With ``yaw = 0`` this is ``origin + corner * resolution``
  exactly as written (``cos = 1``, ``sin = 0``); with a dyadic resolution
  (0.0625, unlike 0.05) ``corner * resolution`` is exact, so each coordinate
  is the true corner rounded once.  Exact integer corners are
  returned alongside (``start_cell``, ``end_cell``).
"""
from __future__ import annotations

import math
import operator
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numba import njit

__all__ = ["occupied_cells", "GridFrame", "GridEdges", "boundary_edges", "cell_occupied_at",
           "DEFAULT_THRESHOLD"]

#: Occupancy value (0..100) from which a cell counts as occupied (ROS map_server's 0.65).
DEFAULT_THRESHOLD = 65


def _positive_int(name: str, value) -> int:
    try:
        n = operator.index(value)
    except TypeError:
        raise ValueError(f"{name} must be an integer, got {value!r}") from None
    if n <= 0:
        raise ValueError(f"{name} must be > 0, got {n}")
    return n


def occupied_cells(data, width: int, height: int, threshold: int = DEFAULT_THRESHOLD,
                   unknown_is_occupied: bool = False) -> np.ndarray:
    """Occupied cells of an occupancy grid's ``data``, shape ``(height, width)``, bool.

    A cell is occupied when its value is ``>= threshold``; unknown cells
    (negative values: ROS uses -1) are free unless ``unknown_is_occupied``.
    ``data`` is row-major (``data[iy * width + ix]``): a sequence of ints, an
    integer array, or a bytes-like object of int8 (``uint8`` arrays are read as
    int8, so a serialized 255 is -1).  Values above 100 count as occupied.

    Raises ValueError naming the problem: data not 1-D or not integers,
    ``len(data) != width * height``, width or height not a positive integer,
    threshold not an integer in 0..100.
    """
    width = _positive_int("width", width)
    height = _positive_int("height", height)
    try:
        threshold = operator.index(threshold)
    except TypeError:
        raise ValueError(f"threshold must be an integer in 0..100, got {threshold!r}") from None
    if not 0 <= threshold <= 100:
        raise ValueError(f"threshold must be in 0..100, got {threshold}")
    if isinstance(data, (bytes, bytearray, memoryview)):
        values = np.frombuffer(data, dtype=np.int8)
    else:
        values = np.asarray(data)
    if values.dtype == np.uint8:
        values = values.view(np.int8)
    if values.ndim != 1:
        raise ValueError(f"data must be 1-D (row-major), got shape {values.shape}")
    if values.size and values.dtype.kind not in "iu":
        raise ValueError(f"data must hold integers, got dtype {values.dtype}")
    if values.size != width * height:
        raise ValueError(f"data has {values.size} values, width*height = {width * height} "
                         f"(width {width}, height {height})")
    values = values.reshape(height, width)
    # threshold >= 0, so negative (unknown) values are never >= threshold
    occupied = values >= threshold
    if unknown_is_occupied:
        occupied |= values < 0
    return occupied


def _finite(name: str, value) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"GridFrame.{name} must be a real number, got {value!r}") from None
    if not math.isfinite(x):
        raise ValueError(f"GridFrame.{name} must be finite, got {x}")
    return x


@dataclass(frozen=True)
class GridFrame:
    """Pose and scale of a grid: grid-corner coordinates <-> map frame (metres).

    Corner ``(ix, iy)`` is at ``origin + R(yaw) @ (ix * resolution, iy * resolution)``.

    Attributes
    ----------
    resolution : cell side, m (finite, > 0).
    origin_x, origin_y : map position of corner (0, 0), m (finite).
    yaw : rotation of the grid about z, rad (finite).
    """

    resolution: float
    origin_x: float = 0.0
    origin_y: float = 0.0
    yaw: float = 0.0

    def __post_init__(self) -> None:
        for name in ("resolution", "origin_x", "origin_y", "yaw"):
            object.__setattr__(self, name, _finite(name, getattr(self, name)))
        if not self.resolution > 0.0:
            raise ValueError(f"GridFrame.resolution must be > 0, got {self.resolution}")

    def cell_to_map(self, ix, iy) -> tuple[np.ndarray, np.ndarray]:
        """Map coordinates (m, float64 arrays) of grid-corner coordinates ``(ix, iy)``.

        Integer arguments give cell corners; fractional ones points inside
        cells (``ix + 0.5, iy + 0.5`` is the centre of cell ``(ix, iy)``).
        """
        px = np.asarray(ix, dtype=np.float64) * self.resolution
        py = np.asarray(iy, dtype=np.float64) * self.resolution
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        # yaw = 0: c = 1, s = 0, so x = origin_x + px with one rounding (module docstring)
        return self.origin_x + (c * px - s * py), self.origin_y + (s * px + c * py)

    def map_to_cell(self, x, y) -> tuple[np.ndarray, np.ndarray]:
        """Continuous grid coordinates ``(fx, fy)`` of map points (inverse of `cell_to_map`).

        Cell ``(floor(fx), floor(fy))`` contains the point (cells half-open).
        """
        dx = np.asarray(x, dtype=np.float64) - self.origin_x
        dy = np.asarray(y, dtype=np.float64) - self.origin_y
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return (c * dx + s * dy) / self.resolution, (c * dy - s * dx) / self.resolution


class GridEdges(NamedTuple):
    """Merged boundary edges, occupied side on the left of start -> end.

    Rows are ordered: horizontal edges by grid line then x, then vertical
    edges by grid line then y.
    """

    start: np.ndarray       #: (E, 2) float64, map frame, m
    end: np.ndarray         #: (E, 2) float64, map frame, m
    start_cell: np.ndarray  #: (E, 2) int64 grid-corner coordinates (ix, iy), exact
    end_cell: np.ndarray    #: (E, 2) int64 grid-corner coordinates (ix, iy), exact


def _check_occupied(occupied) -> np.ndarray:
    occ = np.asarray(occupied)
    if occ.dtype != np.bool_:
        # raw occupancy values (e.g. -1) would all count as occupied
        raise ValueError(f"occupied must be a bool array (see occupied_cells), got dtype "
                         f"{occ.dtype}")
    if occ.ndim != 2:
        raise ValueError(f"occupied must be 2-D (height, width), got shape {occ.shape}")
    return occ


@njit(cache=True, nogil=True)
def _scan(P, fill, per_line, line, first, last, value):
    """One pass over the padded cells ``P`` (module ``_boundary_runs``): the horizontal runs
    (written in order from row 0 when ``fill``) and each vertical line's runs (counted in
    ``per_line``; when ``fill``, written at ``per_line[x]``, the line's next slot, which
    then advances).  Returns the number of horizontal runs.  The inner loops are plain
    loads and compares over a row, in memory order."""
    rows, cols = P.shape  # h + 2, w + 2
    w = cols - 2
    n = 0
    for j in range(rows - 1):  # horizontal line y = j: cells of pad rows j + 1 (above), j
        above, below = P[j + 1], P[j]
        prev, start = 0, 0
        for c in range(1, cols):  # column w + 1 is padding: it closes the last run
            v = np.int64(above[c]) - np.int64(below[c])
            if v != prev:
                if prev != 0:
                    if fill:
                        line[n], first[n], last[n], value[n] = j, start, c - 1, prev
                    n += 1
                start, prev = c - 1, v
    open_v = np.zeros(w + 1, np.int64)
    open_s = np.zeros(w + 1, np.int64)
    for r in range(1, rows):  # vertical lines x = i at cell row r - 1 (row h + 1: padding)
        cells = P[r]
        for i in range(w + 1):
            v = np.int64(cells[i]) - np.int64(cells[i + 1])
            if v != open_v[i]:
                if open_v[i] != 0:
                    if fill:
                        k = per_line[i]
                        line[k], first[k], last[k], value[k] = i, open_s[i], r - 1, open_v[i]
                    per_line[i] += 1
                open_v[i], open_s[i] = v, r - 1
    return n


@njit(cache=True, nogil=True)
def _boundary_runs(occ):
    """Every maximal run of equal nonzero values along the grid lines: (line, first corner,
    one-past-last corner, value) arrays and how many of the rows are horizontal.

    Horizontal line y = j, unit side (i, j) -> (i + 1, j): value occ[j, i] - occ[j - 1, i]
    (+1: the cell above is occupied). Vertical line x = i, side (i, j) -> (i, j + 1): value
    occ[j, i - 1] - occ[j, i] (+1: the cell on its left is occupied); cells outside the grid
    are free (a zero border around a copy of the grid makes that branch-free). Rows:
    horizontal runs by line then x, then vertical runs by line then y.

    Two passes (``_scan``): count, then fill, each vertical run at its line's slot, so no
    sort. Compiled without the GIL: a large map is indexed on the worker thread while the
    executor keeps predicting.
    """
    h, w = occ.shape
    P = np.zeros((h + 2, w + 2), np.uint8)
    for j in range(h):
        for i in range(w):
            P[j + 1, i + 1] = occ[j, i]
    per_line = np.zeros(w + 1, np.int64)
    empty = np.empty(0, np.int64)
    nh = _scan(P, False, per_line, empty, empty, empty, empty)
    slot = np.empty(w + 1, np.int64)
    total = nh
    for i in range(w + 1):
        slot[i] = total
        total += per_line[i]
    line, first, last = (np.empty(total, np.int64), np.empty(total, np.int64),
                         np.empty(total, np.int64))
    value = np.empty(total, np.int64)
    _scan(P, True, slot, line, first, last, value)
    return line, first, last, value, nh


def boundary_edges(occupied, frame: GridFrame) -> GridEdges:
    """Merged boundary edges between occupied and free cells (module docstring).

    Parameters
    ----------
    occupied : (height, width) bool, ``occupied[iy, ix]`` (`occupied_cells`).
    frame : the grid's pose and resolution.

    Returns
    -------
    GridEdges with E rows; every unit cell side between an occupied and a free
    (or outside) cell is covered by exactly one edge, no two edges overlap, and
    no two could be merged (collinear, touching end to start, same direction).
    """
    occ = _check_occupied(occupied)
    line, first, last, value, n_h = _boundary_runs(np.ascontiguousarray(occ))
    hl, hs, he, hv = line[:n_h], first[:n_h], last[:n_h], value[:n_h]
    vl, vs, ve, vv = line[n_h:], first[n_h:], last[n_h:], value[n_h:]
    hpos, vpos = hv > 0, vv > 0
    # (ix, iy) corners; a run from corner s to corner e, reversed where the value is -1
    sx = np.concatenate([np.where(hpos, hs, he), vl]).astype(np.int64)
    sy = np.concatenate([hl, np.where(vpos, vs, ve)]).astype(np.int64)
    ex = np.concatenate([np.where(hpos, he, hs), vl]).astype(np.int64)
    ey = np.concatenate([hl, np.where(vpos, ve, vs)]).astype(np.int64)
    start_cell = np.stack([sx, sy], axis=1)
    end_cell = np.stack([ex, ey], axis=1)
    start = np.stack(frame.cell_to_map(sx, sy), axis=1)
    end = np.stack(frame.cell_to_map(ex, ey), axis=1)
    return GridEdges(start, end, start_cell, end_cell)


def cell_occupied_at(occupied, frame: GridFrame, x, y) -> np.ndarray:
    """Whether map points ``(x, y)`` (m) lie in occupied cells; bool, broadcast shape.

    Cells are half-open (a point on a shared side belongs to the cell with the
    larger index); points outside the grid, or NaN, are free.  A point within
    rounding of a cell side may land in either neighbouring cell.
    """
    occ = _check_occupied(occupied)
    h, w = occ.shape
    fx, fy = frame.map_to_cell(x, y)
    fx, fy = np.broadcast_arrays(np.floor(fx), np.floor(fy))
    inside = (fx >= 0) & (fx < w) & (fy >= 0) & (fy < h)
    out = np.zeros(fx.shape, dtype=bool)
    out[inside] = occ[fy[inside].astype(np.intp), fx[inside].astype(np.intp)]
    return out
