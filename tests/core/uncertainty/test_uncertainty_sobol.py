"""Scrambled Sobol points (core/sobol.py): the properties the RQMC bound relies on.

* Unscrambled: the known first points of the Sobol sequence (dimension 1 is
  van der Corput; dimensions 2-6 from Joe-Kuo's table) and the direction
  numbers' odd m_k.
* Scrambled replicates: every dimension's first 2^m points fall one per
  interval of width 2^-m (the net property survives the linear scramble and
  shift), pairs of dimensions are (0, m, 2)-nets for dims (1, 2), the
  replicates differ, and the same seed gives the same bits.
"""
from __future__ import annotations

import numpy as np

from circle_collision_ros.core.uncertainty.sobol import (BITS, scrambled_directions,
                                                         sobol_directions, sobol_points)


def test_unscrambled_first_points():
    v = sobol_directions(6)
    pts = sobol_points(v, np.zeros(6, dtype=np.uint64), 4)
    eps = 0.5 / 2**BITS  # points are cell centres
    assert np.allclose(pts[0], eps)
    assert np.allclose(pts[1], 0.5 + eps)
    # Gray-code order: the third point is 0.75 / 0.25 in dims 1-2 (point index 3 in natural order)
    assert np.allclose(pts[2, :2], [0.75 + eps, 0.25 + eps])
    for d in range(6):
        m = [int(v[d, k]) >> (BITS - 1 - k) for k in range(BITS)]
        assert all(x % 2 == 1 and x < 2 ** (k + 1) for k, x in enumerate(m))


def test_scrambled_replicates_are_nets():
    m = 9
    n = 2**m
    seen = []
    for seed in range(4):
        dirs, shift = scrambled_directions(6, seed)
        u = sobol_points(dirs, shift, n)
        assert np.all((u > 0) & (u < 1))
        for d in range(6):
            cells = np.floor(u[:, d] * n).astype(int)
            assert np.array_equal(np.sort(cells), np.arange(n))
        # dims (1, 2): every 2^-a x 2^-(m-a) box holds exactly one point
        for a in range(m + 1):
            cx = np.floor(u[:, 0] * 2**a).astype(int)
            cy = np.floor(u[:, 1] * 2 ** (m - a)).astype(int)
            assert len(set(zip(cx.tolist(), cy.tolist()))) == n
        seen.append(u)
    assert not np.array_equal(seen[0], seen[1])
    d2, s2 = scrambled_directions(6, 0)
    assert sobol_points(d2, s2, n).tobytes() == seen[0].tobytes()
