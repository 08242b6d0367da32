"""PROTOTYPE (not used by the package): a certified, branch-free fast path
for the narrow phase, kept for the follow-up on issue 3's 1000x figure.

Run::

    .venv/bin/python bench/prototypes/fast_path_prototype.py

It prints, on bench_core.py's 200,000-pair mix (H = 10 s): the fraction of
rows the fast path leaves undecided (they would go to the robust solver),
the number of decided rows whose result differs from ``time_to_collision``
(bit for bit), and the serial ns/row of the fast path alone.

Idea.  For a finite horizon and |da| > 0, decide most rows with a fixed
sequence of float64 steps and no data-dependent branches, so that the loop
can be SIMD-vectorised; any row whose certificate fails is UNDECIDED.
1. Cull: box distance of g over four sub-intervals of [0, H] (per-axis range
   of a quadratic, 8 eps margin) > R(1 + 4 eps): no contact.
2. Structure of c = g.g' (f'/2): the turning points cut1 < cut2 of c from
   q(t0), with location error dl and the resulting bound Dl on c at a cut;
   signs of c at 0, cut1, cut2, H with error bounds 16 eps S S'.  This fixes
   the piece holding the first minimum e of f (concave piece 0 or convex
   piece 2), or proves f increasing (inf), or f decreasing up to H.
3. Newton on c from the piece end where it is monotone (K_C steps), noting
   any iterate with certainly negative f: then [0, x] holds exactly one root.
4. Entry root: K_F safeguarded model steps (exact for straight lines), then
   one double-double step with _solve_entry's "done" test; else UNDECIDED.
Measured (2026-11-22, this machine): 5.3 % undecided, 0 mismatches on the
200k mix; but ~280-300 ns/row serial, because LLVM does not vectorise this
loop body (small staged loops over column arrays do vectorise, e.g. six
Newton steps on c for 11 ns/row with zmm code).  Findings: numba's builtin
min/max block vectorisation (use ``a if a < b else b``); (n, 2) row arrays cost ~3x over column arrays in a
vectorised loop; the CPU has AVX-512.
"""
import math

import numpy as np
from numba import njit
from numba.extending import overload

from circle_collision_ros.core.narrow_dd import two_sum
from circle_collision_ros.core.narrow_phase import (
    _EPS, _F_ERR, _INF, _cross2, _dot, _f_dd, _g, _gd, _model_err)


UNDECIDED = -1.0


@njit(inline="always")
def MIN(a, b):
    return a if a < b else b


@njit(inline="always")
def MAX(a, b):
    return a if a > b else b


NSUB = 4
K_C = 6
K_F = 4


@njit(error_model="numpy", inline="always")
def _axis_gap(p, v, a, ta, tb):
    ga = p + ta * (v + 0.5 * ta * a)
    gb = p + tb * (v + 0.5 * tb * a)
    ts = -v / a
    gv = p + ts * (v + 0.5 * ts * a)
    inside = (ts > ta) & (ts < tb)
    gv = gv if inside else ga
    lo = MIN(MIN(ga, gb), gv)
    hi = MAX(MAX(ga, gb), gv)
    m = 8.0 * _EPS * (abs(p) + tb * (abs(v) + 0.5 * tb * abs(a)))
    d = MAX(MAX(lo - m, -hi - m), 0.0)
    return d * d


def _box_gap2(P, V, A, ta, tb):
    return sum(_axis_gap(P[k], V[k], A[k], ta, tb) for k in range(len(P)))


@overload(_box_gap2)
def _ov_box_gap2(P, V, A, ta, tb):
    if P.count == 2:
        return lambda P, V, A, ta, tb: (_axis_gap(P[0], V[0], A[0], ta, tb)
                                        + _axis_gap(P[1], V[1], A[1], ta, tb))
    return lambda P, V, A, ta, tb: (_axis_gap(P[0], V[0], A[0], ta, tb)
                                    + _axis_gap(P[1], V[1], A[1], ta, tb)
                                    + _axis_gap(P[2], V[2], A[2], ta, tb))


@njit(error_model="numpy", inline="always")
def _model_step(f, g, gd, A, R2):
    """Branch-free _entry_step: (step, s, rel, is_root)."""
    c = _dot(g, gd)
    gd2 = _dot(gd, gd)
    ga = _dot(g, A)
    a2 = gd2 + ga
    k1 = gd2 * R2
    k2 = _cross2(g, gd)
    k3 = ga * f
    disc = k1 - k2 - k3
    s = math.sqrt(MAX(disc, 0.0))
    root = f / (s - c) if c <= 0.0 else -(c + s) / a2
    vert = -c / a2
    is_root = disc >= 0.0
    step = root if is_root else vert
    rel = (2.0 * _EPS * (k1 + k2 + abs(k3))) / disc + 2.0 * _EPS
    return step, s, rel, is_root


