"""Checks on incoming circle states, free of side effects.

`check_batch` returns which states of a batch are usable and, for each one
that is not, a short reason naming the field and the bad value. Callers decide
what to do with it (the node warns, throttled, naming topic and id; the service
answers `success: false`). The checks are vectorised: a clean batch of 1,000
states costs well under a millisecond; reasons are formatted only for bad rows.
"""
from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass

import numpy as np
from numba import njit

from circle_collision_ros.core.uncertainty.covariance import (COV_PSD_RTOL, COV_SYMMETRY_RTOL,
                                                              covariance_problem)
from circle_collision_ros.pipeline.state_codec import COVARIANCE_SIZE
from circle_collision_ros.pipeline.state_batch import (USED_COVARIANCE_AXES, StateBatch,
                                                       covariance_block)


class StampLimits:
    """How far a state's stamp may lie ahead of the receiving clock.

    Tracker clocks drift by milliseconds; a stamp seconds ahead is a unit or
    clock error, and accepting it would drag the scene's reference time into
    the future for every other body.
    """

    MAX_FUTURE_NS = 1_000_000_000


class ValueLimits:
    """Largest magnitude accepted for radius, position, velocity and acceleration (SI units).

    No robot scene comes near 1e12 m (or m/s, m/s^2); the bound keeps every
    accepted state, even propagated over the largest possible stamp difference
    (~2.1e9 s: dt^2 ~ 5e18), far inside the core's documented input range
    (|values| < ~1e150). Beyond that range the core gives no guarantee: a
    radius of 1e160 overlapping two bodies was predicted as no contact at all
    (tests/reliability/test_fuzz_messages.py).
    """

    MAX_MAGNITUDE = 1e12
    # Covariance entries (m^2, m^2/s, m^2/s^2): the square of the above. Propagated over the
    # largest stamp difference (dt^2 ~ 5e18) they stay finite (~1e43).
    MAX_COVARIANCE = MAX_MAGNITUDE**2


def covariance_rejected(blocks: np.ndarray) -> np.ndarray:
    """(n,) bool: which (n, m, m) covariance blocks core.uncertainty.covariance_problem refuses,
    vectorised with its tolerances (finite; symmetric to COV_SYMMETRY_RTOL x max|C|; smallest
    eigenvalue >= -COV_PSD_RTOL x largest |eigenvalue|).

    A symmetric block whose diagonal dominates (C_ii >= sum_j!=i |C_ij| on every row) has no
    negative eigenvalue (Gershgorin), so it passes without an eigendecomposition; eigvalsh's
    backward error (a few eps x largest |eigenvalue|) is far inside COV_PSD_RTOL, so the
    decision is the one eigvalsh would give.  Only the other blocks are decomposed."""
    blocks = np.ascontiguousarray(blocks, dtype=np.float64)
    n = blocks.shape[0]
    out = np.empty(n, dtype=np.bool_)
    decompose = np.empty(n, dtype=np.bool_)
    _covariance_screen(blocks, COV_SYMMETRY_RTOL, out, decompose)
    _psd_rejected(blocks, decompose, out)
    return out


def _psd_rejected(blocks: np.ndarray, decompose: np.ndarray, rejected: np.ndarray) -> None:
    """rejected[k] = the PSD test with eigenvalues, for the blocks k with decompose[k]."""
    k = np.flatnonzero(decompose)
    if k.size:
        c = blocks[k]
        lam = np.linalg.eigvalsh(0.5 * (c + c.transpose(0, 2, 1)))
        rejected[k] = lam[:, 0] < -COV_PSD_RTOL * np.maximum(np.abs(lam[:, 0]), np.abs(lam[:, -1]))


