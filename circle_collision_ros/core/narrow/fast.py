"""Certified branch-free fast path of the narrow phase (SIMD-vectorised).

For most accelerating pairs of a scene (finite horizon ``H``, relative
acceleration ``|da| > 0``) the first-contact time follows from a *fixed* sequence of
float64 steps.  ``fast_rel`` runs that sequence with selects instead of
branches, so the batch kernels' loop over rows compiles to SIMD code (LLVM
vectorises it: 4 or 8 rows per instruction), and it certifies each answer:
every claim is checked against a rigorous rounding-error bound, and a row
whose certificate fails is returned as ``UNDECIDED``; the kernels then hand
that row to the robust solver (``robust._ttc_rel``).  A decided row's
answer therefore carries the robust solver's guarantees: a no-contact is
proved; a contact time comes from the same double-double polishing step and
the same "done" test as ``robust._solve_entry``.

The sequence (f = |g|^2 - R^2, c = g.g' = f'/2, q = c', see robust):

0. t = 0: f(0) certainly < 0 -> 0.0 (overlap; the robust solver's own
   float test); certainly > 0 is needed for everything below.
1. Cull: the box distance of g over both halves of [0, H] (per-axis
   range of a quadratic) exceeds R on each -> inf.
2. Structure of the cubic c from its turning points cut1 < cut2 (roots of the
   quadratic q, closed form about the inflection point t0), with bounds on
   their location error: fixes the *piece* of c holding the first local
   minimum e of f (concave piece 0 left of cut1, or convex piece 2 right of
   cut2), or proves f increasing on [0, inf) (-> inf) or decreasing up to H.
3. Newton on c from the side of e where it converges monotonically (piece
   0: its left end; piece 2: a closed-form bound beyond e), K_C steps,
   recording any iterate with certainly negative f: [0, x] then holds
   exactly one sign change of f (the entry root).  A converged e with
   certainly positive f(e) (+ a slack for |x - e|) on piece 2 -> inf.
4. Entry root in [0, hi]: K_F bracketed model steps (exact for straight
   motion), then one double-double step; its result is returned when
   ``_solve_entry``'s "done" test passes, else the row is undecided.

On bench_core.py's mix (half aimed, half random) about one row in a hundred
is left undecided (tests/core/narrow/test_narrow_fast.py holds it under 3 %);
on those rows the robust solver runs.  Long horizons are left to the robust
solver no more often.
Each numerical decision is commented where it is made.

``fast_rows`` is the one loop over rows (per dimension D = 2, 3): it reads
the inputs, forms the exact relative state and runs ``fast_rel``.  Making
LLVM vectorise it took, each step measured on the benchmark mix:

* every helper inlined and free of calls and inner loops (LLVM vectorises
  only an innermost loop whose body calls nothing; a non-inlined ``f_dd``
  kept it scalar);
* flat 1-D views of the inputs and uint64 indices (see ``fast_rows``);
* two vectors interleaved per iteration (``_Interleaved2``), because the
  sequence is one long dependency chain per row.

bench/bench_core.py prints the cost per row of the loop, of a whole batch
kernel and of the robust solver alone.

Rows with da == 0 exactly (constant relative velocity) get their own loop,
``straight_rows``, over ``straight``'s branch-free closed form (the
sequence above needs |da| > 0): the same loads and compiler options, any
horizon; on bench_core.py's mix it costs less per row than the accelerating
mix.
"""
from __future__ import annotations

import math

import numpy as np
from llvmlite.binding import set_option
from numba import njit
from numba.core.compiler import Compiler
from numba.core.compiler_lock import global_compiler_lock
from numba.extending import overload, register_jitable

from circle_collision_ros.core.narrow.dd import exponent, pow2
from circle_collision_ros.core.narrow.straight import straight_rel
from circle_collision_ros.core.narrow.evaluate import (EPS, F_ERR, INF, NAN, UNDECIDED, c_bound,
                                                       c_err, dot, f0_err, f_dd_inline, g_at, gd_at,
                                                       fmax, fmin, model_err, model_root,
                                                       polish_done, rel2, rel3, scale_at,
                                                       turning_points, valid_row)


