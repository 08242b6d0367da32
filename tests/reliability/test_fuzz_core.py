"""Hypothesis fuzzing of the core: time_to_collision and predict_all_pairs.

Guarantees proved here:
- over the whole float64 range (subnormals, huge magnitudes, +-inf, NaN,
  negative and zero radii, D = 2 and 3) time_to_collision never raises for
  well-shaped input, and returns NaN exactly where documented (a non-finite
  input, a negative radius, a negative/NaN horizon); otherwise 0, a time in
  (0, horizon] or +inf;
- predict_all_pairs raises ValueError for non-finite/negative-radius rows or a
  bad horizon (and nothing else), never raises otherwise, and inside the
  documented input range (|values| < ~1e150) returns exactly the brute-force
  narrow-phase pairs, bitwise; outside it, it only has to survive;
- on a sample of fuzzed in-range pairs the mpmath reference (tests/core/reference.py)
  confirms contact/no contact and the time (<= 4 ulp, scaled by |cos| as in
  tests/core/test_narrow_phase_accuracy.py).

Example counts: a quick sample by default, the full counts under --stress (tests/stress.py).
"""
from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from circle_collision_ros.core import predict_all_pairs, time_to_collision
from tests.core.reference import reference
from tests.reliability.conftest import tally
from tests.stress import examples

IN_RANGE = 1e150
# narrow_phase.py: "finite values with magnitudes below ~1e150".
# Core bugs found by these fuzzers (core/ is others' to fix; regression tests below):
# - spurious contact at t = 0 with a tiny closing velocity (HEAD 5ceb7cb): fixed by fbe136e;
# - ZeroDivisionError out of range (fbe136e): fixed (error_model="numpy"); regression test below;
# - coincident centres with a subnormal R (R^2 underflows) missed (fbe136e), and states
#   whose magnitudes are all tiny (~1e-80) or all huge (~1e78): fixed by scaling the
#   relative state by a power of two (narrow_eval); regression tests below and in
#   tests/core/test_narrow_phase_api.py.
# Documented dynamic range: components of the relative state below ~1e-150 of its largest
# one are negligible (a relative acceleration that small may count as zero, a radius sum
# that small as a point), so the mpmath sample skips those.
ULP_TOL = 4.0

any_float = st.floats(allow_nan=True, allow_infinity=True, allow_subnormal=True)
special = st.sampled_from([0.0, -0.0, 5e-324, -5e-324, 2.2250738585072014e-308, 1e-200, 1e150,
                           -1e150, 1e200, 1.7976931348623157e308, -1.7976931348623157e308,
                           math.inf, -math.inf, math.nan])
finite_special = st.sampled_from([0.0, -0.0, 5e-324, -5e-324, 2.2250738585072014e-308, 1e-200,
                                  1e-120, 1e149, -1e149, 1e151, 1e200, 1.7976931348623157e308])
# Finite over the whole range (subnormals included), plain magnitudes weighted up so that
# in-range cases are common; non-finite values are injected separately (_inject).
wild = st.one_of(st.floats(allow_nan=False, allow_infinity=False), finite_special,
                 st.floats(-1e3, 1e3), st.floats(-1e3, 1e3))
NON_FINITE = st.sampled_from([None, None, None, math.nan, math.inf, -math.inf])
# For the mpmath sample: spread-out values (hypothesis' favourite 0, 1, 0.5 make
# perfect-power quartics on which mpmath.polyroots does not converge), tiny ones too.
moderate = st.one_of(st.integers(-10**7, 10**7).map(lambda k: k / 997.0),
                     st.sampled_from([0.0, 5e-324, 1e-300, -1e-200]))
radius_in_range = st.one_of(st.integers(0, 10**6).map(lambda k: k / 1009.0),
                            st.sampled_from([0.0, 5e-324, 1e-200]))

quiet = warnings.catch_warnings  # overflow warnings out of range are expected, not errors


def _vec(elements, d):
    return st.lists(elements, min_size=d, max_size=d)