@njit(error_model="numpy", inline="always")
def _fast_rel(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, H):
    R2 = Rh * Rh
    Rp = Rh * (1.0 + 4.0 * _EPS)
    P2 = _dot(Ph, Ph)
    A2 = _dot(Ah, Ah)
    nP = math.sqrt(P2)
    nV = math.sqrt(_dot(Vh, Vh))
    nA = math.sqrt(A2)
    # ---- cull
    lim = Rp * Rp * (1.0 + 8.0 * _EPS)
    culled = H < _INF
    for j in range(NSUB):
        ta = H * (j / NSUB)
        tb = H * ((j + 1) / NSUB)
        culled = culled & (_box_gap2(Ph, Vh, Ah, ta, tb) > lim)
    f0 = P2 - R2
    ok = (f0 > 8.0 * _EPS * (P2 + R2)) & (A2 > 0.0) & (H < _INF)
    # ---- structure of c = g.g'
    c0 = _dot(Ph, Vh)
    ec0 = 16.0 * _EPS * nP * nV
    t0 = -_dot(Ah, Vh) / A2
    at0 = abs(t0)
    g = _g(Ph, Vh, Ah, t0)
    gd = _gd(Vh, Ah, t0)
    q0 = _dot(gd, gd) + _dot(g, Ah)
    S0 = nP + at0 * (nV + 0.5 * at0 * nA)
    Sd0 = nV + at0 * nA
    dt0 = 8.0 * _EPS * at0
    eq0 = 16.0 * _EPS * (Sd0 * Sd0 + S0 * nA) + 1.5 * A2 * dt0 * dt0
    cuts = q0 < -eq0
    ok = ok & ((q0 > eq0) | cuts)
    r = math.sqrt(MAX(-q0, 0.0) / (1.5 * A2))
    cut1 = t0 - r
    cut2 = t0 + r
    dl = (8.0 * _EPS * (at0 + r) + eq0 / (3.0 * A2 * r)) if cuts else 0.0
    Dl = 1.5 * A2 * dl * dl * (2.0 * r + dl)
    # c at the cuts
    g1 = _g(Ph, Vh, Ah, cut1)
    c1 = _dot(g1, _gd(Vh, Ah, cut1))
    a1 = abs(cut1)
    ec1 = 16.0 * _EPS * (nP + a1 * (nV + 0.5 * a1 * nA)) * (nV + a1 * nA)
    g2 = _g(Ph, Vh, Ah, cut2)
    c2 = _dot(g2, _gd(Vh, Ah, cut2))
    a2_ = abs(cut2)
    ec2 = 16.0 * _EPS * (nP + a2_ * (nV + 0.5 * a2_ * nA)) * (nV + a2_ * nA)
    neg0 = c0 < -ec0
    pos0 = c0 > ec0
    # case N: approaching at 0
    n_p0 = neg0 & (cut1 > dl) & (c1 > ec1)             # e in (0, cut1): concave
    n_p2 = neg0 & ((cut1 < -dl) | (c1 < -(ec1 + Dl)))  # e after MAX(cut2, 0): convex
    # case P: receding at 0
    p_inf = pos0 & ((cut2 < -dl) | (c2 > ec2 + Dl))
    p_p2 = pos0 & (cut2 > dl) & (c2 < -ec2)
    piece0 = n_p0
    piece2 = n_p2 | p_p2
    ea = 0.0 if piece0 else MAX(cut2, 0.0)
    eb = MIN(cut1, H) if piece0 else H
    # c at H decides whether the first minimum lies within the horizon
    gH = _g(Ph, Vh, Ah, H)
    gdH = _gd(Vh, Ah, H)
    cH = _dot(gH, gdH)
    SH = nP + H * (nV + 0.5 * H * nA)
    SdH = nV + H * nA
    ecH = 16.0 * _EPS * SH * SdH
    fH = _dot(gH, gH) - R2
    efH = _F_ERR * (SH * SH + R2)
    h_needed = piece2 | (piece0 & (cut1 >= H))
    no_min = h_needed & (cH < -ecH)  # f decreasing up to H (after any rise)
    has_min = (not no_min) & (piece0 | (cH > ecH)) & (ea < eb)
    # ---- Newton on c for the minimum e, monotone from the safe end
    x = ea if piece0 else eb
    hit = False
    hitx = eb
    xp = x
    for _ in range(K_C):
        g = _g(Ph, Vh, Ah, x)
        gd = _gd(Vh, Ah, x)
        fx = _dot(g, g) - R2
        Sx = nP + x * (nV + 0.5 * x * nA)
        h = fx < -_F_ERR * (Sx * Sx + R2)
        hitx = x if h else hitx
        hit = hit | h
        cx = _dot(g, gd)
        qx = _dot(gd, gd) + _dot(g, Ah)
        xn = x - cx / qx
        xn = MIN(MAX(xn, ea), eb)
        xp = x
        x = xn
    g = _g(Ph, Vh, Ah, x)
    fe = _dot(g, g) - R2
    Se = nP + x * (nV + 0.5 * x * nA)
    efe = _F_ERR * (Se * Se + R2)
    dx = abs(x - xp)
    conv = dx <= 1e-9 * x
    slack = 2.0 * ((nV + x * nA) * (nV + x * nA) + Se * nA) * dx * dx
    he = conv & (fe < -efe)
    hitx = x if he else hitx
    hit = hit | he
    e_miss = conv & (fe > efe + slack) & piece2
    # ---- decision and bracket [0, hi] for the entry root
    contact = ok & ((no_min & (fH < -efH)) | (has_min & hit))
    miss = ok & (p_inf | (no_min & (fH > efH)) | (has_min & (not hit) & e_miss))
    hi = H if no_min else hitx
    # ---- entry root: safeguarded model steps in float64
    lo = 0.0
    t = hi
    hi0 = hi
    conv_f = False
    for _ in range(K_F):
        g = _g(Ph, Vh, Ah, t)
        f = _dot(g, g) - R2
        pos = f > 0.0
        lo = t if pos else lo
        hi = hi if pos else t
        gd = _gd(Vh, Ah, t)
        step, s, rel, is_root = _model_step(f, g, gd, Ah, R2)
        tn = t + step
        inside = (tn > lo) & (tn < hi)
        me = _model_err(step, s, gd, Ah, A2) if is_root else _INF
        now = (inside & (me <= 1e-7 * abs(tn))) | (abs(step) <= 32.0 * _EPS * abs(t)) | (f == 0.0)
        tn = tn if inside else 0.5 * (lo + hi)
        tn = t if (conv_f | (f == 0.0)) else tn
        conv_f = conv_f | now
        t = tn
    # ---- one double-double polish step (as _solve_entry)
    f, g = _f_dd(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, t)
    gd = _gd(Vh, Ah, t)
    step, s, rel, is_root = _model_step(f, g, gd, Ah, R2)
    tn = t + step
    inb = (tn >= 0.0) & (tn <= hi0)
    at = abs(tn)
    ast = abs(step)
    small = ast <= 64.0 * _EPS * at
    done = inb & is_root & (ast * rel <= 1e-4 * _EPS * at) & (
        small | (_model_err(step, s, gd, Ah, A2) <= 1e-4 * _EPS * at))
    done = done | (f == 0.0)
    tn = t if f == 0.0 else tn
    res = tn if (contact & conv_f & done) else UNDECIDED
    res = _INF if miss else res
    res = _INF if culled else res
    return res


