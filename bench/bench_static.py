"""Static geometry (``core.static``): exactness on hard cases, against Box2D and a fixed step.

    .venv/bin/python bench/bench_static.py [--rows N] [--quick] [--out DIR]

Prints and writes ``bench/results/static.md``, all figures from one run (compare ratios,
not times, across machines; the machine is recorded).  ``--quick``: 300 rows, 20,000 pairs.

1. Accuracy: stress families of the hard cases (``--rows`` each).  ``time_to_static``
   (world + index) against an exact reference with neither index nor certified kernels:
   min over every edge of ``exact_edge_contact`` and every corner of ``exact_first_contact``
   (a corner touched only while sliding along a wall through it at exactly r is dropped, as
   docs/static.md says), 0 if the centre is strictly inside a solid (rational
   point-in-polygon; the map's float cell lines).  Wrong = status differs (0 / finite / inf)
   or |t - t_ref| > 4 condition-normalised ulps: ulps of t_ref times |cos| of the angle
   between contact normal and velocity at contact, as in bench/accuracy_vs_time.py (raw ulps
   shown too: the documented bound is 1).  "needed exact": rows with a feature the certified
   kernels (``edge_contact``, ``certified_pair2``, run on every feature in the reference
   loop) left UNDECIDED; "kernel errors": decided kernel answers off by status or > 1 ulp.
2. Box2D ``b2TimeOfImpact`` (pip ``box2d`` 2.3.10, float32), same rows: circle vs convex
   polygon, a = 0, our horizon H as its sweep [0, 1] scaled by H.  Box2D stops at separation
   r + skin - 3 b2_linearSlop (r - 5 mm) within b2_linearSlop / 4: error raw (against the
   first touch) and slop-corrected (against the exact time of its target separation).  Time
   per pair: Box2D through its Python binding (overhead dominates); ours by
   ``time_to_static`` (batch per polygon; one row per call) and by the raw kernel loop
   (numba, certified kernels only: no index, exact fallback or inside test).
3. nav2-style fixed step (collision_monitor approach mode, 0.1 s steps): first step whose
   disc holds a corner point (nav2 checks points) or, to be fair, touches a segment or has
   its centre in a solid.  Error against the exact time, misses (tunnelling), spurious hits,
   cost per body (numba) beside ``time_to_static`` on the same rows.
4. ns per body-segment pair (rows near each other): the ``edge_contact`` loop against the
   circle-circle narrow phase on the same rows (radius-0 circle at the segment's midpoint):
   ``certified_pair2`` loop, ``ttc_kernel_h`` (serial batch), ``time_to_collision`` (threads
   as its policy decides); mixed, straight-only and accelerating-only rows.
"""
from __future__ import annotations

import argparse
import math
import multiprocessing
import time
from fractions import Fraction
from pathlib import Path
from typing import NamedTuple

import numpy as np
from numba import njit

import _common
import machine
from _common import fmt_ns, fmt_ulp, md_table
from circle_collision_ros.core import time_to_collision
from circle_collision_ros.core.narrow.batch import certified_pair2, ttc_kernel_h
from circle_collision_ros.core.narrow.evaluate import UNDECIDED
from circle_collision_ros.core.narrow.exact import exact_first_contact
from circle_collision_ros.core.static import (GridFrame, OccupancyMap, Polygon, Segments,
                                              StaticIndex, StaticWorld, time_to_static)
from circle_collision_ros.core.static.edge import edge_contact
from circle_collision_ros.core.static.edge_exact import exact_edge_contact

INF = math.inf
ULP_LIMIT = 4.0
DT = 0.1  # nav2 collision_monitor simulation_time_step


class Family(NamedTuple):
    key: str
    title: str
    world: StaticWorld
    P: np.ndarray
    V: np.ndarray
    A: np.ndarray
    R: np.ndarray
    H: float


def _dy(x, bits: int = 6):
    """Rounded to a multiple of 2^-bits (short dyadics keep hand-built geometry exact)."""
    return np.round(np.asarray(x, dtype=float) * 2.0 ** bits) / 2.0 ** bits


def _sgn(rng) -> int:
    return int(rng.choice([-1, 1]))


def convex(rng, centre, radius: float, n: int) -> np.ndarray:
    """A random convex polygon, counter-clockwise: n points on a circle at least 0.3 rad
    apart, rounded to 2^-12 m (far below their sagitta, so they stay convex; float32-exact)."""
    while True:
        ang = np.sort(rng.uniform(0, 2 * math.pi, n))
        if np.diff(np.r_[ang, ang[0] + 2 * math.pi]).min() > 0.3:
            return _dy(np.array(centre) + radius * np.c_[np.cos(ang), np.sin(ang)], 12)


BOX = Polygon("box", np.array([[-10.0, -1], [10, -1], [10, 0], [-10, 0]]))
WALL = Segments("wall", np.array([[-10.0, 3]]), np.array([[10.0, 3]]))
DIRS = [(1, 0), (0, 1), (-1, 0), (0, -1), (3, 4), (4, 3), (-3, 4), (-4, 3), (3, -4), (4, -3),
        (-3, -4), (-4, -3)]  # exact directions: |(3, 4)| = 5


