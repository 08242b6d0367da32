"""The scene's snapshots: captures of the stored states (copy on write), snapshots
propagated to the reference time, the stored states themselves.

A part of ``Scene``.
"""
from __future__ import annotations

import threading

import numpy as np

from circle_collision_ros.core.scene.results import SceneSnapshot
from circle_collision_ros.core.scene.store import propagate_ns

__all__ = ["SnapshotMixin"]


class SnapshotMixin:
    """Scene's captures and snapshots."""

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
            p, v = propagate_ns(P, V, A, self._args[0] - T)
            self._snapshot = SceneSnapshot(self._args[0], ids.tolist(), np.ascontiguousarray(p),
                                           np.ascontiguousarray(v), A, R)
        return self._snapshot
