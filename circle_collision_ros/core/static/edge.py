"""Certified first contact of a moving circle with the interior of one static segment.

The circle's centre is ``c(t) = p + v t + a t^2/2``, its radius ``r``; the segment is
``A -> B``.  With ``e = B - A``, ``w = (-e_y, e_x)`` (its left normal), ``L = |e|`` and
``g(t) = c(t) - A``, the distance to the segment's line is ``|psi(t)| / L`` with the
power-basis quadratic ``psi(t) = w.g(t) = psi0 + psi1 t + psi2 t^2``, and the foot point is
inside the open segment while ``0 < pi(t) = e.g(t) < L^2``.  For each side
``sigma = +-1``, ``phi(t) = sigma psi(t) - r L`` has at most one *entering* root (phi goes
from > 0 to <= 0); the edge's contact is the earliest entering root in ``[0, H]`` whose foot
point is inside the open segment (the endpoints are point features of their own, so a contact
whose foot point is exactly an endpoint is the endpoint's).  The full contract, t = 0 rules
included, is ``edge_exact.exact_edge_contact``'s; this kernel answers the rows it can prove
and returns ``UNDECIDED`` for the rest, which the exact solver decides.

What this kernel proves, and how:

* Relative state by TwoSum: ``p - A`` and ``B - A`` are exact double-doubles, so map-sized
  coordinates (1e4 m and beyond) with millimetre gaps lose nothing.
* Signs of ``psi2 = w.a/2`` and ``psi1 = w.v`` are exact (two_prod and two_sum on the
  2 x 2 determinant; a wall parallel to the acceleration or velocity gives exactly 0).  They
  fix the shape of phi: which piece of [0, H] is decreasing, so whether an entering root
  can exist at all.
* Every other sign (phi at 0, at H, at the bracket's ends, the discriminant, phi' at H) is
  taken from float64 only beyond the rounding bound ``16 eps M(t)``, and from the
  compensated evaluation (double-double power-basis coefficients, compensated Horner) only
  beyond ``64 eps^2 M(t)``, with ``M(t) = |e|_1 (|g0|_1 + |v|_1 t + |a|_1 t^2/2 + r)``
  bounding every term's magnitude.  Either bound is several times the worst-case rounding
  error of its evaluation (``_phi_dd`` derives the second's), so a sign that clears it is
  the sign of the exact value.
* A time is returned only inside a proved bracket ``phi(lo) > 0 > phi(hi)`` of adjacent
  floats (or of t's two neighbours; the entering root is the only + -> - crossing of a
  quadratic), so it lies within one ulp of the exact root; of two adjacent floats the one
  with the smaller ``|phi|`` is returned, in practice the nearest float.  First, though,
  one compensated value phi(t) and a Newton step t1 usually prove more at once: phi at
  t1's two midpoints is phi(t) plus ``phi'(t) x + k2 x^2`` for exact small offsets x, so
  signs there beyond the bound put the root between the midpoints -- t1 is *the* nearest
  float (``_nearest_from``).
* a = 0 exactly (constant velocity, the common tracker model) has its own closed form,
  ``_edge_straight``: psi is linear, only the side it moves towards can be entered, and
  the root ``(sigma psi0 - r L) / |psi1|`` comes from dd numerator and denominator built
  once, one compensated evaluation, one Newton step and the same midpoint proof, with
  selects rather than branches where the outcome is data-dependent.  What it cannot prove
  (t = 0 touches, motion within ~1e-15 rad of parallel, feet at an end to within
  rounding, roots at a midpoint to within the bound) goes on to the general path.
* The foot point must be proved inside the open segment on a proved bracket of the root:
  first on a wider bracket ``t +- w`` proved in float64 (w a few float error bounds over
  the slope), which settles most rows without the compensated evaluation, and on the
  one-ulp bracket otherwise.  Proved outside, the side has no edge contact (the end's
  corner has it).
* Touching at t = 0 (phi(0) within its bound of 0), near-tangent grazes, a foot point at an
  endpoint to within rounding, and inputs outside [2^-300, 2^300] are left UNDECIDED.

References: J. R. Shewchuk, "Adaptive Precision Floating-Point Arithmetic and Fast Robust
Geometric Predicates", Discrete Comput. Geom. 18 (1997) (filtered predicates, exact
fallback); T. Ogita, S. M. Rump, S. Oishi, "Accurate sum and dot product", SIAM J. Sci.
Comput. 26 (2005) (error-free transformations).
"""
from __future__ import annotations

import math

from numba import njit

from circle_collision_ros.core.narrow.dd import (
    dd_add,
    dd_mul,
    next_down,
    next_up,
    two_prod,
    two_sum,
)
from circle_collision_ros.core.narrow.evaluate import EPS, UNDECIDED

INF = math.inf
NAN = math.nan
F_BOUND = 16.0 * EPS  # float64 evaluation: error < ~4 eps M(t), see the module docstring
DD_BOUND = 64.0 * EPS * EPS  # compensated evaluation: error < 10 eps^2 M(t) (_phi_dd)
# Inputs whose nonzero magnitudes lie in [2^-300, 2^300] keep every product below (up to
# 4 factors, times t^2 <= H^2 bounded separately) normal and finite; the rest go exact.
_TINY = 2.0 ** -300
_HUGE = 2.0 ** 300
_UNKNOWN = 2  # a sign the filters could not decide
_GENERAL = -2.0  # _edge_straight: not proved there, the general path decides
_P_MIN = 2.0 ** -900  # _edge_straight's range guards (its docstring)
_T_MIN = 2.0 ** -600
_P_MAX = 2.0 ** 900
_T_MAX = 2.0 ** 600
_D_MAX = 0.125


