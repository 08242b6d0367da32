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
  with the smaller ``|phi|`` is returned, in practice the nearest float.
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


@njit(cache=True, error_model="numpy")
def _psi_dd(gxh, gxl, gyh, gyl, exh, exl, eyh, eyl, vx, vy, ax, ay, r):
    """``r L`` as a dd (L from Q = e.e in dd, with sqrt's Newton correction) and the dd
    power-basis coefficients of ``psi = w.g(t)`` (a 6-tuple for ``_horner_dd``).

    Each coefficient is a 2-term dot product of exact inputs (g0 and e are TwoSum dd's, v
    and a floats, halving a is exact), so it errs by ~6u^2 of its term sizes, which
    ``M(t)`` bounds.
    """
    qh, ql = two_prod(exh, exh)
    q2h, q2l = two_prod(eyh, eyh)
    qh, ql2 = two_sum(qh, q2h)
    ql = ql + q2l + ql2 + 2.0 * (exh * exl + eyh * eyl)
    Lh = math.sqrt(qh)
    sqh, sql = two_prod(Lh, Lh)
    Ll = ((qh - sqh) - sql + ql) / (2.0 * Lh)
    rLh, rLl = two_prod(r, Lh)
    rLl += r * Ll
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
    # --- cheap, exact-safe rejection: the swept box of the centre against the segment's box
    if H < INF:
        for c0, c1, c2, s0, s1 in ((px, vx, ax, Ax, Bx), (py, vy, ay, Ay, By)):
            lo_c = min(c0, c0 + H * (c1 + 0.5 * H * c2))
            hi_c = max(c0, c0 + H * (c1 + 0.5 * H * c2))
            if c2 != 0.0:
                tv = -c1 / c2
                if 0.0 < tv < H:
                    cv = c0 + tv * (c1 + 0.5 * tv * c2)
                    lo_c = min(lo_c, cv)
                    hi_c = max(hi_c, cv)
            # margin: 16 ulps of the coordinate's scale covers the rounding of these few
            # operations (the vertex value included, whose tv is itself rounded); _TINY
            # covers their absolute error where values are subnormal (the scale check
            # below comes after this test); an overflow gives inf or NaN, never a rejection
            m = F_BOUND * (abs(c0) + H * abs(c1) + H * H * abs(c2) + abs(s0) + abs(s1) + r)
            m += _TINY
            if lo_c - r - m > max(s0, s1) or hi_c + r + m < min(s0, s1):
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
        lo_p = min(psi0, psi0 + H * (psi1 + H * psi2))
        hi_p = max(psi0, psi0 + H * (psi1 + H * psi2))
        lo_q = min(pi0, pi0 + H * (pi1 + H * pi2))
        hi_q = max(pi0, pi0 + H * (pi1 + H * pi2))
        if psi2 != 0.0:
            tv = -psi1 / (2.0 * psi2)
            if 0.0 < tv < H:
                x = psi0 + tv * (psi1 + tv * psi2)
                lo_p = min(lo_p, x)
                hi_p = max(hi_p, x)
        if pi2 != 0.0:
            tv = -pi1 / (2.0 * pi2)
            if 0.0 < tv < H:
                x = pi0 + tv * (pi1 + tv * pi2)
                lo_q = min(lo_q, x)
                hi_q = max(hi_q, x)
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
        # bracket by proved signs, phi(lo) > 0 > phi(hi) with lo, hi adjacent floats or
        # t's two neighbours: the root is then within one ulp of the t returned
        ok = False
        for _ in range(4):
            if t <= 0.0:
                t = next_up(0.0)
            ft = _phi_dd(sig, ps, rLh, rLl, t)
            ct = _certain(ft, DD_BOUND * m_at(t))
            lo, hi = next_down(t), next_up(t)
            if ct > 0:  # the root is above t: is it below t's successor?
                lo, flo = t, ft
                fhi = _phi_dd(sig, ps, rLh, rLl, hi)
                ok = _certain(fhi, DD_BOUND * m_at(hi)) < 0
            elif ct < 0:
                hi, fhi = t, ft
                flo = _phi_dd(sig, ps, rLh, rLl, lo)
                ok = _certain(flo, DD_BOUND * m_at(lo)) > 0
            else:  # phi(t) is 0 to within its bound: prove both neighbours
                flo = _phi_dd(sig, ps, rLh, rLl, lo)
                fhi = _phi_dd(sig, ps, rLh, rLl, hi)
                ok = (_certain(flo, DD_BOUND * m_at(lo)) > 0
                      and _certain(fhi, DD_BOUND * m_at(hi)) < 0)
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
