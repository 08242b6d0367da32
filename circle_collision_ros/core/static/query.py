"""First contact of moving circles with a static world: the public batch entry.

``time_to_static`` answers, for each body (centre ``p + v t + a t^2/2``, radius ``r``), the
first time in ``[0, H]`` it touches any obstacle of an indexed world, which obstacle, and the
contact point, normal and closing speed.  Per body the index lists the edges and corner points
near its swept box; each is decided by a certified kernel (``edge.edge_contact`` for an edge's
interior, the circle-circle narrow phase against a radius-0 point for a corner), and the few
rows a kernel cannot prove are decided exactly (``edge_exact``, ``narrow.exact``).  A body
whose centre starts inside a solid (polygon or occupied map cell) overlaps it: time 0.

Why the union of features is exact: the distance to a segment is the distance to its line
while the foot point is inside the segment and to the nearer endpoint otherwise, so the
first time it reaches r is the earliest of the endpoints' contacts and the line's entering
contacts with an interior foot point.  For a solid polygon a contact from its inner side
can only follow an earlier contact (the body would already be inside, or within r of
another edge), so both sides of every edge can be tested alike.
"""
from __future__ import annotations

import math
import os
from concurrent.futures import ThreadPoolExecutor
from fractions import Fraction
from typing import NamedTuple

import numpy as np
from numba import njit

from circle_collision_ros.core.broad.bounds import swept_bound_row
from circle_collision_ros.core.narrow.batch import certified_pair2
from circle_collision_ros.core.narrow.evaluate import EPS, UNDECIDED
from circle_collision_ros.core.parallel_policy import threads_pay
from circle_collision_ros.core.narrow.exact import exact_first_contact
from circle_collision_ros.core.static.edge import edge_contact
from circle_collision_ros.core.static.edge_exact import exact_edge_contact
from circle_collision_ros.core.static.index import StaticIndex, cell_range
from circle_collision_ros.core.static.occupancy import cell_occupied_at

__all__ = ["StaticContacts", "time_to_static", "KIND_NONE", "KIND_EDGE", "KIND_POINT",
           "KIND_INSIDE"]

KIND_NONE, KIND_EDGE, KIND_POINT, KIND_INSIDE = 0, 1, 2, 3


class StaticContacts(NamedTuple):
    """Per body: ``time`` (s; 0 = overlapping at t = 0, inf = none in [0, H], NaN = invalid
    row), ``obstacle`` (index into the world's ``names``, -1 for none), ``kind``/``feature``
    (KIND_EDGE + edge index, KIND_POINT + point index, KIND_INSIDE + -1: the centre starts
    inside a solid), ``point`` (contact point on the obstacle, m), ``normal`` (unit, from the
    body towards the obstacle) and ``closing_speed`` (m/s along the normal, > 0 approaching).
    Point, normal and speed are NaN without a contact and for KIND_INSIDE rows."""

    time: np.ndarray
    obstacle: np.ndarray
    kind: np.ndarray
    feature: np.ndarray
    point: np.ndarray
    normal: np.ndarray
    closing_speed: np.ndarray


@njit(cache=True, inline="always", error_model="numpy")
def _better(t, ob, kind, idx, bt, bob, bkind, bidx):
    """Ties break on (obstacle, kind, feature), so the answer never depends on visit order."""
    if t != bt or t == math.inf:
        return t < bt
    if ob != bob:
        return ob < bob
    if kind != bkind:
        return kind < bkind
    return idx < bidx


# A swept box over all of [0, H] holds every feature near the box's diagonal for a diagonal
# path; up to this many boxes over equal parts of [0, H] follow the path (~1/3 of the
# candidates of a long diagonal path in the benchmark rooms), at one cell range each.
PIECES = 8