@njit(cache=True, error_model="numpy", inline="always")
def _nz(x):
    """|x| for the scale window's minimum: zeros are exempt."""
    return x if x != 0.0 else INF


@njit(cache=True, error_model="numpy", inline="always")
def _certain(x, err):
    """+1 or -1 when |x| > err proves the sign, else _UNKNOWN."""
    if x > err:
        return 1
    if x < -err:
        return -1
    return _UNKNOWN


@njit(cache=True, error_model="numpy", inline="always")
def _det_sign(exh, exl, eyh, eyl, x, y):
    """Exact sign of ``w.(x, y) = e_x y - e_y x`` (0 exactly when it is 0), or _UNKNOWN.

    The high products and their rounding errors are exact (two_prod); the low parts of e
    add less than 2u of the products' size, so a two_sum head beyond 4u of it decides.
    When the head cancels exactly and e has no low part, the sign of the exact error terms
    decides, 0 included: that is the wall parallel to the motion, which must be exact.
    """
    p1, e1 = two_prod(exh, y)
    p2, e2 = two_prod(eyh, x)
    s, es = two_sum(p1, -p2)
    size = abs(p1) + abs(p2)
    if abs(s) > 2.0 * EPS * size:
        return 1 if s > 0.0 else -1
    if s == 0.0 and es == 0.0 and exl == 0.0 and eyl == 0.0:
        d = e1 - e2  # a float difference is 0 only when exact, and keeps the exact sign
        if d == 0.0:
            return 0
        return 1 if d > 0.0 else -1
    return _UNKNOWN


@njit(cache=True, error_model="numpy", inline="always")
def _dd_dot(ah, al, bh, bl, ch, cl, dh, dl):
    """``a b + c d`` for dd factors, as a dd (error ~6u^2 of ``|a b| + |c d|``)."""
    p1h, p1l = dd_mul(ah, al, bh, bl)
    p2h, p2l = dd_mul(ch, cl, dh, dl)
    return dd_add(p1h, p1l, p2h, p2l)


@njit(cache=True, error_model="numpy", inline="always")
def _dd_dot_f(ah, al, b, ch, cl, d):
    """``a b + c d`` for dd a, c and float b, d, as a dd: the high products are exact
    (two_prod) and their sum exact (two_sum); only the low terms round, by ~2u^2 of
    ``|a b| + |c d|``."""
    p1, e1 = two_prod(ah, b)
    p2, e2 = two_prod(ch, d)
    sh, sl = two_sum(p1, p2)
    sl += (e1 + al * b) + (e2 + cl * d)
    return two_sum(sh, sl)


@njit(cache=True, error_model="numpy", inline="always")
def _horner_dd(c, t):
    """``(c2 t + c1) t + c0`` for dd coefficients ``c = (c0h, c0l, c1h, c1l, c2h, c2l)`` and
    a float t, by compensated Horner: each step's product and sum errors are exact
    (two_prod, two_sum) and carried, with the coefficients' low parts, in a float
    correction.  Returns (value, correction); their sum errs from the value of the dd
    coefficients by less than 24u^2 of ``|c2| t^2 + |c1| t + |c0|`` (each step's
    correction is below u of its terms and is summed with relative error < 4u), as a
    double-double evaluation would, at about half its cost.

    Reference: S. Graillat, P. Langlois, N. Louvet, "Compensated Horner scheme", Research
    Report RR2005-04, Univ. Perpignan (2005).
    """
    p, pe = two_prod(c[4], t)
    s, se = two_sum(p, c[2])
    err = c[5] * t + pe + se + c[3]
    p, pe = two_prod(s, t)
    s, se = two_sum(p, c[0])
    return s, err * t + pe + se + c[1]


@njit(cache=True, error_model="numpy", inline="always")
def _rl_dd(exh, exl, eyh, eyl, r):
    """``r L`` as a dd, L = |e| from Q = e.e in dd (exact products and sum of the high
    parts, the low parts' first-order terms; the dropped ``exl^2 + eyl^2`` is below u^2 Q)
    with sqrt's Newton correction: within ~4u^2 of ``r |e|`` (the estimate in _phi_dd's
    budget; a worst-case count of every rounding gives < 26u^2, still far inside it)."""
    qh, ql = two_prod(exh, exh)
    q2h, q2l = two_prod(eyh, eyh)
    qh, ql2 = two_sum(qh, q2h)
    ql = ql + q2l + ql2 + 2.0 * (exh * exl + eyh * eyl)
    Lh = math.sqrt(qh)
    sqh, sql = two_prod(Lh, Lh)
    Ll = ((qh - sqh) - sql + ql) / (2.0 * Lh)
    rLh, rLl = two_prod(r, Lh)
    return rLh, rLl + r * Ll


@njit(cache=True, error_model="numpy", inline="always")  # inlined: shares sqrt(Q) with its caller
def _psi_dd(gxh, gxl, gyh, gyl, exh, exl, eyh, eyl, vx, vy, ax, ay, r):
    """``r L`` as a dd (L from Q = e.e in dd, with sqrt's Newton correction) and the dd
    power-basis coefficients of ``psi = w.g(t)`` (a 6-tuple for ``_horner_dd``).

    Each coefficient is a 2-term dot product of exact inputs (g0 and e are TwoSum dd's, v
    and a floats, halving a is exact), so it errs by ~6u^2 of its term sizes, which
    ``M(t)`` bounds.
    """
    rLh, rLl = _rl_dd(exh, exl, eyh, eyl, r)
    c0 = _dd_dot(exh, exl, gyh, gyl, -eyh, -eyl, gxh, gxl)
    c1 = _dd_dot_f(exh, exl, vy, -eyh, -eyl, vx)
    c2 = _dd_dot_f(exh, exl, 0.5 * ay, -eyh, -eyl, 0.5 * ax)
    return rLh, rLl, (c0[0], c0[1], c1[0], c1[1], c2[0], c2[1])