# Newton steps on c and float64 model steps for the entry root (written out
# in fast_rel; tests/core/narrow/test_narrow_fast.py checks the counts).  On
# the benchmark mix fewer than 4 Newton steps from the closed-form start, or
# 3 model steps instead of 4, leave markedly more rows undecided, and more
# steps decide almost none more; a step in the SIMD loop costs a small
# fraction of one robust fallback.
K_C = 4
K_F = 4


@register_jitable(error_model="numpy")
def _axis_gap2(p, v, a, ta, tb):
    """Squared lower bound of |g_k(t)| over [ta, tb] (0 <= ta <= tb) for one axis.

    g_k is a quadratic, so its range over [ta, tb] is spanned by its values
    at ta, tb and at the vertex -v/a when inside.  Exact-safe: the float64
    Horner values are within 4u S_k of the exact ones (3u Horner + u for the
    dropped dd low parts) with S_k = |p| + tb (|v| + tb |a| / 2), since every
    point of [ta, tb] has t <= tb; a vertex time off by a few ulp moves the
    value by ~|a| (u t)^2 / 2 <= u^2 S_k (the quadratic is flat there).  The
    margin m = 8 eps S_k = 16u S_k covers both 4x.  A division by a = 0 gives
    a NaN or infinite vertex time, which is never inside (comparisons false).
    """
    ga = p + ta * (v + 0.5 * ta * a)
    gb = p + tb * (v + 0.5 * tb * a)
    ts = -v / a
    gv = p + ts * (v + 0.5 * ts * a)
    gv = gv if (ts > ta) & (ts < tb) else ga
    lo = fmin(fmin(ga, gb), gv)
    hi = fmax(fmax(ga, gb), gv)
    m = 8.0 * EPS * (abs(p) + tb * (abs(v) + 0.5 * tb * abs(a)))
    d = fmax(fmax(lo - m, -hi - m), 0.0)
    return d * d


@njit(cache=True, error_model="numpy", inline="always")
def _box_gap2(P, V, A, ta, tb):
    """Squared lower bound of |g(t)| over [ta, tb] (sum of the axes' bounds).

    A loop over the D axes (LLVM unrolls it): an overload per tuple length,
    like the other vector helpers, would be a call that LLVM does not inline
    for D = 3, which would keep the fast path's loop scalar."""
    s = 0.0
    for k in range(len(P)):
        s += _axis_gap2(P[k], V[k], A[k], ta, tb)
    return s


@register_jitable(error_model="numpy")
def _cbrt_up(y):
    """A power of two in (cbrt(y), 2 cbrt(y)] for a normal y > 0 (0 for
    y = 0; for a subnormal y only an upper bound), from the exponent bits:
    no libm call, so the SIMD loop keeps vectorising.  Only a starting guess
    is made from it."""
    k = (exponent(y) - 1023) // 3 + 1
    return pow2(k + 1023) if y > 0.0 else 0.0


@register_jitable(error_model="numpy")
def _newton_c(Ph, Vh, Ah, R2, nP, nV, nA, ea, eb, x, hit, hitx):
    """One Newton step on c, clamped to [ea, eb]; records a certain f < 0.

    Returns (x_new, hit, hitx).  A clamped step only slows convergence
    (the row may then be left undecided); it never makes a claim."""
    g = g_at(Ph, Vh, Ah, x)
    gd = gd_at(Vh, Ah, x)
    S = scale_at(nP, nV, nA, x)
    # f(x) < 0 beyond its error bound (F_ERR, see evaluate): certain
    h = dot(g, g) - R2 < -F_ERR * (S * S + R2)
    hitx = x if (h & (not hit)) else hitx
    hit = hit | h
    xn = x - dot(g, gd) / (dot(gd, gd) + dot(g, Ah))
    return fmin(fmax(xn, ea), eb), hit, hitx


