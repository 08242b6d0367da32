"""Float64 and double-double evaluations shared by the narrow-phase solvers.

Everything here is evaluated *geometrically* from ``g(t) = dp + t (dv + t da/2)``
(never from power-basis coefficients of the quartic), on relative quantities
given as tuples of length D = 2 or 3 (high parts ``Ph, Vh, Ah``; the low parts
``Pl, Vl, Al`` of the exact double-double relative state where a residual
must be exact).  Used by the robust solver (``robust``) and the
branch-free fast path (``fast``), so both decide with the same
evaluations and the same error bounds.

Also here: the exact relative state (``rel2``, ``rel3``) and the validity
test of a row's input (``valid_row``), shared by both solvers' entry points.

The helpers the fast path uses are inlined into it (numba IR inlining, or
small ``register_jitable`` functions that LLVM inlines; ``f_dd`` through its
``f_dd_inline`` twin): it runs them inside one SIMD-vectorised loop, and
LLVM vectorises no loop that calls a function.
"""
from __future__ import annotations

import math

from numba import njit
from numba.extending import overload, register_jitable

from circle_collision_ros.core.narrow.dd import pow2_scales, two_prod, two_sum

EPS = 2.220446049250313e-16  # float64 machine epsilon (2u)
# Error bound of f = |g|^2 - R^2 evaluated in float64 from the high parts of
# the relative state (Horner g, see g_at): |dg| <= 6u S with
# S = |dp| + t|dv| + t^2|da|/2 (incl. the dropped dd low parts, |lo| <= u|hi|),
# so | |g~|^2 - |g|^2 | <= ~12u S^2; the dot product adds 3u S^2, R^2 from the
# high part of R = r_a + r_b and its rounding ~3u R^2, the subtraction u.
# Total < 17u (S^2 + R^2) = 8.5 eps (S^2 + R^2); 16 eps gives ~2x margin.
F_ERR = 16.0 * EPS
# Error bound of the double-double f (f_dd): ~u^2 (S^2 + R^2) (compensated
# Horner g to u^2 S, exact squares and sums, O(u^2) cross terms); signs are
# taken from it only beyond 16 eps^2 (S^2 + R^2) = 64 u^2 (S^2 + R^2).
DD_ERR = 16.0 * EPS * EPS
INF = math.inf
NAN = math.nan
UNDECIDED = -1.0  # a row no certified path decided (never a result: those are >= 0, inf or NaN)

# --------------------------------------------------------------------------
# exact relative state (the only place absolute coordinates meet)
# --------------------------------------------------------------------------


@register_jitable(error_model="numpy")
def fmin(a, b):
    # numba's builtin min/max compile to branches that block vectorisation
    return a if a < b else b


@register_jitable(error_model="numpy")
def fmax(a, b):
    return a if a > b else b


# The first-contact time does not change when dp, dv, da and R are scaled by
# one factor, and a power of two scales them exactly.  rel2/rel3 scale the
# relative state so that its largest magnitude lies in [2, 4): every later
# product (up to 4th powers of lengths, e.g. |g x g'|^2 and |g'|^2 R^2 in the
# model root) then stays far from underflow and overflow for any inputs with
# magnitudes below ~1e150 (unscaled, a state ~1e-80 m or ~1e78 m was solved
# wrongly).  The solver is homogeneous in length (every sum adds terms of the
# same length degree, every bound is relative), so wherever the unscaled
# state did not under- or overflow the results are bitwise those of the
# unscaled solver (checked on 1.8 million rows).
#
# Span of magnitudes.  Scaling down is exact only above the subnormal range:
# a component far below the largest one is rounded on the subnormal grid or
# flushed to 0, and then da looks exactly 0 (the straight-line closed form
# answered rows that accelerate: dp = 1e150, da = -1e-175 gave inf, the
# exact answer is 4.47e162 s), and even an exact small component makes its
# squares underflow (|dv|^2 = 0 for dv = 1e-163 dp: "static", inf instead of
# 5e162 s).  So a row is solved in floating point only when every nonzero
# high part (dp, dv, da components, R) of the scaled state is >= _SPAN =
# 2^-240 (the largest is >= 2): products of up to four of them are then
# >= 2^-960, normal, and every rounding error is relative as the bounds
# assume.  Low parts only enter double-double residuals, where a subnormal
# rounding (<= 2^-1075 absolute) is far below the dd error bound
# (16 eps^2 S^2 with S >= 2^-240).  Rows outside the span -- never a physical
# scene: 72 orders of magnitude between two quantities -- come out of
# rel2/rel3 with ``fine`` False and are decided exactly (exact).
_SPAN = 2.0 ** -240


