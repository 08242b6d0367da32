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
operations exactly (kernels.py).

When every body carries the stamp ``R`` (a tracker array), ``t_p == R`` for
every pair and the result is the narrow phase on the states propagated to
``R``, i.e. ``predict_all_pairs`` on them (the narrow phase's root does not
depend on the horizon argument once the contact lies inside it).  Bodies with
older stamps are evaluated at the newer stamp of their pair and shifted, which
can differ from propagating everything to ``R`` in the last bits.

Swept bounds cover ``[max(E, T), E + S + H]``, which contains every reportable
contact until the epoch moves.

Ego set (``set_ego``): when set, only the pairs with at least one ego body are listed by
the broad phase (each ego body's bounds against every body's, another body's against the
ego bodies' only: ``broad.ego``), evaluated and reported; the rows are those of the same
scene without an ego set that have an ego body, bit for bit and in the same order.
"""
from __future__ import annotations

import math
import weakref
from typing import Hashable, Iterable

import numpy as np

from circle_collision_ros.core.scene.all_pairs import check_horizon
from circle_collision_ros.core.scene.ordering import OrderingMixin
from circle_collision_ros.core.scene.pairs import PairsMixin
from circle_collision_ros.core.scene.snapshot import SnapshotMixin
from circle_collision_ros.core.scene.store import EMPTY_I, StoreMixin
from circle_collision_ros.core.scene.stream import NEVER, StreamMixin
from circle_collision_ros.core.scene.uncertain import NO_WAITING, UncertainMixin

__all__ = ["Scene"]


class Scene(StoreMixin, StreamMixin, PairsMixin, OrderingMixin, UncertainMixin, SnapshotMixin):
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
    ego_ids : the ego set (see set_ego); None: every pair.

    The class combines parts with one responsibility each: the slot store
    (store.py), the stream rules (stream.py), the pair records (pairs.py), the
    order and publication (ordering.py), the uncertain path (uncertain.py) and
    captures/snapshots (snapshot.py).  The state they share is declared and
    initialised here only (``clear``, ``_clear_records``).
    """

    def __init__(self, horizon: float, dim: int = 2, *, slack: float | None = None,
                 max_bodies: int | None = None, method: str = "sweep",
                 full_rebuild_fraction: float = 0.05,
                 ego_ids: Iterable[Hashable] | None = None) -> None:
        if dim not in (2, 3):
            raise ValueError(f"dim must be 2 or 3, got {dim}")
        if method not in ("sweep", "grid"):
            raise ValueError(f"unknown broad-phase method {method!r}")
        self._dim = dim
        self._Z = (0.0,) * dim  # the kernels' dimension, known when they compile
        self._method = method
        self._full_frac = float(full_rebuild_fraction)
        self.max_bodies = max_bodies
        self._slack_arg = slack
        self._set_horizon(horizon)
        self._ego_ids: frozenset = frozenset()  # configuration: kept by clear()
        self.clear()
        self.set_ego(ego_ids)

    def _set_horizon(self, horizon: float) -> None:
        self._h = check_horizon(horizon)
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

    def set_ego(self, ids: Iterable[Hashable] | None) -> None:
        """Evaluate and report only the pairs with at least one body of ``ids`` (the ego set).

        None or empty: every pair (the default).  With an ego set, ``predictions()`` and
        ``uncertain_pairs()`` report exactly the rows of the same scene without it that have an
        ego body, bit for bit and in the same order (each pair's result is a function of its
        two states, R, H and S alone), and the broad phase lists no other pair: each ego body's
        box is tested against every box and another body's against the ego boxes only
        (``broad.ego``), so an update of a non-ego body costs a test per ego body.  Ids may
        name bodies not (yet) in the scene: they count from their first state on.  The ego set
        is configuration: ``clear()`` keeps it.  A change rebuilds the pairs at the next query.
        """
        new = frozenset(() if ids is None else ids)
        if new == self._ego_ids:
            return
        self._ego_ids = new
        self._ego[:] = False
        for bid in new:
            slot = self._slot.get(bid)
            if slot is not None:
                self._ego[slot] = True
        self._ego_slots = None
        self._need_full = True
        self._listing = None  # the uncertain listing holds the pairs of the old set
        self._version += 1

    @property
    def ego_ids(self) -> frozenset:
        """The ego set (empty: every pair is evaluated)."""
        return self._ego_ids

    def _ego_members(self) -> np.ndarray:
        """The slots of the ego bodies in the scene, ascending (cached until one comes or
        goes)."""
        if self._ego_slots is None:
            self._ego_slots = np.flatnonzero(self._ego)
        return self._ego_slots

    def _take_id(self, bid, s: int) -> None:
        """Slot s takes the new body bid (its ego flag from the ego set)."""
        self._slot[bid] = s
        self._writable_ids()[s] = bid
        self._alive[s] = True
        self._members_serial += 1
        if self._ego_ids and bid in self._ego_ids:
            self._ego[s] = True
            self._ego_slots = None

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
        self._ego = np.zeros(cap, dtype=bool)         # alive and in the ego set (set_ego)
        self._ego_slots = EMPTY_I                     # _ego's slots (None: to be listed again)
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
        # bumped whenever a body comes or goes (_take_id, _drop): merge's id look-ups of the
        # last message (_last_named: its ids, their slots, this serial) hold while it is unchanged
        self._members_serial = getattr(self, "_members_serial", 0) + 1
        self._last_named = None
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
        self._recv_floor = NEVER
        self._removal_floor = NEVER
        self._rhead = np.full(cap, -1, dtype=np.int64)  # each slot's newest record (see _REC)
        self._clear_records()
        self._version = getattr(self, "_version", 0) + 1
        self._cache = None
        self.evaluated_pairs = 0  # narrow-phase pair evaluations of the last predictions() call
        # box tests of the ego broad phase (broad.ego) in the last predictions() call (0
        # without an ego set: the sweep, the grid or the hashed grid list the pairs)
        self.box_tests = 0
        self._captures = weakref.WeakSet()  # live captures sharing the state arrays
        self._uncertain_cache = None
        self._uncertain_serial = 0     # uncertain_pairs evaluations so far (the budget's clock)
        self._uncertain_waiting = NO_WAITING  # the deferred pairs and since when they wait
        # core.uncertainty.uncertain_pairs(memo=...): last full evaluations
        self._uncertain_memo = {}
        self._uncertain_memo_ref = None  # the reference time of those evaluations
        self._listing = None           # the inflated broad phase's pairs (_inflated_pairs)
        self._pair_answers = None      # _PairAnswers of the last uncertain_pairs call
        self.uncertain_evaluated = 0   # pairs the last uncertain_pairs call gave the core
        self._sv = np.zeros(cap, dtype=np.int64)  # each slot's state serial (bumped per change)
        self._sv_next = 1
        # each slot's body serial (set when a body takes it)
        self._born = np.zeros(cap, dtype=np.int64)
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
        self._past = EMPTY_I
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
