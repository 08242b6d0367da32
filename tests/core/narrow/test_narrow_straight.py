"""The constant-velocity closed form (``narrow_straight``): its SIMD loop
(``narrow_fast.straight_rows``), the robust solver and the scalar entry points.

Guarantees proved here:

* Every da = 0 row the straight loop decides gets the exact answer: 0.0 and
  inf exactly, a time within one ulp of the exact first contact
  (``tests.core.reference.exact_reference``: exact rationals), on aimed,
  grazing (miss distance R (1 +- 1e-15 .. 1e-3)), touching, dyadic and
  far-scaled rows, with H finite, 0 and inf -- test_straight_rows_are_exact.
* The loop, the robust solver and the scalar entry points run the same
  function: bit for bit the same answers -- test_one_function_on_every_path.
* It decides the bulk of constant-velocity batches (else the speed-up would
  come from nowhere): >= 99 % of the benchmark mix with da = 0, H = 10 s and
  inf -- test_decides_the_bulk.
* Batches mixing straight and accelerating rows in one block: every row gets
  its answer alone, whichever loop ran on it -- test_mixed_blocks.
* Invalid rows (non-finite value, negative radius or horizon) are never
  decided by it: NaN from the robust solver -- test_invalid_rows.
* Tiny bodies or points far apart (R down to 0 and up to ~1e-42 |dp|),
  head-on or grazing within an ulp of R, with a relative state that needs
  double-double (so the cross product of the miss test has its absolute
  error ~u^2 |dp|): the straight loop never calls such a contact a miss, and
  the public API gets every row exactly -- test_tiny_bodies_far_apart (the
  miss test's bound is derived next to it in narrow_straight).
"""
from __future__ import annotations

import math
from fractions import Fraction

import numpy as np
import pytest

from circle_collision_ros.core.narrow import batch as npz
from circle_collision_ros.core.narrow.evaluate import UNDECIDED
from circle_collision_ros.core.narrow.fast import count_straight, straight_rows
from circle_collision_ros.core.narrow import time_to_collision
from tests.core.narrow.test_narrow_fast import _robust
from tests.core.narrow.test_narrow_phase_accuracy import mixed_pairs
from tests.core.narrow.test_narrow_phase_exact import _agrees
from tests.core.reference import ExactRef, exact_reference
from tests.stress import examples


def _agrees_straight(t, row, ref, H):
    """``_agrees`` with the reference interval narrowed first: exact_reference
    stops bisecting once both ends round to the same float, and then accepts
    only that float although the root may lie just below it (the float below
    is then within one ulp too).  f is the quadratic |dp + t dv|^2 - R^2,
    > 0 before its first root and <= 0 just after it: 200 more exact
    bisections leave an interval that straddles no float."""
    if _agrees(t, ref, H) or ref.t == 0.0 or math.isinf(ref.t) or ref.lo == ref.hi:
        return _agrees(t, ref, H)
    F = lambda x: Fraction(float(x))  # noqa: E731
    dp = [F(x) - F(y) for x, y in zip(row[0], row[4])]
    dv = [F(x) - F(y) for x, y in zip(row[1], row[5])]
    R = F(row[3]) + F(row[7])
    lo, hi = ref.lo, ref.hi
    for _ in range(200):
        mid = (lo + hi) / 2
        if sum((p + mid * v) ** 2 for p, v in zip(dp, dv)) > R * R:
            lo = mid
        else:
            hi = mid
    return _agrees(t, ExactRef(float(lo), lo, hi), H)


def _straight_loop(args, H, keep_from=None):
    """straight_rows over all rows (one call); keep_from: values already in out."""
    n = args[3].shape[0]
    out = np.full(n, np.nan) if keep_from is None else keep_from.copy()
    Hs = np.broadcast_to(np.asarray(H, float), (n,)).copy()
    straight_rows(*args, Hs, 0, out, 0, n, (0.0,) * args[0].shape[1], keep_from is not None)
    return out