@njit(cache=True, error_model="numpy", inline="always")
def _model_step(Ph, Vh, Ah, R2, A2, t, lo, hi, conv):
    """One float64 step of _solve_entry's coarse phase, as selects.

    Keeps the bracket [lo, hi] by the sign of f(t); a model step leaving it
    becomes a bisection; once converged (model truncation estimate
    < 1e-7 relative, a sub-32-ulp step, or f = 0) t is frozen.  Only the
    final double-double step's "done" test certifies the result."""
    g = g_at(Ph, Vh, Ah, t)
    f = dot(g, g) - R2
    pos = f > 0.0
    lo = t if pos else lo
    hi = hi if pos else t
    gd = gd_at(Vh, Ah, t)
    step, s, _rel, c, a2, disc = model_root(f, g, gd, Ah, R2)
    # no model root: its vertex, as entry_step (exact for a double root)
    step = step if disc >= 0.0 else -c / a2
    tn = t + step
    inside = (tn > lo) & (tn < hi)
    me = model_err(step, s, gd, Ah, A2) if disc > 0.0 else INF
    now = (inside & (me <= 1e-7 * abs(tn))) | (abs(step) <= 32.0 * EPS * abs(t)) | (f == 0.0)
    tn = tn if inside else 0.5 * (lo + hi)
    tn = t if (conv | (f == 0.0)) else tn
    return tn, lo, hi, conv | now


