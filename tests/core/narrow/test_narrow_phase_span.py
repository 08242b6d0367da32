"""Rows whose relative quantities span more magnitudes than float64 keeps.

The solver scales the relative state by a power of two so that its largest
component lies in [2, 4) (``narrow_eval._rel2/_rel3``).  A component far
below the largest is then rounded on the subnormal grid or flushed to 0, and
even an exact small component has squares that underflow.  Found in a review:
``dp = 1e150, da = -1e-175`` looked like ``da = 0`` and the
straight-line closed form answered inf; the exact answer is 4.47e162 s.

Guarantee proved here (against ``tests.core.reference.exact_reference``,
exact rationals): rows with a nonzero relative component below 2^-240 of the
largest (``narrow_eval._SPAN``) -- tiny da against huge dp or dv, tiny dv
with or without da, tiny dp or R against huge dv, flushed, subnormal or
with underflowing squares, 2-D and 3-D -- get the exact answer (0.0 / inf
exactly, a finite time within one ulp; they are decided by the exact path,
so correctly rounded) from the batch entry, the one-pair entry (tuples,
lists, 1-D arrays) and the numba scalar alike, alone or mixed into a batch
of ordinary rows.  Inputs are dyadic with short mantissas, so the
constructions hold exactly.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from circle_collision_ros.core import time_to_collision
from tests.core.reference import exact_reference
from tests.core.narrow.test_narrow_phase_accuracy import mixed_pairs
from tests.core.narrow.test_narrow_phase_exact import _agrees, _check

SPAN_BITS = 240  # narrow_eval._SPAN = 2^-240


def _ivec(rng, D, k=8):
    """A nonzero vector of small integers (exact in any power-of-two scale)."""
    while True:
        w = rng.integers(-k, k + 1, D).astype(float)
        if w.any():
            return w


def _p2(e):
    return math.ldexp(1.0, int(e))


def _bodies(rng, dp, dv, da, R, eb_p, eb_v, eb_a):
    """Absolute states of two bodies with the given exact relative state:
    body b at a dyadic offset of the same scale as each quantity (so every
    sum stays exact), radii splitting R."""
    D = len(dp)
    pb = _ivec(rng, D) * _p2(eb_p) if rng.random() < 0.5 else np.zeros(D)
    vb = _ivec(rng, D) * _p2(eb_v) if rng.random() < 0.5 else np.zeros(D)
    ab = _ivec(rng, D) * _p2(eb_a) if rng.random() < 0.5 else np.zeros(D)
    ra = R * rng.choice([1.0, 0.5, 0.25, 0.0])
    rb = R - ra
    pa, va, aa = pb + dp, vb + dv, ab + da
    assert (
        (pa - pb == dp).all() and (va - vb == dv).all() and (aa - ab == da).all() and ra + rb == R
    )
    return tuple(map(tuple, (pa, va, aa))) + (ra,) + tuple(map(tuple, (pb, vb, ab))) + (rb,)


def gen_tiny_da(rng, n, D):
    """|dp| ~ 2^ep (up to ~1e150), da 2^241 to 2^1500 times smaller pulling
    body a back (flushed to 0, subnormal or squares underflowing after the
    scaling); dv 0, slow along the line, or slow sideways."""
    rows = []
    for _ in range(n):
        ep = int(rng.integers(150, 495))
        ea = int(rng.integers(-1070, ep - SPAN_BITS - 1))
        w = _ivec(rng, D)
        dp = w * _p2(ep)
        da = -w * _p2(ea) * float(rng.integers(1, 4))
        if rng.random() < 0.3:
            da = da + _ivec(rng, D, 2) * _p2(ea)  # not exactly along the line
        # time to fall back ~ sqrt(2 |dp| / |da|) = 2^et; dv ~ |dp| / that time or less
        et = (ep - ea + 1) // 2
        kind = rng.integers(3)
        ev = max(ep - et - int(rng.integers(0, 4)), -1070)
        dv = (
            np.zeros(D)
            if kind == 0
            else (
                w * _p2(ev) * rng.choice([-1.0, 1.0]) if kind == 1 else _ivec(rng, D, 2) * _p2(ev)
            )
        )
        R = _p2(ep) * rng.choice([0.0, 0.5, 0.75])
        rows.append(_bodies(rng, dp, dv, da, R, ep, ev, ea))
    return rows


def _closing(rng, D, ep, ev):
    """(w, dp, dv): dp = w 2^ep along a small-integer vector w, dv closing
    along the same line at 1-3 x 2^ev."""
    w = _ivec(rng, D)
    return w, w * _p2(ep), -w * _p2(ev) * float(rng.integers(1, 4))


def gen_tiny_dv(rng, n, D):
    """Constant velocity (da = 0) with dv 2^241 to 2^1020 times smaller than
    dp: along the line (contact after up to ~2^1020 s), beside it, or
    flushed completely (then the contact time overflows float64: inf);
    a fifth with a small nonzero da as well."""
    rows = []
    for _ in range(n):
        ep = int(rng.integers(-200, 495))
        ev = int(rng.integers(max(ep - 1100, -1070), ep - SPAN_BITS - 1))
        w, dp, dv = _closing(rng, D, ep, ev)
        if rng.random() < 0.3:
            dv = dv + _ivec(rng, D, 1) * _p2(ev)
        da = np.zeros(D)
        ea = ev
        if rng.random() < 0.2:
            ea = max(2 * ev - ep - int(rng.integers(0, 8)), -1070)
            da = -w * _p2(ea)
        R = _p2(ep) * rng.choice([0.0, 0.5, 0.75])
        rows.append(_bodies(rng, dp, dv, da, R, ep, ev, ea))
    return rows


def gen_tiny_dp(rng, n, D):
    """Huge dv against a tiny dp (and a tiny or zero R): contacts after
    2^-1000 to 2^-241 s (subnormal-free), points and tiny bodies; bodies
    with R > 0 also pass beside each other on straight or curved paths.
    (Points, R = 0, stay on the line through them: off it their distance is
    ~2^(ep - ev) of the scale, and the Descartes reference takes ~15 s to
    prove such a near-double root absent.)"""
    rows = []
    for _ in range(n):
        ev = int(rng.integers(-100, 495))
        ep = int(rng.integers(max(ev - 1000, -1060), ev - SPAN_BITS - 1))
        w, dp, dv = _closing(rng, D, ep, ev)
        R = _p2(ep) * rng.choice([0.0, 0.5, 0.75, 1.0])
        da = np.zeros(D) if rng.random() < 0.5 else w * _p2(ev) * rng.choice([-1.0, 1.0])
        if R > 0.0 and rng.random() < 0.5:
            dv = dv + _ivec(rng, D, 1) * _p2(ev - int(rng.integers(0, 3)))
            da = da + _ivec(rng, D) * _p2(ev)
        rows.append(_bodies(rng, dp, dv, da, R, ep, ev, ev))
    return rows


GENS = {"tiny_da": gen_tiny_da, "tiny_dv": gen_tiny_dv, "tiny_dp": gen_tiny_dp}


def _horizons(rows, rng):
    """Per row: inf, or a power of two near the exact contact time (either
    side), so both outcomes of the horizon test occur."""
    Hs = []
    for r in rows:
        if rng.random() < 0.5:
            Hs.append(math.inf)
            continue
        t = exact_reference(*r).t
        if t == 0.0 or math.isinf(t):
            Hs.append(_p2(int(rng.integers(-20, 600))))
        else:
            Hs.append(_p2(math.frexp(t)[1] + int(rng.integers(-2, 2))))
    return np.array(Hs)


def test_issue_repro_flushed_da():
    """dp = 1e150, da = -1e-175 (flushed to 0 by the scaling): not straight."""
    row = ((1e150, 0.0), (0.0, 0.0), (-1e-175, 0.0), 1.0, (0.0, 0.0), (0.0, 0.0), (0.0, 0.0), 0.0)
    ref = exact_reference(*row)
    assert 4.47e162 < ref.t < 4.48e162
    _check([row], math.inf)
    row3 = (
        ((1e150, 0.0, 0.0), (0.0, 0.0, 0.0), (-1e-175, 0.0, 0.0), 1.0) + ((0.0,) * 3,) * 3 + (0.0,)
    )
    _check([row3], math.inf)


def test_repro_underflowing_speed_squared():
    """da = 0, dv = 1e-163 dp: |dv|^2 underflows (was "at rest": inf)."""
    row = ((1.0, 0.0), (-1e-163, 0.0), (0.0, 0.0), 0.5, (0.0, 0.0), (0.0, 0.0), (0.0, 0.0), 0.0)
    assert math.isfinite(exact_reference(*row).t)
    _check([row], math.inf)


@pytest.mark.parametrize("D", [2, 3])
@pytest.mark.parametrize("gen", sorted(GENS))
def test_span_rows(gen, D):
    """Each generator, per-row horizons; batch, one pair and numba scalar."""
    rng = np.random.default_rng([1717, len(gen), D])
    rows = GENS[gen](rng, 40, D)
    _check(rows, _horizons(rows, rng))


@pytest.mark.parametrize("D", [2, 3])
def test_span_rows_in_ordinary_batches(D):
    """Span rows mixed into ordinary rows (fast, straight and robust paths in
    the same blocks), one float horizon; also the one-pair entry with lists
    and 1-D arrays: every row exact, ordinary rows unchanged."""
    rng = np.random.default_rng([2626, D])
    span = sum((GENS[g](rng, 12, D) for g in sorted(GENS)), [])
    H = 2.0**600
    P = mixed_pairs(300, D, 5)
    ordinary = time_to_collision(*P, horizon=H)
    m = len(span)
    idx = rng.permutation(300 + m)
    arrs = [np.empty((300 + m, D)) if k not in (3, 7) else np.empty(300 + m) for k in range(8)]
    for k in range(8):
        arrs[k][idx[:300]] = P[k]
        arrs[k][idx[300:]] = np.array([r[k] for r in span], dtype=float)
    t = time_to_collision(*arrs, horizon=H)
    assert np.array_equal(t[idx[:300]], ordinary)
    bad = []
    for j, row in enumerate(span):
        ref = exact_reference(*row, H)
        got = float(t[idx[300 + j]])
        as_lists = float(
            time_to_collision(*(list(x) if isinstance(x, tuple) else x for x in row), H)
        )
        as_arrays = float(
            time_to_collision(*(np.array(x) if isinstance(x, tuple) else x for x in row), H)
        )
        if not (_agrees(got, ref, H) and as_lists == got and as_arrays == got):
            bad.append((row, got, as_lists, as_arrays, ref.t))
    assert not bad, f"{len(bad)} of {m} wrong, first: {bad[:3]}"
