"""Scrambled Sobol points (up to 6 dimensions) for seeded randomized quasi-Monte Carlo.

Why hand-written: scipy (scipy.stats.qmc) is not a dependency of the package
and is ~40 MB for one generator; the Sobol construction is 30 lines.  Direction
numbers: Joe & Kuo's ``new-joe-kuo-6.21201`` table, dimensions 2-6 (dimension 1
is van der Corput).  Randomization: Matousek's random linear scramble (a random
lower-triangular binary matrix with unit diagonal per dimension) and a random
digital shift, drawn from ``numpy.random.Generator(PCG64(seed))`` -- so each
replicate is a randomly scrambled (0, m, s)-type net and the replicate means
are independent unbiased estimates (their spread gives the standard error),
while a fixed seed makes every run bit-identical.

tests/core/uncertainty/test_uncertainty_sobol.py checks the net property (each of the
first 2^m points of a dimension falls in its own interval of width 2^-m) and
the first points of the unscrambled sequence.
"""
from __future__ import annotations

import numpy as np

__all__ = ["sobol_directions", "scrambled_directions", "sobol_points", "BITS", "MAX_DIM"]

BITS = 32
MAX_DIM = 6
# (s, a, m_1..m_s) of dimensions 2..6 (Joe & Kuo, new-joe-kuo-6.21201)
_JOE_KUO = ((1, 0, (1,)), (2, 1, (1, 3)), (3, 1, (1, 3, 1)), (3, 2, (1, 1, 1)),
            (4, 1, (1, 1, 3, 3)))


def sobol_directions(dim: int) -> np.ndarray:
    """(dim, BITS) uint64 direction numbers v_k (bit BITS-1 is the 1/2 digit)."""
    if not 1 <= dim <= MAX_DIM:
        raise ValueError(f"Sobol dimension {dim} outside 1..{MAX_DIM}")
    v = np.zeros((dim, BITS), dtype=np.uint64)
    for k in range(BITS):
        v[0, k] = 1 << (BITS - 1 - k)
    for d in range(1, dim):
        s, a, m0 = _JOE_KUO[d - 1]
        m = list(m0)
        for k in range(s, BITS):
            x = m[k - s] ^ (m[k - s] << s)
            for j in range(1, s):
                if (a >> (s - 1 - j)) & 1:
                    x ^= m[k - j] << j
            m.append(x)
        for k in range(BITS):
            v[d, k] = m[k] << (BITS - 1 - k)
    return v


def scrambled_directions(dim: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(directions (dim, BITS) uint64 after a random linear scramble, digital
    shift (dim,) uint64) for one replicate."""
    rng = np.random.Generator(np.random.PCG64(seed))
    v = sobol_directions(dim)
    out = np.zeros_like(v)
    shift = np.zeros(dim, dtype=np.uint64)
    for d in range(dim):
        # L[i, j], i >= j, digit 0 = the 1/2 digit; unit diagonal
        L = np.tril(rng.integers(0, 2, size=(BITS, BITS)), -1) + np.eye(BITS, dtype=np.int64)
        for k in range(BITS):
            x = int(v[d, k])
            digits = [(x >> (BITS - 1 - i)) & 1 for i in range(BITS)]
            y = 0
            for i in range(BITS):
                bit = 0
                for j in range(i + 1):
                    bit ^= int(L[i, j]) & digits[j]
                y |= bit << (BITS - 1 - i)
            out[d, k] = y
        shift[d] = int(rng.integers(0, 1 << BITS))
    return out, shift


def sobol_points(directions: np.ndarray, shift: np.ndarray, n: int) -> np.ndarray:
    """(n, dim) points in (0, 1) of one replicate (Gray-code order; the point
    is the centre of its 2^-BITS cell, never 0 or 1)."""
    dim = directions.shape[0]
    out = np.empty((n, dim))
    x = shift.copy()
    scale = 1.0 / float(1 << BITS)
    for i in range(n):
        out[i] = (x.astype(np.float64) + 0.5) * scale
        c = (~i & (i + 1)).bit_length() - 1  # index of the lowest zero bit of i
        x = x ^ directions[:, c]
    return out
