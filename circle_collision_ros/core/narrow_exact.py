"""Exact-rational decision of the first-contact time (the narrow phase's fallback).

Float64 inputs are dyadic rationals, so the relative state
``dp, dv, da, R`` and the power-basis coefficients of

    f(t) = |dp + t dv + t^2 da / 2|^2 - R^2 = c4 t^4 + c3 t^3 + c2 t^2 + c1 t + c0

are exact rationals (``fractions.Fraction``).  Everything below is decided
exactly on them, with no rounding anywhere before the final one:

* Order of contact at t = 0 (``f(0) = 0``, touching): the first nonzero
  coefficient of ``c1, c2, c3, c4`` is the sign of f just after 0.  Negative:
  the bodies interpenetrate immediately (approaching) -> 0.  Positive: they
  separate; the answer is the next root of f in (0, H].  All zero (``f`` is
  identically 0: touching for all time, never approaching) -> inf.
* Roots in (0, H]: a Sturm sequence of the square-free part of ``f / t^k``
  (k = the order of the root at 0) counts the distinct real roots in any
  interval exactly; double roots (tangent grazes, point bodies whose paths
  cross) count like any other root.
* The returned time is the first root rounded to the nearest float64 (ties to
  even), found by bisection over float64 bit patterns in (0, H]: the root
  count on (0, x] is monotone in x.  A positive root is never rounded to 0.

Cost: ~1-5 ms per row in plain Python; the batch kernels call it only for
rows their certified float64/double-double paths leave undecided.
"""
from __future__ import annotations

import math
import struct
from fractions import Fraction
from typing import Sequence

__all__ = ["exact_first_contact"]

_MAX_BITS = 0x7FEFFFFFFFFFFFFF  # bit pattern of the largest finite float64
_MAX_INPUT = 1e150  # the narrow phase's documented input range


def _bits(x: float) -> int:
    return struct.unpack("<q", struct.pack("<d", x))[0]


def _float(b: int) -> float:
    return struct.unpack("<d", struct.pack("<q", b))[0]


def _trim(p: list) -> list:
    """Drop zero leading (highest-degree) coefficients; coefficients ascending."""
    while p and p[-1] == 0:
        p = p[:-1]
    return p


def _rem(a: list, b: list) -> list:
    """Remainder of a / b (ascending coefficients, exact)."""
    a = list(a)
    db = len(b) - 1
    lead = b[-1]
    while len(a) - 1 >= db and a:
        k = Fraction(a[-1]) / lead
        shift = len(a) - 1 - db
        for i, c in enumerate(b):
            a[shift + i] -= k * c
        a = _trim(a[:-1])
    return a


def _quo(a: list, b: list) -> list:
    """Exact quotient of a / b when b divides a (ascending coefficients)."""
    a = list(a)
    db = len(b) - 1
    out = [Fraction(0)] * (len(a) - db)
    while len(a) - 1 >= db and a:
        k = Fraction(a[-1]) / b[-1]
        shift = len(a) - 1 - db
        out[shift] = k
        for i, c in enumerate(b):
            a[shift + i] -= k * c
        a = _trim(a[:-1])
    return out


def _deriv(p: list) -> list:
    return [i * c for i, c in enumerate(p)][1:]


def _gcd(a: list, b: list) -> list:
    while b:
        a, b = b, _rem(a, b)
    return a


def _eval(p: list, x: Fraction) -> Fraction:
    r = Fraction(0)
    for c in reversed(p):
        r = r * x + c
    return r


def _sturm(p: list) -> list:
    seq = [p, _deriv(p)]
    while seq[-1]:
        r = _rem(seq[-2], seq[-1])
        if not r:
            break
        seq.append([-c for c in r])
    return [s for s in seq if s]


def _variations(signs) -> int:
    last = 0
    v = 0
    for s in signs:
        if s != 0:
            if last != 0 and s != last:
                v += 1
            last = s
    return v


def _sign(x) -> int:
    return (x > 0) - (x < 0)


class _Roots:
    """Root counting on (0, x] for a polynomial with p(0) != 0 (exact)."""

    def __init__(self, p: list):
        g = _gcd(p, _deriv(p))
        self.p = _quo(p, g) if len(g) > 1 else p  # square-free part
        self.seq = _sturm(self.p)
        self.v0 = _variations(_sign(s[0]) for s in self.seq)

    def v(self, x: Fraction) -> int:
        return _variations(_sign(_eval(s, x)) for s in self.seq)

    def v_inf(self) -> int:
        return _variations(_sign(s[-1]) for s in self.seq)

    def any_upto(self, x: Fraction) -> bool:
        """Some root in (0, x] (x > 0)."""
        if _eval(self.p, x) == 0:
            return True
        return self.v0 - self.v(x) > 0


