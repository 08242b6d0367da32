"""Narrow phase: first-contact time of two uniformly accelerated discs/spheres.

Model.  Body centres follow ``p(t) = p0 + v t + a t^2/2``.  With relative
quantities ``dp = p_a - p_b``, ``dv = v_a - v_b``, ``da = a_a - a_b`` and
``R = r_a + r_b`` the relative centre is ``g(t) = dp + t (dv + t da/2)`` and
the bodies touch when ``f(t) = |g(t)|^2 - R^2 = 0`` (a quartic in ``t``).

Method (numerical decisions are justified next to the code, DynamO
``stable_poly.hpp`` style):

1. Relative quantities are formed *exactly* as double-double values
   (TwoSum), so map/UTM coordinates (~1e6 m) lose nothing, and the answer
   is that of the inputs exactly as given; then scaled by a power of two
   (exact) so that no product of lengths under- or overflows.
2. Cheap exact-safe rejection for a finite horizon: if one coordinate of
   ``g`` stays beyond ``+-R`` on all of ``[0, H]`` (swept interval of a
   quadratic, with a rounding margin) there is no contact (``_axis_reject``);
   likewise if ``|dp| - H|dv| - H^2|da|/2 > R``.
3. The quartic is never expanded for root finding.  ``f`` is monotone
   between stationary points, which are roots of the cubic
   ``c(t) = g . g' = f'/2``; ``c`` is monotone between the roots of the
   quadratic ``q = c' = |g'|^2 + g . da``, which are found in closed form from
   its vertex.  Only *local minima* of ``f`` (``c`` crossing - to +) can start
   a contact, so at most two brackets are ever examined, in time order.  The
   root of ``c`` on a piece starts from its closed form (depressed cubic about
   the inflection point, Cardano / trigonometric) -- a guess only -- and is
   finished by safeguarded Newton, stopped by its own error estimate.
4. Every function is evaluated geometrically from ``g(t)`` (not from power
   coefficients).  Signs that decide contact vs no contact are taken from a
   float64 evaluation only when it exceeds a rigorous rounding-error bound
   (``_F_ERR``), else from a double-double evaluation (compensated Horner for
   ``g``, exact TwoProd/TwoSum for ``|g|^2 - R^2``), so tiny radii at large
   distances are safe.  A certainly negative ``f`` at a Newton iterate on
   ``c`` already brackets the contact (the minimum is then not needed).
5. Roots are found by a safeguarded step that is *exact for straight-line
   motion* (the entering root of the local quadratic model, written in the
   cancellation-free form), falling back to bisection; the float64 phase
   stops when the model's truncation estimate is < 1e-7 relative (cubic
   convergence), then a double-double residual polishes it -- one step when
   its truncation + rounding estimate is < 1e-4 ulp, which gives the
   correctly rounded root for well-conditioned contacts.
6. A local minimum whose exact value is ``<= 0`` is a contact even if no
   float ``t`` makes ``f <= 0`` (tangent grazes, point bodies with ``R = 0``):
   the closest-approach distance is computed from the cross product
   ``|g x g'| / |g'|``, which does not cancel.

7. Batches with a finite horizon first go through a certified branch-free
   version of steps 2-5 (``narrow_fast``), compiled to one SIMD loop over
   the rows; it decides ~99 % of a typical batch (its every claim checked
   against the same error bounds) and leaves the rest to the solver above.
   A single pair runs the same loop as a one-row batch, so a result never
   depends on the batch it comes in.

Planar inputs run through 2-component tuples (the helpers are specialised
per length with ``numba.extending.overload``); a 3-D input with ``z = 0``
gives bitwise the same result.

Public entry points
-------------------
``time_to_collision`` (vectorised numpy API) and ``_ttc_scalar`` (one pair,
an ``@njit`` function that other numba code can call directly::

    t = _ttc_scalar(pax, pay, paz, vax, vay, vaz, aax, aay, aaz, r_a,
                    pbx, pby, pbz, vbx, vby, vbz, abx, aby, abz, r_b, horizon)

use 0.0 for the z components in 2-D).  Both follow the same contract.

Input range: finite values with magnitudes below ~1e150.  The relative
state is scaled exactly by a power of two so that its largest component lies
in [2, 4) (``narrow_eval._rel2``), so only its dynamic range matters:
components below ~1e-150 of the largest (whose squares underflow) are
negligible -- a relative acceleration that small is treated as zero, a sum
of radii that small as a point (R = 0).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit, objmode, prange, types
from numba.extending import overload

from circle_collision_ros.core.narrow_dd import (
    dd_add,
    dd_mul,
    dd_sqr,
)
from circle_collision_ros.core.narrow_eval import (
    _DD_ERR,
    _EPS,
    _F_ERR,
    _INF,
    _NAN,
    _c,
    _c_err,
    _cross2,
    _dot,
    _entry_step,
    _f_dd,
    _g,
    _gd,
    _model_err,
    _rel2,
    _rel3,
    _scale,
    _turning_points,
    _valid,
)
from circle_collision_ros.core.narrow_exact import exact_first_contact
from circle_collision_ros.core.narrow_fast import UNDECIDED, fast_rows

__all__ = ["time_to_collision", "_ttc_scalar", "_ttc_kernel", "_ttc_kernel_h"]


@njit(cache=True, error_model="numpy")
def _solve_entry(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, lo, hi, t):
    """First root of f in [lo, hi] given f(lo) > 0 >= f(hi) and that f > 0
    exactly on [lo, root) and f <= 0 on [root, hi]; iteration starts at t.

    Coarse phase in float64 with the model step, safeguarded by the bracket
    (any step leaving (lo, hi) becomes a bisection, so it always converges);
    it stops once the model truncation estimate says the iterate is within
    1e-7 relative of the root (cubic convergence: the next step would be
    exact to ~1e-21), or at the float64 noise floor.  Then double-double
    polishing steps, kept inside the original bracket: the polished residual
    is accurate to ~u^2 |g|^2, so a dd step whose own truncation estimate is
    < 1% of an ulp (or that is <= 64 ulp, as before) ends the polish; the
    result is within ~0.5 ulp + |residual error / f'| of the exact root.
    """
    R2 = Rh * Rh
    A2 = _dot(Ah, Ah)
    lo0 = lo
    hi0 = hi
    prev = _INF
    for _ in range(100):
        g = _g(Ph, Vh, Ah, t)
        f = _dot(g, g) - R2
        if f > 0.0:
            lo = t
        else:
            hi = t
        if f == 0.0:
            break
        gd = _gd(Vh, Ah, t)
        step, sd, _rel = _entry_step(f, g, gd, Ah, R2)
        tn = t + step
        ast = abs(step)
        if ast <= 32.0 * _EPS * abs(t):
            t = tn  # converged (checked before the safeguard, see _root_c)
            break
        if not (tn > lo and tn < hi):
            tn = 0.5 * (lo + hi)
            ast = abs(tn - t)
            if hi - lo <= 32.0 * _EPS * hi:
                t = tn
                break
        elif _model_err(step, sd, gd, Ah, A2) <= 1e-7 * abs(tn):
            t = tn
            break
        # Stop at the float64 noise floor: either the step is tiny, or it is
        # small and no longer shrinking (the residual is rounding noise, so
        # further float64 steps would wander).  The dd polish takes over.
        if ast <= 32.0 * _EPS * abs(tn) or (ast <= 1e-9 * abs(tn) and ast >= 0.5 * prev):
            t = tn
            break
        prev = ast
        t = tn
    # double-double polish: the float64 residual above is only good to u*S.
    for _ in range(4):
        f, g = _f_dd(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, t)
        if f == 0.0:
            break
        gd = _gd(Vh, Ah, t)
        step, sd, rel = _entry_step(f, g, gd, Ah, R2)
        if step != step:
            break
        tn = t + step
        clamped = False
        if tn < lo0:
            tn = lo0
            clamped = True
        elif tn > hi0:
            tn = hi0
            clamped = True
        at = abs(tn)
        ast = abs(tn - t)
        # done if the step's own rounding |step| * rel (large at grazing
        # incidence) is < 1e-4 ulp and either the step is <= 64 ulp (then the
        # truncation error, ~step^2 x curvature, is far below an ulp) or the
        # model truncation estimate is < 1e-4 ulp (so the final rounding of
        # t + step is the correct rounding unless the root lies within 1e-4
        # ulp of a rounding boundary).  Clamped and non-root
        # (vertex) steps: done when <= 64 ulp.
        small = ast <= 64.0 * _EPS * at
        if clamped or not (rel < _INF):
            done = small
        else:
            done = ast * rel <= 1e-4 * _EPS * at and (
                small or _model_err(step, sd, gd, Ah, A2) <= 1e-4 * _EPS * at)
        t = tn
        if done:
            break
    return t


@njit(cache=True, error_model="numpy")
def _root_c(P, V, A, lo, hi, clo, hitR2, nP, nV, nA, t0, q0, c_t0, which):
    """Root of the cubic c on [lo, hi] where c is monotone and changes sign.

    Safeguarded Newton with c' = q (both geometric): a Newton iterate outside
    the current bracket is replaced by bisection, so convergence is
    guaranteed; the root only needs ~1e-9 relative accuracy because it is
    used as a bracket end and a closest-approach time (both insensitive to
    it: f is stationary there).

    Returns (t, hit).  With ``hitR2 >= 0`` (the piece ends a decreasing run
    of f that starts before lo with f > 0) each iterate also checks
    f = |g|^2 - hitR2 in float64: if f is negative by more than its error
    bound (_F_ERR), that iterate is returned with hit=True -- it is a valid
    right bracket end for the entry root (f decreases to the minimum and
    increases after it within the piece, so {f <= 0} is an interval ending
    at or after it), and the minimum itself is not needed.
    """
    neg_lo = clo < 0.0
    A2 = _dot(A, A)
    # Starting guess in closed form (a *guess* only: the safeguarded Newton
    # below decides).  t0 = -(da.dv)/|da|^2 is the inflection point of c
    # (c'' = 3 g'.da = 0 there) and q0 = c'(t0), so exactly
    #   c(t0 + x) = c(t0) + q0 x + (|da|^2 / 2) x^3,
    # a depressed cubic x^3 + p x + r.  One real root (D >= 0): Cardano in
    # the cancellation-free form x = w - p/(3w), w = cbrt(-r/2 - sgn(r) sqrt(D));
    # three (D < 0): trigonometric form; ``which`` = 0/1/2 picks the
    # smallest/middle/largest for the piece left of / between / right of the
    # turning points t0 -+ sqrt(-p/3).  t0 + x cancels when |t0| >> |t| (tiny
    # |da|): the guess is then only rough and Newton takes a few more steps.
    k = 0.5 * A2
    hp = q0 / (3.0 * k)
    hr = 0.5 * c_t0 / k
    D = hr * hr + hp * hp * hp
    if D >= 0.0:
        w = np.cbrt(-hr - math.copysign(math.sqrt(D), hr))
        x = w - hp / w if w != 0.0 else 0.0
    else:
        m = math.sqrt(-hp)
        ct = -hr / (m * m * m)
        ct = min(1.0, max(-1.0, ct))
        th = math.acos(ct) / 3.0
        if which == 0:
            th += 2.0943951023931957  # 2 pi / 3
        elif which == 1:
            th -= 2.0943951023931957
        x = 2.0 * m * math.cos(th)
    t = t0 + x
    if not (t > lo and t < hi):
        # Fallback start where Newton is monotone: c'' changes sign only at
        # t0; on a convex piece Newton from the right end never overshoots,
        # on a concave piece from the left end; mixed pieces: the midpoint.
        if lo >= t0:
            t = hi if (clo < 0.0) else lo
        elif hi <= t0:
            t = lo if (clo < 0.0) else hi
        else:
            t = 0.5 * (lo + hi)
    prev = _INF
    for _ in range(200):
        g = _g(P, V, A, t)
        gd = _gd(V, A, t)
        ct = _dot(g, gd)
        if hitR2 >= 0.0:
            S = nP + t * (nV + 0.5 * t * nA)
            if _dot(g, g) - hitR2 < -_F_ERR * (S * S + hitR2):
                return t, True
        if ct == 0.0:
            return t, False
        if (ct < 0.0) == neg_lo:
            lo = t
        else:
            hi = t
        gdA = _dot(gd, A)
        qt = _dot(gd, gd) + _dot(g, A)
        tn = t - ct / qt if qt != 0.0 else _NAN
        ast = abs(tn - t)
        # converged: test before the safeguard, since t itself is a bracket
        # end now and a sub-ulp step would otherwise be turned into a bisection
        if ast <= 32.0 * _EPS * abs(t):
            return tn, False
        if not (tn > lo and tn < hi):
            tn = 0.5 * (lo + hi)
            ast = abs(tn - t)
        else:
            # Newton error after the step: c is a cubic, so exactly
            # c(t + x) = c + q x + 1.5 (g'.da) x^2 + 0.5 |da|^2 x^3 and the
            # new error is ~(1.5 |g'.da| + 0.5 |da|^2 |x|) x^2 / |q|.  When
            # that is both < 1e-3 of the step (asymptotic regime, the
            # estimate is reliable) and < 1e-11 |t| (100x below the 1e-9
            # accuracy the callers assume), stop without another evaluation.
            est = ast * ast * (1.5 * abs(gdA) + 0.5 * A2 * ast) / abs(qt)
            if est <= 1e-11 * abs(tn) and est <= 1e-3 * ast:
                return tn, False
        # same noise-floor stop as in _solve_entry
        if ast <= 32.0 * _EPS * abs(tn) or hi - lo <= 32.0 * _EPS * abs(hi):
            return tn, False
        if ast <= 1e-9 * abs(tn) and ast >= 0.5 * prev:
            return tn, False
        prev = ast
        t = tn
    return t, False


@njit(cache=True, error_model="numpy", inline="always")
def _closest_distance(g, gd, gd2, window):
    """Closest distance of the local straight-line model g + tau g' for |tau| <= window.

    window is how far (s) the located minimum may be from the exact one.  When the
    line's own closest point lies inside the window, |g x g'| / |g'| has no
    cancellation (g is perpendicular to g' there) and is used.  Outside it the line
    model would extrapolate past where it is valid: in a collinear turnaround g' is
    nearly 0 and parallel to g, so |g x g'| / |g'| is 0 although the bodies stay
    |g| apart (tests/reliability/test_fuzz_core.py::test_collinear_turnaround_near_miss);
    the minimum over the window's ends is the right bound there.
    """
    g2 = _dot(g, g)
    if gd2 > 0.0:
        c = _dot(g, gd)
        tau = -c / gd2
        if abs(tau) <= window:
            return math.sqrt(_cross2(g, gd) / gd2)
        tau = window if tau > 0.0 else -window
        return math.sqrt(max(g2 + tau * (2.0 * c + tau * gd2), 0.0))
    return math.sqrt(g2)


@njit(cache=True, error_model="numpy")
def _at_minimum(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, lo, s, nP, nV, nA):
    """Decide contact for the decreasing run [lo, s] ending at a local min s.

    Returns the contact time or -1.0 for none.  f(lo) > 0 is known.
    """
    S = nP + s * (nV + 0.5 * s * nA)
    R = Rh + Rl
    # _root_c stops at ~1e-9 relative accuracy; the curvature term for that
    # ds bounds how far d(s) can be from the exact minimum distance (below).
    ds = 1e-8 * s
    dtol = R * (1.0 + 8.0 * _EPS) + 0.5 * nA * ds * ds + 8.0 * _EPS * _EPS * S
    # float64 screen, decided only when the sign / margin exceeds the
    # rounding error bound (otherwise the double-double path below decides):
    # * f(s) < -_F_ERR (S^2 + R^2): certainly f(s) < 0, a contact in [lo, s];
    # * a lower bound of d(s) = |g x g'|/|g'| above the miss threshold of the
    #   dd test below: certainly a miss.  Error of d from float g, g': with
    #   |dg| <= 6u S, |dg'| <= 3u (|dv| + s |da|) (Horner, incl. the dropped
    #   low parts of the dd relative state), d moves by at most
    #   |dg| + |g| |dg'| / |g'| + ~4u d; the bound below uses 8 eps (~4x).
    g = _g(Ph, Vh, Ah, s)
    R2 = Rh * Rh
    g2 = _dot(g, g)
    if g2 - R2 < -_F_ERR * (S * S + R2):
        if s <= lo:
            return lo
        return _solve_entry(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, lo, s, s)
    gd = _gd(Vh, Ah, s)
    gd2 = _dot(gd, gd)
    if gd2 > 0.0:
        ngd = math.sqrt(gd2)
        d = math.sqrt(_cross2(g, gd)) / ngd
        derr = 8.0 * _EPS * (S + S * (nV + s * nA) / ngd + d)
        if d - derr > dtol:
            return -1.0
    f, g = _f_dd(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, s)
    if f == 0.0:
        return s  # exact touch at the minimum (dd residual is exact here)
    if f <= 0.0:
        if s <= lo:
            return lo
        return _solve_entry(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, lo, s, s)
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
    d = _closest_distance(g, gd, gd2, ds)
    if d > dtol:
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
            return _solve_entry(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, lo, s, s)
        gd = _gd(Vh, Ah, s)
        gd2 = _dot(gd, gd)
    ds = 16.0 * _EPS * s
    d = _closest_distance(g, gd, gd2, ds)
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


@njit(cache=True, error_model="numpy")
def _straight(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, f0, H):
    """da == 0 exactly: f is a quadratic, closed form + one dd polish."""
    V2 = _dot(Vh, Vh)
    if V2 == 0.0:
        return _INF  # static pair, f0 > 0 (overlap handled by caller)
    # c0 = dp.dv in double-double: its sign decides approach vs separation
    ch, cl = 0.0, 0.0
    for k in range(len(Ph)):
        a, b = dd_mul(Ph[k], Pl[k], Vh[k], Vl[k])
        ch, cl = dd_add(ch, cl, a, b)
    c0 = ch + cl
    # dd_mul / dd_add: error <= ~8u^2 |dp||dv|; closer to 0 the exact path decides
    if abs(c0) <= _DD_ERR * math.sqrt(_dot(Ph, Ph) * V2):
        return UNDECIDED
    if c0 > 0.0:
        return _INF  # separating: |g| never decreases
    # squared miss distance d^2 = |dp x dv|^2 / |dv|^2, cross product in dd
    # (no cancellation for near-collinear head-on pairs either)
    cr2 = 0.0
    for k in range(3 if len(Ph) == 3 else 1):
        i = (k + 1) % 3 if len(Ph) == 3 else 0  # 2-D: only the z component
        j = (k + 2) % 3 if len(Ph) == 3 else 1
        a, b = dd_mul(Ph[i], Pl[i], Vh[j], Vl[j])
        e, f = dd_mul(Ph[j], Pl[j], -Vh[i], -Vl[i])
        xh, xl = dd_add(a, b, e, f)
        x = xh + xl
        cr2 += x * x
    d = math.sqrt(cr2 / V2)
    R = Rh + Rl
    # d carries <= ~4u relative error (rounded dd cross product, division,
    # sqrt), R = r_a + r_b rounded u: a miss is proved beyond R (1 + 8 eps).
    # Closer, the closed form is only a start: the caller certifies the time.
    if d > R * (1.0 + 8.0 * _EPS):
        return _INF
    s = math.sqrt(V2 * max(R - d, 0.0) * (R + d))
    # f0 / (-c0 + s): both denominator terms are >= 0, no cancellation
    t = f0 / (s - c0)
    tm = -c0 / V2  # closest approach; the entry root lies in [0, tm]
    hi = tm
    if not (t <= H):
        # The closed form is not yet polished and may sit a few ulp above
        # the root (more at grazing incidence), so t > H does not prove the
        # root is beyond H.  If H >= tm the root (<= tm) is within the
        # horizon; else f decreases on [0, H] and the dd sign of f(H) decides.
        if H < tm:
            fH, _g_unused = _f_dd(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, H)
            SH = math.sqrt(_dot(Ph, Ph)) + H * math.sqrt(V2)
            eH = _DD_ERR * (SH * SH + R * R)
            if fH > eH:
                return _INF
            if not (fH < -eH):
                return UNDECIDED
            hi = H
        t = min(t, hi)
    fx, g = _f_dd(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, t)  # da == 0 (hi and lo)
    cc = _dot(g, Vh)
    den = s - cc
    if den > 0.0:
        tn = t + fx / den
        if tn >= 0.0 and tn <= hi:
            t = tn
    if not (t <= H):
        return _INF
    return t


@njit(cache=True, error_model="numpy", inline="always")
def _axis_reject(Ph, Vh, Ah, Rp, H):
    """True if some coordinate of g stays beyond +-Rp on all of [0, H].

    Swept-interval test: g_k(t) = dp_k + t dv_k + t^2 da_k / 2 is a quadratic,
    so its range over [0, H] is spanned by its values at 0, H and the vertex
    -dv_k/da_k (if inside).  If that range misses [-R, R] for one axis, then
    |g(t)| >= |g_k(t)| > R throughout and there is no contact (exact-safe):
    * the float64 Horner values (high parts only) are within 4u S_k of the
      exact ones, S_k = |dp_k| + H |dv_k| + H^2 |da_k| / 2 (3u Horner + u for
      the dropped dd low parts), and a vertex time off by a few ulp moves the
      value by |da_k| (u t)^2 / 2 <= u^2 S_k (the quadratic is flat there);
      the margin 8 eps S_k = 16u S_k covers both 4x;
    * Rp = (r_a + r_b)(1 + 4 eps) covers the rounding of R;
    * overflow gives inf/NaN, whose comparisons are false: no rejection.
    Rejects ~3/4 of the random benchmark pairs at H = 10 s for ~10 ns.
    """
    for k in range(len(Ph)):
        p = Ph[k]
        v = Vh[k]
        a = Ah[k]
        gH = p + H * (v + 0.5 * H * a)
        # endpoints first (cheap, decides most pairs); an interior vertex can
        # only lower the minimum if a > 0, only raise the maximum if a < 0
        if p > Rp and gH > Rp:
            m = min(p, gH)
            if a > 0.0:
                ts = -v / a
                if ts > 0.0 and ts < H:
                    m = min(m, p + ts * (v + 0.5 * ts * a))
            if m - 8.0 * _EPS * (abs(p) + H * (abs(v) + 0.5 * H * abs(a))) > Rp:
                return True
        elif p < -Rp and gH < -Rp:
            m = max(p, gH)
            if a < 0.0:
                ts = -v / a
                if ts > 0.0 and ts < H:
                    m = max(m, p + ts * (v + 0.5 * ts * a))
            if m + 8.0 * _EPS * (abs(p) + H * (abs(v) + 0.5 * H * abs(a))) < -Rp:
                return True
    return False


@njit(cache=True, error_model="numpy")
def _ttc_rel(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, H):
    """Core on exact (double-double) relative quantities; see module doc.

    Returns UNDECIDED where a decision it needs is not certain in float64 /
    double-double arithmetic (the callers then decide the row exactly,
    ``narrow_exact``): f(0) within its error bound of 0 (touching, where the
    order of contact decides), dp.dv within its bound of 0, an uncertain
    structure of c, and every contact time that ``_certified`` rejects.
    """
    # f(0) = |dp|^2 - R^2: float64 first; its error is below
    # 4u(|dp|^2 + R^2) + 2|dp||dp_lo| + ..., so the dd value is only needed
    # when |f0| is within 8 eps of that scale.  The dd value (dd_sqr, dd_add:
    # a few u^2 of the scale each) is certain beyond 16 eps^2 of the scale;
    # closer (an exact touch in particular) the sign is left to the exact
    # path, which applies the order-of-contact rule.
    P2 = _dot(Ph, Ph)
    f0 = P2 - Rh * Rh
    if abs(f0) <= 8.0 * _EPS * (P2 + Rh * Rh):
        f0h, f0l = dd_sqr(Rh, Rl)
        f0h, f0l = -f0h, -f0l
        for k in range(len(Ph)):
            a, b = dd_sqr(Ph[k], Pl[k])
            f0h, f0l = dd_add(f0h, f0l, a, b)
        f0 = f0h + f0l
        if abs(f0) <= 16.0 * _EPS * _EPS * (P2 + Rh * Rh):
            return UNDECIDED
    if f0 < 0.0:
        return 0.0
    t = _ttc_walk(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, H, f0, P2)
    if t == _INF or t == UNDECIDED:
        return t
    return t if _certified(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, H, t) else UNDECIDED


@njit(cache=True, error_model="numpy")
def _certified(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, H, t):
    """True if t in (0, H] is within one ulp of the first root of f.

    The walk in ``_ttc_walk`` puts t in a run of f that decreases from a
    point with f > 0 (0, or the end of an increasing run after a proved
    miss) to a local minimum, followed at most by an increasing part.  In it
    f(pred(t)) > 0 proves no root up to pred(t) (pred(t) lies in the
    decreasing part: past the minimum f(t) >= f(pred(t))), and f(t) < 0 or
    f(succ(t)) < 0 (succ(t) <= H) a root in (pred(t), succ(t)).  Signs come
    from the dd residual, certain beyond its error bound 16 eps^2 (S^2 + R^2)
    (_f_dd: ~u^2 (S^2 + R^2), 64x margin).  Grazes whose f never gets below
    that bound, and any wrong time (class C/D of issue 17), fail the test.
    """
    if not (t > 0.0 and t <= H):
        return False
    nP = math.sqrt(_dot(Ph, Ph))
    nV = math.sqrt(_dot(Vh, Vh))
    nA = math.sqrt(_dot(Ah, Ah))
    R2 = Rh * Rh
    tp = np.nextafter(t, 0.0)
    if tp > 0.0:
        S = _scale(nP, nV, nA, tp)
        fp, _g_unused = _f_dd(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, tp)
        if not (fp > _DD_ERR * (S * S + R2)):
            return False
    S = _scale(nP, nV, nA, t)
    ft, _g_unused = _f_dd(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, t)
    if ft < -_DD_ERR * (S * S + R2):
        return True
    tn = np.nextafter(t, _INF)
    if not (tn <= H):
        return False
    S = _scale(nP, nV, nA, tn)
    fn, _g_unused = _f_dd(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, tn)
    return fn < -_DD_ERR * (S * S + R2)


@njit(cache=True, error_model="numpy")
def _ttc_walk(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, H, f0, P2):
    """Given f(0) = f0 > 0 certainly: the first contact time (to be
    certified by the caller), inf (proved) or UNDECIDED."""
    A2 = _dot(Ah, Ah)
    nP = math.sqrt(P2)
    nV = math.sqrt(_dot(Vh, Vh))
    nA = math.sqrt(A2)
    if H < _INF:
        # Cheap exact-safe rejection: for t in [0, H] the triangle inequality
        # gives |g(t)| >= |dp| - t|dv| - t^2|da|/2 >= nP - reach.  The norms
        # of the high parts differ from the exact ones by <= ~3u relative
        # (rounding + dropped low parts), reach and the difference add ~3u;
        # the 8 eps (nP + reach) margin (>= 16u of every term) and R(1+4eps)
        # (R = r_a + r_b rounded) keep it from ever rejecting a real contact.
        reach = H * (nV + 0.5 * H * nA)
        if nP - reach > (Rh + Rl) * (1.0 + 4.0 * _EPS) + 8.0 * _EPS * (nP + reach):
            return _INF
    if A2 == 0.0:
        return _straight(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, f0, H)
    # Turning points of c (roots of the quadratic q = c', closed form about
    # its vertex t0, _turning_points): they split [0, inf) into pieces on
    # which c is monotone.  Where q(t0) is within its error bound of 0 the
    # number of pieces is uncertain: undecided.  Each turning point is within
    # dl of exact, which moves c there by at most Dl: the sign of c at a cut
    # (and at 0) is used only when it exceeds its float64 error bound plus
    # Dl, so the run structure of f below is proved.
    R2 = Rh * Rh
    t0, q0, c_t0, eq0, cuts, r, dl, Dl = _turning_points(Ph, Vh, Ah, nP, nV, nA, A2)
    if not (cuts or q0 > eq0):
        return UNDECIDED
    n_cut = 0
    cut1 = 0.0
    cut2 = 0.0
    if cuts:
        cut1 = t0 - r
        cut2 = t0 + r
        n_cut = 2

    # Walk the monotone pieces of c in time order.  f decreases where c < 0;
    # a contact can only start in a decreasing run of f, which ends at a
    # local minimum (c crossing - to + on an increasing piece of c) or at H.
    a = 0.0
    ca = _c(Ph, Vh, Ah, 0.0)
    if not (abs(ca) > _c_err(nP, nV, nA, 0.0) + Dl):
        return UNDECIDED  # f(0) > 0 but (nearly) stationary: order decided exactly
    dec_start = 0.0 if ca < 0.0 else -1.0
    for piece in range(3):
        increasing = True
        which = piece if n_cut == 2 else 2
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
            s, hit = _root_c(Ph, Vh, Ah, a, b, ca, R2, nP, nV, nA, t0, q0, c_t0, which)
            if hit:
                return _solve_entry(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, dec_start, s, s)
            res = _at_minimum(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, dec_start, s, nP, nV, nA)
            return res if res >= 0.0 else _INF
        cb = _c(Ph, Vh, Ah, b)
        if not last and not (abs(cb) > _c_err(nP, nV, nA, b) + Dl):
            return UNDECIDED
        if increasing:
            if ca < 0.0 and cb >= 0.0:
                s, hit = _root_c(Ph, Vh, Ah, a, b, ca, R2, nP, nV, nA, t0, q0, c_t0, which)
                if hit:
                    return _solve_entry(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, dec_start, s, s)
                res = _at_minimum(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, dec_start, s, nP, nV, nA)
                if res >= 0.0:
                    return res
                dec_start = -1.0
        else:
            if ca >= 0.0 and cb < 0.0:
                dec_start, _hit_unused = _root_c(Ph, Vh, Ah, a, b, ca, -1.0, nP, nV, nA, t0, q0, c_t0, which)
        a = b
        ca = cb
        if last:
            break
    # reached the horizon inside a decreasing run: contact iff f(H) <= 0
    if dec_start >= 0.0 and H < _INF:
        # float64 screen first (error bound _F_ERR), dd only when uncertain
        gH = _g(Ph, Vh, Ah, H)
        SH = nP + H * (nV + 0.5 * H * nA)
        fH = _dot(gH, gH) - R2
        eH = _F_ERR * (SH * SH + R2)
        if fH > eH:
            return _INF
        if fH < -eH:
            return _solve_entry(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, dec_start, H, H)
        fH, _g_unused = _f_dd(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, H)
        if fH < -_DD_ERR * (SH * SH + R2):
            return _solve_entry(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, dec_start, H, H)
        if not (fH > _DD_ERR * (SH * SH + R2)):
            return UNDECIDED
    return _INF


@njit(cache=True, error_model="numpy")
def _robust_pair3(pax, pay, paz, vax, vay, vaz, aax, aay, aaz, r_a,
                  pbx, pby, pbz, vbx, vby, vbz, abx, aby, abz, r_b, horizon):
    """The robust solver on absolute 3-D inputs (NaN for invalid input): the
    batch kernels' answer for a row the fast path leaves undecided."""
    chk = (pax + pay + paz + vax + vay + vaz + aax + aay + aaz + r_a
           + pbx + pby + pbz + vbx + vby + vbz + abx + aby + abz + r_b)
    if not _valid(chk, r_a, r_b, horizon):
        return _NAN
    Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl = _rel3(pax, pay, paz, vax, vay, vaz, aax, aay, aaz, r_a,
                                           pbx, pby, pbz, vbx, vby, vbz, abx, aby, abz, r_b)
    if Rh != Rh:  # the relative state overflowed (out of range): NaN, see pow2_scales
        return _NAN
    t = _ttc_rel(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, horizon)
    return _NAN if t != t else t


@njit(cache=True, error_model="numpy")
def _robust_pair2(pax, pay, vax, vay, aax, aay, r_a, pbx, pby, vbx, vby, abx, aby, r_b, horizon):
    """Planar ``_robust_pair3`` (2-component tuples throughout; same result
    as ``_robust_pair3`` with z = 0, bit for bit)."""
    chk = (pax + pay + vax + vay + aax + aay + r_a + pbx + pby + vbx + vby + abx + aby + r_b)
    if not _valid(chk, r_a, r_b, horizon):
        return _NAN
    Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl = _rel2(pax, pay, vax, vay, aax, aay, r_a,
                                           pbx, pby, vbx, vby, abx, aby, r_b)
    if Rh != Rh:  # the relative state overflowed (out of range): NaN, see pow2_scales
        return _NAN
    t = _ttc_rel(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, horizon)
    return _NAN if t != t else t


# --------------------------------------------------------------------------
# batch kernels: vectors (n, D), radii (n,), horizon H (n,) or one float,
# out (n,).  One per dimension (a planar-only process never compiles or
# loads the 3-D chain), serial or multi-threaded.
#
# Rows go in blocks of <= _BLOCK: the fast path (narrow_fast) runs over the
# block as one vectorised loop, then the rows it left UNDECIDED go to the
# robust solver.  A row's result depends only on the row, never on the
# batch or kernel it comes in.  Each call of the fast loop costs ~0.5 us of
# set-up (run-time alias and overflow checks, vector prologue), so blocks of
# 1024 rows (~2 ns/row less than 256 on the benchmark mix).
# --------------------------------------------------------------------------
_BLOCK = 1024


def _h_at(H, i):
    """Horizon of row i: H[i] for an array, H for one float."""
    return H[i] if isinstance(H, np.ndarray) else H


@overload(_h_at, inline="always")
def _ov_h_at(H, i):
    if isinstance(H, types.Array):
        return lambda H, i: H[i]
    return lambda H, i: H


def _h_rows(H, hb, i0, m):
    """(Hs, hofs) with Hs[hofs + j] the horizon of row i0 + j: the array H
    itself, or the scratch hb filled with the float H.  The fast loop thus
    always reads an array, so it is compiled once for both kinds of H."""
    if isinstance(H, np.ndarray):
        return H, i0
    hb[:m] = H
    return hb, 0


@overload(_h_rows, inline="always")
def _ov_h_rows(H, hb, i0, m):
    if isinstance(H, types.Array):
        return lambda H, hb, i0, m: (H, i0)

    def impl(H, hb, i0, m):
        hb[:m] = H
        return hb, 0
    return impl


def _any_finite(H, i0, i1):
    """Some row of [i0, i1) has a finite horizon (else the fast path cannot
    decide anything but overlap, which the robust solver decides the same way)."""
    return bool(np.any(np.asarray(H)[i0:i1] < _INF)) if isinstance(H, np.ndarray) else H < _INF


@overload(_any_finite, inline="always")
def _ov_any_finite(H, i0, i1):
    if isinstance(H, types.Array):
        def impl(H, i0, i1):
            for i in range(i0, i1):
                if H[i] < _INF:
                    return True
            return False
        return impl
    return lambda H, i0, i1: H < _INF


def _robust_row(pa, va, aa, ra, pb, vb, ab, rb, H, i, Z):
    """Row i of a batch through the robust solver (vectors (n, D), D = len(Z))."""


@overload(_robust_row, inline="always")
def _ov_robust_row(pa, va, aa, ra, pb, vb, ab, rb, H, i, Z):
    if Z.count == 2:
        return lambda pa, va, aa, ra, pb, vb, ab, rb, H, i, Z: _robust_pair2(
            pa[i, 0], pa[i, 1], va[i, 0], va[i, 1], aa[i, 0], aa[i, 1], ra[i],
            pb[i, 0], pb[i, 1], vb[i, 0], vb[i, 1], ab[i, 0], ab[i, 1], rb[i], H)
    return lambda pa, va, aa, ra, pb, vb, ab, rb, H, i, Z: _robust_pair3(
        pa[i, 0], pa[i, 1], pa[i, 2], va[i, 0], va[i, 1], va[i, 2],
        aa[i, 0], aa[i, 1], aa[i, 2], ra[i],
        pb[i, 0], pb[i, 1], pb[i, 2], vb[i, 0], vb[i, 1], vb[i, 2],
        ab[i, 0], ab[i, 1], ab[i, 2], rb[i], H)


@njit(cache=True, error_model="numpy", inline="always")
def _block(pa, va, aa, ra, pb, vb, ab, rb, H, out, i0, i1, hb, Z):
    """Rows [i0, i1) of a batch with vectors (n, D), D = len(Z) (a tuple of D
    zeros, so each dimension compiles its own chain); hb: scratch of
    >= i1 - i0 floats.  Returns how many rows the robust solver, too, left
    UNDECIDED (``_resolve`` decides them exactly)."""
    n_und = 0
    if _any_finite(H, i0, i1):
        Hs, hofs = _h_rows(H, hb, i0, i1 - i0)
        fast_rows(pa, va, aa, ra, pb, vb, ab, rb, Hs, hofs, out, i0, i1 - i0, Z)
        for i in range(i0, i1):
            if out[i] == UNDECIDED:
                out[i] = _robust_row(pa, va, aa, ra, pb, vb, ab, rb, _h_at(H, i), i, Z)
                n_und += out[i] == UNDECIDED
    else:
        for i in range(i0, i1):
            out[i] = _robust_row(pa, va, aa, ra, pb, vb, ab, rb, _h_at(H, i), i, Z)
            n_und += out[i] == UNDECIDED
    return n_und


_Z2 = (0.0, 0.0)
_Z3 = (0.0, 0.0, 0.0)


@njit(cache=True, error_model="numpy")
def _k2(pa, va, aa, ra, pb, vb, ab, rb, H, out):
    n = out.shape[0]
    hb = np.empty(_BLOCK)
    n_und = 0
    for i0 in range(0, n, _BLOCK):
        n_und += _block(pa, va, aa, ra, pb, vb, ab, rb, H, out, i0, min(n, i0 + _BLOCK), hb, _Z2)
    return n_und


@njit(cache=True, error_model="numpy")
def _k3(pa, va, aa, ra, pb, vb, ab, rb, H, out):
    n = out.shape[0]
    hb = np.empty(_BLOCK)
    n_und = 0
    for i0 in range(0, n, _BLOCK):
        n_und += _block(pa, va, aa, ra, pb, vb, ab, rb, H, out, i0, min(n, i0 + _BLOCK), hb, _Z3)
    return n_und


# Threaded kernels spread every thread's rows over the whole batch.  A plain
# prange over rows hands each thread one contiguous run, but row costs are
# rarely uniform along a batch (the broad phase emits pairs sorted in space;
# the benchmark puts its aimed pairs, ~2.5x dearer, first), so one thread
# finished early and idled (measured 1.3x instead of 2x on 2 cores).  Here
# the rows are cut into nb = 2^m blocks of <= _BLOCK rows and prange runs
# over k = 0..nb-1 taking block bitrev(k): numba's static schedule gives each
# of T threads a contiguous run of k, which bit reversal maps to every T-th
# block when T is a power of two (and close to that otherwise).  Blocks of
# ~1000 rows keep each thread's writes to `out` on its own cache lines.


@njit(cache=True, error_model="numpy")
def _blocks(n):
    """(nb, bits, size): nb = 2^bits blocks of `size` rows covering n rows."""
    nb = 1
    bits = 0
    while nb * _BLOCK < n:
        nb *= 2
        bits += 1
    return nb, bits, (n + nb - 1) // nb


@njit(cache=True, error_model="numpy")
def _block_rows(k, bits, size, n):
    """Row range of the block bitrev(k) (bit reversal over `bits` bits).

    Deliberately not inlined: it shifts its copy of k, and numba's parfor
    pass rejects any assignment to an (inlined) prange index."""
    b = 0
    for _ in range(bits):
        b = (b << 1) | (k & 1)
        k >>= 1
    return b * size, min(n, (b + 1) * size)


@njit(cache=True, error_model="numpy", parallel=True)
def _k2p(pa, va, aa, ra, pb, vb, ab, rb, H, out):
    n = out.shape[0]
    nb, bits, size = _blocks(n)
    n_und = 0
    for k in prange(nb):
        i0, i1 = _block_rows(k, bits, size, n)
        n_und += _block(pa, va, aa, ra, pb, vb, ab, rb, H, out, i0, i1, np.empty(_BLOCK), _Z2)
    return n_und


@njit(cache=True, error_model="numpy", parallel=True)
def _k3p(pa, va, aa, ra, pb, vb, ab, rb, H, out):
    n = out.shape[0]
    nb, bits, size = _blocks(n)
    n_und = 0
    for k in prange(nb):
        i0, i1 = _block_rows(k, bits, size, n)
        n_und += _block(pa, va, aa, ra, pb, vb, ab, rb, H, out, i0, i1, np.empty(_BLOCK), _Z3)
    return n_und


def _exact_flat(r, D, horizon):
    """Exact answer of the one-row batch packed by _ttc_scalar / _ttc_scalar2."""
    v = r[:6 * D].reshape((6, D))
    return exact_first_contact(v[0], v[1], v[2], r[6 * D], v[3], v[4], v[5], r[6 * D + 1], horizon)


def _resolve(n_und, pa, va, aa, ra, pb, vb, ab, rb, H, out):
    """Decide exactly (narrow_exact) the rows the kernels left UNDECIDED.

    n_und: the kernels' count of such rows (0: nothing to do, no scan)."""
    if not n_und:
        return
    arr = isinstance(H, np.ndarray)
    for i in np.flatnonzero(out == UNDECIDED):
        out[i] = exact_first_contact(pa[i], va[i], aa[i], ra[i], pb[i], vb[i], ab[i], rb[i],
                                     H[i] if arr else H)


@njit(cache=True, error_model="numpy")
def _ttc_scalar(pax, pay, paz, vax, vay, vaz, aax, aay, aaz, r_a,
                pbx, pby, pbz, vbx, vby, vbz, abx, aby, abz, r_b, horizon):
    """First-contact time of one pair (numba-callable, same contract and
    bitwise the same result as ``time_to_collision``; pass 0.0 for z in
    2-D).  NaN for invalid input.  It runs the 3-D batch kernel on a one-row
    batch (~1 us); batches should go through the kernels directly."""
    r = np.empty(22)  # one row each of pa, va, aa, pb, vb, ab (3), ra, rb; out; horizon
    r[0], r[1], r[2], r[3], r[4], r[5] = pax, pay, paz, vax, vay, vaz
    r[6], r[7], r[8], r[9], r[10], r[11] = aax, aay, aaz, pbx, pby, pbz
    r[12], r[13], r[14], r[15], r[16], r[17] = vbx, vby, vbz, abx, aby, abz
    r[18], r[19] = r_a, r_b
    v = r[:18].reshape((6, 1, 3))
    if _block(v[0], v[1], v[2], r[18:19], v[3], v[4], v[5], r[19:20], float(horizon),
              r[20:21], 0, 1, r[21:], _Z3):
        with objmode(t="float64"):
            t = _exact_flat(r, 3, horizon)
        return t
    return r[20]


@njit(cache=True, error_model="numpy")
def _ttc_scalar2(pax, pay, vax, vay, aax, aay, r_a, pbx, pby, vbx, vby, abx, aby, r_b, horizon):
    """Planar twin of ``_ttc_scalar`` (bitwise the same result with z = 0)."""
    r = np.empty(16)  # one row each of pa, va, aa, pb, vb, ab (2), ra, rb; out; horizon
    r[0], r[1], r[2], r[3], r[4], r[5] = pax, pay, vax, vay, aax, aay
    r[6], r[7], r[8], r[9], r[10], r[11] = pbx, pby, vbx, vby, abx, aby
    r[12], r[13] = r_a, r_b
    v = r[:12].reshape((6, 1, 2))
    if _block(v[0], v[1], v[2], r[12:13], v[3], v[4], v[5], r[13:14], float(horizon),
              r[14:15], 0, 1, r[15:], _Z2):
        with objmode(t="float64"):
            t = _exact_flat(r, 2, horizon)
        return t
    return r[14]


# (D, threaded) -> kernel (each compiles once per horizon type: an array
# or one float); inputs C-contiguous (see _contiguous)
_KERNELS = {(2, False): _k2, (3, False): _k3, (2, True): _k2p, (3, True): _k3p}


def _run(threaded, pa, va, aa, ra, pb, vb, ab, rb, H, out):
    """A batch kernel over C-contiguous rows, then the exact decision of the
    rows it leaves undecided: out holds the final answers."""
    n_und = _KERNELS[(pa.shape[1], threaded)](pa, va, aa, ra, pb, vb, ab, rb, H, out)
    _resolve(n_und, pa, va, aa, ra, pb, vb, ab, rb, H, out)


def _contiguous(*arrays):
    """The kernels read rows through flat views: C-contiguous copies where needed."""
    return tuple(np.ascontiguousarray(x) for x in arrays)


def _ttc_kernel(pa, va, aa, ra, pb, vb, ab, rb, H, out):
    """Serial loop over rows: vectors (n, D) with D in {2, 3}, radii and
    horizons H (n,), results into out (n,)."""
    _run(False, *_contiguous(pa, va, aa, ra, pb, vb, ab, rb, H), out)


def _ttc_kernel_h(pa, va, aa, ra, pb, vb, ab, rb, H, out):
    """``_ttc_kernel`` with one float horizon H for all rows."""
    _run(False, *_contiguous(pa, va, aa, ra, pb, vb, ab, rb), float(H), out)


# Rows from which the threaded kernels are used.  On an idle 2-core VM with a
# warm thread pool 2 threads already win from ~64 rows (1.4x) and reach ~1.9x
# from ~1000; but when other processes keep a core busy a parallel launch
# waits for a time slice: measured 8x *slower* than serial at 1024 rows and
# ~1x at 200k rows, while 4096 rows still won 1.9x.  The robot shares its
# cores with other nodes, so the threshold stays conservative.
PARALLEL_MIN_ROWS = 4096

_ND = np.ndarray
_F8 = np.dtype(np.float64)


def _as_rows(x: np.ndarray, batch: tuple, n: int, D: int) -> np.ndarray:
    """C-contiguous (n, D) / (n,) float64 rows of x broadcast to ``batch``."""
    shape = batch + (D,) if D else batch
    if x.shape != shape:
        # broadcasting assignment into a fresh array: ~1 us, where
        # np.broadcast_to + ascontiguousarray costs ~5-10 us
        y = np.empty(shape)
        y[...] = x
        x = y
    else:
        x = np.ascontiguousarray(x)
    return x.reshape((n, D) if D else (n,))


def _rows_ok(p_a, v_a, a_a, r_a, p_b, v_b, a_b, r_b) -> bool:
    """True if the inputs are already what the kernels take: C-contiguous
    float64 ndarrays, vectors (n, D) with D in {2, 3}, radii (n,)."""
    if not (type(p_a) is _ND and type(v_a) is _ND and type(a_a) is _ND and type(r_a) is _ND
            and type(p_b) is _ND and type(v_b) is _ND and type(a_b) is _ND and type(r_b) is _ND):
        return False
    shp = p_a.shape
    if len(shp) != 2 or not (shp[1] == 2 or shp[1] == 3):
        return False
    n1 = shp[:1]
    return (v_a.shape == shp and a_a.shape == shp and p_b.shape == shp and v_b.shape == shp
            and a_b.shape == shp and r_a.shape == n1 and r_b.shape == n1
            and p_a.dtype is _F8 and v_a.dtype is _F8 and a_a.dtype is _F8 and r_a.dtype is _F8
            and p_b.dtype is _F8 and v_b.dtype is _F8 and a_b.dtype is _F8 and r_b.dtype is _F8
            and p_a.flags.c_contiguous and v_a.flags.c_contiguous and a_a.flags.c_contiguous
            and r_a.flags.c_contiguous and p_b.flags.c_contiguous and v_b.flags.c_contiguous
            and a_b.flags.c_contiguous and r_b.flags.c_contiguous)


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
        negative/NaN horizon (other elements are unaffected); out of the
        input range, also where a relative quantity (p_a - p_b, ...)
        overflows.

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
    # Fast path (Scene / node hot path): inputs already in kernel layout and
    # a scalar horizon -- no conversions, no temporaries besides the output.
    th = type(horizon)
    if (th is float or th is int or th is np.float64) and _rows_ok(
            p_a, v_a, a_a, r_a, p_b, v_b, a_b, r_b):
        n = r_a.shape[0]
        out = np.empty(n)
        _run(n >= PARALLEL_MIN_ROWS, p_a, v_a, a_a, r_a, p_b, v_b, a_b, r_b, float(horizon), out)
        return out
    vecs = [np.asarray(x, dtype=np.float64) for x in (p_a, v_a, a_a, p_b, v_b, a_b)]
    D = vecs[0].shape[-1] if vecs[0].ndim else 0
    if D not in (2, 3) or any(x.ndim == 0 or x.shape[-1] != D for x in vecs):
        raise ValueError("position/velocity/acceleration must share a last axis of size 2 or 3")
    sc = [np.asarray(x, dtype=np.float64) for x in (r_a, r_b, horizon)]
    shapes = {x.shape[:-1] for x in vecs} | {x.shape for x in sc[:2]}
    if sc[2].ndim:
        shapes.add(sc[2].shape)
    batch = shapes.pop() if len(shapes) == 1 else np.broadcast_shapes(*shapes)
    n = math.prod(batch)
    out = np.empty(n, dtype=np.float64)
    pa, va, aa, pb, vb, ab = (_as_rows(x, batch, n, D) for x in vecs)
    ra, rb = (_as_rows(x, batch, n, 0) for x in sc[:2])
    if sc[2].ndim == 0:  # one horizon for all rows: passed as a float
        hz = float(sc[2])
    else:
        hz = _as_rows(sc[2], batch, n, 0)
    _run(n >= PARALLEL_MIN_ROWS, pa, va, aa, ra, pb, vb, ab, rb, hz, out)
    return out.reshape(batch)
