"""uncertain_pairs / inflation_radius / covariance_problem: contract-level checks.

Guarantees proved here (docs/uncertainty.md):
* zero covariance rows give the exact solver's answer bit for bit, with
  probability exactly 0.0 or 1.0 and bound 0.0;
* a row's result does not depend on the batch it comes in;
* the k-sigma exits: far pairs report 0 and deep contacts 1, bound TUBE_TAIL;
* covariance_problem names each bad class.
"""
from __future__ import annotations

import numpy as np
import pytest

from circle_collision_ros.core import time_to_collision
from circle_collision_ros.core.uncertainty import (BROAD_PHASE_SIGMAS, TUBE_TAIL, UncertainPairs,
                                                   covariance_problem, inflation_radius,
                                                   uncertain_pairs)


def _batch(rng, n, D, sigma_scale):
    pa = rng.normal(size=(n, D)) * 5
    va = rng.normal(size=(n, D))
    aa = rng.normal(size=(n, D)) * 0.3 * (rng.random((n, 1)) < 0.5)
    pb = rng.normal(size=(n, D)) * 5
    vb = rng.normal(size=(n, D))
    ab = np.zeros((n, D))
    ra = rng.uniform(0.2, 1.0, n)
    rb = rng.uniform(0.2, 1.0, n)

    def cov():
        B = rng.normal(size=(n, 2 * D, 2 * D)) * sigma_scale
        return B @ B.transpose(0, 2, 1)

    return pa, va, aa, ra, cov(), pb, vb, ab, rb, cov()


@pytest.mark.parametrize("D", [2, 3])
def test_zero_covariance_is_the_exact_answer_bit_for_bit(D):
    rng = np.random.default_rng(5 + D)
    pa, va, aa, ra, ca, pb, vb, ab, rb, cb = _batch(rng, 400, D, 0.0)
    H = 3.0
    res = uncertain_pairs(pa, va, aa, ra, ca, pb, vb, ab, rb, cb, H, 0.01)
    assert isinstance(res, UncertainPairs)
    t = time_to_collision(pa, va, aa, ra, pb, vb, ab, rb, H)
    hit = t <= H
    assert hit.any() and (~hit).any()
    assert np.array_equal(res.collision_probability, np.where(hit, 1.0, 0.0))
    assert np.array_equal(res.collision_probability_bound, np.zeros(400))
    assert np.array_equal(res.plausible_time, np.where(hit, t, np.inf))


def test_rows_do_not_depend_on_the_batch():
    rng = np.random.default_rng(11)
    args = _batch(rng, 12, 2, 0.2)
    H = 2.0
    whole = uncertain_pairs(*args, H, 0.05)
    for i in (0, 5, 11):
        one = uncertain_pairs(*(a[i:i + 1] for a in args), H, 0.05)
        for f_whole, f_one in zip(whole, one):
            assert f_whole[i].tobytes() == f_one[0].tobytes()
    again = uncertain_pairs(*args, H, 0.05)
    for x, y in zip(whole, again):
        assert x.tobytes() == y.tobytes()


def test_k_sigma_exits():
    """Far apart: exactly 0 with bound TUBE_TAIL; head-on with tiny sigma: 1."""
    z = np.zeros((2, 2))
    pa = np.array([[0.0, 0.0], [0.0, 0.0]])
    va = np.array([[1.0, 0.0], [1.0, 0.0]])
    pb = np.array([[5.0, 100.0], [5.0, 0.0]])
    cov = np.zeros((2, 4, 4))
    cov[:] = np.diag([1e-4, 1e-4, 1e-6, 1e-6])
    res = uncertain_pairs(pa, va, z, np.ones(2) * 0.5, cov, pb, z, z, np.ones(2) * 0.5,
                          np.zeros((2, 4, 4)), 10.0, 0.01)
    assert res.collision_probability.tolist() == [0.0, 1.0]
    assert res.collision_probability_bound.tolist() == [TUBE_TAIL, TUBE_TAIL]
    assert res.plausible_time[0] == np.inf
    # exact contact at t = 4; P(overlap) reaches 1 % ~2.3 sigma (~0.025 m) earlier
    assert 3.95 < res.plausible_time[1] < 4.0


def test_tube_tail_is_below_the_target():
    assert 2 * TUBE_TAIL < 1e-9
    assert BROAD_PHASE_SIGMAS == 7.5