@njit(cache=True, error_model="numpy")
def _pi_coeffs_dd(gxh, gxl, gyh, gyl, exh, exl, eyh, eyl, vx, vy, ax, ay):
    """The dd power-basis coefficients of ``pi = e.g(t)`` (same errors as ``_psi_dd``'s)."""
    c0 = _dd_dot(exh, exl, gxh, gxl, eyh, eyl, gyh, gyl)
    c1 = _dd_dot_f(exh, exl, vx, eyh, eyl, vy)
    c2 = _dd_dot_f(exh, exl, 0.5 * ax, eyh, eyl, 0.5 * ay)
    return (c0[0], c0[1], c1[0], c1[1], c2[0], c2[1])


@njit(cache=True, error_model="numpy", inline="always")
def _phi_dd(sig, ps, rLh, rLl, t):
    """``sigma psi(t) - r L``, compensated (value as one float).

    Error, with u = eps/2 and ``T = |psi2| t^2 + |psi1| t + |psi0| <= M(t)``: the dd
    coefficients err by < 6u^2 of their term sizes (<= 6u^2 M(t) at t); compensated Horner
    by < 24u^2 T (each step's correction is below u of its terms and is summed with
    relative error < 4u); r L by < 4u^2 r |e|; the final two_sum is exact and its
    correction's sum errs by < 6u^2 M(t).  Total < 40u^2 M(t) = 10 eps^2 M(t): DD_BOUND
    (64 eps^2 M(t)) holds it with a 6x margin, and the last rounding keeps the sign of a
    value beyond that bound.
    """
    h, l = _horner_dd(ps, t)
    fh, fe = two_sum(sig * h, -rLh)
    return fh + (fe + (sig * l - rLl))


@njit(cache=True, error_model="numpy", inline="always")
def _pi_dd(pc, t):
    """``e.g(t)``, compensated (value as one float; error as ``_phi_dd``'s, < 10 eps^2 of
    ``M(t) + |e|^2``)."""
    h, l = _horner_dd(pc, t)
    return h + l


@njit(cache=True, error_model="numpy", inline="always")
def _foot(q_lo, q_hi, dip, Q, err):
    """Where the foot point is over a bracket [lo, hi] of the root, from ``pi = e.g`` at its
    ends (each within ``err``): +1 inside the open segment (0 < pi < Q) on all of it, -1
    outside it ([0, Q] excluded) on all of it, 0 not proved.  ``dip`` bounds how far the
    quadratic pi strays beyond its end values inside the bracket (``|pi2| (hi - lo)^2``);
    Q = e.e is itself rounded, by less than ``4 eps Q``."""
    e = err + dip
    eQ = 4.0 * EPS * Q
    if min(q_lo, q_hi) > e and Q - max(q_lo, q_hi) > e + eQ:
        return 1
    if max(q_lo, q_hi) < -e or min(q_lo, q_hi) - Q > e + eQ:
        return -1
    return 0


@njit(cache=True, error_model="numpy", inline="always")
def _clamped_vertex(tv, H):
    """The vertex time clamped to [0, H] (NaN, from 0 / 0, to 0): the quadratic's value
    there is then a value on [0, H] -- at the vertex when it lies inside, else exactly
    an end's (the same expression) -- so taking it into a range is always valid, and
    needs no branch (which the sign of tv would mispredict)."""
    tv = tv if tv > 0.0 else 0.0
    return tv if tv < H else H


@njit(cache=True, error_model="numpy", inline="always")
def _quad_range(q0, q1, q2, H):
    """(min, max) over t in [0, H] of the float ``q0 + t (q1 + t q2)`` at 0, H and the
    vertex (clamped); ``q2 = 0`` gives an infinite or NaN vertex time, clamped to an end."""
    qH = q0 + H * (q1 + H * q2)
    tv = _clamped_vertex(-q1 / (2.0 * q2), H)
    x = q0 + tv * (q1 + tv * q2)
    return min(min(q0, qH), x), max(max(q0, qH), x)


@njit(cache=True, error_model="numpy", inline="always")
def _box_misses(c0, c1, c2, s0, s1, r, H):
    """True when the centre's coordinate ``c0 + c1 t + c2 t^2 / 2`` stays more than r
    beyond the segment's range [s0, s1] (either order) on all of [0, H] (finite H)."""
    cH = c0 + H * (c1 + 0.5 * H * c2)
    tv = _clamped_vertex(-c1 / c2, H)
    cv = c0 + tv * (c1 + 0.5 * tv * c2)
    lo_c = min(min(c0, cH), cv)
    hi_c = max(max(c0, cH), cv)
    # margin: 16 ulps of the coordinate's scale covers the rounding of these few
    # operations (the vertex value included, whose tv is itself rounded); _TINY covers
    # their absolute error where values are subnormal (the scale check comes after this
    # test); an overflow gives inf or NaN, never a rejection
    m = F_BOUND * (abs(c0) + H * abs(c1) + H * H * abs(c2) + abs(s0) + abs(s1) + r)
    m += _TINY
    return (lo_c - r - m > max(s0, s1)) | (hi_c + r + m < min(s0, s1))


