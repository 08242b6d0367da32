"""``contact_details`` (one compiled formula, core/contact.py) equals the
vectorised numpy statement of the same formula, bit for bit, through every entry.

The oracle below is the formula written with numpy broadcasting, as the
package computed it before the compiled kernel: relative centre
``g = (p_b - p_a) + t((v_b - v_a) + (t/2)(a_b - a_a))``, relative velocity
``w = (v_a - v_b) + t(a_a - a_b)``, normal ``g/|g|`` (else ``w/|w|``, else +x),
point ``p_a(t) + r_a n``, closing speed ``w . n``; NaN for a non-finite ``t``,
point or closing speed, or a negative/NaN radius.  Proved on random rows over
ten decades, coincident centres, zero relative velocity, ``t`` = 0, -0, inf,
bad radii, and broadcast shapes (test_*_bitwise).
"""
from __future__ import annotations

import numpy as np
import pytest

from circle_collision_ros.core.narrow.contact import (contact_details, details_on_index_pairs,
                                               details_on_rows)


def numpy_details(p_a, v_a, a_a, r_a, p_b, v_b, a_b, t):
    p_a, v_a, a_a, p_b, v_b, a_b = (
        np.asarray(x, dtype=np.float64) for x in (p_a, v_a, a_a, p_b, v_b, a_b)
    )
    r_a = np.asarray(r_a, dtype=np.float64)[..., None]
    t = np.asarray(t, dtype=np.float64)[..., None]
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        h = 0.5 * t
        g = (p_b - p_a) + t * ((v_b - v_a) + h * (a_b - a_a))
        w = (v_a - v_b) + t * (a_a - a_b)
        ng = np.sqrt(np.sum(g * g, axis=-1, keepdims=True))
        nw = np.sqrt(np.sum(w * w, axis=-1, keepdims=True))
        ex = np.zeros_like(g)
        ex[..., 0] = 1.0
        fallback = np.where(nw > 0, w / np.where(nw > 0, nw, 1.0), ex)
        n = np.where(ng > 0, g / np.where(ng > 0, ng, 1.0), fallback)
        point = (p_a + t * (v_a + h * a_a)) + r_a * n
        closing = np.sum(w * n, axis=-1)
        bad = ~np.isfinite(t[..., 0]) | ~np.isfinite(closing) | ~np.all(np.isfinite(point), axis=-1)
        bad = bad | ~(r_a[..., 0] >= 0)
    return (np.where(bad[..., None], np.nan, point), np.where(bad[..., None], np.nan, n),
            np.where(bad, np.nan, closing))


def bits(x) -> np.ndarray:
    return np.ascontiguousarray(x, dtype=np.float64).view(np.uint64)


def assert_same(got, want):
    for g, w in zip(got, want):
        assert g.shape == w.shape
        assert np.array_equal(bits(g), bits(w))


def rows(rng, n, D):
    sc = 10.0 ** rng.uniform(-5, 5, (n, 1))
    pa, va, aa, pb, vb, ab = (rng.normal(size=(n, D)) * sc for _ in range(6))
    pa[::9] += 1e6  # map-frame offsets
    pb[::9] += 1e6
    pb[::13] = pa[::13]  # coincident centres at t = 0
    vb[::13] = va[::13]
    vb[::26] = va[::26]  # zero relative velocity
    ab[::26] = aa[::26]
    ra = np.abs(rng.normal(size=n))
    ra[::50], ra[::77] = -1.0, np.nan
    t = np.abs(rng.normal(size=n))
    t[::7], t[::11], t[::19], t[::23] = 0.0, np.inf, -0.0, np.nan
    return pa, va, aa, ra, pb, vb, ab, t


@pytest.mark.parametrize("D", [2, 3])
def test_rows_bitwise(D):
    pa, va, aa, ra, pb, vb, ab, t = rows(np.random.default_rng([31, D]), 5000, D)
    want = numpy_details(pa, va, aa, ra, pb, vb, ab, t)
    assert_same(contact_details(pa, va, aa, ra, pb, vb, ab, ra, t), want)
    assert_same(details_on_rows(pa, va, aa, ra, pb, vb, ab, t), want)
    # the same rows as pairs of a body table, gathered by index inside the kernel
    n = pa.shape[0]
    P, V, A, R = (np.concatenate(x) for x in ((pa, pb), (va, vb), (aa, ab), (ra, ra)))
    I, J = np.arange(n), np.arange(n, 2 * n)
    assert_same(details_on_index_pairs(P, V, A, R, I, J, t), want)


def test_broadcast_shapes_bitwise():
    rng = np.random.default_rng(32)
    cases = [
        ([-10.0, 0.0], [1.0, 0.0], [0.0, 0.0], 1.0, [0.0, 0.0], [0.0, 0.0], [0.0, 0.0], 8.0),
        (rng.normal(size=(4, 5, 3)), rng.normal(size=3), np.zeros(3), rng.uniform(0, 1, (4, 5)),
         np.zeros((5, 3)), np.zeros(3), rng.normal(size=(4, 1, 3)), rng.uniform(0, 2, 5)),
        (np.zeros((3, 3)), np.zeros(3), np.zeros(3), 1.0, np.zeros(3), np.zeros(3), np.zeros(3),
         0.0),
    ]
    for pa, va, aa, ra, pb, vb, ab, t in cases:
        assert_same(
            contact_details(pa, va, aa, ra, pb, vb, ab, 0.5, t),
            numpy_details(pa, va, aa, ra, pb, vb, ab, t),
        )


@pytest.mark.parametrize("D", [2, 3])
def test_threaded_index_kernel_is_the_serial_kernel(D):
    """details_on_index_pairs runs on numba's threads from PARALLEL_MIN_CONTACTS
    rows: the same bits as the serial kernel, row for row (test_rows_bitwise's
    5,000 rows also go through it, against the numpy statement)."""
    from circle_collision_ros.core.narrow import contact as c

    pa, va, aa, ra, pb, vb, ab, t = rows(
        np.random.default_rng([33, D]), 3 * c.PARALLEL_MIN_CONTACTS, D
    )
    n = pa.shape[0]
    P, V, A, R = (np.concatenate(x) for x in ((pa, pb), (va, vb), (aa, ab), (ra, ra)))
    I, J = np.arange(n), np.arange(n, 2 * n)
    out = [(np.empty((n, D)), np.empty((n, D)), np.empty(n)) for _ in range(2)]
    c._index_kernel(P, V, A, R, I, J, t, *out[0])
    c._index_kernel_par(P, V, A, R, I, J, t, *out[1])
    assert_same(out[1], out[0])
