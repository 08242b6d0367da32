"""Where a Rice panel's nodes go: a sinh map of [-1, 1] onto the panel, dense at the entry bump.

The entry rate nu+(t) over a tube interval is a bump a few sigma-crossing times wide inside an
interval ~(R + k sigma) / speed wide (k = BROAD_PHASE_SIGMAS), so equally spaced panels see it
with a few of their nodes: a K15 on either half of the interval was often too coarse to pass its
error estimate, and took Patterson's 16 more values.  The rule runs instead in s in [-1, 1] with

    t(s) = c + w sinh(alpha + h (s + 1)),   dt/ds = w cosh(alpha + h (s + 1)) h,

alpha = asinh((a - c) / w), h = (asinh((b - c) / w) - alpha) / 2, so that t(-1) = a, t(1) = b
and the nodes crowd within ~w of c (the sinh map of Johnston and Elliott [1] for near-peaked
integrands).  The integral is the same (a change of variables); nu+(t(s)) dt/ds is smooth
wherever nu+ is, so the rules and their error estimates apply to it unchanged.  A second bump
away from c falls where the nodes are sparse, and there K15 and its Patterson extension can
agree on a value that misses it (as on any panel whose nodes a feature falls between): so each
interval is first cut midway between the bumps the grid shows (``bump_cuts``), and each panel
maps onto its own bump.

c and w come from the mean path, not from nu+: z(t) = (|g(t)| - R) / sigma_g(t), the mean
distance to the sphere in units of the position sigma along g, on a _GRID-step grid; c is where
z first falls through 0 (the mean path enters: entries crowd there, spread by ~1 / |z'|), else
where |z| is least (a near miss: the closest approach), with w the half-width of the run where z
stays within 1 of that least value.  w is kept within [_W_MIN, 1] of the panel width: a tiny w
would put every node at c.

References
----------
.. [1] Johnston, P. R. and Elliott, D., "A sinh transformation for evaluating nearly singular
   boundary element integrals", Int. J. Numer. Meth. Engng. 62 (2005) 564-578.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["bump_map", "bump_cuts", "map_to_t", "map_to_s", "MAX_BUMPS"]

#: At most this many bumps of one tube interval get a panel of their own (bump_cuts)
MAX_BUMPS = 4

_GRID = 32  # grid steps over the panel for c and w (one nu+ value costs more than the grid)
_W_MIN = 1e-3  # w at least this fraction of the panel width


@njit(cache=True, error_model="numpy")
def _z(dp, dv, da, R, Sigma, t):
    """(|g(t)| - R) / sigma along g(t) (sqrt(tr S / D) where g = 0 or S(t) is not positive):
    scalar code, g's components formed once (this runs on every grid point of every panel)."""
    D = dp.shape[0]
    g0 = dp[0] + t * (dv[0] + 0.5 * t * da[0])
    g1 = dp[1] + t * (dv[1] + 0.5 * t * da[1])
    g2 = dp[2] + t * (dv[2] + 0.5 * t * da[2]) if D == 3 else 0.0
    gg = g0 * g0 + g1 * g1 + g2 * g2
    q = 0.0  # g^T S(t) g
    tr = 0.0
    for i in range(D):
        gi = g0 if i == 0 else (g1 if i == 1 else g2)
        for j in range(D):
            gj = g0 if j == 0 else (g1 if j == 1 else g2)
            s = Sigma[i, j] + t * (Sigma[i, D + j] + Sigma[D + i, j]) + t * t * Sigma[D + i, D + j]
            q += gi * s * gj
            if i == j:
                tr += s
    var = q / gg if gg > 0.0 and q > 0.0 else tr / D
    return (math.sqrt(gg) - R) / math.sqrt(max(var, 1e-300))


@njit(cache=True, error_model="numpy")
def _z_grid(dp, dv, da, R, Sigma, a, b):
    zs = np.empty(_GRID + 1)
    for i in range(_GRID + 1):
        zs[i] = _z(dp, dv, da, R, Sigma, a + (b - a) * i / _GRID)
    return zs


@njit(cache=True, error_model="numpy")
def bump_cuts(dp, dv, da, R, Sigma, a, b, cuts):
    """Cut points of [a, b] between its bumps, into cuts; returns their count (< MAX_BUMPS).

    A bump is where entries crowd: where z (module doc) falls through 0 (the mean path enters),
    or a local minimum of z > 0 (a near miss; an end of [a, b] counts where z rises from it).
    Bumps within two grid steps of the previous one are one; after MAX_BUMPS the rest share
    the last panel.  Each cut lies midway between two bumps, so every panel holds one bump,
    which bump_map of that panel then finds (its first entry, else its least |z|)."""
    zs = _z_grid(dp, dv, da, R, Sigma, a, b)
    step = (b - a) / _GRID
    found = np.empty(MAX_BUMPS)
    n = 0
    last = -10
    for i in range(_GRID + 1):
        if n == MAX_BUMPS:
            break
        entry = i < _GRID and zs[i] > 0.0 and zs[i + 1] <= 0.0
        low = (zs[i] > 0.0 and (i == 0 or zs[i] <= zs[i - 1])
               and (i == _GRID or zs[i] < zs[i + 1]))
        if (entry or low) and i - last > 2:
            found[n] = a + step * i
            n += 1
            last = i
    for k in range(n - 1):
        cuts[k] = 0.5 * (found[k] + found[k + 1])
    return max(n - 1, 0)


@njit(cache=True, error_model="numpy")
def bump_map(dp, dv, da, R, Sigma, a, b):
    """(c, w, alpha, h) of the module doc's map of [-1, 1] onto [a, b] (a < b)."""
    zs = _z_grid(dp, dv, da, R, Sigma, a, b)
    step = (b - a) / _GRID
    c = math.nan
    w = 0.0
    for i in range(_GRID):
        if zs[i] > 0.0 and zs[i + 1] <= 0.0:  # the mean path enters
            f = zs[i] / (zs[i] - zs[i + 1])
            c = a + step * (i + f)
            w = step / (zs[i] - zs[i + 1])  # 1 / |z'| over the step
            break
    if not (c == c):  # no entry: the closest approach, and the run within 1 of it
        im = 0
        for i in range(1, _GRID + 1):
            if abs(zs[i]) < abs(zs[im]):
                im = i
        lo = im
        hi = im
        while lo > 0 and abs(zs[lo - 1]) < abs(zs[im]) + 1.0:
            lo -= 1
        while hi < _GRID and abs(zs[hi + 1]) < abs(zs[im]) + 1.0:
            hi += 1
        c = a + step * im
        w = 0.5 * step * (hi - lo + 1)
    w = min(max(w, _W_MIN * (b - a)), b - a)
    alpha = math.asinh((a - c) / w)
    h = 0.5 * (math.asinh((b - c) / w) - alpha)
    return c, w, alpha, h


@njit(cache=True, error_model="numpy", inline="always")
def map_to_t(mp, s):
    """(t(s), dt/ds) of the map mp = (c, w, alpha, h)."""
    u = mp[2] + mp[3] * (s + 1.0)
    return mp[0] + mp[1] * math.sinh(u), mp[1] * math.cosh(u) * mp[3]


@njit(cache=True, error_model="numpy", inline="always")
def map_to_s(mp, t):
    """s(t), the inverse of map_to_t, clamped to [-1, 1]."""
    s = (math.asinh((t - mp[0]) / mp[1]) - mp[2]) / mp[3] - 1.0
    return min(max(s, -1.0), 1.0)
