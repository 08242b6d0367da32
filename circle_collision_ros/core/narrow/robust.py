"""Robust narrow-phase solver: one row at a time, every decision certified.

Model (see ``batch``): ``g(t) = dp + t (dv + t da/2)``,
``f(t) = |g(t)|^2 - R^2``; first contact = first root of f in [0, H].

Method (numerical decisions are justified next to the code, DynamO
``stable_poly.hpp`` style):

1. The relative quantities arrive *exactly* as double-double values
   (``evaluate.rel2/rel3``: TwoSum, then an exact power-of-two scaling);
   a row whose nonzero components span more than 2^240 (``_SPAN``: the
   scaling would flush or round the small ones, or their squares underflow)
   is left UNDECIDED for the exact path.
2. t = 0: the sign of f(0) decides overlap (-> 0) when it clears its error
   bound (float64, else double-double).  Closer to 0 -- an exact touch in
   particular -- the row is left UNDECIDED: the order of contact (the
   lowest-order nonzero term of f decides between approaching -> 0 and
   separating) is then applied exactly by ``exact``.
3. Cheap exact-safe rejection for a finite horizon: if one coordinate of
   ``g`` stays beyond ``+-R`` on all of ``[0, H]`` (swept interval of a
   quadratic, with a rounding margin) there is no contact (``_axis_reject``);
   likewise if ``|dp| - H|dv| - H^2|da|/2 > R``.
4. The quartic is never expanded for root finding.  ``f`` is monotone
   between stationary points, which are roots of the cubic
   ``c(t) = g . g' = f'/2``; ``c`` is monotone between the roots of the
   quadratic ``q = c' = |g'|^2 + g . da``, which are found in closed form from
   its vertex with a certified location error (``turning_points``).  Only
   *local minima* of ``f`` (``c`` crossing - to +) can start a contact, so
   at most two brackets are ever examined, in time order; the sign of ``c``
   at 0 and at each turning point is used only beyond its error bound
   (else UNDECIDED), so the run structure of ``f`` is proved.  The root of
   ``c`` on a piece starts from its closed form (depressed cubic about the
   inflection point, Cardano / trigonometric) -- a guess only -- and is
   finished by safeguarded Newton, stopped by its own error estimate.
5. Every function is evaluated geometrically from ``g(t)`` (not from power
   coefficients).  Signs that decide contact vs no contact are taken from a
   float64 evaluation only when it exceeds a rigorous rounding-error bound
   (``F_ERR``), else from a double-double evaluation (compensated Horner for
   ``g``, exact TwoProd/TwoSum for ``|g|^2 - R^2``, bound ``DD_ERR``).  A
   certainly negative ``f`` at a Newton iterate on ``c`` already brackets
   the contact (the minimum is then not needed).
6. Roots are found by a safeguarded step that is *exact for straight-line
   motion* (the entering root of the local quadratic model, written in the
   cancellation-free form), falling back to bisection; the float64 phase
   stops when the model's truncation estimate is < 1e-7 relative (cubic
   convergence), then a double-double residual polishes it.
7. A local minimum is a miss only when its closest-approach distance
   (cross product ``|g x g'| / |g'|``, no cancellation) provably exceeds R.
8. Every contact time is certified before it is returned (``_certified``):
   f(pred(t)) > 0 and f(t) < 0 or f(succ(t)) < 0, each beyond the dd error
   bound, inside a run of f proved to decrease from a positive value -- so
   the exact first contact lies within one ulp of t.  Tangent grazes,
   near-touching sliding pairs and tiny bodies whose f never clears the
   bound are left UNDECIDED, and decided exactly by ``exact``.

Planar inputs run through 2-component tuples (the helpers are specialised
per length with ``numba.extending.overload``); a 3-D input with ``z = 0``
gives bitwise the same result.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit
from numba.extending import register_jitable

from circle_collision_ros.core.narrow.dd import dd_add, dd_sqr
from circle_collision_ros.core.narrow.evaluate import (DD_ERR, EPS, F_ERR, INF, NAN, c_at, c_err,
                                                       cross2, dot, entry_step, f0_err, f_dd, g_at,
                                                       gd_at, model_err, polish_done, reach_miss,
                                                       rel2, rel3, scale_at, turning_points,
                                                       valid_row)
from circle_collision_ros.core.narrow.evaluate import UNDECIDED
from circle_collision_ros.core.narrow.straight import straight


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
    is accurate to ~u^2 |g|^2; the polish ends by ``polish_done`` (at most
    4 steps).  The result is a candidate only: ``_certified`` checks it.
    """
    R2 = Rh * Rh
    A2 = dot(Ah, Ah)
    lo0 = lo
    hi0 = hi
    prev = INF
    for _ in range(100):
        g = g_at(Ph, Vh, Ah, t)
        f = dot(g, g) - R2
        if f > 0.0:
            lo = t
        else:
            hi = t
        if f == 0.0:
            break
        gd = gd_at(Vh, Ah, t)
        step, sd, _rel = entry_step(f, g, gd, Ah, R2)
        tn = t + step
        ast = abs(step)
        if ast <= 32.0 * EPS * abs(t):
            t = tn  # converged (checked before the safeguard, see _root_c)
            break
        if not (tn > lo and tn < hi):
            tn = 0.5 * (lo + hi)
            ast = abs(tn - t)
            if hi - lo <= 32.0 * EPS * hi:
                t = tn
                break
        elif model_err(step, sd, gd, Ah, A2) <= 1e-7 * abs(tn):
            t = tn
            break
        # Stop at the float64 noise floor: either the step is tiny, or it is
        # small and no longer shrinking (the residual is rounding noise, so
        # further float64 steps would wander).  The dd polish takes over.
        if ast <= 32.0 * EPS * abs(tn) or (ast <= 1e-9 * abs(tn) and ast >= 0.5 * prev):
            t = tn
            break
        prev = ast
        t = tn
    # double-double polish: the float64 residual above is only good to u*S.
    for _ in range(4):
        f, g = f_dd(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, t)
        if f == 0.0:
            break
        gd = gd_at(Vh, Ah, t)
        step, sd, rel = entry_step(f, g, gd, Ah, R2)
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
        # clamped and non-root (vertex) steps: done when <= 64 ulp
        if clamped or not (rel < INF):
            done = ast <= 64.0 * EPS * at
        else:
            done = polish_done(ast, at, rel, model_err(step, sd, gd, Ah, A2))
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
    bound (F_ERR), that iterate is returned with hit=True -- it is a valid
    right bracket end for the entry root (f decreases to the minimum and
    increases after it within the piece, so {f <= 0} is an interval ending
    at or after it), and the minimum itself is not needed.
    """
    neg_lo = clo < 0.0
    A2 = dot(A, A)
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
    prev = INF
    for _ in range(200):
        g = g_at(P, V, A, t)
        gd = gd_at(V, A, t)
        ct = dot(g, gd)
        if hitR2 >= 0.0:
            S = nP + t * (nV + 0.5 * t * nA)
            if dot(g, g) - hitR2 < -F_ERR * (S * S + hitR2):
                return t, True
        if ct == 0.0:
            return t, False
        if (ct < 0.0) == neg_lo:
            lo = t
        else:
            hi = t
        gdA = dot(gd, A)
        qt = dot(gd, gd) + dot(g, A)
        tn = t - ct / qt if qt != 0.0 else NAN
        ast = abs(tn - t)
        # converged: test before the safeguard, since t itself is a bracket
        # end now and a sub-ulp step would otherwise be turned into a bisection
        if ast <= 32.0 * EPS * abs(t):
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
        if ast <= 32.0 * EPS * abs(tn) or hi - lo <= 32.0 * EPS * abs(hi):
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
    g2 = dot(g, g)
    if gd2 > 0.0:
        c = dot(g, gd)
        tau = -c / gd2
        if abs(tau) <= window:
            return math.sqrt(cross2(g, gd) / gd2)
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
    dtol = R * (1.0 + 8.0 * EPS) + 0.5 * nA * ds * ds + 8.0 * EPS * EPS * S
    # float64 screen, decided only when the sign / margin exceeds the
    # rounding error bound (otherwise the double-double path below decides):
    # * f(s) < -F_ERR (S^2 + R^2): certainly f(s) < 0, a contact in [lo, s];
    # * a lower bound of d(s) = |g x g'|/|g'| above the miss threshold of the
    #   dd test below: certainly a miss.  Error of d from float g, g': with
    #   |dg| <= 6u S, |dg'| <= 3u (|dv| + s |da|) (Horner, incl. the dropped
    #   low parts of the dd relative state), d moves by at most
    #   |dg| + |g| |dg'| / |g'| + ~4u d; the bound below uses 8 eps (~4x).
    g = g_at(Ph, Vh, Ah, s)
    R2 = Rh * Rh
    g2 = dot(g, g)
    if g2 - R2 < -F_ERR * (S * S + R2):
        if s <= lo:
            return lo
        return _solve_entry(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, lo, s, s)
    gd = gd_at(Vh, Ah, s)
    gd2 = dot(gd, gd)
    if gd2 > 0.0:
        ngd = math.sqrt(gd2)
        d = math.sqrt(cross2(g, gd)) / ngd
        derr = 8.0 * EPS * (S + S * (nV + s * nA) / ngd + d)
        if d - derr > dtol:
            return -1.0
    f, g = f_dd(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, s)
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
    gd = gd_at(Vh, Ah, s)
    gd2 = dot(gd, gd)
    d = _closest_distance(g, gd, gd2, ds)
    if d > dtol:
        return -1.0
    # Near-graze: refine s with Newton on c using the dd g (quadratic
    # convergence from 1e-9 reaches the ~ulp level in one or two steps).
    for _ in range(3):
        qq = gd2 + dot(g, Ah)
        if not (qq > 0.0):
            break
        sn = s - dot(g, gd) / qq
        if not (sn > lo) or sn == s:
            break
        s = sn
        f, g = f_dd(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, s)
        if f <= 0.0:
            return _solve_entry(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, lo, s, s)
        gd = gd_at(Vh, Ah, s)
        gd2 = dot(gd, gd)
    ds = 16.0 * EPS * s
    d = _closest_distance(g, gd, gd2, ds)
    tol = 0.5 * nA * ds * ds + 8.0 * EPS * EPS * S
    if d > R * (1.0 + 8.0 * EPS) + tol:
        return -1.0
    if gd2 == 0.0:
        return s
    c = dot(g, gd)
    w = (R - d) * (R + d)
    if w < 0.0:
        w = 0.0
    t = s - (c + math.sqrt(gd2 * w)) / gd2
    if t < lo:
        t = lo
    if t > s:
        t = s
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
            if m - 8.0 * EPS * (abs(p) + H * (abs(v) + 0.5 * H * abs(a))) > Rp:
                return True
        elif p < -Rp and gH < -Rp:
            m = max(p, gH)
            if a < 0.0:
                ts = -v / a
                if ts > 0.0 and ts < H:
                    m = max(m, p + ts * (v + 0.5 * ts * a))
            if m + 8.0 * EPS * (abs(p) + H * (abs(v) + 0.5 * H * abs(a))) < -Rp:
                return True
    return False


@njit(cache=True, error_model="numpy")
def _ttc_rel(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, H):
    """Core on exact (double-double) relative quantities; see module doc.

    Returns UNDECIDED where a decision it needs is not certain in float64 /
    double-double arithmetic (the callers then decide the row exactly,
    ``exact``): f(0) within its error bound of 0 (touching, where the
    order of contact decides), dp.dv within its bound of 0, an uncertain
    structure of c, and every contact time that ``_certified`` rejects.
    """
    # f(0) = |dp|^2 - R^2: float64 first; its error is below
    # 4u(|dp|^2 + R^2) + 2|dp||dp_lo| + ..., so the dd value is only needed
    # when |f0| is within 8 eps of that scale.  The dd value (dd_sqr, dd_add:
    # a few u^2 of the scale each) is certain beyond 16 eps^2 of the scale;
    # closer (an exact touch in particular) the sign is left to the exact
    # path, which applies the order-of-contact rule.
    P2 = dot(Ph, Ph)
    f0 = P2 - Rh * Rh
    if abs(f0) <= f0_err(P2, Rh * Rh):
        f0h, f0l = dd_sqr(Rh, Rl)
        f0h, f0l = -f0h, -f0l
        for k in range(len(Ph)):
            a, b = dd_sqr(Ph[k], Pl[k])
            f0h, f0l = dd_add(f0h, f0l, a, b)
        f0 = f0h + f0l
        if abs(f0) <= 16.0 * EPS * EPS * (P2 + Rh * Rh):
            return UNDECIDED
    if f0 < 0.0:
        return 0.0
    if _is_zero(Ah):
        # da == 0 exactly: the closed form, certified itself (straight)
        return straight(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, f0, H)
    t = _ttc_walk(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, H, f0, P2)
    if t == INF or t == UNDECIDED:
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
    (f_dd: ~u^2 (S^2 + R^2), 64x margin).  Grazes whose f never gets below
    that bound, and any wrong time, fail the test.
    """
    if not (t > 0.0 and t <= H):
        return False
    nP = math.sqrt(dot(Ph, Ph))
    nV = math.sqrt(dot(Vh, Vh))
    nA = math.sqrt(dot(Ah, Ah))
    R2 = Rh * Rh
    tp = np.nextafter(t, 0.0)
    if tp > 0.0:
        S = scale_at(nP, nV, nA, tp)
        fp, _g_unused = f_dd(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, tp)
        if not (fp > DD_ERR * (S * S + R2)):
            return False
    S = scale_at(nP, nV, nA, t)
    ft, _g_unused = f_dd(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, t)
    if ft < -DD_ERR * (S * S + R2):
        return True
    tn = np.nextafter(t, INF)
    if not (tn <= H):
        return False
    S = scale_at(nP, nV, nA, tn)
    fn, _g_unused = f_dd(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, tn)
    return fn < -DD_ERR * (S * S + R2)