@njit(cache=True, error_model="numpy", inline="always")
def _nearest_from(ft, et, t, slope, k2, s1, s2):
    """(t1, proved): a Newton step from ``ft``, phi(t) to within ``et``, and the proof that
    t1 is the nearest float to the entering root of the quadratic ``phi`` (decreasing
    there), from ft alone.

    ``slope = k1 + 2 k2 t`` is phi'(t) from the float coefficients and ``k2`` phi's
    leading one; ``s1 = |e|_1 (|v|_1 + |a|_1 t)`` and ``s2 = |e|_1 |a|_1`` bound their
    sizes.  The float coefficients (products of high parts, low parts dropped, three
    roundings) err by < 3u |e|_1 |v|_1 and < 1.5u s2, so ``|slope - phi'(t)| < 5u s1``
    (with its two roundings) and ``|k2 - k2*| < 1.5u s2``.  With ``|t1 - t| <= t / 8``,
    ``d = t1 - t`` is exact (Sterbenz) and so are ``x = d - h-`` and ``x = d + h+`` (h
    half the gap to t1's neighbours; as in ``_edge_straight``), and exactly
    ``phi(t + x) = phi(t) + phi'(t) x + k2* x^2``.  Computed as
    ``(ft + slope x) + k2 x x``, it errs by < ``et + 5u s1 |x| + 2.5u s2 x^2 +
    u (|ft| + 2 |slope x|)`` (the two roundings of ``k2 x x`` are below u s2 x^2; those of
    ``slope x`` and of the sum below u |slope x| and u |ft + slope x|; the last sum's
    rounding keeps the sign of a value compared with a float), which the bound below
    holds (eps = 2u; ``et``, _phi_dd's bound, with its own 6x margin).  ``et`` above
    2^-900 keeps any subnormal rounding (< 2^-1074 an operation) far inside that margin.
    So ``phi(t1 - h-) > 0 > phi(t1 + h+)``, proved, puts the root strictly between t1's
    midpoints (a quadratic has one + -> - crossing): t1 is its nearest float.
    """
    t1 = t - ft / slope
    d = t1 - t
    xl = d - (t1 - next_down(t1)) * 0.5
    xh = d + (next_up(t1) - t1) * 0.5
    yl = slope * xl
    yh = slope * xh
    bl = et + EPS * (4.0 * s1 * abs(xl) + 2.0 * s2 * xl * xl + abs(ft) + 2.0 * abs(yl))
    bh = et + EPS * (4.0 * s1 * abs(xh) + 2.0 * s2 * xh * xh + abs(ft) + 2.0 * abs(yh))
    ok = ((abs(d) <= _D_MAX * t) & (t1 > _T_MIN) & (et > _P_MIN)
          & ((ft + yl) + k2 * xl * xl > bl) & ((ft + yh) + k2 * xh * xh < -bh))
    return t1, ok


