"""The scene's pair records: evaluation of candidate pairs at their pair time, the full
rebuild, the hashed grid of per-body updates and the incremental update.

A part of ``Scene`` (the records' buffers are declared in ``Scene._clear_records``).
"""
from __future__ import annotations

import numpy as np

from circle_collision_ros.core import broad as _broad
from circle_collision_ros.core.narrow.contact import details_on_rows
from circle_collision_ros.core.scene import kernels as _sk
from circle_collision_ros.core.scene.all_pairs import narrow_on_pairs
from circle_collision_ros.core.scene.store import EMPTY_I, propagate_ns

__all__ = ["PairsMixin"]


class PairsMixin:
    """Scene's pair records: one row per pair with a contact within H + S of its t_p."""

    #: Below this many pairs the compiled row loop (kernels.evaluate_rows) beats the
    #: vectorised batch (its numpy set-up per call; measured: bench/bench_scene.py); both
    #: give the same bits.
    COMPILED_ROWS = 4096

    def _evaluate(self, A: np.ndarray, B: np.ndarray, t_eval: np.ndarray, horizon: float,
                  compiled: bool | None = None):
        """Narrow phase + details for slot pairs (A[k], B[k]) at t_eval (ns); the hits
        ``(hit, t_eval, tau, point, normal, closing, overlapping)``.

        compiled : None picks by size; False forces the vectorised numpy path
            (full_recomputation, the reference the compiled path is tested against).
        """
        n = A.shape[0]
        if compiled is None:
            compiled = n < self.COMPILED_ROWS
        if compiled:
            D = self._dim
            tau, pt, nm = np.empty(n), np.empty((n, D)), np.empty((n, D))
            cs, ov = np.empty(n), np.empty(n, dtype=bool)
            if n:  # (no rows: nothing to evaluate, and no need of the solver's kernels)
                self.evaluated_pairs += _sk.evaluate_rows(self._P, self._V, self._A, self._R,
                                                          self._T, A, B, t_eval, horizon, tau, pt,
                                                          nm, cs, ov, self._Z)
            hit = tau <= horizon
            if hit.all():
                return hit, t_eval, tau, pt, nm, cs, ov
            h = np.flatnonzero(hit)
            return hit, t_eval[h], tau[h], pt[h], nm[h], cs[h], ov[h]
        pa, va = propagate_ns(self._P[A], self._V[A], self._A[A], t_eval - self._T[A])
        pb, vb = propagate_ns(self._P[B], self._V[B], self._A[B], t_eval - self._T[B])
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

    def compile_evaluation(self) -> None:
        """Compile (or load) the kernels that evaluate pairs and store their records, on this
        scene's arrays and no pair: they call the solver and no broad-phase or ordering kernel,
        so a set-up can compile them as soon as the solver is (``core.warm_up``)."""
        D, e = self._dim, np.empty(0)
        _sk.evaluate_rows(self._P, self._V, self._A, self._R, self._T, EMPTY_I, EMPTY_I, EMPTY_I,
                          self._h_eval, e, np.empty((0, D)), np.empty((0, D)), e,
                          np.empty(0, dtype=np.bool_), self._Z)
        _sk.evaluate_and_store(EMPTY_I, EMPTY_I, 0, self._P, self._V, self._A, self._R, self._T,
                               self._h_eval, self._ra, self._rb, self._rtp, self._rtau, self._rpt,
                               self._rnm, self._rcs, self._rov, self._rlive, self._rnext,
                               self._rhead, self._rsP, self._rsV, self._rsA, self._rsR, self._rsT,
                               self._reserve_records(0), self._Z)

    def _evaluate_at_tp(self, A, B, compiled: bool | None = None):
        t_p = np.maximum(self._epoch, np.maximum(self._T[A], self._T[B]))
        return self._evaluate(A, B, t_p, self._h_eval, compiled)

    def _pairs_full(self):
        """All candidate slot pairs (a before b by id), from scratch; sets bounds.

        With an ego set (set_ego), only the pairs with an ego body: each ego body's bounds
        against every body's (kernels.ego_pairs, no sweep), the same pairs as the sweep's
        that contain an ego body."""
        slots = self._sorted_slots()
        if self._ego_ids:
            if slots.size < 2:  # (bounds of a lone body: as below)
                if slots.size:
                    self._Tf[slots] = (self._T[slots] - self._epoch).astype(np.float64) * 1e-9
                    self._set_bounds(slots)
                return slots, EMPTY_I, EMPTY_I
            ego = self._ego_members()
            A, B, tests = _sk.ego_pairs(slots, ego, self._alive, self._ego, ego, self._P,
                                        self._V, self._A, self._R, self._T, self._Tf, self._lo,
                                        self._hi, self._epoch, self._slack_ns, self._h,
                                        self._slack_ns * 1e-9 + self._h, self._rank,
                                        np.int64(self._R.shape[0]))
            self.box_tests += tests
            return slots, A, B
        if slots.size:
            self._Tf[slots] = (self._T[slots] - self._epoch).astype(np.float64) * 1e-9
            self._set_bounds(slots)
        if slots.size < 2:
            return slots, EMPTY_I, EMPTY_I
        I, J, _ = _broad.candidate_pairs(self._lo[slots], self._hi[slots], p=self._P[slots],
                                         v=self._V[slots], a=self._A[slots], r=self._R[slots],
                                         tref=self._Tf[slots], t_start=0.0,
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
            getattr(self, name)[: live.size] = arr
        self._rlive[: live.size] = True
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
            self._rdead += int(
                _sk.kill_records(slots, self._ra, self._rnext, self._rhead, self._rlive)
            )

    def _rebuild_all(self) -> None:
        self._clear_records()
        _, A, B = self._pairs_full()
        self._store_pairs(A, B)  # a few pairs (an ego set's): one compiled pass
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
            self._cell, _ = _broad.choose_cell_size(self._lo[slots], self._hi[slots])
        keys, owner, big = _broad.cell_keys(
            self._lo[slots], self._hi[slots], self._cell, _broad.MAX_CELLS_PER_BODY
        )
        # Any order within a cell will do: a query sorts and dedups the pairs it collects
        # (incremental_pairs), so quicksort (measured faster than a stable sort).
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
        if self._ego_ids:
            # only the pairs with an ego body: a changed ego body's bounds against every body's,
            # another changed body's against the ego bodies' (no grid)
            self._ensure_rank()
            A, B, tests = _sk.ego_pairs(dirty, dirty, self._alive, self._ego, self._ego_members(),
                                        self._P, self._V, self._A, self._R, self._T, self._Tf,
                                        self._lo, self._hi, self._epoch, self._slack_ns, self._h,
                                        self._slack_ns * 1e-9 + self._h, self._rank,
                                        np.int64(self._R.shape[0]))
            self.box_tests += tests
            self._store_pairs(A, B)
            return
        if not self._grid_built or self._n_moved + dirty.size > max(
            64, len(self._slot) // self._MOVED_FRACTION
        ):
            # (re)build the static part from the current bounds; dirty slots
            # are marked stale and searched as moved below
            self._build_grid()
        self._ensure_rank()
        A, B, self._n_moved = _sk.incremental_pairs(dirty, self._alive, self._P, self._V, self._A,
                                                    self._R, self._T, self._Tf, self._lo, self._hi,
                                                    self._epoch, self._slack_ns, self._h,
                                                    self._slack_ns * 1e-9 + self._h, self._cell,
                                                    _broad.MAX_CELLS_PER_BODY, self._gkeys,
                                                    self._gslot, self._gstale, self._gbig,
                                                    self._moved, self._n_moved, self._inmoved,
                                                    self._rank, np.int64(self._R.shape[0]))
        self._store_pairs(A, B)

    def _store_pairs(self, A: np.ndarray, B: np.ndarray) -> None:
        """Evaluate candidate pairs (A, B) (new ones of an incremental update, or all of a
        rebuild) and store the hits."""
        if A.size == 0:
            return
        if A.size >= self.COMPILED_ROWS:
            self._store(A, B, self._evaluate_at_tp(A, B))
            return
        n = self._reserve_records(A.size)
        end, evaluated = _sk.evaluate_and_store(A, B, self._epoch, self._P, self._V, self._A,
                                                self._R, self._T, self._h_eval, self._ra, self._rb,
                                                self._rtp, self._rtau, self._rpt, self._rnm,
                                                self._rcs, self._rov, self._rlive, self._rnext,
                                                self._rhead, self._rsP, self._rsV, self._rsA,
                                                self._rsR, self._rsT, n, self._Z)
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