@register_jitable(error_model="numpy")
def _is_zero(A):
    """All components exactly 0."""
    z = True
    for k in range(len(A)):
        z &= A[k] == 0.0
    return z


@njit(cache=True, error_model="numpy")
def _ttc_walk(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, H, f0, P2):
    """Given f(0) = f0 > 0 certainly and da != 0: the first contact time (to
    be certified by the caller), inf (proved) or UNDECIDED."""
    A2 = dot(Ah, Ah)
    nP = math.sqrt(P2)
    nV = math.sqrt(dot(Vh, Vh))
    nA = math.sqrt(A2)
    if reach_miss(nP, nV, nA, Rh, Rl, H):
        return INF
    if A2 == 0.0:
        # da != 0 (the caller took da == 0) but |da|^2 underflows: cannot
        # happen for a state inside the span (evaluate._SPAN), kept so
        # that the straight-line answers never ignore a real acceleration.
        return UNDECIDED
    # Turning points of c (roots of the quadratic q = c', closed form about
    # its vertex t0, turning_points): they split [0, inf) into pieces on
    # which c is monotone.  Where q(t0) is within its error bound of 0 the
    # number of pieces is uncertain: undecided.  Each turning point is within
    # dl of exact, which moves c there by at most Dl: the sign of c at a cut
    # (and at 0) is used only when it exceeds its float64 error bound plus
    # Dl, so the run structure of f below is proved.
    R2 = Rh * Rh
    t0, q0, c_t0, eq0, cuts, r, dl, Dl = turning_points(Ph, Vh, Ah, nP, nV, nA, A2)
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
    ca = c_at(Ph, Vh, Ah, 0.0)
    if not (abs(ca) > c_err(nP, nV, nA, 0.0) + Dl):
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
                b = INF
        else:
            if piece > 0:
                break
            b = INF
        if b <= a:
            continue
        last = False
        if b >= H:
            b = H
            last = True
        if b == INF:
            # final piece (c increasing to +inf since |da| > 0)
            if ca >= 0.0:
                return INF
            # Fujiwara bound on the roots of c (c3 = |da|^2/2, c2 = 1.5 da.dv,
            # c1 = |dv|^2 + da.dp, c0 = dp.dv), bounded with norms; doubled
            # until c(b) >= 0 in case rounding puts c(b) slightly negative.
            b = 2.0 * max(3.0 * nV / nA, math.sqrt(2.0 * (nV * nV + nA * nP)) / nA,
                          (nP * nV / A2) ** (1.0 / 3.0))
            b = max(b, 2.0 * a) + 1e-300
            cb = c_at(Ph, Vh, Ah, b)
            for _ in range(64):
                if cb >= 0.0 or cb != cb:
                    break
                b = 2.0 * b
                cb = c_at(Ph, Vh, Ah, b)
            s, hit = _root_c(Ph, Vh, Ah, a, b, ca, R2, nP, nV, nA, t0, q0, c_t0, which)
            if hit:
                return _solve_entry(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, dec_start, s, s)
            res = _at_minimum(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, dec_start, s, nP, nV, nA)
            return res if res >= 0.0 else INF
        cb = c_at(Ph, Vh, Ah, b)
        if not last and not (abs(cb) > c_err(nP, nV, nA, b) + Dl):
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
                dec_start, _hit_unused = _root_c(
                    Ph, Vh, Ah, a, b, ca, -1.0, nP, nV, nA, t0, q0, c_t0, which
                )
        a = b
        ca = cb
        if last:
            break
    # reached the horizon inside a decreasing run: contact iff f(H) <= 0
    if dec_start >= 0.0 and H < INF:
        # float64 screen first (error bound F_ERR), dd only when uncertain
        gH = g_at(Ph, Vh, Ah, H)
        SH = nP + H * (nV + 0.5 * H * nA)
        fH = dot(gH, gH) - R2
        eH = F_ERR * (SH * SH + R2)
        if fH > eH:
            return INF
        if fH < -eH:
            return _solve_entry(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, dec_start, H, H)
        fH, _g_unused = f_dd(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, H)
        if fH < -DD_ERR * (SH * SH + R2):
            return _solve_entry(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, dec_start, H, H)
        if not (fH > DD_ERR * (SH * SH + R2)):
            return UNDECIDED
    return INF


