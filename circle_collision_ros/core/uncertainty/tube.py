"""The k-sigma tube of a Gaussian relative state: which times can matter.

With z the whitened (dp, dv), every path with |z| <= k stays within
k sqrt(lambda_max(S(t))) of the mean path g(t) (Cauchy-Schwarz), so an interval
tree over [0, H] classifies each node as outside the ball, wholly inside, or
ambiguous.  ``tube_intervals`` gives the ambiguous intervals the entry-rate
integral runs over; ``screen_rows`` / ``screen_rows_at`` the screen that answers
far rows with a certified bound; ``max_sigma_over`` the broad-phase inflation.

See docs/uncertainty.md for the mathematics; each guarantee is stated where
it is made.
"""
from __future__ import annotations

import functools
import math

import numpy as np
from numba import njit

from circle_collision_ros.core.uncertainty.entry_rate import BROAD_K
from circle_collision_ros.core.uncertainty.quadrature import push_halves

__all__ = ["BROAD_PHASE_SIGMAS", "TUBE_TAIL", "TUBE_DEPTH", "chi2_tail_even", "S_at",
           "lam_max_sym3", "max_sigma_over", "max_sigma_rows", "mean_range", "tube_intervals",
           "tube_window", "screen_rows", "screen_rows_at", "row_state", "row_classes",
           "screen_sigmas"]