@register_jitable(error_model="numpy")
def _kept(c, cs):
    """The raw relative component c, scaled to cs, is 0 or inside the span."""
    return (c == 0.0) | (abs(cs) >= _SPAN)


@njit(cache=True, error_model="numpy", inline="always")
def rel3(pax, pay, paz, vax, vay, vaz, aax, aay, aaz, r_a,
          pbx, pby, pbz, vbx, vby, vbz, abx, aby, abz, r_b):
    """Exact relative state (TwoSum) as (Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, fine):
    the only place absolute coordinates meet, so ~1e6 m map offsets cost
    nothing.  The state is scaled by a power of two (see above; times are
    unchanged); ``fine``: every nonzero high part lies inside the span
    (_SPAN), else the row must be decided exactly."""
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
    m = fmax(fmax(fmax(abs(x0), abs(y0)), fmax(abs(z0), abs(u0))),
             fmax(fmax(fmax(abs(v0), abs(w0)), fmax(abs(i0), abs(j0))), fmax(abs(k0), Rh)))
    s, t = pow2_scales(m)
    X, Y, Z = (x0 * s) * t, (y0 * s) * t, (z0 * s) * t
    U, V, W = (u0 * s) * t, (v0 * s) * t, (w0 * s) * t
    I, J, K = (i0 * s) * t, (j0 * s) * t, (k0 * s) * t
    Rs = (Rh * s) * t
    fine = (_kept(x0, X) & _kept(y0, Y) & _kept(z0, Z) & _kept(u0, U) & _kept(v0, V)
            & _kept(w0, W) & _kept(i0, I) & _kept(j0, J) & _kept(k0, K) & _kept(Rh, Rs))
    return ((X, Y, Z), ((x1 * s) * t, (y1 * s) * t, (z1 * s) * t),
            (U, V, W), ((u1 * s) * t, (v1 * s) * t, (w1 * s) * t),
            (I, J, K), ((i1 * s) * t, (j1 * s) * t, (k1 * s) * t),
            Rs, (Rl * s) * t, fine)


@njit(cache=True, error_model="numpy", inline="always")
def rel2(pax, pay, vax, vay, aax, aay, r_a, pbx, pby, vbx, vby, abx, aby, r_b):
    """Planar ``rel3`` (2-component tuples)."""
    x0, x1 = two_sum(pax, -pbx)
    y0, y1 = two_sum(pay, -pby)
    u0, u1 = two_sum(vax, -vbx)
    v0, v1 = two_sum(vay, -vby)
    i0, i1 = two_sum(aax, -abx)
    j0, j1 = two_sum(aay, -aby)
    Rh, Rl = two_sum(r_a, r_b)
    m = fmax(fmax(fmax(abs(x0), abs(y0)), fmax(abs(u0), abs(v0))), fmax(fmax(abs(i0), abs(j0)), Rh))
    s, t = pow2_scales(m)
    X, Y = (x0 * s) * t, (y0 * s) * t
    U, V = (u0 * s) * t, (v0 * s) * t
    I, J = (i0 * s) * t, (j0 * s) * t
    Rs = (Rh * s) * t
    fine = (_kept(x0, X) & _kept(y0, Y) & _kept(u0, U) & _kept(v0, V) & _kept(i0, I)
            & _kept(j0, J) & _kept(Rh, Rs))
    return ((X, Y), ((x1 * s) * t, (y1 * s) * t), (U, V), ((u1 * s) * t, (v1 * s) * t),
            (I, J), ((i1 * s) * t, (j1 * s) * t), Rs, (Rl * s) * t, fine)


