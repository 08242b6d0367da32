"""Instantaneous overlap probability P(|X| <= R) against mpmath, 1e-9 absolute.

Guarantee proved here (docs/uncertainty.md, "Instantaneous probability"):
``overlap_probability(mean, S, R)`` (Ruben's mixture where it closes, else the
quadrature; the mixture is also tested alone below) is within 1e-9 of the exact value for the
float inputs as given, in 2-D and 3-D, for covariances that are isotropic,
strongly anisotropic (axis ratio up to 1e6), singular (rank 0, 1, 2),
sigma << R (down to 1e-5 R) and sigma >> R (up to 1e4 R), and means inside,
on the edge of and far outside the disc/ball.  The narrow balls' Gauss-Hermite
chord rule (sigma <= R / 8, where Ruben's mixture gives way) wherever it is
accepted: against the quadrature (1,200 cases) and mpmath, and its guard
against near-step integrands.

The default run checks a share of each test's cases (the same cases, or the first
of the same sequence); ``--stress`` (CI) runs every case and the 3-D and
anisotropic mpmath references marked ``stress``.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from circle_collision_ros.core.special import eig_sym
from circle_collision_ros.core.uncertainty.overlap import overlap_probability
from tests.core.uncertainty.uncertainty_reference import isotropic_reference, overlap_reference
from tests.stress import STRESS, examples

TOL = 1e-9


def _rotation(rng, D):
    q, r = np.linalg.qr(rng.normal(size=(D, D)))
    return q * np.sign(np.diag(r))


def random_case(rng, D):
    """(mean, S, R): random orientation, scales and degeneracies."""
    R = 10 ** rng.uniform(-1, 1)
    kind = rng.integers(0, 6)
    if kind == 0:    # comparable sigma
        sig = R * 10 ** rng.uniform(-1, 0.5, size=D)
    elif kind == 1:  # strongly anisotropic
        sig = R * 10 ** rng.uniform(-1, 1, size=D)
        sig[rng.integers(0, D)] *= 10 ** rng.uniform(-6, -3)
    elif kind == 2:  # singular: some directions exact
        sig = R * 10 ** rng.uniform(-1, 0.5, size=D)
        sig[rng.permutation(D)[: rng.integers(1, D + 1)]] = 0.0
    elif kind == 3:  # sigma << R
        sig = R * 10 ** rng.uniform(-5, -2, size=D)
    elif kind == 4:  # sigma >> R
        sig = R * 10 ** rng.uniform(1, 4, size=D)
    else:            # mixed
        sig = R * 10 ** rng.uniform(-4, 3, size=D)
    Q = _rotation(rng, D)
    S = Q @ np.diag(sig ** 2) @ Q.T
    S = 0.5 * (S + S.T)
    where = rng.integers(0, 4)
    u = rng.normal(size=D)
    u /= np.linalg.norm(u)
    scale = max(R, float(sig.max()))
    if where == 0:
        mean = u * R * rng.uniform(0, 1)                     # inside
    elif where == 1:
        mean = u * (R + rng.normal() * float(sig.max()) * 2)  # near the edge
    elif where == 2:
        mean = u * (R + scale * rng.uniform(1, 10))           # outside / far
    else:
        mean = u * R * rng.uniform(0, 3)
    return mean, S, R


@pytest.mark.parametrize("D", [2, 3])
def test_isotropic_against_the_poisson_series(D):
    rng = np.random.default_rng(7 + D)
    for _ in range(examples(15, 40)):
        s = 10 ** rng.uniform(-3, 2)
        R = 10 ** rng.uniform(-1, 1)
        m = rng.choice(
            [0.0, rng.uniform(0, 2 * R), R + rng.normal() * s, rng.uniform(0, R + 8 * s)]
        )
        m = min(m, 100 * s)  # keeps the series short (noncentrality <= 1e4)
        u = rng.normal(size=D)
        mean = u / np.linalg.norm(u) * m
        got = overlap_probability(mean, s * s * np.eye(D), R)
        ref = isotropic_reference(float(np.linalg.norm(mean)), s, R, D)
        assert abs(got - ref) <= TOL, (mean, s, R, got, ref)


@pytest.mark.parametrize("seed", range(examples(2, 4)))
def test_random_2d_against_mpmath(seed):
    rng = np.random.default_rng(100 + seed)
    worst = 0.0
    for _ in range(40):
        mean, S, R = random_case(rng, 2)
        got = overlap_probability(mean, S, R)
        ref = overlap_reference(mean, S, R)
        worst = max(worst, abs(got - ref))
        assert abs(got - ref) <= TOL, (mean.tolist(), S.tolist(), R, got, ref)
    assert 0.0 <= worst <= TOL


@pytest.mark.stress
@pytest.mark.parametrize("seed", range(3))
def test_random_3d_against_mpmath(seed):
    rng = np.random.default_rng(200 + seed)
    for _ in range(4):
        mean, S, R = random_case(rng, 3)
        got = overlap_probability(mean, S, R)
        ref = overlap_reference(mean, S, R, dps=20)
        assert abs(got - ref) <= TOL, (mean.tolist(), S.tolist(), R, got, ref)


def test_degenerate_covariances_exactly():
    """Zero covariance: the indicator (edge included); rank 1: a 1-D interval."""
    z = np.zeros((2, 2))
    assert overlap_probability(np.array([0.6, 0.8]), z, 1.0) == 1.0
    assert overlap_probability(np.array([0.6, 0.8000001]), z, 1.0) == 0.0
    S = np.array([[0.0, 0.0], [0.0, 4.0]])  # only y uncertain, x exact at 0.6
    w = math.sqrt(1 - 0.36)
    ref = 0.5 * (
        math.erf((w - 0.5) / (2 * math.sqrt(2))) - math.erf((-w - 0.5) / (2 * math.sqrt(2)))
    )
    assert abs(overlap_probability(np.array([0.6, 0.5]), S, 1.0) - ref) <= 1e-15
    assert overlap_probability(np.array([1.5, 0.0]), S, 1.0) == 0.0
    assert overlap_probability(np.zeros(3), np.zeros((3, 3)), 0.5) == 1.0


def test_eigen_decomposition_is_accurate():
    rng = np.random.default_rng(3)
    for n in (2, 3, 4, 6):
        for _ in range(20):
            B = rng.normal(size=(n, n)) * 10 ** rng.uniform(-3, 3, size=n)
            A = B @ B.T
            lam, V = eig_sym(A)
            assert np.all(np.diff(lam) >= 0)
            assert np.abs(V @ np.diag(lam) @ V.T - A).max() <= 1e-13 * np.abs(A).max()
            assert np.abs(V.T @ V - np.eye(n)).max() <= 1e-13


@pytest.mark.parametrize("seed", range(examples(1, 2)))
def test_2d_looser_tolerance_within_its_stated_error(seed):
    """The 2-D plausible-time walk evaluates P at a looser quadrature tolerance
    (core.uncertainty.walk.WALK_TOL_2D; an edge piece whose density mass is <= tol is
    not integrated, its mass counted as its error): within DISC_ERR_PER_TOL x tol of
    the mpmath reference on the random cases above (the far-edge drop is exercised by
    the sigma << R and inside classes), and the standard tolerance's answer unchanged."""
    from circle_collision_ros.core.uncertainty.overlap import (
        DISC_ERR_PER_TOL,
        overlap_probability_tol,
    )

    rng = np.random.default_rng(300 + seed)
    for _ in range(examples(20, 40)):
        mean, S, R = random_case(rng, 2)
        ref = overlap_reference(mean, S, R)
        assert overlap_probability_tol(mean, S, R, 1e-10) == overlap_probability(mean, S, R)
        for tol in (1e-9, 2.5e-8, 1e-7, 1e-6):
            got = overlap_probability_tol(mean, S, R, tol)
            assert abs(got - ref) <= DISC_ERR_PER_TOL * tol, (mean.tolist(), S.tolist(), R, tol,
                                                              got, ref)


