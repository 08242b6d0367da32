"""The certified fast path (``narrow_fast.fast_rows``) against the robust solver.

Guarantees proved here:

* Every row the fast path decides gets the robust solver's answer: the same
  contact / no-contact decision and the same time to within 1 ulp (on these
  mixes it is bit for bit the same; the accuracy families in
  test_narrow_phase_accuracy.py check both against mpmath with a finite
  horizon, where the fast path runs).
* It decides the bulk of a typical batch (else the speed would come from
  nowhere): >= 97 % of the benchmark mix at H = 10 s and at H = 1000 s.
* Invalid input (non-finite value, negative radius, negative or NaN
  horizon) is never decided by it, so the robust path returns NaN; an
  infinite horizon is left to the robust solver except for overlaps.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from circle_collision_ros.core import narrow_phase as npz
from circle_collision_ros.core.narrow_fast import UNDECIDED, fast_rows
from tests.core.test_narrow_phase_accuracy import mixed_pairs


def _fast(args, H):
    n = args[3].shape[0]
    out = np.full(n, np.nan)
    Hs = np.broadcast_to(np.asarray(H, float), (n,)).copy()
    fast_rows(*args, Hs, 0, out, 0, n, (0.0,) * args[0].shape[1])
    return out


def _robust(args, H):
    robust = npz._robust2 if args[0].shape[1] == 2 else npz._robust3
    Hs = np.broadcast_to(np.asarray(H, float), (args[3].shape[0],))
    return np.array([robust(*args, float(Hs[i]), i) for i in range(args[3].shape[0])])


@pytest.mark.parametrize("D", [2, 3])
@pytest.mark.parametrize("H", [0.5, 3.0, 10.0, 1e3])
def test_decided_rows_match_the_robust_solver(D, H):
    args = mixed_pairs(6000, D, seed=21 + D, straight_fraction=1 / 8)
    fast = _fast(args, H)
    assert not np.isnan(fast).any()  # every row written
    dec = fast != UNDECIDED
    assert dec.mean() > 0.8, dec.mean()  # (1/8 of the rows have da = 0: robust solver)
    ref = _robust(args, H)
    f, r = fast[dec], ref[dec]
    assert np.array_equal(np.isinf(f), np.isinf(r))
    fin = np.isfinite(r)
    assert (np.abs(f[fin] - r[fin]) <= np.spacing(r[fin])).all()
    assert fin.sum() > 50 and (f[fin] > 0).any() and (f == 0.0).any() and np.isinf(f).any()


@pytest.mark.parametrize("D", [2, 3])
@pytest.mark.parametrize("H", [10.0, 1e3])
def test_decides_the_bulk_of_the_benchmark_mix(D, H):
    """>= 97 % of bench_core's mix (H = 10 s) never reaches the robust solver,
    and long horizons are no exception (Newton on c starts from a closed-form
    bound, not from H: ~99 % at H = 1e3 s)."""
    args = mixed_pairs(20000, D, seed=1)
    assert (_fast(args, H) != UNDECIDED).mean() >= 0.97


def test_horizon_per_row_and_offset():
    """Row i reads its horizon from Hs[hofs + i - i0]: a shifted window of
    rows gives the same answers as the whole batch."""
    args = mixed_pairs(1000, 2, seed=4)
    H = np.random.default_rng(0).uniform(0.5, 12.0, 1000)
    whole = _fast(args, H)
    part = np.full(1000, np.nan)
    fast_rows(*args, H, 300, part, 300, 400, (0.0, 0.0))
    assert np.array_equal(part[300:700], whole[300:700])
    assert np.isnan(part[:300]).all() and np.isnan(part[700:]).all()  # nothing else written


def test_invalid_rows_are_left_to_the_robust_solver():
    args = [x.copy() for x in mixed_pairs(64, 2, seed=9)]
    H = np.full(64, 10.0)
    bad = {1: ("pa", np.nan), 2: ("va", np.inf), 3: ("aa", -np.inf), 4: ("ra", -1.0),
           5: ("rb", np.nan), 6: ("pb", np.nan), 7: ("H", -1.0), 8: ("H", np.nan)}
    names = ["pa", "va", "aa", "ra", "pb", "vb", "ab", "rb"]
    for i, (what, v) in bad.items():
        if what == "H":
            H[i] = v
        else:
            x = args[names.index(what)]
            x[i] = v
    out = np.empty(64)
    fast_rows(*args, H, 0, out, 0, 64, (0.0, 0.0))
    assert (out[list(bad)] == UNDECIDED).all()
    good = np.setdiff1d(np.arange(64), list(bad))
    full = npz.time_to_collision(*args, horizon=H)
    assert np.isnan(full[list(bad)]).all() and not np.isnan(full[good]).any()


def test_infinite_horizon_and_overlap():
    """H = inf: only overlaps (0.0) are decided; an overlap is 0.0 at any horizon."""
    args = mixed_pairs(2000, 2, seed=12)
    fast = _fast(args, math.inf)
    assert set(np.unique(fast)) <= {UNDECIDED, 0.0}
    dp = args[0] - args[4]
    R = args[3] + args[7]
    deep = np.einsum("ij,ij->i", dp, dp) < 0.9 * R * R
    assert deep.any()
    assert (fast[deep] == 0.0).all() and (_fast(args, 0.0)[deep] == 0.0).all()


def test_scalar_entries_run_the_batch_code():
    """_ttc_scalar / _ttc_scalar2 (one-row batches) give the batch answer bit for bit."""
    args = mixed_pairs(400, 2, seed=5)
    for H in (10.0, math.inf):
        t = npz.time_to_collision(*args, horizon=H)
        for i in range(0, 400, 7):
            pa, va, aa, ra, pb, vb, ab, rb = (x[i] for x in args)
            s2 = npz._ttc_scalar2(pa[0], pa[1], va[0], va[1], aa[0], aa[1], ra,
                                  pb[0], pb[1], vb[0], vb[1], ab[0], ab[1], rb, H)
            s3 = npz._ttc_scalar(pa[0], pa[1], 0.0, va[0], va[1], 0.0, aa[0], aa[1], 0.0, ra,
                                 pb[0], pb[1], 0.0, vb[0], vb[1], 0.0, ab[0], ab[1], 0.0, rb, H)
            assert s2 == t[i] and s3 == t[i]
    assert math.isnan(npz._ttc_scalar2(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, -1.0,
                                       1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 1.0))