@njit(cache=True, error_model="numpy", inline="always")
def valid_row(chk, r_a, r_b, horizon):
    """Input a row may be solved for: all values finite (chk is their sum:
    inf or NaN if any is, as inf - inf = NaN), radii >= 0, horizon >= 0.
    (& rather than `and`: no branches in the fast loop.)"""
    return (chk - chk == 0.0) & (r_a >= 0.0) & (r_b >= 0.0) & (horizon >= 0.0)


# --------------------------------------------------------------------------
# float64 geometric evaluations (used to *locate* things; never for signs that
# decide contact vs no contact, which use the double-double versions below)
# --------------------------------------------------------------------------


# Vector helpers on tuples of length D = 2 or 3.  The numba implementations
# are selected per tuple length at compile time (``overload``), so planar
# pairs carry no z = 0 components through the solver; a 3-D computation with
# z = 0 gives bitwise the same values (x + 0 = x, except the sign of a zero).
# The plain Python bodies are used under NUMBA_DISABLE_JIT.


def g_at(P, V, A, t):
    """g(t) = dp + t (dv + t da/2) in float64 (Horner in t)."""
    h = 0.5 * t
    return tuple(P[k] + t * (V[k] + h * A[k]) for k in range(len(P)))


def gd_at(V, A, t):
    """g'(t) = dv + t da."""
    return tuple(V[k] + t * A[k] for k in range(len(V)))


def dot(x, y):
    s = x[0] * y[0] + x[1] * y[1]
    return s + x[2] * y[2] if len(x) == 3 else s


def cross2(x, y):
    """|x cross y|^2 (in 2-D the square of the scalar cross product)."""
    cz = x[0] * y[1] - x[1] * y[0]
    if len(x) == 2:
        return cz * cz
    cx = x[1] * y[2] - x[2] * y[1]
    cy = x[2] * y[0] - x[0] * y[2]
    return cx * cx + cy * cy + cz * cz


@overload(g_at)
def _ov_g(P, V, A, t):
    # Horner in t: g = dp + t (dv + t da/2).  Absolute error ~u*S with
    # S = |dp| + t|dv| + t^2|da|/2, i.e. the scale of the terms, which is the
    # best any float64 evaluation can do; digits lost by cancellation near a
    # contact are recovered by the double-double residual later.
    if P.count == 2:
        def impl(P, V, A, t):
            h = 0.5 * t
            return (P[0] + t * (V[0] + h * A[0]), P[1] + t * (V[1] + h * A[1]))
        return impl

    def impl3(P, V, A, t):
        h = 0.5 * t
        return (P[0] + t * (V[0] + h * A[0]), P[1] + t * (V[1] + h * A[1]),
                P[2] + t * (V[2] + h * A[2]))
    return impl3


@overload(gd_at)
def _ov_gd(V, A, t):
    if V.count == 2:
        return lambda V, A, t: (V[0] + t * A[0], V[1] + t * A[1])
    return lambda V, A, t: (V[0] + t * A[0], V[1] + t * A[1], V[2] + t * A[2])


@overload(dot)
def _ov_dot(x, y):
    if x.count == 2:
        return lambda x, y: x[0] * y[0] + x[1] * y[1]
    return lambda x, y: x[0] * y[0] + x[1] * y[1] + x[2] * y[2]


@overload(cross2)
def _ov_cross2(x, y):
    if x.count == 2:
        def impl(x, y):
            cz = x[0] * y[1] - x[1] * y[0]
            return cz * cz
        return impl

    def impl3(x, y):
        cx = x[1] * y[2] - x[2] * y[1]
        cy = x[2] * y[0] - x[0] * y[2]
        cz = x[0] * y[1] - x[1] * y[0]
        return cx * cx + cy * cy + cz * cz
    return impl3


