"""Broad phase: swept bounds are conservative and pair generators are complete.

Guarantees proved here (each next to its test):
* ``swept_bounds`` contains the whole inflated arc over the window (incl. arcs
  whose velocity turns around inside it) -- test_bounds_contain_arc.
* grid and sweep generators return exactly the set of bound-overlapping pairs
  (brute force), incl. oversized bodies and 3-D -- test_generators_exact.
* the broad phase never drops a pair the narrow phase reports, even for
  near-tangent grazes at 1e6 m coordinates -- test_never_drops_graze and the
  scene-level tests in test_scene_predict_all_pairs.py.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from circle_collision_ros.core import broad as bp
from circle_collision_ros.core.broad import relative, sweep
from circle_collision_ros.core.narrow import time_to_collision

finite = st.floats(-50, 50, allow_nan=False)


@settings(max_examples=200, deadline=None)
@given(p=st.lists(finite, min_size=3, max_size=3), v=st.lists(finite, min_size=3, max_size=3),
       a=st.lists(finite, min_size=3, max_size=3), r=st.floats(0, 5),
       t0=st.floats(0, 10), dt=st.floats(0, 20), offset=st.sampled_from([0.0, 1e6, -3e5]))
def test_bounds_contain_arc(p, v, a, r, t0, dt, offset):
    """Every sampled point of the arc (+- r) lies inside the bound, incl. turnarounds."""
    P = np.array([p]) + offset
    V, A = np.array([v]), np.array([a])
    t1 = t0 + dt
    lo, hi = bp.swept_bounds(P, V, A, np.array([r]), t0, t1)
    ts = np.linspace(t0, t1, 257)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        tstar = -V[0] / A[0]
    ts = np.concatenate([ts, tstar[(tstar >= t0) & (tstar <= t1)]])
    X = P + V * ts[:, None] + 0.5 * A * ts[:, None] ** 2
    assert np.all(X - r >= lo) and np.all(X + r <= hi)


def _brute_overlap(lo, hi):
    n = lo.shape[0]
    I, J = np.triu_indices(n, 1)
    ok = np.all((lo[I] <= hi[J]) & (lo[J] <= hi[I]), axis=1)
    return set(zip(I[ok].tolist(), J[ok].tolist()))


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("seed", range(4))
def test_generators_exact(dim, seed):
    """grid == sweep == brute-force bound overlap (boxes of mixed sizes, some huge)."""
    rng = np.random.default_rng(seed)
    n = 400
    c = rng.uniform(0, 100, (n, dim))
    ext = rng.lognormal(0, 1, (n, dim))
    ext[:5] *= 100  # oversized bodies take the grid's brute-force path
    lo, hi = c - ext, c + ext
    ref = _brute_overlap(lo, hi)
    for method in ("grid", "sweep"):
        I, J, n_box = bp.candidate_pairs(lo, hi, method=method)
        got = list(zip(I.tolist(), J.tolist()))
        assert len(got) == len(set(got)) == n_box, method  # no duplicates
        assert set(got) == ref, method
        assert np.all(I < J)


def test_generators_tiny_inputs():
    z = np.zeros((0, 2))
    for m in ("grid", "sweep"):
        I, J, n = bp.candidate_pairs(z, z, method=m)
        assert I.size == J.size == n == 0
        I, J, n = bp.candidate_pairs(np.zeros((1, 2)), np.ones((1, 2)), method=m)
        assert I.size == 0
    with pytest.raises(ValueError):
        bp.candidate_pairs(np.zeros((2, 2)), np.ones((2, 2)), method="octree")


@settings(max_examples=300, deadline=None)
@given(miss=st.floats(-1e-8, 1e-8), R=st.sampled_from([1e-3, 0.5, 3.0]),
       speed=st.floats(0.01, 30), acc=st.floats(-2, 2), ang=st.floats(0, 2 * math.pi),
       tc=st.floats(0.0, 6.0), offset=st.sampled_from([0.0, 1e6, -2.5e5]),
       H=st.sampled_from([1e-3, 0.5, 5.0, 1e3]))
def test_never_drops_graze(miss, R, speed, acc, ang, tc, offset, H):
    """Near-tangent passes (clearance +-1e-8 relative): if the narrow phase
    reports a contact, the pair survives both bound overlap and the relative test."""
    d = np.array([math.cos(ang), math.sin(ang)])
    nrm = np.array([-d[1], d[0]])
    ra = 0.3 * R
    rb = R - ra
    # b passes a's centre at distance R(1+miss) at time tc, along d
    pb_tc = nrm * R * (1.0 + miss)
    vb = d * speed
    ab = d * acc
    pb = pb_tc - vb * tc - 0.5 * ab * tc * tc
    P = np.array([[offset, offset], pb + offset])
    V = np.array([[0.0, 0.0], vb])
    A = np.array([[0.0, 0.0], ab])
    r = np.array([ra, rb])
    t = time_to_collision(P[0], V[0], A[0], r[0], P[1], V[1], A[1], r[1], H)
    if not t <= H:
        return
    lo, hi = bp.swept_bounds(P, V, A, r, 0.0, H)
    for m in ("grid", "sweep"):
        I, J, _ = bp.candidate_pairs(lo, hi, p=P, v=V, a=A, r=r, tref=np.zeros(2),
                                     t_start=0.0, t_end=H, method=m)
        assert list(zip(I.tolist(), J.tolist())) == [(0, 1)], (m, t)


def test_relative_filter_static_pairs():
    """Apart pairs with no relative motion are culled; touching/overlapping ones kept."""
    P = np.array([[0.0, 0.0], [3.0, 0.0], [2.0, 0.0], [100.0, 5.0], [104.0, 5.0]])
    V = np.array([[1.0, 2.0], [1.0, 2.0], [0.0, 0.0], [0.0, 0.0], [0.0, 0.0]])
    A = np.array([[0.5, 0.0], [0.5, 0.0], [0.0, 0.0], [0.0, 0.0], [0.0, 0.0]])
    r = np.ones(5)
    I = np.array([0, 3, 0])
    J = np.array([1, 4, 2])
    keep = bp.relative_filter(P, V, A, r, np.zeros(5), I, J, 0.0, 10.0)
    # (0,1): identical motion, 3 m apart, R = 2 -> culled; (3,4) static apart -> culled;
    # (0,2): relative motion brings them together -> kept
    assert keep.tolist() == [False, False, True]
    keep = bp.relative_filter(np.array([[0.0, 0.0], [2.0, 0.0]]), np.zeros((2, 2)),
                              np.zeros((2, 2)), np.ones(2), np.zeros(2), np.array([0]),
                              np.array([1]), 0.0, 1.0)
    assert keep.tolist() == [True]  # exactly touching static pair goes to the narrow phase


def test_propagate_identity_at_zero():
    p = np.array([[1e6 + 0.1, -3.3]])
    v = np.array([[1.0, 2.0]])
    a = np.array([[0.3, -0.7]])
    q, w = bp.propagate(p, v, a, 0.0)
    assert np.array_equal(q, p) and np.array_equal(w, v)
    q, w = bp.propagate(p, v, a, 2.0)
    assert np.array_equal(q, p + v * 2.0 + 0.5 * a * 2.0 * 2.0)
    assert np.array_equal(w, v + a * 2.0)


def _scene_bounds(rng, n, dim, layout):
    c = rng.uniform(0, 200, (n, dim))
    ext = rng.lognormal(0, 0.7, (n, dim))
    if layout == "line":  # every centre on one line across the strips
        c[:, 1:] = 50.0
    elif layout == "column":  # every centre on one line along the sweep axis
        c[:, 0] = 50.0
    elif layout == "points":  # zero-extent bounds, many coincident
        c = np.round(c / 20.0) * 20.0
        ext[:] = 0.0
    elif layout == "tall":  # some bounds span every strip
        ext[:7, 1] = 500.0
    elif layout == "far":  # one body far away: the strip height must not collapse
        c[0] = 1e9
    return c - ext, c + ext


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("layout", ["uniform", "line", "column", "points", "tall", "far"])
def test_sweep_strips_exact(dim, layout):
    """The sweep in strips returns exactly the bound-overlapping pairs (brute
    force), each once, however the centres are laid out across the strips;
    with states given, exactly those that also pass relative_filter."""
    rng = np.random.default_rng(len(layout) + dim)
    n = 300
    lo, hi = _scene_bounds(rng, n, dim, layout)
    ref = _brute_overlap(lo, hi)
    I, J, n_box = bp.candidate_pairs(lo, hi, method="sweep")
    got = list(zip(I.tolist(), J.tolist()))
    assert len(got) == len(set(got)) == n_box == len(ref)
    assert set(got) == ref and np.all(I < J)
    # relative test: random states whose swept bounds are lo/hi's boxes
    p = 0.5 * (lo + hi)
    v = rng.normal(0, 2, (n, dim))
    a = rng.normal(0, 1, (n, dim))
    r = rng.uniform(0, 1, n)
    tref = rng.uniform(-0.5, 0.0, n)
    I, J, n_box = bp.candidate_pairs(lo, hi, p=p, v=v, a=a, r=r, tref=tref, t_start=0.0, t_end=2.0)
    RI, RJ = (np.array(x, dtype=np.int64) for x in zip(*sorted(ref)))
    keep = bp.relative_filter(p, v, a, r, tref, RI, RJ, 0.0, 2.0)
    assert n_box == len(ref)
    assert set(zip(I.tolist(), J.tolist())) == set(zip(RI[keep].tolist(), RJ[keep].tolist()))


def test_relative_test_threaded_is_serial():
    """The relative test on numba's threads (from PARALLEL_MIN_PAIRS pairs)
    keeps exactly the pairs the serial one keeps."""
    rng = np.random.default_rng(3)
    n = 4000
    p = rng.uniform(0, 60, (n, 2))
    v = rng.normal(0, 3, (n, 2))
    a = rng.normal(0, 1, (n, 2))
    r = rng.uniform(0.2, 1.5, n)
    tref = np.zeros(n)
    I = rng.integers(0, n, 3 * relative.PARALLEL_MIN_PAIRS)
    J = rng.integers(0, n, I.size)
    args = (p, v, a, r, tref, I, J, 0.0, 3.0)
    assert np.array_equal(relative.rel_mask_par(*args), relative.rel_mask(*args))
    lo, hi = bp.swept_bounds(p, v, a, r, 0.0, 3.0)
    I, J, n_box = bp.candidate_pairs(lo, hi, p=p, v=v, a=a, r=r, tref=tref, t_start=0.0, t_end=3.0)
    assert n_box >= relative.PARALLEL_MIN_PAIRS  # the threaded branch, when a core is free
    ref = _brute_overlap(lo, hi)
    RI, RJ = (np.array(x, dtype=np.int64) for x in zip(*sorted(ref)))
    keep = bp.relative_filter(p, v, a, r, tref, RI, RJ, 0.0, 3.0)
    assert set(zip(I.tolist(), J.tolist())) == set(zip(RI[keep].tolist(), RJ[keep].tolist()))


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize(
    "layout", ["uniform", "line", "column", "points", "tall", "far", "cluster"]
)
def test_threaded_sweep_is_the_serial_sweep(dim, layout):
    """The sweep on numba's threads (from PARALLEL_MIN_BODIES bodies) returns the
    serial sweep's pairs in the serial sweep's order, whatever the layout --
    including a cluster whose pairs overflow a group's slice (every bound
    overlaps every other), where it hands over to the serial sweep."""
    rng = np.random.default_rng(10 * dim + len(layout))
    n = 600
    if layout == "cluster":
        lo, hi = _scene_bounds(rng, n, dim, "uniform")
        lo[:150], hi[:150] = 99.0, 101.0  # 150 bodies on one spot: 149 overlaps each
    else:
        lo, hi = _scene_bounds(rng, n, dim, layout)
    ax, ay = sweep._sweep_axes(lo, hi)
    order = np.argsort(lo[:, ax])
    first, last = sweep._strips(lo, hi, ay)
    start, body = sweep._strip_entries(order, first, last)
    S0, T0 = sweep._sweep_strips(lo, hi, ax, first, start, body)
    S1, T1 = sweep._sweep_strips_par(lo, hi, ax, first, start, body)
    assert np.array_equal(S0, S1) and np.array_equal(T0, T1)
    if layout == "cluster":  # more pairs than all slices hold: some group overflowed
        assert S0.size > sweep._PAIRS_PER_ENTRY * body.size + 16 * sweep._SWEEP_GROUPS
    ref = _brute_overlap(lo, hi)
    assert set(zip(body[S1].tolist(), body[T1].tolist())) == ref


def test_threaded_sweep_through_candidate_pairs():
    """A scene above PARALLEL_MIN_BODIES takes the threaded sweep and still returns
    exactly the brute-force pairs."""
    rng = np.random.default_rng(5)
    n = sweep.PARALLEL_MIN_BODIES + 500
    c = rng.uniform(0, 400, (n, 2))
    ext = rng.uniform(0.5, 3.0, (n, 2))
    lo, hi = c - ext, c + ext
    I, J, n_box = bp.candidate_pairs(lo, hi)
    ref = _brute_overlap(lo, hi)
    assert n_box == len(ref) and set(zip(I.tolist(), J.tolist())) == ref