@njit(cache=True, nogil=True, error_model="numpy")
def _query_range(b0, b1, P, V, A, R, H, ok, starts, ends, side, points, eob, pob, x0, y0,
                 inv_h, nx, ny, eptr, eitems, pptr, pitems, out_t, out_ob, out_kind, out_idx,
                 skip_ptr, skip, und):
    """Certified pass over bodies b0..b1-1; returns the number of undecided (row, kind,
    index) triples written to ``und`` (or -needed when ``und`` is too small).  Row b ignores
    the points ``skip[skip_ptr[b]:skip_ptr[b + 1]]`` (corners it only slides past)."""
    ne = starts.shape[0]
    npt = points.shape[0]
    seen_e = np.full(ne, -1, np.int64)
    seen_p = np.full(npt, -1, np.int64)
    # the broad phase's swept bound of the body over a window (core.broad.swept_bound_row:
    # the disc stays inside it, with its margins), viewed as one row
    box_lo = np.empty((1, 2))
    box_hi = np.empty((1, 2))
    lo = box_lo[0]
    hi = box_hi[0]
    n_und = 0
    for b in range(b0, b1):
        out_t[b] = math.nan
        out_ob[b] = -1
        out_kind[b] = 0
        out_idx[b] = -1
        if not ok[b]:
            continue
        px, py, vx, vy, ax, ay, r = P[b, 0], P[b, 1], V[b, 0], V[b, 1], A[b, 0], A[b, 1], R[b]
        bt, bob, bk, bi = math.inf, -1, 0, -1
        full = not (H < math.inf)
        pieces = 1
        if not full:
            swept_bound_row(P, V, A, R, b, 0.0, H, box_lo, box_hi, 0)
            i0, j0, i1, j1 = cell_range(lo, hi, x0, y0, inv_h, nx, ny)
            if not (lo[0] - lo[0] == 0.0 and hi[0] - hi[0] == 0.0 and lo[1] - lo[1] == 0.0
                    and hi[1] - hi[1] == 0.0):
                full = True  # an overflowing box: visit everything rather than trust it
            elif (i1 - i0 + 1) * (j1 - j0 + 1) > ne + npt:
                full = True
            elif (i1 - i0) + (j1 - j0) > 4:  # a long path: follow it with smaller boxes
                pieces = PIECES
        for piece in range(pieces):
            if full:
                i0, j0, i1, j1 = 0, 0, 0, 0
            elif pieces > 1:
                swept_bound_row(P, V, A, R, b, H * piece / pieces, H * (piece + 1) / pieces,
                                box_lo, box_hi, 0)
                i0, j0, i1, j1 = cell_range(lo, hi, x0, y0, inv_h, nx, ny)
            for j in range(j0, j1 + 1):
                for i in range(i0, i1 + 1):
                    c = j * nx + i
                    n_e = ne if full else eptr[c + 1] - eptr[c]
                    for q in range(n_e):
                        k = q if full else eitems[eptr[c] + q]
                        if seen_e[k] == b:
                            continue
                        # outside this part's box (which holds the disc over that part of
                        # [0, H]): no contact during it; another part may still list it
                        if not full and (
                                min(starts[k, 0], ends[k, 0]) > hi[0]
                                or max(starts[k, 0], ends[k, 0]) < lo[0]
                                or min(starts[k, 1], ends[k, 1]) > hi[1]
                                or max(starts[k, 1], ends[k, 1]) < lo[1]):
                            continue
                        seen_e[k] = b
                        t = edge_contact(px, py, vx, vy, ax, ay, r, starts[k, 0], starts[k, 1],
                                         ends[k, 0], ends[k, 1], side[k], H)
                        if t == UNDECIDED:
                            if n_und < und.shape[0]:
                                und[n_und, 0], und[n_und, 1], und[n_und, 2] = b, 1, k
                            n_und += 1
                        elif _better(t, eob[k], 1, k, bt, bob, bk, bi):
                            bt, bob, bk, bi = t, eob[k], 1, k
                    n_p = npt if full else pptr[c + 1] - pptr[c]
                    for q in range(n_p):
                        k = q if full else pitems[pptr[c] + q]
                        if seen_p[k] == b:
                            continue
                        if not full and (points[k, 0] > hi[0] or points[k, 0] < lo[0]
                                         or points[k, 1] > hi[1] or points[k, 1] < lo[1]):
                            continue
                        seen_p[k] = b
                        skipped = False
                        for q2 in range(skip_ptr[b], skip_ptr[b + 1]):
                            skipped |= skip[q2] == k
                        if skipped:
                            continue
                        t = certified_pair2(px, py, vx, vy, ax, ay, r, points[k, 0], points[k, 1],
                                            0.0, 0.0, 0.0, 0.0, 0.0, H)
                        if t == UNDECIDED:
                            if n_und < und.shape[0]:
                                und[n_und, 0], und[n_und, 1], und[n_und, 2] = b, 2, k
                            n_und += 1
                        elif _better(t, pob[k], 2, k, bt, bob, bk, bi):
                            bt, bob, bk, bi = t, pob[k], 2, k
        out_t[b], out_ob[b], out_kind[b], out_idx[b] = bt, bob, bk, bi
    return n_und if n_und <= und.shape[0] else -n_und


