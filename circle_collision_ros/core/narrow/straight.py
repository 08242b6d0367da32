"""Constant relative velocity (da = 0 exactly): the certified closed form.

With ``da = 0`` the relative centre ``g(t) = dp + t dv`` is a line and
``f(t) = |g|^2 - R^2`` a quadratic, so the first contact needs no iteration:
the entering root in the cancellation-free form ``f0 / (-c0 + s)``, one
double-double polishing step, and the same certificate as every other
contact time (``robust._certified``: dd signs of f at t and its float
neighbours).  Constant velocity is the most common tracker model, so this is
written *without branches* (selects only): the batch kernels run it as its
own SIMD loop over the rows with ``da = 0`` (``fast.straight_rows``),
and the robust solver and the scalar entry points call the same function,
so a row's answer never depends on the path that decided it.

Each decision is certified (bounds next to the code); a row whose decision
is not certain comes out ``UNDECIDED`` and is decided exactly
(``exact``).
"""
from __future__ import annotations

import math

from numba import njit
from numba.extending import overload, register_jitable

from circle_collision_ros.core.narrow.dd import next_down, next_up, dd_add, dd_mul
from circle_collision_ros.core.narrow.evaluate import (DD_ERR, EPS, INF, UNDECIDED, dot, f0_err,
                                                       f_dd_inline, fmax, reach_miss, scale_at)


def _dd_cross2(Ph, Pl, Vh, Vl):
    """|dp x dv|^2 with each cross-product component from double-double
    products (no cancellation for near-collinear pairs), rounded to float64."""


@register_jitable(error_model="numpy")
def _dd_cross_comp(pi_h, pi_l, vj_h, vj_l, pj_h, pj_l, vi_h, vi_l):
    """dp_i dv_j - dp_j dv_i from dd products, rounded to float64."""
    a, b = dd_mul(pi_h, pi_l, vj_h, vj_l)
    e, f = dd_mul(pj_h, pj_l, -vi_h, -vi_l)
    xh, xl = dd_add(a, b, e, f)
    return xh + xl


@overload(_dd_cross2, inline="always")
def _ov_dd_cross2(Ph, Pl, Vh, Vl):
    if Ph.count == 2:
        def impl2(Ph, Pl, Vh, Vl):
            z = _dd_cross_comp(Ph[0], Pl[0], Vh[1], Vl[1], Ph[1], Pl[1], Vh[0], Vl[0])
            return 0.0 + z * z
        return impl2

    def impl3(Ph, Pl, Vh, Vl):
        x = _dd_cross_comp(Ph[1], Pl[1], Vh[2], Vl[2], Ph[2], Pl[2], Vh[1], Vl[1])
        y = _dd_cross_comp(Ph[2], Pl[2], Vh[0], Vl[0], Ph[0], Pl[0], Vh[2], Vl[2])
        z = _dd_cross_comp(Ph[0], Pl[0], Vh[1], Vl[1], Ph[1], Pl[1], Vh[0], Vl[0])
        return ((0.0 + x * x) + y * y) + z * z
    return impl3


def _dd_dot(Ph, Pl, Vh, Vl):
    """dp.dv in double-double (error <= ~8u^2 |dp||dv|), rounded to float64."""


@overload(_dd_dot, inline="always")
def _ov_dd_dot(Ph, Pl, Vh, Vl):
    if Ph.count == 2:
        def impl2(Ph, Pl, Vh, Vl):
            ah, al = dd_mul(Ph[0], Pl[0], Vh[0], Vl[0])
            ch, cl = dd_add(0.0, 0.0, ah, al)
            ah, al = dd_mul(Ph[1], Pl[1], Vh[1], Vl[1])
            ch, cl = dd_add(ch, cl, ah, al)
            return ch + cl
        return impl2

    def impl3(Ph, Pl, Vh, Vl):
        ah, al = dd_mul(Ph[0], Pl[0], Vh[0], Vl[0])
        ch, cl = dd_add(0.0, 0.0, ah, al)
        ah, al = dd_mul(Ph[1], Pl[1], Vh[1], Vl[1])
        ch, cl = dd_add(ch, cl, ah, al)
        ah, al = dd_mul(Ph[2], Pl[2], Vh[2], Vl[2])
        ch, cl = dd_add(ch, cl, ah, al)
        return ch + cl
    return impl3