def test_2d_looser_tolerance_drops_only_light_edge_pieces():
    """Cases built so that an edge piece is dropped (mean inside, sigma ~ R / 10 to R / 6:
    the far edge is 6-20 sigma away) against the standard tolerance's answer, which
    the tests above prove within 1e-9: within DISC_ERR_PER_TOL x tol + 1e-9."""
    from circle_collision_ros.core.uncertainty.overlap import (
        DISC_ERR_PER_TOL,
        overlap_probability_tol,
    )

    rng = np.random.default_rng(310)
    for _ in range(300):
        R = 10 ** rng.uniform(-1, 1)
        sig = R * rng.uniform(0.1, 0.17, size=2) * 10 ** rng.uniform(-0.5, 0, size=2)
        Q = _rotation(rng, 2)
        S = Q @ np.diag(sig**2) @ Q.T
        u = rng.normal(size=2)
        mean = u / np.linalg.norm(u) * R * rng.uniform(0, 1.3)
        a = overlap_probability(mean, S, R)
        for tol in (2.5e-8, 1e-6):
            b = overlap_probability_tol(mean, S, R, tol)
            assert abs(a - b) <= DISC_ERR_PER_TOL * tol + 1e-9, (mean.tolist(), S.tolist(), R, tol,
                                                                 a, b)


