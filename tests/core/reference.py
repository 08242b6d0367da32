"""High-precision reference for the first-contact time (mpmath, slow: ~5 ms/pair).

Independent of the production method: it expands the *exact* quartic in power
basis at 320 bits (float64 inputs convert to mpf exactly, and every
coefficient is a short sum of products of doubles, so the coefficients are
exact for the input ranges used in the tests), then finds all complex roots
with ``mpmath.polyroots`` at 320 + 320 extra bits and keeps the real ones.

Why the real/complex test is safe here: at 640 bits a true double root
(a tangent graze, or point bodies whose paths cross) comes out with
``|imag| ~ 1e-95`` relative (square root of the working precision), while a near miss by a gap
``delta`` of
``f = |g|^2 - R^2`` has ``|imag| ~ sqrt(delta)/|g'|``; the tests only demand
a definite answer when ``|f_min| > 1e-9 R^2``, far above the threshold
``1e-30`` (relative) used below.  Cases where some local minimum of ``f`` on
``[0, H]`` (or ``f(H)``) lies within ``1e-9 R^2`` of zero are flagged
``ambiguous`` so tests can exempt them from the missed/spurious count.
"""
from __future__ import annotations

import math
import struct
import sys
from dataclasses import dataclass

import mpmath
from mpmath import mp, mpf

PREC = 320


@dataclass
class Ref:
    t: float  # first contact time rounded to float64 (0.0, inf allowed)
    t_mp: object  # exact-ish mpf (or None for 0/inf)
    cos: float  # |cos| of angle between centre line and relative velocity at contact
    ambiguous: bool  # some local min of f (or f(H)) within 1e-9 R^2 of zero
    fmin: object  # smallest local-minimum value of f on (0, H] (mpf or None)


def _vec(x, D):
    x = [float(v) for v in x]
    return [mpf(v) for v in x] + [mpf(0)] * (3 - D)


def _roots(coeffs):
    """Real roots of a polynomial (descending mp coefficients), high precision."""
    while coeffs and coeffs[0] == 0:
        coeffs = coeffs[1:]
    n = len(coeffs) - 1
    if n <= 0:
        return []
    if n == 1:
        return [-coeffs[1] / coeffs[0]]
    if n == 2:
        a, b, c = coeffs
        disc = b * b - 4 * a * c
        if disc < 0:
            return []
        s = mpmath.sqrt(disc)
        q = -(b + (s if b >= 0 else -s)) / 2
        out = []
        if q != 0:
            out = [q / a, c / q]
        else:
            out = [mpf(0), mpf(0)]
        return sorted(out)
    with mp.workprec(PREC):
        for steps in (100, 400, 2000):
            try:
                rts = mpmath.polyroots(coeffs[::-1], maxsteps=steps, extraprec=PREC, asc=True)
                break
            except mpmath.libmp.libhyper.NoConvergence:
                continue
        else:  # pragma: no cover
            raise RuntimeError("polyroots failed")
        scale = max(abs(r) for r in rts) + mpf(1e-300)
        real = [
            mpmath.re(r)
            for r in rts
            if abs(mpmath.im(r)) <= mpf(10) ** -30 * max(abs(r), scale * mpf(10) ** -20)
        ]
        return sorted(real)


