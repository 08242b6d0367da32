"""The scene's stream rules: merge (removals, then states), upsert, remove, expire.

A part of ``Scene``; the rules are stated in scene.py's module docstring.
"""
from __future__ import annotations

from itertools import repeat
from typing import Hashable, Sequence

import numpy as np
from numba import njit

from circle_collision_ros.core.scene.all_pairs import validate_bodies
from circle_collision_ros.core.scene.results import MergeResult
from circle_collision_ros.core.scene.store import EMPTY_I

__all__ = ["StreamMixin", "NEVER"]


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


@njit(cache=True)
def store_states(P, V, A, Rad, T, recv, slots, rows, p, v, a, r, stamps, received):
    """Rows `rows` of the message (p, v, a: (k, >= D), r, stamps) into the slots `slots`, and
    the receive time: the copies of merge's numpy assignments, in one pass."""
    D = P.shape[1]
    for j in range(slots.shape[0]):
        s, x = slots[j], rows[j]
        for d in range(D):
            P[s, d] = p[x, d]
            V[s, d] = v[x, d]
            A[s, d] = a[x, d]
        Rad[s] = r[x]
        T[s] = stamps[x]
        recv[s] = received


@njit(cache=True)
def newer_rows(slots, stamps, T, newer):
    """newer[x] = whether row x is for a body not stored (slots[x] < 0) or newer than its
    stored state (stamps[x] > T[slots[x]]); returns how many rows are for stored bodies."""
    known = 0
    for x in range(slots.shape[0]):
        s = slots[x]
        if s < 0:
            newer[x] = True
        else:
            known += 1
            newer[x] = stamps[x] > T[s]
    return known


def _c_f64(x):
    """``x`` as a C-ordered, writeable float64 array (itself when it is one)."""
    if type(x) is np.ndarray and x.dtype == np.float64 and x.flags.c_contiguous \
            and x.flags.writeable:
        return x
    return np.require(x, np.float64, "CW")


#: From this many accepted states merge copies them by store_states (numpy below).
_COMPILED_STORE = 64

NEVER = 1 << 62  # later than any receive time, ns
_FIRST_ROW = np.zeros(1, dtype=np.int64)
_FIRST_ROW.flags.writeable = False