def _rel(x: Sequence[float], y: Sequence[float]) -> list:
    return [Fraction(float(a)) - Fraction(float(b)) for a, b in zip(x, y)]


def exact_first_contact(p_a: Sequence[float], v_a: Sequence[float], a_a: Sequence[float], r_a: float,
                        p_b: Sequence[float], v_b: Sequence[float], a_b: Sequence[float], r_b: float,
                        horizon: float = math.inf) -> float:
    """First-contact time of one pair decided in exact rational arithmetic.

    Same contract as ``time_to_collision`` for valid input (finite values,
    radii >= 0, horizon >= 0): 0.0 for overlap or an approaching touch at
    t = 0 (order-of-contact rule in the module docstring); else the first
    contact time in (0, horizon] rounded to nearest float64; inf if none.
    """
    vals = [float(x) for x in (*p_a, *v_a, *a_a, r_a, *p_b, *v_b, *a_b, r_b)]
    if max(abs(x) for x in vals) > _MAX_INPUT:
        # beyond the documented input range: exact rationals with ~2000-bit
        # parts make the exact path arbitrarily slow (NaN, like an overflow)
        return math.nan
    dp, dv, da = _rel(p_a, p_b), _rel(v_a, v_b), _rel(a_a, a_b)
    R = Fraction(float(r_a)) + Fraction(float(r_b))

    def dot(x, y):
        return sum((i * j for i, j in zip(x, y)), Fraction(0))

    coeffs = [dot(dp, dp) - R * R, 2 * dot(dp, dv), dot(dv, dv) + dot(da, dp),
              dot(da, dv), dot(da, da) / 4]
    if coeffs[0] < 0:
        return 0.0
    k = 0
    if coeffs[0] == 0:
        # touching at t = 0: the lowest-order nonzero term decides
        k = next((i for i in range(1, 5) if coeffs[i] != 0), 5)
        if k == 5:
            return math.inf  # f == 0: touching for all time, never approaching
        if coeffs[k] < 0:
            return 0.0
    h = _trim(coeffs[k:])  # f / t^k: same roots in (0, H], h(0) > 0
    H = float(horizon)
    if len(h) == 1 or H <= 0.0:
        return math.inf
    roots = _Roots(h)
    if math.isinf(H):
        if roots.v0 - roots.v_inf() == 0:
            return math.inf
        hi = _MAX_BITS
    else:
        hi = _bits(H)
    if not roots.any_upto(Fraction(_float(hi))):
        return math.inf
    lo = 0  # invariant: no root in (0, float(lo)], a root in (0, float(hi)]
    # Sturm counts until (lo, hi] isolates the first root; from then on the
    # sign of the square-free part (every root simple, so a sign change at
    # each) decides, one polynomial evaluation per step instead of a sequence
    s_lo = _sign(_eval(roots.p, Fraction(0)))
    v_lo, v_hi = roots.v0, roots.v(Fraction(_float(hi)))
    single = _eval(roots.p, Fraction(_float(hi))) != 0 and v_lo - v_hi == 1
    while hi - lo > 1:
        mid = (lo + hi) // 2
        x = Fraction(_float(mid))
        if single:
            s_mid = _sign(_eval(roots.p, x))
            if s_mid == s_lo:
                lo = mid
            else:
                hi = mid
            continue
        v_mid = roots.v(x)
        if _eval(roots.p, x) == 0 or v_lo - v_mid > 0:
            hi = mid
            single = _eval(roots.p, x) != 0 and v_lo - v_mid == 1
            v_hi = v_mid
        else:
            lo = mid
            v_lo = v_mid
            s_lo = _sign(_eval(roots.p, x))
            single = v_lo - v_hi == 1 and _eval(roots.p, Fraction(_float(hi))) != 0
    # first root r in (x_lo, x_hi]: round to nearest (never to 0)
    x_lo, x_hi = _float(lo), _float(hi)
    if lo == 0:
        return x_hi
    m = (Fraction(x_lo) + Fraction(x_hi)) / 2
    if not roots.any_upto(m):
        return x_hi  # r > m
    if _eval(roots.p, m) != 0:
        return x_lo  # r < m
    # m is a root: r == m unless another root lies in (x_lo, m); deflate m
    # (a simple root of the square-free part) and count on the rest
    q = _quo(roots.p, [-m, Fraction(1)])
    if len(q) > 1:
        sq = _sturm(q)
        va = _variations(_sign(_eval(s, Fraction(x_lo))) for s in sq)
        vm = _variations(_sign(_eval(s, m)) for s in sq)
        if va - vm > 0:
            return x_lo  # r < m
    return x_lo if lo % 2 == 0 else x_hi  # tie: even mantissa