def fam_slide(rng, n: int) -> Family:
    ramp = Polygon("ramp", np.array([[20.0, 0], [50, 40], [46, 43]]))
    P, V, A, R = np.zeros((n, 2)), np.zeros((n, 2)), np.zeros((n, 2)), np.zeros(n)
    for i in range(n):
        k = i % 6
        if k < 4:  # the box's top (y = r) or either side of the wall (y = 3 +- r)
            r = float(_dy(rng.uniform(0.05, 1.0), 10))
            vx, y, vy, ay = _sgn(rng) * rng.uniform(0.2, 3.0), r, 0.0, 0.0
            if k == 1:  # off by a few ulps or 1e-15 / 1e-12
                y += _sgn(rng) * rng.choice([math.ulp(r), 4 * math.ulp(r), 1e-15, 1e-12])
            elif k == 2:  # drifting in or out by 1e-15 / 1e-12 (velocity or acceleration)
                tiny = _sgn(rng) * rng.choice([1e-15, 1e-12])
                vy, ay = (tiny * abs(vx), 0.0) if rng.random() < 0.5 else (0.0, tiny)
            elif k == 3:
                y = 3.0 + _sgn(rng) * r
            P[i], V[i], R[i] = (_dy(rng.uniform(-12, 12)), y), (vx, vy), r
            A[i] = (rng.choice([0.0, rng.uniform(-0.3, 0.3)]), ay)
        else:  # outside the ramp's (3, 4) edge at exactly r = 5 m / 64 (k = 5: x off by ulps)
            m, s = int(rng.integers(1, 13)), float(_dy(rng.uniform(-2, 12), 4))
            c = _sgn(rng) * float(_dy(rng.uniform(0.05, 0.5)))
            ca = rng.choice([0.0, float(_dy(rng.uniform(-0.05, 0.05), 8))])
            x = 20 + 3 * s + 4 * m / 64
            x += (k == 5) * _sgn(rng) * int(rng.integers(1, 5)) * math.ulp(x)
            P[i], V[i], A[i], R[i] = (x, 4 * s - 3 * m / 64), (3 * c, 4 * c), (3 * ca, 4 * ca), \
                5 * m / 64
    return Family("slide", "(a) sliding along a wall at r (+- tiny)",
                  StaticWorld.build([BOX, WALL, ramp]), P, V, A, R, 30.0)


def fam_corner(rng, n: int) -> Family:
    poly = convex(rng, (0.0, 0.0), 1.5, 8)  # near the origin: r (1 +- 1e-15) survives rounding
    P, V, A, R = np.zeros((n, 2)), np.zeros((n, 2)), np.zeros((n, 2)), np.zeros(n)
    for i in range(n):
        while True:  # a tangent direction whose supporting vertex is unique
            d = np.array(DIRS[rng.integers(len(DIRS))], float)
            nrm = _sgn(rng) * np.array([-d[1], d[0]])
            proj = np.sort(poly @ nrm)
            if proj[-1] > proj[-2]:
                break
        c, k = poly[np.argmax(poly @ nrm)], int(rng.integers(4, 200)) / 256
        dl = _sgn(rng) * [0.0, 1e-12, 1e-13, 1e-14, 1e-15][rng.integers(5)]
        q = c + (k * (1 + dl)) * nrm  # closest approach: r (1 + dl) from the corner
        vel = int(rng.integers(16, 192)) / 64 * d
        acc = int(rng.integers(1, 32)) / 64 * nrm * (rng.random() < 1 / 3)  # curving away
        T = float(_dy(rng.uniform(0.5, 5), 4))
        P[i], V[i], A[i] = q - vel * T + acc * T * T / 2, vel - acc * T, acc
        R[i] = (5.0 if d.all() else 1.0) * k
    return Family("corner", "(b) grazing a convex corner at r(1 +- 1e-12..1e-15)",
                  StaticWorld.build([Polygon("poly", poly)]), P, V, A, R, 10.0)


def fam_touch(rng, n: int) -> Family:
    tri = Polygon("tri", np.array([[20.0, -2], [24, -2], [22, 0]]))
    vecs = np.array([(0, 0), (0, 1), (0, -1), (1, 0), (-1, 0), (1, 1), (-1, 1), (1, -1),
                     (-1, -1)], float)
    cones = [((10.0, 0.0), [(1, 0), (0, 1), (3, 4), (4, 3)]),  # outward normal cones
             ((-10.0, 0.0), [(-1, 0), (0, 1), (-3, 4), (-4, 3)]),
             ((22.0, 0.0), [(0, 1), (3, 4), (-3, 4)])]
    P, R = np.zeros((n, 2)), np.zeros(n)
    for i in range(n):
        k, r, x0 = i % 4, int(rng.integers(4, 200)) / 256, float(_dy(rng.uniform(-9, 9)))
        if k == 0:
            P[i] = (x0, r)
        elif k == 1:
            P[i] = (x0, 3.0 + _sgn(rng) * r)
        elif k == 2:  # a corner at distance exactly r
            corner, us = cones[rng.integers(3)]
            u = np.array(us[rng.integers(len(us))], float)
            P[i], r = np.array(corner) + r * u, (5.0 if u.all() else 1.0) * r
        else:  # the wall's end: beside it, or the foot point exactly at it
            sx = _sgn(rng)
            P[i] = (sx * (10 + r), 3.0) if rng.random() < 0.5 else (sx * 10.0, 3 + _sgn(rng) * r)
        R[i] = r
    V = vecs[rng.integers(9, size=n)] * rng.integers(1, 64, (n, 1)) / 32
    A = vecs[rng.integers(9, size=n)] * rng.integers(1, 64, (n, 1)) / 64
    return Family("touch", "(c) touching at t = 0 (away / approaching / tangent)",
                  StaticWorld.build([BOX, WALL, tri]), P, V, A, R, 10.0)


