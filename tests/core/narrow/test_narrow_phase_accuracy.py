"""Accuracy of ``time_to_collision`` against the mpmath reference, per family.

Guarantees proved here (each family, fixed seeds, a few hundred cases; the default
run scores every third of them, ``--stress`` all):

* Well-conditioned contacts: ``|t - t_ref| / ulp(t_ref) * |cos| <= 4`` where
  ``cos`` is the angle between the centre line and the relative velocity at
  contact (grazes are inherently sensitive; this normalisation is the one
  stated for the narrow phase).  ``t_ref`` is computed from the binary64 inputs *as
  given*: the implementation forms ``p_a - p_b`` etc. exactly (TwoSum), so no
  extra allowance is made for the rounding of the relative state.
* ``t_ref == 0`` (overlap / approaching touch) must give exactly 0.
* No missed and no spurious contact, except cases flagged ambiguous by the
  reference (a local minimum of ``f = |g|^2 - R^2`` on [0, H], or ``f(H)``,
  within ``1e-9 R^2`` of zero).

Run ``python -m tests.core.narrow.test_narrow_phase_accuracy`` for the table.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from circle_collision_ros.core import time_to_collision
from tests.core.reference import Ref, reference
from tests.stress import examples

N = 300  # cases per family: mpmath polyroots costs ~3-5 ms per case
# families whose reference is a quadratic (closed form) are cheap: more cases
N_CHEAP = {"zero_acc": 600, "straight_graze": 1000, "static": 600, "overlap_t0": 400, "points": 400}
ULP_TOL = 4.0


def _unit(rng, n, D):
    u = rng.normal(size=(n, D))
    return u / np.linalg.norm(u, axis=1, keepdims=True)


def _aimed(rng, n, D=2, acc=1.0, T=(0.1, 10.0), r=(0.1, 2.0), speed=2.0, zero_acc=False):
    """Pairs constructed to touch at time ~T (before rounding of p_a)."""
    pb = rng.uniform(-20, 20, size=(n, D))
    vb = rng.normal(0, speed, size=(n, D))
    ab = rng.normal(0, acc, size=(n, D))
    ra = rng.uniform(*r, size=n)
    rb = rng.uniform(*r, size=n)
    Tc = rng.uniform(*T, size=n)
    dv = rng.normal(0, speed, size=(n, D))
    da = np.zeros((n, D)) if zero_acc else acc * _unit(rng, n, D) * rng.uniform(0.2, 1, size=(n, 1))
    gd = dv + Tc[:, None] * da
    nrm = _unit(rng, n, D)
    # make the contact normal face the relative velocity (entering contact)
    flip = np.sum(nrm * gd, axis=1) > 0
    nrm[flip] *= -1
    gT = (ra + rb)[:, None] * nrm
    dp = gT - Tc[:, None] * dv - 0.5 * Tc[:, None] ** 2 * da
    pa = pb + dp
    va = vb + dv
    aa = ab + da
    return pa, va, aa, ra, pb, vb, ab, rb


def mixed_pairs(n: int, D: int = 2, seed: int = 1, straight_fraction: float = 0.0):
    """Half aimed (contact at a random T in [0.1, 10] s), half random: the speed benchmark's mix.

    The first `straight_fraction` of rows get zero relative acceleration (the closed-form path).
    Shared by bench/bench_core.py and the solver-path tests.
    """
    rng = np.random.default_rng(seed)
    h = n // 2
    pb = rng.uniform(-20, 20, (n, D))
    vb = rng.normal(0, 2, (n, D))
    ab = rng.normal(0, 1, (n, D))
    ra = rng.uniform(0.1, 2, n)
    rb = rng.uniform(0.1, 2, n)
    dv = rng.normal(0, 2, (n, D))
    da = rng.normal(0, 1, (n, D))
    pa = rng.uniform(-20, 20, (n, D))
    T = rng.uniform(0.1, 10, h)
    u = rng.normal(size=(h, D))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    gd = dv[:h] + T[:, None] * da[:h]
    u[np.sum(u * gd, axis=1) > 0] *= -1  # on the approach side at T
    pa[:h] = (
        pb[:h]
        + (ra[:h] + rb[:h])[:, None] * u
        - T[:, None] * dv[:h]
        - 0.5 * T[:, None] ** 2 * da[:h]
    )
    da[: int(n * straight_fraction)] = 0.0
    return pa, vb + dv, ab + da, ra, pb, vb, ab, rb


def fam_random(rng, n):
    D = 2
    return (rng.uniform(-20, 20, (n, D)), rng.normal(0, 2, (n, D)), rng.normal(0, 1, (n, D)),
            rng.uniform(0.1, 2, n), rng.uniform(-20, 20, (n, D)), rng.normal(0, 2, (n, D)),
            rng.normal(0, 1, (n, D)), rng.uniform(0.1, 2, n)), 20.0


def fam_aimed(rng, n):
    return _aimed(rng, n), math.inf


def fam_zero_acc(rng, n):
    pa, va, aa, ra, pb, vb, ab, rb = _aimed(rng, n, zero_acc=True)
    aa = ab.copy()  # both accelerate identically: da == 0 exactly
    return (pa, va, aa, ra, pb, vb, ab, rb), math.inf


def fam_tiny_acc_1e4(rng, n):
    pa, va, aa, ra, pb, vb, ab, rb = _aimed(rng, n, acc=1e-4)
    return (pa, va, aa, ra, pb, vb, ab, rb), math.inf


def fam_tiny_acc_1e12(rng, n):
    z = np.zeros((n, 2))
    pa, va, _, ra, pb, vb, _, rb = _aimed(rng, n, acc=1e-12)
    aa = 1e-12 * _unit(rng, n, 2)
    return (pa, va, aa, ra, pb, vb, z, rb), math.inf


def fam_map_offset(rng, n):
    pa, va, aa, ra, pb, vb, ab, rb = _aimed(rng, n)
    off = np.where(rng.random((n, 1)) < 0.5, 5e5, 5e6) * _unit(rng, n, 2)
    return (pa + off, va, aa, ra, pb + off, vb, ab, rb), math.inf


def fam_tiny_radii(rng, n):
    pa, va, aa, ra, pb, vb, ab, rb = _aimed(rng, n, r=(5e-7, 5e-7), T=(1.0, 500.0))
    return (pa, va, aa, ra, pb, vb, ab, rb), math.inf


def fam_slow_long(rng, n):
    pa, va, aa, ra, pb, vb, ab, rb = _aimed(rng, n, acc=1e-8, speed=1e-3, T=(1e3, 1e5))
    return (pa, va, aa, ra, pb, vb, ab, rb), 1e5


def fam_overlap(rng, n):
    D = 2
    pb = rng.uniform(-20, 20, (n, D))
    ra = rng.uniform(0.1, 2, n)
    rb = rng.uniform(0.1, 2, n)
    pa = pb + _unit(rng, n, D) * ((ra + rb) * rng.uniform(0, 0.999, n))[:, None]
    return (pa, rng.normal(0, 2, (n, D)), rng.normal(0, 1, (n, D)), ra, pb,
            rng.normal(0, 2, (n, D)), rng.normal(0, 1, (n, D)), rb), math.inf


def _graze(rng, n, curved):
    """Closest approach at T with distance R(1 +- k), k in 1e-12..1e-3."""
    D = 2
    pb = rng.uniform(-20, 20, (n, D))
    vb = rng.normal(0, 2, (n, D))
    ab = rng.normal(0, 1, (n, D))
    ra = rng.uniform(0.1, 2, n)
    rb = rng.uniform(0.1, 2, n)
    R = ra + rb
    T = rng.uniform(0.5, 10, n)
    dv = rng.normal(0, 2, (n, D))
    da = rng.normal(0, 1, (n, D)) if curved else np.zeros((n, D))
    gd = dv + T[:, None] * da
    perp = np.stack([-gd[:, 1], gd[:, 0]], axis=1)
    perp /= np.linalg.norm(perp, axis=1, keepdims=True)
    k = 10.0 ** rng.uniform(-12, -3, n) * np.where(rng.random(n) < 0.5, -1, 1)
    gT = perp * (R * (1 + k))[:, None]
    dp = gT - T[:, None] * dv - 0.5 * T[:, None] ** 2 * da
    ab2 = ab if curved else ab.copy()
    return (pb + dp, vb + dv, ab2 + da, ra, pb, vb, ab2, rb), math.inf


def fam_straight_graze(rng, n):
    (pa, va, aa, ra, pb, vb, ab, rb), H = _graze(rng, n, False)
    aa = ab  # da == 0 exactly
    return (pa, va, aa, ra, pb, vb, ab, rb), H


def fam_curved_graze(rng, n):
    return _graze(rng, n, True)


def fam_static(rng, n):
    D = 2
    pa = rng.uniform(-3, 3, (n, D))
    pb = rng.uniform(-3, 3, (n, D))
    v = rng.normal(0, 1, (n, D))
    a = rng.normal(0, 1, (n, D))
    return (pa, v, a, rng.uniform(0.1, 2, n), pb, v, a, rng.uniform(0.1, 2, n)), math.inf


def fam_points(rng, n):
    """R = 0: half exact crossings built from dyadic values, half random.

    The crossings are exact in binary64 (a few significant bits each), so the
    exact contact time is known in closed form: g(t) = (t - T)(dv + (t + T) da/2)
    vanishes at T, and earlier only if dv + (t + T) da/2 = 0 for some t in
    (0, T).  Their exact minimum gap is 0, i.e. they sit *on* the slack
    boundary; they are checked against the known time instead of the
    (slow for exact double roots) polynomial reference.
    """
    D = 2
    h = n // 2
    T = rng.integers(1, 64, h) / 8.0
    dv = rng.integers(-16, 17, (h, D)) / 4.0
    da = rng.integers(-16, 17, (h, D)) / 4.0
    dv[np.all(dv == 0, axis=1)] = (1.0, 0.0)
    pb = rng.integers(-64, 64, (h, D)) / 2.0
    dp = -(T[:, None] * dv) - 0.5 * T[:, None] ** 2 * da  # exact: few bits each
    known = T.copy()
    for i in range(h):
        if np.all(dp[i] == 0):
            known[i] = 0.0
            continue
        cr = dv[i, 0] * da[i, 1] - dv[i, 1] * da[i, 0]
        if cr == 0 and np.any(da[i] != 0):
            lam = dv[i] @ da[i] / (da[i] @ da[i])
            alt = -2 * lam - T[i]
            if 0 < alt < T[i]:
                known[i] = alt
    z = np.zeros(h)
    hit = (pb + dp, dv, da, z, pb, np.zeros((h, D)), np.zeros((h, D)), z)
    rnd, _ = fam_random(rng, n - h)
    rnd = rnd[:3] + (np.zeros(n - h),) + rnd[4:7] + (np.zeros(n - h),)
    args = tuple(np.concatenate([x, y]) for x, y in zip(hit, rnd))
    return args, 50.0, np.concatenate([known, np.full(n - h, np.nan)])


def fam_3d(rng, n):
    h = n // 2
    a = _aimed(rng, h, D=3)
    b = (rng.uniform(-20, 20, (n - h, 3)), rng.normal(0, 2, (n - h, 3)),
         rng.normal(0, 1, (n - h, 3)), rng.uniform(0.1, 2, n - h), rng.uniform(-20, 20, (n - h, 3)),
         rng.normal(0, 2, (n - h, 3)), rng.normal(0, 1, (n - h, 3)), rng.uniform(0.1, 2, n - h))
    return tuple(np.concatenate([x, y]) for x, y in zip(a, b)), 20.0


FAMILIES = {"random": fam_random, "aimed": fam_aimed, "zero_acc": fam_zero_acc,
            "tiny_acc_1e-4": fam_tiny_acc_1e4, "tiny_acc_1e-12": fam_tiny_acc_1e12,
            "map_offset": fam_map_offset, "tiny_radii": fam_tiny_radii,
            "slow_long_horizon": fam_slow_long, "overlap_t0": fam_overlap,
            "straight_graze": fam_straight_graze, "curved_graze": fam_curved_graze,
            "static": fam_static, "points": fam_points, "3d": fam_3d}


def family_cases(name: str, n: int, seed: int = 0):
    """(args, horizon, known) of a family: the rows every accuracy figure is computed on.

    Deterministic per (family, seed); `known` holds exact times where a family
    builds them in closed form (NaN elsewhere: use the mpmath reference).
    Shared with bench/accuracy_vs_time.py, so tests and benchmarks score the same rows.
    """
    rng = np.random.default_rng([seed, *name.encode()])
    fam = FAMILIES[name](rng, n)
    args, H = fam[:2]
    known = fam[2] if len(fam) > 2 else np.full(n, np.nan)
    return tuple(np.asarray(x, dtype=np.float64) for x in args), float(H), np.asarray(known, float)


def case_error(got: float, t_ref: float, cos: float) -> float:
    """Condition-normalised error in ulps of the exact time, for a contact both agree on.

    A graze's time is inherently sensitive, so the error is scaled by |cos| of the
    angle between the centre line and the relative velocity at contact.
    """
    if t_ref == 0.0:
        return 0.0 if got == 0.0 else math.inf
    return abs(got - t_ref) / float(np.spacing(t_ref)) * cos


def evaluate(
    name: str, n: int = N, seed: int = 0, horizon: float | None = None, every: int = 1
) -> dict:
    """Score a family against the reference; ``horizon`` replaces the family's own.

    ``every``: score rows 0, every, 2 every, ... of the n-row family only (the same
    rows as the full score, fewer mpmath references; the whole batch is still solved)."""
    args, H, known = family_cases(name, n, seed)
    if horizon is not None:
        H = horizon
        known = np.where(known > H, math.inf, known)  # a known contact beyond H is none
    t = time_to_collision(*args, horizon=H)
    worst = 0.0
    missed = spurious = ambiguous = contacts = agree = 0
    bad = []
    for i in range(0, n, every):
        row = [x[i] for x in args]
        got = float(t[i])
        if not np.isnan(known[i]):
            ref = Ref(float(known[i]), None, 1.0, False, None)
        else:
            ref = reference(*row, horizon=H)
        if ref.ambiguous:
            ambiguous += 1
            agree += math.isinf(ref.t) == math.isinf(got)
            continue
        if math.isinf(ref.t) != math.isinf(got):
            if math.isinf(got):
                missed += 1
            else:
                spurious += 1
            bad.append((i, got, ref.t))
            continue
        if math.isinf(got):
            continue
        contacts += 1
        err = case_error(got, ref.t, ref.cos)
        if err > worst:
            worst = err
        if err > ULP_TOL:
            bad.append((i, got, ref.t, err))
    return dict(family=name, n=n, contacts=contacts, worst_ulp=worst, missed=missed,
                spurious=spurious, ambiguous=ambiguous, ambiguous_agree=agree, bad=bad[:5])


#: The default run scores every EVERY-th row of each family (the stress run all of them):
#: the mpmath polynomial reference is what costs.
EVERY = examples(3, 1)


@pytest.mark.parametrize("name", list(FAMILIES))
def test_family(name):
    """Per family: worst conditioned error <= 4 ulp; no missed/spurious contact."""
    r = evaluate(name, N_CHEAP.get(name, N), every=EVERY)
    assert r["missed"] == 0 and r["spurious"] == 0, r
    assert r["worst_ulp"] <= ULP_TOL, r
    if name not in ("random", "static", "straight_graze", "curved_graze"):
        assert r["contacts"] > 0, r


# The families built for an infinite horizon again with a finite one: only
# then does the batch kernels' certified fast path (narrow_fast) run, so this
# proves the same guarantees for the answers it gives (contacts beyond the
# horizon turn into inf, and its culls and early misses are checked too).
FINITE_H = {name: 7.0 for name, fam in FAMILIES.items() if math.isinf(family_cases(name, 1)[1])}
FINITE_H["tiny_radii"] = 300.0  # its contacts come at up to ~500 s


@pytest.mark.parametrize("name", list(FINITE_H))
def test_family_finite_horizon(name):
    """As test_family, with a finite horizon (the fast path decides most rows)."""
    r = evaluate(name, 200, seed=1, horizon=FINITE_H[name], every=EVERY)
    assert r["missed"] == 0 and r["spurious"] == 0, r
    assert r["worst_ulp"] <= ULP_TOL, r
    if name not in ("static", "straight_graze", "curved_graze"):
        assert r["contacts"] > 0, r


if __name__ == "__main__":  # pragma: no cover - reporting helper
    import sys
    import time

    n = int(sys.argv[1]) if len(sys.argv) > 1 else N
    print(
        f"{'family':20s} {'n':>5s} {'contacts':>8s} {'worst ulp*cos':>14s} {'missed':>6s} "
        f"{'spurious':>8s} {'ambig':>5s} {'(agree)':>7s}"
    )
    for name in FAMILIES:
        t0 = time.perf_counter()
        r = evaluate(name, N_CHEAP.get(name, n) if n == N else n)
        print(
            f"{name:20s} {r['n']:5d} {r['contacts']:8d} {r['worst_ulp']:14.3f} {r['missed']:6d} "
            f"{r['spurious']:8d} {r['ambiguous']:5d} {r['ambiguous_agree']:7d}  "
            f"({time.perf_counter() - t0:.1f} s) {r['bad'][:2]}"
        )
