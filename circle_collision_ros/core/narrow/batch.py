"""Narrow phase: first-contact time of two uniformly accelerated discs/spheres.

Model.  Body centres follow ``p(t) = p0 + v t + a t^2/2``.  With relative
quantities ``dp = p_a - p_b``, ``dv = v_a - v_b``, ``da = a_a - a_b`` and
``R = r_a + r_b`` the relative centre is ``g(t) = dp + t (dv + t da/2)`` and
the bodies touch when ``f(t) = |g(t)|^2 - R^2 = 0`` (a quartic in ``t``).

Contract.  0.0 if the bodies overlap at t = 0 (f(0) < 0) or touch there and
approach; otherwise the first root of f in (0, H], or inf.  Order of contact
at t = 0 (f(0) = 0): the lowest-order nonzero coefficient of
f(t) = c1 t + c2 t^2 + c3 t^3 + c4 t^4 decides -- c1 = 2 dp.dv,
c2 = |dv|^2 + dp.da, c3 = da.dv, c4 = |da|^2/4 -- negative: approaching,
0.0; positive: separating, the next root; all zero (touching for all time,
never approaching): inf.  Tangent grazes (a local minimum of f exactly 0)
are contacts.

This module holds the public entry points and the batch plumbing; the
solvers are:

* ``fast``: a certified branch-free version of the method, one SIMD
  loop over the accelerating rows (da != 0) of a batch with a finite horizon
  (decides ~99 % of a typical batch, leaves the rest UNDECIDED), and one over
  the constant-velocity rows (da == 0, any horizon) running
  ``straight``'s certified closed form (the robust solver and the
  scalar entry points call the same function for such rows);
* ``robust``: the robust solver, one row at a time, every decision
  certified against rigorous rounding bounds (rows it cannot certify stay
  UNDECIDED -- well under 0.1 % of the benchmark mixes, see
  bench/fallback.py);
* ``exact``: exact rational arithmetic (Sturm sequences on the exact
  quartic) for the rest, in plain Python, called after the kernels.

So every 0.0 and inf is proved; a finite time is within one ulp of the
exact first contact time by sign checks (robust path), correctly rounded
(exact path), or within the polishing step's error estimate inside a proved
bracket (fast path; tests/core/narrow/test_narrow_phase_exact.py and the accuracy
tests check all three).  A row's result
depends only on the row, never on the batch it comes in.

Public entry points
-------------------
``time_to_collision`` (vectorised numpy API) and ``ttc_scalar`` (one pair,
an ``@njit`` function that other numba code can call directly::

    t = ttc_scalar(pax, pay, paz, vax, vay, vaz, aax, aay, aaz, r_a,
                    pbx, pby, pbz, vbx, vby, vbz, abx, aby, abz, r_b, horizon)

use 0.0 for the z components in 2-D).  Both follow the same contract.

Input range: finite values with magnitudes below ~1e150.  The relative
state is scaled exactly by a power of two so that its largest component lies
in [2, 4) (``evaluate.rel2``); every error bound is relative to that
scale.  A row with a nonzero relative component (of dp, dv, da or R) below
2^-240 of the largest (``evaluate._SPAN``: scaling would round it on the
subnormal grid or flush it to 0 -- da = 0 would then look straight -- or its
squares would underflow) is decided by the exact path
(tests/core/narrow/test_narrow_phase_span.py).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit, objmode, prange, types
from numba.extending import overload

from circle_collision_ros.core.narrow.evaluate import INF, NAN, UNDECIDED, rel2, rel3, valid_row
from circle_collision_ros.core.narrow.exact import exact_first_contact
from circle_collision_ros.core.narrow.fast import fast_rel, count_straight, fast_rows, straight_rows
from circle_collision_ros.core.narrow.robust import robust_pair2, robust_pair3
from circle_collision_ros.core.narrow.straight import straight_rel
from circle_collision_ros.core.parallel_policy import threads_pay

__all__ = ["time_to_collision", "ttc_scalar", "ttc_kernel", "ttc_kernel_h"]


# --------------------------------------------------------------------------
# batch kernels: vectors (n, D), radii (n,), horizon H (n,) or one float,
# out (n,).  One per dimension (a planar-only process never compiles or
# loads the 3-D chain), serial or multi-threaded.
#
# Rows go in blocks of <= _BLOCK: the fast paths (fast) run over the
# block as vectorised loops -- fast_rows for accelerating rows (finite
# horizon), straight_rows for rows with da == 0 (each loop only where the
# block has such rows; a cheap vectorised count decides) -- then the rows
# they left UNDECIDED go to the robust solver; the kernels return how many
# rows that leaves UNDECIDED, and _run decides those exactly (exact,
# plain Python).  A row's result depends only on the row, never on the batch
# or kernel it comes in.  Each call of a fast loop pays a fixed set-up
# (run-time alias and overflow checks, vector prologue), so blocks are 1024
# rows: cheaper per row than 256 on bench/bench_core.py's mix.
# --------------------------------------------------------------------------
_BLOCK = 1024


def _h_at(H, i):
    """Horizon of row i: H[i] for an array, H for one float."""
    return H[i] if isinstance(H, np.ndarray) else H


@overload(_h_at, inline="always")
def _ov_h_at(H, i):
    if isinstance(H, types.Array):
        return lambda H, i: H[i]
    return lambda H, i: H


def _h_rows(H, hb, i0, m):
    """(Hs, hofs) with Hs[hofs + j] the horizon of row i0 + j: the array H
    itself, or the scratch hb filled with the float H.  The fast loop thus
    always reads an array, so it is compiled once for both kinds of H."""
    if isinstance(H, np.ndarray):
        return H, i0
    hb[:m] = H
    return hb, 0


@overload(_h_rows, inline="always")
def _ov_h_rows(H, hb, i0, m):
    if isinstance(H, types.Array):
        return lambda H, hb, i0, m: (H, i0)

    def impl(H, hb, i0, m):
        hb[:m] = H
        return hb, 0
    return impl


def _any_finite(H, i0, i1):
    """Some row of [i0, i1) has a finite horizon (else the fast path cannot
    decide anything but overlap, which the robust solver decides the same way)."""
    return bool(np.any(np.asarray(H)[i0:i1] < INF)) if isinstance(H, np.ndarray) else H < INF


@overload(_any_finite, inline="always")
def _ov_any_finite(H, i0, i1):
    if isinstance(H, types.Array):
        def impl(H, i0, i1):
            for i in range(i0, i1):
                if H[i] < INF:
                    return True
            return False
        return impl
    return lambda H, i0, i1: H < INF


def _robust_row(pa, va, aa, ra, pb, vb, ab, rb, H, i, Z):
    """Row i of a batch through the robust solver (vectors (n, D), D = len(Z))."""


@overload(_robust_row, inline="always")
def _ov_robust_row(pa, va, aa, ra, pb, vb, ab, rb, H, i, Z):
    if Z.count == 2:
        return lambda pa, va, aa, ra, pb, vb, ab, rb, H, i, Z: robust_pair2(
            pa[i, 0], pa[i, 1], va[i, 0], va[i, 1], aa[i, 0], aa[i, 1], ra[i],
            pb[i, 0], pb[i, 1], vb[i, 0], vb[i, 1], ab[i, 0], ab[i, 1], rb[i], H)
    return lambda pa, va, aa, ra, pb, vb, ab, rb, H, i, Z: robust_pair3(
        pa[i, 0], pa[i, 1], pa[i, 2], va[i, 0], va[i, 1], va[i, 2],
        aa[i, 0], aa[i, 1], aa[i, 2], ra[i],
        pb[i, 0], pb[i, 1], pb[i, 2], vb[i, 0], vb[i, 1], vb[i, 2],
        ab[i, 0], ab[i, 1], ab[i, 2], rb[i], H)


@njit(cache=True, error_model="numpy", inline="always")
def _block(pa, va, aa, ra, pb, vb, ab, rb, H, out, i0, i1, hb, Z):
    """Rows [i0, i1) of a batch with vectors (n, D), D = len(Z) (a tuple of D
    zeros, so each dimension compiles its own chain); hb: scratch of
    >= i1 - i0 floats.  Returns how many rows the robust solver, too, left
    UNDECIDED (``_resolve`` decides them exactly)."""
    m = i1 - i0
    n_st = count_straight(aa, ab, i0, m, Z)
    Hs, hofs = _h_rows(H, hb, i0, m)
    fast = n_st < m and _any_finite(H, i0, i1)
    if fast:
        fast_rows(pa, va, aa, ra, pb, vb, ab, rb, Hs, hofs, out, i0, m, Z)
    if n_st > 0:
        straight_rows(pa, va, aa, ra, pb, vb, ab, rb, Hs, hofs, out, i0, m, Z, fast)
    n_und = 0
    if fast or n_st > 0:
        for i in range(i0, i1):
            if out[i] == UNDECIDED:
                out[i] = _robust_row(pa, va, aa, ra, pb, vb, ab, rb, _h_at(H, i), i, Z)
                n_und += out[i] == UNDECIDED
    else:
        for i in range(i0, i1):
            out[i] = _robust_row(pa, va, aa, ra, pb, vb, ab, rb, _h_at(H, i), i, Z)
            n_und += out[i] == UNDECIDED
    return n_und


_Z2 = (0.0, 0.0)
_Z3 = (0.0, 0.0, 0.0)


@njit(cache=True, error_model="numpy")
def _k2(pa, va, aa, ra, pb, vb, ab, rb, H, out):
    n = out.shape[0]
    hb = np.empty(_BLOCK)
    n_und = 0
    for i0 in range(0, n, _BLOCK):
        n_und += _block(pa, va, aa, ra, pb, vb, ab, rb, H, out, i0, min(n, i0 + _BLOCK), hb, _Z2)
    return n_und


@njit(cache=True, error_model="numpy")
def _k3(pa, va, aa, ra, pb, vb, ab, rb, H, out):
    n = out.shape[0]
    hb = np.empty(_BLOCK)
    n_und = 0
    for i0 in range(0, n, _BLOCK):
        n_und += _block(pa, va, aa, ra, pb, vb, ab, rb, H, out, i0, min(n, i0 + _BLOCK), hb, _Z3)
    return n_und


# Threaded kernels spread every thread's rows over the whole batch.  A plain
# prange over rows hands each thread one contiguous run, but row costs are
# rarely uniform along a batch (the broad phase emits pairs sorted in space;
# the benchmark puts its dearer aimed pairs first), so one thread finished
# early and idled.  Here
# the rows are cut into nb = 2^m blocks of <= _BLOCK rows and prange runs
# over k = 0..nb-1 taking block bitrev(k): numba's static schedule gives each
# of T threads a contiguous run of k, which bit reversal maps to every T-th
# block when T is a power of two (and close to that otherwise).  Blocks of
# ~1000 rows keep each thread's writes to `out` on its own cache lines.


@njit(cache=True, error_model="numpy")
def _blocks(n):
    """(nb, bits, size): nb = 2^bits blocks of `size` rows covering n rows."""
    nb = 1
    bits = 0
    while nb * _BLOCK < n:
        nb *= 2
        bits += 1
    return nb, bits, (n + nb - 1) // nb


@njit(cache=True, error_model="numpy")
def _block_rows(k, bits, size, n):
    """Row range of the block bitrev(k) (bit reversal over `bits` bits).

    Deliberately not inlined: it shifts its copy of k, and numba's parfor
    pass rejects any assignment to an (inlined) prange index."""
    b = 0
    for _ in range(bits):
        b = (b << 1) | (k & 1)
        k >>= 1
    return b * size, min(n, (b + 1) * size)


@njit(cache=True, error_model="numpy", parallel=True)
def _k2p(pa, va, aa, ra, pb, vb, ab, rb, H, out):
    n = out.shape[0]
    nb, bits, size = _blocks(n)
    n_und = 0
    for k in prange(nb):
        i0, i1 = _block_rows(k, bits, size, n)
        n_und += _block(pa, va, aa, ra, pb, vb, ab, rb, H, out, i0, i1, np.empty(_BLOCK), _Z2)
    return n_und


@njit(cache=True, error_model="numpy", parallel=True)
def _k3p(pa, va, aa, ra, pb, vb, ab, rb, H, out):
    n = out.shape[0]
    nb, bits, size = _blocks(n)
    n_und = 0
    for k in prange(nb):
        i0, i1 = _block_rows(k, bits, size, n)
        n_und += _block(pa, va, aa, ra, pb, vb, ab, rb, H, out, i0, i1, np.empty(_BLOCK), _Z3)
    return n_und


def _exact_pair(pax, pay, paz, vax, vay, vaz, aax, aay, aaz, r_a,
                pbx, pby, pbz, vbx, vby, vbz, abx, aby, abz, r_b, horizon):
    """Exact answer of one pair (the scalar entry points' fallback; 0.0 for z in 2-D)."""
    return exact_first_contact((pax, pay, paz), (vax, vay, vaz), (aax, aay, aaz), r_a,
                               (pbx, pby, pbz), (vbx, vby, vbz), (abx, aby, abz), r_b, horizon)


def _resolve(n_und, pa, va, aa, ra, pb, vb, ab, rb, H, out):
    """Decide exactly (exact) the rows the kernels left UNDECIDED.

    n_und: the kernels' count of such rows (0: nothing to do, no scan)."""
    if not n_und:
        return
    arr = isinstance(H, np.ndarray)
    for i in np.flatnonzero(out == UNDECIDED):
        out[i] = exact_first_contact(pa[i], va[i], aa[i], ra[i], pb[i], vb[i], ab[i], rb[i],
                                     H[i] if arr else H)


# The scalar entry points run a batch row's steps on one row without the
# batch loop (no scratch arrays, no vector-loop set-up): the fast
# path's fast_rel (finite horizon) or, for da == 0, straight_rel (any
# horizon), then the robust solver for what it leaves undecided
# (certified_pair2/3, also compiled as the C one-pair entry's kernels, see
# one_pair), then the exact decision for the rest.  The arithmetic
# per row is the same IEEE operations as in the (vectorised) loop, so the
# result is bitwise the batch answer (tests/core/narrow/test_narrow_fast.py and
# tests/core/narrow/test_narrow_one_pair.py check it).
@njit(cache=True, error_model="numpy")
def certified_pair3(pax, pay, paz, vax, vay, vaz, aax, aay, aaz, r_a,
                     pbx, pby, pbz, vbx, vby, vbz, abx, aby, abz, r_b, horizon):
    """``ttc_scalar`` without the exact decision: UNDECIDED where the
    certified float paths cannot decide (NaN for invalid input)."""
    t = UNDECIDED
    straight = (aax == abx) & (aay == aby) & (aaz == abz)
    if straight or horizon < INF:
        chk = (pax + pay + paz + vax + vay + vaz + aax + aay + aaz + r_a
               + pbx + pby + pbz + vbx + vby + vbz + abx + aby + abz + r_b)
        Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, fine = rel3(pax, pay, paz, vax, vay, vaz, aax, aay, aaz,
                                                    r_a, pbx, pby, pbz, vbx, vby, vbz, abx, aby,
                                                    abz, r_b)
        h = horizon if (valid_row(chk, r_a, r_b, horizon) & fine) else NAN
        if straight:
            t = straight_rel(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, h)
        else:
            t = fast_rel(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, h)
    if t == UNDECIDED:
        t = robust_pair3(pax, pay, paz, vax, vay, vaz, aax, aay, aaz, r_a, pbx, pby, pbz, vbx, vby,
                         vbz, abx, aby, abz, r_b, horizon)
    return t


@njit(cache=True, error_model="numpy")
def certified_pair2(pax, pay, vax, vay, aax, aay, r_a, pbx, pby, vbx, vby, abx, aby, r_b, horizon):
    """Planar ``certified_pair3`` (bitwise the same result with z = 0)."""
    t = UNDECIDED
    straight = (aax == abx) & (aay == aby)
    if straight or horizon < INF:
        chk = pax + pay + vax + vay + aax + aay + r_a + pbx + pby + vbx + vby + abx + aby + r_b
        Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, fine = rel2(
            pax, pay, vax, vay, aax, aay, r_a, pbx, pby, vbx, vby, abx, aby, r_b
        )
        h = horizon if (valid_row(chk, r_a, r_b, horizon) & fine) else NAN
        if straight:
            t = straight_rel(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, h)
        else:
            t = fast_rel(Ph, Pl, Vh, Vl, Ah, Al, Rh, Rl, h)
    if t == UNDECIDED:
        t = robust_pair2(
            pax, pay, vax, vay, aax, aay, r_a, pbx, pby, vbx, vby, abx, aby, r_b, horizon
        )
    return t


@njit(cache=True, error_model="numpy")
def ttc_scalar(pax, pay, paz, vax, vay, vaz, aax, aay, aaz, r_a, pbx, pby, pbz, vbx, vby, vbz, abx,
               aby, abz, r_b, horizon):
    """First-contact time of one pair (numba-callable, same contract and
    bitwise the same result as ``time_to_collision``; pass 0.0 for z in
    2-D).  NaN for invalid input."""
    t = certified_pair3(pax, pay, paz, vax, vay, vaz, aax, aay, aaz, r_a, pbx, pby, pbz, vbx, vby,
                        vbz, abx, aby, abz, r_b, horizon)
    if t == UNDECIDED:
        with objmode(t="float64"):
            t = _exact_pair(pax, pay, paz, vax, vay, vaz, aax, aay, aaz, r_a, pbx, pby, pbz, vbx,
                            vby, vbz, abx, aby, abz, r_b, horizon)
    return t


@njit(cache=True, error_model="numpy")
def ttc_scalar2(pax, pay, vax, vay, aax, aay, r_a, pbx, pby, vbx, vby, abx, aby, r_b, horizon):
    """Planar twin of ``ttc_scalar`` (bitwise the same result with z = 0)."""
    t = certified_pair2(
        pax, pay, vax, vay, aax, aay, r_a, pbx, pby, vbx, vby, abx, aby, r_b, horizon
    )
    if t == UNDECIDED:
        with objmode(t="float64"):
            t = _exact_pair(pax, pay, 0.0, vax, vay, 0.0, aax, aay, 0.0, r_a, pbx, pby, 0.0, vbx,
                            vby, 0.0, abx, aby, 0.0, r_b, horizon)
    return t


# (D, threaded) -> kernel (each compiles once per horizon type: an array
# or one float); inputs C-contiguous (see _contiguous)
_KERNELS = {(2, False): _k2, (3, False): _k3, (2, True): _k2p, (3, True): _k3p}


def _run(threaded, pa, va, aa, ra, pb, vb, ab, rb, H, out):
    """A batch kernel over C-contiguous rows, then the exact decision of the
    rows it leaves undecided: out holds the final answers."""
    n_und = _KERNELS[(pa.shape[1], threaded)](pa, va, aa, ra, pb, vb, ab, rb, H, out)
    _resolve(n_und, pa, va, aa, ra, pb, vb, ab, rb, H, out)


def _contiguous(*arrays):
    """The kernels read rows through flat views: C-contiguous copies where needed."""
    return tuple(np.ascontiguousarray(x) for x in arrays)


def ttc_kernel(pa, va, aa, ra, pb, vb, ab, rb, H, out):
    """Serial loop over rows: vectors (n, D) with D in {2, 3}, radii and
    horizons H (n,), results into out (n,)."""
    _run(False, *_contiguous(pa, va, aa, ra, pb, vb, ab, rb, H), out)


def ttc_kernel_h(pa, va, aa, ra, pb, vb, ab, rb, H, out):
    """``ttc_kernel`` with one float horizon H for all rows."""
    _run(False, *_contiguous(pa, va, aa, ra, pb, vb, ab, rb), float(H), out)


# Rows from which the threaded kernels may be used.  On an idle machine with
# a warm thread pool 2 threads win from far fewer rows; but when other
# processes keep a core busy a parallel launch waits for a time slice and
# can be much slower than serial (bench/accuracy_vs_time.py times both).  So
# threads are used only when a core is free at the call
# (parallel_policy.threads_pay), and the threshold stays conservative
# because a core taken right after that check still costs the wait.
PARALLEL_MIN_ROWS = 4096

_ND = np.ndarray
_F8 = np.dtype(np.float64)


def _as_rows(x: np.ndarray, batch: tuple, n: int, D: int) -> np.ndarray:
    """C-contiguous (n, D) / (n,) float64 rows of x broadcast to ``batch``."""
    shape = batch + (D,) if D else batch
    if x.shape != shape:
        # broadcasting assignment into a fresh array: several times cheaper
        # than np.broadcast_to + ascontiguousarray
        y = np.empty(shape)
        y[...] = x
        x = y
    else:
        x = np.ascontiguousarray(x)
    return x.reshape((n, D) if D else (n,))


def _rows_ok(p_a, v_a, a_a, r_a, p_b, v_b, a_b, r_b) -> bool:
    """True if the inputs are already what the kernels take: C-contiguous
    float64 ndarrays, vectors (n, D) with D in {2, 3}, radii (n,)."""
    if not (
        type(p_a) is _ND
        and type(v_a) is _ND
        and type(a_a) is _ND
        and type(r_a) is _ND
        and type(p_b) is _ND
        and type(v_b) is _ND
        and type(a_b) is _ND
        and type(r_b) is _ND
    ):
        return False
    shp = p_a.shape
    if len(shp) != 2 or not (shp[1] == 2 or shp[1] == 3):
        return False
    n1 = shp[:1]
    return (
        v_a.shape == shp
        and a_a.shape == shp
        and p_b.shape == shp
        and v_b.shape == shp
        and a_b.shape == shp
        and r_a.shape == n1
        and r_b.shape == n1
        and p_a.dtype is _F8
        and v_a.dtype is _F8
        and a_a.dtype is _F8
        and r_a.dtype is _F8
        and p_b.dtype is _F8
        and v_b.dtype is _F8
        and a_b.dtype is _F8
        and r_b.dtype is _F8
        and p_a.flags.c_contiguous
        and v_a.flags.c_contiguous
        and a_a.flags.c_contiguous
        and r_a.flags.c_contiguous
        and p_b.flags.c_contiguous
        and v_b.flags.c_contiguous
        and a_b.flags.c_contiguous
        and r_b.flags.c_contiguous
    )


_VEC_NAMES = ("p_a", "v_a", "a_a", "p_b", "v_b", "a_b")


def _floats(x, name: str) -> np.ndarray:
    """x as a float64 array, or an error naming the argument (None would
    silently become NaN)."""
    if x is None:
        raise TypeError(f"time_to_collision: {name} is None (expected numbers)")
    try:
        return np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"time_to_collision: {name} is not numeric ({exc})") from None


