"""The analytic interval bound of the plausible-time walk, the over-count estimator
of accelerating pairs and the tube's whole ambiguous nodes (docs/uncertainty.md,
"Earliest plausible contact", "Accelerating" and "Localisation").

Guarantees proved here:
* ``instant_bound(.., ta, tb)`` >= P(|X(t)| <= R) for every t in [ta, tb]
  (checked against ``overlap_probability``, itself within 1e-9 of mpmath, on
  a dense grid; 2-D and 3-D, correlated, position-only, velocity-only and
  rank-deficient covariances, sigma from ~0.03 R to ~50 R); ``det_lower`` is
  a lower bound of det S(t) on the interval; the bound is tight (within 30 %)
  where sigma >> R and S is near-isotropic (the large-sigma family);
* ``swept_ball_bound(.., a, b) + TUBE_TAIL`` >= P(contact within [a, b]) (seeded
  Monte Carlo on the exact solver from the state at a, 4 standard errors; 2-D
  and 3-D, straight and accelerating, every covariance class, velocity sigma
  up to ~30x the mean speed, steps from 1e-3 s to 1 s): without its velocity
  term k sqrt(lambda_max(Svv)) the test fails;
* ``lam_max_sym3`` (the tube's 3-D lambda_max in closed form) is an upper
  bound within 1e-11 relative of the 40-digit mpmath eigenvalue (random,
  rank-deficient, near-isotropic and near-rank-1 matrices, scales 1e-12 to 1e6);
* ``quartic_crossings`` counts the inside-at-0 and the entries of a path as
  the exact solver and a 200,001-point time grid do;
* ``overcount_counts``' convexity shortcut (over [0, H]) changes no count;
* ``overcount_counts`` in stages, with the shortcut on the tube's hull for tube paths,
  counts exactly what every path's crossings give, and ``overcount_answer`` gives the
  answer of the staged rule computed from those counts (every stage, with and without a
  tolerance);
* an accelerating pair whose paths often exit and come back (over-count
  E[O] ~ 0.3) is answered within its stated bound of 1e6-sample Monte Carlo;
* ``no_reentry`` is a certificate: where it holds over the hull of the
  ambiguous intervals, f'' = 2 (|Xdot|^2 + X.da) > 0 there on every sampled
  path of the tube (interior and boundary |z| = k); it certifies the
  benchmark's accelerating pairs at the sigmas the bracket needs; a certified accelerating
  pair skips the over-count RQMC, its bound is the quadrature's (below the
  RQMC's 3/2048 floor) and holds against 1e6-sample Monte Carlo;
* ``tube_intervals``' whole ambiguous nodes: every reported interval is a hull
  of ambiguous leaves of the fully refined walk, covering all of them, with the
  same t_inside (mutations dropping either condition of ``_ambiguous_through``
  fail it).
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from circle_collision_ros.core import time_to_collision
from circle_collision_ros.core.uncertainty import uncertain_pairs
from circle_collision_ros.core.uncertainty.pair import (OUT_ERR, OUT_HI, OUT_LO, OUT_QMC,
                                                        OUT_SIZE, OUT_T0, OUT_T1,
                                                        QMC_TOL_POINTS, overcount_answer,
                                                        pair_kernel)
from circle_collision_ros.core.uncertainty.qmc import (QMC_CV_POINTS, QMC_CV_TARGET, QMC_POINTS,
                                                       QMC_REPLICATES, QMC_T, factor,
                                                       normal_table, overcount_counts,
                                                       quartic_crossings)
from circle_collision_ros.core.uncertainty.reentry import (BRACKET_HALF_WIDTH, REENTRY_SIGMAS,
                                                           no_reentry)
from circle_collision_ros.core.uncertainty.tube import (BROAD_PHASE_SIGMAS, TUBE_DEPTH, TUBE_TAIL,
                                                        S_at, lam_max_sym3, max_sigma_over,
                                                        mean_range, tube_intervals)
from circle_collision_ros.core.uncertainty.walk import (ST_PTOL, ST_SIZE, ST_SWEEP_DV, det_lower,
                                                        instant_bound, instant_probability,
                                                        swept_ball_bound, swept_ball_split,
                                                        velocity_sigma)
from tests.core.uncertainty.test_uncertainty_horizon import KINDS, mc_probability, random_pair
from tests.stress import examples


def test_instant_bound_holds_on_every_interval():
    rng = np.random.default_rng(21)
    tight = []
    checked = 0
    for D in (2, 3):
        for it in range(120 if D == 2 else 40):
            pa, va, aa, ra, ca, pb, vb, ab, rb, cb = random_pair(rng, D, KINDS[it % len(KINDS)])
            scale = 10 ** rng.uniform(-1.5, 2.5)  # sigma from << R to >> R
            dp, dv, da, R = pa - pb, va - vb, aa - ab, ra + rb
            S = np.ascontiguousarray((ca + cb) * scale)
            ta = rng.uniform(0, 3)
            tb = ta + rng.uniform(0, 3) * rng.choice([1.0, 0.1, 0.01])
            ts = np.linspace(ta, tb, 61)
            P = np.array([instant_probability(dp, dv, da, R, S, t) for t in ts])
            bound = instant_bound(dp, dv, da, R, S, ta, tb)
            assert P.max() <= bound, (D, it, P.max(), bound)
            dets = [np.linalg.det(S_at(S, t)) for t in ts]
            assert det_lower(S, ta, tb) <= min(dets) + 1e-12 * max(abs(d) for d in dets) + 1e-300
            checked += 1
    # tight where sigma >> R and S is near-isotropic (the large-sigma family: the walk
    # certifies whole panels there)
    for it in range(20):
        R = rng.uniform(0.5, 1.5)
        s = R * rng.uniform(10, 40)
        S = np.diag([s * s, s * s, 0.01 * s * s, 0.01 * s * s])
        dp = rng.normal(size=2) * s * 0.7
        dv = rng.normal(size=2)
        da = np.zeros(2)
        ta = rng.uniform(0, 2.9)
        tb = ta + 0.05
        P = max(instant_probability(dp, dv, da, R, S, t) for t in np.linspace(ta, tb, 11))
        tight.append(instant_bound(dp, dv, da, R, S, ta, tb) / P)
    assert checked == 160 and max(tight) < 1.3, max(tight)


def _contact_within(dp, dv, da, R, Sig, a, b, n, seed):
    """(estimate, standard error) of P(the path touches |x| <= R within [a, b]):
    seeded samples of (dp, dv) through the exact solver from the state at a."""
    D = dp.shape[0]
    lam, V = np.linalg.eigh(Sig)
    y = (
        np.random.default_rng(seed).standard_normal((n, 2 * D))
        @ (V * np.sqrt(np.clip(lam, 0, None))).T
    )
    p0, v0 = dp + y[:, :D], dv + y[:, D:]
    z = np.zeros((n, D))
    t = time_to_collision(p0 + a * v0 + 0.5 * a * a * da, v0 + a * da, np.broadcast_to(da, (n, D)),
                          np.full(n, R), z, z, z, np.zeros(n), b - a)
    p = np.count_nonzero(t <= b - a) / n
    return p, math.sqrt(max(p * (1 - p), 1 / n) / n)


def _swept_bound(dp, dv, da, R, Sig, a, b):
    st = np.zeros(ST_SIZE)
    st[ST_PTOL] = 0.0  # the standard tolerance: within 1e-9
    st[ST_SWEEP_DV] = BROAD_PHASE_SIGMAS * velocity_sigma(Sig)
    return swept_ball_bound(dp, dv, da, R, Sig, a, b, st) + TUBE_TAIL + 1e-9


def test_swept_ball_bound_covers_contact_within_the_step():
    rng = np.random.default_rng(44)
    close = 0
    for it in range(48):
        D = 2 + it % 2
        if it % 4 == 3:
            # the velocity noise alone brings the bodies together: the mean
            # path rests just outside, position sigma small, velocity sigma ~1
            R = rng.uniform(0.3, 1.0)
            dp = rng.normal(size=D)
            dp *= (R + rng.uniform(0.05, 0.4)) / np.linalg.norm(dp)
            dv = np.zeros(D)
            da = np.zeros(D)
            B = rng.normal(size=(2 * D, 2 * D))
            B[:D] *= 0.02
            B[D:] *= rng.uniform(0.5, 1.5)
            Sig = np.ascontiguousarray(B @ B.T / (2 * D))
            a = rng.uniform(0.0, 1.0)
            b = a + rng.choice([0.03, 0.3, 1.0])
        else:
            kind = KINDS[it % len(KINDS)]
            pa, va, aa, ra, ca, pb, vb, ab, rb, cb = random_pair(rng, D, kind)
            dp, dv, da, R = pa - pb, va - vb, aa - ab, ra + rb
            Sig = np.ascontiguousarray((ca + cb) * 10 ** rng.uniform(-1, 1))
            # steps near the mean path's closest approach, where contact is likely
            t_ca = -float(dp @ dv) / max(float(dv @ dv), 1e-12)
            a = min(max(t_ca + rng.uniform(-0.6, 0.1), 0.0), 2.5)
            b = a + rng.choice([1e-3, 0.03, 0.3, 1.0])
        bound = _swept_bound(dp, dv, da, R, Sig, a, b)
        p, se = _contact_within(dp, dv, da, R, Sig, a, b, 40_000, 1000 + it)
        assert p <= bound + 4 * se, (it, D, a, b, p, bound)
        close += 0.01 < p and p > 0.5 * bound
    assert close >= 8, close  # not vacuous: the bound is within 2x on some steps


def test_split_swept_ball_bounds_the_end_game_step():
    """The end game's split bound (``swept_ball_split``: the swept ball over
    _ENDGAME_SPLIT sub-steps) is >= P(|X(t)| <= R) on a 41-point grid of the step
    (each P at 1e-9) and never above the single swept ball; on steps of the walk's
    end-game width (3e-6 s) near closest approach its excess over P(midpoint) is
    typically ~1/4 of the single ball's (the inflation shrinks with the sub-step;
    the rise of P across the step stays)."""
    rng = np.random.default_rng(46)
    st = np.zeros(ST_SIZE)
    ratios = []
    for it in range(60):
        D = 2 + it % 2
        kind = KINDS[it % len(KINDS)]
        pa, va, aa, ra, ca, pb, vb, ab, rb, cb = random_pair(rng, D, kind)
        dp, dv, da, R = pa - pb, va - vb, aa - ab, ra + rb
        Sig = np.ascontiguousarray((ca + cb) * 10 ** rng.uniform(-1, 1))
        st[ST_SWEEP_DV] = BROAD_PHASE_SIGMAS * velocity_sigma(Sig)
        t_ca = -float(dp @ dv) / max(float(dv @ dv), 1e-12)
        a = min(max(t_ca + rng.uniform(-0.6, 0.1), 0.0), 2.5)
        end_game = it % 4 < 2
        b = a + (3e-6 if end_game else rng.choice([1e-3, 0.03]))
        split = swept_ball_split(dp, dv, da, R, Sig, a, b, st, 2.0)
        single = swept_ball_bound(dp, dv, da, R, Sig, a, b, st)
        grid = max(instant_probability(dp, dv, da, R, Sig, t) for t in np.linspace(a, b, 41))
        assert grid <= split + 2e-9, (it, grid, split)
        assert split <= single + 2e-9, (it, split, single)
        pm = instant_probability(dp, dv, da, R, Sig, 0.5 * (a + b))
        if end_game and single - pm > 2e-8:
            ratios.append((split - pm) / (single - pm))
    assert len(ratios) >= 5 and np.median(ratios) <= 0.35, ratios


def test_lam_max_sym3_is_a_tight_upper_bound():
    import mpmath as mp

    mp.mp.dps = 40
    rng = np.random.default_rng(3)
    for i in range(600):
        kind = i % 4
        B = rng.normal(size=(3, 3)) * 10 ** rng.uniform(-6, 3)
        if kind == 1:
            B[:, 2] = 0.0  # rank 2
        elif kind == 2:
            B = np.diag(rng.uniform(0.5, 1.0, 3)) + 1e-9 * rng.normal(size=(3, 3))  # near isotropic
        elif kind == 3:
            B = np.outer(rng.normal(size=3), rng.normal(size=3)) + 1e-8 * rng.normal(size=(3, 3))
        S = B @ B.T
        ub = lam_max_sym3(S[0, 0], S[1, 1], S[2, 2], S[0, 1], S[0, 2], S[1, 2])
        exact = max(mp.eigsy(mp.matrix(S.tolist()))[0])
        assert exact <= ub <= exact * (1 + 1e-11), (i, ub, exact)


def test_quartic_crossings_match_the_exact_solver_and_a_fine_grid():
    rng = np.random.default_rng(5)
    grid = np.linspace(0.0, 3.0, 200_001)
    repeated = 0
    # 4000 paths (the ones that come back are rare: 6 of them, from the 1790th), the first
    # 1500 also on the grid (--stress; the first 100 by default: the grid is what costs)
    on_grid = examples(100, 1500)
    for it in range(4000):
        D = 2 + it % 2
        p, v, a = rng.normal(size=D) * 1.5, rng.normal(size=D) * 1.5, rng.normal(size=D) * 3.0
        R = rng.uniform(0.2, 2.0)
        inside0, entries = quartic_crossings(p, v, a, R, 3.0)
        z = np.zeros(D)
        contact = float(time_to_collision(p, v, a, R, z, z, z, 0.0, 3.0)) <= 3.0
        assert contact == (inside0 or entries >= 1), (p, v, a, R)
        if it < on_grid:
            X = p[None] + grid[:, None] * (v[None] + 0.5 * grid[:, None] * a[None])
            f = np.einsum("ij,ij->i", X, X) - R * R
            assert entries == np.count_nonzero((f[:-1] > 0) & (f[1:] <= 0)), (p, v, a, R)
            assert inside0 == (f[0] <= 0)
        repeated += (int(inside0) + entries) >= 2
    assert repeated >= 3  # paths that come back are in the mix


def test_overcount_shortcut_changes_no_count():
    rng = np.random.default_rng(8)
    Z = normal_table(4)
    seen = 0
    for it in range(25):
        Sigma = np.diag([0.3, 0.3, 0.2, 0.2]) * 10 ** rng.uniform(-1, 0.5)
        dp, dv, da = rng.normal(size=2) * 2, rng.normal(size=2), rng.normal(size=2) * 3
        L = factor(Sigma)
        tot = np.zeros(Z.shape[0], dtype=np.int64)
        overcount_counts(dp, dv, da, 1.0, 3.0, L, Z, 0, 64, 0.0, 3.0, 0.0, tot)
        est = tot / 64
        direct = 0
        for r in range(Z.shape[0]):
            for i in range(64):
                y = L @ Z[r, i]
                inside0, entries = quartic_crossings(dp + y[:2], dv + y[2:], da, 1.0, 3.0)
                direct += max(int(inside0) + entries - 1, 0)
        assert round(est.sum() * 64) == direct
        seen += direct
    assert seen > 0


def _path_overcounts(dp, dv, da, R, H, L, Z):
    """(replicates, points) over-count of every path, from its crossings alone."""
    o = np.zeros(Z.shape[:2], dtype=np.int64)
    for r in range(Z.shape[0]):
        for i in range(Z.shape[1]):
            y = L @ Z[r, i]
            inside0, entries = quartic_crossings(dp + y[:2], dv + y[2:], da, R, H)
            o[r, i] = max(int(inside0) + entries - 1, 0)
    return o


def test_overcount_stages_and_tube_shortcut_count_every_path():
    """Accelerating pairs whose paths often turn back, from the tracker family (slow, pairs
    passing near each other) to paths that exit and come back: the counts of each stage,
    added to the last stage's, with the f'' shortcut on the tube's hull, equal the paths'
    own crossing counts; the answer is the staged rule's on those counts."""
    rng = np.random.default_rng(12)
    Z = normal_table(4)
    leaves = np.empty((1 << TUBE_DEPTH, 2))
    out = np.empty(OUT_SIZE)
    seen = asked = 0
    for it in range(40):
        if it % 2:  # a tracker frame's pairs
            H, R = 5.0, float(rng.uniform(1.0, 3.0))
            Sigma = np.diag([0.18, 0.18, 0.08, 0.08]) * 10 ** rng.uniform(-1, 0.5)
            dp, dv, da = rng.normal(size=2) * 4, rng.normal(size=2) * 1.2, rng.normal(size=2) * 0.4
        else:  # strong accelerations: many paths exit and come back
            H, R = 3.0, 1.0
            Sigma = np.diag([0.3, 0.3, 0.2, 0.2]) * 10 ** rng.uniform(-1, 0.5)
            dp, dv, da = rng.normal(size=2) * 2, rng.normal(size=2), rng.normal(size=2) * 3
        cnt, _ = tube_intervals(dp, dv, da, R, Sigma, H, leaves, BROAD_PHASE_SIGMAS)
        if cnt == 0:
            continue
        t0, t1 = leaves[0, 0], leaves[cnt - 1, 1]
        L = factor(Sigma)
        o = _path_overcounts(dp, dv, da, R, H, L, Z[:, :QMC_POINTS // 2])
        tot = np.zeros(Z.shape[0], dtype=np.int64)
        done = 0
        for m in (32, 64, 128, 256):
            overcount_counts(dp, dv, da, R, H, L, Z, done, m, t0, t1, BROAD_PHASE_SIGMAS**2, tot)
            assert np.array_equal(tot, o[:, :m].sum(axis=1)), (it, m)
            done = m
        seen += int(o.sum() > 0)
        # the staged rule, from the counts alone (the bracket taken only where it is within
        # the tolerance); upper, lo and slack as a kernel could leave them
        upper = float(rng.uniform(0.05, 1.0))
        out[:] = 0.0
        out[OUT_QMC], out[OUT_HI], out[OUT_LO], out[OUT_ERR] = 2.0, upper, 0.0, 1e-3
        out[OUT_T0], out[OUT_T1] = t0, t1
        full = _path_overcounts(dp, dv, da, R, H, L, Z)
        for tol in (0.0, 0.005, 0.02):
            stages = [m for m in QMC_TOL_POINTS if tol > 0 and 3.0 / (QMC_REPLICATES * m) <= tol]
            for m in stages + [QMC_CV_POINTS, QMC_POINTS]:
                est = full[:, :m].sum(axis=1) / m
                mean = est.mean()
                se = math.sqrt(((est - mean) ** 2).sum() / (len(est) - 1) / len(est))
                stat = max(QMC_T * se, 3.0 / (QMC_REPLICATES * m))
                if stat <= QMC_CV_TARGET or stat + 1e-3 <= tol:
                    break
            want = (min(1.0, max(0.0, min(max(upper - mean, 0.0), upper))), stat + 1e-3)
            got = overcount_answer(dp, dv, da, R, Sigma, H, out, tol, Z)
            assert got == pytest.approx(want, rel=1e-12, abs=1e-15), (it, tol)
            asked += 1
    assert seen >= 5 and asked >= 60  # paths that come back are in the mix


def test_accelerating_pair_that_comes_back_is_within_its_bound():
    # X(t) = (-3, 0.2) + (5, 0) t + (-3, 0) t^2 / 2: in at ~0.6 s, out at ~1 s, back in
    # at ~2.3 s: about a third of the paths enter twice
    z2 = np.zeros(2)
    cov = np.diag([0.09, 0.09, 0.04, 0.04]) / 2
    pair = (np.array([-3.0, 0.2]), np.array([5.0, 0.0]), np.array([-3.0, 0.0]), 0.25, cov, z2, z2,
            z2, 0.25, cov)
    res = uncertain_pairs(*(np.asarray(x, float)[None] for x in pair), 3.0, 0.01)
    p, b = float(res.collision_probability[0]), float(res.collision_probability_bound[0])
    q, se = mc_probability(*pair, 3.0, 1_000_000, seed=31)
    assert abs(p - q) <= b + 4 * se, (p, b, q, se)
    assert b < 0.01
    # the over-count is large here: P0 + E[entries] alone would be far off
    Z = normal_table(4)
    tot = np.zeros(Z.shape[0], dtype=np.int64)
    overcount_counts(pair[0], pair[1], pair[2], 0.5, 3.0, factor(cov * 2), Z, 0, 512, 0.0, 3.0,
                     0.0, tot)
    est = tot / 512
    assert est.mean() > 0.05
    assert math.isfinite(float(res.plausible_time[0]))


def _tube_leaves_reference(dp, dv, da, R, Sigma, H, k):
    """The k-sigma tube walk refined to every leaf (no whole ambiguous nodes): the
    ambiguous leaves (unmerged) and t_inside, by the same node tests."""
    leaves, t_inside = [], math.inf
    stack = [(0.0, H, 0)]
    while stack:
        ta, tb, d = stack.pop()
        rho = k * max_sigma_over(Sigma, ta, tb)
        gmin, gmax = mean_range(dp, dv, da, ta, tb)
        if gmin - rho > R:
            continue
        if gmax + rho < R:
            t_inside = min(t_inside, ta)
            continue
        m = 0.5 * (ta + tb)
        if d >= TUBE_DEPTH or not (ta < m < tb):
            leaves.append((ta, tb))
            continue
        stack += [(m, tb, d + 1), (ta, m, d + 1)]
    return leaves, t_inside


def test_tube_whole_ambiguous_nodes_are_hulls_of_the_leaves():
    """tube_intervals keeps an ambiguous node whole when both ends are ambiguous and
    k^2 tr S(t) / D >= R^2 on it: the reported intervals must be unions of whole
    reference leaves' hulls (every ambiguous leaf covered, every interval starting
    and ending at an ambiguous leaf's end), with t_inside and "any interval"
    unchanged; sigma from ~1e-4 R (no shortcut, inside nodes) to ~10 R."""
    rng = np.random.default_rng(181)
    H = 3.0
    out = np.empty((1 << TUBE_DEPTH, 2))
    wide = inside = 0
    for i in range(300):
        D = 2 if i % 3 else 3
        kind = KINDS[i % len(KINDS)]
        pa, va, aa, ra, ca, pb, vb, ab, rb, cb = random_pair(rng, D, kind)
        Sigma = (ca + cb) * 10 ** rng.uniform(-8, 2)
        dp, dv, da, R = pa - pb, va - vb, aa - ab, float(ra + rb)
        cnt, t_inside = tube_intervals(dp, dv, da, R, Sigma, H, out, BROAD_PHASE_SIGMAS)
        ref, ref_inside = _tube_leaves_reference(dp, dv, da, R, Sigma, H, BROAD_PHASE_SIGMAS)
        assert t_inside == ref_inside
        assert (cnt > 0) == (len(ref) > 0)
        got = [(out[j, 0], out[j, 1]) for j in range(cnt)]
        starts = {a for a, _ in ref}
        ends = {b for _, b in ref}
        for a, b in got:
            assert a in starts and b in ends, (a, b)
        for a, b in ref:
            assert any(ga <= a and b <= gb for ga, gb in got), (a, b)
        wide += BROAD_PHASE_SIGMAS**2 * np.trace(Sigma[:D, :D]) / D >= R * R and cnt > 0
        inside += t_inside <= H
    assert wide >= 30 and inside >= 30, (wide, inside)  # both regimes drawn


@pytest.mark.parametrize("k", [BROAD_PHASE_SIGMAS, min(REENTRY_SIGMAS)])
def test_no_reentry_certificate_holds_on_the_tube(k):
    rng = np.random.default_rng(44)
    certified = 0
    cases = examples(160, 400)  # the first 160 of the same cases by default
    for it in range(cases):
        D = 2 if it % 3 else 3
        # accelerating kinds
        pa, va, aa, ra, ca, pb, vb, ab, rb, cb = random_pair(rng, D, KINDS[1 + it % 2])
        scale = 10 ** rng.uniform(-3.0, 0.0)
        dp, dv, da = pa - pb, va - vb, (aa - ab) * 10 ** rng.uniform(-2.0, 0.5)
        S = np.ascontiguousarray((ca + cb) * scale)
        t0 = rng.uniform(0.0, 2.0)
        t1 = t0 + rng.uniform(0.0, 1.5)
        if not no_reentry(dp, dv, da, S, t0, t1, k):
            continue
        certified += 1
        L = factor(S)
        z = rng.standard_normal((400, 2 * D))
        z /= np.linalg.norm(z, axis=1)[:, None]
        z *= np.where(rng.random(400) < 0.5, k, k * rng.random(400) ** (1 / (2 * D)))[:, None]
        y = z @ L.T
        ts = np.linspace(t0, t1, 301)
        X = (
            dp
            + y[:, None, :D]
            + (dv + y[:, None, D:]) * ts[None, :, None]
            + 0.5 * da * ts[None, :, None] ** 2
        )
        Xd = dv + y[:, None, D:] + da * ts[None, :, None]
        fpp = np.sum(Xd * Xd, axis=2) + X @ da
        assert fpp.min() > 0.0, (it, fpp.min())
    # the property was exercised, by each of the two bounds where the other fails
    assert certified > 50 * cases // 400  # the property was exercised


def test_no_reentry_certifies_the_benchmark_accelerating_family():
    """The benchmark's accelerating family (|da| ~1.1 m/s^2, hull ~2.3 s, |g| up to ~6 m),
    which the cruder (min |gd| - k sigma_v)^2 > (max |g| + k sigma_x) |da| certified at no
    k: each of its first four pairs is certified at some k' of REENTRY_SIGMAS, so its
    bracket answers it without the RQMC (within its bound of 1e6-sample Monte Carlo: the
    first two pairs by default, all four under --stress)."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "bench"))
    import bench_uncertainty as bench

    fi = [name for name, _ in bench.FAMILIES].index("accelerating")
    rng = np.random.default_rng(18 + 100 * fi)  # the benchmark's own pairs
    leaves = np.empty((1 << TUBE_DEPTH, 2))
    out = np.empty(OUT_SIZE)
    for k in range(4):
        pair = bench._family("accelerating", rng, 2)
        pa, va, aa, ra, ca, pb, vb, ab, rb, cb = pair
        dp, dv, da, R, S = pa - pb, va - vb, aa - ab, ra + rb, np.ascontiguousarray(ca + cb)
        cnt, _ = tube_intervals(dp, dv, da, R, S, bench.H, leaves, BROAD_PHASE_SIGMAS)
        assert any(
            no_reentry(dp, dv, da, S, leaves[0, 0], leaves[cnt - 1, 1], kk) for kk in REENTRY_SIGMAS
        ), k
        pair_kernel(dp, dv, da, R, S, bench.H, bench.THRESHOLD, out)
        assert out[OUT_QMC] == 0.0, k  # answered by the bracket
        res = uncertain_pairs(*(np.asarray(x, float)[None] for x in pair), bench.H, bench.THRESHOLD)
        p, b = float(res.collision_probability[0]), float(res.collision_probability_bound[0])
        if k < examples(2, 4):
            q, se = mc_probability(*pair, bench.H, 1_000_000, seed=90 + k)
            assert abs(p - q) <= b + 4 * se, (k, p, b, q, se)


def test_certified_accelerating_pair_skips_the_overcount():
    """Fast approach, gentle acceleration: no tube path can come back, so the answer is
    P0 + E[entries] with the quadrature's bound, below the over-count RQMC's floor of
    3 / 2048 (which every accelerating pair carried before the certificate)."""
    z2 = np.zeros(2)
    cov = np.diag([0.04, 0.04, 0.01, 0.01]) / 2
    pair = (np.array([-4.0, 0.3]), np.array([3.0, 0.0]), np.array([0.2, 0.1]), 0.5, cov, z2, z2, z2,
            0.5, cov)
    leaves = np.empty((1 << TUBE_DEPTH, 2))
    dp, dv, da, S = pair[0], pair[1], pair[2], cov * 2
    cnt, _ = tube_intervals(dp, dv, da, 1.0, S, 3.0, leaves, BROAD_PHASE_SIGMAS)
    assert cnt > 0 and no_reentry(
        dp, dv, da, S, leaves[0, 0], leaves[cnt - 1, 1], BROAD_PHASE_SIGMAS
    )
    res = uncertain_pairs(*(np.asarray(x, float)[None] for x in pair), 3.0, 0.01)
    p, b = float(res.collision_probability[0]), float(res.collision_probability_bound[0])
    assert b < 3.0 / 2048
    q, se = mc_probability(*pair, 3.0, 1_000_000, seed=32)
    assert abs(p - q) <= b + 4 * se, (p, b, q, se)


def test_uncertified_accelerating_pairs_answered_by_their_bracket():
    """Accelerating pairs that no_reentry cannot certify on the full tube but whose
    bracket [max(largest instantaneous P, U - slack - E[O] bound of a narrower
    certified tube), U + slack] is no wider than the RQMC's tightest bound are answered
    by its midpoint without sampling; the answer holds against 1e6-sample Monte Carlo,
    and its bound stays within U's slack + the RQMC's floor (3/2048)."""
    rng = np.random.default_rng(77)
    H = 3.0
    leaves = np.empty((1 << TUBE_DEPTH, 2))
    out = np.empty(OUT_SIZE)
    checked = narrow = 0
    want = examples(4, 8)  # pairs checked against Monte Carlo: the first 4 by default
    for it in range(400):
        pair = random_pair(rng, 2, "accelerating-wide" if it % 2 else "accelerating")
        pa, va, aa, ra, ca, pb, vb, ab, rb, cb = pair
        dp, dv, da, R, S = pa - pb, va - vb, aa - ab, float(ra + rb), ca + cb
        cnt, t_inside = tube_intervals(dp, dv, da, R, S, H, leaves, BROAD_PHASE_SIGMAS)
        if (
            cnt == 0
            or t_inside <= H
            or no_reentry(dp, dv, da, S, leaves[0, 0], leaves[cnt - 1, 1], BROAD_PHASE_SIGMAS)
        ):
            continue
        pair_kernel(dp, dv, da, R, S, H, 0.01, out)
        if out[OUT_QMC] != 0.0:
            continue
        res = uncertain_pairs(*(np.asarray(x, float)[None] for x in pair), H, 0.01)
        p, b = float(res.collision_probability[0]), float(res.collision_probability_bound[0])
        assert b <= BRACKET_HALF_WIDTH + 0.01, b
        q, se = mc_probability(*pair, H, 1_000_000, seed=500 + it)
        assert abs(p - q) <= b + 4 * se, (it, p, b, q, se)
        narrow += any(
            no_reentry(dp, dv, da, S, leaves[0, 0], leaves[cnt - 1, 1], k) for k in REENTRY_SIGMAS
        )
        checked += 1
        if checked == want:
            break
    assert checked == want and narrow >= 1, (checked, narrow)  # both sides of the bracket exercised