def stress_rows(n, D, seed):
    """da = 0 rows of several kinds (a_a == a_b, both nonzero): aimed, grazing
    at a miss distance R (1 +- 10^-k), touching at t = 0, dyadic small
    integers (exact touches and grazes), and random rows scaled by 10^+-100."""
    rng = np.random.default_rng(seed)
    kind = np.arange(n) % 5
    pb = rng.uniform(-20, 20, (n, D))
    vb = rng.normal(0, 2, (n, D))
    ab = rng.normal(0, 1, (n, D))
    ra = rng.uniform(0.1, 2, n)
    rb = rng.uniform(0.1, 2, n)
    R = ra + rb
    dv = rng.normal(0, 2, (n, D))
    T = rng.uniform(0.01, 10, n)
    u = rng.normal(size=(n, D))
    u -= (np.sum(u * dv, axis=1) / np.sum(dv * dv, axis=1))[:, None] * dv  # perpendicular to dv
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    pa = rng.uniform(-20, 20, (n, D))
    # aimed: touching at T on the approach side
    w = -dv / np.linalg.norm(dv, axis=1, keepdims=True)
    e = rng.uniform(0.2, 1.0, n)[:, None] * w + rng.uniform(-0.5, 0.5, n)[:, None] * u
    e /= np.linalg.norm(e, axis=1, keepdims=True)
    aim = pb - R[:, None] * e - T[:, None] * dv
    pa[kind == 0] = aim[kind == 0]
    # grazing: closest approach R (1 +- 10^-k) at T
    k = rng.uniform(3, 15, n)
    miss = R * (1 + rng.choice([-1.0, 1.0], n) * 10.0 ** -k)
    graze = pb + miss[:, None] * u - T[:, None] * dv
    pa[kind == 1] = graze[kind == 1]
    # touching at t = 0 (|dp| = R up to rounding), any direction of motion
    pa[kind == 2] = (pb + R[:, None] * u)[kind == 2]
    va = vb + dv
    rows = [pa, va, ab.copy(), ra, pb, vb, ab, rb]
    # dyadic: small integers, b at rest at the origin with r_b = 0
    d = kind == 3
    rows[0][d] = rng.integers(-6, 7, (d.sum(), D))
    rows[1][d] = rng.integers(-3, 4, (d.sum(), D))
    rows[3][d] = rng.integers(0, 5, d.sum())
    rows[4][d] = 0.0
    rows[5][d] = 0.0
    rows[7][d] = 0.0
    # far scales: everything times 10^s, s in [-100, 100]
    f = kind == 4
    s = 10.0 ** rng.uniform(-100, 100, f.sum())
    for x in rows:
        x[f] = x[f] * (s[:, None] if x.ndim == 2 else s)
    rows[2] = rows[6].copy()  # a_a == a_b exactly: da = 0
    return tuple(np.ascontiguousarray(x, dtype=float) for x in rows)


@pytest.mark.parametrize("D", [2, 3])
@pytest.mark.parametrize("H", [0.0, 0.5, 5.0, math.inf])
def test_straight_rows_are_exact(D, H):
    args = stress_rows(600, D, seed=7 + D)
    got = _straight_loop(args, H)
    assert not np.isnan(got).any()
    dec = np.flatnonzero(got != UNDECIDED)
    assert dec.size > 0.7 * got.size, dec.size
    bad = []
    for i in dec:
        row = tuple(x[i] for x in args)
        ref = exact_reference(*row, H)
        if not _agrees_straight(float(got[i]), row, ref, H):
            bad.append((i, got[i], ref.t))
    assert not bad, f"{len(bad)} wrong, first {bad[:3]}"
    # the public API decides the rest (robust solver, exact path) the same way
    api = time_to_collision(*args, H)
    assert np.array_equal(api[dec], got[dec])
    for i in np.flatnonzero(got == UNDECIDED)[:40]:
        row = tuple(x[i] for x in args)
        assert _agrees_straight(float(api[i]), row, exact_reference(*row, H), H)


@pytest.mark.parametrize("D", [2, 3])
@pytest.mark.parametrize("H", [3.0, math.inf])
def test_one_function_on_every_path(D, H):
    args = stress_rows(1500, D, seed=40 + D)
    loop = _straight_loop(args, H)
    robust = _robust(args, H)  # robust solver per row (+ exact where it is undecided)
    dec = loop != UNDECIDED
    assert np.array_equal(loop[dec], robust[dec])
    api = time_to_collision(*args, H)
    assert api.tobytes() == robust.tobytes()
    scalar = npz.ttc_scalar2 if D == 2 else npz.ttc_scalar
    for i in range(0, 1500, 13):
        row = [x[i] for x in args]
        flat = [*row[0], *row[1], *row[2], row[3], *row[4], *row[5], *row[6], row[7], H]
        assert scalar(*flat) == api[i] or (math.isnan(scalar(*flat)) and math.isnan(api[i]))


@pytest.mark.parametrize("D", [2, 3])
@pytest.mark.parametrize("H", [10.0, math.inf])
def test_decides_the_bulk(D, H):
    args = mixed_pairs(20000, D, seed=3, straight_fraction=1.0)
    assert count_straight(args[2], args[6], 0, 20000, (0.0,) * D) == 20000
    got = _straight_loop(args, H)
    assert (got != UNDECIDED).mean() >= 0.99