def reference(p_a, v_a, a_a, r_a, p_b, v_b, a_b, r_b, horizon=math.inf) -> Ref:
    """First contact of one pair from the exact binary64 inputs as given."""
    D = len(p_a)
    with mp.workprec(PREC):
        pa, va, aa, pb, vb, ab = (_vec(x, D) for x in (p_a, v_a, a_a, p_b, v_b, a_b))
        R = mpf(float(r_a)) + mpf(float(r_b))
        H = mpf(float(horizon)) if math.isfinite(horizon) else None
        dp = [x - y for x, y in zip(pa, pb)]
        dv = [x - y for x, y in zip(va, vb)]
        da = [x - y for x, y in zip(aa, ab)]
        dot = lambda x, y: sum(i * j for i, j in zip(x, y))  # noqa: E731
        c4 = dot(da, da) / 4
        c3 = dot(da, dv)
        c2 = dot(dv, dv) + dot(da, dp)
        c1 = 2 * dot(dp, dv)
        c0 = dot(dp, dp) - R * R
        coeffs = [c4, c3, c2, c1, c0]

        def f(t):
            return (((c4 * t + c3) * t + c2) * t + c1) * t + c0

        def geom(t):
            g = [p + t * (v + t * a / 2) for p, v, a in zip(dp, dv, da)]
            gd = [v + t * a for v, a in zip(dv, da)]
            return g, gd

        slack = mpf("1e-9") * R * R
        # local minima of f on (0, H]: roots of f' where f'' > 0
        crit = _roots([4 * c4, 3 * c3, 2 * c2, c1])
        mins = [
            s
            for s in crit
            if s > 0 and (H is None or s <= H) and (12 * c4 * s * s + 6 * c3 * s + 2 * c2) >= 0
        ]
        fmins = [f(s) for s in mins]
        ambiguous = any(abs(v) <= slack for v in fmins)
        if H is not None and abs(f(H)) <= slack and c0 > slack:
            ambiguous = True
        fmin = min(fmins) if fmins else None

        if c0 < 0:
            return Ref(0.0, None, 1.0, False, fmin)
        if c0 == 0:
            for c in (c1, c2, c3, c4):  # first non-zero derivative decides
                if c < 0:
                    return Ref(0.0, None, 1.0, False, fmin)
                if c > 0:
                    break
        rts = _roots(coeffs)
        tiny = mpf(10) ** -60
        cand = [r for r in rts if r > tiny * (1 + abs(r)) and (H is None or r <= H)]
        if c0 > 0:
            cand = [r for r in rts if r > 0 and (H is None or r <= H)]
        if not cand:
            return Ref(math.inf, None, 1.0, ambiguous, fmin)
        t = cand[0]
        g, gd = geom(t)
        ng = mpmath.sqrt(dot(g, g))
        ngd = mpmath.sqrt(dot(gd, gd))
        if ng == 0 or ngd == 0 or R == 0:
            cos = 1.0
        else:
            cos = float(abs(dot(g, gd)) / (ng * ngd))
        return Ref(float(t), t, cos, ambiguous, fmin)


# --------------------------------------------------------------------------
# Exact-rational reference: no rounding before the final one.
# Independent of circle_collision_ros.core.narrow.exact (which counts roots
# with Sturm sequences and bisects over float bit patterns): here real roots
# of the square-free part are isolated with Descartes' rule of signs on
# Moebius-transformed intervals (Vincent-Collins-Akritas bisection), the
# first one refined by sign bisection until both ends round to the same
# float64 (Python's float(Fraction) rounds correctly).
# --------------------------------------------------------------------------
from fractions import Fraction  # noqa: E402


@dataclass
class ExactRef:
    t: float  # first contact time correctly rounded (0.0 / inf allowed)
    lo: Fraction  # the exact time lies in [lo, hi] (lo == hi when known exactly)
    hi: Fraction


def _p_trim(p):
    p = list(p)
    while p and p[-1] == 0:
        p.pop()
    return p


def _p_divmod(a, b):
    a = [Fraction(x) for x in a]
    q = [Fraction(0)] * max(len(a) - len(b) + 1, 1)
    while len(a) >= len(b) and a:
        k = a[-1] / b[-1]
        sh = len(a) - len(b)
        q[sh] = k
        for i, c in enumerate(b):
            a[sh + i] -= k * c
        a = _p_trim(a[:-1])
    return q, a


def _p_eval(p, x):
    r = Fraction(0)
    for c in reversed(p):
        r = r * x + c
    return r


def _squarefree(p):
    d = [i * c for i, c in enumerate(p)][1:]
    a, b = p, d
    while b:
        a, b = b, _p_divmod(a, b)[1]
    if len(a) <= 1:
        return p
    return _p_divmod(p, a)[0]


def _descartes(p, a, b):
    """Sign variations of (1+x)^n p((a + b x)/(1+x)): bounds the number of
    roots of p in (a, b) (exact when 0 or 1)."""
    n = len(p) - 1
    # q(x) = sum c_i (a + b x)^i (1 + x)^(n - i)
    q = [Fraction(0)] * (n + 1)
    for i, c in enumerate(p):
        # (a + b x)^i (1 + x)^(n - i), by repeated multiplication
        term = [Fraction(1)]
        for _ in range(i):
            term = [Fraction(0)] + term  # * x
            term = [
                term[j] * b + (term[j + 1] * a if j + 1 < len(term) else 0)
                for j in range(len(term))
            ]
        for _ in range(n - i):
            term = [
                (term[j] if j < len(term) else 0) + (term[j - 1] if j >= 1 else 0)
                for j in range(len(term) + 1)
            ]
        for j, t in enumerate(term):
            q[j] += c * t
    signs = [x > 0 for x in q if x != 0]
    return sum(1 for u, v in zip(signs, signs[1:]) if u != v)