@njit(cache=True, error_model="numpy", inline="always")
def _edge_straight(px, py, vx, vy, r, Ax, Ay, Bx, By, H):
    """``edge_contact`` for a = 0 exactly (valid, finite inputs): the same answer, or
    ``_GENERAL`` where this closed form proves nothing (the general path then decides).

    With a = 0, ``psi(t) = psi0 + psi1 t`` is linear, so only the side
    ``sigma = -sign(psi1)`` can have an entering root, ``t* = N / D`` with
    ``N = phi(0) = sigma psi0 - r L`` and ``D = -sigma psi1 = |psi1| > 0``: phi is exactly
    ``N - D t``.  N and D are built once as unnormalised dd's; phi at the float quotient
    t costs one two_prod and six roundings, and that one value both corrects t to the
    root's nearest float t1 and proves it (phi at t1's midpoints is phi(t) minus D times
    an exact small offset) -- no quadratic, no Horner, no search.

    Error bounds (u = eps/2; ``P0 = |exh gyh| + |eyh gxh|``, ``P1 = |exh vy| + |eyh vx|``,
    below ``|e|_1 |g0|_1`` and ``|e|_1 |v|_1``, so every term below is a part of ``M(t)``):

    * ``psi1 = dh + dl``: the two_prod's and the two_sum are exact; ``dl`` gathers five
      terms each below u P1 with five roundings, each below u of a partial sum of at most
      4u P1: within 20u^2 P1 of psi1.  ``psi0 = ch + cl`` likewise (the products of two
      low parts, below u^2 P0, dropped; eight roundings): within 18u^2 P0.
    * ``r L = rLh + rLl``: Q = e.e as a dd to 10u^2 Q (five roundings of terms below
      2u Q, and the dropped ``exl^2 + eyl^2``), ``Lh = sqrt(qh)`` and one Newton
      correction ``(Q - Lh^2) / (2 Lh)`` (|correction| < 2.5u L, so its truncation is
      below 3.2u^2 L), formed with a reciprocal of qh taken alongside the sqrt (three
      roundings: 7.5u^2 L) from a residual rounded twice and Q's low part (17u^2 Q, so
      8.5u^2 L): L within 20u^2 L, and r L within 26u^2 r L after the two roundings of
      ``r Ll``; L <= |e|_1.
    * N = Nh + Ne + (sigma cl) - rLl (Nh + Ne = sigma ch - rLh exactly, two_sum), within
      18u^2 P0 + 26u^2 r |e|_1 + u |Nc| (Nc = Ne + sigma cl, |Nc| < 6u (P0 + r |e|_1)):
      40u^2 m0, m0 = |e|_1 (|g0|_1 + r).  And ``|N - Nh| < 8u m0 < F_BOUND m0`` (|Nc|
      and |rLl| < 1.1u r L), so Nh's sign beyond that bound is N's; the same holds for
      the float ``-sigma ch - rLh`` against ``-sigma psi0 - r L``.
    * phi(t) from ``p + pe = Dh t`` (exact) as
      ``F = ((((Nh - p) - pe) - Dl t) + Nc) - rLl``: besides N's and D's errors
      (40u^2 m0 + 20u^2 P1 t), six roundings, each below u of its result; the results
      are below ``|Nh - p|`` plus terms below 6u M(t), and the last is F: at most
      ``4u |Nh - p| + u |F| + 36u^2 M(t)``.

    So ``|F - phi(t)| < 100u^2 M(t) + 4u |Nh - p| + u |F|``, which
    ``E = DD_BOUND M(t) + eps (2 |Nh - p| + |F|)`` (DD_BOUND = 256u^2) holds, with the
    20u^2 M(t) the proof below adds, with a 2x margin (the bound's own rounding, a few u
    of it, included).

    The nearest float: ``t1 = t + F (1 - Dl / Dh) / Dh`` (a Newton step; any float would
    do: only the proof decides); with ``|t1 - t| <= t / 8``, ``d = t1 - t`` is exact
    (Sterbenz) and so are ``x- = d - h-`` and ``x+ = d + h+`` (h- = (t1 - pred t1) / 2,
    h+ = (succ t1 - t1) / 2; t and t1 lie in the same or adjacent binades, so all four
    are multiples of a quarter of ulp(t1), and |x| < t / 8 + ulp(t1) holds fewer than
    2^53 of them).  Exactly, ``phi(t1 -+ h) = phi(t) - D x``, with ``D x = Dh x + Dl x``
    up to 20u^2 P1 |x| (below 20u^2 M(t): |x| < t; counted above); the three roundings of
    ``(F - Dh x) - Dl x`` are below
    ``u (|F| + 3 |Dh x|)`` (|Dl| < Dh / 2).  So
    ``(F - Dh x-) - Dl x- > E + eps (|F| + 2 |Dh x-|)`` and the mirror test at x+ prove
    ``phi(t1 - h-) > 0 > phi(t1 + h+)``: the root lies strictly between the midpoints
    around t1, which is then its nearest float.  A rounded result compared with a float is
    safe both ways (rounding is monotone).

    Range: the general path's scale window ([2^-300, 2^300]) keeps every bound's product
    normal and finite; the proof also requires ``2^-900 < Dh t < 2^900`` (so ``pe`` is
    exact and the bound, above 2^-1000, dwarfs any subnormal rounding of the low terms)
    and ``2^-600 < t < 2^600`` (normal ulps); an overflow elsewhere gives inf or NaN,
    which fails every test.
    """
    gxh, gxl = two_sum(px, -Ax)
    gyh, gyl = two_sum(py, -Ay)
    exh, exl = two_sum(Bx, -Ax)
    eyh, eyl = two_sum(By, -Ay)
    agx, agy, aex, aey, avx, avy = abs(gxh), abs(gyh), abs(exh), abs(eyh), abs(vx), abs(vy)
    # the general path's scale window (non-zero magnitudes in [2^-300, 2^300]): first
    # without the zero exemption, which decides the common row; zeros take the full test
    Le = aex + aey
    Lg = agx + agy
    Lv = avx + avy
    big = max(max(Le, Lg), max(Lv, r))  # a sum of two is at most twice its largest part
    small = min(min(min(agx, agy), min(aex, aey)), min(min(avx, avy), r))
    if not (big <= _HUGE and small >= _TINY):
        small = min(min(min(_nz(agx), _nz(agy)), min(_nz(aex), _nz(aey))),
                    min(min(_nz(avx), _nz(avy)), _nz(r)))
        if not (big <= _HUGE and small >= _TINY):
            return _GENERAL

    # psi1 = w.v as dh + dl: |dl - exact low| < 20u^2 Le Lv and the exact low part is below
    # 3.1u Le Lv, so |dh| > 4 eps Le Lv (8u) proves sign(psi1) = sign(dh) and |Dl| < Dh / 2.
    # Smaller |dh| (motion within ~1e-15 rad of parallel to the wall, or exactly parallel)
    # goes to the general path, whose exact sign test handles it.
    p1, q1 = two_prod(exh, vy)
    p2, q2 = two_prod(eyh, vx)
    dh, dse = two_sum(p1, -p2)
    if not (abs(dh) > 4.0 * EPS * Le * Lv):
        return _GENERAL
    sig = -1.0 if dh > 0.0 else 1.0  # the side whose phi decreases
    Dh = abs(dh)
    Dl = -sig * ((dse + (q1 - q2)) + (exl * vy - eyl * vx))
    # psi0 = w.g0 as ch + cl, r L as rLh + rLl (docstring bounds)
    p1, q1 = two_prod(exh, gyh)
    p2, q2 = two_prod(eyh, gxh)
    ch, cse = two_sum(p1, -p2)
    qh, ql = two_prod(exh, exh)
    q2h, q2l = two_prod(eyh, eyh)
    qh, ql2 = two_sum(qh, q2h)
    Lh = math.sqrt(qh)
    rLh, rLe = two_prod(r, Lh)
    m0 = Le * (Lg + r)
    Nh, Ne = two_sum(sig * ch, -rLh)
    e0 = F_BOUND * m0  # |N - Nh| < 4 eps m0: the sign of Nh beyond e0 is N's
    if not (Nh > e0):
        # phi_sigma(0) < 0: no entering root on this side, and the other side's phi
        # increases.  phi_-sigma(0) = -sigma psi0 - r L (its float value within 4 eps m0
        # likewise) > 0: beyond the band on the side it moves away to; < 0: inside the
        # band, an overlap if the foot point is inside the open segment, else no entering
        # root at all.  pi0 in float errs by < 4 eps Le Lg and Q by < 3 eps Q (dropped low
        # parts, roundings): inside F_BOUND (m0 + Le^2), as in the general path.
        if not (Nh < -e0):
            return _GENERAL  # a touch at t = 0 to within rounding: the exact rules
        n1 = -sig * ch - rLh
        if n1 > e0:
            return INF
        if not (n1 < -e0):
            return _GENERAL
        pi0 = exh * gxh + eyh * gyh
        eq = F_BOUND * (m0 + Le * Le)
        if (pi0 > eq) & (qh - pi0 > eq):
            return 0.0
        return INF if (pi0 < -eq) | (pi0 - qh > eq) else _GENERAL

    # N > 0 proved: the rest is written with selects only (every candidate computed, the
    # proved one kept), so the row's outcome costs no mispredicted branch
    cl = (cse + (q1 - q2)) + ((exh * gyl - eyh * gxl) + (exl * gyh - eyl * gxh))
    ql = ql + q2l + ql2 + 2.0 * (exh * exl + eyh * eyl)
    sqh, sql = two_prod(Lh, Lh)
    rLl = rLe + r * (((qh - sqh) - sql + ql) * (Lh * (0.5 / qh)))
    Nc = Ne + sig * cl
    inv = 1.0 / Dh
    t = Nh * inv
    p, pe = two_prod(Dh, t)
    a = Nh - p
    F = (((a - pe) - Dl * t) + Nc) - rLl
    Mt = Le * (Lg + Lv * t + r)
    E = DD_BOUND * Mt + EPS * (2.0 * abs(a) + abs(F))
    # 1 / D to first order in Dl / Dh, which matters near parallel (|Dl| ~ u Le Lv is
    # then not far below Dh); off the path of t and F
    t1 = t + F * (inv * (1.0 - Dl * inv))
    d = t1 - t
    xl = d - (t1 - next_down(t1)) * 0.5
    xh = d + (next_up(t1) - t1) * 0.5
    yl = Dh * xl
    yh = Dh * xh
    proved = ((p > _P_MIN) & (p < _P_MAX) & (t > _T_MIN) & (t < _T_MAX)
              & (abs(d) <= _D_MAX * t)
              & ((F - yl) - Dl * xl > E + EPS * (abs(F) + 2.0 * abs(yl)))
              & ((F - yh) - Dl * xh < -(E + EPS * (abs(F) + 2.0 * abs(yh)))))
    # the foot point at t* (a proved result has |t* - t| < |d| + ulp(t1) / 2, below
    # |d| + eps t (t1 < 9t / 8), and |pi1| < Le Lv (1 + u)): pi(t*) is within
    # Le Lv (|d| + eps t) (1 + u) of pi(t), whose float value errs by < 6 eps M(t)
    # (dropped low parts, five roundings); Q as in _foot.  Taken at t, not t1, it runs
    # alongside the proof.
    pi_t = (exh * gxh + eyh * gyh) + t * (exh * vx + eyh * vy)
    e = F_BOUND * (Mt + Le * Le) + Le * Lv * (abs(d) + EPS * t)
    eQ = e + 4.0 * EPS * qh
    # inside: pi_t > e and qh - pi_t > eQ; outside: pi_t < -e or pi_t - qh > eQ (one
    # comparison each, so they compile to selects, not to a mispredicted branch)
    res = t1 if min(pi_t - e, (qh - pi_t) - eQ) > 0.0 else _GENERAL
    res = INF if max(-pi_t - e, (pi_t - qh) - eQ) > 0.0 else res
    res = INF if t1 > H else res  # t* > t1 - h- > pred(t1) >= H
    res = _GENERAL if t1 == H else res  # t* may lie on either side of H
    return res if proved else _GENERAL  # the root near a midpoint, or out of range


