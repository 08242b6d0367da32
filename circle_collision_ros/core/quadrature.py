"""Adaptive Gauss-Kronrod (7/15) quadrature for numba code.

``make_adaptive(fn)(prm, a, b, tol)`` integrates ``fn(x, prm)`` over [a, b] with
the 15-point Kronrod rule on panels, splitting a panel in two while
|K15 - G7| exceeds its share of ``tol`` (share proportional to its width),
down to ``MAX_DEPTH`` halvings.  It returns ``(value, err)`` with err the sum
of the accepted panels' |K15 - G7| -- for smooth integrands a gross
over-estimate of the true error (K15 is exact for polynomials of degree 22,
G7 of degree 13), which is why it serves as the stated quadrature error.  A
feature much narrower than a panel that no node of the panel sees is not
detected by any such rule: callers place panels so that every peak of the
integrand lies at a panel end (see overlap_probability, entry_rate).

Deterministic: the panel order is fixed (depth first, left to right) and no
state is kept between calls.  ``fn`` is any ``@njit`` function.
"""
from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["make_adaptive", "push_halves", "MAX_DEPTH"]

# QUADPACK's dqk15 abscissae and weights (tests/core/test_uncertainty_quadrature.py
# checks them against mpmath's Gauss-Legendre nodes and polynomial exactness).
_XGK = np.array([0.991455371120812639206854697526329, 0.949107912342758524526189684047851,
                 0.864864423359769072789712788640926, 0.741531185599394439863864773280788,
                 0.586087235467691130294144845693013, 0.405845151377397166906606412076961,
                 0.207784955007898467600689403773245, 0.000000000000000000000000000000000])
_WGK = np.array([0.022935322010529224963732008058970, 0.063092092629978553290700663189204,
                 0.104790010322250183839876322541518, 0.140653259715525918745189590510238,
                 0.169004726639267902826583426598550, 0.190350578064785409913256402421014,
                 0.204432940075298892414161999234649, 0.209482141084727828012999174891714])
_WG = np.array([0.129484966168869693270611432679082, 0.279705391489276667901467771423780,
                0.381830050505118944950369775488975, 0.417959183673469387755102040816327])

MAX_DEPTH = 40
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


def make_adaptive(fn):
    """``adaptive(prm, a, b, tol) -> (integral, error estimate)`` of
    ``fn(x, prm)`` over [a, b] (a <= b), see the module doc.

    One compiled integrator per integrand: a closure over ``fn`` rather than
    a first-class function argument, which numba cannot cache on disk."""

    @njit(cache=True, error_model="numpy")
    def gk15(prm, a, b):
        """(K15, |K15 - G7|) of fn over [a, b]."""
        c = 0.5 * (a + b)
        h = 0.5 * (b - a)
        fc = fn(c, prm)
        k = fc * _WGK[7]
        g = fc * _WG[3]
        for j in range(7):
            dx = h * _XGK[j]
            s = fn(c - dx, prm) + fn(c + dx, prm)
            k += _WGK[j] * s
            if j % 2 == 1:
                g += _WG[j // 2] * s
        return k * h, abs((k - g) * h)

    @njit(cache=True, error_model="numpy")
    def adaptive(prm, a, b, tol):
        if not (b > a):
            return 0.0, 0.0
        # the whole interval first, without the stack: most calls end here, and
        # the three stack arrays (allocated below) cost more than the rule itself
        # on the innermost levels; the same panels in the same order either way
        val, e = gk15(prm, a, b)
        m = 0.5 * (a + b)
        if not (e > tol) or not (a < m < b):
            return val, e
        width = b - a
        sa = np.empty(_STACK)
        sb = np.empty(_STACK)
        sd = np.empty(_STACK, dtype=np.int64)
        top = push_halves(sa, sb, sd, 0, a, m, b, 0)
        total = 0.0
        err = 0.0
        while top > 0:
            top -= 1
            pa = sa[top]
            pb = sb[top]
            d = sd[top]
            val, e = gk15(prm, pa, pb)
            m = 0.5 * (pa + pb)
            # (a NaN estimate is accepted: never split without end)
            if not (e > tol * ((pb - pa) / width)) or d >= MAX_DEPTH or not (pa < m < pb):
                total += val
                err += e
            else:
                top = push_halves(sa, sb, sd, top, pa, m, pb, d)
        return total, err

    return adaptive