def _ruben_case(rng, D):
    """(R, m, s sorted ascending, tol): sigma 0.06-5 R, means inside to ~3 R out."""
    R = 10 ** rng.uniform(-1, 1)
    s = np.sort(R * 10 ** rng.uniform(-1.2, 0.7, size=D))
    m = rng.normal(size=D) * R * rng.uniform(0, 2.5)
    return R, m, s, 10 ** rng.uniform(-10, -7)


def _ruben(R, m, s, tol, max_terms):
    from circle_collision_ros.core.uncertainty.overlap import ruben_probability

    if len(m) == 2:
        return ruben_probability(R, m[0], s[0], m[1], s[1], 0.0, -1.0, tol, max_terms)
    return ruben_probability(R, m[0], s[0], m[1], s[1], m[2], s[2], tol, max_terms)


# (D, cases) and the cases the default run checks (all under --stress): 3-D's nested
# mpmath reference takes 3-60 s a case; 0 and 3 are the cheap ones.
RUBEN_DEFAULT = {2: range(0, 60, 3), 3: (0, 3)}


@pytest.mark.parametrize("D, cases", [(2, 60), (3, 8)])
def test_ruben_mixture_within_its_stated_error(D, cases):
    """Ruben's chi-square mixture (the fast path of the instantaneous probability):
    where it decides, the mpmath reference lies within its stated error above it
    (it returns the bracket's lower end), which is at most tol + RUBEN_ROUNDING
    (the bracket is rigorous: the mixture's weights are a probability
    distribution and F_{n+2k} falls with k).  Most cases of this class (sigma
    0.06-5 R, axis ratios up to ~80) decide within the 3-D budget; the others
    answer (nan, -1).  Default run: the cases in RUBEN_DEFAULT; --stress: all."""
    from circle_collision_ros.core.uncertainty.overlap import RUBEN_MAX_TERMS_3D, RUBEN_ROUNDING
    from tests.core.uncertainty.uncertainty_reference import independent_reference

    rng = np.random.default_rng(400 + D)
    decided = 0
    checked = range(cases) if STRESS else RUBEN_DEFAULT[D]
    for k in range(cases):
        R, m, s, tol = _ruben_case(rng, D)
        if k not in checked:
            continue
        v, err = _ruben(R, m, s, tol, RUBEN_MAX_TERMS_3D)
        if err == -1.0 and math.isnan(v):
            continue
        decided += 1
        assert 0.0 <= err <= tol + RUBEN_ROUNDING, (R, m.tolist(), s.tolist(), tol, err)
        ref = independent_reference(R, m, s, dps=30 if D == 2 else 20)
        assert abs(v - ref) <= err, (R, m.tolist(), s.tolist(), tol, v, err, ref)
        assert v <= ref + RUBEN_ROUNDING  # the bracket's lower end
    assert decided >= 0.6 * len(checked)