def fam_vertex(rng, n: int) -> Family:
    occ = np.zeros((6, 6), bool)
    occ[1:3, 1:4] = occ[4, 4] = True
    world = StaticWorld.build([
        Polygon("box", np.array([[-4.0, -1], [4, -1], [4, 0], [-4, 0]])),
        Polygon("ell", np.array([[6.0, 0], [8, 0], [8, 1], [7, 1], [7, 3], [6, 3]])),
        Polygon("tri", np.array([[-3.0, 1.0], [-1.5, 1.25], [-2.75, 2.5]])),
        Segments("walls", np.array([[0.0, 4], [-3, 3]]), np.array([[3.0, 4], [-1, 5]])),
        OccupancyMap("map", occ, GridFrame(0.125, 10.0, -1.0))])
    pe = np.concatenate([np.arange(f, f + m) for _, f, m in world.polygons])
    mids = (world.starts[pe] + world.ends[pe]) / 2  # on the polygons' edges
    P, V, A, R = np.zeros((n, 2)), np.zeros((n, 2)), np.zeros((n, 2)), np.zeros(n)
    for i in range(n):
        on_edge, near = rng.random() < 0.15, rng.random() < 0.5  # from a polygon's edge
        c = (mids if on_edge else world.points)[rng.integers(len(mids) if on_edge else
                                                             len(world.points))]
        c = c + (on_edge and near) * rng.normal(size=2) * 1e-16  # or within 1e-16 of it
        d = rng.integers(-4, 5, 2)
        while not d.any():
            d = rng.integers(-4, 5, 2)
        vel = int(rng.integers(8, 64)) / 32 * d
        acc = rng.integers(-8, 9, 2) / 16 * (rng.random() < 1 / 3)
        T = 0.0 if on_edge or rng.random() < 0.1 else float(_dy(rng.uniform(0.25, 3), 5))
        P[i], V[i], A[i] = c - vel * T + acc * T * T / 2, vel - acc * T, acc  # c at t = T
        R[i] = 0.0 if rng.random() < 0.5 else (1e-30 if on_edge and near else [
            2.0 ** -10, 1e-3, 1e-6, 2.0 ** -30][rng.integers(4)])
    return Family("vertex", "(d) exactly through a vertex, or from an edge (r = 0, small r)", world,
                  P, V, A, R, 5.0)


def fam_thin(rng, n: int) -> Family:
    occ = np.zeros((64, 64), bool)
    occ[5:59, 20] = occ[40, 25:61] = occ[30, 50] = occ[50, 10] = True
    for k in range(6):
        occ[10 + k, 45 + k] = True  # a diagonal: cells touching at corners only
    frame = GridFrame(0.05, -1.6, -1.6)
    iy, ix = np.nonzero(occ)
    P = rng.uniform(-1.6, 1.6, (n, 2))
    j = rng.integers(len(ix), size=n)
    aim = np.stack(frame.cell_to_map(ix[j] + 0.5, iy[j] + 0.5), 1) - P
    aim = np.where((rng.random(n) < 0.7)[:, None], aim, rng.normal(size=(n, 2)))
    speed = 10 ** rng.uniform(math.log10(5), 3, (n, 1))
    V = aim / np.linalg.norm(aim, axis=1)[:, None] * speed
    A = rng.normal(size=(n, 2)) * 100 * (rng.random(n) < 0.5)[:, None]
    return Family("thin", "(e) one-cell walls of a map (res 0.05), 5-1000 m/s",
                  StaticWorld.build([OccupancyMap("map", occ, frame)]), P, V, A,
                  rng.uniform(0.002, 0.03, n), 0.5)


def fam_far(rng, n: int) -> Family:
    O, w, mm = np.array([12345.678, -9876.54321]), 0.401, 0.001  # corridor 2 x 0.2 + 1 mm
    frame = GridFrame(0.05, O[0] + 8, O[1])
    occ = np.zeros((20, 20), bool)
    occ[5:15, 5:8] = True
    sq = np.array([[0.0, 0], [2, 0], [2, 1], [0, 1]])
    world = StaticWorld.build([Polygon("a", O + sq), Polygon("b", O + sq + [2 + w, 0]),
                               Segments("wall", (O + [5.0, 0])[None], (O + [5.0, 3])[None]),
                               OccupancyMap("map", occ, frame)])
    corner = np.array(frame.cell_to_map(5, 5), float)
    P, V = np.zeros((n, 2)), np.zeros((n, 2))
    R = 0.2 + rng.uniform(-0.8, 0.8, n) * mm
    for i in range(n):
        k, r, tilt, speed = i % 4, R[i], rng.uniform(-1e-4, 1e-4), rng.uniform(0.5, 2)
        if k == 0:  # up the corridor, ~0.5 mm from both boxes
            P[i], V[i] = O + (2 + w / 2 + rng.uniform(-1, 1) * mm, -rng.uniform(0.5, 2)), \
                (tilt, speed)
        elif k == 1:  # towards the wall from ~1 mm
            P[i] = O + (5 - r - rng.uniform(0.5, 1.5) * mm, rng.uniform(0.2, 2.8))
            V[i] = (rng.uniform(0.001, 0.1), rng.uniform(-0.1, 0.1))
        elif k == 2:  # over the wall's top end, ~1 mm off
            P[i], V[i] = O + (5 - rng.uniform(0.5, 2), 3 + r + rng.uniform(-1, 1) * mm), \
                (speed, tilt)
        else:  # up past a map corner, ~1 mm beside it
            P[i], V[i] = corner + (-(r + rng.uniform(-1, 1.5) * mm), -rng.uniform(0.5, 2)), \
                (tilt, speed)
    A = rng.normal(size=(n, 2)) * 1e-3 * (rng.random(n) < 0.5)[:, None]
    return Family("far", "(f) 1e4 m coordinates, millimetre gaps", world, P, V, A, R, 10.0)