@njit(cache=True, error_model="numpy", inline="always")
def fast_rel(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, H):
    """First-contact time on the exact (dd) relative state, or UNDECIDED.

    Same contract as ``robust._ttc_rel`` for a finite H >= 0 on the rows
    it decides; H must be NaN for a row with invalid input (then UNDECIDED).
    """
    R2 = Rh * Rh
    P2 = dot(Ph, Ph)
    A2 = dot(Ah, Ah)
    nP = math.sqrt(P2)
    nV = math.sqrt(dot(Vh, Vh))
    nA = math.sqrt(A2)

    # ---- 0. t = 0: the float sign of f0 beyond its error bound (f0_err),
    # the robust solver's own threshold, beyond which it decides exactly so.
    f0 = P2 - R2
    e0 = f0_err(P2, R2)
    overlap = f0 < -e0
    ok = (f0 > e0) & (A2 > 0.0) & (H < INF)

    # ---- 1. cull over the two halves of [0, H] (H/2 is exact, so they cover
    # [0, H]; four quarters culled 0.1 % more rows of the benchmark mix and
    # cost 1 ns/row more).  Rp = R (1 + 4 eps) covers the rounding of
    # R = r_a + r_b, (1 + 8 eps) the rounding of the squares and the sum.
    # Overflow gives NaN: no cull.
    Rp = Rh * (1.0 + 4.0 * EPS)
    lim = Rp * Rp * (1.0 + 8.0 * EPS)
    h2 = 0.5 * H
    culled = ((H < INF) & (f0 > e0)
              & (_box_gap2(Ph, Vh, Ah, 0.0, h2) > lim) & (_box_gap2(Ph, Vh, Ah, h2, H) > lim))

    # ---- 2. structure of c (cubic, leading coefficient A2/2 > 0) from its
    # turning points with certified location error (turning_points): "cuts"
    # (q0 < -eq0) means two turning points cut1,2 = t0 -+ r, each within dl
    # of exact; q0 > eq0 means none (c increasing everywhere); in between:
    # undecided.
    c0 = dot(Ph, Vh)
    ec0 = 16.0 * EPS * nP * nV
    t0, q0, ct0, eq0, cuts, r, dl, Dl = turning_points(Ph, Vh, Ah, nP, nV, nA, A2)
    ok = ok & ((q0 > eq0) | cuts)
    cut1 = t0 - r
    cut2 = t0 + r
    c1, ec1 = c_bound(Ph, Vh, Ah, nP, nV, nA, cut1)
    c2, ec2 = c_bound(Ph, Vh, Ah, nP, nV, nA, cut2)
    # Without cuts r = dl = 0 and cut1 = cut2 = t0, so the same tests read
    # "t0 on which side of 0" and "sign of c(t0)" for a monotone c.
    neg0 = c0 < -ec0  # approaching at t = 0 (f decreasing)
    pos0 = c0 > ec0  # receding
    # approaching: c < 0 from 0 up to its first root e (the minimum of f)
    #   e in (0, cut1): c(cut1) > 0 certainly (c increasing, concave there);
    #   e in piece 2: cut1 < 0 (c decreasing then increasing on [0, inf)) or
    #   c(cut1) < 0 (the local maximum of c, so c < 0 up to piece 2)
    n_p0 = neg0 & (cut1 > dl) & (c1 > ec1)
    n_p2 = neg0 & ((cut1 < -dl) | (c1 < -(ec1 + Dl)))
    # receding: f increases while c > 0; no contact ever if c stays > 0 on
    # [0, inf): cut2 < 0 (c increasing on [0, inf)) or c(cut2) > 0 (local
    # minimum of c); else c turns negative before cut2 and back after it
    # (one local minimum e of f on (0, inf), in piece 2)
    p_inf = pos0 & ((cut2 < -dl) | (c2 > ec2 + Dl))
    p_p2 = pos0 & (cut2 > dl) & (c2 < -ec2)
    piece0 = n_p0
    piece2 = n_p2 | p_p2
    # piece 2 starts at the exact cut2 >= cut2 - dl (c increasing beyond it)
    ea = 0.0 if piece0 else fmax(cut2 - dl, 0.0)
    eb = fmin(cut1, H) if piece0 else H
    # c(H) < 0 certainly: f still decreasing at H, so the minimum is beyond H
    # (for piece 0 only if cut1 >= H; c(H) > 0 when H lies just past cut1)
    gH = g_at(Ph, Vh, Ah, H)
    cH = dot(gH, gd_at(Vh, Ah, H))
    ecH = c_err(nP, nV, nA, H)
    SH = scale_at(nP, nV, nA, H)
    fH = dot(gH, gH) - R2
    efH = F_ERR * (SH * SH + R2)
    no_min = (piece2 | (piece0 & (cut1 >= H))) & (cH < -ecH)
    # (only on a known piece: the one-sign-change argument of step 3 needs it)
    has_min = (not no_min) & (piece0 | (piece2 & (cH > ecH))) & (ea < eb)

    # ---- 3. Newton on c from the end of the piece where it is monotone:
    # c increasing and concave on piece 0 -> from the left end (iterates stay
    # <= e); increasing and convex on piece 2 -> from the right end (>= e).
    # A hit x (f(x) certainly < 0) bounds a single sign change of f on [0, x]:
    # f > 0 at 0 and f decreases to e; past e (piece 2, or overshoot by
    # rounding) f increases but is still < 0 at x; on piece 0, x <= cut1 and
    # c > 0 on [cut1, x] would be needed to come back, which eb = min(cut1, H)
    # excludes.  Receding pairs (p_p2): f > 0 while it increases, so any hit
    # lies in its single decreasing run.
    # Start on piece 2 near e, from the right: c(t0 + s) = c(t0) + q0 s +
    # A2 s^3 / 2 > 0 once s >= sb = max(sqrt(4|q0|/A2), cbrt(4|c(t0)|/A2))
    # (then A2 s^3 / 4 covers each of the other terms), so e < t0 + sb; a far
    # start at H took ~1/3 off per step (H = 1e3 s: 39 % of the mix decided,
    # now 99 %).  Only a starting guess: the step is clamped to [ea, eb], a
    # hit anywhere there brackets the entry, and the miss test below brackets
    # e itself, so its rounding (and the 1.01) cannot affect an answer.
    sb = fmax(math.sqrt(4.0 * abs(q0) / A2), _cbrt_up(4.0 * abs(ct0) / A2))
    x = ea if piece0 else fmin(eb, fmax(ea, t0 + 1.01 * sb))
    hit = False
    hitx = eb
    x, hit, hitx = _newton_c(Ph, Vh, Ah, R2, nP, nV, nA, ea, eb, x, hit, hitx)
    x, hit, hitx = _newton_c(Ph, Vh, Ah, R2, nP, nV, nA, ea, eb, x, hit, hitx)
    x, hit, hitx = _newton_c(Ph, Vh, Ah, R2, nP, nV, nA, ea, eb, x, hit, hitx)
    x, hit, hitx = _newton_c(Ph, Vh, Ah, R2, nP, nV, nA, ea, eb, x, hit, hitx)
    g = g_at(Ph, Vh, Ah, x)
    Se = scale_at(nP, nV, nA, x)
    fe = dot(g, g) - R2
    efe = F_ERR * (Se * Se + R2)
    he = fe < -efe
    hitx = x if (he & (not hit)) else hitx
    hit = hit | he
    # No contact at the minimum e (piece 2 only: there e is the only local
    # minimum of f after 0; on piece 0 a second one may follow in piece 2).
    # Bracket e: y = x - w, z = x + w with w = max(2 |Newton step|, 1e-9 x),
    # both inside piece 2 past cut2 + dl where c increases; certain signs
    # c(y) < 0 < c(z) put e in (y, z).  Then |f(x) - f(e)| = 2 |int_e^x c|
    # <= 2 M (z - y), M = max |c| on [y, z] = max(-c(y), c(z)) + error, so
    # f(x) beyond its error bound plus that slack proves f(e) > 0.
    gd = gd_at(Vh, Ah, x)
    w = fmax(2.0 * abs(dot(g, gd) / (dot(gd, gd) + dot(g, Ah))), 1e-9 * x)
    y = x - w
    z = x + w
    cy, ecy = c_bound(Ph, Vh, Ah, nP, nV, nA, y)
    cz, ecz = c_bound(Ph, Vh, Ah, nP, nV, nA, z)
    M = fmax(-cy, cz) + fmax(ecy, ecz)
    e_miss = (piece2 & (y >= fmax(cut2 + dl, 0.0)) & (cy < -ecy) & (cz > ecz)
              & (fe > efe + 2.0 * M * (z - y)))

    # ---- decision
    contact = ok & ((no_min & (fH < -efH)) | (has_min & hit))
    # f(H) > 0 with f decreasing (or rising then decreasing) on [0, H]: the
    # minimum of f on [0, H] is min(f0, f(H)) > 0
    miss = ok & (p_inf | (no_min & (fH > efH)) | (has_min & (not hit) & e_miss))
    hi = H if no_min else hitx

    # ---- 4. entry root in [0, hi] (f(0) > 0 > f(hi), one sign change)
    lo = 0.0
    t = hi
    conv = False
    t, lo, hi2, conv = _model_step(Ph, Vh, Ah, R2, A2, t, lo, hi, conv)
    t, lo, hi2, conv = _model_step(Ph, Vh, Ah, R2, A2, t, lo, hi2, conv)
    t, lo, hi2, conv = _model_step(Ph, Vh, Ah, R2, A2, t, lo, hi2, conv)
    t, lo, hi2, conv = _model_step(Ph, Vh, Ah, R2, A2, t, lo, hi2, conv)
    # one double-double step with _solve_entry's "done" test: the step's
    # rounding (|step| rel) < 1e-4 ulp and either a step of <= 64 ulp or a
    # model truncation estimate < 1e-4 ulp; the result must stay in [0, hi]
    # (_solve_entry would clamp and polish again: left to it)
    f, g = f_dd_inline(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, t)
    gd = gd_at(Vh, Ah, t)
    step, s, rel, c, a2, disc = model_root(f, g, gd, Ah, R2)
    tn = t + step
    at = abs(tn)
    ast = abs(step)
    # a model root step exactly as entry_step would take it (its fallbacks
    # are left to _solve_entry)
    root = (disc > 0.0) & ((c <= 0.0) | (a2 > 0.0))
    done = ((tn >= 0.0) & (tn <= hi) & root
            & polish_done(ast, at, rel, model_err(step, s, gd, Ah, A2)))
    done = done | (f == 0.0)
    tn = t if f == 0.0 else tn
    res = tn if (contact & conv & done) else UNDECIDED
    res = INF if (miss | culled) else res
    res = 0.0 if overlap else res
    return res if H >= 0.0 else UNDECIDED


