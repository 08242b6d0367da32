"""The one scene model: bodies of a state stream and their incrementally kept pair predictions.

The node, the `predict_collisions` service and `replay` all run on this class
(through ``pipeline.predictor.CollisionPredictor``).  Times are integer
nanoseconds (header stamps), so nothing depends on float rounding of ~1.7e18.

Stream rules (deterministic: the same calls in the same order give the same
scene, bit for bit)
----------------------------------------------------------------------------
* A body's state is replaced only by a strictly newer stamp; an older or
  equal one is ignored (late and duplicated states are harmless).
* A removal at stamp ``T`` deletes the body if its state is not newer than
  ``T`` and is remembered: a later-arriving state of that id stamped ``<= T``
  is ignored.  Removals are forgotten ``stale_timeout`` after they were
  received (receive clock), so this memory is bounded by the input rate.
* Within one ``merge`` call the removals are applied first, so ``max_bodies``
  counts the scene after them.
* Staleness is judged on the receive clock given by the caller (never read
  here): ``expire(now_ns, timeout_ns)`` drops bodies received before
  ``now_ns - timeout_ns``.
* The reference time ``R`` is the newest accepted stamp since the scene was
  last empty.  Predictions are reported relative to ``R``.

Prediction rule (what is published)
-----------------------------------
Let ``H`` be the horizon, ``S`` the slack (default ``H / 4``, in ns) and the
epoch ``E = R - (R mod S)`` (a pure function of ``R``).  Each stored state
``(p, v, a, r)`` at its own stamp ``T`` is never propagated in place.

* A pair ``(a, b)`` (``a``'s id sorts first) is evaluated at its pair time
  ``t_p = max(E, T_a, T_b)``: both states are propagated to ``t_p`` with
  ``dt = (t_p - T) * 1e-9`` s as ``p + dt (v + (dt/2) a)``, ``v + dt a``, and
  the narrow phase runs with horizon ``H + S`` giving ``tau``.
* If ``t_p == R`` the pair reports ``ttc = tau``.  Otherwise, with
  ``d = (R - t_p) * 1e-9`` (< S), it reports ``ttc = tau - d`` if
  ``tau > d``; if the contact already began before ``R`` (``tau <= d``) the
  pair is evaluated again at ``R`` with horizon ``H``.
* A pair is reported iff ``ttc <= H``; rows are sorted by ``(ttc, id_a,
  id_b)``.  ``contact_ns = t_p + round(tau * 1e9)`` (``R + round(ttc * 1e9)``
  for a pair evaluated at ``R``); a pair with ``ttc == 0`` whose propagated
  gap at ``R`` is negative is *overlapping*.

So a pair's result is a pure function of its two stored states, ``R`` and
``H``, ``S``: a one-body update re-evaluates only that body's candidate pairs
(a hashed grid of swept bounds finds them), a newer stamp that keeps the epoch
only shifts the cached times, and a rebuild happens when the epoch moves
(every ``S`` of stamp time), the horizon changes, or more than
``full_rebuild_fraction`` of the bodies changed (a tracker array moving every
body takes the vectorised full-scene path).  :meth:`Scene.full_recomputation`
applies the rule from scratch (vectorised numpy); incremental results equal it
bitwise.  Between rebuilds the sorted order of the last query is kept and
repaired rather than re-sorted, and only the pairs whose contact began before
``R`` (overlapping pairs, typically) are evaluated again at each new ``R``;
small batches run through compiled row loops that repeat the numpy
operations exactly (core/scene_kernels.py).

When every body carries the stamp ``R`` (a tracker array), ``t_p == R`` for
every pair and the result is the narrow phase on the states propagated to
``R``, i.e. ``predict_all_pairs`` on them (the narrow phase's root does not
depend on the horizon argument once the contact lies inside it).  Bodies with
older stamps are evaluated at the newer stamp of their pair and shifted, which
can differ from propagating everything to ``R`` in the last bits.

Swept bounds cover ``[max(E, T), E + S + H]``, which contains every reportable
contact until the epoch moves.
"""
from __future__ import annotations

import bisect
import math
import threading
import weakref
from dataclasses import dataclass
from functools import cached_property
from typing import Hashable, NamedTuple, Sequence

import numpy as np
from numba import njit

from circle_collision_ros.core import broad_phase as _bp
from circle_collision_ros.core import scene_kernels as _sk
from circle_collision_ros.core.pair_predictions import (
    narrow_on_pairs, validate_bodies, _check_horizon)
from circle_collision_ros.core.contact import details_on_rows

__all__ = ["Scene", "SceneContacts", "SceneSnapshot", "SceneUncertainty", "MergeResult"]


class MergeResult(NamedTuple):
    """Row indices (into the merged arrays) by outcome."""

    accepted: np.ndarray        # states stored
    not_newer: np.ndarray       # states not newer than the body's state or its removal
    full: np.ndarray            # new ids refused: max_bodies reached
    removed: np.ndarray         # removals that deleted a body
    removal_ignored: np.ndarray  # removals of unknown ids or older than the body's state


@dataclass(frozen=True)
class SceneContacts:
    """Reported pairs at ``reference_ns``, soonest first (arrays are read-only).

    id_a, id_b : body ids (id_a sorts first; gathered on first use).  ttc : s from
    reference_ns.  contact_ns : absolute contact time, ns.  overlapping : (K,) bool.
    point, normal : (K, D) m and unit.  closing_speed : (K,) m/s.
    """

    reference_ns: int
    #: the scene's ids by slot as published (the scene copies before it changes them)
    #: and each row's two slots: id_a / id_b are gathered from them when first read --
    #: the node's path encodes from id_utf8 and never reads them
    slot_ids: np.ndarray
    slot_a: np.ndarray
    slot_b: np.ndarray
    ttc: np.ndarray
    contact_ns: np.ndarray
    overlapping: np.ndarray
    point: np.ndarray
    normal: np.ndarray
    closing_speed: np.ndarray
    #: The ids as UTF-8 for encoders: ``(blob, start_a, len_a, start_b, len_b)``,
    #: row k's id_a is ``blob[start_a[k]:start_a[k] + len_a[k]]`` (None: ids not all str).
    id_utf8: tuple | None = None

    @cached_property
    def id_a(self) -> np.ndarray:
        return self.slot_ids[self.slot_a]

    @cached_property
    def id_b(self) -> np.ndarray:
        return self.slot_ids[self.slot_b]

    def __len__(self) -> int:
        return int(self.ttc.shape[0])


@dataclass(frozen=True)
class SceneUncertainty:
    """Pairs with an uncertain body that may touch within ``[R, R + H]``, evaluated at ``R``.

    Every pair with at least one uncertain body (non-zero covariance) that the broad phase,
    with radii inflated by ``core.uncertainty.inflation_radius``, cannot rule out, plus every
    such pair with a mean contact; each evaluated by ``core.uncertainty.uncertain_pairs`` on
    the states and covariances propagated to its pair time t_p (``Sigma' = M Sigma M^T``;
    t_p = R for a tracker array, within ``Scene.UNCERTAIN_LAG_NS`` before R otherwise, see
    ``Scene.uncertain_pairs``). Arrays (K,): id_a (sorts first), id_b, probability (of
    contact within [t_p, t_p + H]), probability_bound, plausible_ttc (s from R, +inf if
    never).  Rows are in (id_a, id_b) order.  Pairs of two exact bodies are never listed
    (the exact path answers them).
    """

    reference_ns: int
    id_a: np.ndarray
    id_b: np.ndarray
    probability: np.ndarray
    probability_bound: np.ndarray
    plausible_ttc: np.ndarray
    #: rows not evaluated for lack of budget (``max_evaluated``): probability 1.0, bound 1.0
    deferred: int = 0
    #: (K,) int64: each row's row in `matched` (the contacts given to uncertain_pairs) for the
    #: same pair, -1 if none; None when no contacts were given
    contact_rows: np.ndarray | None = None
    matched: SceneContacts | None = None
    #: The ids as UTF-8 for encoders, as SceneContacts.id_utf8 (None: ids not all str).
    id_utf8: tuple | None = None

    def __len__(self) -> int:
        return int(self.probability.shape[0])


@dataclass(frozen=True)
class SceneSnapshot:
    """All bodies propagated to ``reference_ns``, ordered by id; arrays (N, D) and (N,)."""

    reference_ns: int
    ids: list
    positions: np.ndarray
    velocities: np.ndarray
    accelerations: np.ndarray
    radii: np.ndarray


def _propagate_ns(P, V, A, dt_ns):
    """States moved by ``dt_ns`` (int64 ns, >= 0): ``p + dt (v + (dt/2) a)``, ``v + dt a``."""
    # Integer subtraction first (by the caller): stamps ~1.7e18 ns would lose detail as floats.
    dt = (np.asarray(dt_ns).astype(np.float64) * 1e-9)[:, None]
    return P + dt * (V + (0.5 * dt) * A), V + dt * A


@njit(cache=True, error_model="numpy", inline="always")
def _covariance_row(C, t, out):
    """A joint (position, velocity) covariance (2D, 2D) moved by t s into out: ``M C M^T``,
    ``M = [[I, t I], [0, I]]`` (acceleration is exact, so it adds no uncertainty):
    ``Spp + t (Spv + Svp) + t^2 Svv``, ``Spv + t Svv``, ``Svp + t Svv``, ``Svv``, evaluated
    in that order (the numpy block expression's operations and rounding)."""
    D = C.shape[0] // 2
    tt = t * t
    for r in range(D):
        for c in range(D):
            vv = C[D + r, D + c]
            out[r, c] = C[r, c] + t * (C[r, D + c] + C[D + r, c]) + tt * vv
            out[r, D + c] = C[r, D + c] + t * vv
            out[D + r, c] = C[D + r, c] + t * vv
            out[D + r, D + c] = vv


