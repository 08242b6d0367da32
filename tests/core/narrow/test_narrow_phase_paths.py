"""``time_to_collision`` entry paths agree bit for bit.

The fast path (C-contiguous float64 row arrays + scalar horizon), the general
broadcasting path, the per-row-horizon kernels, the threaded kernels, the
planar (2-component) solver chain vs the 3-D chain with z = 0, and the early
rejection tests must not change any result.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from circle_collision_ros.core.narrow import batch as npz
from circle_collision_ros.core.narrow import time_to_collision
from tests.core.narrow.test_narrow_phase_accuracy import mixed_pairs


def _pairs(n, D=2, seed=5):
    return mixed_pairs(n, D, seed, straight_fraction=1 / 8)


def _same(x, y):
    return np.array_equal(x, y, equal_nan=True)


@pytest.mark.parametrize("D", [2, 3])
@pytest.mark.parametrize("H", [0.5, 10.0, math.inf])
def test_fast_general_and_kernels_agree(D, H):
    args = _pairs(3000, D)
    fast = time_to_collision(*args, horizon=H)  # row arrays: fast path
    assert fast.shape == (3000,) and np.isfinite(fast).any()
    # general path: horizon as an array, radii as (n, 1)-broadcastable lists
    gen = time_to_collision(*args[:3], args[3].tolist(), *args[4:7], args[7].tolist(),
                            horizon=np.full(3000, H))
    assert _same(fast, gen)
    # non-contiguous inputs (general path) and numpy-scalar / int horizon
    nc = tuple(np.asfortranarray(x) for x in args)
    assert _same(fast, time_to_collision(*nc, horizon=np.float64(H)))
    if math.isfinite(H) and H == int(H):
        assert _same(fast, time_to_collision(*args, horizon=int(H)))
    # every kernel variant, serial and threaded
    out = np.empty(3000)
    for par in (False, True):
        for scal in (False, True):
            out[:] = -1.0
            npz._run(par, *args, H if scal else np.full(3000, H), out)
            assert _same(fast, out), (D, par, scal)


def test_planar_chain_equals_3d_with_zero_z():
    """The 2-component solver gives the 3-D solver's result with z = 0."""
    args = _pairs(4000, 2, seed=11)
    z = [np.concatenate([x, np.zeros((x.shape[0], 1))], axis=1) if x.ndim == 2 else x for x in args]
    for H in (3.0, math.inf):
        assert _same(time_to_collision(*args, horizon=H), time_to_collision(*z, horizon=H))


def test_threaded_threshold_and_small_batches_agree():
    """Big batches (threaded when a core is free: parallel_policy), the threaded and
    the serial kernel called directly, and small batches give the same bits."""
    args = _pairs(2 * npz.PARALLEL_MIN_ROWS + 7)
    big = time_to_collision(*args, horizon=10.0)
    small = np.concatenate([time_to_collision(*(x[i:i + 10] for x in args), horizon=10.0)
                            for i in range(0, big.shape[0], 10)])
    assert _same(big, small)
    rows = npz._contiguous(*args)
    for threaded in (True, False):
        out = np.empty(big.shape[0])
        npz._run(threaded, *rows, 10.0, out)
        assert _same(out, big)


def test_fast_path_validation_and_nan():
    """The fast path keeps the contract: NaN rows isolated, bad shapes raise."""
    pa, va, aa, ra, pb, vb, ab, rb = _pairs(8)
    pa[1, 0] = np.nan
    ra = ra.copy()
    ra[2] = -1.0
    t = time_to_collision(pa, va, aa, ra, pb, vb, ab, rb, 10.0)
    assert np.isnan(t[1]) and np.isnan(t[2]) and not np.isnan(t[[0, 3, 4, 5, 6, 7]]).any()
    assert np.isnan(time_to_collision(pa, va, aa, ra, pb, vb, ab, rb, -1.0)).all()
    with pytest.raises(ValueError):
        time_to_collision(
            pa[:, :1], va[:, :1], aa[:, :1], ra, pb[:, :1], vb[:, :1], ab[:, :1], rb, 1.0
        )
    with pytest.raises(ValueError):
        time_to_collision(pa, va[:, :1], aa, ra, pb, vb, ab, rb, 1.0)
    # float32 inputs are converted (general path), same result as float64
    f32 = [x.astype(np.float32) for x in (pa, va, aa, ra, pb, vb, ab, rb)]
    f64 = [x.astype(np.float64) for x in f32]
    assert _same(time_to_collision(*f32, horizon=10.0), time_to_collision(*f64, horizon=10.0))


def test_horizon_at_the_contact_time():
    """Horizons one ulp either side of the (correctly rounded) contact time
    bracket the exact root: just above keeps the contact with the same time,
    just below gives inf -- so neither the early rejections nor the horizon
    handling drop or invent a contact at the boundary."""
    args = list(_pairs(2000, 2, seed=3))
    t = time_to_collision(*args, horizon=10.0)
    hit = np.flatnonzero(np.isfinite(t) & (t > 0))
    assert hit.size > 500
    for i in hit[:300]:
        row = [x[i : i + 1] for x in args]
        above = float(np.nextafter(t[i], math.inf))
        below = float(np.nextafter(t[i], 0.0))
        assert time_to_collision(*row, horizon=above)[0] == t[i]
        assert math.isinf(time_to_collision(*row, horizon=below)[0])


@pytest.mark.parametrize(
    "n",
    [0, 1, npz._BLOCK - 1, npz._BLOCK, npz._BLOCK + 1, 5000, 64 * npz._BLOCK, 64 * npz._BLOCK + 1,
     200 * npz._BLOCK + 17],
)
def test_threaded_blocks_cover_every_row_once(n):
    """The threaded kernels' bit-reversed blocks cover each row exactly once,
    whatever n is relative to the block size and the power-of-two block
    count: every output is written (a -1 sentinel never survives) and equals
    the serial kernel's."""
    args = _pairs(max(n, 1))
    args = tuple(np.ascontiguousarray(x[:n]) for x in args)
    ser = np.empty(n)
    npz._run(False, *args, 10.0, ser)
    for scal in (True, False):
        par = np.full(n, -1.0)
        npz._run(True, *args, 10.0 if scal else np.full(n, 10.0), par)
        assert _same(ser, par), (n, scal)
    # 3-D chain with z = 0 through the threaded kernels too
    z = tuple(np.concatenate([x, np.zeros((n, 1))], axis=1) if x.ndim == 2 else x for x in args)
    par3 = np.full(n, -1.0)
    npz._run(True, *z, 10.0, par3)
    assert _same(ser, par3)
