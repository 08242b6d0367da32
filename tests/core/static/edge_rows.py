"""Seeded rows ``(p, v, a, r, A, B, solid_side, H)`` for the edge-interior kernels' tests."""
from __future__ import annotations

import math

import numpy as np

INF = math.inf


def unit_normal(A, B):
    e = np.subtract(B, A)
    return np.array([-e[1], e[0]]) / math.hypot(*e), e / math.hypot(*e)


def make_row(p, v, a, r, A, B, side, H=INF):
    f = [float(x) for x in (*p, *v, *a, r, *A, *B)]
    return (f[0:2], f[2:4], f[4:6], f[6], f[7:9], f[9:11], int(side), float(H))


def random_rows(seed: int, n: int, accelerate: bool, scale: float = 1.0,
                 offset: float = 0.0):
    """Bodies aimed (with noise) at a random point of a random segment."""
    rng = np.random.default_rng(seed)
    rows = []
    for i in range(n):
        A = offset + scale * rng.uniform(-5, 5, 2)
        B = offset + scale * rng.uniform(-5, 5, 2)
        p = offset + scale * rng.uniform(-10, 10, 2)
        target = A + rng.uniform(-0.1, 1.1) * (B - A)
        v = (target - p) * rng.uniform(0.2, 2) + scale * rng.normal(0, 0.3, 2)
        a = scale * rng.normal(0, 1, 2) if accelerate else np.zeros(2)
        r = 0.0 if i % 7 == 0 else scale * rng.uniform(0, 2)
        H = INF if i % 2 else rng.uniform(0, 3)
        rows.append(make_row(p, v, a, r, A, B, rng.integers(-1, 2), H))
    return rows


def _wall(rng, scale: float, offset: float) -> tuple:
    """A random segment A -> B in a square of side 10 scale around offset, its unit normal
    and tangent, and a random side (+-1)."""
    A = offset + scale * rng.uniform(-5, 5, 2)
    B = offset + scale * rng.uniform(-5, 5, 2)
    nrm, tan = unit_normal(A, B)
    return A, B, nrm, tan, rng.choice([-1, 1])


def graze_rows(seed: int, n: int, gaps, scale: float = 1.0, offset: float = 0.0):
    """Parabolic paths passing at distance r + gap of the line at t*, foot inside.

    Hits (gap < 0: two roots near t*) and near misses (gap > 0).
    """
    rng = np.random.default_rng(seed)
    rows = []
    for i in range(n):
        A, B, nrm, tan, side = _wall(rng, scale, offset)
        r = scale * rng.uniform(0.2, 2)
        foot = A + rng.uniform(0.1, 0.9) * (B - A)
        t_star = rng.uniform(0.5, 5)
        centre = foot + side * (r + gaps(rng, r)) * nrm
        u = tan * scale * rng.uniform(-2, 2)  # velocity at t*: along the line
        a = side * scale * rng.uniform(0.1, 2) * nrm + scale * rng.normal(0, 0.5) * tan
        v = u - a * t_star
        p = centre - v * t_star - a * t_star ** 2 / 2
        rows.append(make_row(p, v, a, r, A, B, rng.integers(-1, 2)))
    return rows


def endpoint_rows(seed: int, n: int, exponents: tuple[float, float] = (-13, -11),
                  finite_horizons: bool = False):
    """Contacts whose foot point is within 10**exponents (relative) of A or B, either side:
    the end's contact or the edge's; with ``finite_horizons`` every fourth row has a random
    horizon in [0, 6] s (the rest none)."""
    rng = np.random.default_rng(seed)
    rows = []
    for i in range(n):
        A, B = rng.uniform(-5, 5, 2), rng.uniform(-5, 5, 2)
        nrm, tan = unit_normal(A, B)
        side = rng.choice([-1, 1])
        r = rng.uniform(0.1, 2) if i % 5 else 0.0
        lam = rng.choice([-1, 1]) * 10 ** rng.uniform(*exponents)
        lam = lam if i % 2 else 1 + lam
        t_c = rng.uniform(0.5, 5)
        centre = A + lam * (B - A) + side * r * nrm
        u = -side * rng.uniform(0.5, 2) * nrm + rng.normal(0, 1) * tan  # entering at t_c
        a = rng.normal(0, 0.5, 2) if i % 3 else np.zeros(2)
        v = u - a * t_c
        p = centre - v * t_c - a * t_c ** 2 / 2
        H = rng.uniform(0, 6) if finite_horizons and i % 4 == 0 else INF
        rows.append(make_row(p, v, a, r, A, B, rng.integers(-1, 2), H))
    return rows


