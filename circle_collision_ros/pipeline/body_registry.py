"""The scene's bodies: the latest accepted state per id, and their common time.

Deterministic by construction, so that replaying the same inputs reproduces
the same scene bit for bit:

- a body's state is replaced only by a strictly newer header stamp (an older
  or equal one arriving late is ignored, which also makes duplicates harmless);
- the reference time is the newest stamp accepted since the scene was last
  empty (integer ns, monotone while any body is held);
- staleness is judged on the receiving clock passed in by the caller (the node's
  clock live, the recorded receive time in replay), never read here;
- bodies are ordered by id when exported, independent of arrival order.

Storage is a set of arrays indexed by slot plus an id -> slot map, so a batch
of states is merged with a few vectorised assignments.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from circle_collision_ros.pipeline.state_batch import StateBatch


@dataclass(frozen=True)
class SceneSnapshot:
    """All bodies propagated to `reference_ns`, ordered by id; arrays are (N, D) and (N,)."""

    reference_ns: int
    ids: list[str]
    positions: np.ndarray
    velocities: np.ndarray
    accelerations: np.ndarray
    radii: np.ndarray


@dataclass(frozen=True)
class MergeResult:
    """Row indices (into the batch) by outcome."""

    accepted: np.ndarray
    not_newer: np.ndarray
    full: np.ndarray


class BodyRegistry:
    """Latest state per body id, with removal, expiry and propagation.

    Parameters
    ----------
    max_bodies : new ids beyond this many are refused (MergeResult.full), which
        bounds memory and compute when a source floods the node.
    """

    def __init__(self, max_bodies: int) -> None:
        self.max_bodies = max_bodies
        self.reference_ns: int | None = None
        self._slot: dict[str, int] = {}
        self._ids: list[str] = []
        self._order: np.ndarray | None = None  # slots sorted by id; None when membership changed
        self._alloc(16)

    def _alloc(self, capacity: int) -> None:
        old = getattr(self, "_stamp", None)
        n = len(self._ids)
        stamp, received = np.zeros(capacity, np.int64), np.zeros(capacity, np.int64)
        radius, vectors = np.zeros(capacity), np.zeros((capacity, 9))
        if old is not None:
            stamp[:n], received[:n] = self._stamp[:n], self._received[:n]
            radius[:n], vectors[:n] = self._radius[:n], self._vectors[:n]
        self._stamp, self._received, self._radius, self._vectors = stamp, received, radius, vectors

    def __len__(self) -> int:
        return len(self._ids)

    def __contains__(self, body_id: str) -> bool:
        return body_id in self._slot

    def merge(self, batch: StateBatch, rows: np.ndarray, received_ns: int) -> MergeResult:
        """Store rows of `batch` (distinct ids, validated) that are newer than what is held."""
        rows = np.asarray(rows, dtype=np.int64)
        slots = np.fromiter((self._slot.get(batch.ids[k], -1) for k in rows.tolist()),
                            dtype=np.int64, count=rows.size)
        stamps = batch.stamp_ns[rows]
        known = slots >= 0
        newer = np.ones(rows.size, dtype=bool)
        newer[known] = stamps[known] > self._stamp[slots[known]]
        fresh = np.flatnonzero(~known)
        room = max(0, self.max_bodies - len(self._ids))
        full = fresh[room:]
        fresh = fresh[:room]
        if fresh.size:
            if len(self._ids) + fresh.size > self._stamp.shape[0]:
                self._alloc(max(2 * self._stamp.shape[0], len(self._ids) + fresh.size))
            start = len(self._ids)
            slots[fresh] = np.arange(start, start + fresh.size)
            for k, slot in zip(rows[fresh].tolist(), slots[fresh].tolist()):
                self._slot[batch.ids[k]] = slot
                self._ids.append(batch.ids[k])
            self._order = None
        take = newer.copy()
        take[full] = False
        target, source = slots[take], rows[take]
        self._stamp[target] = batch.stamp_ns[source]
        self._received[target] = received_ns
        self._radius[target] = batch.radius[source]
        self._vectors[target, 0:3] = batch.position[source]
        self._vectors[target, 3:6] = batch.velocity[source]
        self._vectors[target, 6:9] = batch.acceleration[source]
        if source.size:
            newest = int(batch.stamp_ns[source].max())
            if self.reference_ns is None or newest > self.reference_ns:
                self.reference_ns = newest
        return MergeResult(accepted=source, not_newer=rows[~newer], full=rows[full])

    def remove(self, body_id: str, stamp_ns: int) -> bool:
        """Remove `body_id` unless its current state is newer than the removal."""
        slot = self._slot.get(body_id)
        if slot is None or stamp_ns < self._stamp[slot]:
            return False
        self._drop(slot)
        return True

    def _drop(self, slot: int) -> None:
        # Swap-remove: the last slot moves into the hole, so arrays stay dense.
        last = len(self._ids) - 1
        del self._slot[self._ids[slot]]
        if slot != last:
            moved = self._ids[last]
            self._ids[slot] = moved
            self._slot[moved] = slot
            for arr in (self._stamp, self._received, self._radius, self._vectors):
                arr[slot] = arr[last]
        self._ids.pop()
        self._order = None
        if not self._ids:
            # Nothing left to propagate: forget the reference time. Otherwise, after a
            # tracker's clock reset (stamps jump back) the new bodies would be propagated
            # into the old future and their contacts missed for as long as the jump
            # (tests/reliability/test_faults_clock.py::test_stamps_jump_backwards).
            self.reference_ns = None

    def expire(self, now_ns: int, stale_timeout_s: float) -> list[str]:
        """Drop bodies not received within `stale_timeout_s` of `now_ns`; returns their ids."""
        limit = now_ns - int(round(stale_timeout_s * 1e9))
        stale = np.flatnonzero(self._received[:len(self._ids)] < limit)
        gone = [self._ids[s] for s in stale.tolist()]
        for body_id in gone:
            self._drop(self._slot[body_id])
        return gone

    def clear(self) -> None:
        self._slot.clear()
        self._ids.clear()
        self._order = None
        self.reference_ns = None

    def snapshot(self, dimensions: int) -> SceneSnapshot:
        """Every body propagated to the reference time (exact under the model).

        p + dt (v + (dt/2) a) and v + dt a with dt = (reference - stamp) >= 0, so
        a body's prediction does not depend on when other bodies were stamped.
        """
        if self._order is None:
            self._order = np.array(sorted(range(len(self._ids)), key=self._ids.__getitem__),
                                   dtype=np.int64)
        order = self._order
        ref = self.reference_ns if self.reference_ns is not None else 0
        v9 = self._vectors[order]
        p, v, a = v9[:, 0:3], v9[:, 3:6], v9[:, 6:9]
        # Integer subtraction first: stamps ~1.7e18 ns would lose sub-us detail as floats.
        dt = ((ref - self._stamp[order]).astype(np.float64) * 1e-9)[:, None]
        p = p + dt * (v + (0.5 * dt) * a)
        v = v + dt * a
        d = dimensions
        return SceneSnapshot(ref, [self._ids[s] for s in order.tolist()], np.ascontiguousarray(p[:, :d]),
                             np.ascontiguousarray(v[:, :d]), np.ascontiguousarray(a[:, :d]),
                             self._radius[order])