def test_ruben_mixture_gives_way_where_it_would_not_close():
    """Outside its regime the mixture answers (nan, -1) and the quadrature takes
    over: sigma << R (x = (R / s1)^2 huge) with the mean near the edge, very
    unequal sigmas (a slow geometric tail), a mean far out in sigmas; and
    overlap_probability is then still within 1e-9 of mpmath."""
    from circle_collision_ros.core.uncertainty.overlap import RUBEN_MAX_TERMS_2D

    cases = [(1.0, np.array([1.0, 0.0]), np.array([0.01, 0.02])),
             (1.0, np.array([0.5, 0.5]), np.array([1e-3, 3.0])),
             (1.0, np.array([30.0, 0.0]), np.array([0.5, 0.6]))]
    for R, m, s in cases:
        v, err = _ruben(R, m, s, 1e-10, RUBEN_MAX_TERMS_2D)
        assert err == -1.0 and math.isnan(v)
        got = overlap_probability(m, np.diag(s**2), R)
        assert abs(got - overlap_reference(m, np.diag(s**2), R)) <= TOL


def test_ruben_mixture_rounding_is_far_below_its_allowance():
    """With the bracket closed to 1e-16 the mixture's value is within 1e-13 of 40-digit
    mpmath on 40 random 2-D cases (--stress; the first 15 by default; measured: ~1e-15), two orders
    of magnitude inside
    the RUBEN_ROUNDING = 1e-12 its stated error adds for rounding."""
    from circle_collision_ros.core.uncertainty.overlap import RUBEN_ROUNDING
    from tests.core.uncertainty.uncertainty_reference import independent_reference

    rng = np.random.default_rng(9)
    for _ in range(examples(15, 40)):
        R = 10 ** rng.uniform(-1, 1)
        s = np.sort(R * 10 ** rng.uniform(-0.8, 0.3, size=2))
        m = rng.normal(size=2) * R
        v, err = _ruben(R, m, s, 1e-16, 256)
        assert 0.0 <= err <= 1e-16 + RUBEN_ROUNDING
        assert abs(v - independent_reference(R, m, s, dps=40)) <= 1e-13, (R, m.tolist(), s.tolist())


def _narrow_case(rng, k):
    """(R, m, s) with s1 <= s2 <= s3 <= R / 8, a mean near the sphere (the walk's
    regime), near the centre or on an axis; isotropic, mildly or strongly anisotropic."""
    R = 10 ** rng.uniform(-1, 1)
    kind = k % 4
    if kind == 0:
        s = 10 ** rng.uniform(-3.5, -0.9, 3) * R
    elif kind == 1:
        s = np.full(3, 10 ** rng.uniform(-3.0, -0.9)) * R * (1 + 0.3 * rng.random(3))
    elif kind == 2:
        s = 10 ** rng.uniform(-2.5, -0.9, 3) * R
        s[0] = s[1] * 10 ** rng.uniform(-3, 0)
    else:
        s = np.r_[10 ** rng.uniform(-4, -2), 10 ** rng.uniform(-1.5, -0.9, 2)] * R
    s = np.sort(s)
    d = rng.normal(size=3)
    d /= np.linalg.norm(d)
    if k % 7 == 0:
        d = np.eye(3)[rng.integers(3)] * rng.choice([-1.0, 1.0])
    m = d * (R + rng.normal() * rng.choice([1.0, 3.0, 8.0]) * s[2])
    if k % 11 == 0:
        m = rng.normal(size=3) * s[2] * 3.0
    return R, m, s