@njit(cache=True, error_model="numpy", inline="always")
def c_at(P, V, A, t):
    """f'(t)/2 = g . g' (geometric form, no power-basis coefficients)."""
    return dot(g_at(P, V, A, t), gd_at(V, A, t))


@register_jitable(error_model="numpy")
def scale_at(nP, nV, nA, t):
    """S(t) = |dp| + |t| (|dv| + |t| |da| / 2): the scale of the terms of g(t)."""
    at = abs(t)
    return nP + at * (nV + 0.5 * at * nA)


@register_jitable(error_model="numpy")
def f0_err(P2, R2):
    """Error bound of the float64 f(0) = |dp|^2 - R^2 from the high parts
    (P2 = dp.dp, R2 = Rh^2): < 8 eps (P2 + R2) (rounding of the squares and
    sums, the dropped low parts <= u).  Beyond it every solver decides on the
    float sign (overlap -> 0.0, or f(0) > 0); within it the robust solver
    takes the double-double value, the branch-free paths leave the row."""
    return 8.0 * EPS * (P2 + R2)


@register_jitable(error_model="numpy")
def reach_miss(nP, nV, nA, Rh, Rl, H):
    """True if no contact in [0, H] by the triangle inequality (finite H):
    |g(t)| >= |dp| - t |dv| - t^2 |da| / 2 >= nP - reach.  The norms of the
    high parts differ from the exact ones by <= ~3u relative (rounding and
    the dropped low parts), reach and the difference add ~3u; the margin
    8 eps (nP + reach) (>= 16u of every term) and R (1 + 4 eps) (R = r_a + r_b
    rounded) keep it from ever rejecting a real contact."""
    reach = H * (nV + 0.5 * H * nA)
    return (H < INF) & (nP - reach > (Rh + Rl) * (1.0 + 4.0 * EPS) + 8.0 * EPS * (nP + reach))


@register_jitable(error_model="numpy")
def c_err(nP, nV, nA, t):
    """Bound of the float64 error of c(t) = g.g': |dg| <= 6u S, |dg'| <= 3u S',
    the dot product 2u S S' -> 11u S S'; 16 eps = 32u gives ~3x margin."""
    at = abs(t)
    return 16.0 * EPS * scale_at(nP, nV, nA, t) * (nV + at * nA)


@register_jitable(error_model="numpy")
def c_bound(Ph, Vh, Ah, nP, nV, nA, t):
    """(c(t), a bound of its float64 error): see c_err."""
    return c_at(Ph, Vh, Ah, t), c_err(nP, nV, nA, t)