def fam_random(rng, n: int) -> Family:
    occ = np.zeros((48, 64), bool)
    occ[0, :] = occ[-1, :] = occ[:, 0] = occ[:, -1] = True
    occ[20:28, 30] = occ[5:9, 5:12] = True
    world = StaticWorld.build([
        OccupancyMap("map", occ, GridFrame(0.0625, -2.0, -1.5)),
        Polygon("crate", np.array([[0.5, 0.25], [1.25, 0.5], [0.75, 1.0], [0.25, 0.75]])),
        Polygon("ell", np.array([[-1.0, 0.0], [-0.5, 0.0], [-0.5, 0.25], [-0.75, 0.25],
                                 [-0.75, 0.75], [-1.0, 0.75]])),
        Segments("rail", np.array([[-1.5, -1.0], [0.0, -1.0]]),
                 np.array([[-0.25, -1.25], [1.0, -0.5]]))])
    return Family("random", "(g) random rows with acceleration (room)", world,
                  rng.uniform([-1.9, -1.4], [1.9, 1.4], size=(n, 2)), rng.normal(size=(n, 2)),
                  0.5 * rng.normal(size=(n, 2)), rng.uniform(0.0, 0.15, n), 2.5)


FAMILIES = [fam_slide, fam_corner, fam_touch, fam_vertex, fam_thin, fam_far, fam_random]


# ---------------------------------------------------------------- exact reference

def _inside_polygon(x: float, y: float, loop: np.ndarray) -> bool:
    """Strictly inside (boundary points are not), in rationals."""
    F, inside = Fraction, False
    for (x1, y1), (x2, y2) in zip(loop, np.roll(loop, -1, 0)):
        if (min(x1, x2) <= x <= max(x1, x2) and min(y1, y2) <= y <= max(y1, y2)
                and (F(x2) - F(x1)) * (F(y) - F(y1)) == (F(y2) - F(y1)) * (F(x) - F(x1))):
            return False
        if (y1 > y) != (y2 > y) and F(x) < F(x1) + (F(y) - F(y1)) * (F(x2) - F(x1)) / (
                F(y2) - F(y1)):
            inside = not inside
    return inside


def _inside_map(x: float, y: float, occ: np.ndarray, frame: GridFrame) -> bool:
    """Strictly inside the occupied cells, bounded by the float cell lines the world's edges
    use (yaw 0): every cell whose closure holds the point is occupied (float compares)."""
    assert frame.yaw == 0.0
    h, w = occ.shape

    def cells(z, lines):
        i = int(np.searchsorted(lines, z, side="right")) - 1
        return [i - 1, i] if 0 <= i < len(lines) and lines[i] == z else [i]
    X = frame.cell_to_map(np.arange(w + 1), 0)[0]
    Y = frame.cell_to_map(0, np.arange(h + 1))[1]
    return all(0 <= i < w and 0 <= j < h and occ[j, i] for i in cells(x, X) for j in cells(y, Y))


def _slides(p, v, a, r, s, e, c) -> bool:
    """Moving along the line of s-e at exactly r for ever, c on that closed segment."""
    F = Fraction
    ex, ey = F(e[0]) - F(s[0]), F(e[1]) - F(s[1])
    cx, cy = F(c[0]) - F(s[0]), F(c[1]) - F(s[1])
    gx, gy = F(p[0]) - F(s[0]), F(p[1]) - F(s[1])
    return (ex * F(v[1]) == ey * F(v[0]) and ex * F(a[1]) == ey * F(a[0])
            and ex * cy == ey * cx and 0 <= ex * cx + ey * cy <= ex * ex + ey * ey
            and (ex * gy - ey * gx) ** 2 == F(r) ** 2 * (ex * ex + ey * ey))


def _agree(tk: float, te: float) -> bool:
    return tk == te or (0 < tk < INF and 0 < te < INF and abs(tk - te) <= math.ulp(te))


def reference(world: StaticWorld, p, v, a, r: float, H: float) -> tuple:
    """(t, kind 1 edge / 2 corner / 3 inside, feature, needed exact, kernel errors)."""
    best, kind, feat, und, kerr = INF, 0, -1, False, 0
    pv = (p[0], p[1], v[0], v[1], a[0], a[1], r)
    for k, (s, e, side) in enumerate(zip(world.starts, world.ends, world.solid_side)):
        te = exact_edge_contact(p, v, a, r, s, e, int(side), H)
        tk = edge_contact(*pv, s[0], s[1], e[0], e[1], int(side), H)
        und, kerr = und or tk == UNDECIDED, kerr + (tk != UNDECIDED and not _agree(tk, te))
        if te < best:
            best, kind, feat = te, 1, k
    for k, c in enumerate(world.points):
        tp = exact_first_contact(p, v, a, r, c, (0.0, 0.0), (0.0, 0.0), 0.0, H)
        tk = certified_pair2(*pv, c[0], c[1], 0.0, 0.0, 0.0, 0.0, 0.0, H)
        und, kerr = und or tk == UNDECIDED, kerr + (tk != UNDECIDED and not _agree(tk, tp))
        if tp < best and not any(_slides(p, v, a, r, s, e, c)
                                 for s, e in zip(world.starts, world.ends)):
            best, kind, feat = tp, 2, k
    if any(_inside_polygon(p[0], p[1], world.starts[f:f + m]) for _, f, m in world.polygons) \
            or any(_inside_map(p[0], p[1], occ, fr) for _, occ, fr in world.maps):
        best, kind, feat = 0.0, 3, -1
    return best, kind, feat, und, kerr


_JOBS: dict = {}


def _ref_job(job: tuple) -> tuple:
    f, i = _JOBS[job[0]], job[1]
    return reference(f.world, f.P[i], f.V[i], f.A[i], float(f.R[i]), f.H)


def references(fams: list, jobs: int) -> dict:
    """key -> reference tuples per row (forked workers, before any numba thread starts)."""
    _JOBS.clear()
    _JOBS.update({f.key: f for f in fams})
    work = [(f.key, i) for f in fams for i in range(len(f.R))]
    with multiprocessing.get_context("fork").Pool(jobs) as pool:
        res = pool.map(_ref_job, work, chunksize=16)
    out: dict = {f.key: [] for f in fams}
    for (key, _), r in zip(work, res):
        out[key].append(r)
    return out


