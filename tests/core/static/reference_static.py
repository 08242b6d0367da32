"""High-precision reference for the edge-interior contact (mpmath; ~1-3 ms/row).

Independent of ``core.static.edge_exact`` (exact algebra on the entering root of
each side's quadratic): here the candidate times are the real roots of the quartic

    F(t) = (w.g(t))^2 - r^2 Q     (|s(t)| = r on either side at once),

whose coefficients are formed exactly (``Fraction``), made square-free exactly
(so a tangent graze is a simple root), then rooted by ``mpmath.polyroots`` at
``PREC`` + 64 bits (more when the exact coefficients are longer: inputs
spanning hundreds of binades, where it takes seconds per row).  A root counts
when the body was farther than r just before it (|w.g| - r L at t (1 - 2^-120)
is positive: a graze from outside counts, one from inside does not) and the foot
point is strictly inside the segment; the first one, rounded by mpmath to
nearest float64, is the answer.  The t = 0 rules are evaluated exactly on the
rational coefficients.

Accuracy: simple roots come out to ~2^-PREC relative, far below the 1e-30
margins here (double roots were removed exactly).  ``ambiguous`` flags rows
whose answer hinges on a quantity within ``TOL`` (relative) of zero -- a graze
of |s| = r, the foot point at an end, the time at the horizon or at a rounding
midpoint -- so stress tests can exempt exactly those rows (a graze is flagged
wherever the foot point is: conservative).
"""
from __future__ import annotations

import math
from fractions import Fraction

import mpmath
import numpy as np
from mpmath import mp, mpf

PREC = 400
TOL = mpf("1e-30")


def _poly(cs, t):
    out = mpf(0)
    for c in reversed(cs):
        out = out * t + c
    return out


def _first_nonzero_sign(*cs) -> int:
    for c in cs:
        if c != 0:
            return 1 if c > 0 else -1
    return 0


def _log2(x: Fraction) -> int:
    """floor-ish log2 |x| (x != 0): enough to pick a scale."""
    return abs(x.numerator).bit_length() - x.denominator.bit_length()


def _real_roots(asc, prec: int):
    """Real roots (mpf) of the polynomial with ascending ``Fraction`` coefficients.

    Its leading and constant coefficients must be nonzero.
    """
    n = len(asc) - 1
    # t = 2^k tau with 2^k ~ the roots' geometric mean: polyroots' tolerances are
    # absolute, so the roots it sees should be of order 1 (exact power-of-two rescaling)
    k = round((_log2(asc[0]) - _log2(asc[-1])) / n)
    scale = Fraction(2) ** k
    asc = [_mp(c * scale ** i) for i, c in enumerate(asc)]
    # float64 starting points make Durand-Kerner converge in a few steps (the
    # iteration itself runs at prec + 64 bits, so they only affect the speed)
    try:
        with np.errstate(all="ignore"):
            init = [mpmath.mpc(complex(z)) for z in np.roots([float(x) for x in asc[::-1]])]
        if len(init) != n or not all(mpmath.isfinite(z) for z in init):
            init = None
    except (OverflowError, np.linalg.LinAlgError):
        init = None
    for steps in (100, 1000, 5000):
        try:
            rts = mpmath.polyroots(asc, maxsteps=steps, extraprec=64, roots_init=init, asc=True)
            break
        except mpmath.libmp.libhyper.NoConvergence:
            init = None
            continue
    else:  # pragma: no cover
        raise RuntimeError("polyroots failed")
    out = []
    for z in rts:
        z = mpmath.mpc(z)
        # a real (simple) root comes out with |im| ~ 2^-PREC relative, the complex
        # pair of a near miss by a relative gap delta with |im| ~ sqrt(delta): 1e-60
        # separates them for every gap above 1e-120 (below 1e-30: flagged ambiguous)
        if abs(z.imag) <= mpf("1e-60") * abs(z):
            out.append(z.real * mpf(2) ** k)
    return sorted(out)


def _mp(x: Fraction):
    return mpf(x.numerator) / x.denominator


def _pdivmod(a, b):
    """Quotient and remainder of ascending Fraction polynomials (b's top != 0)."""
    a = list(a)
    q = [Fraction(0)] * max(len(a) - len(b) + 1, 1)
    while len(a) >= len(b) and a:
        k = a[-1] / b[-1]
        sh = len(a) - len(b)
        q[sh] = k
        for i, c in enumerate(b):
            a[sh + i] -= k * c
        a.pop()
        while a and a[-1] == 0:
            a.pop()
    return q, a


