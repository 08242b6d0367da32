"""The threshold screen of uncertain_pairs(screen=True) (docs/uncertainty.md, "Screening").

Guarantees proved here:
* a screened row reports (0.0, U, +inf) with U <= threshold / 2: U = P(chi^2_2D > k^2) where
  the k-sigma tube never reaches the ball, else the projection bound; U is a certified upper
  bound of P(contact within [0, H]): the full evaluation's probability minus its own bound
  never exceeds U, and seeded Monte Carlo on the exact solver agrees (MC <= U + 4 SE); both
  kinds occur;
* rows the screen does not clear are bit for bit the unscreened answer;
* the screen is decided row by row, is invariant under swapping a and b, and
  is monotone in R (clear at R => clear at every smaller R);
* zero-covariance rows are never screened (the exact answer, bit for bit).
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from circle_collision_ros.core import time_to_collision
from circle_collision_ros.core.uncertainty import uncertain_pairs
from circle_collision_ros.core.uncertainty.tube import chi2_tail_even, screen_rows, screen_sigmas


def screened(res, thr: float) -> np.ndarray:
    """Rows a screen answered: (0.0, U <= threshold / 2, +inf) (a full evaluation gives 0.0
    only where the tube never reaches the ball, which the screen clears first)."""
    return ((res.collision_probability == 0.0) & np.isinf(res.plausible_time)
            & (res.collision_probability_bound > 0.0)
            & (res.collision_probability_bound <= thr / 2))


def _near_pairs(rng, n, D, miss_sigmas):
    """n pairs whose mean paths pass at about ``miss_sigmas`` relative sigmas."""
    sp, sv = 0.2, 0.1
    pa = np.zeros((n, D))
    va = np.zeros((n, D))
    va[:, 0] = 2.0
    pb = np.zeros((n, D))
    pb[:, 0] = 6.0
    vb = np.zeros((n, D))
    vb[:, 0] = -1.0
    aa = np.zeros((n, D))
    aa[: n // 2] = rng.normal(size=(n // 2, D)) * 0.2  # half accelerating
    ab = np.zeros((n, D))
    ra = np.full(n, 0.4)
    rb = np.full(n, 0.3)

    def cov():
        B = rng.normal(size=(n, 2 * D, 2 * D))
        B[:, :D] *= sp
        B[:, D:] *= sv
        return B @ B.transpose(0, 2, 1) / (2 * D)

    ca, cb = cov(), cov()
    # lateral offset: R + miss_sigmas * (a typical relative sigma at the meeting time)
    pb[:, 1] = 0.7 + rng.uniform(*miss_sigmas, n) * math.sqrt(2) * 0.25
    return pa, va, aa, ra, ca, pb, vb, ab, rb, cb


@pytest.mark.parametrize("D", [2, 3])
def test_screened_rows_are_certified_below_the_threshold(D):
    rng = np.random.default_rng(40 + D)
    n = 40 if D == 2 else 12
    args = _near_pairs(rng, n, D, (1.0, 9.0) if D == 2 else (1.0, 16.0))
    H, thr = 3.0, 0.01
    full = uncertain_pairs(*args, H, thr)
    scr = uncertain_pairs(*args, H, thr, screen=True)
    k, U = screen_sigmas(thr, 2 * D)
    assert U == chi2_tail_even(k * k, 2 * D) and U <= thr / 2
    cleared = screened(scr, thr)
    assert cleared.any() and (~cleared).any(), "the mix must have screened and evaluated rows"
    by_tube = scr.collision_probability_bound == U
    assert by_tube.any() and (cleared & ~by_tube).any(), "both screens must clear rows"
    assert np.all(scr.collision_probability[cleared] == 0.0)
    assert np.all(np.isinf(scr.plausible_time[cleared]))
    # certified: the full answer (within its own bound) never exceeds U
    assert np.all(
        full.collision_probability[cleared] - full.collision_probability_bound[cleared] <= U
    )
    assert np.all(np.isinf(full.plausible_time[cleared]))
    # and the rest are the unscreened answer, bit for bit
    for f, g in zip(full, scr):
        assert f[~cleared].tobytes() == g[~cleared].tobytes()
    # Monte Carlo on the exact solver (seeded) on the screened rows
    rows = np.flatnonzero(cleared)
    for i in np.concatenate((rows[by_tube[rows]][:3], rows[~by_tube[rows]][:4])):
        pa, va, aa, ra, ca, pb, vb, ab, rb, cb = (x[i] for x in args)
        m = 100_000
        g = np.random.default_rng(1000 + i)
        lam, V = np.linalg.eigh(ca + cb)
        y = g.standard_normal((m, 2 * D)) @ (V * np.sqrt(np.clip(lam, 0, None))).T
        z = np.zeros((m, D))
        t = time_to_collision((pa - pb) + y[:, :D], (va - vb) + y[:, D:],
                              np.broadcast_to(aa - ab, (m, D)), np.full(m, ra + rb), z, z, z,
                              np.zeros(m), H)
        p = np.count_nonzero(t <= H) / m
        u = scr.collision_probability_bound[i]
        assert p <= u + 4 * math.sqrt(max(p * (1 - p), 1 / m) / m)


def test_screen_is_swap_invariant_and_monotone_in_radius():
    rng = np.random.default_rng(7)
    args = _near_pairs(rng, 60, 2, (0.0, 12.0))
    pa, va, aa, ra, ca, pb, vb, ab, rb, cb = args
    H, thr = 3.0, 0.01
    _, U = screen_sigmas(thr, 4)
    a = uncertain_pairs(*args, H, thr, screen=True)
    b = uncertain_pairs(pb, vb, ab, rb, cb, pa, va, aa, ra, ca, H, thr, screen=True)
    for x, y in zip(a, b):
        assert x.tobytes() == y.tobytes()
    cleared = screened(a, thr)
    smaller = uncertain_pairs(pa, va, aa, ra * 0.5, ca, pb, vb, ab, rb, cb, H, thr, screen=True)
    assert np.all(screened(smaller, thr)[cleared])
    assert np.all(smaller.collision_probability_bound[cleared]
                  <= a.collision_probability_bound[cleared])
    larger = uncertain_pairs(pa, va, aa, ra + 1.0, ca, pb, vb, ab, rb, cb, H, thr, screen=True)
    assert np.count_nonzero(screened(larger, thr)) < np.count_nonzero(cleared)
    assert np.count_nonzero(a.collision_probability_bound == U) < np.count_nonzero(cleared)


def test_screen_leaves_exact_rows_alone():
    rng = np.random.default_rng(3)
    args = list(_near_pairs(rng, 20, 2, (3.0, 9.0)))
    args[4] = np.zeros_like(args[4])
    args[9] = np.zeros_like(args[9])
    exact = uncertain_pairs(*args, 3.0, 0.01, screen=True)
    plain = uncertain_pairs(*args, 3.0, 0.01)
    for x, y in zip(exact, plain):
        assert x.tobytes() == y.tobytes()
    assert np.all(exact.collision_probability_bound == 0.0)


def test_budget_defers_the_latest_pairs_honestly():
    """max_evaluated=m: the m uncleared rows whose screening tube may reach the ball first get
    the full answer (bit for bit); the others the cheap certified interval of their own states
    (probability +- bound containing the full answer, never 1.0 +- 1.0) with t_first never
    later than the full answer's plausible time; deferred_count counts them."""
    from circle_collision_ros.core.uncertainty import deferred_count

    rng = np.random.default_rng(21)
    args = _near_pairs(rng, 30, 2, (0.0, 9.0))
    H, thr = 3.0, 0.01
    full = uncertain_pairs(*args, H, thr, screen=True)
    _, U = screen_sigmas(thr, 4)
    open_rows = np.flatnonzero(~screened(full, thr))
    assert open_rows.size > 5
    m = 3
    part = uncertain_pairs(*args, H, thr, screen=True, max_evaluated=m)
    deferred = part.deferred
    assert deferred_count(part) == np.count_nonzero(deferred) == open_rows.size - m
    p, b = part.collision_probability[deferred], part.collision_probability_bound[deferred]
    q, e = full.collision_probability[deferred], full.collision_probability_bound[deferred]
    assert np.all(np.abs(p - q) <= b + e)
    assert np.all((p - b >= 0.0) & (p + b <= 1.0)) and not np.any((p == 1.0) & (b == 1.0))
    assert np.all(part.plausible_time[deferred] <= full.plausible_time[deferred])
    kept = ~deferred
    for f, g in zip(full, part):
        assert f[kept].tobytes() == g[kept].tobytes()
    # the evaluated rows are those whose screening tube may reach the ball first
    pa, va, aa, ra, ca, pb, vb, ab, rb, cb = args
    k, _ = screen_sigmas(thr, 4)
    clear, t_first = np.zeros(30, dtype=bool), np.empty(30)
    screen_rows(
        pa - pb, va - vb, aa - ab, ra + rb, np.ascontiguousarray(ca + cb), H, k, clear, t_first
    )
    evaluated = kept & ~screened(part, thr)
    assert np.all(screened(part, thr)[clear])
    assert np.count_nonzero(evaluated) == m
    assert t_first[evaluated].max() <= t_first[deferred].min()
    assert np.array_equal(part.plausible_time[deferred], t_first[deferred])
    again = uncertain_pairs(*args, H, thr, screen=True, max_evaluated=m)
    for f, g in zip(part, again):
        assert f.tobytes() == g.tobytes()
    with pytest.raises(ValueError, match="screen=True"):
        uncertain_pairs(*args, H, thr, max_evaluated=m)