# numba IR inlining (not a register_jitable call): the fast path's SIMD loop
# must not contain a call, and LLVM does not inline a function of this size
@njit(cache=True, error_model="numpy", inline="always")
def turning_points(Ph, Vh, Ah, nP, nV, nA, A2):
    """Turning points of c (roots of q = c') with certified location error.

    c is a cubic with leading coefficient A2/2 > 0: c'' = 3 A2 (t - t0) with
    t0 = -(da.dv)/A2 (c concave left of t0, convex right of it) and
    q = c' = q(t0) + 1.5 A2 (t - t0)^2; q0 = q(t0) is evaluated geometrically.
    t0 is within dt0 of exact: the dot product da.dv (its rounding and the
    dropped dd low parts) is good to 4u |da||dv| absolutely -- it may cancel,
    so no relative bound -- i.e. t0 to 4u |dv|/|da|, and A2 and the division
    add 5u |t0|; dt0 takes 4x that.  Evaluating q at t0 + dt0 instead raises
    q0 by at most 1.5 A2 dt0^2 (q is stationary at t0).  With eq0 bounding
    the error of q0, ``cuts`` (q0 < -eq0) means two turning points
    t0 -+ r, r = sqrt(-q0 / (1.5 A2)), each within dl of exact; q0 > eq0
    means none (c increasing everywhere); in between the structure of c is
    not certain.  Dl bounds how much c changes when a turning point moves by
    dl.  Returns (t0, q0, c(t0), eq0, cuts, r, dl, Dl).
    """
    t0 = -dot(Ah, Vh) / A2
    at0 = abs(t0)
    g = g_at(Ph, Vh, Ah, t0)
    gd = gd_at(Vh, Ah, t0)
    q0 = dot(gd, gd) + dot(g, Ah)
    ct0 = dot(g, gd)
    S0 = scale_at(nP, nV, nA, t0)
    Sd0 = nV + at0 * nA
    dt0 = 8.0 * EPS * (at0 + nV / nA)
    eq0 = 16.0 * EPS * (Sd0 * Sd0 + S0 * nA) + 1.5 * A2 * dt0 * dt0
    cuts = q0 < -eq0
    r = math.sqrt(fmax(-q0, 0.0) / (1.5 * A2))
    # location error: dt0, the effect of eq0 on r -- r'^2 - r^2 = d / (1.5 A2)
    # with |d| <= eq0 < -q0, so |r' - r| = |d| / (1.5 A2 (r + r')) <=
    # eq0 / (1.5 A2 r) -- and the rounding of sqrt, the division and
    # t0 -+ r (8 eps (|t0| + r) covers them twice over)
    dl = (dt0 + 8.0 * EPS * (at0 + r) + eq0 / (1.5 * A2 * r)) if cuts else 0.0
    # c is stationary at a turning point: moving it by dl changes c by at
    # most |c''| dl^2 / 2 + A2 |dl|^3 / 2 = 1.5 A2 r dl^2 + A2 dl^3 / 2 <= Dl
    Dl = 1.5 * A2 * dl * dl * (2.0 * r + dl)
    return t0, q0, ct0, eq0, cuts, r, dl, Dl


# --------------------------------------------------------------------------
# double-double evaluations
# --------------------------------------------------------------------------


@register_jitable(error_model="numpy")
def _g_comp_dd(ph, pl, vh, vl, ah, al, t):
    """One component of g(t) = dp + t (dv + t da/2) as an unevaluated sum
    hi + lo with absolute error ~u^2 S (compensated Horner, Graillat et al.
    2005): every Horner operation's rounding error is recovered exactly by
    TwoProd/TwoSum and, together with the dd low parts of the inputs, summed
    into a correction whose own rounding is u * O(u S)."""
    h = 0.5 * ah  # exact scaling
    p1, e1 = two_prod(h, t)
    s1, e2 = two_sum(p1, vh)
    p2, e3 = two_prod(s1, t)
    r, e4 = two_sum(p2, ph)
    # exact: g = r + e4 + e3 + t (e1 + e2 + vl + t al/2) + pl
    corr = e4 + e3 + t * (e1 + e2 + vl + t * (0.5 * al)) + pl
    return two_sum(r, corr)  # |corr| may exceed |r| after cancellation


def _g_dd(Ph, Pl, Vh, Vl, Ah, Al, t):
    """g(t) as (hi, lo) tuples, double-double per component."""
    g = [_g_comp_dd(Ph[k], Pl[k], Vh[k], Vl[k], Ah[k], Al[k], t) for k in range(len(Ph))]
    return tuple(x[0] for x in g), tuple(x[1] for x in g)


@overload(_g_dd, inline="always")
def _ov_g_dd(Ph, Pl, Vh, Vl, Ah, Al, t):
    if Ph.count == 2:
        def impl(Ph, Pl, Vh, Vl, Ah, Al, t):
            gxh, gxl = _g_comp_dd(Ph[0], Pl[0], Vh[0], Vl[0], Ah[0], Al[0], t)
            gyh, gyl = _g_comp_dd(Ph[1], Pl[1], Vh[1], Vl[1], Ah[1], Al[1], t)
            return (gxh, gyh), (gxl, gyl)
        return impl

    def impl3(Ph, Pl, Vh, Vl, Ah, Al, t):
        gxh, gxl = _g_comp_dd(Ph[0], Pl[0], Vh[0], Vl[0], Ah[0], Al[0], t)
        gyh, gyl = _g_comp_dd(Ph[1], Pl[1], Vh[1], Vl[1], Ah[1], Al[1], t)
        gzh, gzl = _g_comp_dd(Ph[2], Pl[2], Vh[2], Vl[2], Ah[2], Al[2], t)
        return (gxh, gyh, gzh), (gxl, gyl, gzl)
    return impl3


