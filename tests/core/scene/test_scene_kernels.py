"""The scene's compiled small-update steps equal the numpy code they replace, bit for bit.

Guarantees proved here (core/scene/kernels.py):

* ``evaluate_rows`` = propagation (``store.propagate_ns``) + ``time_to_collision``
  + ``contact_details`` + the overlap test of ``Scene._resolve``, bitwise, on
  random rows, on overlapping rows (where it decides f(0) < 0 without the narrow
  phase), touching and coincident centres, zero relative velocity, negative
  zeros -- test_evaluate_rows_bitwise;
* ``swept_bound_rows`` = ``broad.swept_bounds`` bitwise, also with turning
  points inside the window and zero accelerations -- test_swept_bound_rows_bitwise;
* ``order_rows`` sorts by (ttc, key) like a lexsort, from nearly sorted rows and
  new ones, and reports when its move budget is exceeded -- test_order_rows.
"""

from __future__ import annotations

import numpy as np
import pytest

from circle_collision_ros.core import broad as bp
from circle_collision_ros.core.scene import kernels as sk
from circle_collision_ros.core.narrow.contact import contact_details
from circle_collision_ros.core.narrow import time_to_collision
from circle_collision_ros.core.scene.store import propagate_ns


def bits(x) -> np.ndarray:
    return np.ascontiguousarray(x, dtype=np.float64).view(np.uint64)


def _states(rng, n, dim, side):
    P = rng.uniform(-side, side, (n, dim)) + 1e5  # map-frame offsets
    V = rng.normal(0, 2, (n, dim))
    A = rng.normal(0, 0.5, (n, dim))
    R = rng.uniform(0.2, 2.0, n)
    # special rows: at rest, coincident centres, touching, negative zeros
    V[0] = 0.0
    A[0] = -0.0
    P[1] = P[2]
    V[1] = V[2]
    A[1] = A[2]
    P[3] = P[4] + np.eye(dim)[0] * (R[3] + R[4])
    V[3] = -0.0
    V[4] = 0.0
    A[5] = 0.0
    T = 1_700_000_000 * 10**9 - rng.integers(0, 2 * 10**9, n)
    return P, V, A, R, T


@pytest.mark.parametrize("dim", [2, 3])
def test_evaluate_rows_bitwise(dim) -> None:
    rng = np.random.default_rng(dim)
    n = 400
    P, V, A, R, T = _states(rng, n, dim, 12.0 if dim == 2 else 6.0)
    ia = np.concatenate([rng.integers(0, n, 3000), [1, 3, 0, 5]]).astype(np.int64)
    ib = np.concatenate([rng.integers(0, n, 3000), [2, 4, 0, 0]]).astype(np.int64)
    keep = ia != ib
    keep[-2:] = True  # a body with itself: distance 0, overlapping
    ia, ib = ia[keep], ib[keep]
    t_eval = np.maximum(T[ia], T[ib]) + rng.integers(0, 3, ia.size) * 250_000_000
    for horizon in (5.0, 0.01):
        k = ia.size
        tau, pt, nm = np.empty(k), np.empty((k, dim)), np.empty((k, dim))
        cs, ov = np.empty(k), np.empty(k, dtype=bool)
        sk.evaluate_rows(P, V, A, R, T, ia, ib, t_eval, horizon, tau, pt, nm, cs, ov, (0.0,) * dim)
        pa, va = propagate_ns(P[ia], V[ia], A[ia], t_eval - T[ia])
        pb, vb = propagate_ns(P[ib], V[ib], A[ib], t_eval - T[ib])
        want = time_to_collision(pa, va, A[ia], R[ia], pb, vb, A[ib], R[ib], horizon)
        assert np.array_equal(bits(tau), bits(want))
        h = np.flatnonzero(want <= horizon)
        if horizon == 5.0:
            assert np.count_nonzero(want[h] == 0.0) > 20 and np.count_nonzero(want[h] > 0.0) > 20
        p2, n2, c2 = contact_details(
            pa[h], va[h], A[ia][h], R[ia][h], pb[h], vb[h], A[ib][h], R[ib][h], want[h]
        )
        assert np.array_equal(bits(np.nan_to_num(pt[h])), bits(np.nan_to_num(p2)))
        assert np.array_equal(bits(np.nan_to_num(nm[h])), bits(np.nan_to_num(n2)))
        assert np.array_equal(bits(np.nan_to_num(cs[h])), bits(np.nan_to_num(c2)))
        over = (want[h] == 0.0) & (
            np.linalg.norm(pa[h] - pb[h], axis=1) - (R[ia][h] + R[ib][h]) < 0.0
        )
        assert np.array_equal(ov[h], over)


