"""predict_all_pairs == narrow phase on every pair, exactly.

Guarantee: for any valid scene the result holds exactly the pairs ``(i, j)``,
``i < j``, for which ``time_to_collision(body i, body j, horizon) <= horizon``,
with bitwise-identical times, sorted by ``(ttc, i, j)``, and the contact
details are ``contact_details`` at those times.  Proved against brute force
over all pairs on random scenes covering: 2-D and 3-D, static pairs, identical
motion, 1e6 m coordinates, tiny and huge horizons, accelerations that turn
around inside the horizon, dense clusters, near-tangent grazes, zero radii.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from circle_collision_ros.core import predict_all_pairs
from circle_collision_ros.core.narrow.contact import contact_details
from circle_collision_ros.core.narrow import time_to_collision


def brute_force(p, v, a, r, h):
    n = r.shape[0]
    if n < 2:
        e = np.empty(0, dtype=np.int64)
        return e, e, np.empty(0)
    I, J = np.triu_indices(n, 1)
    t = time_to_collision(p[I], v[I], a[I], r[I], p[J], v[J], a[J], r[J], h)
    m = t <= h
    I, J, t = I[m], J[m], t[m]
    o = np.lexsort((J, I, t))
    return I[o], J[o], t[o]


def assert_exact(p, v, a, r, h, method="grid"):
    res = predict_all_pairs(p, v, a, r, h, method=method)
    I, J, T = brute_force(p, v, a, r, h)
    assert res.i.tolist() == I.tolist()
    assert res.j.tolist() == J.tolist()
    assert np.array_equal(res.ttc, T)  # bitwise: same narrow-phase outputs
    assert res.i.dtype.kind == "i" and res.ttc.dtype == np.float64
    if len(res):
        pt, nm, cs = contact_details(p[I], v[I], a[I], r[I], p[J], v[J], a[J], r[J], T)
        assert np.array_equal(res.point, pt) and np.array_equal(res.normal, nm)
        assert np.array_equal(res.closing_speed, cs)
    return res


def scene(rng, n, dim, side, vmax=3.0, amax=0.5, rmax=2.0, offset=0.0):
    p = rng.uniform(0, side, (n, dim)) + offset
    v = rng.uniform(-vmax, vmax, (n, dim))
    a = rng.uniform(-amax, amax, (n, dim))
    r = rng.uniform(0.0, rmax, n)
    return p, v, a, r


@pytest.mark.parametrize("method", ["grid", "sweep"])
@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("seed", range(3))
def test_random_scenes_exact(method, dim, seed):
    rng = np.random.default_rng(seed)
    for side, h in [(200.0, 5.0), (30.0, 2.0), (500.0, 60.0), (20.0, 1e-6), (1000.0, 1e4)]:
        assert_exact(*scene(rng, 250, dim, side), h, method)


@pytest.mark.parametrize("dim", [2, 3])
def test_huge_coordinates(dim):
    """1e6 m map coordinates: same exactness (the narrow phase works relative)."""
    rng = np.random.default_rng(7)
    res = assert_exact(*scene(rng, 300, dim, 60.0, offset=1e6), 5.0)
    assert len(res) > 0


def test_static_and_identical_motion():
    """Static / co-moving pairs: skipped when apart, reported (ttc 0) when overlapping."""
    rng = np.random.default_rng(3)
    n = 300
    p = rng.uniform(0, 40, (n, 2))
    v = np.zeros((n, 2))
    a = np.zeros((n, 2))
    v[::2] = [1.5, -0.5]   # half of them share one motion
    a[::2] = [0.2, 0.1]
    v[1::4] = [0.0, 0.0]
    r = rng.uniform(0.2, 1.5, n)
    res = assert_exact(p, v, a, r, 5.0)
    assert np.any(res.ttc == 0.0)
    # exactly touching static pair: whatever the narrow phase says, we say
    P = np.array([[0.0, 0.0], [2.0, 0.0], [10.0, 0.0]])
    assert_exact(P, np.zeros((3, 2)), np.zeros((3, 2)), np.ones(3), 5.0)


def test_turnaround_accelerations():
    """Bodies that brake and reverse inside the horizon (extremes mid-window)."""
    rng = np.random.default_rng(11)
    n = 300
    p = rng.uniform(0, 60, (n, 2))
    v = rng.uniform(-6, 6, (n, 2))
    a = -v / rng.uniform(0.5, 4.0, (n, 1))  # velocity crosses zero within 0.5..4 s
    r = rng.uniform(0.2, 1.0, n)
    assert_exact(p, v, a, r, 8.0)
    assert_exact(p, v, a, r, 8.0, "sweep")


def test_dense_cluster_and_points():
    rng = np.random.default_rng(5)
    p, v, a, r = scene(rng, 400, 2, 8.0)
    r[::3] = 0.0  # point bodies
    res = assert_exact(p, v, a, r, 3.0)
    assert len(res) > 1000


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(0, 40), dim=st.sampled_from([2, 3]),
       side=st.sampled_from([1.0, 10.0, 100.0]), h=st.sampled_from([1e-3, 0.7, 5.0, 100.0]),
       offset=st.sampled_from([0.0, 1e6]), graze=st.booleans())
def test_hypothesis_exact(seed, n, dim, side, h, offset, graze):
    """Random small scenes incl. planted near-tangent pairs (clearance ~1e-9 R)."""
    rng = np.random.default_rng(seed)
    p, v, a, r = scene(rng, n, dim, side, offset=offset)
    if graze and n >= 2:
        # make body 1 pass body 0 at distance R(1 +- 1e-9) at time t = h/2 on a straight line
        a[0] = 0.0
        a[1] = 0.0
        d = rng.normal(size=dim)
        d /= np.linalg.norm(d)
        perp = rng.normal(size=dim)
        perp -= perp.dot(d) * d
        perp /= np.linalg.norm(perp)
        R = r[0] + r[1]
        tc = 0.5 * h
        rel = perp * R * (1.0 + rng.uniform(-1e-9, 1e-9)) - d * tc
        p[1] = p[0] + rel
        v[1] = v[0] + d
    assert_exact(p, v, a, r, h)


def test_empty_and_single():
    for dim in (2, 3):
        z = np.zeros((0, dim))
        res = predict_all_pairs(z, z, z, np.zeros(0), 1.0)
        assert len(res) == 0 and res.point.shape == (0, dim)
        one = np.zeros((1, dim))
        res = predict_all_pairs(one, one, one, np.ones(1), 1.0)
        assert len(res) == 0


def test_sorted_with_deterministic_ties():
    """Many overlapping pairs (ttc 0): ties broken by (i, j)."""
    p = np.zeros((6, 2))
    p[:, 0] = np.arange(6) * 0.1
    res = predict_all_pairs(p, np.zeros((6, 2)), np.zeros((6, 2)), np.ones(6), 1.0)
    assert len(res) == 15 and np.all(res.ttc == 0.0)
    keys = list(zip(res.i.tolist(), res.j.tolist()))
    assert keys == sorted(keys)


def test_bad_inputs_raise_naming_rows():
    """Non-finite rows or negative radii raise ValueError naming the rows (the
    narrow phase would return NaN); so do bad shapes and horizons."""
    rng = np.random.default_rng(0)
    p, v, a, r = scene(rng, 10, 2, 10.0)
    p[3, 1] = np.nan
    v[7, 0] = np.inf
    with pytest.raises(ValueError, match=r"row\(s\): 3, 7$"):
        predict_all_pairs(p, v, a, r, 1.0)
    p, v, a, r = scene(rng, 10, 2, 10.0)
    r[4] = -1.0
    with pytest.raises(ValueError, match=r"row\(s\): 4$"):
        predict_all_pairs(p, v, a, r, 1.0)
    p, v, a, r = scene(rng, 10, 2, 10.0)
    for h in (0.0, -1.0, math.inf, math.nan):
        with pytest.raises(ValueError, match="horizon"):
            predict_all_pairs(p, v, a, r, h)
    with pytest.raises(ValueError):
        predict_all_pairs(p[:, :1], v[:, :1], a[:, :1], r, 1.0)
    with pytest.raises(ValueError):
        predict_all_pairs(p, v[:5], a, r, 1.0)


def test_collinear_turnaround():
    """Relative velocity vanishes exactly at the closest approach, 0.98 m clear:
    an early narrow-phase version reported a contact here that no conservative
    broad phase can reproduce; kept as a regression case for both."""
    p = np.array([[0.0, 0.0], [-1.2341884490, -2.6770145134]])
    v = np.array([[0.0, 0.0], [0.9751245207200570, 2.2876490393041227]])
    a = np.array([[0.0, 0.0], -v[1]])  # relative velocity reaches exactly 0 at t = 1 s
    r = np.array([0.36999600089515494, 0.35217189715440045])
    assert len(assert_exact(p, v, a, r, 2.5)) == 0


def test_validation_names_only_bad_rows_across_the_float_range():
    """Rows of huge finite values (whose sums overflow) are valid; rows with
    inf, NaN or a negative radius are named."""
    from circle_collision_ros.core.scene.all_pairs import validate_bodies
    big = np.finfo(float).max
    p = np.array([[big, big], [0.0, 0.0], [0.0, np.inf], [1.0, 1.0], [0.0, np.nan]])
    v = np.array([[big, -big], [0.0, 0.0], [0.0, 0.0], [0.0, 0.0], [0.0, 0.0]])
    a = np.array([[big, big], [0.0, 0.0], [0.0, 0.0], [0.0, 0.0], [0.0, 0.0]])
    r = np.array([big, 1.0, 1.0, -1.0, 1.0])
    with pytest.raises(ValueError, match=r"in 3 row\(s\): 2, 3, 4$"):
        validate_bodies(p, v, a, r)
    validate_bodies(p[:2], v[:2], a[:2], r[:2])  # huge but finite: accepted


def test_order_by_time_then_key_is_the_lexicographic_order():
    """order_by_time_then_key (unstable time sort, then runs of equal times sorted
    by key) gives exactly the (time, key) order: short and long runs of ties,
    zeros, a run at the end."""
    from circle_collision_ros.core.scene.all_pairs import order_by_time_then_key
    rng = np.random.default_rng(41)
    for n, levels in ((0, 1), (1, 1), (50, 3), (5000, 40), (5000, 4000), (20000, 7)):
        ttc = rng.integers(0, levels, n) * 0.25  # many exact ties
        ttc[rng.random(n) < 0.3] = 0.0
        key = rng.permutation(10 * n + 1)[:n].astype(np.int64)  # unique
        got = order_by_time_then_key(ttc, key)
        assert got.tolist() == np.lexsort((key, ttc)).tolist()


def test_equal_times_across_a_lattice():
    """A lattice of identical pairs closing at the same speed: hundreds of equal
    nonzero contact times, reported in (ttc, i, j) order."""
    k = 15
    xs = np.arange(k) * 10.0
    pa = np.stack(np.meshgrid(xs, xs), -1).reshape(-1, 2)
    p = np.concatenate([pa, pa + [3.0, 0.0]])
    v = np.concatenate([np.tile([0.5, 0.0], (k * k, 1)), np.tile([-0.5, 0.0], (k * k, 1))])
    a = np.zeros_like(p)
    r = np.full(2 * k * k, 0.5)
    res = assert_exact(p, v, a, r, 5.0, method="sweep")
    assert len(res) >= k * k and np.count_nonzero(res.ttc == res.ttc[0]) >= k * k
