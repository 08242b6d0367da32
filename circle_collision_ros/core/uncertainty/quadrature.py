"""Adaptive Gauss-Kronrod-Patterson (7/15/31) quadrature for numba code.

``make_adaptive(fn)(prm, a, b, tol)`` integrates ``fn(x, prm)`` over [a, b] with
the 15-point Kronrod rule on panels; where |K15 - G7| exceeds the panel's share
of ``tol`` (share proportional to its width) it extends the same panel to
Patterson's 31-point rule (16 more values) and takes |P31 - K15| as the
estimate; only where that also exceeds the share does it split the panel in two,
down to ``MAX_DEPTH`` halvings.  It returns ``(value, err)`` with err the sum
of the accepted panels' estimates -- for smooth integrands a gross
over-estimate of the true error (P31 is exact for polynomials of degree 46,
K15 of degree 22, G7 of degree 13), which is why it serves as the stated
quadrature error.  (|K15 - G7| is often ~100x K15's error on a panel much
wider than a peak at its end; P31 settles most such panels for 16 values where
two K15 halves cost 30.)  A
feature much narrower than a panel that no node of the panel sees is not
detected by any such rule: callers place panels so that every peak of the
integrand lies at a panel end (see overlap_probability, entry_rate).

``make_adaptive_nested(fn, last_inner)(prm, a, b, tol)`` is the same rule for an
integrand that is itself an integral, but judges a K15 panel by ``k15_error``
(QUADPACK's rescaled estimate; the whole value on a panel that few nodes
resolve) instead of |K15 - G7|: ``last_inner(prm)`` returns the error
estimate of fn's latest evaluation, and the rule returns ``(value, err,
inner)`` with inner = the accepted panels' sum of those estimates weighted by
the accepted rule (K15 or P31; the outer rule applied to the inner errors: all
weights are positive, so this is the integral of the inner error as the rule
sees it, not the width times its largest value).

Deterministic: the panel order is fixed (depth first, left to right) and no
state is kept between calls.  ``fn`` is any ``@njit`` function.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["make_adaptive", "make_adaptive_angle", "make_adaptive_nested", "push_halves",
           "MAX_DEPTH", "K15_NODES", "K15_WEIGHTS", "G7_WEIGHTS", "P31_K15_WEIGHTS",
           "P31_NEW_NODES", "P31_NEW_WEIGHTS", "P31_NODES", "P31_K15_POS", "P31_NEW_POS",
           "subinterval_integral", "k15_error", "K15_MIN_NODES"]

# QUADPACK's dqk15 abscissae and weights (tests/core/uncertainty/test_uncertainty_quadrature.py
# checks them against mpmath's Gauss-Legendre nodes and polynomial exactness).
_XGK = np.array(
    [0.991455371120812639206854697526329, 0.949107912342758524526189684047851,
     0.864864423359769072789712788640926, 0.741531185599394439863864773280788,
     0.586087235467691130294144845693013, 0.405845151377397166906606412076961,
     0.207784955007898467600689403773245, 0.000000000000000000000000000000000]
)
_WGK = np.array(
    [0.022935322010529224963732008058970, 0.063092092629978553290700663189204,
     0.104790010322250183839876322541518, 0.140653259715525918745189590510238,
     0.169004726639267902826583426598550, 0.190350578064785409913256402421014,
     0.204432940075298892414161999234649, 0.209482141084727828012999174891714]
)
_WG = np.array(
    [0.129484966168869693270611432679082, 0.279705391489276667901467771423780,
     0.381830050505118944950369775488975, 0.417959183673469387755102040816327]
)

MAX_DEPTH = 40

# Patterson's extension of K15 to 31 nodes (P31): K15's 15 nodes plus the 16 roots
# of the degree-16 polynomial orthogonal to every polynomial of degree < 16 under
# the weight prod_i (x - x_i) over K15's nodes, with interpolatory weights (all
# positive; exact to degree 46).  Computed with 80-digit mpmath from K15's double
# nodes (Patterson, Math. Comp. 22, 1968, for the construction); the new nodes in
# descending order, their weights, and P31's weights at _XGK's nodes (centre
# last).  tests/core/uncertainty/test_uncertainty_quadrature.py checks exactness and nesting.
# A caller that kept a failed panel's 15 values gets P31 for 16 more evaluations,
# where two K15 halves cost 30, and |P31 - K15| estimates K15's error.
_XP = np.array(
    [0.998687109678466736856163991655745, 0.975383588208893309378361848952381,
     0.912204882783262879480605349911247, 0.807688939172437535290584967355574,
     0.667348098104300192207894772374814, 0.498636786552832022580976520528730,
     0.308579247910587794455515921297326, 0.104528273810780721560468847483968]
)
_WP_NEW = np.array(
    [0.00363493119504988336900140830212555, 0.0210394462587267987276830963868583,
     0.0421935005845465604686166305828589, 0.0618219856454498606464231479107728,
     0.0778753471152459973200931565030062, 0.0902618021465586024682586951838610,
     0.0991968576674329142408250773477446, 0.104099955472697361899485819349970]
)
_WP_K = np.array(
    [0.0113194684446834888743013129247231, 0.0315777062170458184272064104349905,
     0.0523843708209826812931727210357308, 0.0703320464104006567387747094909071,
     0.0844987653012430197430705039693262, 0.0951780299318306817349781830783723,
     0.102214180005702747261601665971035, 0.104743213564805853573014923055435]
)

# The same rule as 15 nodes in ascending order on [-1, 1] (G7's weights zero at
# the Kronrod-only nodes), for callers that keep the values (``panel_k15``).
K15_NODES = np.concatenate((-_XGK[:7], [0.0], _XGK[6::-1]))
K15_WEIGHTS = np.concatenate((_WGK[:7], [_WGK[7]], _WGK[6::-1]))
G7_WEIGHTS = np.zeros(15)
G7_WEIGHTS[1:7:2] = _WG[:3]
G7_WEIGHTS[7] = _WG[3]
G7_WEIGHTS[9:15:2] = _WG[2::-1]
# P31 in the same form: its weights at K15_NODES, and its 16 other nodes (ascending)
# with their weights
P31_K15_WEIGHTS = np.concatenate((_WP_K[:7], [_WP_K[7]], _WP_K[6::-1]))
P31_NEW_NODES = np.concatenate((-_XP, _XP[::-1]))
P31_NEW_WEIGHTS = np.concatenate((_WP_NEW, _WP_NEW[::-1]))


def _legendre_table(x: np.ndarray, n: int) -> np.ndarray:
    """(len(x), n): P_k(x_i), k < n (three-term recurrence)."""
    P = np.empty((x.size, n))
    P[:, 0] = 1.0
    if n > 1:
        P[:, 1] = x
    for k in range(1, n - 1):
        P[:, k + 1] = ((2 * k + 1) * x * P[:, k] - k * P[:, k - 1]) / (k + 1)
    return P


# Legendre coefficients of the polynomial interpolating the 15 values (degree
# 14): K15's nodes are close to Chebyshev-distributed, so the solve is well
# conditioned (cond 6.4); tests/core/uncertainty/test_uncertainty_quadrature.py checks it.
K15_TO_LEGENDRE = np.linalg.inv(_legendre_table(K15_NODES, 15))
# The same for P31's 31 nodes in ascending order (degree 30; cond 10.3)
P31_NODES = np.sort(np.concatenate((K15_NODES, P31_NEW_NODES)))
P31_K15_POS = np.searchsorted(P31_NODES, K15_NODES)  # where K15's nodes and the new ones sit in it
P31_NEW_POS = np.searchsorted(P31_NODES, P31_NEW_NODES)
P31_TO_LEGENDRE = np.linalg.inv(_legendre_table(P31_NODES, 31))
_STACK = MAX_DEPTH + 2


@njit(cache=True, error_model="numpy", inline="always")
def push_halves(sa, sb, sd, top, a, m, b, d):
    """Push [m, b] then [a, m] (depth d + 1) on the interval stack; returns
    the new top.  The left half ends on top, so intervals are processed left
    to right (depth first)."""
    sa[top] = m
    sb[top] = b
    sd[top] = d + 1
    sa[top + 1] = a
    sb[top + 1] = m
    sd[top + 1] = d + 1
    return top + 2


def _make_driver(rule):
    """The adaptive loop over ``rule(prm, a, b, share) -> (value, err, inner)``; a panel
    is accepted when err <= share, its share of the tolerance (a rule may use share
    to try a higher order on the same panel before the loop splits it)."""

    @njit(cache=True, error_model="numpy")
    def adaptive(prm, a, b, tol):
        if not (b > a):
            return 0.0, 0.0, 0.0
        # the whole interval first, without the stack: most calls end here, and
        # the three stack arrays (allocated below) cost more than the rule itself
        # on the innermost levels; the same panels in the same order either way
        val, e, ie = rule(prm, a, b, tol)
        m = 0.5 * (a + b)
        if not (e > tol) or not (a < m < b):
            return val, e, ie
        width = b - a
        sa = np.empty(_STACK)
        sb = np.empty(_STACK)
        sd = np.empty(_STACK, dtype=np.int64)
        top = push_halves(sa, sb, sd, 0, a, m, b, 0)
        total = 0.0
        err = 0.0
        inner = 0.0
        while top > 0:
            top -= 1
            pa = sa[top]
            pb = sb[top]
            d = sd[top]
            share = tol * ((pb - pa) / width)
            val, e, ie = rule(prm, pa, pb, share)
            m = 0.5 * (pa + pb)
            # (a NaN estimate is accepted: never split without end)
            if not (e > share) or d >= MAX_DEPTH or not (pa < m < pb):
                total += val
                err += e
                inner += ie
            else:
                top = push_halves(sa, sb, sd, top, pa, m, pb, d)
        return total, err, inner

    return adaptive


def _value_and_error(driver):
    """``adaptive(prm, a, b, tol) -> (integral, error estimate)`` from a driver of a
    rule without inner errors."""

    @njit(cache=True, error_model="numpy")
    def adaptive(prm, a, b, tol):
        v, e, _ = driver(prm, a, b, tol)
        return v, e

    return adaptive


def make_adaptive(fn):
    """``adaptive(prm, a, b, tol) -> (integral, error estimate)`` of
    ``fn(x, prm)`` over [a, b] (a <= b), see the module doc.

    One compiled integrator per integrand: a closure over ``fn`` rather than
    a first-class function argument, which numba cannot cache on disk."""

    @njit(cache=True, error_model="numpy")
    def gk15(prm, a, b, share):
        """(K15, |K15 - G7|, 0) of fn over [a, b]; when |K15 - G7| > share,
        (P31, |P31 - K15|, 0) with 16 more values."""
        c = 0.5 * (a + b)
        h = 0.5 * (b - a)
        fc = fn(c, prm)
        k = fc * _WGK[7]
        g = fc * _WG[3]
        p = fc * _WP_K[7]
        for j in range(7):
            dx = h * _XGK[j]
            s = fn(c - dx, prm) + fn(c + dx, prm)
            k += _WGK[j] * s
            p += _WP_K[j] * s
            if j % 2 == 1:
                g += _WG[j // 2] * s
        if not (abs((k - g) * h) > share):
            return k * h, abs((k - g) * h), 0.0
        for j in range(8):
            dx = h * _XP[j]
            p += _WP_NEW[j] * (fn(c - dx, prm) + fn(c + dx, prm))
        return p * h, abs((p - k) * h), 0.0

    return _value_and_error(_make_driver(gk15))


def make_adaptive_angle(fn):
    """``adaptive(prm, a, b, tol) -> (integral, error estimate)`` of ``fn(c, s, prm)``
    over the angle psi in [a, b], where c, s = cos(psi), sin(psi): make_adaptive's
    rule (the same nodes, weights, panels and order), but each panel computes
    cos/sin of its centre and of its 7 node offsets only (8 more for P31), and
    forms the node values by the angle-addition formulas: 8 cos/sin pairs per
    K15 instead of 15 (the integrand's dominant cost on the 2-D arc).  The formulas' rounding
    (a few ulps of the direction, the same on every machine) moves no result
    beyond the quadrature's own error estimate."""

    @njit(cache=True, error_model="numpy")
    def gk15(prm, a, b, share):
        """(K15, |K15 - G7|, 0) of fn over [a, b]; when |K15 - G7| > share,
        (P31, |P31 - K15|, 0) with 16 more values (two K15 halves cost 30)."""
        c = 0.5 * (a + b)
        h = 0.5 * (b - a)
        cc = math.cos(c)
        sc = math.sin(c)
        fc = fn(cc, sc, prm)
        k = fc * _WGK[7]
        g = fc * _WG[3]
        p = fc * _WP_K[7]
        for j in range(7):
            dx = h * _XGK[j]
            cd = math.cos(dx)
            sd = math.sin(dx)
            # cos/sin of c - dx and of c + dx
            s = fn(cc * cd + sc * sd, sc * cd - cc * sd, prm) + fn(
                cc * cd - sc * sd, sc * cd + cc * sd, prm
            )
            k += _WGK[j] * s
            p += _WP_K[j] * s
            if j % 2 == 1:
                g += _WG[j // 2] * s
        if not (abs((k - g) * h) > share):
            return k * h, abs((k - g) * h), 0.0
        for j in range(8):
            dx = h * _XP[j]
            cd = math.cos(dx)
            sd = math.sin(dx)
            s = fn(cc * cd + sc * sd, sc * cd - cc * sd, prm) + fn(
                cc * cd - sc * sd, sc * cd + cc * sd, prm
            )
            p += _WP_NEW[j] * s
        return p * h, abs((p - k) * h), 0.0

    return _value_and_error(_make_driver(gk15))


def make_adaptive_nested(fn, last_inner):
    """``adaptive(prm, a, b, tol) -> (integral, error estimate, weighted inner
    error)`` of ``fn(x, prm)``, an integrand whose own error estimate
    ``last_inner(prm)`` reads after each evaluation (module doc).  A K15 panel
    is judged by QUADPACK's estimate (``k15_error``), not |K15 - G7| alone: the
    entry rate over a panel of a tube interval is a bump that K15 and G7 can
    both miss alike when it falls between their nodes."""

    @njit(cache=True, error_model="numpy")
    def gk15(prm, a, b, share):
        """(K15, k15_error, K15 of the inner errors) of fn over [a, b]; when
        that estimate > share, (P31, |P31 - K15|, P31 of the inner errors)."""
        c = 0.5 * (a + b)
        h = 0.5 * (b - a)
        f15 = np.empty(15)  # the values at K15_NODES (ascending), for k15_error
        fc = fn(c, prm)
        f15[7] = fc
        ec = last_inner(prm)
        ie = ec * _WGK[7]
        iep = ec * _WP_K[7]
        k = fc * _WGK[7]
        g = fc * _WG[3]
        p = fc * _WP_K[7]
        for j in range(7):
            dx = h * _XGK[j]
            f1 = fn(c - dx, prm)
            e1 = last_inner(prm)
            f2 = fn(c + dx, prm)
            e2 = last_inner(prm)
            f15[j] = f1
            f15[14 - j] = f2
            s = f1 + f2
            k += _WGK[j] * s
            p += _WP_K[j] * s
            ie += _WGK[j] * (e1 + e2)
            iep += _WP_K[j] * (e1 + e2)
            if j % 2 == 1:
                g += _WG[j // 2] * s
        est = k15_error(f15, h, k * h, abs((k - g) * h))
        if not (est > share):
            return k * h, est, ie * h
        for j in range(8):
            dx = h * _XP[j]
            f1 = fn(c - dx, prm)
            e1 = last_inner(prm)
            f2 = fn(c + dx, prm)
            e2 = last_inner(prm)
            p += _WP_NEW[j] * (f1 + f2)
            iep += _WP_NEW[j] * (e1 + e2)
        return p * h, abs((p - k) * h), iep * h

    return _make_driver(gk15)


@njit(cache=True, error_model="numpy")
def _legendre_antiderivative(coef, x):
    """int_{-1}^{x} sum_k coef[k] P_k
    (int P_0 = x + 1; int P_k = (P_{k+1} - P_{k-1}) / (2k + 1))."""
    n = coef.shape[0]
    p_prev = 1.0  # P_0
    p = x  # P_1
    total = coef[0] * (x + 1.0)
    for k in range(1, n):
        p_next = ((2 * k + 1) * x * p - k * p_prev) / (k + 1)  # P_{k+1}
        total += coef[k] * (p_next - p_prev) / (2 * k + 1)
        p_prev = p
        p = p_next
    return total


@njit(cache=True, error_model="numpy")
def subinterval_integral(f, xl, xr):
    """(integral over [xl, xr] of the degree-14 polynomial p15 through the 15
    values f at K15_NODES, an error estimate) for -1 <= xl <= xr <= 1
    (unit-interval coordinates: multiply both by the half-width).  Over
    [-1, 1] the value is K15 of f.  With 31 values f at P31_NODES: the same
    with the degree-30 interpolant (over [-1, 1]: P31 of f) and its last four
    coefficients (k = 27..30).

    The estimate is (xr - xl) * sum of |c_k| over p15's last four Legendre
    coefficients (k = 11..14): the spectral tail, as Chebfun judges a
    truncation (|P_k| <= 1, so a series whose coefficients keep decaying
    geometrically beyond k = 14 with ratio below ~0.75 differs from p15 by less
    than that sum anywhere).  A heuristic like |K15 - G7| (a function that p15
    does not resolve shows as a large tail), far above the true error on
    smooth integrands; the interpolant of the 7 Gauss values would not do
    (its pointwise error is orders of magnitude above G7's quadrature error)."""
    n = f.shape[0]
    T = K15_TO_LEGENDRE if n == 15 else P31_TO_LEGENDRE
    c = np.zeros(n)
    for k in range(n):
        a = 0.0
        for i in range(n):
            a += T[k, i] * f[i]
        c[k] = a
    value = _legendre_antiderivative(c, xr) - _legendre_antiderivative(c, xl)
    tail = abs(c[n - 4]) + abs(c[n - 3]) + abs(c[n - 2]) + abs(c[n - 1])
    return value, (xr - xl) * tail


# A K15 panel counts as resolved when at least K15_MIN_NODES of its 15 values are at
# least _SIGNIFICANT of the largest (k15_error): a bump that spans fewer nodes is one the
# rule's estimates cannot judge
K15_MIN_NODES = 6
_SIGNIFICANT = 1e-3


@njit(cache=True, error_model="numpy")
def k15_error(f, h, value, diff):
    """QUADPACK's error estimate of a K15 (dqk15): f the 15 values at K15_NODES, h the
    half-width, value the K15 integral, diff = |K15 - G7|; returns
    max(diff, resasc min(1, (200 diff / resasc)^1.5)), resasc = h sum w_i |f_i - value / 2h|;
    on a panel that is not resolved, max(diff, |value|).

    |K15 - G7| alone can fall below the error where K15 and G7 agree by chance on a
    peaked integrand (a 2-D pair's entry rate whose peak sits between nodes: K15 off by
    9.7e-4 with |K15 - G7| = 4.3e-4); QUADPACK's rescaling (Piessens et al., QUADPACK,
    1983, section 2.2.1) grows a large difference relative to the integrand's spread, and the
    max keeps it never below |K15 - G7|.

    Neither sees a feature that only a few nodes sample, such as an entry rate whose bump
    fills the first tenth of a long panel (tests/core/uncertainty/test_uncertainty_horizon.py,
    BUMP_AT_START_PAIR).  Where fewer than K15_MIN_NODES values are at least _SIGNIFICANT of
    the largest, the whole value is the estimate, so the panel goes on to P31 or halves unless
    its integral is itself within the tolerance (a tail panel)."""
    fmax = 0.0
    for i in range(15):
        fmax = max(fmax, abs(f[i]))
    seen = 0
    for i in range(15):
        if abs(f[i]) >= _SIGNIFICANT * fmax:
            seen += 1
    if seen < K15_MIN_NODES:
        return max(diff, abs(value))
    mean = value / (2.0 * h) if h > 0.0 else 0.0
    resasc = 0.0
    for i in range(15):
        resasc += K15_WEIGHTS[i] * abs(f[i] - mean)
    resasc *= h
    if resasc > 0.0 and diff > 0.0:
        return max(diff, resasc * min(1.0, (200.0 * diff / resasc) ** 1.5))
    return diff