@njit(cache=True, error_model="numpy")
def robust_pair3(pax, pay, paz, vax, vay, vaz, aax, aay, aaz, r_a, pbx, pby, pbz, vbx, vby, vbz,
                 abx, aby, abz, r_b, horizon):
    """The robust solver on absolute 3-D inputs (NaN for invalid input): the
    batch kernels' answer for a row the fast path leaves undecided."""
    chk = (
        pax
        + pay
        + paz
        + vax
        + vay
        + vaz
        + aax
        + aay
        + aaz
        + r_a
        + pbx
        + pby
        + pbz
        + vbx
        + vby
        + vbz
        + abx
        + aby
        + abz
        + r_b
    )
    if not valid_row(chk, r_a, r_b, horizon):
        return NAN
    Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, fine = rel3(pax, pay, paz, vax, vay, vaz, aax, aay, aaz, r_a,
                                                pbx, pby, pbz, vbx, vby, vbz, abx, aby, abz, r_b)
    if Rh != Rh:  # the relative state overflowed (out of range): NaN, see pow2_scales
        return NAN
    if not fine:  # outside the span of magnitudes solved in floating point (_SPAN)
        return UNDECIDED
    t = _ttc_rel(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, horizon)
    return NAN if t != t else t


@njit(cache=True, error_model="numpy")
def robust_pair2(pax, pay, vax, vay, aax, aay, r_a, pbx, pby, vbx, vby, abx, aby, r_b, horizon):
    """Planar ``robust_pair3`` (2-component tuples throughout; same result
    as ``robust_pair3`` with z = 0, bit for bit)."""
    chk = pax + pay + vax + vay + aax + aay + r_a + pbx + pby + vbx + vby + abx + aby + r_b
    if not valid_row(chk, r_a, r_b, horizon):
        return NAN
    Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, fine = rel2(
        pax, pay, vax, vay, aax, aay, r_a, pbx, pby, vbx, vby, abx, aby, r_b
    )
    if Rh != Rh:  # the relative state overflowed (out of range): NaN, see pow2_scales
        return NAN
    if not fine:  # outside the span of magnitudes solved in floating point (_SPAN)
        return UNDECIDED
    t = _ttc_rel(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, horizon)
    return NAN if t != t else t
