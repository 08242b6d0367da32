"""The cheap certified interval of rows the budget leaves unevaluated (core.uncertainty.interval).

Guarantees proved here (docs/uncertainty.md, "Screening and the per-prediction budget"):
* lo <= P(contact within [0, H]) <= hi: the seeded Monte Carlo estimate on the exact solver
  lies within [lo - 4 SE, hi + 4 SE] on every benchmark family (near miss, large sigma,
  accelerating, overlap at start, 3-D) and every covariance class of the horizon tests (2-D
  and 3-D, correlated, accelerating, position-only, velocity-only, rank-deficient);
* the interval meets the full evaluation's (P +- bound) on every row of those families;
* it is informative where the answer is clear: probable head-on pairs get lo > 0.5, far
  pairs hi at the ladder's smallest tail;
* each row is decided from its own inputs: the same bits whatever the other rows or their
  order; through uncertain_pairs, swapping a and b of deferred rows changes no bit.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from circle_collision_ros.core.uncertainty import uncertain_pairs
from circle_collision_ros.core.uncertainty.interval import INTERVAL_TAILS, cheap_intervals
from tests.core.uncertainty.test_uncertainty_horizon import KINDS, mc_probability, random_pair

sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "bench"))
import bench_uncertainty as bench  # noqa: E402


def _rows(pairs):
    return [np.array([p[i] for p in pairs], dtype=float) for i in range(10)]


def _intervals(pairs, H):
    pa, va, aa, ra, ca, pb, vb, ab, rb, cb = _rows(pairs)
    return cheap_intervals(pa - pb, va - vb, aa - ab, ra + rb, np.ascontiguousarray(ca + cb), H)


def _groups():
    for name, D in bench.FAMILIES:
        yield name, lambda rng, name=name, D=D: bench._family(name, rng, D), bench.H
    for D in (2, 3):
        for kind in KINDS:
            yield f"{kind} {D}-D", lambda rng, D=D, kind=kind: random_pair(rng, D, kind), 3.0


GROUPS = list(_groups())


def _check_against_mc(per_group: int, n_mc: int, seed: int) -> None:
    for g, (name, make, H) in enumerate(GROUPS):
        rng = np.random.default_rng(seed + 100 * g)
        pairs = [make(rng) for _ in range(per_group)]
        lo, hi = _intervals(pairs, H)
        for k, pair in enumerate(pairs):
            q, se = mc_probability(*pair, H, n_mc, seed=seed * 1000 + 10 * g + k)
            assert lo[k] - 4 * se <= q <= hi[k] + 4 * se, (name, k, lo[k], hi[k], q, se)


def test_interval_contains_monte_carlo() -> None:
    _check_against_mc(per_group=2, n_mc=100_000, seed=31)


@pytest.mark.stress
def test_interval_contains_large_monte_carlo() -> None:
    _check_against_mc(per_group=5, n_mc=1_000_000, seed=32)


@pytest.mark.parametrize("name,make,H", GROUPS, ids=[g[0] for g in GROUPS])
def test_interval_meets_the_full_evaluation(name, make, H) -> None:
    rng = np.random.default_rng(7)
    pairs = [make(rng) for _ in range(30)]
    lo, hi = _intervals(pairs, H)
    full = uncertain_pairs(*_rows(pairs), H, 0.01)
    p, b = full.collision_probability, full.collision_probability_bound
    assert np.all((0.0 <= lo) & (lo <= hi) & (hi <= 1.0))
    assert np.all((lo <= p + b) & (p - b <= hi)), name


def test_interval_is_informative_where_the_answer_is_clear() -> None:
    rng = np.random.default_rng(3)
    head_on = [bench._family("head-on", rng, 2) for _ in range(10)]
    lo, _ = _intervals(head_on, bench.H)
    assert np.all(lo > 0.5)
    far = []
    for pair in head_on:
        pa, va, aa, ra, ca, pb, vb, ab, rb, cb = pair
        far.append((pa, 0 * va, aa, ra, ca, pb + 50.0, 0 * vb, ab, rb, cb))
    lo, hi = _intervals(far, bench.H)
    assert np.all(lo == 0.0) and np.all(hi <= INTERVAL_TAILS[0])


def test_rows_are_decided_from_themselves() -> None:
    rng = np.random.default_rng(11)
    pairs = [GROUPS[g][1](rng) for g in (0, 2, 4, 6) for _ in range(5)]  # 2-D families
    lo, hi = _intervals(pairs, bench.H)
    order = rng.permutation(len(pairs))
    lo2, hi2 = _intervals([pairs[k] for k in order], bench.H)
    assert lo2.tobytes() == lo[order].tobytes() and hi2.tobytes() == hi[order].tobytes()
    one_lo, one_hi = _intervals(pairs[3:4], bench.H)
    assert one_lo[0] == lo[3] and one_hi[0] == hi[3]


def test_deferred_rows_do_not_depend_on_which_body_is_a() -> None:
    rng = np.random.default_rng(12)
    pairs = [GROUPS[g][1](rng) for g in (0, 2, 4, 6, 7, 8) for _ in range(4)]
    for D in (2, 3):
        chosen = [p for p in pairs if len(p[0]) == D]
        rows = _rows(chosen)
        swapped = rows[5:] + rows[:5]
        a = uncertain_pairs(*rows, bench.H, 0.01, screen=True, max_evaluated=0)
        b = uncertain_pairs(*swapped, bench.H, 0.01, screen=True, max_evaluated=0)
        assert a.deferred.any() and np.array_equal(a.deferred, b.deferred)
        for x, y in zip(a[:3], b[:3]):
            assert x.tobytes() == y.tobytes()
