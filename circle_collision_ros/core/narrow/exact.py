"""Exact decision of the first-contact time (the narrow phase's fallback).

Float64 inputs are dyadic rationals m * 2^e, so scaling every input by one
power of two 2^-E (E the smallest exponent among them) makes the relative state
``dp, dv, da, R`` integers, and

    4 * 2^(-2E) * f(t),   f(t) = |dp + t dv + t^2 da / 2|^2 - R^2 = c4 t^4 + ... + c0,

a polynomial with integer coefficients and the same sign as f everywhere.  All
arithmetic below is on Python integers (exact, no rounding before the final
one); only signs of polynomials are ever needed, so every polynomial may be
scaled by any positive factor (each is kept primitive: coefficients divided by
their positive gcd).

* Order of contact at t = 0 (``f(0) = 0``, touching): the first nonzero
  coefficient of ``c1, c2, c3, c4`` is the sign of f just after 0.  Negative:
  the bodies interpenetrate immediately (approaching) -> 0.  Positive: they
  separate; the answer is the next root of f in (0, H].  All zero (``f`` is
  identically 0: touching for all time, never approaching) -> inf.
* Roots in (0, H]: a Sturm sequence of the square-free part of ``f / t^k``
  (k = the order of the root at 0) counts the distinct real roots in any
  interval exactly; double roots (tangent grazes, point bodies whose paths
  cross) count like any other root.  The sequence is built with pseudo-
  remainders whose multipliers are made positive, so each member is a positive
  multiple of the classical (rational) Sturm polynomial: same signs.
* The sign of a polynomial p of degree d at a float x = n / 2^s (s >= 0) is
  the sign of the integer sum_i c_i n^i 2^(s (d - i)) = 2^(s d) p(x).
* The returned time is the first root rounded to the nearest float64 (ties to
  even), found by bisection over float64 bit patterns in (0, H]: the root
  count on (0, x] is monotone in x.  A positive root is never rounded to 0.

Cost: tens to hundreds of microseconds per row in plain Python (integer
arithmetic; bench/fallback.py prints it); the batch kernels call it only for
rows their certified float64/double-double paths leave undecided.
"""
from __future__ import annotations

import math
import struct
from typing import Sequence

__all__ = ["exact_first_contact"]

_MAX_BITS = 0x7FEFFFFFFFFFFFFF  # bit pattern of the largest finite float64
_MAX_INPUT = 1e150  # the narrow phase's documented input range

Poly = list  # integer coefficients, ascending powers, highest one nonzero


def float_bits(x: float) -> int:
    """The float64's bit pattern as a signed 64-bit integer (consecutive floats differ by 1)."""
    return struct.unpack("<q", struct.pack("<d", x))[0]


def bits_float(b: int) -> float:
    """The float64 with bit pattern ``b`` (inverse of float_bits)."""
    return struct.unpack("<d", struct.pack("<q", b))[0]


def int_sign(x: int) -> int:
    """-1, 0 or 1."""
    return (x > 0) - (x < 0)


def _trim(p: Poly) -> Poly:
    """Drop zero leading (highest-degree) coefficients."""
    while p and p[-1] == 0:
        p = p[:-1]
    return p


