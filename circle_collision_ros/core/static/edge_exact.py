"""Exact first contact of a moving circle with the interior of one static segment.

The circle (radius r >= 0) has centre c(t) = p + v t + a t^2 / 2; the segment runs
from A to B (A != B).  With e = B - A, Q = e.e, L = sqrt(Q), w = (-e_y, e_x) and
g(t) = c(t) - A, the signed distance to the line is s(t) = w.g(t) / L (> 0: left
of A->B) and the foot point lies in the open segment iff 0 < pr(t) = e.g(t) < Q.
The endpoints are point features of their own, so only contacts whose foot point
is strictly inside the segment are reported here:

* t = 0, overlap: |s(0)| < r with 0 < pr(0) < Q -> 0.
* t = 0, touching (|s(0)| = r > 0, sigma = sign s(0)): 0 if approaching (the
  lowest-order nonzero coefficient of sigma s(t) - r is negative) and the foot
  point is inside or enters (pr(0) = 0 and pr increasing, or pr(0) = Q and pr
  decreasing, by the lowest-order nonzero coefficient of pr(t) - pr(0)).  A
  separating touch, or sliding at exactly r for ever, is no contact at t = 0.
* t = 0, r = 0 on the line: a bare wall (solid_side 0) is never entered at t = 0;
  an edge with the solid on side k = +-1 is, iff k s(t) starts positive (same
  foot-point rule).
* t > 0: on each side sigma = +-1 (whatever solid_side), phi = sigma s(t) - r is
  a quadratic; its entering root (phi goes from > 0 to <= 0; a double root only
  when phi >= 0, i.e. a tangent graze) counts if it lies in (0, horizon] with
  0 < pr < Q there (pr exactly 0 or Q: the endpoint reports that time).  This is
  the moving-sphere-vs-plane test (Ericson, Real-Time Collision Detection, 2005,
  sec. 5.5.3) restricted to the open segment.

Result: the earliest contact time rounded to the nearest float64 (ties to even;
a positive time is never rounded to 0.0, which means contact at t = 0), 0.0, inf
when none lies in [0, horizon] (or it overflows float64), nan for invalid input.

Exactness.  Float64 inputs are dyadic, so one common power of two makes every
length an integer (time is not rescaled: v and a scale like lengths).  The entering
root is T = (x + y sqrt(D)) / d with an integer d > 0 and x, y, D in Z[sqrt(Q)]
(sqrt(Q) enters through r L), so every decision is the sign of an element of
Z[sqrt(Q)][sqrt(D)], each level decided as for CGAL's Sqrt_extension (CGAL
manual, Number Types): sign(a + b sqrt(c)), c >= 0, is the sign of a or b when
the other is 0 or of the same sign, else sign(a) sign(a^2 - b^2 c).  A perfect
square Q (axis-aligned walls, 3-4-5 walls) needs no special case: the rule is
exact for it too, so an exact touch or graze is recognised.  Comparisons with
floats (0, the horizon, rounding candidates and their midpoints, all n / 2^s)
and the sign of pr(T) are such signs after multiplying by positive d, d^2, 2^s.
Rounding: a float estimate of T (cancellation removed with conjugates), a
galloping search over float64 bit patterns until two neighbours bracket T, and
the exact midpoint decides (IEEE 754 roundTiesToEven).  The two sides' times
are rounded separately: rounding is monotone, so the smaller rounded time is
the rounded smaller time.

Cost: ~20-60 us per call in plain Python for ordinary inputs (a handful of
exact comparisons); inputs spanning ~2^1000 in magnitude use integers of
thousands of bits and a bisection instead of the float estimate (~1 ms).
"""
from __future__ import annotations

import math
import sys
from typing import Sequence

from circle_collision_ros.core.narrow.exact import (bits_float, dyadic, float_bits, int_sign,
                                                    scaled_ints)

__all__ = ["exact_edge_contact"]