def time_to_collision(p_a, v_a, a_a, r_a, p_b, v_b, a_b, r_b, horizon=math.inf) -> np.ndarray:
    """Earliest time at which two uniformly accelerated discs/spheres touch.

    Parameters
    ----------
    p_a, v_a, a_a, p_b, v_b, a_b : array_like, shape (..., D), D = 2 or 3
        Centre position [m], velocity [m/s], acceleration [m/s^2] at t = 0.
    r_a, r_b : array_like, shape (...)
        Radii [m]; 0 is a point.
    horizon : array_like, shape (...), optional
        Latest time of interest [s] (inclusive), default inf.

    Returns
    -------
    numpy.ndarray of float64 of the broadcast batch shape; for batch shape
    () (one pair) a numpy.float64, as numpy returns for a 0-d result
        0.0 if the bodies overlap at t = 0 or touch while approaching;
        otherwise the smallest t in (0, horizon] with centre distance equal
        to r_a + r_b (tangent grazes count); inf if none.  A pair touching at
        t = 0 while separating reports its next contact, if any.
        NaN for an element with a non-finite input, a negative radius or a
        negative/NaN horizon (other elements are unaffected); out of the
        input range, also where a relative quantity (p_a - p_b, ...)
        overflows.

    Touching at t = 0: the lowest-order nonzero term of |g(t)|^2 - R^2
    decides (approaching -> 0.0, separating -> the next contact; touching
    for all time without approaching -> inf); see the module docstring.

    Guarantees (for the inputs exactly as given; proved in
    tests/core/narrow/test_narrow_phase_exact.py against an exact-rational
    reference, and tests/core/narrow/test_narrow_phase*.py): 0.0 and inf are exact
    decisions -- no missed or spurious contact, tangent grazes included --
    and a finite time is within one ulp of the exact first contact time
    (correctly rounded where the exact fallback decides), never negative and
    never beyond the horizon.

    Raises
    ------
    ValueError
        If the vector shapes disagree in D, D is not 2 or 3, the shapes do
        not broadcast, or an argument is not numeric (the message names the
        arguments and their shapes).
    TypeError
        If an argument is None.

    One pair given as 1-D vectors (lists, tuples or 1-D float64 arrays) or
    (1, D) arrays, and numbers or (1,) arrays, is answered in C (this name is
    bound to the builtin of ``narrow.one_pair``; ``bench/bench_core.py
    --one-pair`` prints its time per call) with the same answers, bit for
    bit, as the batch.
    """
    # Fast path (Scene / node hot path): inputs already in kernel layout and
    # a scalar horizon -- no conversions, no temporaries besides the output.
    th = type(horizon)
    if (th is float or th is int or th is np.float64) and _rows_ok(
        p_a, v_a, a_a, r_a, p_b, v_b, a_b, r_b
    ):
        n = r_a.shape[0]
        out = np.empty(n)
        _run(threads_pay(n, PARALLEL_MIN_ROWS), p_a, v_a, a_a, r_a, p_b, v_b, a_b, r_b,
             float(horizon), out)
        return out
    vecs = [_floats(x, nm) for x, nm in zip((p_a, v_a, a_a, p_b, v_b, a_b), _VEC_NAMES)]
    D = vecs[0].shape[-1] if vecs[0].ndim else 0
    if D not in (2, 3) or any(x.ndim == 0 or x.shape[-1] != D for x in vecs):
        raise ValueError(
            "time_to_collision: position/velocity/acceleration must share a last axis "
            "of size 2 or 3; got shapes "
            + ", ".join(f"{nm} {x.shape}" for nm, x in zip(_VEC_NAMES, vecs))
        )
    sc = [_floats(x, nm) for x, nm in zip((r_a, r_b, horizon), ("r_a", "r_b", "horizon"))]
    shapes = {x.shape[:-1] for x in vecs} | {x.shape for x in sc[:2]}
    if sc[2].ndim:
        shapes.add(sc[2].shape)
    try:
        batch = shapes.pop() if len(shapes) == 1 else np.broadcast_shapes(*shapes)
    except ValueError:
        raise ValueError(
            "time_to_collision: batch shapes do not broadcast: "
            + ", ".join(f"{nm} {x.shape[:-1]}" for nm, x in zip(_VEC_NAMES, vecs))
            + f", r_a {sc[0].shape}, r_b {sc[1].shape}, horizon {sc[2].shape}"
        ) from None
    n = math.prod(batch)
    out = np.empty(n, dtype=np.float64)
    pa, va, aa, pb, vb, ab = (_as_rows(x, batch, n, D) for x in vecs)
    ra, rb = (_as_rows(x, batch, n, 0) for x in sc[:2])
    if sc[2].ndim == 0:  # one horizon for all rows: passed as a float
        hz = float(sc[2])
    else:
        hz = _as_rows(sc[2], batch, n, 0)
    _run(threads_pay(n, PARALLEL_MIN_ROWS), pa, va, aa, ra, pb, vb, ab, rb, hz, out)
    return out.reshape(batch) if batch else out[0]  # batch shape (): a numpy.float64