# --------------------------------------------------------------------------
# SIMD loops over batch rows (one compiled loop per dimension, shared by the
# batch kernels and the scalar entry points, so both run the same code)
# --------------------------------------------------------------------------
class _Interleaved2(Compiler):
    """numba compiler pipeline for the fast loop: two LLVM loop-vectoriser
    options are set while it compiles, then put back to LLVM's defaults.

    ``-force-vector-interleave=2``: the fast path is one long chain of
    dependent operations per row (Newton and model steps in sequence), ~1600
    instructions per vector of rows, far more than the CPU's reorder window,
    so with one vector per iteration the FP units wait on latency (~1.2
    instructions per cycle from the instruction count and the time).  Two
    interleaved vectors give the scheduler independent work: 39 -> 25 ns/row
    (2-D), 46 -> 32 (3-D) on the benchmark mix; 3 or 4 gained nothing more.

    ``-vectorize-scev-check-threshold=64`` (default 16): the 3-D loop's
    stride-3 indices need more run-time overflow checks than the default
    allows, and without them it stayed scalar (300 ns/row).

    The arithmetic per row is the same either way, so results are bitwise
    the same (a cache compiled without the options is only slower).  The
    options are global to LLVM, so they are set and reset under numba's
    compiler lock, which every compilation holds.
    """

    def compile_extra(self, func):
        with global_compiler_lock:
            set_option("", "-force-vector-interleave=2")
            set_option("", "-vectorize-scev-check-threshold=64")
            try:
                return super().compile_extra(func)
            finally:
                set_option("", "-force-vector-interleave=0")
                set_option("", "-vectorize-scev-check-threshold=16")