@pytest.mark.parametrize("D", [2, 3])
def test_mixed_blocks(D):
    """Blocks of the batch kernels holding both kinds of rows, in runs and
    interleaved, finite and infinite horizons per row: each row as alone."""
    acc = mixed_pairs(3000, D, seed=11)
    st = stress_rows(3000, D, seed=12)
    rng = np.random.default_rng(13)
    pick = rng.random(3000) < 0.5
    pick[:700] = False  # a run of accelerating rows, then a run of straight ones
    pick[700:1400] = True
    rows = tuple(np.where(pick[:, None] if a.ndim == 2 else pick, b, a) for a, b in zip(acc, st))
    H = np.where(rng.random(3000) < 0.2, math.inf, rng.uniform(0.0, 12.0, 3000))
    batch = time_to_collision(*rows, H)
    one = np.array(
        [float(time_to_collision(*(x[i] for x in rows), float(H[i]))) for i in range(3000)]
    )
    assert batch.tobytes() == one.tobytes()
    # and the straight loop never overwrites an accelerating row's answer
    pre = np.arange(3000, dtype=float) + 0.25
    kept = _straight_loop(rows, H, keep_from=pre)
    assert np.array_equal(kept[~pick], pre[~pick])


@pytest.mark.parametrize("D", [2, 3])
def test_invalid_rows(D):
    args = [x.copy() for x in stress_rows(50, D, seed=5)]
    args[0][0, 0] = np.nan
    args[1][1, 0] = np.inf
    args[3][2] = -1.0
    args[6][3, 0] = args[2][3, 0] = np.inf  # a_a == a_b == inf: not finite
    H = np.full(50, 4.0)
    H[4] = -1.0
    H[5] = np.nan
    got = _straight_loop(tuple(args), H)
    assert np.all(got[:6] == UNDECIDED)
    assert np.isnan(time_to_collision(*args, H)[:6]).all()


def tiny_rows(n, D, seed):
    """da = 0 rows with tiny bodies far apart: body a at p_a (|p_a| ~ 0.1-8,
    short mantissas) moving at v_a = -k p_a (k with few bits: exact), body b
    at p_b, |p_b| ~ 2^-e |p_a| with e in [55, 140] (short mantissas too; so
    dp = p_a - p_b needs a double-double), either moving at v_b = -k p_b exactly (dv = -k dp: a
    head-on course, miss distance d = 0, R = 0 or 2^-j) or at a random tiny
    v_b (d ~ 2^-e |dp|; R the float just above or just below the exact d).
    The closest approach is at t = 1/k > 0, so the exact answer is a contact
    iff R >= d (a tangent graze if equal).  a_a == a_b, nonzero."""
    rng = np.random.default_rng(seed)
    rows = []
    for i in range(n):
        L = 2.0 ** int(rng.integers(-3, 4))
        pa = rng.integers(1, 2**40, D) * 2.0**-40 * L * rng.choice([-1, 1], D)
        k = float(rng.choice([3.0, 5.0, 0.75, 1.5, 7.0, 0.3125]))
        va = -k * pa
        pb = (
            rng.integers(1, 2**40, D)
            * 2.0 ** -(40 + int(rng.integers(55, 140)))
            * L
            * rng.choice([-1, 1], D)
        )
        head_on = i % 4 == 0
        vb = -k * pb if head_on else rng.normal(size=D) * np.linalg.norm(pb)
        dp = [Fraction(x) - Fraction(y) for x, y in zip(pa, pb)]
        dv = [Fraction(x) - Fraction(y) for x, y in zip(va, vb)]
        assert not head_on or all(v == -Fraction(k) * p for p, v in zip(dp, dv))
        cross = [dp[1] * dv[2] - dp[2] * dv[1], dp[2] * dv[0] - dp[0] * dv[2]] if D == 3 else []
        cross.append(dp[0] * dv[1] - dp[1] * dv[0])
        d2 = sum(c * c for c in cross) / sum(v * v for v in dv)  # exact miss distance^2
        if d2 == 0:
            R = float(rng.choice([0.0, 2.0 ** -int(rng.integers(60, 160))]))
        else:
            R = math.sqrt(float(d2))
            while Fraction(R) ** 2 < d2:  # the float just above d
                R = math.nextafter(R, math.inf)
            if i % 2:  # the float just below d: a miss by less than an ulp of R
                R = math.nextafter(R, 0.0)
        ab = rng.normal(size=D)
        rows.append((pa, va, ab.copy(), R, pb, vb, ab, 0.0))
    return tuple(np.array([r[j] for r in rows], dtype=float) for j in range(8))


@pytest.mark.parametrize("D", [2, 3])
@pytest.mark.parametrize("H", [10.0, math.inf])
def test_tiny_bodies_far_apart(D, H):
    # 80 rows under --stress, the first 24 of them by default (the exact reference's
    # rationals span ~2^-300: ~0.1 s a row)
    args = tuple(x[: examples(24, 80)] for x in tiny_rows(80, D, seed=[17, 3, D]))
    got = _straight_loop(args, H)
    api = time_to_collision(*args, H)
    bad = []
    for i in range(len(api)):
        row = tuple(x[i] for x in args)
        ref = exact_reference(*row, H)
        loop_ok = got[i] == UNDECIDED or _agrees_straight(float(got[i]), row, ref, H)
        if not (loop_ok and _agrees_straight(float(api[i]), row, ref, H)):
            bad.append((i, got[i], api[i], ref.t))
    assert not bad, f"{len(bad)} wrong, first {bad[:3]}"