def _split(lo, hi):
    """A dyadic point strictly inside (lo, hi) (0 <= lo < hi <= max float64):
    the float64 halfway between them in bit-pattern order, so intervals from
    2^-1000 to 2^1000 shrink like a binary search over the float64 grid
    (~64 splits) instead of one bit per split; the arithmetic midpoint where
    no float64 lies strictly inside.  Any interior point is a valid split
    for the root counts, so only the speed depends on it."""
    bl = struct.unpack("<q", struct.pack("<d", float(lo)))[0]
    bh = struct.unpack("<q", struct.pack("<d", float(hi)))[0]
    mid = Fraction(struct.unpack("<d", struct.pack("<q", (bl + bh) // 2))[0])
    return mid if lo < mid < hi else (lo + hi) / 2


def _isolate_first(p, a, b):
    """Isolating interval (lo, hi) of the smallest root of square-free p in
    (a, b], or None.  Endpoints are checked exactly."""
    stack = [(a, b)]
    while stack:
        lo, hi = stack.pop()
        if _p_eval(p, hi) == 0:
            # a root at hi: the first one unless one lies in (lo, hi)
            v = _descartes(p, lo, hi)
            if v == 0:
                return hi, hi
        else:
            v = _descartes(p, lo, hi)
            if v == 0:
                continue
            if v == 1:
                return lo, hi
        mid = _split(lo, hi)
        stack.append((mid, hi))
        stack.append((lo, mid))  # left half first
    return None


def exact_reference(p_a, v_a, a_a, r_a, p_b, v_b, a_b, r_b, horizon=math.inf) -> ExactRef:
    """First contact from the binary64 inputs as given, decided exactly."""
    F = lambda x: Fraction(float(x))  # noqa: E731
    dp = [F(x) - F(y) for x, y in zip(p_a, p_b)]
    dv = [F(x) - F(y) for x, y in zip(v_a, v_b)]
    da = [F(x) - F(y) for x, y in zip(a_a, a_b)]
    R = F(r_a) + F(r_b)
    dot = lambda x, y: sum((i * j for i, j in zip(x, y)), Fraction(0))  # noqa: E731
    c = [dot(dp, dp) - R * R, 2 * dot(dp, dv), dot(dv, dv) + dot(da, dp), dot(da, dv),
         dot(da, da) / 4]
    zero = ExactRef(0.0, Fraction(0), Fraction(0))
    never = ExactRef(math.inf, Fraction(0), Fraction(0))
    if c[0] < 0:
        return zero
    k = 0
    while k < 5 and c[k] == 0:
        k += 1
    if k == 5:
        return never  # f == 0: touching for all time without approaching
    if k > 0 and c[k] < 0:
        return zero
    p = _p_trim(c[k:])
    if len(p) <= 1 or float(horizon) <= 0:
        return never
    if math.isfinite(horizon):
        B = F(horizon)
    else:  # Cauchy bound on the roots, at most the largest float64: a first
        # root beyond it has no float64 time (inf, as narrow_exact reports)
        B = min(1 + max(abs(x / p[-1]) for x in p[:-1]), Fraction(sys.float_info.max))
    p = _squarefree(p)
    iso = _isolate_first(p, Fraction(0), B)
    if iso is None:
        return never
    lo, hi = iso
    pos_lo = _p_eval(p, lo) > 0  # p(lo) != 0: a root at lo would be found first
    while lo != hi and float(lo) != float(hi):
        mid = _split(lo, hi)
        fm = _p_eval(p, mid)
        if fm == 0:
            lo = hi = mid
        elif (fm > 0) == pos_lo:
            lo = mid
        else:
            hi = mid
    t = float(lo)
    if t == 0.0:  # a positive root is never reported as 0 (that means overlap)
        t = 5e-324
    return ExactRef(t, lo, hi)