@njit(cache=True)
def _screen_block(c, sym_rtol):
    """(rejected, decompose) of one (m, m) block: rejected if not finite or (scale > 0 and)
    asymmetric beyond sym_rtol x scale; else decompose = whether the PSD test needs
    eigenvalues (scale > 0 and the symmetrised diagonal does not dominate)."""
    m = c.shape[0]
    finite = True
    scale = 0.0
    asym = 0.0
    for r in range(m):
        for q in range(m):
            x = c[r, q]
            if not math.isfinite(x):
                finite = False
            scale = max(scale, abs(x))
            asym = max(asym, abs(x - c[q, r]))
    if not finite:
        return True, False
    if scale > 0.0 and asym > sym_rtol * scale:
        return True, False
    if scale == 0.0:
        return False, False
    for r in range(m):
        off = 0.0
        for q in range(m):
            if q != r:
                off += abs(0.5 * (c[r, q] + c[q, r]))
        if c[r, r] < off:
            return False, True
    return False, False


@njit(cache=True)
def _covariance_screen(blocks, sym_rtol, rejected, decompose):
    """_screen_block of every block."""
    for i in range(blocks.shape[0]):
        rejected[i], decompose[i] = _screen_block(blocks[i], sym_rtol)


@njit(cache=True)
def _covariance_rows(
    cov, size, remove, axes, max_abs, sym_rtol, block, given, bad, flagged, decompose
):
    """covariance_checks' pass over the (n, 36) row-major 6x6 covariances, one row at a time:
    block[i] = the rows/columns `axes` of row i; given[i] = 36 values and the block not all
    zero (a NaN is not zero); bad[i] = a count other than 0 or 36, or (given, not a removal)
    a finite block whose largest |value| exceeds max_abs; flagged[i] / decompose[i] (given,
    not a removal, not bad) = _screen_block's rejected / decompose (a non-finite block is
    flagged: the core's check words and confirms it)."""
    m = axes.shape[0]
    for i in range(cov.shape[0]):
        nonzero = False
        finite = True
        largest = 0.0
        for r in range(m):
            for q in range(m):
                x = cov[i, 6 * axes[r] + axes[q]]  # row-major 6x6
                block[i, r, q] = x
                if x != 0.0:
                    nonzero = True
                if not math.isfinite(x):
                    finite = False
                largest = max(largest, abs(x))
        given[i] = size[i] == COVARIANCE_SIZE and nonzero
        bad[i] = size[i] != 0 and size[i] != COVARIANCE_SIZE
        flagged[i] = False
        decompose[i] = False
        if not given[i] or remove[i]:
            continue
        if finite and largest > max_abs:
            bad[i] = True
            continue
        flagged[i], decompose[i] = _screen_block(block[i], sym_rtol)


@dataclass(frozen=True)
class Rejection:
    """One state refused: its index in the message, its id (may be empty), and why."""

    index: int
    body_id: str
    reason: str  # every problem of the state, "; "-joined


@dataclass(frozen=True)
class BatchCheck:
    """Outcome of check_batch: usable rows, rejections, and the scene frame to use."""

    good: np.ndarray  # (N,) bool
    rejections: list[Rejection]
    frame_id: str
    uncertain: np.ndarray | None = None  # (N,) bool: good states with a non-zero covariance
    #: (N, 2D, 2D) the used rows/columns of each state's covariance (None: the batch has none)
    covariance: np.ndarray | None = None


_VECTORS = ("position", "velocity", "acceleration")


class StampHint:
    """How to stamp a state, for the warning on a zero stamp (the `ros2 topic pub` way)."""

    ZERO = (
        "header.stamp is zero (unset): stamp each state with the time it is valid at"
        " (ros2 topic pub: header: {stamp: now})"
    )