def chi2_tail_even(x: float, dof: int) -> float:
    """P(chi^2_dof > x) for even dof (closed form: e^{-x/2} sum_{j < dof/2} (x/2)^j / j!)."""
    h = 0.5 * x
    term, s = 1.0, 0.0
    for j in range(dof // 2):
        s += term
        term *= h / (j + 1)
    return math.exp(-h) * s


# k of the k-sigma tube: with z the whitened (dp, dv) (2D <= 6 standard
# normals), P(|z| > k) = P(chi^2_6 > k^2) <= TUBE_TAIL (fewer dof: smaller),
# and on |z| <= k every t has |X(t) - g(t)| <= k sqrt(lambda_max(S(t)))
# (Cauchy-Schwarz).  Two bodies: 2 * TUBE_TAIL = 5.2e-10 < 1e-9.
BROAD_PHASE_SIGMAS = 7.5
TUBE_TAIL = chi2_tail_even(BROAD_PHASE_SIGMAS**2, 6)  # 2.6e-10
assert BROAD_K == BROAD_PHASE_SIGMAS


@njit(cache=True, error_model="numpy")
def S_at(Sigma, t):
    """Position covariance S(t) = Spp + t (Spv + Svp) + t^2 Svv of (D, D)."""
    D = Sigma.shape[0] // 2
    S = np.empty((D, D))
    for i in range(D):
        for j in range(D):
            S[i, j] = (
                Sigma[i, j] + t * (Sigma[i, D + j] + Sigma[D + i, j]) + t * t * Sigma[D + i, D + j]
            )
    return S


@njit(cache=True, error_model="numpy")
def _lam_max(Sigma, t):
    """Largest eigenvalue of S(t) (closed form in 2-D, Jacobi in 3-D)."""
    if Sigma.shape[0] == 4:  # scalar (no temporaries: the tube calls this per node); as S_at
        s00 = Sigma[0, 0] + t * (Sigma[0, 2] + Sigma[2, 0]) + t * t * Sigma[2, 2]
        s11 = Sigma[1, 1] + t * (Sigma[1, 3] + Sigma[3, 1]) + t * t * Sigma[3, 3]
        s01 = Sigma[0, 1] + t * (Sigma[0, 3] + Sigma[2, 1]) + t * t * Sigma[2, 3]
        s10 = Sigma[1, 0] + t * (Sigma[1, 2] + Sigma[3, 0]) + t * t * Sigma[3, 2]
        h = 0.5 * (s00 + s11)
        d = 0.5 * (s00 - s11)
        o = 0.5 * (s01 + s10)
        return h + math.sqrt(d * d + o * o)
    # 3-D: the symmetric part of S(t) entry by entry, as S_at
    return lam_max_sym3(_s_sym(Sigma, t, 0, 0), _s_sym(Sigma, t, 1, 1), _s_sym(Sigma, t, 2, 2),
                        _s_sym(Sigma, t, 0, 1), _s_sym(Sigma, t, 0, 2), _s_sym(Sigma, t, 1, 2))


@njit(cache=True, error_model="numpy", inline="always")
def _s_sym(Sigma, t, i, j):
    """Entry (i, j) of the symmetric part of S(t) in 3-D."""
    return 0.5 * (
        (Sigma[i, j] + Sigma[j, i])
        + t * ((Sigma[i, 3 + j] + Sigma[3 + i, j]) + (Sigma[j, 3 + i] + Sigma[3 + j, i]))
        + t * t * (Sigma[3 + i, 3 + j] + Sigma[3 + j, 3 + i])
    )


@njit(cache=True, error_model="numpy")
def lam_max_sym3(s00, s11, s22, s01, s02, s12):
    """Upper bound of the largest eigenvalue of the symmetric PSD 3x3 matrix
    [[s00, s01, s02], [s01, s11, s12], [s02, s12, s22]] in closed form (the
    trigonometric solution of the characteristic cubic: ~30 flops instead of a
    Jacobi eigendecomposition with its temporaries).  With q = tr / 3 and
    p = |S - q I|_F / sqrt 6, lambda_max = q + 2 p cos(acos(det((S - q I) / p) / 2) / 3).
    Its rounding error is a few hundred ulps of |q| + p <= 2 tr at worst (acos
    is ill-conditioned only at r = +-1, where a change dr moves lambda_max by at
    most 2 p dr / 9); the 1e-12 tr added covers it, and the result is never below
    the largest diagonal entry (a lower bound of lambda_max)."""
    tr = s00 + s11 + s22
    q = tr / 3.0
    a = s00 - q
    b = s11 - q
    c = s22 - q
    off = s01 * s01 + s02 * s02 + s12 * s12
    p = math.sqrt((a * a + b * b + c * c + 2.0 * off) / 6.0)
    lam = q
    if p > 0.0:
        det = a * (b * c - s12 * s12) - s01 * (s01 * c - s12 * s02) + s02 * (s01 * s12 - b * s02)
        r = min(max(0.5 * det / (p * p * p), -1.0), 1.0)
        lam = q + 2.0 * p * math.cos(math.acos(r) / 3.0)
    return max(lam, s00, s11, s22) + 1e-12 * abs(tr)


@njit(cache=True, error_model="numpy")
def max_sigma_over(Sigma, ta, tb):
    """Upper bound of sqrt(lambda_max(S(t))) over t in [ta, tb]: lambda_max
    of S(t) is convex in t, so its maximum is at an end; the factor
    (1 + 1e-9) covers the rounding of S and of the eigenvalues
    (relative error ~1e-15 of the largest eigenvalue)."""
    lm = max(_lam_max(Sigma, ta), _lam_max(Sigma, tb))
    return math.sqrt(lm * (1.0 + 1e-9))


@njit(cache=True, error_model="numpy")
def _axis_range(p, v, a, ta, tb):
    """[lo, hi] of p + v t + a t^2 / 2 over [ta, tb], widened by the rounding."""
    ga = p + ta * (v + 0.5 * ta * a)
    gb = p + tb * (v + 0.5 * tb * a)
    lo = min(ga, gb)
    hi = max(ga, gb)
    if a != 0.0:
        ts = -v / a
        if ta < ts < tb:
            gv = p + ts * (v + 0.5 * ts * a)
            lo = min(lo, gv)
            hi = max(hi, gv)
    m = 8.0 * 2.220446049250313e-16 * (abs(p) + tb * (abs(v) + 0.5 * tb * abs(a)))
    return lo - m, hi + m


@njit(cache=True, error_model="numpy")
def mean_range(dp, dv, da, ta, tb):
    """(min |g|, max |g|) bounds over [ta, tb] (per-axis boxes)."""
    dmin = 0.0
    dmax = 0.0
    for k in range(dp.shape[0]):
        lo, hi = _axis_range(dp[k], dv[k], da[k], ta, tb)
        if lo > 0.0:
            dmin += lo * lo
        elif hi < 0.0:
            dmin += hi * hi
        m = max(abs(lo), abs(hi))
        dmax += m * m
    return math.sqrt(dmin), math.sqrt(dmax)


@njit(cache=True, error_model="numpy")
def max_sigma_rows(cov, ta, tb, out):
    """out[i] = max_sigma_over(cov[i], ta, tb) for a C-contiguous (n, 2D, 2D) stack."""
    for i in range(cov.shape[0]):
        out[i] = max_sigma_over(cov[i], ta, tb)


TUBE_DEPTH = 8  # leaves of width >= H / 256


@njit(cache=True, error_model="numpy")
def _ambiguous_through(dp, dv, da, R, Sigma, ta, tb, k):
    """True when refining the ambiguous node [ta, tb] cannot change what the tube
    walk reports but the shape of the merged ambiguous run: (i) the tube is not
    outside at the points ta and tb (zero-width nodes: the leaves holding them have
    a smaller box bound of |g| and a larger radius, so they are ambiguous too), and
    (ii) no sub-node can be wholly inside (its radius k sqrt(lambda_max) >=
    k sqrt(tr S(t) / D) >= R on all of [ta, tb]: gmax + rho < R is impossible).
    Then [ta, tb] is the hull of its ambiguous leaves and holds no inside leaf, so
    reporting it whole leaves t_inside and "some interval is ambiguous" unchanged
    and only adds leaves where the tube is outside (integrating the entry rate
    there adds true entries of tail paths: the integral moves towards the
    untruncated one).  Saves most of the 2 x 256 nodes of a wide tube."""
    D = dp.shape[0]
    # (ii) tr S(t) = c0 + c1 t + c2 t^2 (c2 = tr Svv >= 0): its minimum over [ta, tb]
    c0 = 0.0
    c1 = 0.0
    c2 = 0.0
    for i in range(D):
        c0 += Sigma[i, i]
        c1 += Sigma[i, D + i] + Sigma[D + i, i]
        c2 += Sigma[D + i, D + i]
    trmin = min(c0 + ta * (c1 + ta * c2), c0 + tb * (c1 + tb * c2))
    if c2 > 0.0:
        tv = -c1 / (2.0 * c2)
        if ta < tv < tb:
            trmin = min(trmin, c0 + tv * (c1 + tv * c2))
    # 1e-6 relative: far above the rounding of tr, lambda_max and the 1e-9 widening
    if not (k * k * trmin >= D * R * R * (1.0 + 1e-6)):
        return False
    # (i) not outside at ta nor at tb (the walk's own test on zero-width nodes)
    for t in (ta, tb):
        gmin, _ = mean_range(dp, dv, da, t, t)
        if gmin - k * max_sigma_over(Sigma, t, t) > R:
            return False
    return True


@njit(cache=True, error_model="numpy")
def _tube_walk(dp, dv, da, R, Sigma, H, out, k, first_only, depth):
    """The k-sigma tube's interval tree over [0, H] down to `depth` levels, nodes visited
    depth first, left to right.  Returns (count of ambiguous leaves written to out, t_inside);
    with first_only it stops at the first terminal node that is not outside and returns
    (0, its start): by the visiting order, the smallest start of any such node.  A smaller
    depth reports a superset of the ambiguous time (a terminal node is ambiguous) and
    t_inside no earlier: cheaper, coarser and still sound."""
    sa = np.empty(depth + 2)
    sb = np.empty(depth + 2)
    sd = np.empty(depth + 2, dtype=np.int64)
    sa[0] = 0.0
    sb[0] = H
    sd[0] = 0
    top = 1
    cnt = 0
    t_inside = math.inf
    while top > 0:
        top -= 1
        ta = sa[top]
        tb = sb[top]
        d = sd[top]
        rho = k * max_sigma_over(Sigma, ta, tb)
        gmin, gmax = mean_range(dp, dv, da, ta, tb)
        if gmin - rho > R:
            continue
        if gmax + rho < R:
            if first_only:
                return 0, ta
            t_inside = min(t_inside, ta)
            continue
        m = 0.5 * (ta + tb)
        if (
            d >= depth
            or not (ta < m < tb)
            or (not first_only and _ambiguous_through(dp, dv, da, R, Sigma, ta, tb, k))
        ):
            if first_only:
                return 0, ta
            if cnt > 0 and out[cnt - 1, 1] == ta:
                out[cnt - 1, 1] = tb
            else:
                out[cnt, 0] = ta
                out[cnt, 1] = tb
                cnt += 1
            continue
        top = push_halves(sa, sb, sd, top, ta, m, tb, d)
    return cnt, t_inside


@njit(cache=True, error_model="numpy")
def tube_intervals(dp, dv, da, R, Sigma, H, out, k):
    """Classify [0, H] with the k-sigma tube (pair_probability: k = BROAD_PHASE_SIGMAS).

    Writes the ambiguous leaf intervals [out[j, 0], out[j, 1]] (merged when
    adjacent; out has >= 2^TUBE_DEPTH rows) and returns (count, inside):
    inside is True when some interval has the whole tube inside the ball (then
    P(contact) >= 1 - TUBE_TAIL).  Outside the ambiguous intervals, no path of
    the tube touches the sphere |x| = R."""
    return _tube_walk(dp, dv, da, R, Sigma, H, out, k, False, TUBE_DEPTH)


@njit(cache=True, error_model="numpy")
def tube_window(dp, dv, da, R, Sigma, H, out, k, depth):
    """tube_intervals refined to `depth` levels only (out has >= 2^depth rows): coarser
    ambiguous intervals, a superset of tube_intervals' (still no tube path touches the
    sphere outside them), and the inside test no earlier."""
    return _tube_walk(dp, dv, da, R, Sigma, H, out, k, False, depth)


@njit(cache=True, error_model="numpy")
def screen_rows(dp, dv, da, R, Sigma, H, k, clear, t_first):
    """clear[i] = True when the k-sigma tube of row i never reaches the ball
    within [0, H] (no ambiguous interval, never wholly inside): then
    P(contact within [0, H]) <= P(chi^2_{2D} > k^2) for that row (a contact
    path has |z| > k, docs/uncertainty.md "Screening").  t_first[i] = the
    first t where the tube may reach the ball (start of the first ambiguous
    interval, or where it lies wholly inside; +inf if never): before it
    P(|X(t)| <= R) <= P(chi^2_{2D} > k^2).  Rows (n, D), Sigma (n, 2D, 2D)
    C-contiguous; each row is decided from itself alone."""
    unused = np.empty((0, 2))
    for i in range(dp.shape[0]):
        _, t_first[i] = _tube_walk(dp[i], dv[i], da[i], R[i], Sigma[i], H, unused, k, True,
                                   TUBE_DEPTH)
        clear[i] = not (t_first[i] <= H)


@njit(cache=True, error_model="numpy", inline="always")
def row_state(pa, va, aa, pb, vb, ab, i, dp, dv, da):
    """The relative state a - b of row i of per-body arrays into dp, dv, da."""
    for c in range(pa.shape[1]):
        dp[c] = pa[i, c] - pb[i, c]
        dv[c] = va[i, c] - vb[i, c]
        da[c] = aa[i, c] - ab[i, c]


@njit(cache=True, error_model="numpy", nogil=True)
def screen_rows_at(pa, va, aa, ra, pb, vb, ab, rb, sigma, rows, H, k, clear, t_first):
    """screen_rows on the rows ``rows`` of the per-body arrays (relative state formed
    here as a - b, Sigma = sigma[row]): the same tube test without gathering the rows
    into new arrays first (a scene screens ~1,000 rows per prediction)."""
    D = pa.shape[1]
    dp = np.empty(D)
    dv = np.empty(D)
    da = np.empty(D)
    unused = np.empty((0, 2))
    for j in range(rows.shape[0]):
        i = rows[j]
        row_state(pa, va, aa, pb, vb, ab, i, dp, dv, da)
        _, t_first[j] = _tube_walk(dp, dv, da, ra[i] + rb[i], sigma[i], H, unused, k, True,
                                   TUBE_DEPTH)
        clear[j] = not (t_first[j] <= H)


@njit(cache=True, error_model="numpy")
def row_classes(pa, va, aa, ra, pb, vb, ab, rb, sigma, exact, finite):
    """Per row: exact[i] = Sigma all zero (a NaN is not zero); finite[i] = every
    position, velocity, acceleration and Sigma entry finite and both radii >= 0
    (one pass instead of a dozen array reductions).  Returns (count of exact rows,
    count of rows neither finite nor exact)."""
    n = pa.shape[0]
    n_exact = 0
    n_bad = 0
    D = pa.shape[1]
    m = sigma.shape[1]
    for i in range(n):
        ex = True
        fin = ra[i] >= 0.0 and rb[i] >= 0.0
        for r in range(m):
            for c in range(m):
                x = sigma[i, r, c]
                if x != 0.0:
                    ex = False
                if not math.isfinite(x):
                    fin = False
        for c in range(D):
            if not (
                math.isfinite(pa[i, c])
                and math.isfinite(va[i, c])
                and math.isfinite(aa[i, c])
                and math.isfinite(pb[i, c])
                and math.isfinite(vb[i, c])
                and math.isfinite(ab[i, c])
            ):
                fin = False
        exact[i] = ex
        finite[i] = fin
        if ex:
            n_exact += 1
        elif not fin:
            n_bad += 1
    return n_exact, n_bad


@functools.lru_cache(maxsize=16)  # a pure function of (threshold, dof): ~50 tail evaluations, once
def screen_sigmas(threshold: float, dof: int) -> tuple[float, float]:
    """(k, U): the smallest k (to 1e-12) with U = P(chi^2_dof > k^2) <= threshold / 2,
    dof even; (inf, 0.0) when no k <= 40 qualifies (a threshold below ~1e-300)."""
    target = 0.5 * threshold
    lo, hi = 0.0, 40.0
    if chi2_tail_even(hi * hi, dof) > target:
        return math.inf, 0.0
    while hi - lo > 1e-12:
        m = 0.5 * (lo + hi)
        if chi2_tail_even(m * m, dof) <= target:
            hi = m
        else:
            lo = m
    return hi, chi2_tail_even(hi * hi, dof)