def _query(args: tuple, und: np.ndarray, threaded: bool) -> np.ndarray:
    """The certified pass over every body, in ``und.shape[0]`` chunks of bodies; chunks run
    on a thread pool when ``threaded`` (the kernel releases the GIL, and each chunk has its
    own candidate stamps and undecided list, so every body is computed exactly as in one
    pass).  Returns each chunk's count of undecided triples (negative: more than fit)."""
    chunks = und.shape[0]
    n = args[0].shape[0]

    def run(c: int) -> int:
        return _query_range(n * c // chunks, n * (c + 1) // chunks, *args, und[c])

    if threaded and chunks > 1:
        return np.array(list(_pool().map(run, range(chunks))), np.int64)
    return np.array([run(c) for c in range(chunks)], np.int64)


_POOL: list = []


def _pool() -> ThreadPoolExecutor:
    """The query's worker threads (one per core), made on first use."""
    if not _POOL:
        _POOL.append(ThreadPoolExecutor(max_workers=os.cpu_count() or 1,
                                        thread_name_prefix="static_query"))
    return _POOL[0]


#: From this many bodies a query may run on threads (core.parallel_policy decides).
THREADED_BODIES = 256


def _rows(x, name: str, n: int | None) -> np.ndarray:
    a = np.asarray(x, dtype=np.float64)
    if a.ndim == 1:
        a = a[None, :]
    if a.ndim != 2 or a.shape[1] != 2:
        raise ValueError(f"time_to_static: {name} must have shape (N, 2) (2-D only), "
                         f"got {np.shape(x)}")
    if n is not None and len(a) != n:
        if len(a) != 1:
            raise ValueError(f"time_to_static: {name} has {len(a)} rows, p has {n}")
        a = np.repeat(a, n, axis=0)
    return np.ascontiguousarray(a)


def _orientation(x1, y1, x2, y2, px, py):
    """(o, err): the orientation ``(x2 - x1)(py - y1) - (y2 - y1)(px - x1)`` of points
    against edges in float64 (arrays broadcast), and a bound on its rounding error: each
    difference is rounded relative to its operands, each product and the sum once, so
    ``|o| > err`` proves the exact sign (and that the point is off the edge's line)."""
    o = (x2 - x1) * (py - y1) - (y2 - y1) * (px - x1)
    err = 8.0 * EPS * ((np.abs(x2) + np.abs(x1)) * (np.abs(py) + np.abs(y1))
                       + (np.abs(y2) + np.abs(y1)) * (np.abs(px) + np.abs(x1)))
    return o, err


def _strictly_inside_edges(px: float, py: float, x1: np.ndarray, y1: np.ndarray,
                           x2: np.ndarray, y2: np.ndarray) -> bool:
    """Exactly: the point lies in the interior of the region the closed loops of edges
    (x1, y1) -> (x2, y2) bound (even-odd crossings of the ray to +x); on an edge: False.

    Each edge's orientation ``o`` of the point is taken from float64 where beyond its
    rounding bound (then it is not 0, so the point is off that edge's line), and in
    rationals for the rest."""
    o, err = _orientation(x1, y1, x2, y2, px, py)
    sure = np.abs(o) > err
    crosses = (y1 > py) != (y2 > py)
    inside = bool(np.count_nonzero(sure & crosses & ((o > 0) == (y2 > y1))) % 2)
    F = Fraction
    x, y = F(px), F(py)
    for k in np.flatnonzero(~sure):
        a, b, c, d = F(x1[k]), F(y1[k]), F(x2[k]), F(y2[k])
        ok = (c - a) * (y - b) - (d - b) * (x - a)
        if ok == 0 and min(a, c) <= x <= max(a, c) and min(b, d) <= y <= max(b, d):
            return False  # on an edge
        if (b > y) != (d > y) and (ok > 0) == (d > b):
            inside = not inside
    return inside


def _inside_polygon(x: np.ndarray, y: np.ndarray, vx: np.ndarray, vy: np.ndarray) -> np.ndarray:
    """Whether each point lies strictly inside one polygon (vertices vx, vy), exactly.

    Even-odd crossings with the orientation ``o`` of the point against each crossing edge in
    float64; a row where some ``|o|`` is within its rounding bound (the point within rounding
    of an edge's line and box: on the boundary, or nearly) is decided in rationals, where a
    point on the boundary is not inside (a body touching a solid is decided by its edges and
    corners, t = 0 rules included)."""
    inside = np.zeros(x.shape, bool)
    unsure = np.zeros(x.shape, bool)
    n = len(vx)
    for i in range(n):
        x1, y1, x2, y2 = vx[i], vy[i], vx[(i + 1) % n], vy[(i + 1) % n]
        o, err = _orientation(x1, y1, x2, y2, x, y)
        near = ((np.abs(o) <= err) & (x >= min(x1, x2) - err) & (x <= max(x1, x2) + err)
                & (y >= min(y1, y2) - err) & (y <= max(y1, y2) + err))
        unsure |= near
        crosses = (y1 > y) != (y2 > y)
        inside ^= crosses & ((o > 0) == (y2 > y1))
    if unsure.any():
        wx, wy = np.roll(vx, -1), np.roll(vy, -1)
        for k in np.flatnonzero(unsure):
            inside[k] = _strictly_inside_edges(float(x[k]), float(y[k]), vx, vy, wx, wy)
    return inside


@njit(cache=True, inline="always", error_model="numpy")
def _grid_line(c, origin, res, n):
    """(i, on): the grid line i with ``origin + i res <= c < origin + (i + 1) res`` (the
    lines rounded once, as the map's edges are), and whether c is on line i; i = -2 for a
    value beyond the grid's lines (its cells are free either way)."""
    f = (c - origin) / res
    if not (-2.0 <= f <= n + 2.0):  # also NaN: never converted to an integer
        return -2, False
    i = np.int64(math.floor(f))
    for _ in range(2):  # the estimate is off by at most one line
        if origin + i * res > c:
            i -= 1
        if origin + (i + 1) * res <= c:
            i += 1
    return i, origin + i * res == c


@njit(cache=True, inline="always", error_model="numpy")
def _cell(occ, i, j):
    h, w = occ.shape
    return 0 <= i < w and 0 <= j < h and occ[j, i]


@njit(cache=True, error_model="numpy")
def _inside_unrotated(occ, origin_x, origin_y, res, x, y, out):
    """``_inside_map`` for yaw 0, one compiled pass: a point on a cell line is inside only
    when the cells on both sides of it are occupied (all four at a cell corner)."""
    h, w = occ.shape
    for k in range(x.shape[0]):
        i, on_x = _grid_line(x[k], origin_x, res, w)
        j, on_y = _grid_line(y[k], origin_y, res, h)
        inside = _cell(occ, i, j)
        if inside and on_x:
            inside = _cell(occ, i - 1, j)
        if inside and on_y:
            inside = _cell(occ, i, j - 1)
        if inside and on_x and on_y:
            inside = _cell(occ, i - 1, j - 1)
        out[k] = inside


def _inside_map(occ: np.ndarray, frame, x: np.ndarray, y: np.ndarray, world, ob: int
                ) -> np.ndarray:
    """Whether each point lies strictly inside the occupied cells (a point on a boundary
    between occupied and free cells is not inside), exactly for the map's float64 geometry:
    the region its edges (those of obstacle ``ob`` of ``world``: the cell corners rounded
    once) bound.

    With yaw 0 the cell lines are ``origin + i * resolution`` rounded once, exactly the map's
    edges, so locating a point between them, and on one, is exact (``_inside_unrotated``).  A
    rotated map is looked up in float64 (``occupancy.cell_occupied_at``), which is right for
    a point farther from every cell line than the lookup's and the corners' rounding; a point
    within a generous margin of a line is decided by the edges themselves
    (``_strictly_inside_edges``; its merged edges run between rounded corners, so near a
    line only they define the region)."""
    if frame.yaw == 0.0:
        out = np.empty(len(x), np.bool_)
        _inside_unrotated(np.ascontiguousarray(occ, dtype=np.bool_), frame.origin_x,
                          frame.origin_y, frame.resolution, np.ascontiguousarray(x, np.float64),
                          np.ascontiguousarray(y, np.float64), out)
        return out
    inside = cell_occupied_at(occ, frame, x, y)
    fx, fy = frame.map_to_cell(x, y)
    # rounding of the lookup and of the corners, in cells: a few ulps of the coordinates'
    # size over the resolution; 256 ulps and 1e-9 of a cell are far beyond it
    scale = ((np.abs(x) + np.abs(y) + abs(frame.origin_x) + abs(frame.origin_y))
             / frame.resolution + np.abs(fx) + np.abs(fy))
    margin = 1e-9 + 256.0 * EPS * scale
    h, w = occ.shape
    with np.errstate(invalid="ignore"):
        near = (np.abs(fx - np.round(fx)) <= margin) | (np.abs(fy - np.round(fy)) <= margin)
        # beyond the grid by a cell the lookup's "free" stands (and no exact pass is spent
        # on a point so far out that the margin spans cells)
        near &= (fx > -1.0) & (fx < w + 1.0) & (fy > -1.0) & (fy < h + 1.0)
    if near.any():  # the map's edges, gathered only for such a point
        mine = world.edge_obstacle == ob
        s, e = world.starts[mine], world.ends[mine]
        for k in np.flatnonzero(near):
            inside[k] = _strictly_inside_edges(float(x[k]), float(y[k]), s[:, 0], s[:, 1],
                                               e[:, 0], e[:, 1])
    return inside


def _details(p, v, a, t, world, kind, feature):
    """Contact point, normal and closing speed at the contact time (NaN where none)."""
    n = len(t)
    point = np.full((n, 2), np.nan)
    normal = np.full((n, 2), np.nan)
    speed = np.full(n, np.nan)
    m = np.isfinite(t) & ((kind == KIND_EDGE) | (kind == KIND_POINT))
    if not m.any():
        return point, normal, speed
    tm = t[m][:, None]
    k = feature[m]
    edge = kind[m] == KIND_EDGE
    # anchor: the edge start or the corner point; centre relative to it, so map-frame
    # offsets cancel before the products
    anchor = np.where(edge[:, None], world.starts[np.where(edge, k, 0)],
                      world.points[np.where(edge, 0, k)]) if len(world.starts) else \
        world.points[k]
    g = (p[m] - anchor) + tm * (v[m] + 0.5 * tm * a[m])
    foot = np.zeros_like(g)
    if edge.any():
        e = world.ends[k[edge]] - world.starts[k[edge]]
        lam = np.clip(np.einsum("ij,ij->i", g[edge], e) / np.einsum("ij,ij->i", e, e), 0, 1)
        foot[edge] = lam[:, None] * e
    d = foot - g
    dist = np.hypot(d[:, 0], d[:, 1])
    vel = v[m] + tm * a[m]
    with np.errstate(invalid="ignore", divide="ignore"):
        nrm = d / dist[:, None]
    # a point body exactly on the obstacle: the normal is the direction of motion
    zero = ~(dist > 0)
    if zero.any():
        sp = np.hypot(vel[zero, 0], vel[zero, 1])
        nrm[zero] = np.where(sp[:, None] > 0, vel[zero] / np.where(sp > 0, sp, 1)[:, None],
                             np.array([1.0, 0.0]))
    point[m] = anchor + foot
    normal[m] = nrm
    speed[m] = np.einsum("ij,ij->i", vel, nrm)
    return point, normal, speed


def _certified_then_exact(P, V, A, R, H, ok, index, todo, skip_ptr, skip, out_t, out_ob,
                          out_kind, out_idx) -> None:
    """Rows ``todo``: the certified kernels, then the exact solvers for what they left."""
    w = index.world
    sub = (P[todo], V[todo], A[todo], R[todo])
    m = len(todo)
    t, ob, kind, idx = np.empty(m), np.empty(m, np.int32), np.empty(m, np.int8), \
        np.empty(m, np.int64)
    if len(skip):
        sp = np.concatenate([[0], np.cumsum(skip_ptr[todo + 1] - skip_ptr[todo])])
        sk = np.concatenate([skip[skip_ptr[b]:skip_ptr[b + 1]] for b in todo])
    else:  # the first pass: nothing skipped (no per-row Python work)
        sp, sk = np.zeros(m + 1), np.empty(0)
    sp, sk = sp.astype(np.int64), sk.astype(np.int64)
    args = (*sub, H, ok[todo], w.starts, w.ends, w.solid_side.astype(np.int64), w.points,
            w.edge_obstacle, w.point_obstacle, index.x0, index.y0, 1.0 / index.h, index.nx,
            index.ny, index.edge_ptr, index.edge_items, index.point_ptr, index.point_items,
            t, ob, kind, idx, sp, sk)
    threaded = threads_pay(m, THREADED_BODIES)
    chunks = 2 * (os.cpu_count() or 1) if threaded else 1
    cap = 64
    while True:
        und = np.empty((chunks, cap, 3), np.int64)
        counts = _query(args, und, threaded)
        if (counts >= 0).all():
            break
        cap = int(-counts.min())
    rows = np.concatenate([und[c, :counts[c]] for c in range(chunks)])
    for i, fk, k in rows:
        b = todo[i]
        if fk == KIND_EDGE:
            te = exact_edge_contact(P[b], V[b], A[b], R[b], w.starts[k], w.ends[k],
                                    int(w.solid_side[k]), H)
            obk = w.edge_obstacle[k]
        else:
            te = exact_first_contact(P[b], V[b], A[b], R[b], w.points[k], (0.0, 0.0),
                                     (0.0, 0.0), 0.0, H)
            obk = w.point_obstacle[k]
        if te < math.inf and (te, obk, fk, k) < (t[i], ob[i] if ob[i] >= 0 else 1 << 40,
                                                  kind[i], idx[i]):
            t[i], ob[i], kind[i], idx[i] = te, obk, fk, k
    out_t[todo], out_ob[todo], out_kind[todo], out_idx[todo] = t, ob, kind, idx


def _slides_along(p, v, a, r, s, e, corner) -> bool:
    """Exactly: the body moves along the line of segment s-e at distance exactly r for ever,
    and ``corner`` lies on that closed segment."""
    # float filter: a 2 x 2 determinant clearly away from 0 is not 0 (each product and the
    # difference rounded once, the differences of coordinates once: 8 eps of the sizes)
    ex, ey = e[0] - s[0], e[1] - s[1]
    size = (abs(e[0]) + abs(s[0])) + (abs(e[1]) + abs(s[1]))
    for x, y in ((v[0], v[1]), (a[0], a[1]), (corner[0] - s[0], corner[1] - s[1])):
        if abs(ex * y - ey * x) > 8.0 * EPS * size * (abs(x) + abs(y)) + 1e-300:
            return False
    F = Fraction
    ex, ey = F(e[0]) - F(s[0]), F(e[1]) - F(s[1])
    if ex * (F(v[1])) - ey * F(v[0]) != 0 or ex * F(a[1]) - ey * F(a[0]) != 0:
        return False
    cx, cy = F(corner[0]) - F(s[0]), F(corner[1]) - F(s[1])
    if ex * cy - ey * cx != 0 or not 0 <= ex * cx + ey * cy <= ex * ex + ey * ey:
        return False
    gx, gy = F(p[0]) - F(s[0]), F(p[1]) - F(s[1])
    return (ex * gy - ey * gx) ** 2 == F(r) ** 2 * (ex * ex + ey * ey)


def _corners_slid_past(P, V, A, R, index, todo, out_t, out_kind, out_idx) -> list:
    """(row, point) pairs among ``todo`` whose winning corner contact only happens while the
    body slides along a wall through that corner at exactly its radius.

    The distance to the world then stays r before the corner and grows after it: never below
    r, and not an isolated touch, so it is no contact (as sliding along the wall alone is
    none).  The wall contains the corner, so it is listed in the corner's cell.
    """
    w = index.world
    out = []
    t = out_t[todo]
    rows = todo[(out_kind[todo] == KIND_POINT) & (t > 0.0) & (t < math.inf)]
    if len(rows):
        # only a touch with the body moving square to the corner can be a slide past it
        # (g . g' = 0 at the contact); anything clearly away from that is a real contact
        tc = out_t[rows][:, None]
        g = (P[rows] - w.points[out_idx[rows]]) + tc * (V[rows] + 0.5 * tc * A[rows])
        gd = V[rows] + tc * A[rows]
        dot = np.abs(np.einsum("ij,ij->i", g, gd))
        size = np.hypot(g[:, 0], g[:, 1]) * np.hypot(gd[:, 0], gd[:, 1])
        # g is the radius vector at the touch; for a body near rounding size (a point) its
        # direction is rounding residue and says nothing: those rows are always checked
        scale = np.abs(P[rows]).sum(axis=1) + np.abs(w.points[out_idx[rows]]).sum(axis=1)
        rows = rows[~((dot > 1e-6 * size) & (R[rows] > 1e-9 * scale))]
    for b in rows:
        k = out_idx[b]
        c = w.points[k]
        lo = np.array([c[0], c[1]])
        i0, j0, i1, j1 = cell_range(lo, lo, index.x0, index.y0, 1.0 / index.h, index.nx,
                                    index.ny)
        cand = set()
        for j in range(j0, j1 + 1):
            for i in range(i0, i1 + 1):
                cell = j * index.nx + i
                cand.update(index.edge_items[index.edge_ptr[cell]:index.edge_ptr[cell + 1]]
                            .tolist())
        if any(_slides_along(P[b], V[b], A[b], R[b], w.starts[j], w.ends[j], c)
               for j in sorted(cand)):
            out.append((int(b), int(k)))
    return out


def time_to_static(p, v, a, r, index: StaticIndex, horizon: float = math.inf
                   ) -> StaticContacts:
    """First contact of each body with the indexed static world (2-D).

    Parameters: ``p``, ``v``, ``a`` (N, 2) (or one row, broadcast) in m, m/s, m/s^2;
    ``r`` (N,) or scalar, m; ``horizon`` s.  Guarantees: 0 and inf are exact decisions; a
    finite time lies within one ulp of the exact first contact for the float64 geometry of
    the world (the exact solvers round to nearest); ties between obstacles at the same time
    go to the lowest (obstacle, kind, feature).  Rows with non-finite values or r < 0 give
    NaN.  ``horizon`` must be >= 0 (ValueError otherwise).
    """
    H = float(horizon)
    if not H >= 0.0:
        raise ValueError(f"time_to_static: horizon must be >= 0, got {horizon!r}")
    P = _rows(p, "p", None)
    n = len(P)
    V = _rows(v, "v", n)
    A = _rows(a, "a", n)
    R = np.ascontiguousarray(np.broadcast_to(np.asarray(r, dtype=np.float64), (n,)))
    ok = (np.isfinite(P).all(axis=1) & np.isfinite(V).all(axis=1) & np.isfinite(A).all(axis=1)
          & np.isfinite(R) & (R >= 0))
    w = index.world
    out_t = np.empty(n)
    out_ob = np.empty(n, np.int32)
    out_kind = np.empty(n, np.int8)
    out_idx = np.empty(n, np.int64)
    skip_ptr = np.zeros(n + 1, np.int64)
    skip = np.empty(0, np.int64)
    todo = np.arange(n)
    while True:
        _certified_then_exact(P, V, A, R, H, ok, index, todo, skip_ptr, skip,
                              out_t, out_ob, out_kind, out_idx)
        slid = _corners_slid_past(P, V, A, R, index, todo, out_t, out_kind, out_idx)
        if not slid:
            break
        extra = {b: [k] for b, k in slid}
        rows = [list(skip[skip_ptr[b]:skip_ptr[b + 1]]) + extra.get(b, []) for b in range(n)]
        skip_ptr = np.concatenate([[0], np.cumsum([len(x) for x in rows])]).astype(np.int64)
        skip = np.array([k for x in rows for k in x], np.int64)
        todo = np.array(sorted(extra), np.int64)
    # a centre inside a solid overlaps it, however far its boundary is
    live = ok & (out_t != 0.0)
    if live.any():
        rows = np.nonzero(live)[0]
        x, y = P[rows, 0], P[rows, 1]
        inside_ob = np.full(len(rows), -1, np.int64)
        for ob, first, count in w.polygons:
            vs = w.starts[first:first + count]
            hit = _inside_polygon(x, y, vs[:, 0], vs[:, 1]) & (inside_ob < 0)
            inside_ob[hit] = ob
        for ob, occ, frame in w.maps:
            hit = _inside_map(occ, frame, x, y, w, ob) & (inside_ob < 0)
            inside_ob[hit] = ob
        hit = inside_ob >= 0
        rows = rows[hit]
        out_t[rows] = 0.0
        out_ob[rows] = inside_ob[hit]
        out_kind[rows] = KIND_INSIDE
        out_idx[rows] = -1
    point, normal, speed = _details(P, V, A, out_t, w, out_kind, out_idx)
    return StaticContacts(out_t, out_ob, out_kind, out_idx, point, normal, speed)