def _round_dd(Gh, Gl):
    """Components hi + lo rounded to float64."""
    return tuple(Gh[k] + Gl[k] for k in range(len(Gh)))


@overload(_round_dd)
def _ov_round_dd(Gh, Gl):
    if Gh.count == 2:
        return lambda Gh, Gl: (Gh[0] + Gl[0], Gh[1] + Gl[1])
    return lambda Gh, Gl: (Gh[0] + Gl[0], Gh[1] + Gl[1], Gh[2] + Gl[2])


@register_jitable(error_model="numpy")
def f_dd(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, t):
    """Return (f(t), g(t)) with f = |g|^2 - R^2 and g rounded to float64.

    Absolute error of f is ~u^2 (|g|^2 + R^2) + rounding of the result, so the
    *sign* of f is right unless |f| is below ~1e-31 of the squared scale
    (far inside the documented 1e-9 R^2 grazing slack) and g carries full
    relative precision even when |g| << |dp|.
    """
    Gh, Gl = _g_dd(Ph, Pl, Vh, Vl, Ah, Al, t)
    # sum_k (gh + gl)_k^2 - (Rh + Rl)^2: the large terms gh^2 and -Rh^2 are
    # split exactly (TwoProd) and summed exactly (TwoSum); all error terms and
    # the small cross terms 2 gh gl, 2 Rh Rl (each O(u) of the scale) are
    # accumulated in float64, whose rounding is O(u^2) of the scale.
    s, lo = two_prod(-Rh, Rh)
    lo -= 2.0 * Rh * Rl
    for k in range(len(Gh)):
        p, e = two_prod(Gh[k], Gh[k])
        s, e2 = two_sum(s, p)
        lo += (e + e2) + 2.0 * Gh[k] * Gl[k]
    return s + lo, _round_dd(Gh, Gl)


# The fast path's SIMD loop needs f_dd inlined (a loop that calls a function
# is not vectorised, and LLVM keeps a call of this size); IR inlining is slow
# to compile, so only that loop uses this twin of the same code.
f_dd_inline = njit(cache=True, error_model="numpy", inline="always")(f_dd)


@register_jitable(error_model="numpy")
def model_root(f, g, gd, A, R2):
    """Entering root of the local model of f, branch-free.

    Model: f(t+d) ~ f + 2 c d + a2 d^2 with c = g.g', a2 = |g'|^2 + g.da
    (exact Taylor terms; the neglected terms are exactly
    (g'.da) d^3 + |da|^2 d^4 / 4, which vanish for da = 0, so the step is
    *exact* for straight-line motion and converges cubically otherwise).
    The discriminant c^2 - a2 f is rewritten with the Lagrange identity
    c^2 - |g'|^2 |g|^2 = -|g x g'|^2 as
        |g'|^2 R^2 - |g x g'|^2 - (g.da) f
    which avoids the cancellation of c^2 against |g'|^2 |g|^2 for head-on
    approach (|g| >> R); at grazing incidence (|g x g'| ~ |g'| R) its
    absolute error is ~u |g'|^2 R^2.  The root is taken in the form
    f / (-c + sqrt(disc)) when c <= 0 (approaching: no cancellation), else
    (-c - sqrt(disc)) / a2.

    Returns (step, s, rel, c, a2, disc).  The step is the model root only
    where disc > 0 and its denominator is nonzero (c <= 0, or a2 > 0);
    elsewhere it is a meaningless number (or inf/NaN) that callers must not
    use (``entry_step`` substitutes a fallback; the fast path leaves such a
    row undecided).  s = sqrt(max(disc, 0)) is half the model slope at its
    root; rel bounds the relative rounding error of the step (inf unless
    disc > 0): disc carries ~4u of its terms (large relative error at
    grazing incidence, where they cancel), sqrt halves it, the remaining
    operations add no cancellation (<= 3u).  Selects only (no branches), so
    the fast path's SIMD loop can use it.
    """
    c = dot(g, gd)
    gd2 = dot(gd, gd)
    ga = dot(g, A)
    a2 = gd2 + ga
    k1 = gd2 * R2
    k2 = cross2(g, gd)
    k3 = ga * f
    disc = k1 - k2 - k3
    s = math.sqrt(disc if disc > 0.0 else 0.0)
    step = f / (s - c) if c <= 0.0 else -(c + s) / a2
    rel = (2.0 * EPS * (k1 + k2 + abs(k3))) / disc + 2.0 * EPS if disc > 0.0 else INF
    return step, s, rel, c, a2, disc