_MAX = sys.float_info.max
# 2^1024 - 2^970: the midpoint between the largest float64 and 2^1024; a time at
# or beyond it rounds to inf (the tie goes to the "even" 2^1024)
_OVERFLOW = (1 << 1024) - (1 << 970)


def _lowest_sign(*coeffs: int) -> int:
    """Return the sign of the lowest-order nonzero coefficient (0 if all are zero)."""
    for c in coeffs:
        if c:
            return int_sign(c)
    return 0


class _Surd:
    """a + b sqrt(q) with integers a, b and a fixed integer q > 0 (exact)."""

    __slots__ = ("a", "b", "q")

    def __init__(self, a: int, b: int, q: int):
        self.a, self.b, self.q = a, b, q

    def __add__(self, o: _Surd) -> _Surd:
        return _Surd(self.a + o.a, self.b + o.b, self.q)

    def __sub__(self, o: _Surd) -> _Surd:
        return _Surd(self.a - o.a, self.b - o.b, self.q)

    def __mul__(self, o: _Surd | int) -> _Surd:
        if isinstance(o, int):
            return _Surd(self.a * o, self.b * o, self.q)
        return _Surd(self.a * o.a + self.b * o.b * self.q, self.a * o.b + self.b * o.a, self.q)

    __rmul__ = __mul__

    def sign(self) -> int:
        sa, sb = int_sign(self.a), int_sign(self.b)
        if sb == 0 or sa == sb:
            return sa if sa else sb
        if sa == 0:
            return sb
        # opposite signs: the larger of |a| and |b| sqrt(q) wins
        return sa * int_sign(self.a * self.a - self.b * self.b * self.q)

    def approx(self) -> float:
        """Float value, a few ulps off (may raise OverflowError for huge values)."""
        a, b = self.a, self.b
        if b == 0:
            return float(a)
        rq = math.sqrt(self.q)
        if a == 0 or (a > 0) == (b > 0):
            return a + b * rq
        # a + b sqrt(q) = (a^2 - b^2 q) / (a - b sqrt(q)): no cancellation left
        return float(a * a - b * b * self.q) / (a - b * rq)


def _sign2(x: _Surd, y: _Surd, d: _Surd) -> int:
    """Sign of x + y sqrt(d) for d >= 0: the same rule one level up."""
    sx, sy = x.sign(), y.sign()
    if sy == 0 or sx == sy:
        return sx if sx else sy
    if sx == 0:
        return sy
    return sx * (x * x - y * y * d).sign()


class _Time:
    """The exact time T = (x + y sqrt(d)) / den, den a positive integer, d >= 0."""

    __slots__ = ("x", "y", "d", "den")

    def __init__(self, x: _Surd, y: _Surd, d: _Surd, den: int):
        self.x, self.y, self.d, self.den = x, y, d, den

    def cmp(self, n: int, s: int = 0) -> int:
        """Return sign(T - n / 2^s), s >= 0."""
        k = 1 << s
        return _sign2(self.x * k - _Surd(self.den * n, 0, self.x.q), self.y * k, self.d)

    def cmp_float(self, f: float) -> int:
        return self.cmp(*dyadic(f))

    def poly_sign(self, c0: int, c1: int, c2: int) -> int:
        """Sign of c0 + c1 T + c2 T^2 (integers c0, c1, c2).

        Taken on den^2 times it, with (x + y sqrt(d))^2 = x^2 + y^2 d + 2 x y sqrt(d).
        """
        x, y, d, m = self.x, self.y, self.d, self.den
        lin = x * (c1 * m) + (x * x + y * y * d) * c2
        rest = y * (c1 * m) + x * y * (2 * c2)
        return _sign2(_Surd(lin.a + c0 * m * m, lin.b, x.q), rest, self.d)

    def approx(self) -> float:
        """Float estimate (cancellation removed with the conjugate)."""
        xa = self.x.approx()
        if self.y.sign() == 0 or self.d.sign() == 0:
            return xa / self.den
        yd = self.y.approx() * math.sqrt(self.d.approx())
        if (xa >= 0) == (yd >= 0):
            return (xa + yd) / self.den
        # x + y sqrt(d) = (x^2 - y^2 d) / (x - y sqrt(d))
        return (self.x * self.x - self.y * self.y * self.d).approx() / ((xa - yd) * self.den)