def _primitive(p: Poly) -> Poly:
    """p divided by the positive gcd of its coefficients (same signs everywhere)."""
    g = math.gcd(*p)
    return [c // g for c in p] if g > 1 else p


def _pdiv(a: Poly, b: Poly) -> tuple[Poly, Poly]:
    """Pseudo-division with a positive multiplier: (q, r) with m a = q b + r,
    m = |lc(b)|^(deg a - deg b + 1) > 0 and deg r < deg b."""
    db = len(b) - 1
    lead = b[-1]
    steps = len(a) - db
    if steps <= 0:
        return [], a
    q = [0] * steps
    r = list(a)
    for k in range(steps - 1, -1, -1):
        # r := lead * r - r_top x^k b (exact; drops the top coefficient)
        top = r[k + db]
        q = [lead * c for c in q]
        q[k] += top
        r = [lead * c for c in r]
        for i, c in enumerate(b):
            r[k + i] -= top * c
        r.pop()
    if lead < 0 and steps % 2:  # multiplier lead^steps < 0: flip to |lead|^steps
        q = [-c for c in q]
        r = [-c for c in r]
    return q, _trim(r)


def _deriv(p: Poly) -> Poly:
    return [i * c for i, c in enumerate(p)][1:]


def _gcd(a: Poly, b: Poly) -> Poly:
    """A polynomial gcd of a and b (primitive remainder sequence)."""
    while b:
        a, b = b, _pdiv(a, b)[1]
        if b:
            b = _primitive(b)
    return a


def _eval_sign(p: Poly, n: int, s: int) -> int:
    """Sign of p(n / 2^s) for s >= 0 (Horner on 2^(s deg p) p(n / 2^s))."""
    r = p[-1]
    shift = 0
    for c in reversed(p[:-1]):
        shift += s
        r = r * n + (c << shift)
    return int_sign(r)


def dyadic(x: float) -> tuple[int, int]:
    """(n, s) with x = n / 2^s, s >= 0."""
    n, d = x.as_integer_ratio()  # d is a power of two
    return n, d.bit_length() - 1


def _sturm(p: Poly) -> list:
    seq = [p, _primitive(_deriv(p))]
    while True:
        r = _pdiv(seq[-2], seq[-1])[1]
        if not r:
            break
        seq.append(_primitive([-c for c in r]))
    return seq


def _variations(signs) -> int:
    last = 0
    v = 0
    for s in signs:
        if s != 0:
            if last != 0 and s != last:
                v += 1
            last = s
    return v


class _Roots:
    """Root counting on (0, x] for an integer polynomial with p(0) != 0 (exact)."""

    def __init__(self, p: Poly):
        g = _gcd(p, _deriv(p))
        self.p = _primitive(_pdiv(p, g)[0]) if len(g) > 1 else p  # square-free part
        self.seq = _sturm(self.p)
        self.v0 = _variations(int_sign(s[0]) for s in self.seq)

    def sign(self, x: float | tuple[int, int]) -> int:
        """Sign of the square-free part at x (a float, or (n, s) for n / 2^s)."""
        n, s = dyadic(x) if isinstance(x, float) else x
        return _eval_sign(self.p, n, s)

    def v(self, x: float | tuple[int, int]) -> int:
        n, s = dyadic(x) if isinstance(x, float) else x
        return _variations(_eval_sign(q, n, s) for q in self.seq)

    def v_inf(self) -> int:
        return _variations(int_sign(s[-1]) for s in self.seq)

    def any_upto(self, x: float | tuple[int, int]) -> bool:
        """Some root in (0, x] (x > 0)."""
        return self.sign(x) == 0 or self.v0 - self.v(x) > 0


def scaled_ints(vals: list) -> list:
    """The floats in `vals` times one common power of two, as exact integers."""
    ratios = [x.as_integer_ratio() for x in vals]
    s = max(d.bit_length() - 1 for _, d in ratios)  # 2^s clears every denominator
    return [n << (s - (d.bit_length() - 1)) for n, d in ratios]


def exact_first_contact(p_a: Sequence[float], v_a: Sequence[float], a_a: Sequence[float],
                        r_a: float, p_b: Sequence[float], v_b: Sequence[float],
                        a_b: Sequence[float], r_b: float, horizon: float = math.inf) -> float:
    """First-contact time of one pair decided in exact integer arithmetic.

    Same contract as ``time_to_collision`` for valid input (finite values,
    radii >= 0, horizon >= 0): 0.0 for overlap or an approaching touch at
    t = 0 (order-of-contact rule in the module docstring); else the first
    contact time in (0, horizon] rounded to nearest float64; inf if none.
    """
    D = len(p_a)
    vals = [float(x) for x in (*p_a, *v_a, *a_a, r_a, *p_b, *v_b, *a_b, r_b)]
    if max(abs(x) for x in vals) > _MAX_INPUT:
        # beyond the documented input range: integers of ~2000 bits and more
        # make the exact path arbitrarily slow (NaN, like an overflow)
        return math.nan
    w = scaled_ints(vals)  # p_a, v_a, a_a, r_a, p_b, v_b, a_b, r_b, times 2^s
    half = 3 * D + 1
    dp = [w[i] - w[half + i] for i in range(D)]
    dv = [w[D + i] - w[half + D + i] for i in range(D)]
    da = [w[2 * D + i] - w[half + 2 * D + i] for i in range(D)]
    R = w[3 * D] + w[half + 3 * D]

    def dot(x, y):
        return sum(i * j for i, j in zip(x, y))

    # 4 f(t) (times 2^(2s)): integer coefficients, ascending
    coeffs = [4 * (dot(dp, dp) - R * R), 8 * dot(dp, dv), 4 * (dot(dv, dv) + dot(da, dp)),
              4 * dot(da, dv), dot(da, da)]
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
    roots = _Roots(_primitive(h))
    if math.isinf(H):
        if roots.v0 - roots.v_inf() == 0:
            return math.inf
        hi = _MAX_BITS
    else:
        hi = float_bits(H)
    if not roots.any_upto(bits_float(hi)):
        return math.inf
    lo = 0  # invariant: no root in (0, float(lo)], a root in (0, float(hi)]
    # Sturm counts until (lo, hi] isolates the first root; from then on the
    # sign of the square-free part (every root simple, so a sign change at
    # each) decides, one polynomial evaluation per step instead of a sequence
    s_lo = int_sign(roots.p[0])
    v_lo, v_hi = roots.v0, roots.v(bits_float(hi))
    single = roots.sign(bits_float(hi)) != 0 and v_lo - v_hi == 1
    while hi - lo > 1:
        mid = (lo + hi) // 2
        x = bits_float(mid)
        if single:
            if roots.sign(x) == s_lo:
                lo = mid
            else:
                hi = mid
            continue
        v_mid = roots.v(x)
        s_mid = roots.sign(x)
        if s_mid == 0 or v_lo - v_mid > 0:
            hi = mid
            single = s_mid != 0 and v_lo - v_mid == 1
            v_hi = v_mid
        else:
            lo = mid
            v_lo = v_mid
            s_lo = s_mid
            single = v_lo - v_hi == 1 and roots.sign(bits_float(hi)) != 0
    # first root r in (x_lo, x_hi]: round to nearest (never to 0)
    x_lo, x_hi = bits_float(lo), bits_float(hi)
    if lo == 0:
        return x_hi
    # m = (x_lo + x_hi) / 2 = n / 2^s exactly
    (n_lo, e_lo), (n_hi, e_hi) = dyadic(x_lo), dyadic(x_hi)
    e = max(e_lo, e_hi)
    m = (n_lo << (e - e_lo)) + (n_hi << (e - e_hi)), e + 1
    if not roots.any_upto(m):
        return x_hi  # r > m
    if roots.sign(m) != 0:
        return x_lo  # r < m
    # m is a root: r == m unless another root lies in (x_lo, m); deflate m
    # (a simple root of the square-free part: 2^s x - n divides p) and count on the rest
    q = _primitive(_pdiv(roots.p, [-m[0], 1 << m[1]])[0])
    if len(q) > 1:
        sq = _sturm(q)
        va = _variations(_eval_sign(s, *dyadic(x_lo)) for s in sq)
        vm = _variations(_eval_sign(s, *m) for s in sq)
        if va - vm > 0:
            return x_lo  # r < m
    return x_lo if lo % 2 == 0 else x_hi  # tie: even mantissa