# ---------------------------------------------------------------- scoring

def _status(t: float) -> int:
    return 0 if t == 0.0 else (2 if t == INF else (1 if t == t else 3))


def _cos(world: StaticWorld, p, v, a, t: float, kind: int, k: int) -> float:
    """|cos| between the contact normal and the velocity at the exact contact."""
    c, vel = p + t * (v + 0.5 * t * a), v + t * a
    if kind == 1:
        s, e = world.starts[k], world.ends[k]
        nrm = c - (s + np.clip(np.dot(c - s, e - s) / np.dot(e - s, e - s), 0, 1) * (e - s))
    else:
        nrm = c - world.points[k]
    den = np.linalg.norm(nrm) * np.linalg.norm(vel)
    return float(abs(np.dot(nrm, vel)) / den) if den > 0 else 1.0


def score(f: Family, got, refs: list) -> dict:
    wrong, raw, cond, over1 = [], 0.0, 0.0, 0
    for i, (t_ref, kind, feat, _, _) in enumerate(refs):
        g = float(got.time[i])
        if _status(g) != _status(t_ref):
            wrong.append((i, g, t_ref, int(got.kind[i])))
        elif 0 < t_ref < INF:
            u = abs(g - t_ref) / math.ulp(t_ref)
            uc = u * _cos(f.world, f.P[i], f.V[i], f.A[i], t_ref, kind, feat)
            raw, cond, over1 = max(raw, u), max(cond, uc), over1 + (u > 1)
            if uc > ULP_LIMIT:
                wrong.append((i, g, t_ref, int(got.kind[i])))
    st = [_status(r[0]) for r in refs]
    return dict(n=len(refs), st=f"{st.count(0)}/{st.count(1)}/{st.count(2)}", wrong=wrong,
                raw=raw, cond=cond, over1=over1, exact=sum(r[3] for r in refs) / len(refs),
                kerr=sum(r[4] for r in refs))


def hex_row(f: Family, i: int, got: float, ref: float, kind: int) -> str:
    h = float.hex
    return (f"{f.key}[{i}]: p=({h(f.P[i, 0])}, {h(f.P[i, 1])}) v=({h(f.V[i, 0])}, "
            f"{h(f.V[i, 1])}) a=({h(f.A[i, 0])}, {h(f.A[i, 1])}) r={h(float(f.R[i]))} "
            f"H={h(f.H)}: got {got!r} (kind {kind}), exact {ref!r}")


def best_time(fn, repeat: int) -> float:
    return _common.best_of(fn, repeat)[0]


def _pctl(x: np.ndarray, q: float) -> float:
    return float(np.percentile(x, q)) if len(x) else math.nan


# ---------------------------------------------------------------- Box2D

def box2d_rows(rng, n: int, k_polys: int = 16) -> list:
    """A Family per convex polygon (its own world); rows aimed near it, a = 0, H = 5 s."""
    fams = []
    for j in range(k_polys):
        poly = convex(rng, (0.0, 0.0), rng.uniform(0.3, 1.5), int(rng.integers(3, 9)))
        m, rad = len(range(j, n, k_polys)), np.abs(poly).max()
        th = rng.uniform(0, 2 * math.pi, m)
        P = (rad + rng.uniform(-0.3, 6, m))[:, None] * np.c_[np.cos(th), np.sin(th)]
        R = rng.uniform(0.05, 0.5, m)
        aim = -P + (rng.uniform(-1, 1, m) * (rad + R + 0.2))[:, None] * np.c_[-np.sin(th),
                                                                               np.cos(th)]
        V = aim / np.linalg.norm(aim, axis=1)[:, None] * rng.uniform(0.5, 4, (m, 1))
        fams.append(Family(f"b2_{j}", "box2d", StaticWorld.build([Polygon(f"b{j}", poly)]),
                           P, V, np.zeros((m, 2)), R, 5.0))
    return fams


def run_box2d(fams: list) -> tuple[np.ndarray, float, int]:
    """Box2D's time per row (inf: none), seconds per call of the loop, e_failed count."""
    import Box2D as B
    calls = []
    for f in fams:
        poly = B.b2PolygonShape(vertices=[tuple(map(float, q)) for q in f.world.starts])
        for p, v, r in zip(f.P, f.V, f.R):
            sa, sb = B.b2Sweep(), B.b2Sweep()
            for s, c0, c1 in ((sa, p, p + v * f.H), (sb, (0.0, 0.0), (0.0, 0.0))):
                s.localCenter, s.a0, s.a, s.alpha0 = (0.0, 0.0), 0.0, 0.0, 0.0
                s.c0, s.c = tuple(map(float, c0)), tuple(map(float, c1))
            calls.append(dict(shapeA=B.b2CircleShape(radius=float(r)), sweepA=sa, shapeB=poly,
                              sweepB=sb, tMax=1.0))
    toi, O = B.b2TimeOfImpact, B.b2TOIOutput
    out = [toi(**c) for c in calls]
    sec = best_time(lambda: [toi(**c) for c in calls], 3) / len(calls)
    t = np.array([0.0 if s == O.e_overlapped else (b * fams[0].H if s in (
        O.e_touching, O.e_failed) else INF) for s, b in out])
    return t, sec, sum(s == O.e_failed for s, _ in out)