@njit(cache=True)
def _store_covariances(C, slots, cov, rows, nonzero):
    """C[slots[j]] = cov[rows[j]] and nonzero[j] = whether it has a non-zero entry (an
    uncertain body), in one pass."""
    for j in range(slots.shape[0]):
        out, src = C[slots[j]], cov[rows[j]]
        any_ = False
        for r in range(src.shape[0]):
            for c in range(src.shape[1]):
                x = src[r, c]
                out[r, c] = x
                if x != 0.0:
                    any_ = True
        nonzero[j] = any_


@njit(cache=True, error_model="numpy")
def _states_at_rows(P, V, A, C, T, U, slots, t_ns, p, v, c):
    """The stored bodies `slots` moved from their stamps T to t_ns[j] (int64 ns), in one
    compiled pass: p, v as _propagate_ns, c as _covariance_row for an uncertain body
    (U) and zero for an exact one (its stored covariance may be stale).  The same
    operations in the same order as those numpy expressions (no fast-math: no
    contraction into fused multiply-adds), so the same bits."""
    D = P.shape[1]
    for j in range(slots.shape[0]):
        s = slots[j]
        dt = np.float64(t_ns[j] - T[s]) * 1e-9  # integer difference first (stamps ~1.7e18 ns)
        for k in range(D):
            p[j, k] = P[s, k] + dt * (V[s, k] + (0.5 * dt) * A[s, k])
            v[j, k] = V[s, k] + dt * A[s, k]
        if U[s]:
            _covariance_row(C[s], dt, c[j])
        else:
            c[j] = 0.0


_EMPTY_I = np.empty(0, dtype=np.int64)
_NEVER = 1 << 62  # later than any receive time, ns
_FIRST_ROW = np.zeros(1, dtype=np.int64)
_FIRST_ROW.flags.writeable = False
# The empty columns of an exact scene's SceneUncertainty (published read-only, shared).
_NO_IDS = np.empty(0, dtype=object)
_NO_VALUES = np.empty(0)
_NO_IDS.flags.writeable = False
_NO_VALUES.flags.writeable = False