def test_narrow_ball_rule_against_the_quadrature():
    """The narrow balls' Gauss-Hermite chord rule (``ball_gauss_hermite``), wherever
    its estimate is accepted (<= the standard tolerance 1e-10), is within 1e-9 of the
    quadrature at 1e-12 (itself proven against mpmath above) on 1,200 random narrow
    cases (--stress; the first 400 by default); ball_probability agrees with the quadrature on all
    of them (accepted or
    not); the rule is taken on a good share of them."""
    from circle_collision_ros.core.uncertainty.overlap import (TOL, ball_gauss_hermite, narrow3,
                                                               ball_probability)

    rng = np.random.default_rng(61)
    used = 0
    cases = examples(400, 1200)  # the first 400 of the same cases in the default run
    for k in range(cases):
        R, m, s = _narrow_case(rng, k)
        args = (R, m[0], s[0], m[1], s[1], m[2], s[2])
        ref = min(1.0, max(0.0, narrow3(*args, 1e-12)[0]))
        v, err = ball_gauss_hermite(*args)
        if 0.0 <= err <= TOL:
            used += 1
            assert abs(v - ref) <= TOL, (k, args, v, ref, err)
        got = ball_probability(*args)
        assert abs(got - ref) <= TOL, (k, args, got, ref)
    assert used >= cases // 3, used


@pytest.mark.stress
def test_narrow_ball_rule_against_mpmath():
    """Accepted narrow cases (isotropic and anisotropic, means on and off the sphere)
    against the mpmath references: the Poisson series (isotropic) and the nested
    mpmath quadrature (independent components)."""
    from circle_collision_ros.core.uncertainty.overlap import (TOL, ball_gauss_hermite,
                                                               ball_probability)
    from tests.core.uncertainty.uncertainty_reference import independent_reference

    rng = np.random.default_rng(62)
    iso = 0
    aniso = 0
    while iso < 12 or aniso < 2:
        R = 10 ** rng.uniform(-1, 1)
        if iso < 12:
            s = np.full(3, 10 ** rng.uniform(-3.0, -1.0) * R)
        else:
            s = np.sort(10 ** rng.uniform(-2.5, -1.0, 3) * R)
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        m = d * (R + rng.normal() * 2.0 * s[2])
        args = (R, m[0], s[0], m[1], s[1], m[2], s[2])
        v, err = ball_gauss_hermite(*args)
        if not (0.0 <= err <= TOL):
            continue
        got = ball_probability(*args)
        if iso < 12:
            ref = isotropic_reference(float(np.linalg.norm(m)), float(s[0]), R, 3)
            iso += 1
        else:
            ref = independent_reference(R, m, s, dps=20)
            aniso += 1
        assert abs(got - ref) <= TOL, (args, got, ref)


def test_narrow_ball_rule_refuses_a_step():
    """Where the conditional deviation along the mean's direction is small against the
    spread of its mean (y_u nearly a function of y_perp), the integrand is a near step in
    the whitened coordinates and both rules gave exactly 1/2 (estimate 6e-17, error
    0.056): the steepness guard refuses it and the quadrature answers."""
    from circle_collision_ros.core.uncertainty.overlap import (ball_gauss_hermite, narrow3,
                                                               ball_probability)

    R = 7.056586188687591
    m = (-1.80309479, 0.89583906, -6.86923166)
    s = (0.00341824, 0.00568482, 0.7550208)
    args = (R, m[0], s[0], m[1], s[1], m[2], s[2])
    assert ball_gauss_hermite(*args)[1] < 0.0
    ref = narrow3(*args, 1e-12)[0]
    assert abs(ball_probability(*args) - ref) <= TOL
    assert abs(ref - 0.5) > 0.01  # the value the unguarded rules agreed on was wrong