def test_inflation_radius():
    cov = np.zeros((3, 4, 4))
    cov[1] = np.diag([0.04, 0.09, 0.0, 0.0])  # position only: sigma_max 0.3 at all t
    cov[2] = np.diag([0.0, 0.0, 0.01, 0.04])  # velocity only: sigma_max 0.2 t
    r = inflation_radius(cov, 5.0)
    assert r[0] == 0.0
    # the maximum of sqrt(lambda_max(S(t))) over [0, H], widened by 1e-9 relative for rounding
    assert 7.5 * 0.3 <= r[1] <= 7.5 * 0.3 * (1 + 1e-9)
    assert 7.5 * 0.2 * 5.0 <= r[2] <= 7.5 * 0.2 * 5.0 * (1 + 1e-9)


@pytest.mark.parametrize("cov, word", [
    (np.array([[1.0, 0.2], [0.0, 1.0]]), "not symmetric"),
    (np.array([[1.0, 2.0], [2.0, 1.0]]), "not positive semi-definite"),
    (np.array([[1.0, np.nan], [np.nan, 1.0]]), "not finite"),
    (np.ones(3), "square"),
])
def test_covariance_problem_names_the_class(cov, word):
    msg = covariance_problem(cov)
    assert msg is not None and word in msg


def test_covariance_problem_accepts_rounding():
    A = np.diag([1.0, 1.0, 0.0, 0.0])
    A[2, 2] = -1e-12  # rounding-sized negative eigenvalue
    assert covariance_problem(A) is None
    assert covariance_problem(np.zeros((4, 4))) is None


def test_k_sigma_tail_and_the_cauchy_schwarz_step():
    """The two facts behind BROAD_PHASE_SIGMAS (docs/uncertainty.md, "k"):
    P(chi^2_6 > k^2) = TUBE_TAIL (mpmath), and for any whitened z the
    deviation |M_t L z| of a body's centre is <= sqrt(lambda_max(S(t))) |z|
    <= inflation_radius / k * |z| at every t in [0, H]."""
    import mpmath as mp

    from circle_collision_ros.core.uncertainty.tube import chi2_tail_even

    ref = float(mp.gammainc(3, BROAD_PHASE_SIGMAS ** 2 / 2, mp.inf, regularized=True))
    assert abs(TUBE_TAIL - ref) <= 1e-24
    assert abs(chi2_tail_even(BROAD_PHASE_SIGMAS ** 2, 4)
               - float(mp.gammainc(2, BROAD_PHASE_SIGMAS ** 2 / 2, mp.inf,
                                   regularized=True))) <= 1e-24
    rng = np.random.default_rng(2)
    H = 4.0
    for D in (2, 3):
        B = rng.normal(size=(50, 2 * D, 2 * D)) * rng.uniform(0.01, 1, size=(50, 2 * D, 1))
        cov = B @ B.transpose(0, 2, 1)
        r = inflation_radius(cov, H)
        for i in range(50):
            lam, V = np.linalg.eigh(cov[i])
            L = V * np.sqrt(np.clip(lam, 0, None))
            z = rng.normal(size=(200, 2 * D))
            for t in np.linspace(0, H, 17):
                M = np.hstack([np.eye(D), t * np.eye(D)])
                dev = np.linalg.norm(z @ (M @ L).T, axis=1)
                assert np.all(
                    dev <= r[i] / BROAD_PHASE_SIGMAS * np.linalg.norm(z, axis=1) * (1 + 1e-12)
                )


def test_invalid_rows_give_nan_and_leave_the_others_alone():
    rng = np.random.default_rng(4)
    args = list(_batch(rng, 3, 2, 0.2))
    good = uncertain_pairs(*args, 2.0, 0.05)
    args[0] = args[0].copy()
    args[0][1, 0] = np.nan  # pa of row 1
    args[4] = args[4].copy()
    args[4][2, 0, 0] = np.inf  # cov_a of row 2
    res = uncertain_pairs(*args, 2.0, 0.05)
    for f_good, f in zip(good[:3], res[:3]):  # the three float columns
        assert np.isnan(f[1]) and np.isnan(f[2])
        assert f[0].tobytes() == f_good[0].tobytes()
    assert not res.deferred.any()


def test_invalid_exact_rows_give_nan():
    z = np.zeros((1, 2))
    res = uncertain_pairs(np.array([[np.nan, 0.0]]), z, z, np.ones(1), np.zeros((1, 4, 4)), z, z, z,
                          np.ones(1), np.zeros((1, 4, 4)), 1.0, 0.01)
    assert all(np.isnan(f[0]) for f in res[:3]) and not res.deferred[0]