def _load(pa, va, aa, ra, pb, vb, ab, rb, i, Z):
    """(chk, Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, fine) of row i: the sum of its
    inputs (non-finite if any is) and its exact relative state (``fine``: see
    evaluate.rel3).  Vectors are flat
    1-D views of (n, D) rows with D = len(Z) (Z: a tuple of D zeros, which
    selects the implementation at compile time)."""


@overload(_load, inline="always")
def _ov_load(pa, va, aa, ra, pb, vb, ab, rb, i, Z):
    if Z.count == 2:
        def impl2(pa, va, aa, ra, pb, vb, ab, rb, i, Z):
            x = np.uint64(2) * i
            y = x + np.uint64(1)
            chk = (pa[x] + pa[y] + va[x] + va[y] + aa[x] + aa[y] + ra[i]
                   + pb[x] + pb[y] + vb[x] + vb[y] + ab[x] + ab[y] + rb[i])
            return (chk,) + rel2(pa[x], pa[y], va[x], va[y], aa[x], aa[y], ra[i],
                                  pb[x], pb[y], vb[x], vb[y], ab[x], ab[y], rb[i])
        return impl2

    def impl3(pa, va, aa, ra, pb, vb, ab, rb, i, Z):
        x = np.uint64(3) * i
        y = x + np.uint64(1)
        z = x + np.uint64(2)
        chk = (pa[x] + pa[y] + pa[z] + va[x] + va[y] + va[z] + aa[x] + aa[y] + aa[z] + ra[i]
               + pb[x] + pb[y] + pb[z] + vb[x] + vb[y] + vb[z] + ab[x] + ab[y] + ab[z] + rb[i])
        return (chk,) + rel3(pa[x], pa[y], pa[z], va[x], va[y], va[z], aa[x], aa[y], aa[z], ra[i],
                              pb[x], pb[y], pb[z], vb[x], vb[y], vb[z], ab[x], ab[y], ab[z], rb[i])
    return impl3


@njit(cache=True, error_model="numpy", inline="always")
def _flat(pa, va, aa, pb, vb, ab):
    """Flat 1-D views of the (n, D) vector inputs (see below)."""
    return (pa.reshape(-1), va.reshape(-1), aa.reshape(-1),
            pb.reshape(-1), vb.reshape(-1), ab.reshape(-1))


@njit(cache=True, error_model="numpy", inline="always")
def _row(pa, va, aa, ra, pb, vb, ab, rb, Hs, hofs, jj, i, Z):
    """(h, exact relative state) of row i = i0 + jj: h its horizon, NaN for a
    row with invalid input or a state outside the span of magnitudes the
    float paths solve (evaluate._SPAN): the fast paths then leave it
    undecided."""
    chk, Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, fine = _load(pa, va, aa, ra, pb, vb, ab, rb, i, Z)
    h = Hs[np.uint64(hofs + jj)]
    h = h if (valid_row(chk, ra[i], rb[i], h) & fine) else NAN
    return h, Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl


