"""Narrow phase: first-contact time of two uniformly accelerated discs/spheres.

Model.  Body centres follow ``p(t) = p0 + v t + a t^2/2``.  With relative
quantities ``dp = p_a - p_b``, ``dv = v_a - v_b``, ``da = a_a - a_b`` and
``R = r_a + r_b`` the relative centre is ``g(t) = dp + t (dv + t da/2)`` and
the bodies touch when ``f(t) = |g(t)|^2 - R^2 = 0`` (a quartic in ``t``).

Method (numerical decisions are justified next to the code, DynamO
``stable_poly.hpp`` style):

1. Relative quantities are formed *exactly* as double-double values
   (TwoSum), so map/UTM coordinates (~1e6 m) lose nothing, and the answer
   is that of the inputs exactly as given.
2. The quartic is never expanded for root finding.  ``f`` is monotone
   between stationary points, which are roots of the cubic
   ``c(t) = g . g' = f'/2``; ``c`` is monotone between the roots of the
   quadratic ``q = c' = |g'|^2 + g . da``, which are found in closed form from
   its vertex.  Only *local minima* of ``f`` (``c`` crossing - to +) can start
   a contact, so at most two brackets are ever examined, in time order.
3. Every function is evaluated geometrically from ``g(t)`` (not from power
   coefficients); the sign of ``f`` at bracket ends and the final residual are
   evaluated in double-double, so tiny radii at large distances are safe.
4. Roots are found by a safeguarded step that is *exact for straight-line
   motion* (the entering root of the local quadratic model, written in the
   cancellation-free form), falling back to bisection; then polished with a
   double-double residual, which gives ~0.5 ulp for well-conditioned contacts.
5. A local minimum whose exact value is ``<= 0`` is a contact even if no
   float ``t`` makes ``f <= 0`` (tangent grazes, point bodies with ``R = 0``):
   the closest-approach distance is computed from the cross product
   ``|g x g'| / |g'|``, which does not cancel.

Public entry points
-------------------
``time_to_collision`` (vectorised numpy API) and ``_ttc_scalar`` (one pair,
an ``@njit`` function that other numba code can call directly::

    t = _ttc_scalar(pax, pay, paz, vax, vay, vaz, aax, aay, aaz, r_a,
                    pbx, pby, pbz, vbx, vby, vbz, abx, aby, abz, r_b, horizon)

use 0.0 for the z components in 2-D).  Both follow the same contract.

Input range: finite values with magnitudes below ~1e150 (so that squares and
FMA error terms do not overflow/underflow); relative accelerations whose
squared norm underflows (below ~1e-154 m/s^2) are treated as zero.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from circle_collision_ros.core.narrow_dd import (
    dd_add,
    dd_mul,
    dd_mul_d,
    dd_sqr,
    two_prod,
    two_sum,
)

__all__ = ["time_to_collision", "_ttc_scalar", "_ttc_kernel", "_ttc_kernel_par"]

_EPS = 2.220446049250313e-16  # float64 machine epsilon (2u)
_INF = math.inf
_NAN = math.nan

# --------------------------------------------------------------------------
# float64 geometric evaluations (used to *locate* things; never for signs that
# decide contact vs no contact, which use the double-double versions below)
# --------------------------------------------------------------------------


@njit(cache=True, inline="always")
def _g(P, V, A, t):
    # Horner in t: g = dp + t (dv + t da/2).  Absolute error ~u*S with
    # S = |dp| + t|dv| + t^2|da|/2, i.e. the scale of the terms, which is the
    # best any float64 evaluation can do; digits lost by cancellation near a
    # contact are recovered by the double-double residual later.
    h = 0.5 * t
    return (
        P[0] + t * (V[0] + h * A[0]),
        P[1] + t * (V[1] + h * A[1]),
        P[2] + t * (V[2] + h * A[2]),
    )


@njit(cache=True, inline="always")
def _gd(V, A, t):
    return (V[0] + t * A[0], V[1] + t * A[1], V[2] + t * A[2])


@njit(cache=True, inline="always")
def _dot(x, y):
    return x[0] * y[0] + x[1] * y[1] + x[2] * y[2]


@njit(cache=True, inline="always")
def _c(P, V, A, t):
    """f'(t)/2 = g . g' (geometric form, no power-basis coefficients)."""
    return _dot(_g(P, V, A, t), _gd(V, A, t))


@njit(cache=True, inline="always")
def _q(P, V, A, t):
    """c'(t) = |g'|^2 + g . da."""
    gd = _gd(V, A, t)
    return _dot(gd, gd) + _dot(_g(P, V, A, t), A)


# --------------------------------------------------------------------------
# double-double evaluations
# --------------------------------------------------------------------------


@njit(cache=True, inline="always")
def _g_comp_dd(ph, pl, vh, vl, ah, al, t, tth, ttl):
    # dp + t*dv + t^2*(da/2), every product and sum error-free up to ~u^2.
    # da/2 is an exact scaling.
    t1h, t1l = dd_mul_d(vh, vl, t)
    t2h, t2l = dd_mul(tth, ttl, 0.5 * ah, 0.5 * al)
    sh, sl = dd_add(ph, pl, t1h, t1l)
    return dd_add(sh, sl, t2h, t2l)


@njit(cache=True)
def _f_dd(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, t):
    """Return (f(t), g(t)) with f = |g|^2 - R^2 and g rounded to float64.

    Absolute error of f is ~u^2 (|g|^2 + R^2) + rounding of the result, so the
    *sign* of f is right unless |f| is below ~1e-31 of the squared scale
    (far inside the documented 1e-9 R^2 grazing slack) and g carries full
    relative precision even when |g| << |dp|.
    """
    tth, ttl = two_prod(t, t)
    gxh, gxl = _g_comp_dd(Ph[0], Pl[0], Vh[0], Vl[0], Ah[0], Al[0], t, tth, ttl)
    gyh, gyl = _g_comp_dd(Ph[1], Pl[1], Vh[1], Vl[1], Ah[1], Al[1], t, tth, ttl)
    gzh, gzl = _g_comp_dd(Ph[2], Pl[2], Vh[2], Vl[2], Ah[2], Al[2], t, tth, ttl)
    sh, sl = dd_sqr(Rh, Rl)
    fh, fl = -sh, -sl
    a, b = dd_sqr(gxh, gxl)
    fh, fl = dd_add(fh, fl, a, b)
    a, b = dd_sqr(gyh, gyl)
    fh, fl = dd_add(fh, fl, a, b)
    a, b = dd_sqr(gzh, gzl)
    fh, fl = dd_add(fh, fl, a, b)
    return fh + fl, (gxh + gxl, gyh + gyl, gzh + gzl)


@njit(cache=True, inline="always")
def _cross2(x, y):
    """|x cross y|^2 (3-D; z = 0 for planar inputs)."""
    cx = x[1] * y[2] - x[2] * y[1]
    cy = x[2] * y[0] - x[0] * y[2]
    cz = x[0] * y[1] - x[1] * y[0]
    return cx * cx + cy * cy + cz * cz


@njit(cache=True, inline="always")
def _entry_step(f, g, gd, A, R):
    """Step from t to the entering root of the local model of f.

    Model: f(t+d) ~ f + 2 c d + a2 d^2 with c = g.g', a2 = |g'|^2 + g.da
    (exact Taylor terms; the neglected d^3, d^4 terms vanish for da = 0, so
    the step is *exact* for straight-line motion and converges faster than
    Newton otherwise).  The discriminant c^2 - a2 f is rewritten with the
    Lagrange identity c^2 - |g'|^2 |g|^2 = -|g x g'|^2 as
        |g'|^2 (R - d)(R + d) - (g.da) f,   d = |g x g'| / |g'|
    which has no cancellation at grazing incidence (R ~ d), and the root is
    taken in the form f / (-c + sqrt(disc)) when c <= 0 (approaching: no
    cancellation), else (-c - sqrt(disc)) / a2.  Returns NaN when the model
    has no real root (caller then bisects).
    """
    c = _dot(g, gd)
    gd2 = _dot(gd, gd)
    ga = _dot(g, A)
    if gd2 > 0.0:
        d = math.sqrt(_cross2(g, gd) / gd2)
    else:
        d = math.sqrt(_dot(g, g))
    disc = gd2 * (R - d) * (R + d) - ga * f
    if disc < 0.0:
        # The model just misses zero: a (near-)double root, e.g. point bodies
        # (R = 0, f = |g|^2) or a tangent graze.  Step to the model's vertex
        # -c/a2, which is exact for a double root (Newton would only halve
        # the distance per step).  The caller's bracket keeps it safe.
        a2 = gd2 + ga
        if a2 > 0.0:
            return -c / a2
        if c != 0.0:
            return -0.5 * f / c  # plain Newton
        return _NAN
    s = math.sqrt(disc)
    if c <= 0.0:
        den = s - c
        if den == 0.0:
            return 0.0 if f == 0.0 else _NAN
        return f / den
    a2 = gd2 + ga
    if a2 <= 0.0:
        return -0.5 * f / c
    return -(c + s) / a2


@njit(cache=True)
def _solve_entry(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, lo, hi):
    """First root of f in [lo, hi] given f(lo) > 0 >= f(hi) and a unique root.

    Coarse phase in float64 with the model step, safeguarded by the bracket
    (any step leaving (lo, hi) becomes a bisection, so it always converges);
    then up to three double-double polishing steps, kept inside the original
    bracket.  The polished residual is accurate to ~u^2 |g|^2, so the result
    is within ~0.5 ulp + |residual error / f'| of the exact root.
    """
    R = Rh
    lo0 = lo
    hi0 = hi
    t = lo
    prev = _INF
    for _ in range(100):
        g = _g(Ph, Vh, Ah, t)
        ng = math.sqrt(_dot(g, g))
        f = (ng - R) * (ng + R)
        if f > 0.0:
            lo = t
        else:
            hi = t
        if f == 0.0:
            break
        gd = _gd(Vh, Ah, t)
        step = _entry_step(f, g, gd, Ah, R)
        tn = t + step
        if abs(step) <= 32.0 * _EPS * abs(t):
            t = tn  # converged (checked before the safeguard, see _root_c)
            break
        if not (tn > lo and tn < hi):
            tn = 0.5 * (lo + hi)
        # Stop at the float64 noise floor: either the step is tiny, or it is
        # small and no longer shrinking (the residual is rounding noise, so
        # further float64 steps would wander).  The dd polish takes over.
        ast = abs(tn - t)
        if (ast <= 32.0 * _EPS * abs(tn) or hi - lo <= 32.0 * _EPS * hi
                or (ast <= 1e-9 * abs(tn) and ast >= 0.5 * prev)):
            t = tn
            break
        prev = ast
        t = tn
    # double-double polish: the float64 residual above is only good to u*S.
    # One dd step from a float64-converged t leaves an error of (step^2 x
    # curvature) + 0.5 ulp; a step of <= 64 ulp makes the first term far
    # below an ulp, so a second dd residual is only spent on larger steps.
    for _ in range(4):
        f, g = _f_dd(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, t)
        if f == 0.0:
            break
        gd = _gd(Vh, Ah, t)
        step = _entry_step(f, g, gd, Ah, R)
        if step != step:
            break
        tn = t + step
        if tn < lo0:
            tn = lo0
        elif tn > hi0:
            tn = hi0
        done = abs(tn - t) <= 64.0 * _EPS * abs(tn)
        t = tn
        if done:
            break
    return t


@njit(cache=True)
def _root_c(P, V, A, lo, hi, clo):
    """Root of the cubic c on [lo, hi] where c is monotone and changes sign.

    Safeguarded Newton with c' = q (both geometric): a Newton iterate outside
    the current bracket is replaced by bisection, so convergence is
    guaranteed; the root only needs ~float64 accuracy because it is used as
    a bracket end and a closest-approach time (both insensitive to it: f is
    stationary there).
    """
    neg_lo = clo < 0.0
    # Start where Newton is monotone: c'' = 3 g'.da changes sign only at the
    # vertex t0 of q; on a convex piece Newton from the right end never
    # overshoots, on a concave piece from the left end.  Mixed pieces start
    # at the midpoint.  The bracket safeguard makes this a speed choice only.
    t0 = -_dot(A, V) / _dot(A, A)
    if lo >= t0:
        t = hi if (clo < 0.0) else lo
    elif hi <= t0:
        t = lo if (clo < 0.0) else hi
    else:
        t = 0.5 * (lo + hi)
    prev = _INF
    for _ in range(200):
        ct = _c(P, V, A, t)
        if ct == 0.0:
            return t
        if (ct < 0.0) == neg_lo:
            lo = t
        else:
            hi = t
        qt = _q(P, V, A, t)
        tn = t - ct / qt if qt != 0.0 else _NAN
        # converged: test before the safeguard, since t itself is a bracket
        # end now and a sub-ulp step would otherwise be turned into a bisection
        if abs(tn - t) <= 32.0 * _EPS * abs(t):
            return tn
        if not (tn > lo and tn < hi):
            tn = 0.5 * (lo + hi)
        # same noise-floor stop as in _solve_entry; s only needs ~1e-9
        # relative accuracy (f is stationary there: f(s) is off by O(ds^2))
        ast = abs(tn - t)
        if ast <= 32.0 * _EPS * abs(tn) or hi - lo <= 32.0 * _EPS * abs(hi):
            return tn
        if ast <= 1e-9 * abs(tn) and ast >= 0.5 * prev:
            return tn
        prev = ast
        t = tn
    return t


@njit(cache=True)
def _at_minimum(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, lo, s, S):
    """Decide contact for the decreasing run [lo, s] ending at a local min s.

    Returns the contact time or -1.0 for none.  f(lo) > 0 is known.
    """
    f, g = _f_dd(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, s)
    if f == 0.0:
        return s  # exact touch at the minimum (dd residual is exact here)
    if f <= 0.0:
        if s <= lo:
            return lo
        return _solve_entry(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, lo, s)
    # No float time has f <= 0, yet the exact minimum may still be <= 0
    # (tangent graze; point bodies with R = 0 whose paths cross).  The
    # closest-approach distance of the local model, d = |g x g'| / |g'|, has
    # no cancellation (g is perpendicular to g' at a minimum).  It differs
    # from the exact minimum distance by the path curvature over the error
    # of s, |da| * ds^2 / 2 with ds ~ a few ulp(s), and by the dd error
    # ~u^2 S: that is the absolute tolerance below; the relative 8u covers
    # rounding in d itself.  Either only matters within the documented
    # 1e-9 R^2 grazing slack.
    gd = _gd(Vh, Ah, s)
    gd2 = _dot(gd, gd)
    if gd2 > 0.0:
        d = math.sqrt(_cross2(g, gd) / gd2)
    else:
        d = math.sqrt(_dot(g, g))
    nA = math.sqrt(_dot(Ah, Ah))
    R = Rh + Rl
    # _root_c stops at ~1e-9 relative accuracy; the curvature term for that
    # ds bounds how far d(s) can be from the exact minimum distance.  Clear
    # misses are rejected here without further work.
    ds = 1e-8 * s
    if d > R * (1.0 + 8.0 * _EPS) + 0.5 * nA * ds * ds + 8.0 * _EPS * _EPS * S:
        return -1.0
    # Near-graze: refine s with Newton on c using the dd g (quadratic
    # convergence from 1e-9 reaches the ~ulp level in one or two steps).
    for _ in range(3):
        qq = gd2 + _dot(g, Ah)
        if not (qq > 0.0):
            break
        sn = s - _dot(g, gd) / qq
        if not (sn > lo) or sn == s:
            break
        s = sn
        f, g = _f_dd(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, s)
        if f <= 0.0:
            return _solve_entry(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, lo, s)
        gd = _gd(Vh, Ah, s)
        gd2 = _dot(gd, gd)
    if gd2 > 0.0:
        d = math.sqrt(_cross2(g, gd) / gd2)
    else:
        d = math.sqrt(_dot(g, g))
    ds = 16.0 * _EPS * s
    tol = 0.5 * nA * ds * ds + 8.0 * _EPS * _EPS * S
    if d > R * (1.0 + 8.0 * _EPS) + tol:
        return -1.0
    if gd2 == 0.0:
        return s
    c = _dot(g, gd)
    w = (R - d) * (R + d)
    if w < 0.0:
        w = 0.0
    t = s - (c + math.sqrt(gd2 * w)) / gd2
    if t < lo:
        t = lo
    if t > s:
        t = s
    return t


@njit(cache=True)
def _straight(Ph, Pl, Vh, Vl, Rh, Rl, f0, H):
    """da == 0 exactly: f is a quadratic, closed form + one dd polish."""
    V2 = _dot(Vh, Vh)
    if V2 == 0.0:
        return _INF  # static pair, f0 > 0 (overlap handled by caller)
    # c0 = dp.dv in double-double: its sign decides approach vs separation
    ch, cl = 0.0, 0.0
    for k in range(3):
        a, b = dd_mul(Ph[k], Pl[k], Vh[k], Vl[k])
        ch, cl = dd_add(ch, cl, a, b)
    c0 = ch + cl
    if c0 >= 0.0:
        return _INF  # separating (or tangent at t=0): |g| never decreases
    # squared miss distance d^2 = |dp x dv|^2 / |dv|^2, cross product in dd
    # (no cancellation for near-collinear head-on pairs either)
    cr2 = 0.0
    for k in range(3):
        i = (k + 1) % 3
        j = (k + 2) % 3
        a, b = dd_mul(Ph[i], Pl[i], Vh[j], Vl[j])
        e, f = dd_mul(Ph[j], Pl[j], -Vh[i], -Vl[i])
        xh, xl = dd_add(a, b, e, f)
        x = xh + xl
        cr2 += x * x
    d = math.sqrt(cr2 / V2)
    R = Rh + Rl
    if d > R:
        return _INF  # passes by (exact up to rounding of d, ~u relative)
    s = math.sqrt(V2 * (R - d) * (R + d))
    # f0 / (-c0 + s): both denominator terms are >= 0, no cancellation
    t = f0 / (s - c0)
    if not (t <= H):
        return _INF
    tm = -c0 / V2  # closest approach; the entry root lies in [0, tm]
    fx, g = _f_dd(Ph, Pl, Vh, Vl, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), Rh, Rl, t)
    cc = _dot(g, Vh)
    den = s - cc
    if den > 0.0:
        tn = t + fx / den
        if tn >= 0.0 and tn <= tm:
            t = tn
    if not (t <= H):
        return _INF
    return t


@njit(cache=True)
def _ttc_rel(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, H):
    """Core on exact (double-double) relative quantities; see module doc."""
    # f(0) = |dp|^2 - R^2 in dd: decides overlap robustly (exact touch -> 0)
    # float64 first; its error is below 4u(|dp|^2 + R^2) + 2|dp||dp_lo| + ...,
    # so the dd value is only needed when |f0| is within 8u of that scale
    P2 = _dot(Ph, Ph)
    f0 = P2 - Rh * Rh
    if abs(f0) <= 8.0 * _EPS * (P2 + Rh * Rh):
        f0h, f0l = dd_sqr(Rh, Rl)
        f0h, f0l = -f0h, -f0l
        for k in range(3):
            a, b = dd_sqr(Ph[k], Pl[k])
            f0h, f0l = dd_add(f0h, f0l, a, b)
        f0 = f0h + f0l
    if f0 < 0.0:
        return 0.0
    touching = f0 == 0.0
    if touching:
        ch, cl = 0.0, 0.0
        for k in range(3):
            a, b = dd_mul(Ph[k], Pl[k], Vh[k], Vl[k])
            ch, cl = dd_add(ch, cl, a, b)
        c0 = ch + cl
        if c0 < 0.0:
            return 0.0
        if c0 == 0.0 and _q(Ph, Vh, Ah, 0.0) < 0.0:
            return 0.0
    A2 = _dot(Ah, Ah)
    if A2 == 0.0:
        if touching:
            return _INF  # straight line leaving a touch never returns
        return _straight(Ph, Pl, Vh, Vl, Rh, Rl, f0, H)

    nP = math.sqrt(_dot(Ph, Ph))
    nV = math.sqrt(_dot(Vh, Vh))
    nA = math.sqrt(A2)
    # Turning points of c: q is a quadratic with known leading coefficient
    # 1.5|da|^2 and vertex t0 = -(da.dv)/|da|^2, so its roots are
    # t0 -+ sqrt(-q(t0) / (1.5|da|^2)).  q(t0) is evaluated geometrically
    # (no power coefficients).  These roots only split [0, H] into pieces on
    # which c is monotone; an error in them can only matter if c has a
    # near-double root there, i.e. f has a near-inflection with zero slope,
    # where f is too flat for a sign change to be missed outside the slack.
    t0 = -_dot(Ah, Vh) / A2
    q0 = _q(Ph, Vh, Ah, t0)
    n_cut = 0
    cut1 = 0.0
    cut2 = 0.0
    if q0 < 0.0:
        r = math.sqrt(-q0 / (1.5 * A2))
        cut1 = t0 - r
        cut2 = t0 + r
        n_cut = 2

    # Walk the monotone pieces of c in time order.  f decreases where c < 0;
    # a contact can only start in a decreasing run of f, which ends at a
    # local minimum (c crossing - to + on an increasing piece of c) or at H.
    a = 0.0
    if touching:
        ca = 0.0  # separating touch (checked above): f increasing at 0
    else:
        ca = _c(Ph, Vh, Ah, 0.0)
    dec_start = 0.0 if ca < 0.0 else -1.0
    for piece in range(3):
        increasing = True
        if n_cut == 2:
            if piece == 0:
                b = cut1
            elif piece == 1:
                b = cut2
                increasing = False
            else:
                b = _INF
        else:
            if piece > 0:
                break
            b = _INF
        if b <= a:
            continue
        last = False
        if b >= H:
            b = H
            last = True
        if b == _INF:
            # final piece (c increasing to +inf since |da| > 0)
            if ca >= 0.0:
                return _INF
            # Fujiwara bound on the roots of c (c3 = |da|^2/2, c2 = 1.5 da.dv,
            # c1 = |dv|^2 + da.dp, c0 = dp.dv), bounded with norms; doubled
            # until c(b) >= 0 in case rounding puts c(b) slightly negative.
            b = 2.0 * max(
                3.0 * nV / nA,
                math.sqrt(2.0 * (nV * nV + nA * nP)) / nA,
                (nP * nV / A2) ** (1.0 / 3.0),
            )
            b = max(b, 2.0 * a) + 1e-300
            cb = _c(Ph, Vh, Ah, b)
            for _ in range(64):
                if cb >= 0.0 or cb != cb:
                    break
                b = 2.0 * b
                cb = _c(Ph, Vh, Ah, b)
            s = _root_c(Ph, Vh, Ah, a, b, ca)
            S = nP + s * nV + 0.5 * s * s * nA
            res = _at_minimum(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, dec_start, s, S)
            return res if res >= 0.0 else _INF
        cb = _c(Ph, Vh, Ah, b)
        if increasing:
            if ca < 0.0 and cb >= 0.0:
                s = _root_c(Ph, Vh, Ah, a, b, ca)
                S = nP + s * nV + 0.5 * s * s * nA
                res = _at_minimum(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, dec_start, s, S)
                if res >= 0.0:
                    return res
                dec_start = -1.0
        else:
            if ca >= 0.0 and cb < 0.0:
                dec_start = _root_c(Ph, Vh, Ah, a, b, ca)
        a = b
        ca = cb
        if last:
            break
    # reached the horizon inside a decreasing run: contact iff f(H) <= 0
    if dec_start >= 0.0 and H < _INF:
        fH, _g_unused = _f_dd(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, H)
        if fH <= 0.0:
            return _solve_entry(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, dec_start, H)
    return _INF


@njit(cache=True)
def _ttc_scalar(pax, pay, paz, vax, vay, vaz, aax, aay, aaz, r_a,
                pbx, pby, pbz, vbx, vby, vbz, abx, aby, abz, r_b, horizon):
    """First-contact time of one pair (numba-callable, same contract as
    ``time_to_collision``; pass 0.0 for z in 2-D).  NaN for invalid input."""
    # one finiteness test on a sum catches any inf/nan input (inf - inf = nan)
    chk = (pax + pay + paz + vax + vay + vaz + aax + aay + aaz + r_a
           + pbx + pby + pbz + vbx + vby + vbz + abx + aby + abz + r_b)
    if not (chk - chk == 0.0) or not (r_a >= 0.0) or not (r_b >= 0.0):
        return _NAN
    if not (horizon >= 0.0):
        return _NAN
    # exact relative state (TwoSum): the only place absolute coordinates
    # meet, so ~1e6 m map offsets cost nothing
    x0, x1 = two_sum(pax, -pbx)
    y0, y1 = two_sum(pay, -pby)
    z0, z1 = two_sum(paz, -pbz)
    u0, u1 = two_sum(vax, -vbx)
    v0, v1 = two_sum(vay, -vby)
    w0, w1 = two_sum(vaz, -vbz)
    i0, i1 = two_sum(aax, -abx)
    j0, j1 = two_sum(aay, -aby)
    k0, k1 = two_sum(aaz, -abz)
    Rh, Rl = two_sum(r_a, r_b)
    t = _ttc_rel((x0, y0, z0), (x1, y1, z1), (u0, v0, w0), (u1, v1, w1),
                 (i0, j0, k0), (i1, j1, k1), Rh, Rl, horizon)
    if t != t:
        return _NAN
    return t


@njit(cache=True, inline="always")
def _ttc_row(pa, va, aa, ra, pb, vb, ab, rb, H, i):
    if pa.shape[1] == 3:
        return _ttc_scalar(pa[i, 0], pa[i, 1], pa[i, 2], va[i, 0], va[i, 1], va[i, 2],
                           aa[i, 0], aa[i, 1], aa[i, 2], ra[i],
                           pb[i, 0], pb[i, 1], pb[i, 2], vb[i, 0], vb[i, 1], vb[i, 2],
                           ab[i, 0], ab[i, 1], ab[i, 2], rb[i], H[i])
    return _ttc_scalar(pa[i, 0], pa[i, 1], 0.0, va[i, 0], va[i, 1], 0.0,
                       aa[i, 0], aa[i, 1], 0.0, ra[i],
                       pb[i, 0], pb[i, 1], 0.0, vb[i, 0], vb[i, 1], 0.0,
                       ab[i, 0], ab[i, 1], 0.0, rb[i], H[i])


@njit(cache=True)
def _ttc_kernel(pa, va, aa, ra, pb, vb, ab, rb, H, out):
    """Serial loop over rows: vectors (n, D) with D in {2, 3}, scalars (n,)."""
    for i in range(out.shape[0]):
        out[i] = _ttc_row(pa, va, aa, ra, pb, vb, ab, rb, H, i)


@njit(cache=True, parallel=True)
def _ttc_kernel_par(pa, va, aa, ra, pb, vb, ab, rb, H, out):
    """Multi-threaded twin of ``_ttc_kernel`` (rows are independent)."""
    for i in prange(out.shape[0]):
        out[i] = _ttc_row(pa, va, aa, ra, pb, vb, ab, rb, H, i)


# Below this many rows thread start-up (~10-50 us) costs more than it saves.
PARALLEL_MIN_ROWS = 4096


def _as_rows(x: np.ndarray, batch: tuple, n: int, D: int) -> np.ndarray:
    shape = batch + (D,) if D else batch
    if x.shape != shape:  # broadcast_to costs ~5 us: only when needed
        x = np.broadcast_to(x, shape)
    x = np.ascontiguousarray(x)
    return x.reshape((n, D) if D else (n,))


def time_to_collision(p_a, v_a, a_a, r_a, p_b, v_b, a_b, r_b, horizon=math.inf) -> np.ndarray:
    """Earliest time at which two uniformly accelerated discs/spheres touch.

    Parameters
    ----------
    p_a, v_a, a_a, p_b, v_b, a_b : array_like, shape (..., D), D = 2 or 3
        Centre position [m], velocity [m/s], acceleration [m/s^2] at t = 0.
    r_a, r_b : array_like, shape (...)
        Radii [m]; 0 is a point.
    horizon : array_like, shape (...), optional
        Latest time of interest [s] (inclusive), default inf.

    Returns
    -------
    numpy.ndarray of float64, the broadcast batch shape (0-d for scalars)
        0.0 if the bodies overlap at t = 0 or touch while approaching;
        otherwise the smallest t in (0, horizon] with centre distance equal
        to r_a + r_b (tangent grazes count); inf if none.  A pair touching at
        t = 0 while separating reports its next contact, if any.
        NaN for an element with a non-finite input, a negative radius or a
        negative/NaN horizon (other elements are unaffected).

    Guarantees (proved in tests/core/test_narrow_phase*.py): error <= 4 ulp of
    the exact time for the inputs as given, scaled by |cos| of the contact
    angle for grazes; no missed/spurious contact unless the exact minimum of
    |g|^2 - R^2 is within 1e-9 R^2 of zero.

    Raises
    ------
    ValueError
        If the vector shapes disagree in D, D is not 2 or 3, or the shapes
        do not broadcast.
    """
    vecs = [np.asarray(x, dtype=np.float64) for x in (p_a, v_a, a_a, p_b, v_b, a_b)]
    D = vecs[0].shape[-1] if vecs[0].ndim else 0
    if D not in (2, 3) or any(x.ndim == 0 or x.shape[-1] != D for x in vecs):
        raise ValueError("position/velocity/acceleration must share a last axis of size 2 or 3")
    sc = [np.asarray(x, dtype=np.float64) for x in (r_a, r_b, horizon)]
    shapes = {x.shape[:-1] for x in vecs} | {x.shape for x in sc}
    batch = shapes.pop() if len(shapes) == 1 else np.broadcast_shapes(
        *(x.shape[:-1] for x in vecs), *(x.shape for x in sc))
    n = math.prod(batch)
    out = np.empty(n, dtype=np.float64)
    pa, va, aa, pb, vb, ab = (_as_rows(x, batch, n, D) for x in vecs)
    ra, rb, hz = (_as_rows(x, batch, n, 0) for x in sc)
    kernel = _ttc_kernel_par if n >= PARALLEL_MIN_ROWS else _ttc_kernel
    kernel(pa, va, aa, ra, pb, vb, ab, rb, hz, out)
    return out.reshape(batch)