def _round(t: _Time, guess: float, hi: int) -> float:
    """Nearest float64 to t, given 0 < t < float(hi) (ties to even; never 0).

    Gallops over float64 bit patterns from the guess (a few steps when it is a
    few ulps off, logarithmically many when the estimate was poor), bisects the
    bracket down to two neighbours, then the exact midpoint decides.
    """

    def cmp(b: int) -> int:
        return t.cmp_float(bits_float(b))

    lo = 0  # invariant: float(lo) < t < float(hi)
    b = min(max(float_bits(guess), lo + 1), hi - 1) if 0.0 < guess < math.inf else (lo + hi) // 2
    if lo < b < hi:
        c = cmp(b)
        if c == 0:
            return bits_float(b)
        step = 1
        if c > 0:
            lo = b
            while lo + step < hi:
                c = cmp(lo + step)
                if c == 0:
                    return bits_float(lo + step)
                if c < 0:
                    hi = lo + step
                    break
                lo += step
                step *= 2
        else:
            hi = b
            while hi - step > lo:
                c = cmp(hi - step)
                if c == 0:
                    return bits_float(hi - step)
                if c > 0:
                    lo = hi - step
                    break
                hi -= step
                step *= 2
    while hi - lo > 1:
        mid = (lo + hi) // 2
        c = cmp(mid)
        if c == 0:
            return bits_float(mid)
        if c > 0:
            lo = mid
        else:
            hi = mid
    if lo == 0:
        return bits_float(hi)  # below the smallest subnormal: still a positive time
    (n_lo, s_lo), (n_hi, s_hi) = dyadic(bits_float(lo)), dyadic(bits_float(hi))
    s = max(s_lo, s_hi)
    c = t.cmp((n_lo << (s - s_lo)) + (n_hi << (s - s_hi)), s + 1)  # t vs the exact midpoint
    if c == 0:
        return bits_float(lo if lo % 2 == 0 else hi)
    return bits_float(lo if c < 0 else hi)


def _entering(sigma: int, m: tuple[int, int, int], R: int, Q: int) -> _Time | None:
    """Entering root of 2 L phi = sigma (m0 + m1 t + m2 t^2) - 2 R sqrt(Q), or None.

    k2 != 0: T = (-k1 - sqrt(D)) / (2 k2), D = k1^2 - 4 k2 k0, the root where phi
    goes from > 0 to <= 0 (the smaller one if k2 > 0, the larger if k2 < 0); D = 0
    is a double root, entering only when phi >= 0 around it (k2 > 0).
    k2 == 0: T = -k0 / k1 when phi decreases (k1 < 0).
    """
    k0 = _Surd(sigma * m[0], -2 * R, Q)
    k1, k2 = sigma * m[1], sigma * m[2]
    zero = _Surd(0, 0, Q)
    if k2 == 0:
        return _Time(k0, zero, zero, -k1) if k1 < 0 else None
    D = _Surd(k1 * k1, 0, Q) - k0 * (4 * k2)
    sd = D.sign()
    if sd < 0 or (sd == 0 and k2 < 0):
        return None
    g = 1 if k2 > 0 else -1  # numerator and denominator times sign(k2): den > 0
    y = _Surd(-g, 0, Q) if sd else zero
    return _Time(_Surd(-g * k1, 0, Q), y, D if sd else zero, 2 * k2 * g)


