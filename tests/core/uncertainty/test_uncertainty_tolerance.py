"""A scene's probability tolerance (core.uncertainty.uncertain_pairs(tolerance=...)).

Guarantees proved here (docs/uncertainty.md, "Tolerance"):
* tolerance 0 is the per-pair accuracy (pair.finish_row takes the same steps as without the
  option: the other uncertainty tests, unchanged, prove its answers);
* with a tolerance, every row still states a bound that holds: a seeded Monte Carlo estimate
  on the exact solver lies within P +- (bound + 4 SE) on every benchmark family and every
  covariance class of the horizon tests (2-D and 3-D; accelerating pairs are the ones it
  changes);
* the work it saves is on accelerating pairs' sampling: where it changes an answer, the
  stated bound is within the tolerance, and rows it does not concern keep their bits;
* the tolerance is part of a reused row's inputs (memo) and is validated.
"""
from __future__ import annotations

import numpy as np
import pytest

from circle_collision_ros.core.uncertainty import uncertain_pairs
from tests.core.uncertainty.test_uncertainty_horizon import mc_probability
from tests.core.uncertainty.test_uncertainty_interval import GROUPS, _rows

TOLERANCE = 0.01


def _evaluate(pairs, H, tolerance):
    res = uncertain_pairs(*_rows(pairs), H, 0.01, tolerance=tolerance)
    return res.collision_probability, res.collision_probability_bound, res.plausible_time


@pytest.mark.parametrize("name,make,H", GROUPS, ids=[g[0] for g in GROUPS])
def test_tolerance_changes_only_what_it_may(name, make, H) -> None:
    rng = np.random.default_rng(11)
    pairs = [make(rng) for _ in range(6)]
    strict = _evaluate(pairs, H, 0.0)
    loose = _evaluate(pairs, H, TOLERANCE)
    changed = strict[0] != loose[0]
    assert np.all(loose[1][changed] <= TOLERANCE + 1e-15), name
    assert np.array_equal(strict[2], loose[2], equal_nan=True)  # times are not at stake
    assert np.all(np.abs(strict[0] - loose[0]) <= strict[1] + loose[1]), name


def _check_against_mc(per_group: int, n_mc: int, seed: int) -> int:
    changed = 0
    for g, (name, make, H) in enumerate(GROUPS):
        rng = np.random.default_rng(seed + 100 * g)
        pairs = [make(rng) for _ in range(per_group)]
        p, b, _ = _evaluate(pairs, H, TOLERANCE)
        changed += int(np.count_nonzero(p != _evaluate(pairs, H, 0.0)[0]))
        for k, pair in enumerate(pairs):
            q, se = mc_probability(*pair, H, n_mc, seed=seed * 1000 + 10 * g + k)
            assert abs(p[k] - q) <= b[k] + 4 * se, (name, k, p[k], b[k], q, se)
    return changed


def test_loose_rows_contain_monte_carlo() -> None:
    assert _check_against_mc(per_group=3, n_mc=100_000, seed=41) > 0


@pytest.mark.stress
def test_loose_rows_contain_large_monte_carlo() -> None:
    assert _check_against_mc(per_group=6, n_mc=1_000_000, seed=42) > 0


def _changed_pairs():
    """Pairs of a group where the tolerance changes an answer (accelerating pairs sampled)."""
    for name, make, H in GROUPS:
        rng = np.random.default_rng(3)
        pairs = [make(rng) for _ in range(12)]
        if not np.array_equal(_evaluate(pairs, H, 0.0)[0], _evaluate(pairs, H, TOLERANCE)[0]):
            return name, pairs, H
    raise AssertionError("the tolerance changed no answer")


def test_tolerance_is_an_input_of_reuse_and_is_validated() -> None:
    name, pairs, H = _changed_pairs()
    memo: dict = {}
    first = uncertain_pairs(*_rows(pairs), H, 0.01, memo=memo, tolerance=TOLERANCE)
    again = uncertain_pairs(*_rows(pairs), H, 0.01, memo=memo)
    strict = uncertain_pairs(*_rows(pairs), H, 0.01)
    assert np.array_equal(again.collision_probability, strict.collision_probability)
    assert not np.array_equal(first.collision_probability, strict.collision_probability), name
    for bad in (-0.1, 1.0, float("nan")):
        with pytest.raises(ValueError, match="tolerance"):
            uncertain_pairs(*_rows(pairs), H, 0.01, tolerance=bad)
