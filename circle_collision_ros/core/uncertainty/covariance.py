"""The light input check of covariances (numpy only: no numba kernels).

``covariance_problem(cov)`` says why a (position, velocity) covariance is
unusable, or None; the pipeline runs it (or its vectorised form, with the same
tolerances) on every covariance it accepts.
"""
from __future__ import annotations

import numpy as np

__all__ = ["covariance_problem", "COV_SYMMETRY_RTOL", "COV_PSD_RTOL"]

# Tolerances of covariance_problem (the node rejects what fails them):
COV_SYMMETRY_RTOL = 1e-9  # |C - C^T| <= 1e-9 * max|C| (elementwise)
COV_PSD_RTOL = 1e-9       # smallest eigenvalue >= -1e-9 * largest |eigenvalue|


def covariance_problem(cov) -> str | None:
    """Why ``cov`` (a (k, k) covariance, k = 2D) is unusable, or None.

    Checks, in order: square 2-D array; finite; symmetric to
    ``COV_SYMMETRY_RTOL`` (relative to the largest |element|); positive
    semi-definite to ``COV_PSD_RTOL`` (smallest eigenvalue >= -rtol * largest
    |eigenvalue|; smaller negative eigenvalues are rounding and the core
    clamps them to 0)."""
    c = np.asarray(cov, dtype=np.float64)
    if c.ndim != 2 or c.shape[0] != c.shape[1]:
        return f"covariance must be a square matrix, got shape {c.shape}"
    if not np.all(np.isfinite(c)):
        bad = np.argwhere(~np.isfinite(c))[0]
        return f"covariance element ({bad[0]}, {bad[1]}) is not finite ({c[bad[0], bad[1]]})"
    scale = float(np.max(np.abs(c))) if c.size else 0.0
    asym = np.abs(c - c.T)
    if scale > 0 and float(asym.max()) > COV_SYMMETRY_RTOL * scale:
        i, j = np.unravel_index(int(np.argmax(asym)), asym.shape)
        return (f"covariance is not symmetric: element ({i}, {j}) = {c[i, j]!r} but "
                f"({j}, {i}) = {c[j, i]!r}")
    if scale > 0:
        lam = np.linalg.eigvalsh(0.5 * (c + c.T))
        if lam[0] < -COV_PSD_RTOL * max(abs(lam[0]), abs(lam[-1])):
            return (f"covariance is not positive semi-definite: eigenvalue {lam[0]:.6g} "
                    f"(largest {lam[-1]:.6g})")
    return None