def exact_edge_contact(p: Sequence[float], v: Sequence[float], a: Sequence[float], r: float,
                       A: Sequence[float], B: Sequence[float], solid_side: int,
                       horizon: float = math.inf) -> float:
    """First contact time of a moving circle with the open segment A->B, decided exactly.

    p, v, a: the centre's position, velocity, acceleration (2-D, float64); r >= 0
    the radius; solid_side +1 / -1: the segment bounds a solid on its left / right
    (only decides a point body, r = 0, starting on the line), 0: a two-sided wall.
    Returns 0.0 (contact at t = 0), the earliest contact time in (0, horizon]
    rounded to nearest float64, inf (none) or nan (invalid input: non-finite
    values, r < 0, horizon < 0 or nan, A == B, solid_side not in {-1, 0, 1}).
    Rules: the module docstring.
    """
    (px, py), (vx, vy), (ax, ay), (Ax, Ay), (Bx, By) = p, v, a, A, B
    vals = [float(x) for x in (px, py, vx, vy, ax, ay, r, Ax, Ay, Bx, By)]
    H = float(horizon)
    if (not all(math.isfinite(x) for x in vals) or vals[6] < 0 or not H >= 0
            or solid_side not in (-1, 0, 1) or (vals[7], vals[8]) == (vals[9], vals[10])):
        return math.nan
    solid_side = int(solid_side)  # a numpy integer would overflow in the big products
    px, py, vx, vy, ax, ay, R, Ax, Ay, Bx, By = scaled_ints(vals)
    ex, ey = Bx - Ax, By - Ay
    Q = ex * ex + ey * ey
    dx, dy = px - Ax, py - Ay
    # 2 w.g(t) and 2 e.g(t) in the integer units (w = (-ey, ex)); the factor 2
    # keeps a t^2 / 2 integral, so the segment test reads 0 < n(t) < 2 Q
    m = (2 * (ex * dy - ey * dx), 2 * (ex * vy - ey * vx), ex * ay - ey * ax)
    n = (2 * (ex * dx + ey * dy), 2 * (ex * vx + ey * vy), ex * ax + ey * ay)
    Q2 = 2 * Q

    # t = 0: |s(0)| vs r is m0^2 vs 4 R^2 Q (both sides scaled by 4 Q 2^(2 scale))
    gap0 = m[0] * m[0] - 4 * R * R * Q
    if gap0 < 0 and 0 < n[0] < Q2:
        return 0.0
    if gap0 == 0:
        if R > 0:
            sigma = int_sign(m[0])
            approaching = _lowest_sign(sigma * m[1], sigma * m[2]) < 0
        else:  # a point on the line: only a solid can be entered at once
            approaching = bool(solid_side) and _lowest_sign(solid_side * m[1],
                                                            solid_side * m[2]) > 0
        if approaching:
            foot = _lowest_sign(n[1], n[2])
            if 0 < n[0] < Q2 or (n[0] == 0 and foot > 0) or (n[0] == Q2 and foot < 0):
                return 0.0
    if H == 0.0:
        return math.inf

    best = math.inf
    for sigma in (1, -1):
        t = _entering(sigma, m, R, Q)
        if t is None or t.cmp(0) <= 0:
            continue
        if math.isfinite(best) and t.cmp_float(best) >= 0:
            continue  # rounding is monotone: cannot beat the other side's time
        top = H if math.isfinite(H) else _MAX
        c = t.cmp_float(top)  # t vs the horizon (or the largest float64)
        if c > 0 and (top == H or t.cmp(_OVERFLOW) >= 0):
            continue  # beyond the horizon, or rounds to inf
        if t.poly_sign(*n) <= 0 or t.poly_sign(Q2 - n[0], -n[1], -n[2]) <= 0:
            continue  # foot point on or outside an end: the endpoint feature's contact
        if c >= 0:
            best = top  # exactly the horizon, or between the largest float64 and the overflow
            continue
        try:
            guess = t.approx()
        except (OverflowError, ZeroDivisionError, ValueError):
            guess = math.nan  # extreme magnitudes: bisection from scratch
        best = _round(t, guess, float_bits(top))
    return best
