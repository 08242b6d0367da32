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

import inspect
import math

import numpy as np
import pytest
from numba import njit

from circle_collision_ros.core.narrow import fast as nf
from circle_collision_ros.core.narrow import batch as npz
from circle_collision_ros.core.narrow.dd import pow2_scales
from circle_collision_ros.core.narrow.exact import exact_first_contact
from circle_collision_ros.core.narrow.fast import UNDECIDED, fast_rows
from tests.core.narrow.test_narrow_phase_accuracy import mixed_pairs


def _fast(args, H):
    n = args[3].shape[0]
    out = np.full(n, np.nan)
    Hs = np.broadcast_to(np.asarray(H, float), (n,)).copy()
    fast_rows(*args, Hs, 0, out, 0, n, (0.0,) * args[0].shape[1])
    return out


def _robust(args, H):
    robust = npz.robust_pair2 if args[0].shape[1] == 2 else npz.robust_pair3
    Hs = np.broadcast_to(np.asarray(H, float), (args[3].shape[0],))
    pa, va, aa, ra, pb, vb, ab, rb = args
    out = np.array(
        [
            robust(*pa[i], *va[i], *aa[i], ra[i], *pb[i], *vb[i], *ab[i], rb[i], float(Hs[i]))
            for i in range(ra.shape[0])
        ]
    )
    # rows the robust solver cannot certify are decided exactly (as in the kernels)
    for i in np.flatnonzero(out == UNDECIDED):
        out[i] = exact_first_contact(
            pa[i], va[i], aa[i], ra[i], pb[i], vb[i], ab[i], rb[i], float(Hs[i])
        )
    return out


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
    # a horizon window that starts elsewhere than the rows (hofs != i0)
    part[:] = np.nan
    fast_rows(*args, H[300:700].copy(), 0, part, 300, 400, (0.0, 0.0))
    assert np.array_equal(part[300:700], whole[300:700])


@pytest.mark.parametrize("D", [2, 3])
def test_invalid_rows_are_left_to_the_robust_solver(D):
    """Every input of a row (and its horizon) made non-finite, or a radius or
    the horizon negative: the fast path leaves the row undecided, the batch
    answer is NaN there and untouched elsewhere."""
    names = ["pa", "va", "aa", "ra", "pb", "vb", "ab", "rb"]
    bad = [(w, v) for w in names for v in (np.nan, np.inf, -np.inf)]
    bad += [("ra", -1.0), ("rb", -0.5), ("H", -1.0), ("H", np.nan)]
    n = len(bad) + 40
    args = [x.copy() for x in mixed_pairs(n, D, seed=9)]
    H = np.full(n, 10.0)
    for i, (what, v) in enumerate(bad):
        if what == "H":
            H[i] = v
        else:
            x = args[names.index(what)]
            x[i] = v  # a whole vector or a radius
    out = np.empty(n)
    fast_rows(*args, H, 0, out, 0, n, (0.0,) * D)
    k = len(bad)
    assert (out[:k] == UNDECIDED).all()
    full = npz.time_to_collision(*args, horizon=H)
    assert np.isnan(full[:k]).all() and not np.isnan(full[k:]).any()


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
    """ttc_scalar / ttc_scalar2 (one-row batches) give the batch answer bit for bit."""
    args = mixed_pairs(400, 2, seed=5)
    for H in (10.0, math.inf):
        t = npz.time_to_collision(*args, horizon=H)
        for i in range(0, 400, 7):
            pa, va, aa, ra, pb, vb, ab, rb = (x[i] for x in args)
            s2 = npz.ttc_scalar2(pa[0], pa[1], va[0], va[1], aa[0], aa[1], ra, pb[0], pb[1], vb[0],
                                 vb[1], ab[0], ab[1], rb, H)
            s3 = npz.ttc_scalar(pa[0], pa[1], 0.0, va[0], va[1], 0.0, aa[0], aa[1], 0.0, ra, pb[0],
                                pb[1], 0.0, vb[0], vb[1], 0.0, ab[0], ab[1], 0.0, rb, H)
            assert s2 == t[i] and s3 == t[i]
    assert math.isnan(
        npz.ttc_scalar2(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, -1.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 1.0)
    )


def test_step_counts_match_the_constants():
    """K_C / K_F document the written-out Newton and model steps of fast_rel."""
    src = inspect.getsource(nf.fast_rel.py_func)
    assert src.count("_newton_c(") == nf.K_C
    assert src.count("_model_step(") == nf.K_F


@pytest.mark.parametrize(
    "m",
    [0.0, 5e-324, 1e-310, 2.0**-300, np.nextafter(2.0**-300, 0.0), 0.1, 1.0, 3.999, 4.0, 1e150,
     1.7976931348623157e308],
)
def test_pow2_scales(m):
    """m * s1 * s2 lands in [2, 4) exactly (powers of two), 0 stays 0."""
    s1, s2 = pow2_scales(m)
    for s in (s1, s2):
        assert s > 0 and math.frexp(s)[0] == 0.5  # a power of two
    if m == 0.0:
        assert s2 == 1.0
    else:
        y = (m * s1) * s2
        assert 2.0 <= y < 4.0 and y / s2 / s1 == m


def test_pow2_scales_overflowed_state_is_nan():
    assert math.isnan(pow2_scales(math.inf)[1]) and math.isnan(pow2_scales(math.nan)[1])
    # relative state overflows (out of the documented range): no made-up answer
    t = npz.time_to_collision(
        [1e308, 0.0], [0.0, 0.0], [0.0, 0.0], 1.0, [-1e308, 0.0], [0.0, 0.0], [0.0, 0.0], 1.0, 5.0
    )
    assert math.isnan(t)


@pytest.mark.parametrize("y", [1e-300, 1e-30, 0.3, 1.0, 7.9, 8.0, 1e30, 1e300])
def test_cbrt_up(y):
    b = njit(lambda v: nf._cbrt_up(v))(y)  # (compiled: it uses bit-level intrinsics)
    assert math.frexp(b)[0] == 0.5 and y ** (1 / 3) * (1 - 1e-12) < b <= 2 * y ** (1 / 3) * (
        1 + 1e-12
    )
