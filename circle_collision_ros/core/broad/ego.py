"""Ego-centred candidate pairs: only the pairs with at least one ego body, never the others.

A robot asking "what will I hit" needs the pairs of its own body (the ego bodies), not
those of the crowd.  Instead of a sweep over every pair, each ego body's box is tested
against every box, and a non-ego body against the ego boxes only: with one ego body among
N, N - 1 box tests, no sort and no sweep.  The test is the sweep's (closed intervals on
every axis) and the relative test (relative.py) is the same, so the pairs are exactly
those of :func:`~circle_collision_ros.core.broad.candidate_pairs` that contain an ego body.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from circle_collision_ros.core.broad.relative import relative_filter

__all__ = ["ego_box_keys", "ego_candidate_pairs"]


@njit(cache=True, inline="always")
def _room(keys, m, k):
    """keys with room for k more after m (grown before a scan: a buffer reassigned inside the
    scan's loop costs it about four times its speed, measured)."""
    if m + k <= keys.shape[0]:
        return keys
    grown = np.empty(max(2 * keys.shape[0], m + k), dtype=np.int64)
    grown[:m] = keys[:m]
    return grown


@njit(cache=True, inline="always")
def _overlaps(lo, hi, y, l0, l1, l2, h0, h1, h2, D):
    """Box y overlaps the closed box (l0.., h0..) on every axis (the sweep's test); a 2-D
    box repeats its last axis as the third (the same test twice), so the code is one."""
    return ((lo[y, 0] <= h0) & (l0 <= hi[y, 0]) & (lo[y, 1] <= h1) & (l1 <= hi[y, 1])
            & (lo[y, D - 1] <= h2) & (l2 <= hi[y, D - 1]))


@njit(cache=True, inline="always")
def _ego_box_keys(query, alive, ego, ego_members, lo, hi, cap, D):
    n = alive.shape[0]
    inq = np.zeros(n, dtype=np.bool_)
    for x in range(query.shape[0]):
        inq[query[x]] = alive[query[x]]
    keys = np.empty(64, dtype=np.int64)
    m = 0
    tests = 0
    for x in range(query.shape[0]):
        s = query[x]
        if not alive[s]:
            continue
        # s's box in registers (the inner loops read the other boxes only)
        l0, l1, l2 = lo[s, 0], lo[s, 1], lo[s, D - 1]
        h0, h1, h2 = hi[s, 0], hi[s, 1], hi[s, D - 1]
        if ego[s]:
            keys = _room(keys, m, n)
            for y in range(n):
                if not alive[y] or y == s or (inq[y] and ego[y] and y < s):
                    continue
                tests += 1
                if _overlaps(lo, hi, y, l0, l1, l2, h0, h1, h2, D):
                    keys[m] = min(s, y) * cap + max(s, y)
                    m += 1
        else:
            keys = _room(keys, m, ego_members.shape[0])
            for q in range(ego_members.shape[0]):
                y = ego_members[q]
                if not alive[y] or inq[y]:
                    continue
                tests += 1
                if _overlaps(lo, hi, y, l0, l1, l2, h0, h1, h2, D):
                    keys[m] = min(s, y) * cap + max(s, y)
                    m += 1
    return np.sort(keys[:m]), tests


@njit(cache=True)
def ego_box_keys(query, alive, ego, ego_members, lo, hi, cap):
    """The pairs of the bodies `query` with at least one ego body whose boxes overlap (closed
    intervals on every axis, the sweep's test), as sorted keys ``min * cap + max``, and the
    number of box tests made.  lo, hi : (cap, 2 or 3).

    An ego body of `query` is tested against every alive body; a non-ego one against the
    alive ego bodies (`ego_members`) only.  Each pair is tested once: a non-ego body skips
    the ego bodies of `query` (their scans cover it), and of two ego bodies of `query` the
    pair is tested by the lower index.  Bodies of `query` that are not alive are skipped.
    """
    if lo.shape[1] == 2:  # the dimension as a constant: the axis tests unroll
        return _ego_box_keys(query, alive, ego, ego_members, lo, hi, cap, 2)
    return _ego_box_keys(query, alive, ego, ego_members, lo, hi, cap, 3)


def ego_candidate_pairs(lo: np.ndarray, hi: np.ndarray, ego: np.ndarray, *, p=None, v=None,
                        a=None, r=None, tref=None, t_start: float = 0.0,
                        t_end: float = 0.0) -> tuple[np.ndarray, np.ndarray, int]:
    """Pairs ``(i, j)``, ``i < j``, with an ego body (``ego``: (N,) bool) whose bounds overlap
    and, given the states, that pass the relative test: exactly the pairs of
    ``candidate_pairs`` (same arguments) with ``ego[i] or ego[j]``, in ``(i, j)`` order.

    Returns ``(i, j, n_tests)``: n_tests box tests (``(N - 1)`` per ego body, fewer when
    several are ego: a pair is tested once).
    """
    lo = np.ascontiguousarray(lo, dtype=np.float64)
    hi = np.ascontiguousarray(hi, dtype=np.float64)
    n = lo.shape[0]
    ego = np.ascontiguousarray(ego, dtype=np.bool_)
    members = np.flatnonzero(ego)
    keys, tests = ego_box_keys(members, np.ones(n, dtype=np.bool_), ego, members, lo, hi,
                               np.int64(max(n, 1)))
    i, j = keys // max(n, 1), keys % max(n, 1)
    if p is not None and i.size:
        keep = relative_filter(p, v, a, r, np.zeros(n) if tref is None else tref, i, j,
                               t_start, t_end)
        i, j = i[keep], j[keep]
    return i, j, int(tests)