@njit  # uncached: a cached loop keeps the package kernels it was built with
def _feature_loop(P, V, A, R, H, first, count, starts, ends, side, out):
    """Per row the certified kernels on its polygon's edges and corners (no index, no exact
    fallback, no inside test); returns the number of UNDECIDED features."""
    n_und = 0
    for i in range(P.shape[0]):
        best = math.inf
        for k in range(first[i], first[i] + count[i]):
            t = edge_contact(P[i, 0], P[i, 1], V[i, 0], V[i, 1], A[i, 0], A[i, 1], R[i],
                             starts[k, 0], starts[k, 1], ends[k, 0], ends[k, 1], side[k], H)
            t2 = certified_pair2(P[i, 0], P[i, 1], V[i, 0], V[i, 1], A[i, 0], A[i, 1], R[i],
                                 starts[k, 0], starts[k, 1], 0.0, 0.0, 0.0, 0.0, 0.0, H)
            for x in (t, t2):
                if x == UNDECIDED:
                    n_und += 1
                elif x < best:
                    best = x
        out[i] = best
    return n_und


def box2d_section(fams: list, refs: dict, refs_slop: dict, rep: int) -> dict:
    t_b2, sec_b2, failed = run_box2d(fams)
    t_ref, t_slop = ([r[0] for f in fams for r in rs[f.key]] for rs in (refs, refs_slop))
    speed = np.concatenate([np.linalg.norm(f.V, axis=1) for f in fams])
    res = dict(rows=len(t_b2), failed=failed, b2_ns=sec_b2 * 1e9)
    for name, ref in (("raw", np.array(t_ref)), ("slop", np.array(t_slop))):
        both = np.isfinite(ref) & np.isfinite(t_b2)
        err = np.abs(t_b2[both] - ref[both])
        res[name] = [_pctl(err, 50), _pctl(err, 99), _pctl(err, 100),
                     _pctl(err * speed[both] * 1e3, 100),
                     int(np.sum(np.isfinite(ref) & ~np.isfinite(t_b2))),
                     int(np.sum(~np.isfinite(ref) & np.isfinite(t_b2)))]
    idx = [(f, StaticIndex.build(f.world)) for f in fams]
    got = np.concatenate([time_to_static(f.P, f.V, f.A, f.R, ix, f.H).time for f, ix in idx])
    res["ours_wrong"] = sum(_status(g) != _status(r) or not _agree(g, r)
                            for g, r in zip(got, t_ref))
    res["contacts"] = int(np.sum(np.isfinite(t_ref)))
    res["static_ns"] = 1e9 * best_time(lambda: [time_to_static(f.P, f.V, f.A, f.R, ix, f.H)
                                                for f, ix in idx], rep) / len(got)
    one = [(f.P[i:i + 1], f.V[i:i + 1], f.A[i:i + 1], f.R[i:i + 1], ix, f.H) for f, ix in idx
           for i in range(0, len(f.R), 10)]
    res["one_ns"] = 1e9 * best_time(lambda: [time_to_static(*x) for x in one], rep) / len(one)
    w, m = [f.world for f in fams], [len(f.R) for f in fams]
    n_e = np.array([len(x.starts) for x in w])
    first, count = np.repeat(np.cumsum(n_e) - n_e, m), np.repeat(n_e, m)
    P, V, A, R = (np.ascontiguousarray(np.concatenate([getattr(f, k) for f in fams]))
                  for k in "PVAR")
    S, E = (np.concatenate([getattr(x, k) for x in w]) for k in ("starts", "ends"))
    side, out = np.ones(len(S), np.int64), np.empty(len(R))
    loop = lambda: _feature_loop(P, V, A, R, fams[0].H, first, count, S, E, side, out)  # noqa
    res["kernel_und"] = loop()
    res["kernel_ns"] = 1e9 * best_time(loop, 5 * rep) / len(R)
    return res


# ---------------------------------------------------------------- fixed step (nav2-style)

@njit(cache=True)
def _fixed_step(P, V, A, R, H, dt, starts, ends, points, segments, pfirst, pcount, occ,
                ox, oy, res, out):
    """First t = k dt <= H whose disc holds a corner point (segments False), or touches a
    segment or has its centre in a solid (segments True); inf if none."""
    for i in range(P.shape[0]):
        out[i], r2 = math.inf, R[i] * R[i]
        for k in range(int(H / dt + 1e-9) + 1):
            t = k * dt
            cx = P[i, 0] + t * (V[i, 0] + 0.5 * t * A[i, 0])
            cy = P[i, 1] + t * (V[i, 1] + 0.5 * t * A[i, 1])
            hit = False
            if not segments:
                for q in range(points.shape[0]):
                    hit |= (cx - points[q, 0]) ** 2 + (cy - points[q, 1]) ** 2 <= r2
            else:
                for q in range(starts.shape[0]):
                    ex, ey = ends[q, 0] - starts[q, 0], ends[q, 1] - starts[q, 1]
                    gx, gy = cx - starts[q, 0], cy - starts[q, 1]
                    lam = min(max((gx * ex + gy * ey) / (ex * ex + ey * ey), 0.0), 1.0)
                    hit |= (gx - lam * ex) ** 2 + (gy - lam * ey) ** 2 <= r2
                for j in range(pfirst.shape[0]):
                    inside = False
                    for q in range(pfirst[j], pfirst[j] + pcount[j]):
                        y1, y2 = starts[q, 1], ends[q, 1]
                        if (y1 > cy) != (y2 > cy) and cx < starts[q, 0] + (cy - y1) * (
                                ends[q, 0] - starts[q, 0]) / (y2 - y1):
                            inside = not inside
                    hit |= inside
                if occ.shape[0]:
                    ix, iy = math.floor((cx - ox) / res), math.floor((cy - oy) / res)
                    if 0 <= ix < occ.shape[1] and 0 <= iy < occ.shape[0]:
                        hit |= occ[iy, ix]
            if hit:
                out[i] = t
                break


def fixed_step(f: Family, segments: bool, out: np.ndarray) -> None:
    w = f.world
    occ, fr = (w.maps[0][1], w.maps[0][2]) if w.maps else (np.zeros((0, 0), bool), GridFrame(1))
    _fixed_step(f.P, f.V, f.A, f.R, f.H, DT, w.starts, w.ends, w.points, segments,
                np.ascontiguousarray(w.polygons[:, 1]), np.ascontiguousarray(w.polygons[:, 2]),
                occ, fr.origin_x, fr.origin_y, fr.resolution, out)