@njit(cache=True, error_model="numpy", inline="always")
def straight(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, f0, H):
    """First contact for da == 0 exactly (Ah, Al all zero) given f(0) = f0 > 0
    certainly: the certified time, inf (proved) or UNDECIDED.  Selects only.

    Decisions, in the order they take effect:
    1. finite H and |dp| - H |dv| > R with rounding margin (``reach_miss``) -> inf;
    2. dv = 0: g is constant, f = f0 > 0 -> inf;
    3. c0 = dp.dv (double-double, error <= ~8u^2 |dp||dv|): within
       DD_ERR |dp||dv| of 0 -> UNDECIDED (the order of approach is then
       decided exactly); > 0 -> separating, |g| never decreases -> inf;
    4. miss distance d = |dp x dv| / |dv| from the dd cross product: d >
       R (1 + 8 eps) + DD_ERR |dp| -> inf (the bound is derived at the test:
       a relative part and an absolute one, ~14 u^2 |dp|, that matters for
       tiny bodies or points far apart);
    5. the entering root t = f0 / (s - c0), s = sqrt(|dv|^2 (R - d)(R + d))
       (no cancellation: s >= 0 > c0); the closest approach tm = -c0/|dv|^2
       bounds it.  Not yet polished, t > H does not prove the root is beyond
       H: if H < tm f decreases on [0, H] and the dd sign of f(H) decides
       (> bound -> inf; within it -> UNDECIDED; else the root is in [0, H]);
    6. one dd Newton step on the quadratic (slope 2 (s - g.dv)), kept in
       [0, hi]; a result beyond H -> inf;
    7. the certificate of ``robust._certified``: f(pred(t)) > 0 and
       f(t) < 0 or f(succ(t)) < 0 (succ(t) <= H), each beyond the dd error
       bound DD_ERR (S^2 + R^2) -- the exact first contact then lies within
       one ulp of t (f decreases on [0, tm]); else UNDECIDED.
    """
    P2 = dot(Ph, Ph)
    V2 = dot(Vh, Vh)
    nP = math.sqrt(P2)
    nV = math.sqrt(V2)
    R = Rh + Rl
    R2 = Rh * Rh
    far = reach_miss(nP, nV, 0.0, Rh, Rl, H)
    static = V2 == 0.0
    c0 = _dd_dot(Ph, Pl, Vh, Vl)
    c_unc = abs(c0) <= DD_ERR * math.sqrt(P2 * V2)
    recede = c0 > 0.0
    # Miss test.  Each cross-product component x_i y_j - x_j y_i comes from
    # two dd products (each within 8u^2 |x_i||y_j|: the dropped lo*lo term and
    # three roundings of O(u^2) terms), an accurate dd add (3u^2 relative)
    # and a rounding to float64 (u relative): within (u + 3u^2) |z| +
    # 8.01u^2 (|x_i||y_j| + |x_j||y_i|) <= ... + 8.01u^2 |dp||dv|
    # (Cauchy-Schwarz), so |dp x dv| (D <= 3 components) within ~2u relative
    # + 14u^2 |dp||dv|.  The squares, the sum, V2 from the high parts (|Vl| <=
    # u|Vh|), the division and sqrt add <= ~5u relative in all, so the
    # float d = d_exact (1 +- 5u) +- 14.1u^2 |dp|.  The absolute part is
    # not relative to R: for R < ~u |dp| (tiny bodies, points far apart) it
    # exceeds the relative margin, and a contact of bodies smaller than it
    # (head-on or grazing) was reported as a miss
    # (tests/core/narrow/test_narrow_straight.py: test_tiny_bodies_far_apart).
    # So: d > R (1 + 8 eps) + DD_ERR nP (64u^2 |dp| (1 - 3u) >= 14.1u^2
    # |dp| (1 + 5u), nP from the high parts) gives d_exact > R (1 + 16u) /
    # (1 + 5u) >= the exact R = r_a + r_b (R is it rounded, u relative):
    # a proved miss.  Rows with d inside the margin go on; the certificate
    # (7.) cannot pass unless f really turns negative beyond its dd error, so
    # a graze too close to call is UNDECIDED and decided exactly.
    d = math.sqrt(_dd_cross2(Ph, Pl, Vh, Vl) / V2)
    miss = d > R * (1.0 + 8.0 * EPS) + DD_ERR * nP
    s = math.sqrt(V2 * fmax(R - d, 0.0) * (R + d))
    t = f0 / (s - c0)
    tm = -c0 / V2
    beyond = not (t <= H)
    at_h = beyond & (H < tm)  # f decreasing on [0, H]: the sign of f(H) decides
    hi = H if at_h else tm
    t = (hi if hi < t else t) if beyond else t
    fx, g = f_dd_inline(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, t)  # at H when at_h
    SH = nP + H * nV
    eH = DD_ERR * (SH * SH + R * R)
    h_miss = at_h & (fx > eH)
    h_unc = at_h & (not (fx < -eH))
    den = s - dot(g, Vh)
    tn = t + fx / den
    t = tn if ((den > 0.0) & (tn >= 0.0) & (tn <= hi)) else t
    late = not (t <= H)
    # 7. certificate (nA = 0: scale_at is |dp| + t |dv|)
    tp = next_down(t)
    fp, _g1 = f_dd_inline(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, tp)
    Sp = scale_at(nP, nV, 0.0, tp)
    ft, _g2 = f_dd_inline(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, t)
    St = scale_at(nP, nV, 0.0, t)
    tq = next_up(t)
    fq, _g3 = f_dd_inline(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, tq)
    Sq = scale_at(nP, nV, 0.0, tq)
    cert = ((t > 0.0) & (t <= H)
            & ((not (tp > 0.0)) | (fp > DD_ERR * (Sp * Sp + R2)))
            & ((ft < -DD_ERR * (St * St + R2))
               | ((tq <= H) & (fq < -DD_ERR * (Sq * Sq + R2)))))
    res = t if cert else UNDECIDED
    res = INF if late else res
    res = UNDECIDED if h_unc else res
    res = INF if (h_miss | miss | recede) else res
    res = UNDECIDED if c_unc else res
    return INF if (far | static) else res


@njit(cache=True, error_model="numpy", inline="always")
def straight_rel(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, H):
    """``straight`` on the exact relative state of a row with da == 0,
    including t = 0: f(0) beyond its float error bound (``f0_err``, the
    robust solver's threshold, see ``robust._ttc_rel``) decides
    overlap -> 0.0 or the rest; closer to 0, and for H NaN (a row with
    invalid input), UNDECIDED."""
    P2 = dot(Ph, Ph)
    R2 = Rh * Rh
    f0 = P2 - R2
    e0 = f0_err(P2, R2)
    res = straight(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, f0, H)
    res = res if f0 > e0 else UNDECIDED
    res = 0.0 if f0 < -e0 else res
    return res if H >= 0.0 else UNDECIDED