def straight_rows(seed: int, n: int, angles: tuple[float, float] = (-3, 0),
                  gaps: tuple[float, float] = (-3, 0), scale: float = 1.0,
                  offset: float = 0.0, finite_horizons: bool = True):
    """a = 0: straight paths reaching the band ``r`` from the line at a foot point near the
    segment (``lam`` in [-0.1, 1.1] of A -> B), from a gap of ``scale * 10**gaps`` at an
    angle of ``10**angles`` rad to the wall (tiny angles: near-parallel, grazing
    approaches); every fifth row moves away instead, every seventh is a point (r = 0),
    every third has a horizon around its contact time (with ``finite_horizons``)."""
    rng = np.random.default_rng(seed)
    rows = []
    for i in range(n):
        A, B, nrm, tan, side = _wall(rng, scale, offset)
        r = 0.0 if i % 7 == 0 else scale * rng.uniform(0.05, 2)
        lam = rng.uniform(-0.1, 1.1)
        theta = 10 ** rng.uniform(*angles)
        speed = scale * rng.uniform(0.1, 3)
        gap = scale * 10 ** rng.uniform(*gaps)
        v = speed * (math.cos(theta) * rng.choice([-1, 1]) * tan - side * math.sin(theta) * nrm)
        t_c = gap / (speed * math.sin(theta))
        p = A + lam * (B - A) + side * r * nrm - v * t_c  # at r + gap from the line
        if i % 5 == 4:
            v = -v
        H = INF
        if finite_horizons and i % 3 == 0:
            H = t_c * rng.uniform(0.5, 1.5)
        rows.append(make_row(p, v, (0.0, 0.0), r, A, B, rng.integers(-1, 2), H))
    return rows


def touch_rows(seed: int, n: int, offset: float = 0.0):
    """a = 0, axis-aligned walls with dyadic coordinates: the circle exactly touching the
    line at t = 0 (foot inside, beyond an end or at it), or overlapping it by a dyadic
    depth; moving in, out or along the wall."""
    rng = np.random.default_rng(seed)
    rows = []
    for i in range(n):
        x0 = offset + rng.integers(-64, 64) / 8
        y0 = offset + rng.integers(-64, 64) / 8
        L = rng.integers(1, 64) / 8
        r = rng.integers(0, 16) / 16
        side = rng.choice([-1, 1])
        depth = 0.0 if i % 2 else rng.integers(1, 8) / 64
        px = x0 + rng.choice([rng.integers(1, 8) / 8 * L, 0.0, L, -0.125, L + 0.125])
        py = y0 + side * (r - depth)
        v = rng.choice([-1, 0, 1]) * rng.integers(1, 8) / 4, rng.choice([-1, 0, 1]) * rng.integers(
            1, 8) / 4
        A, B = (x0, y0), (x0 + L, y0)
        if i % 4 == 3:  # the same wall, vertical and reversed
            A, B, px, py, v = (y0, x0 + L), (y0, x0), py, px, (v[1], v[0])
        H = INF if i % 3 else rng.uniform(0, 4)
        rows.append(make_row((px, py), v, (0.0, 0.0), r, A, B, rng.integers(-1, 2), H))
    return rows