class Scene:
    """Bodies keyed by id (mutually orderable, e.g. str) with incrementally kept predictions.

    Parameters
    ----------
    horizon : s, finite > 0.   dim : 2 or 3.
    slack : s (default horizon / 4): epoch length; trades bound size against
        how often the whole scene is rebuilt.
    max_bodies : new ids beyond this many are refused (None: no limit).
    method : broad phase of full rebuilds ("sweep" or "grid").
    full_rebuild_fraction : above this fraction of changed bodies, one
        vectorised rebuild replaces per-body updates.
    """

    #: Uncertain pairs: how far (ns) a pair's time t_p may lie before R (see uncertain_pairs).
    #: A pair whose newer state is older than this is evaluated at the start of R's period of
    #: this length, so such pairs are evaluated again once per period, not per input.
    UNCERTAIN_LAG_NS = 100_000_000

    def __init__(self, horizon: float, dim: int = 2, *, slack: float | None = None,
                 max_bodies: int | None = None, method: str = "sweep",
                 full_rebuild_fraction: float = 0.05) -> None:
        if dim not in (2, 3):
            raise ValueError(f"dim must be 2 or 3, got {dim}")
        if method not in ("sweep", "grid"):
            raise ValueError(f"unknown broad-phase method {method!r}")
        self._dim = dim
        self._method = method
        self._full_frac = float(full_rebuild_fraction)
        self.max_bodies = max_bodies
        self._slack_arg = slack
        self._set_horizon(horizon)
        self.clear()

    def _set_horizon(self, horizon: float) -> None:
        self._h = _check_horizon(horizon)
        slack = self._h / 4.0 if self._slack_arg is None else float(self._slack_arg)
        if not (math.isfinite(slack) and slack > 0.0):
            raise ValueError(f"slack must be finite and > 0, got {slack!r}")
        self._slack_ns = max(1, int(round(slack * 1e9)))
        self._h_eval = self._h + self._slack_ns * 1e-9  # narrow-phase horizon at t_p

    def set_horizon(self, horizon: float) -> None:
        """Change the horizon (s); the next query rebuilds every pair."""
        if float(horizon) != self._h:
            self._set_horizon(horizon)
            self._need_full = True
            self._version += 1

    # ------------------------------------------------------------------ basics
    def clear(self) -> None:
        """Forget every body, every remembered removal and the reference time."""
        cap = 16
        D = self._dim
        self._P = np.zeros((cap, D))
        self._V = np.zeros((cap, D))
        self._A = np.zeros((cap, D))
        self._R = np.zeros(cap)
        self._C = np.zeros((cap, 2 * D, 2 * D))      # covariance of (p, v) at the stamp
        self._U = np.zeros(cap, dtype=bool)           # covariance not all zero (an uncertain body)
        self._n_uncertain = 0                         # alive slots with _U set (see _set_uncertain)
        self._T = np.zeros(cap, dtype=np.int64)      # stamp, ns
        self._Tf = np.zeros(cap)                      # (T - E) s, for the broad phase
        self._recv = np.zeros(cap, dtype=np.int64)   # receive clock, ns
        self._lo = np.zeros((cap, D))
        self._hi = np.zeros((cap, D))
        self._alive = np.zeros(cap, dtype=bool)
        self._ids = np.full(cap, None, dtype=object)
        self._ids_published = False  # a SceneContacts reads _ids: copy it before a change
        self._rank = np.full(cap, -1, dtype=np.int64)
        # Each id's UTF-8 bytes in an append-only blob (published contacts keep
        # referring to the blob of their time; growth and compaction copy).
        self._id_start = np.zeros(cap, dtype=np.int64)
        self._id_len = np.zeros(cap, dtype=np.int64)
        self._utf8 = np.zeros(1024, dtype=np.uint8)
        self._utf8_n = 0
        self._utf8_ok = True  # every id seen since clear() is a str
        self._okeys: list = []
        self._rank_ok = True
        self._rank_serial = getattr(self, "_rank_serial", 0) + 1  # bumped whenever _rank changes
        # bumped when live ids move in the blob (today that comes with new ids, so with new
        # ranks too; the serial keeps _rids' validity independent of that)
        self._utf8_serial = getattr(self, "_utf8_serial", 0) + 1
        self._rkey_basis = None  # (_rank_serial, slot capacity, _utf8_serial) of _rkey, _rids
        self._order = None  # alive slots in id order (cached until membership changes)
        self._slot: dict = {}
        self._free: list[int] = list(range(cap - 1, -1, -1))
        self._removals: dict = {}  # id -> (removal stamp ns, received ns)
        self._dirty: set[int] = set()
        self._need_full = True
        self._cell = 1.0
        self._grid_built = False
        self._n_new = 0
        self.reference_ns: int | None = None
        self._epoch: int | None = None
        # Lower bounds of the receive times of the bodies / remembered removals: expire scans
        # only when its limit passes them (once per stale_timeout of a steady stream, not per call).
        self._recv_floor = _NEVER
        self._removal_floor = _NEVER
        self._rhead = np.full(cap, -1, dtype=np.int64)  # each slot's newest record (see _REC)
        self._clear_records()
        self._version = getattr(self, "_version", 0) + 1
        self._cache = None
        self.evaluated_pairs = 0  # narrow-phase pair evaluations of the last predictions() call
        self._captures = weakref.WeakSet()  # live captures sharing the state arrays
        self._uncertain_cache = None
        self._uncertain_serial = 0     # uncertain_pairs evaluations so far (the budget's clock)
        self._uncertain_waiting = _NO_WAITING  # the deferred pairs and since when they wait
        self._uncertain_memo = {}      # core.uncertainty.uncertain_pairs(memo=...): last full evaluations
        self._uncertain_memo_ref = None  # the reference time of those evaluations
        self._pair_answers = None      # _PairAnswers of the last uncertain_pairs call
        self.uncertain_evaluated = 0   # pairs the last uncertain_pairs call gave the core
        self._sv = np.zeros(cap, dtype=np.int64)  # each slot's state serial (bumped per change)
        self._sv_next = 1
        self._born = np.zeros(cap, dtype=np.int64)  # each slot's body serial (set when a body takes it)
        self._born_next = 1

    # Pair records: one row per pair with a contact within H + S of its t_p, in
    # growable buffers; rows of updated bodies are marked dead (compacted when
    # dead rows dominate) so an update touches O(its pairs) rows.  Each slot's
    # records form a linked list (_rhead[slot], _rnext[row, 0 for a / 1 for b])
    # so an update finds its rows without a scan of all records.
    # Each record also keeps its two bodies' stored states (_rsP, _rsV, _rsA: (rows, 2, D),
    # _rsR, _rsT: (rows, 2)), equal to the scene's while it lives (a state change kills the
    # body's records): a pair evaluated again at each new R reads them in record order.
    _REC = ("_ra", "_rb", "_rtp", "_rtau", "_rpt", "_rnm", "_rcs", "_rov", "_rkey", "_rids",
            "_rsP", "_rsV", "_rsA", "_rsR", "_rsT")

    def _clear_records(self, cap: int = 256) -> None:
        D = self._dim
        self._ra = np.zeros(cap, dtype=np.int64)
        self._rb = np.zeros(cap, dtype=np.int64)
        self._rtp = np.zeros(cap, dtype=np.int64)  # pair time t_p, ns
        self._rtau = np.zeros(cap)                  # narrow-phase time from t_p, s
        self._rpt = np.zeros((cap, D))
        self._rnm = np.zeros((cap, D))
        self._rcs = np.zeros(cap)
        self._rov = np.zeros(cap, dtype=bool)      # overlapping at t_p (tau == 0, gap < 0)
        # pair key (rank_a * slots + rank_b, the sort key after ttc) and the ids' places in
        # the UTF-8 blob (start_a, len_a, start_b, len_b): current for records below _rkey_n
        # while the ranks, the slot capacity and the blob layout are those of _rkey_basis
        self._rkey = np.zeros(cap, dtype=np.int64)
        self._rids = np.zeros((cap, 4), dtype=np.int64)
        self._rkey_n = 0
        self._rsP = np.zeros((cap, 2, D))
        self._rsV = np.zeros((cap, 2, D))
        self._rsA = np.zeros((cap, 2, D))
        self._rsR = np.zeros((cap, 2))
        self._rsT = np.zeros((cap, 2), dtype=np.int64)
        self._rlive = np.zeros(cap, dtype=bool)
        self._rnext = np.full((cap, 2), -1, dtype=np.int64)
        self._rhead[:] = -1
        self._rn = 0
        self._rdead = 0
        self._new_rows: list[np.ndarray] = []
        # The last query's order (see _ordered_rows): records not past at its
        # reference time, sorted by (ttc, id_a, id_b), with their ttc; and the
        # past records (contact began before it: evaluated at R each query).
        self._fut = None
        self._fut_ttc = None
        self._past = _EMPTY_I
        # Records stored in pair order (a rebuild), not in the kept order: the next query
        # compacts them into it (see _compact).
        self._records_scattered = True

    @property
    def horizon(self) -> float:
        return self._h

    @property
    def slack(self) -> float:
        return self._slack_ns * 1e-9

    @property
    def epoch_ns(self) -> int | None:
        """E = R - (R mod S), or None for an empty scene."""
        r = self.reference_ns
        return None if r is None else r - r % self._slack_ns

    @property
    def dim(self) -> int:
        return self._dim

    def __len__(self) -> int:
        return len(self._slot)

    def __contains__(self, body_id: Hashable) -> bool:
        return body_id in self._slot

    @property
    def remembered_removals(self) -> int:
        """How many removals are remembered (bounded by expire)."""
        return len(self._removals)

    def ids(self) -> list:
        """Body ids, sorted."""
        self._ensure_rank()
        return list(self._okeys)

    def _ensure_rank(self) -> None:
        if self._rank_ok:
            return
        slots = np.flatnonzero(self._alive)
        ids = self._ids
        order = sorted(slots.tolist(), key=ids.__getitem__)
        self._okeys = [ids[x] for x in order]
        self._rank[:] = -1
        self._rank[np.array(order, dtype=np.int64)] = np.arange(len(order))
        self._rank_ok = True
        self._rank_serial += 1

    def _rank_insert(self, s: int) -> None:
        self._order = None
        if not self._rank_ok:
            return
        if len(self._okeys) > 64 and self._n_new > 32:
            self._rank_ok = False  # bulk insert: cheaper to re-sort once
            return
        pos = bisect.bisect_left(self._okeys, self._ids[s])
        self._okeys.insert(pos, self._ids[s])
        self._rank[self._rank >= pos] += 1
        self._rank[s] = pos
        self._rank_serial += 1

    def _rank_remove(self, s: int) -> None:
        self._order = None
        if not self._rank_ok:
            return
        pos = int(self._rank[s])
        del self._okeys[pos]
        self._rank[self._rank > pos] -= 1
        self._rank[s] = -1
        self._rank_serial += 1

    def _sorted_slots(self) -> np.ndarray:
        if self._order is None:
            self._ensure_rank()
            slots = np.flatnonzero(self._alive)
            self._order = slots[np.argsort(self._rank[slots])]
        return self._order

    # ---------------------------------------------------------------- updates
    def merge(self, ids: Sequence[Hashable], stamps_ns, positions, velocities, accelerations,
              radii, remove, received_ns: int, covariances=None) -> MergeResult:
        """Apply one message: removals first, then states (rules in the module docstring).

        ids : k distinct ids.  stamps_ns : (k,) int ns > 0.  positions, velocities,
        accelerations : (k, >= dim) (extra columns ignored).  radii : (k,).
        remove : (k,) bool; a removal's geometry is ignored.  received_ns : the
        receive clock for expiry.  Rows must be valid (finite, radius >= 0).
        covariances : None (all exact) or (k, 2 dim, 2 dim) joint covariances of
        (position, velocity), symmetric PSD (all zero = exact); see uncertain_pairs.
        """
        if len(ids) == 1 and covariances is None and not remove[0]:
            return self._merge_state(ids[0], int(stamps_ns[0]), positions, velocities, accelerations,
                                     radii, int(received_ns))
        stamps = np.asarray(stamps_ns, dtype=np.int64)
        remove = np.asarray(remove, dtype=bool)
        received_ns = int(received_ns)
        removed, removal_ignored = [], []
        for k in np.flatnonzero(remove).tolist():
            bid, st = ids[k], int(stamps[k])
            s = self._slot.get(bid)
            if s is not None and st < self._T[s]:
                removal_ignored.append(k)  # the body's state is newer than the removal
                continue
            old = self._removals.get(bid)
            if old is None or st >= old[0]:
                self._removals[bid] = (st, received_ns)
                self._removal_floor = min(self._removal_floor, received_ns)
            if s is None:
                removal_ignored.append(k)
            else:
                self._drop(s)
                removed.append(k)
        rows = np.flatnonzero(~remove)
        D = self._dim
        get = self._slot.get
        slots = np.fromiter((get(ids[k], -1) for k in rows.tolist()), dtype=np.int64, count=rows.size)
        st = stamps[rows]
        known = slots >= 0
        newer = np.ones(rows.size, dtype=bool)
        newer[known] = st[known] > self._T[slots[known]]
        if self._removals:
            for x in np.flatnonzero(~known).tolist():
                gone = self._removals.get(ids[rows[x]])
                if gone is not None:
                    if st[x] <= gone[0]:
                        newer[x] = False  # older than its removal: a late state of a removed body
                    else:
                        del self._removals[ids[rows[x]]]
        fresh = np.flatnonzero(~known & newer)
        room = len(fresh) if self.max_bodies is None else max(0, self.max_bodies - len(self._slot))
        full = fresh[room:]
        fresh = fresh[:room]
        self._n_new = int(fresh.size)
        for x in fresh.tolist():
            s = self._alloc()
            self._preserve((s,))
            bid = ids[rows[x]]
            self._slot[bid] = s
            self._writable_ids()[s] = bid
            self._alive[s] = True
            self._rank_insert(s)
            slots[x] = s
        if fresh.size:
            self._add_utf8(slots[fresh])
        take = newer.copy()
        take[full] = False
        sl, src = slots[take], rows[take]
        if src.size:
            self._preserve(sl)
            self._P[sl] = np.asarray(positions)[src, :D]
            self._V[sl] = np.asarray(velocities)[src, :D]
            self._A[sl] = np.asarray(accelerations)[src, :D]
            self._R[sl] = np.asarray(radii)[src]
            if covariances is None:
                self._set_uncertain(sl, False)
            else:
                nonzero = np.empty(sl.size, dtype=np.bool_)
                _store_covariances(self._C, sl, np.ascontiguousarray(covariances, dtype=np.float64), src, nonzero)
                self._set_uncertain(sl, nonzero)
            self._T[sl] = stamps[src]
            self._recv[sl] = received_ns
            self._recv_floor = min(self._recv_floor, received_ns)
            self._dirty.update(sl.tolist())
            newest = int(stamps[src].max())
            if self.reference_ns is None or newest > self.reference_ns:
                self.reference_ns = newest
        if src.size or removed:
            self._version += 1
        return MergeResult(accepted=src, not_newer=rows[~newer], full=rows[full],
                           removed=np.array(removed, dtype=np.int64),
                           removal_ignored=np.array(removal_ignored, dtype=np.int64))

    def _merge_state(self, bid, stamp: int, positions, velocities, accelerations, radii,
                     received_ns: int) -> MergeResult:
        """merge of one exact state (a per-body stream's message) on scalars: the same rules
        and stored bits as the general path, without its array set-up."""
        s = self._slot.get(bid)
        if s is None:
            gone = self._removals.get(bid) if self._removals else None
            if gone is not None:
                if stamp <= gone[0]:
                    return MergeResult(_EMPTY_I, _FIRST_ROW, _EMPTY_I, _EMPTY_I, _EMPTY_I)  # a late state of a removed body
                del self._removals[bid]
            if self.max_bodies is not None and len(self._slot) >= self.max_bodies:
                return MergeResult(_EMPTY_I, _EMPTY_I, _FIRST_ROW, _EMPTY_I, _EMPTY_I)
            s = self._alloc()
            self._preserve((s,))
            self._slot[bid] = s
            self._writable_ids()[s] = bid
            self._alive[s] = True
            self._n_new = 1
            self._rank_insert(s)
            self._add_utf8(np.array([s], dtype=np.int64))
        elif stamp <= self._T[s]:
            return MergeResult(_EMPTY_I, _FIRST_ROW, _EMPTY_I, _EMPTY_I, _EMPTY_I)
        else:
            self._preserve((s,))
            self._n_new = 0
        D = self._dim
        self._P[s] = np.asarray(positions)[0, :D]
        self._V[s] = np.asarray(velocities)[0, :D]
        self._A[s] = np.asarray(accelerations)[0, :D]
        self._R[s] = np.asarray(radii)[0]
        if self._U[s]:
            self._set_uncertain(s, False)
        self._T[s] = stamp
        self._recv[s] = received_ns
        self._recv_floor = min(self._recv_floor, received_ns)
        self._dirty.add(s)
        if self.reference_ns is None or stamp > self.reference_ns:
            self.reference_ns = stamp
        self._version += 1
        return MergeResult(_FIRST_ROW, _EMPTY_I, _EMPTY_I, _EMPTY_I, _EMPTY_I)

    def upsert_many(self, ids: Sequence[Hashable], positions, velocities, accelerations, radii,
                    stamps_ns, received_ns: int = 0) -> MergeResult:
        """Validated ``merge`` of states only (ValueError names bad rows; then nothing changes)."""
        ids = list(ids)
        p, v, a, r = validate_bodies(positions, velocities, accelerations, radii)
        st = np.broadcast_to(np.asarray(stamps_ns, dtype=np.int64), (len(ids),))
        if p.shape != (len(ids), self._dim):
            raise ValueError(f"expected {len(ids)} rows of dimension {self._dim}, got {p.shape}")
        if len(set(ids)) != len(ids):
            raise ValueError("duplicate ids in one update")
        return self.merge(ids, st, p, v, a, r, np.zeros(len(ids), dtype=bool), received_ns)

    def upsert(self, body_id: Hashable, p, v, a, r: float, stamp_ns: int,
               received_ns: int = 0) -> MergeResult:
        """One body's state (see upsert_many)."""
        return self.upsert_many([body_id], np.asarray(p, dtype=np.float64)[None],
                                np.asarray(v, dtype=np.float64)[None],
                                np.asarray(a, dtype=np.float64)[None], [r], [stamp_ns], received_ns)

    def remove(self, body_id: Hashable, stamp_ns: int, received_ns: int = 0) -> bool:
        """A removal at ``stamp_ns``; True if it deleted the body."""
        res = self.merge([body_id], [stamp_ns], np.zeros((1, 3)), np.zeros((1, 3)), np.zeros((1, 3)),
                         [0.0], [True], received_ns)
        return bool(res.removed.size)

    def expire(self, now_ns: int, timeout_ns: int) -> list:
        """Drop bodies (and remembered removals) received before ``now_ns - timeout_ns``; ids dropped, sorted."""
        limit = int(now_ns) - int(timeout_ns)
        if self._removals and limit > self._removal_floor:
            self._removals = {k: v for k, v in self._removals.items() if v[1] >= limit}
            self._removal_floor = min((v[1] for v in self._removals.values()), default=_NEVER)
        if limit <= self._recv_floor:
            return []  # every body was received at or after the floor
        stale = np.flatnonzero(self._alive & (self._recv < limit))
        kept = self._alive & (self._recv >= limit)
        self._recv_floor = int(self._recv[kept].min()) if kept.any() else _NEVER
        gone = sorted(self._ids[s] for s in stale.tolist())
        for s in stale.tolist():
            self._drop(s)
        if gone:
            self._version += 1
        return gone

    def _drop(self, s: int) -> None:
        self._preserve((s,))
        del self._slot[self._ids[s]]
        self._rank_remove(s)
        self._writable_ids()[s] = None
        self._alive[s] = False
        self._set_uncertain(s, False)
        self._dirty.add(s)
        self._free.append(s)
        self._version += 1
        if not self._slot:
            # Nothing left to propagate: forget the reference time, else after a tracker's
            # clock reset (stamps jump back) new bodies would be propagated into the old
            # future (tests/reliability/test_faults_clock.py::test_stamps_jump_backwards).
            self.reference_ns = None
            self._need_full = True

    def _set_uncertain(self, slots, flags) -> None:
        """_U[slots] = flags, counting the uncertain bodies: an exact scene skips the
        uncertain query in O(1) instead of a pass over every slot."""
        before = int(np.count_nonzero(self._U[slots]))
        self._U[slots] = flags
        self._n_uncertain += int(np.count_nonzero(self._U[slots])) - before

    def _writable_ids(self) -> np.ndarray:
        """_ids, first copied if a published SceneContacts reads from it (copy on write: a
        stream that keeps its bodies never copies, and a prediction never gathers its ids
        unless they are read)."""
        if self._ids_published:
            self._ids = self._ids.copy()
            self._ids_published = False
        return self._ids

    def _alloc(self) -> int:
        if not self._free:
            old = self._R.shape[0]
            new = 2 * old
            for name in ("_P", "_V", "_A", "_lo", "_hi"):
                grown = np.zeros((new, self._dim))
                grown[:old] = getattr(self, name)
                setattr(self, name, grown)
            grown = np.zeros((new,) + self._C.shape[1:])
            grown[:old] = self._C
            self._C = grown
            for name, dt in (("_R", np.float64), ("_T", np.int64), ("_Tf", np.float64),
                             ("_recv", np.int64), ("_alive", bool), ("_rank", np.int64),
                             ("_id_start", np.int64), ("_id_len", np.int64), ("_U", bool),
                             ("_sv", np.int64), ("_born", np.int64)):
                grown = np.full(new, -1 if name == "_rank" else 0, dtype=dt)
                grown[:old] = getattr(self, name)
                setattr(self, name, grown)
            ids = np.full(new, None, dtype=object)
            ids[:old] = self._ids
            self._ids = ids
            self._ids_published = False
            head = np.full(new, -1, dtype=np.int64)
            head[:old] = self._rhead
            self._rhead = head
            if self._grid_built:
                stale = np.ones(new, dtype=bool)  # new slots are in no static cell
                stale[:old] = self._gstale
                self._gstale = stale
                inmoved = np.zeros(new, dtype=bool)
                inmoved[:old] = self._inmoved
                self._inmoved = inmoved
                moved = np.empty(new, dtype=np.int64)
                moved[:old] = self._moved
                self._moved = moved
            self._free = list(range(new - 1, old - 1, -1))
        s = self._free.pop()
        self._born[s] = self._born_next
        self._born_next += 1
        return s

    def _add_utf8(self, slots: np.ndarray) -> None:
        """Append the UTF-8 bytes of the ids of new `slots` to the id blob."""
        names = self._ids[slots].tolist()
        if not self._utf8_ok or not all(type(x) is str for x in names):
            self._utf8_ok = False
            return
        joined = "".join(names)
        if joined.isascii():
            lengths = np.fromiter(map(len, names), dtype=np.int64, count=len(names))
            data = joined.encode("ascii")
        else:
            encoded = [x.encode() for x in names]
            lengths = np.fromiter(map(len, encoded), dtype=np.int64, count=len(names))
            data = b"".join(encoded)
        n, k = self._utf8_n, len(data)
        if n + k > self._utf8.shape[0]:
            live = np.flatnonzero(self._alive)
            live = live[~np.isin(live, slots)]
            used = int(self._id_len[live].sum())
            if n > 2 * used + 4096:  # mostly ids of removed bodies: keep only the live ones
                blob = np.zeros(max(1024, 2 * (used + k)), dtype=np.uint8)
                pos = 0
                for s in live.tolist():
                    m = int(self._id_len[s])
                    blob[pos:pos + m] = self._utf8[self._id_start[s]:self._id_start[s] + m]
                    self._id_start[s] = pos
                    pos += m
                n = pos
                self._utf8_serial += 1
            else:
                blob = np.zeros(max(1024, 2 * (n + k)), dtype=np.uint8)
                blob[:n] = self._utf8[:n]
            self._utf8 = blob
        self._utf8[n:n + k] = np.frombuffer(data, dtype=np.uint8)
        starts = np.empty(len(names), dtype=np.int64)
        starts[0] = n
        np.cumsum(lengths[:-1], out=starts[1:])
        starts[1:] += n
        self._id_start[slots] = starts
        self._id_len[slots] = lengths
        self._utf8_n = n + k

    # ------------------------------------------------------------------ states
    def snapshot(self) -> SceneSnapshot:
        """Every body propagated to the reference time, ordered by id."""
        return self.capture().snapshot()

    def capture(self) -> "_Capture":
        """The stored states as of now, for a snapshot on demand (markers).

        Free while the scene is unchanged: the capture shares the scene's
        arrays, and a row about to change while the capture is still
        referenced is copied into it first (an update costs O(its rows), not a
        copy of the scene; a capture with many changed rows takes a private
        copy of everything and is no longer tracked).
        """
        cap = _Capture(self.reference_ns or 0, self._sorted_slots(), self._ids, self._P, self._V,
                       self._A, self._R, self._T)
        self._captures.add(cap)
        return cap

    def _preserve(self, slots) -> None:
        """Before rows `slots` change: live captures keep their values (copy on write, per row);
        the rows get new state serials (uncertain_pairs' per-pair answers key on them)."""
        k = len(slots)
        self._sv[np.asarray(slots, dtype=np.int64)] = np.arange(self._sv_next, self._sv_next + k)
        self._sv_next += k
        if self._captures:
            for cap in list(self._captures):
                if not cap.preserve(slots):
                    self._captures.discard(cap)  # it took a private copy of everything

    def stored_states(self):
        """``(ids, P, V, A, R, T_ns)`` exactly as stored, ids sorted."""
        sl = self._sorted_slots()
        return ([self._ids[s] for s in sl.tolist()], self._P[sl].copy(), self._V[sl].copy(),
                self._A[sl].copy(), self._R[sl].copy(), self._T[sl].copy())

    # ------------------------------------------------------------ pair engine
    def _bounds(self, slots: np.ndarray):
        """Swept bounds over ``[max(E, T), E + S + H]`` (relative to each state's stamp)."""
        E = self._epoch
        tr = self._T[slots]
        t0 = (np.maximum(E, tr) - tr).astype(np.float64) * 1e-9
        t1 = (E + self._slack_ns - tr).astype(np.float64) * 1e-9 + self._h
        return t0, t1

    def _set_bounds(self, slots: np.ndarray) -> None:
        """self._lo/_hi[slots] = the swept bounds (few slots: compiled, bitwise the same)."""
        t0, t1 = self._bounds(slots)
        if slots.size <= 64:
            _sk.swept_bound_rows(self._P, self._V, self._A, self._R, slots, t0, t1, self._lo, self._hi)
        else:
            self._lo[slots], self._hi[slots] = _bp.swept_bounds(
                self._P[slots], self._V[slots], self._A[slots], self._R[slots], t0, t1)

    #: Below this many pairs the compiled row loop (scene_kernels.evaluate_rows) beats the
    #: vectorised batch (numpy set-up costs ~0.3 ms a call); both give the same bits.
    _COMPILED_ROWS = 4096

    def _evaluate(self, A: np.ndarray, B: np.ndarray, t_eval: np.ndarray, horizon: float,
                  compiled: bool | None = None):
        """Narrow phase + details for slot pairs (A[k], B[k]) at t_eval (ns); the hits
        ``(hit, t_eval, tau, point, normal, closing, overlapping)``.

        compiled : None picks by size; False forces the vectorised numpy path
            (full_recomputation, the reference the compiled path is tested against).
        """
        n = A.shape[0]
        if compiled is None:
            compiled = n < self._COMPILED_ROWS
        if compiled:
            D = self._dim
            tau, pt, nm = np.empty(n), np.empty((n, D)), np.empty((n, D))
            cs, ov = np.empty(n), np.empty(n, dtype=bool)
            self.evaluated_pairs += _sk.evaluate_rows(self._P, self._V, self._A, self._R, self._T, A, B,
                                                      t_eval, horizon, tau, pt, nm, cs, ov)
            hit = tau <= horizon
            if hit.all():
                return hit, t_eval, tau, pt, nm, cs, ov
            h = np.flatnonzero(hit)
            return hit, t_eval[h], tau[h], pt[h], nm[h], cs[h], ov[h]
        pa, va = _propagate_ns(self._P[A], self._V[A], self._A[A], t_eval - self._T[A])
        pb, vb = _propagate_ns(self._P[B], self._V[B], self._A[B], t_eval - self._T[B])
        aa, ab, ra, rb = self._A[A], self._A[B], self._R[A], self._R[B]
        tau = narrow_on_pairs(pa, va, aa, ra, pb, vb, ab, rb, horizon)
        self.evaluated_pairs += int(tau.shape[0])
        hit = tau <= horizon
        h = np.flatnonzero(hit)
        pt, nm, cs = details_on_rows(pa[h], va[h], aa[h], ra[h], pb[h], vb[h], ab[h], tau[h])
        ov = np.zeros(h.size, dtype=bool)
        z = np.flatnonzero(tau[h] == 0.0)
        if z.size:
            hz = h[z]
            ov[z] = np.linalg.norm(pa[hz] - pb[hz], axis=1) - (ra[hz] + rb[hz]) < 0.0
        return hit, t_eval[h], tau[h], pt, nm, cs, ov

    def _evaluate_at_tp(self, A, B, compiled: bool | None = None):
        t_p = np.maximum(self._epoch, np.maximum(self._T[A], self._T[B]))
        return self._evaluate(A, B, t_p, self._h_eval, compiled)

    def _pairs_full(self):
        """All candidate slot pairs (a before b by id), from scratch; sets bounds."""
        slots = self._sorted_slots()
        if slots.size:
            self._Tf[slots] = (self._T[slots] - self._epoch).astype(np.float64) * 1e-9
            self._set_bounds(slots)
        if slots.size < 2:
            return slots, _EMPTY_I, _EMPTY_I
        I, J, _ = _bp.candidate_pairs(
            self._lo[slots], self._hi[slots], p=self._P[slots], v=self._V[slots], a=self._A[slots],
            r=self._R[slots], tref=self._Tf[slots], t_start=0.0,
            t_end=self._slack_ns * 1e-9 + self._h, method=self._method)
        return slots, slots[I], slots[J]  # local order is id order and I < J

    def _store(self, A, B, res) -> None:
        hit, tp, tau, pt, nm, cs, ov = res
        k = tp.shape[0]
        n = self._reserve_records(k)
        sl = slice(n, n + k)
        if not hit.all():
            A, B = A[hit], B[hit]
        self._ra[sl] = A
        self._rb[sl] = B
        for j, S in enumerate((A, B)):
            self._rsP[sl, j] = self._P[S]
            self._rsV[sl, j] = self._V[S]
            self._rsA[sl, j] = self._A[S]
            self._rsR[sl, j] = self._R[S]
            self._rsT[sl, j] = self._T[S]
        self._rtp[sl] = tp
        self._rtau[sl] = tau
        self._rpt[sl] = pt
        self._rnm[sl] = nm
        self._rcs[sl] = cs
        self._rov[sl] = ov
        self._rlive[sl] = True
        _sk.link_records(self._ra, self._rb, self._rnext, self._rhead, n, n + k)
        self._rn = n + k
        self._new_rows.append(np.arange(n, n + k))

    def _reserve_records(self, k: int) -> int:
        """Room for k more records (compacting or growing the buffers); the first free row."""
        n = self._rn
        if n + k > self._rlive.shape[0]:
            self._compact(max(256, 2 * (int(np.count_nonzero(self._rlive[:n])) + k)))
        return self._rn

    def _compact(self, cap: int | None = None) -> None:
        """Drop dead records and store the live ones in the kept order (then the past
        records, then the rest): each query walks the kept order and reads its rows' records,
        so it then streams through them instead of jumping (row numbers change: the kept
        order is renumbered)."""
        n = self._rn
        alive = self._rlive[:n]
        if self._fut is None:
            live = np.flatnonzero(alive)
        else:
            kept = self._fut[alive[self._fut]]
            past = self._past[alive[self._past]]
            placed = np.zeros(n, dtype=bool)
            placed[kept] = True
            placed[past] = True
            live = np.concatenate([kept, past, np.flatnonzero(alive & ~placed)])
        old = [getattr(self, name)[live] for name in self._REC]
        renumber = np.full(n, -1, dtype=np.int64)
        renumber[live] = np.arange(live.size)
        fut, fut_ttc, past = self._fut, self._fut_ttc, self._past
        new_rows = [renumber[r] for r in self._new_rows]
        keys_current = self._rkey_n >= n
        self._clear_records(max(256, 2 * live.size) if cap is None else cap)
        self._records_scattered = fut is None
        self._rkey_n = live.size if keys_current else 0  # renumbered: all or nothing
        for name, arr in zip(self._REC, old):
            getattr(self, name)[:live.size] = arr
        self._rlive[:live.size] = True
        _sk.link_records(self._ra, self._rb, self._rnext, self._rhead, 0, live.size)
        self._rn = live.size
        self._new_rows = [r[r >= 0] for r in new_rows]
        if fut is not None:
            f = renumber[fut]
            keep = f >= 0
            self._fut, self._fut_ttc = f[keep], fut_ttc[keep]
            p = renumber[past]
            self._past = p[p >= 0]

    def _kill_rows(self, slots: np.ndarray) -> None:
        """Mark the records of `slots` dead (walks their lists: O(their records))."""
        if self._rn and slots.size:
            self._rdead += int(_sk.kill_records(slots, self._ra, self._rnext, self._rhead, self._rlive))

    def _rebuild_all(self) -> None:
        self._clear_records()
        _, A, B = self._pairs_full()
        self._store(A, B, self._evaluate_at_tp(A, B))
        self._grid_built = False  # rebuilt lazily when a small update needs it
        self._dirty.clear()
        self._need_full = False

    # Grid for per-body neighbour queries: a static part (sorted hashed cell keys -> slots,
    # built vectorised) whose entries of updated/removed slots are masked stale, plus the
    # slots changed since the build ("moved"), which every query tests directly: fewer than
    # _MOVED_FRACTION of the bodies, so a compiled scan of their bounds costs microseconds
    # where a hashed overlay cost a Python dict walk per update.
    _MOVED_FRACTION = 8  # rebuild the static grid when more than n / this have moved

    def _build_grid(self) -> None:
        slots = np.flatnonzero(self._alive)
        if slots.size:
            self._cell, _ = _bp.choose_cell_size(self._lo[slots], self._hi[slots])
        keys, owner, big = _bp.cell_keys(self._lo[slots], self._hi[slots], self._cell,
                                         _bp._MAX_CELLS_PER_BODY)
        # Any order within a cell will do: a query sorts and dedups the pairs it collects
        # (incremental_pairs), so quicksort (0.4 ms at 31,000 keys; stable: 1.9 ms).
        o = np.argsort(keys)
        self._gkeys = keys[o]
        self._gslot = slots[owner[o]]
        cap = self._R.shape[0]
        self._gstale = np.zeros(cap, dtype=bool)
        self._gbig = slots[big]
        self._moved = np.empty(cap, dtype=np.int64)
        self._inmoved = np.zeros(cap, dtype=bool)
        self._n_moved = 0
        self._grid_built = True

    def _update_incremental(self) -> None:
        dirty = np.fromiter(self._dirty, dtype=np.int64, count=len(self._dirty))
        dirty.sort()
        self._dirty.clear()
        self._kill_rows(dirty)
        if not self._grid_built or self._n_moved + dirty.size > max(64, len(self._slot) // self._MOVED_FRACTION):
            # (re)build the static part from the current bounds; dirty slots
            # are marked stale and searched as moved below
            self._build_grid()
        self._ensure_rank()
        A, B, self._n_moved = _sk.incremental_pairs(
            dirty, self._alive, self._P, self._V, self._A, self._R, self._T, self._Tf, self._lo, self._hi,
            self._epoch, self._slack_ns, self._h, self._slack_ns * 1e-9 + self._h, self._cell,
            _bp._MAX_CELLS_PER_BODY, self._gkeys, self._gslot, self._gstale, self._gbig, self._moved,
            self._n_moved, self._inmoved, self._rank, np.int64(self._R.shape[0]))
        if A.size == 0:
            return
        if A.size >= self._COMPILED_ROWS:
            self._store(A, B, self._evaluate_at_tp(A, B))
            return
        n = self._reserve_records(A.size)
        end, evaluated = _sk.evaluate_and_store(
            A, B, self._epoch, self._P, self._V, self._A, self._R, self._T, self._h_eval, self._ra,
            self._rb, self._rtp, self._rtau, self._rpt, self._rnm, self._rcs, self._rov, self._rlive,
            self._rnext, self._rhead, self._rsP, self._rsV, self._rsA, self._rsR, self._rsT, n)
        self.evaluated_pairs += evaluated
        if end > n:
            self._rn = end
            self._new_rows.append(np.arange(n, end))

    def _flush(self) -> None:
        """Bring pair records up to date (all of them, or only the changed bodies' pairs)."""
        epoch = self.epoch_ns
        if epoch != self._epoch:
            self._epoch = epoch
            self._need_full = True
        n = len(self._slot)
        if self._need_full or len(self._dirty) > max(8, self._full_frac * n):
            if self._epoch is None:  # empty scene
                self._clear_records()
                self._dirty.clear()
                self._need_full = False
            else:
                self._rebuild_all()
        elif self._dirty:
            self._update_incremental()

    # ------------------------------------------------------------------ query
    def predictions(self) -> SceneContacts:
        """Pairs touching within ``[R, R + H]`` by the rule of the module docstring.

        Cached until the scene changes.  Work after a small update: the changed
        bodies' pairs, one pass over the kept order (times shifted to the new
        reference time, order repaired where rounding swapped neighbours, new
        rows merged in) and the pairs whose contact began before R (evaluated
        at R); see _ordered_rows.
        """
        self.evaluated_pairs = 0
        if self._cache is not None and self._cache[0] == self._version:
            return self._cache[1]
        self._flush()
        rows, id_rows = self._ordered_rows()
        self._new_rows = []
        if self._rdead > max(1024, self._rn // 2) or self._records_scattered:
            self._compact()
            self._records_scattered = False
        res = self._publish(rows, id_rows)
        self._cache = (self._version, res)
        return res

    def _ordered_rows(self):
        """Reportable rows ``(A, B, ttc, contact_ns, overlapping, pt, nm, cs)`` at R, sorted, and
        their ids' places in the UTF-8 blob ``(start_a, len_a, start_b, len_b)`` (None: no rows).

        Between two queries of one epoch and horizon, R only grows, so a record
        that was past stays past, and a record's ttc = tau - (R - t_p) falls by
        the same amount for every record up to rounding: the kept order stays
        sorted but for swaps of rows within a few ulps, which an insertion pass
        repairs (a budget guards against the unexpected; then a full sort).
        New records are sorted and merged in.  Equal to _resolve + _sort on all
        live records (full_recomputation), bitwise: same rule, same keys.
        """
        R = self.reference_ns
        D = self._dim
        if R is None or self._rn == 0:
            self._fut, self._fut_ttc, self._past = _EMPTY_I, np.empty(0), _EMPTY_I
            e = np.empty(0)
            return (_EMPTY_I, _EMPTY_I, e, _EMPTY_I, np.empty(0, dtype=bool),
                    np.empty((0, D)), np.empty((0, D)), e), None
        live, tp_all, tau_all = self._rlive, self._rtp, self._rtau
        if self._fut is None:  # after a rebuild: every live record is new
            prev, prev_past = _EMPTY_I, _EMPTY_I
            new = np.flatnonzero(live[:self._rn])
        else:
            prev, prev_past = self._fut, self._past
            new = np.concatenate(self._new_rows) if self._new_rows else _EMPTY_I
        self._ensure_rank()
        basis = (self._rank_serial, self._R.shape[0], self._utf8_serial)
        key_from = self._rkey_n if basis == self._rkey_basis else 0  # else every key is stale
        fut, ttc, past, rows, evaluated, id_rows = _sk.ordered_query(
            prev, new, prev_past, live, self._ra, self._rb, self._rkey, self._rids, key_from, self._rn, tp_all,
            tau_all, self._rov, self._rpt, self._rnm, self._rcs, self._rsP, self._rsV, self._rsA, self._rsR,
            self._rsT, R, self._h, self._rank, np.int64(basis[1]), 1024, self._id_start, self._id_len)
        self._rkey_basis, self._rkey_n = basis, self._rn
        self._fut, self._fut_ttc, self._past = fut, ttc, past
        self.evaluated_pairs += evaluated
        return rows, id_rows

    def _resolve(self, A, B, tp, tau, pt, nm, cs, compiled: bool | None = None):
        """Records -> reportable rows ``(A, B, ttc, contact_ns, overlapping, pt, nm, cs)`` at R
        (the rule applied to records at once: full_recomputation's reference path)."""
        R = self.reference_ns
        if R is None or A.size == 0:
            e = np.empty(0)
            return (_EMPTY_I, _EMPTY_I, e, _EMPTY_I, np.empty(0, dtype=bool),
                    np.empty((0, self._dim)), np.empty((0, self._dim)), e)
        dtn = R - tp
        shifted = dtn > 0
        d = dtn.astype(np.float64) * 1e-9
        ttc = np.where(shifted, tau - d, tau)
        cns = tp + np.round(tau * 1e9).astype(np.int64)
        past = np.flatnonzero(shifted & (tau <= d))
        if past.size:
            # the contact began between t_p and R: the first contact from R, evaluated at R
            Ap, Bp = A[past], B[past]
            hit, _, tau2, pt2, nm2, cs2, _ = self._evaluate(
                Ap, Bp, np.full(past.size, R, dtype=np.int64), self._h, compiled)
            fut = np.ones(A.size, dtype=bool)
            fut[past] = False
            A = np.concatenate([A[fut], Ap[hit]])
            B = np.concatenate([B[fut], Bp[hit]])
            ttc = np.concatenate([ttc[fut], tau2])
            cns = np.concatenate([cns[fut], R + np.round(tau2 * 1e9).astype(np.int64)])
            pt = np.concatenate([pt[fut], pt2])
            nm = np.concatenate([nm[fut], nm2])
            cs = np.concatenate([cs[fut], cs2])
        k = np.flatnonzero(ttc <= self._h)
        A, B, ttc, cns, pt, nm, cs = A[k], B[k], ttc[k], cns[k], pt[k], nm[k], cs[k]
        over = np.zeros(A.size, dtype=bool)
        z = np.flatnonzero(ttc == 0.0)
        if z.size:
            Az, Bz = A[z], B[z]
            pa, _ = _propagate_ns(self._P[Az], self._V[Az], self._A[Az], R - self._T[Az])
            pb, _ = _propagate_ns(self._P[Bz], self._V[Bz], self._A[Bz], R - self._T[Bz])
            over[z] = np.linalg.norm(pa - pb, axis=1) - (self._R[Az] + self._R[Bz]) < 0.0
        return A, B, ttc, cns, over, pt, nm, cs

    def _pair_key(self, A, B):
        return self._rank[A] * np.int64(self._R.shape[0]) + self._rank[B]

    def _sort(self, rows):
        """Sort rows by (ttc, id_a, id_b): pair-rank order, then a stable sort on ttc."""
        A, B, ttc = rows[0], rows[1], rows[2]
        if ttc.size == 0:
            return rows
        self._ensure_rank()
        o = np.argsort(self._pair_key(A, B), kind="stable")
        o = o[np.argsort(ttc[o], kind="stable")]
        return tuple(x[o] for x in rows)

    def _id_utf8(self, A: np.ndarray, B: np.ndarray, id_rows=None) -> tuple | None:
        """``(blob, start_a, len_a, start_b, len_b)`` of pairs (slots A, B), read-only (the
        encoders compile for that one kind); None when some id is not a str.  id_rows: the
        four columns when already gathered."""
        if not self._utf8_ok:
            return None
        if id_rows is None:
            id_rows = (self._id_start[A], self._id_len[A], self._id_start[B], self._id_len[B])
        # the blob is appended to in place, but never where published ids lie
        blob = self._utf8.view()
        blob.flags.writeable = False
        for x in id_rows:
            if x.size:
                x.flags.writeable = False
        return (blob,) + tuple(id_rows)

    def _publish(self, rows, id_rows=None) -> SceneContacts:
        """id_rows: the rows' ``(start_a, len_a, start_b, len_b)`` in the id blob when already
        gathered (the query kernel does it on its way)."""
        A, B, ttc, cns, over, pt, nm, cs = rows
        for x in rows:
            # SceneContacts' arrays are read-only; an empty one holds nothing to protect and may
            # be a shared constant (_EMPTY_I) that the kernels also take: freezing it would give
            # every later kernel call a new read-only specialisation to compile (~15 s, once)
            if x.size:
                x.flags.writeable = False
        self._ids_published = True
        return SceneContacts(self.reference_ns or 0, self._ids, A, B, ttc, cns, over, pt, nm, cs,
                             self._id_utf8(A, B, id_rows))

    def full_recomputation(self) -> SceneContacts:
        """The rule applied from scratch to the stored states (caches untouched).

        Tests use it to prove the incremental path bitwise equal to it.
        """
        if self.reference_ns is None:
            return self._publish(self._resolve(_EMPTY_I, _EMPTY_I, None, None, None, None, None))
        saved_epoch, saved_lo, saved_hi, saved_tf = self._epoch, self._lo.copy(), self._hi.copy(), self._Tf.copy()
        try:
            self._epoch = self.epoch_ns
            _, A, B = self._pairs_full()
            hit, tp, tau, pt, nm, cs, _ = self._evaluate_at_tp(A, B, compiled=False)
            return self._publish(self._sort(self._resolve(A[hit], B[hit], tp, tau, pt, nm, cs,
                                                          compiled=False)))
        finally:
            self._epoch, self._lo, self._hi, self._Tf = saved_epoch, saved_lo, saved_hi, saved_tf


    # ------------------------------------------------------------ uncertain pairs
    def uncertain_pairs(self, threshold: float, contacts: SceneContacts | None = None,
                        max_evaluated: int | None = None) -> SceneUncertainty:
        """Probabilities of the pairs with an uncertain body that may touch within [R, R + H].

        Which pairs: those the broad phase at R over [0, H], each uncertain body's radius
        inflated by ``core.uncertainty.inflation_radius``, cannot rule out.  Each listed pair
        is evaluated at its pair time t_p over [t_p, t_p + H]: t_p is the newer of its two
        stamps when that lies within ``UNCERTAIN_LAG_NS`` of R (always so for a tracker array,
        where t_p = R; for per-body streams the pair's newest information), else
        ``R - (R mod UNCERTAIN_LAG_NS)``; so 0 <= R - t_p < UNCERTAIN_LAG_NS.  Both states and
        covariances are propagated to t_p.  A pair's answer is thus a pure function of its two
        stored states and t_p, and is kept between calls: a call evaluates only the listed pairs
        whose body changed or whose t_p moved (a one-body update: that body's pairs), and
        results equal a from-scratch evaluation bit for bit (the core's rows are independent).
        The plausible time is reported from R: ``max(0, tau - (R - t_p))`` (0: the overlap
        probability reached the threshold at or before R).  Cached as a whole while the scene
        and `threshold` are unchanged.  `contacts` (the exact path's rows) adds their
        uncertain pairs should the inflated broad phase not list them.  Pairs certified below
        threshold / 2 skip the full evaluation (``core.uncertainty.uncertain_pairs(screen=True)``);
        `max_evaluated` caps the full evaluations (the rest are deferred, see there).

        Which pairs the budget evaluates: first come, first served.  A pair that is deferred
        waits from the first evaluation (call that follows a change) that defers it until one
        evaluates it; each evaluation takes the `max_evaluated` pairs that have waited longest
        (never deferred before counts as waiting from now), then the earliest possible contact,
        then id order.  A pair deferred at evaluation s is therefore evaluated within
        ceil(n_s / max_evaluated) evaluations, n_s = the pairs waiting at s (itself included),
        as long as it stays listed and unscreened (a pair that leaves the list stops waiting; a
        body removed and added again is a new body: its pairs wait from then).
        A pair whose relative inputs are bit for bit those of a pair fully evaluated by the
        previous evaluation takes that answer without counting against the budget.  The order
        depends only on the sequence of scene inputs and calls (no clock): replay, which makes
        the node's calls in the node's order, reproduces it bit for bit.
        See SceneUncertainty.
        """
        key = (self._version, float(threshold), max_evaluated)
        if self._uncertain_cache is not None and self._uncertain_cache[0] == key:
            return self._uncertain_cache[1]
        res = self._uncertain_pairs(float(threshold), contacts, max_evaluated)
        self._uncertain_cache = (key, res)
        return res

    def _uncertain_pairs(self, threshold: float, contacts: SceneContacts | None,
                         max_evaluated: int | None) -> SceneUncertainty:
        R = self.reference_ns
        if R is None or self._n_uncertain == 0:
            self._uncertain_waiting = _NO_WAITING  # no pair listed: none waits
            self._pair_answers = None
            return SceneUncertainty(R or 0, _NO_IDS, _NO_IDS, _NO_VALUES, _NO_VALUES, _NO_VALUES)
        from circle_collision_ros.core import uncertainty as unc  # heavy kernels: loaded on first use
        slots = self._sorted_slots()
        I, J, at_R, contact_rows = self._uncertain_listed(slots, R, contacts, unc)
        if I.size == 0:
            self._uncertain_waiting = _NO_WAITING
            self._pair_answers = None
            return SceneUncertainty(R, _NO_IDS, _NO_IDS, _NO_VALUES, _NO_VALUES, _NO_VALUES)
        ids = self._ids[slots]
        ida, idb = ids[I], ids[J]
        sa, sb = slots[I], slots[J]
        tp = self._uncertain_pair_times(sa, sb, R)
        key = (sa << 32) | sb
        prob, bound, tau = np.empty(I.size), np.empty(I.size), np.empty(I.size)
        hit = np.zeros(I.size, dtype=bool)
        # where the last call deferred the pair with these same inputs: its screening
        # tube's first time (the deferred answer's time), so the core skips the screen
        screened_first = np.full(I.size, np.nan)
        sv_a, sv_b = self._sv[sa], self._sv[sb]
        old = self._pair_answers
        # a kept answer needs both bodies unchanged since (state serials below old.sv_next):
        # when every body changed (a tracker array) there is nothing to look up
        if old is not None and old.horizon == self._h and old.threshold == threshold \
                and self._sv[slots].min() < old.sv_next and old.key.size:
            keep = np.argsort(old.key, kind="stable")  # keys are distinct
            at = keep[np.minimum(np.searchsorted(old.key[keep], key), keep.size - 1)]
            same = ((old.key[at] == key) & (old.state_a[at] == sv_a)
                    & (old.state_b[at] == sv_b) & (old.pair_ns[at] == tp))
            hit = same & old.answered[at]
            prob[hit], bound[hit], tau[hit] = old.probability[at[hit]], old.bound[at[hit]], old.tau[at[hit]]
            waited = same & ~old.answered[at]
            screened_first[waited] = old.tau[at[waited]]
        todo = np.flatnonzero(~hit)
        answered = hit.copy()
        if todo.size:
            deferred = self._evaluate_uncertain(unc, sa[todo], sb[todo], I[todo], J[todo], at_R, tp[todo],
                                                key[todo], threshold, max_evaluated, screened_first[todo])
            prob[todo], bound[todo], tau[todo] = deferred.probability, deferred.bound, deferred.tau
            answered[todo[~deferred.deferred]] = True
        else:
            self._uncertain_waiting = _NO_WAITING
            self._uncertain_serial += 1
        self._pair_answers = _PairAnswers(self._h, threshold, self._sv_next, key, answered, sv_a, sv_b,
                                          tp, prob, bound, tau)
        self.uncertain_evaluated = int(todo.size)
        # reported from R: the pair's plausible time counts from its t_p <= R (d = R - t_p);
        # one already reached before R is reported as 0 (plausible now)
        d = (R - tp).astype(np.float64) * 1e-9
        plausible = np.where(np.isnan(tau) | (tau > d), tau - d, 0.0)
        return SceneUncertainty(R, ida, idb, prob, bound, plausible,
                                int(np.count_nonzero(~answered)) if max_evaluated is not None else 0,
                                contact_rows, contacts if contact_rows is not None else None,
                                self._id_utf8(sa, sb))

    def _uncertain_listed(self, slots: np.ndarray, R: int, contacts: SceneContacts | None, unc):
        """``(I, J, at_R, contact_rows)``: local index pairs (I < J, into `slots`, id order) with
        an uncertain body that the broad phase at R over [0, H], radii inflated by
        ``unc.inflation_radius``, cannot rule out, plus the uncertain pairs of `contacts`;
        at_R = (P, V, A, radius, C) of `slots`, propagated to R (C zero for exact bodies); contact_rows:
        each pair's row in `contacts`, -1 if none (None without contacts)."""
        P, V, C = self._states_at(slots, np.full(slots.size, R, dtype=np.int64))
        A, Rad = self._A[slots], self._R[slots]
        u = self._U[slots]
        if u.all():
            grow = unc.inflation_radius(C, self._h)
        else:
            grow = np.zeros(slots.size)
            grow[u] = unc.inflation_radius(C[u], self._h)
        zero = np.zeros(slots.size)
        lo, hi = _bp.swept_bounds(P, V, A, Rad + grow, zero, zero + self._h)
        # the sweep whatever the scene's method: on these few inflated bodies per cell it is
        # 4-5x faster than the grid (same pairs; bench_node.py's density, 1,000-10,000 bodies)
        I, J, _ = _bp.candidate_pairs(lo, hi, p=P, v=V, a=A, r=Rad + grow, tref=zero, t_start=0.0,
                                      t_end=self._h, method="sweep")
        keep = u[I] | u[J]
        I, J = I[keep], J[keep]
        if contacts is not None and len(contacts):
            # slot -> local index through an array (no dict of every body per call)
            local = np.empty(self._ids.shape[0], dtype=np.int64)
            local[slots] = np.arange(slots.size)
            if contacts.slot_ids is self._ids:  # no body came or went since: its slots hold
                ca, cb = local[contacts.slot_a], local[contacts.slot_b]
            else:
                slot = self._slot.__getitem__
                ca = local[np.fromiter(map(slot, contacts.id_a.tolist()), np.int64, len(contacts))]
                cb = local[np.fromiter(map(slot, contacts.id_b.tolist()), np.int64, len(contacts))]
            m = u[ca] | u[cb]
            I, J = np.concatenate([I, ca[m]]), np.concatenate([J, cb[m]])
        # local order is id order: (min, max) puts the id that sorts first in front
        n = np.int64(slots.size)
        key = np.minimum(I, J) * n + np.maximum(I, J)
        key.sort()  # then drop repeats (a contact the broad phase listed too): np.unique's result
        if key.size > 1:
            key = key[np.concatenate(([True], key[1:] != key[:-1]))]
        rows = None
        if contacts is not None:
            rows = np.full(key.size, -1, dtype=np.int64)
            if len(contacts):
                ckey = np.minimum(ca, cb) * n + np.maximum(ca, cb)
                order = np.argsort(ckey, kind="stable")
                at = np.minimum(np.searchsorted(ckey[order], key), order.size - 1)
                same = ckey[order[at]] == key
                rows[same] = order[at[same]]
        return key // n, key % n, (P, V, A, Rad, C), rows

    def _states_at(self, slots: np.ndarray, t_ns: np.ndarray):
        """(P, V, C) of the bodies `slots` moved to the times t_ns (int64 ns, per body), C zero
        for exact bodies: see _states_at_rows."""
        m = slots.shape[0]
        D = self._dim
        P, V, C = np.empty((m, D)), np.empty((m, D)), np.empty((m, 2 * D, 2 * D))
        _states_at_rows(self._P, self._V, self._A, self._C, self._T, self._U, slots, t_ns, P, V, C)
        return P, V, C

    def _uncertain_pair_times(self, sa: np.ndarray, sb: np.ndarray, R: int) -> np.ndarray:
        """Pair times t_p (ns): the newer stamp of the two if it lies within UNCERTAIN_LAG_NS
        of R, else the start of R's lag period (R - R mod UNCERTAIN_LAG_NS); R - t_p < the lag."""
        newer = np.maximum(self._T[sa], self._T[sb])
        lag = self.UNCERTAIN_LAG_NS
        return np.where(newer > R - lag, newer, R - R % lag)

    def _evaluate_uncertain(self, unc, sa, sb, la, lb, at_R, tp, key, threshold: float,
                            max_evaluated: int | None, screened_first: np.ndarray) -> "_Evaluated":
        """``unc.uncertain_pairs`` on these pairs (slots sa, sb; local indices la, lb into
        at_R, the bodies at R; key = sa << 32 | sb), each at its t_p over [0, H] (screened,
        within the budget; FIFO bookkeeping of the deferred, see uncertain_pairs);
        screened_first: as ``unc.uncertain_pairs`` takes it (NaN: screen the pair)."""
        R = self.reference_ns
        late = np.flatnonzero(tp != R)  # t_p = R: the bodies as propagated for the listing
        states = []
        for s, loc in ((sa, la), (sb, lb)):
            P, V, A, Rad = _bp.gather_states(loc, *at_R[:4])
            C = at_R[4][loc]
            if late.size:  # the same operations from the stamp to t_p instead
                P[late], V[late], C[late] = self._states_at(s[late], tp[late])
            states.append((P, V, A, Rad, C))
        serial = self._uncertain_serial
        waiting = self._uncertain_waiting
        born_a, born_b = self._born[sa], self._born[sb]
        asked = []

        def waited_since(rows):  # the rows competing for the budget (called only when over it)
            since = waiting.since_of(key[rows], born_a[rows], born_b[rows], serial)
            asked.append((rows, since))
            return since

        if self._uncertain_memo_ref != R:
            # a new reference time moves most pairs' inputs (their t_p follow the stamps):
            # skip the look-ups, which can only forgo a reuse, never give a wrong one
            self._uncertain_memo.clear()
            self._uncertain_memo_ref = R
        res = unc.uncertain_pairs(*states[0], *states[1], self._h, threshold, screen=True,
                                  max_evaluated=max_evaluated, priority=waited_since,
                                  memo=self._uncertain_memo, screened_first=screened_first)
        deferred = (res.collision_probability_bound == unc.DEFERRED_BOUND
                    if max_evaluated is not None else np.zeros(sa.size, dtype=bool))
        # the deferred of the rows that competed wait on (since as looked up); the rest stop
        rows = np.concatenate([r for r, _ in asked]) if asked else _EMPTY_I
        since = np.concatenate([w for _, w in asked]) if asked else _EMPTY_I
        still = deferred[rows]
        rows, since = rows[still], since[still]
        order = np.argsort(key[rows], kind="stable")  # keys are distinct: any sort gives this order
        rows = rows[order]
        self._uncertain_waiting = _Waiting(key[rows], born_a[rows], born_b[rows], since[order])
        self._uncertain_serial = serial + 1
        return _Evaluated(res.collision_probability, res.collision_probability_bound,
                          res.plausible_time, deferred)


class _Waiting(NamedTuple):
    """The pairs the last uncertain evaluation deferred (the budget's FIFO), sorted by key =
    slot_a << 32 | slot_b, with their bodies' serials (``Scene._born``: a slot another body
    took since is another pair; a body removed and added again is a new body, its pairs wait
    from then) and the evaluation serial since which each waits."""

    key: np.ndarray
    born_a: np.ndarray
    born_b: np.ndarray
    since: np.ndarray

    def since_of(self, key: np.ndarray, born_a: np.ndarray, born_b: np.ndarray, default: int) -> np.ndarray:
        """(n,) int64: since when each pair (key, born_a, born_b) waits; `default` if it does not."""
        out = np.full(key.size, default, dtype=np.int64)
        if self.key.size and key.size:
            at = np.minimum(np.searchsorted(self.key, key), self.key.size - 1)
            same = (self.key[at] == key) & (self.born_a[at] == born_a) & (self.born_b[at] == born_b)
            out[same] = self.since[at[same]]
        return out


_NO_WAITING = _Waiting(_EMPTY_I, _EMPTY_I, _EMPTY_I, _EMPTY_I)


class _PairAnswers(NamedTuple):
    """Scene.uncertain_pairs' answers of the last call, per listed pair (key = slot_a << 32 |
    slot_b, in listing order; answered: not deferred): valid for a later call while both
    bodies' states (serials) and t_p are unchanged."""

    horizon: float
    threshold: float
    sv_next: int  # Scene._sv_next then: every state serial of that call is below it
    key: np.ndarray
    answered: np.ndarray
    state_a: np.ndarray
    state_b: np.ndarray
    pair_ns: np.ndarray
    probability: np.ndarray
    bound: np.ndarray
    tau: np.ndarray  # plausible time from t_p, s


class _Evaluated(NamedTuple):
    probability: np.ndarray
    bound: np.ndarray
    tau: np.ndarray
    deferred: np.ndarray


class _Capture:
    """Stored states as of a prediction, propagated to the reference time on demand.

    Shares the scene's arrays; the scene calls preserve() before it changes
    rows, and the captured values of those rows are kept here.  The lock
    makes a reader on another thread (markers) see either the rows before a
    change or their preserved copies: preserve() completes before the scene
    writes, and a reader gathers and patches under the lock.
    """

    #: Preserved rows beyond this fraction of the capture: take a private copy instead.
    COPY_FRACTION = 0.125

    def __init__(self, reference_ns, order, ids, P, V, A, R, T) -> None:
        self._args = (reference_ns, order, ids, P, V, A, R, T)
        self._saved: dict = {}  # slot -> (id, p, v, a, r, t) as captured
        self._private = False
        self._lock = threading.Lock()
        self._snapshot = None

    def preserve(self, slots) -> bool:
        """Keep the captured values of rows about to change; False once the capture holds a
        private copy (the scene need not tell it again)."""
        with self._lock:
            if self._private:
                return False
            ref, order, ids, P, V, A, R, T = self._args
            if len(self._saved) + len(slots) > self.COPY_FRACTION * order.shape[0] + 8:
                # many rows change (a tracker array): one vectorised copy now, while the
                # scene still holds the captured values, instead of a row-by-row loop
                ids, P, V, A, R, T = self._gather()
                self._args = (ref, np.arange(order.shape[0]), ids, P, V, A, R, T)
                self._saved = {}
                self._private = True
                return False
            for s in slots:
                s = int(s)
                # a slot past these arrays was added after the scene grew: not captured here
                if s < ids.shape[0] and s not in self._saved:
                    self._saved[s] = (ids[s], P[s].copy(), V[s].copy(), A[s].copy(), R[s], T[s])
            return True

    def _gather(self):
        """(ids, P, V, A, R, T) of the captured rows, in capture order (hold the lock)."""
        ref, order, ids, P, V, A, R, T = self._args
        out = [ids[order], P[order], V[order], A[order], R[order], T[order]]
        if self._saved:
            where = {s: k for k, s in enumerate(order.tolist()) if s in self._saved}
            for s, k in where.items():
                for column, value in zip(out, self._saved[s]):
                    column[k] = value
        return tuple(out)

    def __len__(self) -> int:
        return int(self._args[1].shape[0])

    def ids(self) -> list:
        """Body ids, sorted."""
        with self._lock:
            return self._gather()[0].tolist()

    def snapshot(self) -> SceneSnapshot:
        if self._snapshot is None:
            with self._lock:
                ids, P, V, A, R, T = self._gather()
            p, v = _propagate_ns(P, V, A, self._args[0] - T)
            self._snapshot = SceneSnapshot(self._args[0], ids.tolist(), np.ascontiguousarray(p),
                                           np.ascontiguousarray(v), A, R)
        return self._snapshot