@st.composite
def pairs(draw, values, radii, inject=False):
    d = draw(st.sampled_from([2, 3]))
    vecs = [draw(_vec(values, d)) for _ in range(6)]
    ra, rb = draw(radii), draw(radii)
    bad = draw(NON_FINITE) if inject else None
    if bad is not None:  # one non-finite number somewhere (a vector component or a radius)
        k = draw(st.integers(0, 6 * d + 1))
        if k < 6 * d:
            vecs[k // d][k % d] = bad
        elif k == 6 * d:
            ra = bad
        else:
            rb = bad
    return d, vecs, ra, rb


def _documented_nan(vecs, ra, rb, horizon) -> bool:
    finite = (
        all(math.isfinite(x) for v in vecs for x in v) and math.isfinite(ra) and math.isfinite(rb)
    )
    return not finite or not (ra >= 0.0) or not (rb >= 0.0) or not (horizon >= 0.0)


def test_coincident_points_subnormal_radius() -> None:
    """Found by test_mpmath_reference_confirms_a_sample on fbe136e: coincident centres with
    R = 5e-324 overlap (distance 0 < R), but R^2 underflowed and time_to_collision said inf.
    Fixed by scaling the relative state exactly (narrow_eval._rel2/_rel3)."""
    z = [0.0, 0.0, 0.0]
    assert float(time_to_collision(z, z, z, 0.0, z, z, z, 5e-324, 0.5)) == 0.0
    assert (
        float(time_to_collision(z[:2], z[:2], z[:2], 0.0, z[:2], z[:2], z[:2], 5e-324, math.inf))
        == 0.0
    )


def _ttc(vecs, ra, rb, horizon) -> float:
    pa, va, aa, pb, vb, ab = vecs
    with quiet():
        warnings.simplefilter("ignore", RuntimeWarning)
        return float(time_to_collision(pa, va, aa, ra, pb, vb, ab, rb, horizon))


@settings(
    max_examples=examples(200, 2000), deadline=None, suppress_health_check=[HealthCheck.too_slow]
)
@given(
    pairs(wild, st.one_of(st.floats(0.0, 10.0), wild), inject=True),
    st.one_of(st.just(math.inf), st.floats(0.0, 100.0), any_float, special),
)
def test_time_to_collision_whole_float_range(pair, horizon) -> None:
    _, vecs, ra, rb = pair
    t = _ttc(vecs, ra, rb, horizon)  # never an exception, in range or not
    tally("examples")
    if _documented_nan(vecs, ra, rb, horizon):
        tally("documented_nan")
        assert math.isnan(t)
        return
    if not _in_range(vecs, (ra, rb)):
        # Outside |values| < ~1e150 nothing is promised but survival; NaN occurs
        # (e.g. velocities ~9e307) and is counted, not failed.
        tally("out_of_range")
        tally("out_of_range_nan", int(math.isnan(t)))
        assert math.isnan(t) or t == math.inf or 0.0 <= t <= horizon
        return
    tally("in_range")
    assert not math.isnan(t), "NaN for finite in-range input with radii >= 0 and horizon >= 0"
    assert t == math.inf or 0.0 <= t <= horizon


@settings(max_examples=examples(30, 300), deadline=None)
@given(pairs(wild, st.one_of(st.floats(0.0, 10.0), wild), inject=True), st.integers(2, 5000))
def test_time_to_collision_batched_equals_scalar(pair, n) -> None:
    """The batched (and, from 4096 rows, multi-threaded) kernel gives the scalar answer per row."""
    d, vecs, ra, rb = pair
    rows = [np.tile(np.asarray(v, dtype=float), (n, 1)) for v in vecs]
    with quiet():
        warnings.simplefilter("ignore", RuntimeWarning)
        out = time_to_collision(*rows[:3], np.full(n, ra), *rows[3:], np.full(n, rb), 5.0)
    one = _ttc(vecs, ra, rb, 5.0)
    tally("examples")
    tally("rows", n)
    assert out.shape == (n,)
    assert np.array_equal(out, np.full(n, one), equal_nan=True)


def test_tiny_closing_velocity_is_no_contact() -> None:
    """Found by test_predict_all_pairs_equals_brute_force_on_dense_scenes at HEAD 5ceb7cb (fixed
    by fbe136e): bodies 1 m apart (R = 0.2), closing at 1e-112 m/s while accelerating apart at
    1 m/s^2, never get closer than ~1 m, yet time_to_collision said 0.0 (touching now)."""
    t = float(
        time_to_collision([0.0, 0.0], [0.0, 0.0], [0.0, 0.0], 0.1, [0.0, 1.0], [0.0, -1e-112],
                          [0.0, 1.0], 0.1, horizon=5.0)
    )
    assert t == math.inf


def _in_range(vecs, radii) -> bool:
    return all(abs(x) < IN_RANGE for v in vecs for x in v) and all(0 <= r < IN_RANGE for r in radii)


def test_out_of_range_example_does_not_raise() -> None:
    """Found by test_time_to_collision_whole_float_range: the kernels raised
    ZeroDivisionError (numba's Python error model) for out-of-range input. Fixed by compiling
    them with error_model="numpy" (IEEE division). Out of range only a finite answer, inf or
    NaN is allowed, never an exception."""
    t = _ttc(
        [[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 0.0, 1.3407807929942597e154],
         [8.98846567431158e307, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]],
        0.0,
        0.0,
        math.inf,
    )
    assert math.isnan(t) or t == math.inf or t >= 0.0


@settings(
    max_examples=examples(60, 200), deadline=None, suppress_health_check=[HealthCheck.too_slow]
)
@given(pairs(moderate, radius_in_range), st.sampled_from([0.5, 5.0, 100.0, math.inf]))
def test_mpmath_reference_confirms_a_sample(pair, horizon) -> None:
    d, vecs, ra, rb = pair
    assume(ra + rb > 0.0)
    tally("examples")
    t = _ttc(vecs, ra, rb, horizon)
    pa, va, aa, pb, vb, ab = vecs
    rel = [abs(x - y) for u, w in ((pa, pb), (va, vb), (aa, ab)) for x, y in zip(u, w)]
    scale = max(rel + [ra + rb])
    da = max(rel[2 * d :])
    if 0.0 < da < 1e-140 * scale or 0.0 < ra + rb < 1e-140 * scale:
        tally("below_dynamic_range")  # documented as negligible (see top)
        return
    try:
        ref = reference(pa, va, aa, ra, pb, vb, ab, rb, horizon=horizon)
    except RuntimeError:  # mpmath.polyroots did not converge: no verdict from the reference
        tally("reference_failed")
        return
    if ref.ambiguous:
        tally("ambiguous")
        return  # within 1e-9 R^2 of a graze: either answer is allowed
    tally("confirmed")
    tally("contacts", int(math.isfinite(t)))
    assert math.isinf(t) == math.isinf(ref.t), (t, ref.t)
    if math.isinf(t):
        return
    if ref.t == 0.0:
        assert t == 0.0
    else:
        assert abs(t - ref.t) / np.spacing(ref.t) * ref.cos <= ULP_TOL, (t, ref.t, ref.cos)


@st.composite
def scenes(draw, values, radii, n_max=10, inject=False):
    d = draw(st.sampled_from([2, 3]))
    n = draw(st.integers(0, n_max))
    def arr():
        return np.array(
            draw(st.lists(values, min_size=n * d, max_size=n * d)),
            dtype=float,
        ).reshape(n, d)

    p, v, a = arr(), arr(), arr()
    r = np.array(draw(st.lists(radii, min_size=n, max_size=n)), dtype=float)
    bad = draw(NON_FINITE) if inject and n else None
    if bad is not None:
        arrays = (p, v, a, r)
        target = arrays[draw(st.integers(0, 3))].reshape(-1)
        target[draw(st.integers(0, target.size - 1))] = bad
    return p, v, a, r


def _brute_force(p, v, a, r, h):
    """Every pair through the narrow phase, one scalar call each: independent of the broad
    phase and of the batched kernel predict_all_pairs uses. (One batched call on all index
    pairs is no cheaper here -- the time goes into the per-pair robust fallbacks of these
    dense scenes, ~2 ms a pair either way -- so the reference stays the one-pair path.)"""
    n = len(r)
    out = {}
    for i in range(n):
        for j in range(i + 1, n):
            t = float(time_to_collision(p[i], v[i], a[i], r[i], p[j], v[j], a[j], r[j], h))
            if t <= h:
                out[(i, j)] = t
    return out


def _compared(res, v) -> dict:
    return dict(zip(zip(res.i.tolist(), res.j.tolist()), res.ttc.tolist()))


def _call(p, v, a, r, h):
    with quiet():
        warnings.simplefilter("ignore", RuntimeWarning)
        return predict_all_pairs(p, v, a, r, h)


@settings(
    max_examples=examples(150, 1500), deadline=None, suppress_health_check=[HealthCheck.too_slow]
)
@given(
    scenes(wild, st.one_of(st.floats(-1.0, 10.0), wild), inject=True),
    st.one_of(st.floats(0.01, 100.0), st.floats(0.01, 100.0), special),
)
def test_predict_all_pairs_whole_float_range(scene, horizon) -> None:
    p, v, a, r = scene
    tally("examples")
    bad_rows = ~(
        np.isfinite(p).all(1)
        & np.isfinite(v).all(1)
        & np.isfinite(a).all(1)
        & np.isfinite(r)
        & (r >= 0.0)
    )
    bad_horizon = not (math.isfinite(horizon) and horizon > 0.0)
    if bad_rows.any() or bad_horizon:
        tally("value_error_expected")
        with pytest.raises(ValueError) as info:
            _call(p, v, a, r, horizon)
        assert (
            ("horizon" in str(info.value))
            if not bad_rows.any()
            else "non-finite state or negative radius" in str(info.value)
        )
        return
    res = _call(p, v, a, r, horizon)
    k = len(res)
    assert res.i.shape == res.j.shape == res.ttc.shape == (k,)
    assert np.all(res.i < res.j) and np.all((res.ttc >= 0.0) & (res.ttc <= horizon))
    assert np.all(np.diff(res.ttc) >= 0.0)
    if _in_range([p.ravel(), v.ravel(), a.ravel()], r.tolist()):
        tally("in_range_compared")
        got = _compared(res, v)
        assert got == _brute_force(p, v, a, r, horizon), [x.tolist() for x in scene]
        assert np.isfinite(res.point).all() and np.isfinite(res.normal).all()
        assert np.isfinite(res.closing_speed).all()


@settings(
    max_examples=examples(15, 300), deadline=None, suppress_health_check=[HealthCheck.too_slow]
)
@given(scenes(st.floats(-50.0, 50.0), st.floats(0.0, 5.0), n_max=40), st.floats(0.1, 20.0))
def test_predict_all_pairs_equals_brute_force_on_dense_scenes(scene, horizon) -> None:
    """Scenes dense enough that the broad phase has real work: still exactly the brute force."""
    p, v, a, r = scene
    tally("examples")
    tally("bodies", len(r))
    res = _call(p, v, a, r, horizon)
    tally("contacts", len(res))
    got = _compared(res, v)
    assert got == _brute_force(p, v, a, r, horizon), [x.tolist() for x in scene]


def test_collinear_turnaround_near_miss() -> None:
    """Found by test_mpmath_reference_confirms_a_sample: collinear motion that turns around
    3% short of contact (minimum gap 1.02/997 m > R = 1/1009 m). The straight-line model at
    the turnaround has g' ~ 0 parallel to g, so |g x g'|/|g'| was 0 and a contact was
    reported (0.0 compiled, 0.28 s pure Python); the exact answer is no contact."""
    t = time_to_collision(np.array([0.0, 0.0]), np.array([0.0, 0.0]), np.array([0.0, -25 / 997.0]),
                          0.0, np.array([0.0, 2 / 997.0]), np.array([0.0, -7 / 997.0]),
                          np.array([0.0, 0.0]), 1 / 1009.0)
    assert float(t) == math.inf
    assert (
        reference([0.0, 0.0], [0.0, 0.0], [0.0, -25 / 997.0], 0.0, [0.0, 2 / 997.0],
                  [0.0, -7 / 997.0], [0.0, 0.0], 1 / 1009.0, horizon=math.inf).t
        == math.inf
    )