def step_rows(f: Family, t_ref: np.ndarray, rep: int) -> list:
    """Table rows (points, segments) for one family."""
    ix = StaticIndex.build(f.world)
    ours = 1e6 * best_time(lambda: time_to_static(f.P, f.V, f.A, f.R, ix, f.H), rep) / len(f.R)
    rows = []
    for segs in (False, True):
        got = np.empty(len(f.R))
        fixed_step(f, segs, got)
        both = np.isfinite(got) & np.isfinite(t_ref)
        d = got[both] - t_ref[both]
        us = 1e6 * best_time(lambda: fixed_step(f, segs, got), rep) / len(f.R)
        rows.append([f.key, "segments" if segs else "points", int(np.sum(np.isfinite(t_ref))),
                     int(np.sum(np.isfinite(t_ref) & ~np.isfinite(got))),
                     int(np.sum(~np.isfinite(t_ref) & np.isfinite(got))), _s(_pctl(d, 50)),
                     _s(_pctl(d, 99)), _s(_pctl(np.abs(d), 100)), f"{us:.2f}", f"{ours:.2f}"])
    return rows


# ---------------------------------------------------------------- kernel ns per pair

@njit  # uncached: a cached loop keeps the package kernels it was built with
def _edge_loop(P, V, A, R, S, E, H, out):
    for i in range(P.shape[0]):
        out[i] = edge_contact(P[i, 0], P[i, 1], V[i, 0], V[i, 1], A[i, 0], A[i, 1], R[i],
                              S[i, 0], S[i, 1], E[i, 0], E[i, 1], 0, H)


@njit  # uncached: a cached loop keeps the package kernels it was built with
def _pair_loop(P, V, A, R, M, H, out):
    for i in range(P.shape[0]):
        out[i] = certified_pair2(P[i, 0], P[i, 1], V[i, 0], V[i, 1], A[i, 0], A[i, 1], R[i],
                                 M[i, 0], M[i, 1], 0.0, 0.0, 0.0, 0.0, 0.0, H)


def kernel_section(n: int, rounds: int) -> dict:
    """Bodies 0.5-4 m from 0.5-3 m segments, half aimed at them, H = 10 s; ns per pair."""
    rng = np.random.default_rng(4)
    M = rng.uniform(-5, 5, (n, 2))
    th, ph = rng.uniform(0, 2 * math.pi, (2, n))
    e = rng.uniform(0.25, 1.5, n)[:, None] * np.c_[np.cos(th), np.sin(th)]
    P = M + rng.uniform(0.5, 4, n)[:, None] * np.c_[np.cos(ph), np.sin(ph)]
    aim = np.where((rng.random(n) < 0.5)[:, None], M + e * rng.uniform(-1, 1, (n, 1)) - P,
                   rng.normal(size=(n, 2)))
    V = aim / np.linalg.norm(aim, axis=1)[:, None] * rng.uniform(0.2, 2, (n, 1))
    A0, R, S, E = 0.5 * rng.normal(size=(n, 2)), rng.uniform(0.1, 0.5, n), M - e, M + e
    H, zero, rb, res = 10.0, np.zeros((n, 2)), np.zeros(n), {}
    half = (np.arange(n) % 2 == 0)[:, None]
    for name, A in (("mixed (half a = 0)", np.where(half, 0.0, A0)), ("straight (a = 0)", zero),
                    ("accelerating", A0)):
        A, o1, o2, o3 = np.ascontiguousarray(A), np.empty(n), np.empty(n), np.empty(n)
        fns = {"edge": lambda: _edge_loop(P, V, A, R, S, E, H, o1),
               "pair": lambda: _pair_loop(P, V, A, R, M, H, o2),
               "serial": lambda: ttc_kernel_h(P, V, A, R, M, zero, zero, rb, H, o3),
               "ttc": lambda: time_to_collision(P, V, A, R, M, zero, zero, rb, horizon=H)}
        best = {k: INF for k in fns}
        for _ in range(rounds):  # interleaved: every method sees the same load
            for k, fn in fns.items():
                best[k] = min(best[k], best_time(fn, 1))
        res[name] = {k: 1e9 * v / n for k, v in best.items()}
        res[name]["und"] = f"{int(np.sum(o1 == UNDECIDED))}/{int(np.sum(o2 == UNDECIDED))}"
        res[name]["hits"] = int(np.sum(np.isfinite(o1) & (o1 >= 0)))
    return res


# ---------------------------------------------------------------- report

def _s(x: float) -> str:
    return "n/a" if x != x else (f"{x:.2e}" if x else "0")


def report_accuracy(fams: list, refs: dict, say) -> None:
    tab, bad = [], []
    for f in fams:
        s = score(f, time_to_static(f.P, f.V, f.A, f.R, StaticIndex.build(f.world), f.H),
                  refs[f.key])
        bad += [hex_row(f, *w) for w in s["wrong"]]
        tab.append([f.title, s["n"], s["st"], len(s["wrong"]), fmt_ulp(s["cond"]),
                    fmt_ulp(s["raw"]), s["over1"], f"{100 * s['exact']:.1f}%", s["kerr"]])
    say("## 1. time_to_static against the exact reference\n")
    say(md_table(["family", "rows", "exact 0/finite/inf", "wrong", "max ulp x cos",
                  "max ulp (raw)", "> 1 ulp (raw)", "needed exact", "kernel errors"], tab))
    say(f"Wrong rows: {len(bad)}{' (the first 30)' if len(bad) > 30 else ''} (float.hex; "
        "kind 3 = the core's 'centre inside a solid', 1 edge, 2 corner)"
        + "".join(f"\n    {b}" for b in bad[:30]) + "\n")


