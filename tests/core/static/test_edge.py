"""The certified edge-interior kernel (``core.static.edge.edge_contact``) against the exact one.

Guarantee proved here (docs/static.md): every row the kernel decides agrees with
``exact_edge_contact`` -- 0, inf and NaN exactly, a finite time within one ulp -- on seeded
families that reach each of its decisions (box and band rejections, t = 0, the float-proved
foot point on either side of an end, the compensated 1-ulp bracket), and the rows it leaves
UNDECIDED for the exact solver stay rare where nothing is degenerate.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from circle_collision_ros.core.narrow.evaluate import UNDECIDED
from circle_collision_ros.core.static.edge import edge_contact
from circle_collision_ros.core.static.edge_exact import exact_edge_contact
from tests.core.static.edge_rows import (
    endpoint_rows,
    graze_rows,
    make_row,
    random_rows,
    unit_normal,
)

INF = math.inf


def _kernel(row) -> float:
    p, v, a, r, A, B, side, H = row
    return edge_contact(p[0], p[1], v[0], v[1], a[0], a[1], r, A[0], A[1], B[0], B[1], side, H)


def _compare(rows) -> dict:
    """Counts of a family's rows; asserts every decided row agrees with the exact solver."""
    bad, und, hits, nearest = [], 0, 0, 0
    for row in rows:
        got, want = _kernel(row), exact_edge_contact(*row)
        if got == UNDECIDED:
            und += 1
            continue
        if 0.0 < want < INF:
            hits += 1
            nearest += got == want
            ok = 0.0 < got < INF and abs(got - want) <= math.ulp(want)
        else:
            ok = got == want or (math.isnan(got) and math.isnan(want))
        if not ok:
            bad.append((row, got.hex(), want.hex() if want == want else want))
    assert not bad, f"{len(bad)} rows disagree with the exact solver, first: {bad[:2]}"
    return {"rows": len(rows), "undecided": und, "hits": hits, "nearest": nearest}


def _foot_beyond_an_end_rows(seed: int, n: int):
    """Bodies entering the band of the line with the foot point just beyond A or B (by 1e-9
    to 1e-2 of the length) or just inside: the contact is the end's, or the edge's."""
    rng = np.random.default_rng(seed)
    rows = []
    for i in range(n):
        A, B = rng.uniform(-5, 5, 2), rng.uniform(-5, 5, 2)
        nrm, tan = unit_normal(A, B)
        side = rng.choice([-1, 1])
        r = rng.uniform(0.05, 1.0)
        lam = rng.choice([-1, 1]) * 10 ** rng.uniform(-9, -2)
        lam = lam if i % 2 else 1 + lam
        t_c = rng.uniform(0.2, 4)
        centre = A + lam * (B - A) + side * r * nrm
        u = -side * rng.uniform(0.3, 2) * nrm + rng.normal(0, 0.5) * tan
        a = rng.normal(0, 0.5, 2) if i % 3 else np.zeros(2)
        v = u - a * t_c
        p = centre - v * t_c - a * t_c ** 2 / 2
        rows.append(make_row(p, v, a, r, A, B, 0, INF if i % 4 else rng.uniform(0, 6)))
    return rows


def _near_segment_rows(seed: int, n: int):
    """Bodies 0.5-4 m from 0.5-3 m segments, half aimed at them, H = 10 s (the benchmark's
    per-pair rows): most reach the bracket or a float rejection."""
    rng = np.random.default_rng(seed)
    rows = []
    for i in range(n):
        m = rng.uniform(-5, 5, 2)
        th, ph = rng.uniform(0, 2 * math.pi, 2)
        e = rng.uniform(0.25, 1.5) * np.array([math.cos(th), math.sin(th)])
        p = m + rng.uniform(0.5, 4) * np.array([math.cos(ph), math.sin(ph)])
        aim = m + e * rng.uniform(-1, 1) - p if i % 2 else rng.normal(size=2)
        v = aim / np.linalg.norm(aim) * rng.uniform(0.2, 2)
        a = 0.5 * rng.normal(size=2) if i % 3 else np.zeros(2)
        rows.append(make_row(p, v, a, rng.uniform(0.1, 0.5), m - e, m + e, 0, 10.0))
    return rows


def _gaps(lo: float, hi: float):
    def gaps(rng, r):
        return rng.choice([-1, 1]) * r * 10 ** rng.uniform(lo, hi)
    return gaps


FAMILIES = {
    "straight": (lambda: random_rows(111, 1500, accelerate=False), 0.01),
    "accelerating": (lambda: random_rows(222, 1500, accelerate=True), 0.01),
    "near_segment": (lambda: _near_segment_rows(333, 2000), 0.01),
    "foot_beyond_an_end": (lambda: _foot_beyond_an_end_rows(444, 1500), 0.01),
    "graze_1e-6": (lambda: graze_rows(555, 1000, _gaps(-7, -5)), 0.05),
    "graze_1e-12": (lambda: graze_rows(666, 500, _gaps(-13, -11)), 1.0),
    "map_scale": (lambda: graze_rows(777, 500, _gaps(-6, -2), offset=1e4)
                  + random_rows(778, 500, accelerate=True, offset=1.2e4), 0.02),
    "foot_at_an_end": (lambda: endpoint_rows(888, 500), 1.0),
}


@pytest.mark.parametrize("name", list(FAMILIES))
def test_kernel_agrees_with_the_exact_solver(name):
    make, max_undecided = FAMILIES[name]
    c = _compare(make())
    assert c["undecided"] <= max_undecided * c["rows"], c
    # the times are the nearest float to the exact root but for rare ties of the bracket
    assert c["nearest"] >= 0.97 * c["hits"], c


def test_each_decision_is_reached():
    """The families above reach the float-proved foot point on both sides and the bracket."""
    rows = _foot_beyond_an_end_rows(444, 1500)
    kinds = {"edge": 0, "end": 0}
    for row in rows:
        t = _kernel(row)
        kinds["edge" if 0.0 < t < INF else "end"] += 1
    assert min(kinds.values()) >= 300, kinds