def covariance_checks(
    batch: StateBatch, dimensions: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """(bad, uncertain, block): per state, whether its covariance is unusable, whether it is
    usable and not all zero on the used axes (a zero or absent covariance is an exact state),
    and the (n, 2D, 2D) block of the used axes (state_batch.covariance_block; None without
    covariances).

    Only the rows and columns a `dimensions`-D scene uses are checked (x, y, vx, vy in 2-D).
    The rule and tolerances are the core's (core.uncertainty.covariance_problem), applied in
    one compiled pass here (_covariance_rows, covariance_rejected's tests); the reason of a
    bad row is that function's text.
    """
    n = len(batch)
    if batch.covariance is None:
        return np.zeros(n, dtype=bool), np.zeros(n, dtype=bool), None
    axes = np.array(USED_COVARIANCE_AXES[dimensions], dtype=np.int64)
    block = np.empty((n, axes.size, axes.size))
    given, bad, flagged, decompose = (np.empty(n, dtype=np.bool_) for _ in range(4))
    _covariance_rows(np.ascontiguousarray(batch.covariance, dtype=np.float64),
                     np.ascontiguousarray(batch.covariance_size, dtype=np.int64),
                     np.ascontiguousarray(batch.remove, dtype=np.bool_), axes,
                     ValueLimits.MAX_COVARIANCE, COV_SYMMETRY_RTOL, block, given, bad, flagged,
                     decompose)
    _psd_rejected(block, decompose, flagged)
    # the core's own check decides (and words) each refusal: no row refused without its reason
    rows = np.flatnonzero(flagged)
    bad[rows] = [covariance_problem(block[k]) is not None for k in rows.tolist()]
    return bad & ~batch.remove, given & ~bad & ~batch.remove, block


def _covariance_reason(batch: StateBatch, k: int, dimensions: int) -> str | None:
    size = int(batch.covariance_size[k])
    if size not in (0, COVARIANCE_SIZE):
        return f"covariance has {size} values (expected 0 or {COVARIANCE_SIZE}: 6x6 row-major)"
    block = covariance_block(batch.covariance[k : k + 1], dimensions)[0]
    axes = "x, y, vx, vy" if dimensions == 2 else "x, y, z, vx, vy, vz"
    largest = float(np.abs(block).max())
    if largest > ValueLimits.MAX_COVARIANCE:
        return (
            f"covariance has a value of magnitude {largest:g}, "
            f"beyond {ValueLimits.MAX_COVARIANCE:g}"
            f" (rows/columns {axes})"
        )
    problem = covariance_problem(block)
    return None if problem is None else f"{problem} (rows/columns {axes})"


def _reasons(
    batch: StateBatch, k: int, frame_id: str, now_ns: int | None, dup: bool, dimensions: int = 3
) -> str:
    """Every problem of row k, in a fixed order (so the message is deterministic), "; "-joined."""
    found: list[str] = []
    if not batch.ids[k]:
        found.append("empty id")
    if dup:
        found.append("id appears more than once in the message")
    if not batch.remove[k]:  # a removal needs only id and stamp; its geometry is ignored
        r = float(batch.radius[k])
        if not np.isfinite(r):
            found.append(f"radius is {r}")
        elif r < 0.0:
            found.append(f"radius is negative ({r})")
        elif r > ValueLimits.MAX_MAGNITUDE:
            found.append(f"radius is {r}, beyond {ValueLimits.MAX_MAGNITUDE:g}")
        for name in _VECTORS:
            for axis, value in zip("xyz", getattr(batch, name)[k].tolist()):
                if not np.isfinite(value):
                    found.append(f"{name}.{axis} is {value}")
                elif abs(value) > ValueLimits.MAX_MAGNITUDE:
                    found.append(
                        f"{name}.{axis} is {value}, beyond +-{ValueLimits.MAX_MAGNITUDE:g}"
                    )
        if batch.covariance is not None:
            problem = _covariance_reason(batch, k, dimensions)
            if problem:
                found.append(problem)
        if frame_id and batch.frames[k] != frame_id:
            found.append(
                f"frame '{batch.frames[k]}' is not the scene frame '{frame_id}'"
                f" (no tf here: publish in '{frame_id}')"
            )
    stamp = int(batch.stamp_ns[k])
    if stamp == 0:
        found.append(StampHint.ZERO)
    elif stamp < 0:
        found.append(f"header.stamp is negative ({stamp * 1e-9:.9f} s)")
    elif now_ns is not None and stamp - now_ns > StampLimits.MAX_FUTURE_NS:
        found.append(f"header.stamp is {(stamp - now_ns) * 1e-9:.3f} s in the future")
    if not found:
        raise AssertionError("row flagged bad without a reason")  # masks and reasons disagree
    return "; ".join(found)


_GOOD = np.ones(1, dtype=bool)
_GOOD.flags.writeable = False
_EXACT = np.zeros(1, dtype=bool)
_EXACT.flags.writeable = False


def clean_single_state(batch: StateBatch, frame_id: str, now_ns: int | None) -> BatchCheck | None:
    """check_batch of a one-state batch without covariance that passes every check, on Python
    scalars (a per-body stream's message: the vectorised checks cost ~0.1 ms of numpy set-up);
    None when any check might fail (the general path then words the reasons)."""
    body_id, frame, stamp = batch.ids[0], batch.frames[0], int(batch.stamp_ns[0])
    if (
        not body_id
        or stamp <= 0
        or (now_ns is not None and stamp - now_ns > StampLimits.MAX_FUTURE_NS)
    ):
        return None
    if not bool(batch.remove[0]):
        limit = ValueLimits.MAX_MAGNITUDE
        r = float(batch.radius[0])
        if not 0.0 <= r <= limit:  # also false for NaN
            return None
        for vector in (batch.position, batch.velocity, batch.acceleration):
            for value in vector[0].tolist():
                if not abs(value) <= limit:
                    return None
        if frame_id and frame != frame_id:
            return None
        frame_id = frame_id or frame
    return BatchCheck(_GOOD, [], frame_id, _EXACT)


@njit(cache=True)
def _value_faults(radius, position, velocity, acceleration, remove, stamps, clock, now_ns,
                  limit, max_future_ns, bad):
    """bad[k] |= row k's values or stamp are unusable, in one pass: a state (not a removal)
    with a radius or vector component beyond +-limit, NaN included (the comparisons are false
    for it), or a negative radius; any row with a stamp <= 0 or more than max_future_ns after
    now_ns (clock False: no future check). _reasons words the same rules."""
    D = position.shape[1]
    for k in range(radius.shape[0]):
        ok = stamps[k] > 0 and not (clock and stamps[k] - now_ns > max_future_ns)
        if not remove[k]:
            # & without branches: a clean row (nearly all) runs straight through
            r = radius[k]
            ok &= (r >= 0.0) & (r <= limit)
            for d in range(D):
                ok &= ((abs(position[k, d]) <= limit) & (abs(velocity[k, d]) <= limit)
                       & (abs(acceleration[k, d]) <= limit))
        if not ok:
            bad[k] = True


class _Seen:
    """The per-id and per-frame checks of the last few id and frame tuples seen.

    state_codec.StateDecoder hands a stream's unchanged ids and frames back as the same
    tuples, so a tracker's frames pay these checks once.  Keyed by identity, a few entries,
    the least recently used evicted first (one per stream of a node with several array
    topics; one entry would make them evict each other every message); an entry holds its
    tuple, so the identity cannot be reused while it is here.  Entries are added and evicted
    whole (dict operations are atomic), so a reader on another thread sees a matching pair.
    """

    SIZE = 8
    ids: dict = {}  # id(ids) -> (ids, (dup, empty))
    frames: dict = {}  # (id(frames), frame_id) -> (frames, every frame is frame_id)

    @staticmethod
    def used(table: dict, key, entry: tuple) -> None:
        """Move a hit entry to the newest place (the oldest-used is evicted first)."""
        table.pop(key, None)
        table[key] = entry

    @classmethod
    def keep(cls, table: dict, key, entry: tuple) -> None:
        """table[key] = entry, dropping the oldest entry beyond SIZE."""
        table[key] = entry
        if len(table) > cls.SIZE:
            # the keys copied in one call: no iterator another thread's change could break
            table.pop(tuple(table)[0], None)


def _id_faults(ids) -> tuple[np.ndarray, np.ndarray]:
    """(dup, empty): per state, whether its id appears more than once, or is empty."""
    if type(ids) is tuple:
        entry = _Seen.ids.get(id(ids))
        if entry is not None and entry[0] is ids:
            _Seen.used(_Seen.ids, id(ids), entry)
            return entry[1]
    n = len(ids)
    # Per-id Python loops only where a set (C speed) shows they can find something:
    # an array of distinct, non-empty ids (the usual tracker frame) skips them.
    distinct = set(ids)
    if len(distinct) == n:
        dup = np.zeros(n, dtype=bool)
    else:
        counts = Counter(ids)
        dup = np.fromiter((counts[i] > 1 for i in ids), dtype=bool, count=n)
    if "" in distinct:
        empty = np.fromiter((not i for i in ids), dtype=bool, count=n)
    else:
        empty = np.zeros(n, dtype=bool)
    dup.flags.writeable = empty.flags.writeable = False  # shared by the frames that reuse them
    if type(ids) is tuple:
        _Seen.keep(_Seen.ids, id(ids), (ids, (dup, empty)))
    return dup, empty


def _all_in(frames, frame_id: str) -> bool:
    """Whether every frame is ``frame_id``."""
    key = (id(frames), frame_id)
    entry = _Seen.frames.get(key)
    if entry is not None and entry[0] is frames:
        _Seen.used(_Seen.frames, key, entry)
        return entry[1]
    every = frames.count(frame_id) == len(frames)
    if type(frames) is tuple:
        _Seen.keep(_Seen.frames, key, (frames, every))
    return every


def check_batch(
    batch: StateBatch, *, frame_id: str, now_ns: int | None, dimensions: int = 3
) -> BatchCheck:
    """Which states are usable.

    Parameters
    ----------
    dimensions : 2 or 3, the scene's; only the covariance rows/columns it uses are checked.
    frame_id : the scene frame; "" adopts the frame of the first otherwise-good
        state (returned in BatchCheck.frame_id).
    now_ns : receiving clock in ns for the future-stamp check; None skips it.
    """
    n = len(batch)
    if n == 0:
        return BatchCheck(np.zeros(0, dtype=bool), [], frame_id)
    if n == 1 and batch.covariance is None:
        clean = clean_single_state(batch, frame_id, now_ns)
        if clean is not None:
            return clean
    dup, empty = _id_faults(batch.ids)
    covariance_bad, uncertain, block = covariance_checks(batch, dimensions)
    bad = empty | dup | covariance_bad
    _value_faults(np.ascontiguousarray(batch.radius, dtype=np.float64),
                  *(np.ascontiguousarray(x, dtype=np.float64)
                    for x in (batch.position, batch.velocity, batch.acceleration)),
                  np.ascontiguousarray(batch.remove, dtype=np.bool_),
                  np.ascontiguousarray(batch.stamp_ns, dtype=np.int64),
                  now_ns is not None, 0 if now_ns is None else int(now_ns),
                  ValueLimits.MAX_MAGNITUDE,
                  StampLimits.MAX_FUTURE_NS, bad)
    if not frame_id:
        candidates = np.flatnonzero(~bad & ~batch.remove)
        if candidates.size:
            frame_id = batch.frames[int(candidates[0])]
    if frame_id and not _all_in(batch.frames, frame_id):  # some state in another frame
        bad |= ~batch.remove & np.fromiter(
            (f != frame_id for f in batch.frames), dtype=bool, count=n
        )
    rejections = [
        Rejection(int(k), batch.ids[k],
                  _reasons(batch, int(k), frame_id, now_ns, bool(dup[k]), dimensions))
        for k in np.flatnonzero(bad)
    ]
    return BatchCheck(~bad, rejections, frame_id, uncertain & ~bad, block)