class StreamMixin:
    """Scene's stream rules: each message changes the stored bodies by them."""

    def merge(self, ids: Sequence[Hashable], stamps_ns, positions, velocities, accelerations,
              radii, remove, received_ns: int, covariances=None) -> MergeResult:
        """Apply one message: removals first, then states (rules in scene.py's module docstring).

        ids : k distinct ids.  stamps_ns : (k,) int ns > 0.  positions, velocities,
        accelerations : (k, >= dim) (extra columns ignored).  radii : (k,).
        remove : (k,) bool; a removal's geometry is ignored.  received_ns : the
        receive clock for expiry.  Rows must be valid (finite, radius >= 0).
        covariances : None (all exact) or (k, 2 dim, 2 dim) joint covariances of
        (position, velocity), symmetric PSD (all zero = exact); see uncertain_pairs.
        """
        if len(ids) == 1 and covariances is None and not remove[0]:
            return self._merge_state(ids[0], int(stamps_ns[0]), positions, velocities,
                                     accelerations, radii, int(received_ns))
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
        named = ids if rows.size == len(ids) else [ids[k] for k in rows.tolist()]
        if type(named) is list:
            named = tuple(named)  # immutable: it can be kept and compared by identity
        last = self._last_named
        if (last is not None and last[2] == self._members_serial and type(named) is tuple
                and (named is last[0] or named == last[0])):
            # the ids of the last message, in its order, and no body came or went since (a
            # tracker array's frames): the slots it looked up (a comparison costs a fraction of
            # the look-ups, and none when a decoder handed the same tuple back)
            slots = last[1].copy()
        else:
            slots = np.fromiter(map(get, named, repeat(-1)), dtype=np.int64, count=rows.size)
        st = stamps if rows.size == stamps.shape[0] else stamps[rows]
        newer = np.empty(rows.size, dtype=bool)
        if newer_rows(slots, st, self._T, newer) == rows.size:
            fresh = EMPTY_I  # every body is stored (a tracker's frames): none to add
        else:
            known = slots >= 0
            if self._removals:
                for x in np.flatnonzero(~known).tolist():
                    gone = self._removals.get(ids[rows[x]])
                    if gone is not None:
                        if st[x] <= gone[0]:
                            # older than its removal: a late state of a removed body
                            newer[x] = False
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
            self._take_id(ids[rows[x]], s)
            self._rank_insert(s)
            slots[x] = s
        if fresh.size:
            self._add_utf8(slots[fresh])
        if type(named) is tuple and rows.size >= _COMPILED_STORE:
            self._last_named = (named, slots.copy(), self._members_serial)
        take = newer.copy()
        take[full] = False
        # every row taken (a tracker's frame): no gathers
        sl, src = (slots, rows) if take.all() else (slots[take], rows[take])
        if src.size:
            self._preserve(sl)
            big = src.size >= _COMPILED_STORE
            if big:
                # one kind of array for the kernel (C order, writeable: no specialisation per
                # input layout; a copy only of inputs that are not so)
                pva = [_c_f64(x) for x in (positions, velocities, accelerations)]
                r = _c_f64(radii)
                n_rows = stamps.shape[0]
                big = r.shape == (n_rows,) and all(
                    x.ndim == 2 and x.shape[0] == n_rows and x.shape[1] >= D for x in pva
                )  # else numpy's assignments below (which raise on bad shapes)
            if big:
                store_states(self._P, self._V, self._A, self._R, self._T, self._recv, sl, src,
                              *pva, r, np.require(stamps, np.int64, "CW"), received_ns)
            else:
                self._P[sl] = np.asarray(positions)[src, :D]
                self._V[sl] = np.asarray(velocities)[src, :D]
                self._A[sl] = np.asarray(accelerations)[src, :D]
                self._R[sl] = np.asarray(radii)[src]
                self._T[sl] = stamps[src]
                self._recv[sl] = received_ns
            if covariances is None:
                self._set_uncertain(sl, False)
            else:
                nonzero = np.empty(sl.size, dtype=np.bool_)
                _store_covariances(
                    self._C, sl, np.ascontiguousarray(covariances, dtype=np.float64), src, nonzero
                )
                self._set_uncertain(sl, nonzero)
            self._recv_floor = min(self._recv_floor, received_ns)
            if self._need_full or sl.size > max(8, self._full_frac * len(self._slot)):
                # the next query rebuilds every pair (as _flush would decide from the dirty
                # count): no need to list the changed bodies (a tracker array's frame)
                self._need_full = True
            else:
                self._dirty.update(sl.tolist())
            newest = int((st if src is rows else stamps[src]).max())
            if self.reference_ns is None or newest > self.reference_ns:
                self.reference_ns = newest
        if src.size or removed:
            self._version += 1
        return MergeResult(accepted=src, not_newer=rows[~newer], full=rows[full],
                           removed=np.array(removed, dtype=np.int64),
                           removal_ignored=np.array(removal_ignored, dtype=np.int64))

    def _merge_state(
        self, bid, stamp: int, positions, velocities, accelerations, radii, received_ns: int
    ) -> MergeResult:
        """merge of one exact state (a per-body stream's message) on scalars: the same rules
        and stored bits as the general path, without its array set-up."""
        s = self._slot.get(bid)
        if s is None:
            gone = self._removals.get(bid) if self._removals else None
            if gone is not None:
                if stamp <= gone[0]:
                    # a late state of a removed body
                    return MergeResult(EMPTY_I, _FIRST_ROW, EMPTY_I, EMPTY_I, EMPTY_I)
                del self._removals[bid]
            if self.max_bodies is not None and len(self._slot) >= self.max_bodies:
                return MergeResult(EMPTY_I, EMPTY_I, _FIRST_ROW, EMPTY_I, EMPTY_I)
            s = self._alloc()
            self._preserve((s,))
            self._take_id(bid, s)
            self._n_new = 1
            self._rank_insert(s)
            self._add_utf8(np.array([s], dtype=np.int64))
        elif stamp <= self._T[s]:
            return MergeResult(EMPTY_I, _FIRST_ROW, EMPTY_I, EMPTY_I, EMPTY_I)
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
        return MergeResult(_FIRST_ROW, EMPTY_I, EMPTY_I, EMPTY_I, EMPTY_I)

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

    def upsert(
        self, body_id: Hashable, p, v, a, r: float, stamp_ns: int, received_ns: int = 0
    ) -> MergeResult:
        """One body's state (see upsert_many)."""
        return self.upsert_many([body_id], np.asarray(p, dtype=np.float64)[None],
                                np.asarray(v, dtype=np.float64)[None],
                                np.asarray(a, dtype=np.float64)[None], [r], [stamp_ns], received_ns)

    def remove(self, body_id: Hashable, stamp_ns: int, received_ns: int = 0) -> bool:
        """A removal at ``stamp_ns``; True if it deleted the body."""
        res = self.merge([body_id], [stamp_ns], np.zeros((1, 3)), np.zeros((1, 3)),
                         np.zeros((1, 3)), [0.0], [True], received_ns)
        return bool(res.removed.size)

    def expire(self, now_ns: int, timeout_ns: int) -> list:
        """Drop bodies (and remembered removals) received before ``now_ns - timeout_ns``.

        Returns the ids dropped, sorted.
        """
        limit = int(now_ns) - int(timeout_ns)
        if self._removals and limit > self._removal_floor:
            self._removals = {k: v for k, v in self._removals.items() if v[1] >= limit}
            self._removal_floor = min((v[1] for v in self._removals.values()), default=NEVER)
        if limit <= self._recv_floor:
            return []  # every body was received at or after the floor
        stale = np.flatnonzero(self._alive & (self._recv < limit))
        kept = self._alive & (self._recv >= limit)
        self._recv_floor = int(self._recv[kept].min()) if kept.any() else NEVER
        gone = sorted(self._ids[s] for s in stale.tolist())
        for s in stale.tolist():
            self._drop(s)
        if gone:
            self._version += 1
        return gone

    def _drop(self, s: int) -> None:
        self._preserve((s,))
        del self._slot[self._ids[s]]
        self._members_serial += 1
        self._rank_remove(s)
        self._writable_ids()[s] = None
        self._alive[s] = False
        if self._ego[s]:
            self._ego[s] = False
            self._ego_slots = None
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
