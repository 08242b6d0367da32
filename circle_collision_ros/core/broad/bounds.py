"""Swept bounds: the box a body's centre stays in over a time window, inflated by its radius.

Every body moves on a parabola ``p(t) = p + v t + a t^2 / 2``.  Over a window
``[t0, t1]`` its centre stays inside the exact axis-aligned box of that arc
(per axis the extremes are at the window ends or where ``v_k + a_k t`` crosses
zero).  Inflating the box by the radius gives a swept bound of the body; two
bodies whose swept bounds are disjoint cannot touch in the window.

Guarantee (the "never lose a contact" property of the whole broad phase): a
pair is dropped only if its exact centre distance stays above ``r_a + r_b`` by
more than a safety margin over the whole window.  The margin (``REL_MARGIN``
times the pair's motion scale, plus ``COORD_MARGIN`` times the absolute
coordinates, plus ``ABS_MARGIN``) absorbs the rounding of the float64 box
arithmetic here and in the relative test (propagation to the window start, the
per-axis extremes, the sums: a few ulps of the motion scale and of the
coordinates) many times over; the narrow phase decides the surviving pairs
exactly, so the margin need not cover any narrow-phase error.  It enlarges
bounds by micrometres per metre of motion, which costs nothing in cull rate.
"""
from __future__ import annotations

import numpy as np
from numba import njit
from numba.extending import register_jitable

from circle_collision_ros.core.kinematics import arc_position, arc_velocity

__all__ = ["propagate", "swept_bounds", "swept_bound_row", "fmin", "fmax",
           "REL_MARGIN", "COORD_MARGIN", "ABS_MARGIN"]

#: Relative safety margin on the motion scale (metres per metre of motion).
REL_MARGIN = 4e-6
#: Relative safety margin on absolute coordinates (covers p_b - p_a rounding, ~4500 ulp).
COORD_MARGIN = 1e-12
#: Absolute safety margin in metres (keeps the test non-strict for all-zero input).
ABS_MARGIN = 1e-12


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
        lo[out, k] = fmin(fmin(x0, x1), xs)
        hi[out, k] = fmax(fmax(x0, x1), xs)
        motion += abs(vk) * tm + 0.5 * abs(ak) * tm * tm
        coord = fmax(coord, abs(pk))
    coord += motion
    pad = r[i] + REL_MARGIN * (r[i] + motion) + COORD_MARGIN * coord + ABS_MARGIN
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


@register_jitable
def fmin(x, y):
    # a select (numba's min/max builtins branch)
    return x if x < y else y


@register_jitable
def fmax(x, y):
    return x if x > y else y