@njit(error_model="numpy")
def _kernel2(pa, va, aa, ra, pb, vb, ab, rb, H, out):
    for i in range(out.shape[0]):
        x0, x1 = two_sum(pa[i, 0], -pb[i, 0])
        y0, y1 = two_sum(pa[i, 1], -pb[i, 1])
        u0, u1 = two_sum(va[i, 0], -vb[i, 0])
        v0, v1 = two_sum(va[i, 1], -vb[i, 1])
        i0, i1 = two_sum(aa[i, 0], -ab[i, 0])
        j0, j1 = two_sum(aa[i, 1], -ab[i, 1])
        Rh, Rl = two_sum(ra[i], rb[i])
        out[i] = _fast_rel((x0, y0), (x1, y1), (u0, v0), (u1, v1), (i0, j0), (i1, j1), Rh, Rl, H)


def main() -> None:
    import os
    import sys
    import time
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    sys.path.insert(0, root)
    from circle_collision_ros.core import time_to_collision
    from tests.core.test_narrow_phase_accuracy import mixed_pairs
    n, H = 200_000, 10.0
    P = mixed_pairs(n, 2, 1)
    out = np.empty(n)
    _kernel2(*P, H, out)
    best = math.inf
    for _ in range(5):
        t0 = time.perf_counter()
        _kernel2(*P, H, out)
        best = min(best, time.perf_counter() - t0)
    ref = time_to_collision(*P, horizon=H)
    dec = out != UNDECIDED
    print(f"undecided: {1 - dec.mean():.4f}  mismatches vs time_to_collision: "
          f"{int(np.sum(out[dec] != ref[dec]))}  fast path alone: {best * 1e9 / n:.1f} ns/row (serial)")


if __name__ == "__main__":
    main()