@pytest.mark.parametrize("dim", [2, 3])
def test_swept_bound_rows_bitwise(dim) -> None:
    rng = np.random.default_rng(10 + dim)
    n = 300
    P, V, A, R, _ = _states(rng, n, dim, 50.0)
    A[::7] = 0.0
    V[1::5] = -A[1::5] * rng.uniform(0.1, 2.0, (len(V[1::5]), 1))  # turning points inside
    t0 = rng.uniform(0.0, 1.0, n)
    t1 = t0 + rng.uniform(0.0, 6.0, n)
    slots = np.arange(n, dtype=np.int64)
    lo, hi = np.zeros((n, dim)), np.zeros((n, dim))
    sk.swept_bound_rows(P, V, A, R, slots, t0, t1, lo, hi)
    lo2, hi2 = bp.swept_bounds(P, V, A, R, t0, t1)
    assert np.array_equal(bits(lo), bits(lo2)) and np.array_equal(bits(hi), bits(hi2))


def test_order_rows() -> None:
    rng = np.random.default_rng(3)
    # new rows: few enough moves for the insertion pass (ties, mostly 0.0 as for pairs overlapping
    # at R) and too many for its budget (2,000 distinct times: the stable-sort fallback)
    for n_sorted, n_new, ties in ((0, 50, 10), (200, 0, 10), (200, 30, 10), (1, 1, 10),
                                  (880, 284, 0), (0, 2000, 10**6), (50, 2000, 10)):
        ttc = np.round(rng.uniform(0, 5, n_sorted + n_new), 1)  # many ties
        if ties == 0:  # the new rows at 0.0 but for a few
            ttc[n_sorted:] = np.where(rng.random(n_new) < 0.05, ttc[n_sorted:], 0.0)
        elif ties == 10**6:
            ttc = rng.uniform(0, 5, n_sorted + n_new)
        key = rng.permutation(10 * (n_sorted + n_new))[: n_sorted + n_new].astype(np.int64)
        o = np.lexsort((key[:n_sorted], ttc[:n_sorted]))
        ttc[:n_sorted], key[:n_sorted] = ttc[:n_sorted][o], key[:n_sorted][o]
        # nearly sorted: a few neighbours swapped
        for i in rng.integers(0, max(1, n_sorted - 1), 5 if n_sorted > 2 else 0):
            ttc[[i, i + 1]], key[[i, i + 1]] = ttc[[i + 1, i]], key[[i + 1, i]]
        rec = np.arange(ttc.size, dtype=np.int64)
        want = np.lexsort((key, ttc))
        t2, k2 = ttc.copy(), key.copy()
        assert sk.order_rows(rec, t2, k2, n_sorted, 10**6)
        assert rec.tolist() == want.tolist()
        assert np.array_equal(t2, ttc[want]) and np.array_equal(k2, key[want])
    # a reversed "nearly sorted" part exceeds a small budget; the rows stay a permutation
    ttc = np.arange(100.0)[::-1].copy()
    key = np.arange(100, dtype=np.int64)
    rec = np.arange(100, dtype=np.int64)
    assert not sk.order_rows(rec, ttc, key, 100, 10)
    assert sorted(rec.tolist()) == list(range(100))
    assert np.array_equal(ttc, 99.0 - rec) and np.array_equal(key, rec)