def report_box2d(b: dict, say) -> None:
    say(f"## 2. Box2D 2.3.10 b2TimeOfImpact: circle vs convex polygon, a = 0 ({b['rows']} rows, "
        f"16 polygons, H = 5 s, {b['contacts']} exact contacts)\n")
    say("Box2D aims at separation r + polygon skin (0.01 m) - 3 b2_linearSlop (0.005 m) = "
        "r - 5 mm, within b2_linearSlop / 4 = 1.25 mm, in float32: 'raw' compares with the "
        "first touch of the polygon as given, 'slop-corrected' with the exact time of reaching "
        f"Box2D's target separation. e_failed (taken as contacts at their time): {b['failed']}."
        f" Ours on the same rows: {b['ours_wrong']} off by more than 1 ulp or in status.\n")
    say(md_table(["Box2D error", "median (s)", "p99 (s)", "max (s)", "max (mm along path)",
                  "missed", "spurious"],
                 [[k, *map(_s, b[n][:3]), f"{b[n][3]:.2f}", *b[n][4:]]
                  for k, n in (("raw", "raw"), ("slop-corrected", "slop"))]))
    rows = [("Box2D b2TimeOfImpact, Python loop over the binding (one pair per call)", b["b2_ns"]),
            ("ours, time_to_static, one batch per polygon (index, kernels, exact fallback, "
             "inside test)", b["static_ns"]),
            ("ours, time_to_static, one row per call", b["one_ns"]),
            (f"ours, raw kernel loop (numba, every edge and corner, {b['kernel_und']} features "
             "left UNDECIDED)", b["kernel_ns"])]
    say(md_table(["time per pair", "ns", "x Box2D"],
                 [[k, fmt_ns(v), f"{v / b['b2_ns']:.2f}"] for k, v in rows], "lrr"))


def report_kernels(k: dict, n: int, say) -> None:
    say(f"## 4. ns per body-segment pair against the circle-circle narrow phase ({n:,} rows, "
        "H = 10 s)\n")
    say("edge = edge_contact loop (segment interior only, UNDECIDED left); pair = "
        "certified_pair2 loop on the same rows with a radius-0 circle at the midpoint; serial = "
        "ttc_kernel_h (the batch kernel, one thread, exact fallback included); ttc = "
        "time_to_collision (threads when its policy finds a core free). Target: edge / serial "
        "<= 1.5.\n")
    say(md_table(["rows", "edge ns", "pair ns", "serial ns", "ttc ns", "edge / serial",
                  "edge / pair", "edge / ttc", "UNDECIDED edge/pair", "edge contacts"],
                 [[name, fmt_ns(x["edge"]), fmt_ns(x["pair"]), fmt_ns(x["serial"]),
                   fmt_ns(x["ttc"]), f"{x['edge'] / x['serial']:.2f}",
                   f"{x['edge'] / x['pair']:.2f}", f"{x['edge'] / x['ttc']:.2f}", x["und"],
                   x["hits"]] for name, x in k.items()]))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=2000)
    ap.add_argument("--quick", action="store_true", help="300 rows, 20,000 kernel pairs")
    ap.add_argument("--out", default=str(_common.HERE / "results"))
    a = ap.parse_args(argv)
    rows, rep = (300 if a.quick and a.rows == 2000 else a.rows), (2 if a.quick else 5)
    info, t_start, walls, lines = machine.collect(argv), time.perf_counter(), {}, []

    def say(s: str = "") -> None:
        print(s, flush=True)
        lines.append(s)

    def lap(name: str) -> None:
        walls[name] = time.perf_counter() - t_start - sum(walls.values())

    import Box2D
    slop, skin = Box2D.b2_linearSlop, Box2D.b2_polygonRadius  # b2TimeOfImpact's target
    fams = [g(np.random.default_rng(2024 + j), rows) for j, g in enumerate(FAMILIES)]
    b2 = box2d_rows(np.random.default_rng(7), rows)
    b2s = [f._replace(key=f.key + "s", R=np.maximum(slop, f.R + skin - 3 * slop)) for f in b2]
    refs = references(fams + b2 + b2s, 2)
    lap("references")
    say(f"# Static geometry: exactness, Box2D, fixed step, kernel cost\n\n`{info['command']}`:"
        f" {rows} rows per family; exact references in {walls['references']:.0f} s (2 "
        "processes); machine at the end. Method: the docstring of bench/bench_static.py.\n")
    report_accuracy(fams, refs, say)
    lap("accuracy")
    report_box2d(box2d_section(b2, refs, {f.key[:-1]: refs[f.key] for f in b2s}, rep), say)
    lap("box2d")
    say(f"## 3. nav2-style fixed step (dt = {DT} s) against the exact time\n")
    say("points: the disc holds a corner point (nav2's point check); segments: it touches a "
        "segment or its centre is in a solid. err = step time - exact time where both see a "
        "contact; cost per body against the family's whole world, beside time_to_static.\n")
    say(md_table(["family", "check", "exact contacts", "missed", "spurious", "median err (s)",
                  "p99 err (s)", "max abs err (s)", "us/body", "time_to_static us/body"],
                 [r for f in fams for r in step_rows(f, np.array([x[0] for x in refs[f.key]]),
                                                     rep)], "llrrrrrrrr"))
    lap("fixed_step")
    n_k = 20_000 if a.quick else 200_000
    report_kernels(kernel_section(n_k, 3 if a.quick else 9), n_k, say)
    lap("kernels")
    info = machine.finish(info, time.perf_counter() - t_start, walls)
    say("## Machine\n\n" + machine.table(info))
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "static.md").write_text("\n".join(lines) + "\n")
    print(f"wrote {out / 'static.md'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