@njit(cache=True, error_model="numpy")
def edge_contact(px, py, vx, vy, ax, ay, r, Ax, Ay, Bx, By, solid_side, H):
    """First contact time (s) of the circle with the open segment A-B's interior.

    0.0 for overlap at t = 0, inf for none in [0, H], NaN for invalid input, UNDECIDED where
    the proof fails (see the module docstring).  ``solid_side`` (+1 solid on the left of
    A -> B, -1 on the right, 0 a two-sided wall) only matters for a point body (r = 0)
    touching at t = 0, which is always UNDECIDED here.
    """
    chk = px + py + vx + vy + ax + ay + r + Ax + Ay + Bx + By
    if not (chk - chk == 0.0) or not (r >= 0.0) or not (H >= 0.0) or (Ax == Bx and Ay == By):
        return NAN
    if ax == 0.0 and ay == 0.0:  # straight: the closed form decides nearly every row
        res = _edge_straight(px, py, vx, vy, r, Ax, Ay, Bx, By, H)
        if res != _GENERAL:
            return res
    # --- cheap, exact-safe rejection: the swept box of the centre against the segment's box
    if H < INF:
        if _box_misses(px, vx, ax, Ax, Bx, r, H) or _box_misses(py, vy, ay, Ay, By, r, H):
            return INF

    gxh, gxl = two_sum(px, -Ax)
    gyh, gyl = two_sum(py, -Ay)
    exh, exl = two_sum(Bx, -Ax)
    eyh, eyl = two_sum(By, -Ay)
    big = max(abs(gxh), abs(gyh), abs(exh), abs(eyh), abs(vx), abs(vy), abs(ax), abs(ay), r)
    if big > _HUGE:
        return UNDECIDED
    for x in (gxh, gyh, exh, eyh, vx, vy, ax, ay, r):
        if x != 0.0 and abs(x) < _TINY:
            return UNDECIDED
    Le = abs(exh) + abs(eyh)
    l1g = abs(gxh) + abs(gyh)
    l1v = abs(vx) + abs(vy)
    l1a = abs(ax) + abs(ay)

    # --- power-basis coefficients in float64 (high parts; bounds cover the low parts)
    psi0 = exh * gyh - eyh * gxh
    psi1 = exh * vy - eyh * vx
    psi2 = 0.5 * (exh * ay - eyh * ax)
    pi0 = exh * gxh + eyh * gyh
    pi1 = exh * vx + eyh * vy
    pi2 = 0.5 * (exh * ax + eyh * ay)
    Q = exh * exh + eyh * eyh
    rL = r * math.sqrt(Q)
    # the dd forms (r L, the power-basis coefficients) are built on first use: most rows
    # are decided from the float values above
    have_dd = False
    rLh, rLl = 0.0, 0.0
    ps = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)

    def m_at(t):
        return Le * (l1g + l1v * t + 0.5 * l1a * t * t + r)

    # --- the band: if |psi| stays beyond r L (or the foot point stays outside the segment)
    # on all of [0, H], no entering root counts
    if H < INF:
        lo_p, hi_p = _quad_range(psi0, psi1, psi2, H)
        lo_q, hi_q = _quad_range(pi0, pi1, pi2, H)
        # the vertex's own rounding (tv is rounded) is covered: psi is flat there
        err = 2.0 * F_BOUND * m_at(H)
        if lo_p - rL > err or hi_p + rL < -err:
            return INF
        errq = 2.0 * F_BOUND * (m_at(H) + Le * Le)
        if hi_q < -errq or lo_q - Q > errq:
            return INF

    # --- t = 0: overlap, or an exact touch (left to the exact solver)
    e0 = F_BOUND * m_at(0.0)
    sp0 = _certain(psi0 - rL, e0)  # phi_+(0)
    sm0 = _certain(-psi0 - rL, e0)  # phi_-(0)
    if sp0 == _UNKNOWN or sm0 == _UNKNOWN:
        rLh, rLl, ps = _psi_dd(gxh, gxl, gyh, gyl, exh, exl, eyh, eyl, vx, vy, ax, ay, r)
        have_dd = True
        d0 = DD_BOUND * m_at(0.0)
        sp0 = _certain(_phi_dd(1.0, ps, rLh, rLl, 0.0), d0)
        sm0 = _certain(_phi_dd(-1.0, ps, rLh, rLl, 0.0), d0)
        if sp0 == _UNKNOWN or sm0 == _UNKNOWN:
            return UNDECIDED
    if sp0 < 0 and sm0 < 0:  # |psi0| < r L: inside the band
        eq = F_BOUND * (m_at(0.0) + Le * Le)
        if pi0 > eq and Q - pi0 > eq:
            return 0.0
        if not (pi0 < -eq or pi0 - Q > eq):
            return UNDECIDED  # foot point at an endpoint to within rounding

    s2 = 0 if (ax == 0.0 and ay == 0.0) else _det_sign(exh, exl, eyh, eyl, ax, ay)
    s1 = 0 if (vx == 0.0 and vy == 0.0) else _det_sign(exh, exl, eyh, eyl, vx, vy)
    if s2 == _UNKNOWN or s1 == _UNKNOWN:
        return UNDECIDED

    best = INF
    for side in (1, -1):
        sig = float(side)
        f0 = sp0 if side == 1 else sm0
        k2s = side * s2
        k1s = side * s1
        k0 = sig * psi0 - rL
        k1 = sig * psi1
        k2 = sig * psi2
        # sign of phi at H (at infinity: the leading coefficient's)
        if H == INF:
            fH = k2s if k2s != 0 else (k1s if k1s != 0 else f0)
        else:
            fH = _certain(k0 + H * (k1 + H * k2), F_BOUND * m_at(H))
            if fH == _UNKNOWN:
                if not have_dd:
                    rLh, rLl, ps = _psi_dd(gxh, gxl, gyh, gyl, exh, exl, eyh, eyl, vx, vy, ax,
                                           ay, r)
                    have_dd = True
                fH = _certain(_phi_dd(sig, ps, rLh, rLl, H), DD_BOUND * m_at(H))
                if fH == _UNKNOWN:
                    return UNDECIDED
        # does phi have an entering root in (0, H]?  (signs only; see the module docstring)
        found = False
        if k2s == 0:
            found = k1s < 0 and f0 > 0 and fH < 0
        else:
            # sign of phi'(H) = k1 + 2 k2 H: where the vertex lies against H
            if H == INF:
                dH = k2s
            else:
                dH = _certain(k1 + 2.0 * H * k2, F_BOUND * Le * (l1v + l1a * H) * 4.0)
                if dH == _UNKNOWN:
                    return UNDECIDED
            disc = k1 * k1 - 4.0 * k2 * k0
            # |error| of disc: both products carry the coefficients' relative errors
            disc_err = 4.0 * F_BOUND * (Le * l1v * Le * l1v
                                        + 2.0 * Le * l1a * (Le * (l1g + r)))
            if k2s > 0:  # convex: decreasing on [0, min(tv, H)]
                if f0 > 0 and k1s < 0:
                    if fH < 0:
                        found = True
                    elif dH > 0:  # the minimum lies inside (0, H): its sign is -sign(disc)
                        sd = _certain(disc, disc_err)
                        if sd == _UNKNOWN:
                            return UNDECIDED
                        found = sd > 0
            else:  # concave: decreasing on [max(tv, 0), H]
                if fH < 0:
                    if f0 > 0:
                        found = True
                    elif k1s > 0 and dH < 0:  # the maximum lies inside (0, H)
                        sd = _certain(disc, disc_err)
                        if sd == _UNKNOWN:
                            return UNDECIDED
                        found = sd > 0
        if not found:
            continue
        # candidate: the entering root in cancellation-free form
        if k2s == 0:
            t = -k0 / k1
        else:
            sq = math.sqrt(max(disc, 0.0))
            t = 2.0 * k0 / (-k1 + sq) if k1 < 0.0 else (-k1 - sq) / (2.0 * k2)
        if not (t > 0.0):
            t = 0.0
        if t > H:
            t = H
        # a float-proved bracket [t - w, t + w] around the root, w a few times the float
        # error over the slope: enough to settle most foot points without double-double
        foot = 0  # foot point on the root's bracket: 1 inside, -1 outside, 0 not proved
        slope = k1 + 2.0 * k2 * t
        if slope < 0.0:
            w = 4.0 * F_BOUND * m_at(t) / -slope
            tl, th = t - w, t + w
            if tl > 0.0 and th <= H and tl < t < th:
                fl_ok = k0 + tl * (k1 + tl * k2) > F_BOUND * m_at(tl)
                fh_ok = k0 + th * (k1 + th * k2) < -F_BOUND * m_at(th)
                if fl_ok and fh_ok:
                    foot = _foot(pi0 + tl * (pi1 + tl * pi2), pi0 + th * (pi1 + th * pi2),
                                 abs(pi2) * (th - tl) * (th - tl), Q,
                                 2.0 * F_BOUND * (m_at(th) + Le * Le))
        if foot < 0:
            continue  # the contact with the line is beyond an end: the end's (a corner)
        if not have_dd:
            rLh, rLl, ps = _psi_dd(gxh, gxl, gyh, gyl, exh, exl, eyh, eyl, vx, vy, ax, ay, r)
            have_dd = True
        # first, one compensated value: phi(t) = ft, one Newton step t1 = t - ft / slope,
        # and the proof that t1 is the root's nearest float from ft alone (its docstring)
        ok = False
        lo, hi = t, t
        if slope < 0.0 and t > _T_MIN:
            ft = _phi_dd(sig, ps, rLh, rLl, t)
            t1, ok = _nearest_from(ft, DD_BOUND * m_at(t), t, slope, k2,
                                   Le * (l1v + l1a * t), Le * l1a)
            # t1 = H leaves the root on either side of H: the bracket below decides it
            ok = ok and (H == INF or next_up(t1) <= H)
            if ok:
                t = t1
                lo, hi = next_down(t), next_up(t)
        # else bracket by proved signs, phi(lo) > 0 > phi(hi) with lo, hi adjacent floats or
        # t's two neighbours: the root is then within one ulp of the t returned
        for _ in range(0 if ok else 4):
            if t <= 0.0:
                t = next_up(0.0)
            ft = _phi_dd(sig, ps, rLh, rLl, t)
            ct = _certain(ft, DD_BOUND * m_at(t))
            lo, hi = next_down(t), next_up(t)
            # (signs are compared with == 1 / == -1: _UNKNOWN is 2, so "> 0" would take an
            # unproved sign for a positive one -- it did, returning times 2-4 ulps off on
            # near-parallel straight rows)
            if ct == 1:  # the root is above t: is it below t's successor?
                lo, flo = t, ft
                fhi = _phi_dd(sig, ps, rLh, rLl, hi)
                ok = _certain(fhi, DD_BOUND * m_at(hi)) == -1
            elif ct == -1:
                hi, fhi = t, ft
                flo = _phi_dd(sig, ps, rLh, rLl, lo)
                ok = _certain(flo, DD_BOUND * m_at(lo)) == 1
            else:  # phi(t) is 0 to within its bound: prove both neighbours
                flo = _phi_dd(sig, ps, rLh, rLl, lo)
                fhi = _phi_dd(sig, ps, rLh, rLl, hi)
                ok = (_certain(flo, DD_BOUND * m_at(lo)) == 1
                      and _certain(fhi, DD_BOUND * m_at(hi)) == -1)
            if ok:
                if ct != _UNKNOWN:  # of two adjacent floats, the one nearer the root
                    t = lo if flo < -fhi else hi
                break
            # Newton from the dd value (the slope needs no accuracy: only the bracket proves)
            slope = k1 + 2.0 * k2 * t
            if not (slope < 0.0):
                break
            t = t - ft / slope
            if not (t > 0.0) or t > H or t != t:
                break
        if not ok or hi > H and H < INF:
            return UNDECIDED
        if foot == 0:  # the foot point over the 1-ulp bracket, compensated
            pc = _pi_coeffs_dd(gxh, gxl, gyh, gyl, exh, exl, eyh, eyl, vx, vy, ax, ay)
            foot = _foot(_pi_dd(pc, lo), _pi_dd(pc, hi), abs(pi2) * (hi - lo) * (hi - lo), Q,
                         DD_BOUND * (m_at(hi) + Le * Le))
        if foot > 0:
            best = min(best, t)
        elif foot == 0:
            return UNDECIDED
    return best