def _squarefree(p):
    """Return p / gcd(p, p') exactly: every root simple (Durand-Kerner converges fast)."""
    a, b = p, [i * c for i, c in enumerate(p)][1:]
    while b:
        a, b = b, _pdivmod(a, b)[1]
    return _pdivmod(p, a)[0] if len(a) > 1 else p


def reference_edge(p, v, a, r, A, B, solid_side, horizon=math.inf) -> tuple[float, bool]:
    """(first edge-interior contact time rounded to float64, ambiguous flag)."""
    P, V, Acc, Av, Bv = ([Fraction(float(c)) for c in x] for x in (p, v, a, A, B))
    R = Fraction(float(r))
    e = [Bv[0] - Av[0], Bv[1] - Av[1]]
    w = [-e[1], e[0]]
    d = [P[0] - Av[0], P[1] - Av[1]]
    Q = e[0] * e[0] + e[1] * e[1]

    def dot(x, y):
        return x[0] * y[0] + x[1] * y[1]

    c = [dot(w, d), dot(w, V), dot(w, Acc) / 2]  # w.g(t), ascending powers
    pr = [dot(e, d), dot(e, V), dot(e, Acc) / 2]  # e.g(t)
    quart = [c[0] ** 2 - R * R * Q, 2 * c[0] * c[1], c[1] ** 2 + 2 * c[0] * c[2],
             2 * c[1] * c[2], c[2] ** 2]

    # t = 0 (exact rational comparisons)
    inside0 = 0 < pr[0] < Q
    if quart[0] < 0 and inside0:
        return 0.0, False
    if quart[0] == 0:
        if R > 0:
            sig = 1 if c[0] > 0 else -1
            approaching = _first_nonzero_sign(sig * c[1], sig * c[2]) < 0
        else:
            approaching = solid_side != 0 and _first_nonzero_sign(
                solid_side * c[1], solid_side * c[2]) > 0
        foot = _first_nonzero_sign(pr[1], pr[2])
        if approaching and (inside0 or (pr[0] == 0 and foot > 0) or (pr[0] == Q and foot < 0)):
            return 0.0, False
    if float(horizon) == 0.0:
        return math.inf, False

    # t > 0: roots of the square-free part of F / t^k (k: the order of the root at 0)
    k = 0
    while k < 5 and quart[k] == 0:
        k += 1
    cs = quart[k:]
    while cs and cs[-1] == 0:
        cs.pop()
    # PREC bits, or more when the exact (dyadic) coefficients have longer mantissas:
    # extreme magnitudes (slow, seconds per row, but still exact coefficients)
    prec = max(PREC, 64 + max((abs(x.numerator).bit_length() for x in cs), default=0))
    cs = _squarefree(cs) if len(cs) > 2 else cs
    with mp.workprec(prec):
        H = mpf(float(horizon)) if math.isfinite(horizon) else None
        RL = _mp(R) * mpmath.sqrt(_mp(Q))
        cm, prm, Qm = [_mp(x) for x in c], [_mp(x) for x in pr], _mp(Q)
        ambiguous = False
        # a graze: the extremum of w.g on (0, H] within TOL of distance r
        if c[2] != 0:
            ts = -cm[1] / (2 * cm[2])
            if ts > 0 and (H is None or ts <= H * (1 + TOL)):
                scale = abs(cm[0]) + abs(cm[1] * ts) + abs(cm[2] * ts * ts) + RL
                if abs(abs(_poly(cm, ts)) - RL) <= TOL * scale:
                    ambiguous = True
        roots = _real_roots(cs, prec) if len(cs) > 1 else []
        for t in roots:
            if t <= 0:
                continue
            if H is not None:
                if abs(t - H) <= TOL * t:
                    ambiguous = True
                if t > H:
                    continue
            before = t * (1 - mpf(2) ** -120)
            if abs(_poly(cm, before)) - RL <= 0:
                continue  # already at distance <= r: not an entering root
            x = _poly(prm, t)
            scale = abs(prm[0]) + abs(prm[1] * t) + abs(prm[2] * t * t) + Qm
            if abs(x) <= TOL * scale or abs(x - Qm) <= TOL * scale:
                ambiguous = True
            if not 0 < x < Qm:
                continue
            out = float(t)
            if out == 0.0:
                out = 5e-324  # a positive time is never reported as 0
            if math.isfinite(out):
                nb = math.nextafter(out, math.inf if t > out else 0.0)
                if abs(t - (mpf(out) + mpf(nb)) / 2) <= TOL * t:
                    ambiguous = True  # within TOL of a rounding midpoint
            return out, ambiguous
        return math.inf, ambiguous