# The loop reads the (n, D) input arrays through flat 1-D views with a
# constant stride D and indexes with uint64: with 2-D indexing LLVM versions
# the loop on "row stride == 1" (false for (n, 2) rows) and always ran the
# scalar copy, and numba's negative-index wraparound on signed indices turned
# loads into gathers.  Reading the inputs in the loop, not from a transposed
# copy, lets the loads overlap the arithmetic (a separate gather pass was
# memory bound at ~7 ns/row).
@njit(cache=True, error_model="numpy", pipeline_class=_Interleaved2)
def fast_rows(pa, va, aa, ra, pb, vb, ab, rb, Hs, hofs, out, i0, m, Z):
    """out[i] = fast-path result (or UNDECIDED) of rows i0 <= i < i0 + m.

    Vectors (n, D) with D = len(Z) (Z: a tuple of D zeros), radii (n,), all
    C-contiguous float64; row i's horizon is Hs[hofs + i - i0].  Rows with
    invalid input come out UNDECIDED.
    """
    pa, va, aa, pb, vb, ab = _flat(pa, va, aa, pb, vb, ab)
    for jj in range(m):
        i = np.uint64(i0 + jj)
        h, Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl = _row(pa, va, aa, ra, pb, vb, ab, rb, Hs, hofs, jj, i, Z)
        out[i] = fast_rel(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, h)


def _raw_straight(aa, ab, i, Z):
    """Row i (flat (n, D) views, D = len(Z)) has a_a == a_b exactly, so its
    relative acceleration (and the scaled one) is exactly 0."""


@overload(_raw_straight, inline="always")
def _ov_raw_straight(aa, ab, i, Z):
    if Z.count == 2:

        def impl2(aa, ab, i, Z):
            x = np.uint64(2) * i
            return (aa[x] == ab[x]) & (aa[x + np.uint64(1)] == ab[x + np.uint64(1)])

        return impl2

    def impl3(aa, ab, i, Z):
        x = np.uint64(3) * i
        return (
            (aa[x] == ab[x])
            & (aa[x + np.uint64(1)] == ab[x + np.uint64(1)])
            & (aa[x + np.uint64(2)] == ab[x + np.uint64(2)])
        )

    return impl3


@njit(cache=True, error_model="numpy")
def count_straight(aa, ab, i0, m, Z):
    """How many of rows i0 <= i < i0 + m have da == 0 exactly (a_a == a_b)."""
    aa = aa.reshape(-1)
    ab = ab.reshape(-1)
    c = 0
    for jj in range(m):
        c += _raw_straight(aa, ab, np.uint64(i0 + jj), Z)
    return c


# The straight loop: the rows with da == 0 through straight's
# branch-free closed form, vectorised like fast_rows.  It writes only those
# rows; with `keep` the others keep what fast_rows wrote, else they get
# UNDECIDED.  A straight row that fast_rows already decided (its box cull or
# the overlap test, certified) keeps that answer if the closed form leaves it
# undecided.
@njit(cache=True, error_model="numpy", pipeline_class=_Interleaved2)
def straight_rows(pa, va, aa, ra, pb, vb, ab, rb, Hs, hofs, out, i0, m, Z, keep):
    """out[i] = straight-path result (or UNDECIDED) of the rows with da == 0
    among i0 <= i < i0 + m (layout as ``fast_rows``)."""
    pa, va, aa, pb, vb, ab = _flat(pa, va, aa, pb, vb, ab)
    for jj in range(m):
        i = np.uint64(i0 + jj)
        h, Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl = _row(pa, va, aa, ra, pb, vb, ab, rb, Hs, hofs, jj, i, Z)
        res = straight_rel(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, h)
        st = _raw_straight(aa, ab, i, Z)
        old = out[i] if keep else UNDECIDED
        out[i] = res if (st & ((res != UNDECIDED) | (not keep))) else old