@njit(cache=True, error_model="numpy", inline="always")
def entry_step(f, g, gd, A, R2):
    """Step from t to the entering root of the local model of f (``model_root``),
    with fallbacks where the model has no usable root.

    Returns (step, sqrt(disc), rel): sqrt(disc) is half the model slope at
    its root (used by callers for the truncation estimate) and 0.0 when the
    step is not a model root (vertex / Newton fallback); rel bounds the
    relative rounding error of the computed step (inf if not a root step).
    step is NaN when there is no usable step (caller then bisects).
    """
    step, s, rel, c, a2, disc = model_root(f, g, gd, A, R2)
    if disc < 0.0:
        # The model just misses zero: a (near-)double root, e.g. point bodies
        # (R = 0, f = |g|^2) or a tangent graze.  Step to the model's vertex
        # -c/a2, which is exact for a double root (Newton would only halve
        # the distance per step).  The caller's bracket keeps it safe.
        if a2 > 0.0:
            return -c / a2, 0.0, INF
        if c != 0.0:
            return -0.5 * f / c, 0.0, INF  # plain Newton
        return NAN, 0.0, INF
    if c <= 0.0:
        if s - c == 0.0:
            return (0.0 if f == 0.0 else NAN), 0.0, INF
        return step, s, rel
    if a2 <= 0.0:
        return -0.5 * f / c, 0.0, INF
    return step, s, rel


@register_jitable(error_model="numpy")
def model_err(step, s, gd, A, A2):
    """Estimated root error left after a model step of size ``step``.

    f(t + d) differs from the quadratic model by (g'.da) d^3 + |da|^2 d^4/4
    exactly (f is a quartic); divided by the model slope 2 s at the new point
    this is the distance to the true root, to first order.  inf when the step
    was not a model root (s == 0).
    """
    if not (s > 0.0):
        return INF
    ad = abs(step)
    return ad * ad * ad * (abs(dot(gd, A)) + 0.25 * A2 * ad) / (2.0 * s)


@register_jitable(error_model="numpy")
def polish_done(ast, at, rel, merr):
    """The "done" test of a double-double polishing step (robust and fast path).

    A step of size ast to a root t of magnitude at is final when its own
    rounding ast * rel (large at grazing incidence) is < 1e-4 ulp and either
    the step is <= 64 ulp (then the truncation error, ~step^2 x curvature, is
    far below an ulp) or the model truncation estimate merr (``model_err``)
    is < 1e-4 ulp (so the final rounding of t + step is the correct rounding
    unless the root lies within 1e-4 ulp of a rounding boundary).  Selects
    only, for the fast path's SIMD loop.  Only an estimate: the robust path
    certifies its result by signs (``robust._certified``).
    """
    return (ast * rel <= 1e-4 * EPS * at) & ((ast <= 64.0 * EPS * at) | (merr <= 1e-4 * EPS * at))

