"""The scene's order: ids in sorted order (ranks), the reported rows kept sorted between
queries and repaired, and their publication as SceneContacts.

A part of ``Scene``.
"""
from __future__ import annotations

import bisect

import numpy as np

from circle_collision_ros.core.scene import kernels as _sk
from circle_collision_ros.core.scene.results import SceneContacts
from circle_collision_ros.core.scene.store import EMPTY_I, propagate_ns

__all__ = ["OrderingMixin"]


class OrderingMixin:
    """Scene's id order and the sorted, published prediction."""

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

    # ------------------------------------------------------------------ query
    #: Scattered records are compacted into the kept order from this many on: below it the
    #: query's walk over them costs less than the compaction's array set-up (an ego-centred
    #: scene's few records: bench/bench_ego.py).
    _SCATTERED_ROWS = 256

    def predictions(self) -> SceneContacts:
        """Pairs touching within ``[R, R + H]`` by the rule of the module docstring.

        Cached until the scene changes.  Work after a small update: the changed
        bodies' pairs, one pass over the kept order (times shifted to the new
        reference time, order repaired where rounding swapped neighbours, new
        rows merged in) and the pairs whose contact began before R (evaluated
        at R); see _ordered_rows.
        """
        self.evaluated_pairs = 0
        self.box_tests = 0
        if self._cache is not None and self._cache[0] == self._version:
            return self._cache[1]
        self._flush()
        rows, id_rows = self._ordered_rows()
        self._new_rows = []
        if self._rdead > max(1024, self._rn // 2) or (self._records_scattered
                                                      and self._rn > self._SCATTERED_ROWS):
            self._compact()
            self._records_scattered = False
        res = self._publish(rows, id_rows)
        self._cache = (self._version, res)
        return res

    def compile_ordering(self) -> None:
        """Compile (or load) the kernels that order and merge the rows, on this scene's record
        arrays, without evaluating a pair: they never call the solver, so a set-up can compile
        them beside it (``core.warm_up``); ``predictions`` then finds them compiled.  Also the
        ego broad phase (kernels.ego_pairs, see set_ego) and merge's store of many states
        (stream.store_states), on no row: neither calls the solver either."""
        from circle_collision_ros.core.scene.stream import store_states

        D, f64 = self._dim, np.float64
        store_states(self._P, self._V, self._A, self._R, self._T, self._recv, EMPTY_I, EMPTY_I,
                      np.zeros((0, D)), np.zeros((0, D)), np.zeros((0, D)), np.zeros(0),
                      np.zeros(0, dtype=np.int64), 0)
        _sk.ego_pairs(EMPTY_I, EMPTY_I, self._alive, self._ego, self._ego_members(), self._P,
                      self._V, self._A, self._R, self._T, self._Tf, self._lo, self._hi, 0,
                      self._slack_ns, self._h, f64(self._slack_ns * 1e-9 + self._h), self._rank,
                      np.int64(self._R.shape[0]))
        live = self._rlive
        _sk.split_and_order(EMPTY_I, np.flatnonzero(live[:self._rn]), EMPTY_I, live, self._rkey,
                            self._rtp, self._rtau, 0, 1024)
        # the merge with the types reported_rows passes (fresh C arrays): no future row and one
        # past one, record 0 (read, not written: the buffers exist from construction)
        one, zero = np.zeros(1, dtype=np.int64), np.zeros(1)
        rows = np.zeros((1, self._rpt.shape[1]))
        _sk.assemble(EMPTY_I, np.empty(0), EMPTY_I, one, zero, np.zeros(1, dtype=np.bool_), rows,
                     rows, zero, self._ra, self._rb, self._rkey, self._rids, self._rtp, self._rtau,
                     self._rov, self._rpt, self._rnm, self._rcs, 0)

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
            self._fut, self._fut_ttc, self._past = EMPTY_I, np.empty(0), EMPTY_I
            e = np.empty(0)
            return (EMPTY_I, EMPTY_I, e, EMPTY_I, np.empty(0, dtype=bool),
                    np.empty((0, D)), np.empty((0, D)), e), None
        live, tp_all, tau_all = self._rlive, self._rtp, self._rtau
        if self._fut is None:  # after a rebuild: every live record is new
            prev, prev_past = EMPTY_I, EMPTY_I
            new = np.flatnonzero(live[:self._rn])
        else:
            prev, prev_past = self._fut, self._past
            new = np.concatenate(self._new_rows) if self._new_rows else EMPTY_I
        self._ensure_rank()
        basis = (self._rank_serial, self._R.shape[0], self._utf8_serial)
        key_from = self._rkey_n if basis == self._rkey_basis else 0  # else every key is stale
        fut, ttc, past, rows, evaluated, id_rows = _sk.ordered_query(prev, new, prev_past, live,
                                                                     self._ra, self._rb, self._rkey,
                                                                     self._rids, key_from, self._rn,
                                                                     tp_all, tau_all, self._rov,
                                                                     self._rpt, self._rnm,
                                                                     self._rcs, self._rsP,
                                                                     self._rsV, self._rsA,
                                                                     self._rsR, self._rsT, R,
                                                                     self._h, self._rank,
                                                                     np.int64(basis[1]), 1024,
                                                                     self._id_start, self._id_len,
                                                                     self._Z)
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
            return (EMPTY_I, EMPTY_I, e, EMPTY_I, np.empty(0, dtype=bool), np.empty((0, self._dim)),
                    np.empty((0, self._dim)), e)
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
                Ap, Bp, np.full(past.size, R, dtype=np.int64), self._h, compiled
            )
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
            pa, _ = propagate_ns(self._P[Az], self._V[Az], self._A[Az], R - self._T[Az])
            pb, _ = propagate_ns(self._P[Bz], self._V[Bz], self._A[Bz], R - self._T[Bz])
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
            # be a shared constant (EMPTY_I) that the kernels also take: freezing it would give
            # every later kernel call a new read-only specialisation to compile
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
            return self._publish(self._resolve(EMPTY_I, EMPTY_I, None, None, None, None, None))
        saved_epoch, saved_lo, saved_hi, saved_tf = (self._epoch, self._lo.copy(), self._hi.copy(),
                                                     self._Tf.copy())
        try:
            self._epoch = self.epoch_ns
            _, A, B = self._pairs_full()
            hit, tp, tau, pt, nm, cs, _ = self._evaluate_at_tp(A, B, compiled=False)
            return self._publish(
                self._sort(self._resolve(A[hit], B[hit], tp, tau, pt, nm, cs, compiled=False))
            )
        finally:
            self._epoch, self._lo, self._hi, self._Tf = saved_epoch, saved_lo, saved_hi, saved_tf
