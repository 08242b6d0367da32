"""Stateful scene for streams of body states: incremental whole-scene prediction.

Design (exactness first)
------------------------
* Every body is stored as it was given: ``(p, v, a, r)`` plus its reference
  time ``t_ref`` (the stamp the state refers to; default the scene time at the
  update).  States are never propagated in place, so advancing time never
  re-rounds them; ``state(id)`` propagates from ``t_ref`` in one step.
* The scene has a time ``now`` (``set_time`` / ``advance``, monotone) and an
  *epoch* ``E <= now``.  When ``now`` passes ``E + slack`` the epoch moves to
  ``now`` and everything is rebuilt, so ``now - E <= slack`` always.
* A pair ``(a, b)`` (``a`` orders before ``b`` by id) is evaluated at
  ``t_p = max(E, t_ref_a, t_ref_b)``: both states are propagated to ``t_p`` and
  the narrow phase runs with horizon ``H + slack`` giving ``tau``.  Because
  ``now - t_p <= slack`` that window covers ``[now, now + H]``.  The reported time is
  ``ttc = tau - (now - t_p)`` (bitwise ``tau`` when ``t_p == now``).  If the contact
  already lies in the past (``ttc < 0``: overlapping or touched since ``t_p``)
  the pair is evaluated again at ``now`` with horizon ``H``, on every query.
  Pairs with ``ttc <= H`` are reported.
* Swept bounds cover ``[max(E, t_ref), E + slack + H]``, which contains every
  reportable contact, so they stay valid until the epoch moves.
* Consequently a pair's result is a pure function of the two stored states,
  their ``t_ref``, ``E`` and ``now``; an update re-evaluates only the pairs of
  the updated bodies (found through a hashed uniform grid of the bounds),
  and ``advance`` only shifts cached times.  "Incremental equals
  full recomputation" therefore holds bitwise, where the full recomputation
  (:meth:`Scene.full_recomputation`) applies the same rule to all stored states
  from scratch.  A reported ``ttc`` may differ in the last bits from running the
  narrow phase on states propagated to ``now`` (it was evaluated at ``t_p``); it
  is identical when all bodies were updated at ``now`` *and* the narrow phase's
  root does not depend on the horizon argument.

``slack`` trades bound size (more candidates) against how often the epoch rolls
(full rebuild); the default is ``horizon / 4``.

Costs: an update of k bodies is O(k x neighbours) (hashed grid, numpy per
body) unless k exceeds ``full_rebuild_fraction`` of the scene, when one
vectorised rebuild is cheaper.  A query at an unchanged time merges the new
rows into the previous sorted result; after a time change it re-sorts the
cached records and re-evaluates only pairs whose contact has passed.

Typical node use (states stamped at various times, predictions relative to
the newest stamp)::

    scene.set_time(newest_stamp)
    scene.upsert_many(ids, P, V, A, R, stamps=stamps)   # stamps <= newest_stamp
    pred = scene.predictions()                            # ttc from newest_stamp
"""
from __future__ import annotations

import bisect
import math
from typing import Hashable, Iterable

import numpy as np

from circle_collision_ros.core import broad_phase as _bp
from circle_collision_ros.core.pair_predictions import (
    PairPredictions, details_on_pairs, narrow_on_pairs, validate_bodies, _check_horizon)

__all__ = ["Scene"]


def _idkey(x):
    # ids of one type compare natively; mixed types are grouped by type name
    return (type(x).__name__, x)


class Scene:
    """Bodies keyed by id with incrementally maintained pair predictions.

    Parameters
    ----------
    horizon : float
        Prediction horizon H, s (finite, > 0).
    dim : int
        2 or 3.
    time : float
        Initial scene time, s.
    slack : float, optional
        Epoch length, s (default ``horizon / 4``); see module docstring.
    method : str
        Broad-phase generator for full rebuilds (``"sweep"`` or ``"grid"``).
    full_rebuild_fraction : float
        If more than this fraction of bodies changed since the last query, all
        pairs are rebuilt with the vectorised broad phase instead of per body.

    Bodies are keyed by hashable ids; ids must be mutually orderable within a
    type (ids of different types are ordered by type name first).
    """

    def __init__(self, horizon: float, dim: int = 2, *, time: float = 0.0,
                 slack: float | None = None, method: str = "sweep",
                 full_rebuild_fraction: float = 0.05) -> None:
        self._h = _check_horizon(horizon)
        if dim not in (2, 3):
            raise ValueError(f"dim must be 2 or 3, got {dim}")
        self._dim = dim
        self._slack = self._h / 4.0 if slack is None else float(slack)
        if not (math.isfinite(self._slack) and self._slack >= 0.0):
            raise ValueError(f"slack must be finite and >= 0, got {slack!r}")
        t = float(time)
        if not math.isfinite(t):
            raise ValueError(f"time must be finite, got {time!r}")
        self._now = t
        self._epoch = t
        if method not in ("sweep", "grid"):
            raise ValueError(f"unknown broad-phase method {method!r}")
        self._method = method
        self._full_frac = float(full_rebuild_fraction)
        self.clear()

    # ------------------------------------------------------------------ basics
    def clear(self) -> None:
        """Remove all bodies (time and epoch are kept)."""
        cap = 16
        D = self._dim
        self._P = np.zeros((cap, D))
        self._V = np.zeros((cap, D))
        self._A = np.zeros((cap, D))
        self._R = np.zeros(cap)
        self._T = np.zeros(cap)
        self._lo = np.zeros((cap, D))
        self._hi = np.zeros((cap, D))
        self._alive = np.zeros(cap, dtype=bool)
        self._ids = np.full(cap, None, dtype=object)   # slot -> id
        self._keys: list = [None] * cap                  # slot -> _idkey(id)
        # id order: rank[slot] = position of its id in sorted order (-1: free);
        # maintained by bisection for single adds/removes, re-sorted in bulk
        self._rank = np.full(cap, -1, dtype=np.int64)
        self._okeys: list = []
        self._rank_ok = True
        self._slot: dict = {}
        self._free: list[int] = list(range(cap - 1, -1, -1))
        self._dirty: set[int] = set()
        self._need_full = True
        self._cell = 1.0
        self._grid_built = False
        self._clear_records()
        self._version = 0
        self._cache = None

    # Pair records: one row per pair with a contact within H + slack of its t_p,
    # in growable buffers; rows of updated bodies are marked dead (compacted
    # when dead rows dominate) so an update touches O(its pairs) rows.
    _REC = ("_ra", "_rb", "_rtp", "_rtau", "_rpt", "_rnm", "_rcs")

    def _clear_records(self, cap: int = 256) -> None:
        D = self._dim
        self._ra = np.zeros(cap, dtype=np.int64)  # slot of body a (orders first by id)
        self._rb = np.zeros(cap, dtype=np.int64)
        self._rtp = np.zeros(cap)                 # evaluation time t_p, s
        self._rtau = np.zeros(cap)                # narrow-phase time from t_p, s
        self._rpt = np.zeros((cap, D))
        self._rnm = np.zeros((cap, D))
        self._rcs = np.zeros(cap)
        self._rlive = np.zeros(cap, dtype=bool)
        self._rn = 0        # rows used
        self._rdead = 0     # dead rows among them
        self._new_rows: list[np.ndarray] = []  # rows stored since the last query
        self._out = None    # last query's sorted rows (slots and values), for merging

    @property
    def time(self) -> float:
        """Current scene time, s; predictions are relative to it."""
        return self._now

    @property
    def epoch(self) -> float:
        """Epoch E, s (pairs are evaluated at ``max(E, t_ref_a, t_ref_b)``)."""
        return self._epoch

    @property
    def horizon(self) -> float:
        return self._h

    @property
    def slack(self) -> float:
        return self._slack

    @property
    def dim(self) -> int:
        return self._dim

    def __len__(self) -> int:
        return len(self._slot)

    def __contains__(self, body_id: Hashable) -> bool:
        return body_id in self._slot

    def ids(self) -> list:
        """Body ids, sorted."""
        self._ensure_rank()
        return [k[1] for k in self._okeys]

    def _ensure_rank(self) -> None:
        if self._rank_ok:
            return
        slots = np.flatnonzero(self._alive)
        keys = self._keys
        order = sorted(slots.tolist(), key=keys.__getitem__)
        self._okeys = [keys[x] for x in order]
        self._rank[:] = -1
        self._rank[np.array(order, dtype=np.int64)] = np.arange(len(order))
        self._rank_ok = True

    def _rank_insert(self, s: int) -> None:
        if not self._rank_ok:
            return
        if len(self._okeys) > 64 and self._n_new > 32:
            self._rank_ok = False  # bulk insert: cheaper to re-sort once
            return
        pos = bisect.bisect_left(self._okeys, self._keys[s])
        self._okeys.insert(pos, self._keys[s])
        self._rank[self._rank >= pos] += 1
        self._rank[s] = pos

    def _rank_remove(self, s: int) -> None:
        if not self._rank_ok:
            return
        pos = int(self._rank[s])
        del self._okeys[pos]
        self._rank[self._rank > pos] -= 1
        self._rank[s] = -1

    # -------------------------------------------------------------------- time
    def set_time(self, t: float) -> None:
        """Move the scene clock to ``t`` (s, must not go backwards).

        Stored states are not touched (see module docstring); cached pair times
        shift.  Rolls the epoch (full rebuild at the next query) when
        ``t > epoch + slack``.
        """
        t = float(t)
        if not math.isfinite(t) or t < self._now:
            raise ValueError(f"scene time must be finite and non-decreasing: {t!r} < {self._now!r}"
                             " (use clear() after a clock reset)")
        if t == self._now:
            return
        self._now = t
        self._version += 1
        if t - self._epoch > self._slack:
            self._epoch = t
            self._need_full = True

    def advance(self, dt: float) -> None:
        """``set_time(time + dt)``, ``dt >= 0`` s: every body moves on its own parabola."""
        self.set_time(self._now + float(dt))

    # ---------------------------------------------------------------- updates
    def upsert(self, body_id: Hashable, p, v, a, r: float, stamp: float | None = None) -> None:
        """Insert or replace one body; ``p, v, a`` (D,) at time ``stamp`` (default now).

        Raises ValueError for non-finite values, negative radius, wrong shape or
        ``stamp > time`` (call ``set_time`` first).
        """
        self.upsert_many([body_id], np.asarray(p, dtype=np.float64)[None],
                         np.asarray(v, dtype=np.float64)[None],
                         np.asarray(a, dtype=np.float64)[None], [r],
                         None if stamp is None else [stamp])

    def add(self, body_id: Hashable, p, v, a, r: float, stamp: float | None = None) -> None:
        """Like :meth:`upsert` but KeyError if ``body_id`` already exists."""
        if body_id in self._slot:
            raise KeyError(f"body {body_id!r} already in scene")
        self.upsert(body_id, p, v, a, r, stamp)

    def upsert_many(self, ids: Iterable[Hashable], positions, velocities, accelerations,
                    radii, stamps=None) -> None:
        """Insert or replace several bodies; arrays ``(k, D)``/``(k,)``, ``stamps`` (k,) s or None.

        Validated as a whole before anything changes (ValueError names bad rows).
        """
        ids = list(ids)
        p, v, a, r = validate_bodies(positions, velocities, accelerations, radii)
        if p.shape[0] != len(ids) or p.shape[1] != self._dim:
            raise ValueError(f"expected {len(ids)} rows of dimension {self._dim}, got {p.shape}")
        if len(set(ids)) != len(ids):
            raise ValueError("duplicate ids in one update")
        if stamps is None:
            st = np.full(len(ids), self._now)
        else:
            st = np.asarray(stamps, dtype=np.float64).reshape(-1)
            if st.shape[0] != len(ids):
                raise ValueError("stamps must have one entry per id")
            bad = np.flatnonzero(~np.isfinite(st) | (st > self._now))
            if bad.size:
                raise ValueError(f"stamps must be finite and <= scene time {self._now}; rows {bad.tolist()}")
        get = self._slot.get
        slots = [get(b) for b in ids]
        self._n_new = slots.count(None)
        if self._n_new:
            for k, bid in enumerate(ids):
                if slots[k] is None:
                    s = self._alloc()
                    self._slot[bid] = s
                    self._ids[s] = bid
                    self._keys[s] = _idkey(bid)
                    self._alive[s] = True
                    self._rank_insert(s)
                    slots[k] = s
        sl = np.array(slots, dtype=np.int64)
        self._P[sl] = p
        self._V[sl] = v
        self._A[sl] = a
        self._R[sl] = r
        self._T[sl] = st
        self._dirty.update(slots)
        self._version += 1

    def remove(self, body_id: Hashable) -> None:
        """Remove one body (KeyError if absent)."""
        self.remove_many([body_id])

    def remove_many(self, ids: Iterable[Hashable]) -> None:
        """Remove several bodies (KeyError if any is absent; then nothing changes)."""
        ids = list(ids)
        missing = [b for b in ids if b not in self._slot]
        if missing:
            raise KeyError(f"unknown body id(s): {missing[:20]}")
        if len(ids) > 32:
            self._rank_ok = False
        for bid in ids:
            s = self._slot.pop(bid)
            self._rank_remove(s)
            self._ids[s] = None
            self._keys[s] = None
            self._alive[s] = False
            self._dirty.add(s)
            self._free.append(s)
        self._version += 1

    def _alloc(self) -> int:
        if not self._free:
            old = self._R.shape[0]
            new = 2 * old
            for name in ("_P", "_V", "_A", "_lo", "_hi"):
                arr = getattr(self, name)
                grown = np.zeros((new, self._dim))
                grown[:old] = arr
                setattr(self, name, grown)
            for name, dt in (("_R", np.float64), ("_T", np.float64), ("_alive", bool),
                             ("_rank", np.int64)):
                arr = getattr(self, name)
                grown = np.full(new, -1 if name == "_rank" else 0, dtype=dt)
                grown[:old] = arr
                setattr(self, name, grown)
            ids = np.full(new, None, dtype=object)
            ids[:old] = self._ids
            self._ids = ids
            self._keys.extend([None] * (new - old))
            if self._grid_built:
                stale = np.ones(new, dtype=bool)
                stale[:old] = self._gstale
                self._gstale = stale
            self._free = list(range(new - 1, old - 1, -1))
        return self._free.pop()

    # ------------------------------------------------------------------ states
    def state(self, body_id: Hashable) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
        """``(p, v, a, r)`` of one body propagated to the scene time."""
        s = self._slot[body_id]
        p, v = _bp.propagate(self._P[s], self._V[s], self._A[s], self._now - self._T[s])
        return p, v, self._A[s].copy(), float(self._R[s])

    def states(self) -> tuple[list, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(ids, P, V, A, R)`` of all bodies at the scene time, ids sorted."""
        ids = self.ids()
        sl = np.array([self._slot[b] for b in ids], dtype=np.int64)
        P, V = _bp.propagate(self._P[sl], self._V[sl], self._A[sl], self._now - self._T[sl])
        return ids, P, V, self._A[sl].copy(), self._R[sl].copy()

    def stored_states(self) -> tuple[list, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(ids, P, V, A, R, T_ref)``: states exactly as stored (at their own ``T_ref``), ids sorted."""
        ids = self.ids()
        sl = np.array([self._slot[b] for b in ids], dtype=np.int64)
        return (ids, self._P[sl].copy(), self._V[sl].copy(), self._A[sl].copy(),
                self._R[sl].copy(), self._T[sl].copy())

    # ------------------------------------------------------------ pair engine
    def _bounds(self, slots: np.ndarray):
        t_end = self._epoch + self._slack + self._h
        tr = self._T[slots]
        t0 = np.maximum(self._epoch, tr) - tr
        return _bp.swept_bounds(self._P[slots], self._V[slots], self._A[slots], self._R[slots],
                                t0, t_end - tr)

    def _evaluate(self, A: np.ndarray, B: np.ndarray, t_eval: np.ndarray | None, horizon: float):
        """Narrow phase + details for slot pairs (A[k], B[k]) at times t_eval (None: rule t_p)."""
        if t_eval is None:
            t_eval = np.maximum(self._epoch, np.maximum(self._T[A], self._T[B]))
        pa, va = _bp.propagate(self._P[A], self._V[A], self._A[A], t_eval - self._T[A])
        pb, vb = _bp.propagate(self._P[B], self._V[B], self._A[B], t_eval - self._T[B])
        aa, ab, ra, rb = self._A[A], self._A[B], self._R[A], self._R[B]
        tau = narrow_on_pairs(pa, va, aa, ra, pb, vb, ab, rb, horizon)
        hit = tau <= horizon
        h = np.flatnonzero(hit)
        pt, nm, cs = details_on_pairs(pa[h], va[h], aa[h], ra[h], pb[h], vb[h], ab[h], rb[h], tau[h])
        return hit, t_eval[h], tau[h], pt, nm, cs

    def _orient(self, X: np.ndarray, Y: np.ndarray):
        """Order each slot pair so that the first body's id sorts first."""
        self._ensure_rank()
        swap = self._rank[X] > self._rank[Y]
        return np.where(swap, Y, X), np.where(swap, X, Y)

    def _pairs_full(self):
        """All candidate slot pairs (a before b by id), from scratch."""
        self._ensure_rank()
        slots = np.flatnonzero(self._alive)
        slots = slots[np.argsort(self._rank[slots])]
        lo, hi = self._bounds(slots)
        self._last_bounds = (slots, lo, hi)
        if slots.size < 2:
            e = np.empty(0, dtype=np.int64)
            return slots, e, e.copy()
        I, J, _ = _bp.candidate_pairs(
            lo, hi, p=self._P[slots], v=self._V[slots], a=self._A[slots], r=self._R[slots],
            tref=self._T[slots], t_start=self._epoch, t_end=self._epoch + self._slack + self._h,
            method=self._method)
        # local indices follow sorted-id order, and candidate_pairs returns I < J
        return slots, slots[I], slots[J]

    def _store(self, A, B, res) -> None:
        hit, tp, tau, pt, nm, cs = res
        k = tp.shape[0]
        n = self._rn
        if n + k > self._rlive.shape[0]:
            live = np.flatnonzero(self._rlive[:n])
            new_cap = max(256, 2 * (live.size + k))
            old = [getattr(self, name)[live] for name in self._REC]
            self._new_rows = []  # row numbers change; the merge path is not used
            self._out = None
            self._clear_records(new_cap)
            n = live.size
            for name, arr in zip(self._REC, old):
                getattr(self, name)[:n] = arr
            self._rlive[:n] = True
        sl = slice(n, n + k)
        self._ra[sl] = A[hit]
        self._rb[sl] = B[hit]
        self._rtp[sl] = tp
        self._rtau[sl] = tau
        self._rpt[sl] = pt
        self._rnm[sl] = nm
        self._rcs[sl] = cs
        self._rlive[sl] = True
        self._rn = n + k
        self._new_rows.append(np.arange(n, n + k))

    def _kill_rows(self, slots: np.ndarray) -> None:
        n = self._rn
        if n == 0:
            return
        if slots.size == 1:
            s = slots[0]
            m = (self._ra[:n] == s) | (self._rb[:n] == s)
        else:
            m = np.isin(self._ra[:n], slots) | np.isin(self._rb[:n], slots)
        m &= self._rlive[:n]
        self._rdead += int(np.count_nonzero(m))
        self._rlive[:n][m] = False

    def _live_rows(self):
        idx = np.flatnonzero(self._rlive[:self._rn])
        return tuple(getattr(self, name)[idx] for name in self._REC)

    def _rebuild_all(self) -> None:
        self._clear_records()
        slots, A, B = self._pairs_full()
        if slots.size:
            _, lo, hi = self._last_bounds
            self._lo[slots] = lo
            self._hi[slots] = hi
        self._store(A, B, self._evaluate(A, B, None, self._h + self._slack))
        self._grid_built = False  # rebuilt lazily when a small update needs it
        self._dirty.clear()
        self._need_full = False

    # Grid for per-body neighbour queries: a static part (sorted hashed cell
    # keys -> slots, built vectorised) plus a small dict overlay for bodies
    # updated since; static entries of updated/removed slots are masked stale.
    def _build_grid(self) -> None:
        slots = np.flatnonzero(self._alive)
        if slots.size:
            self._cell, _ = _bp.choose_cell_size(self._lo[slots], self._hi[slots])
        keys, owner, big = _bp.cell_keys(self._lo[slots], self._hi[slots], self._cell,
                                         _bp._MAX_CELLS_PER_BODY)
        o = np.argsort(keys, kind="stable")
        self._gkeys = keys[o]
        self._gslot = slots[owner[o]]
        self._gstale = np.zeros(self._R.shape[0], dtype=bool)
        self._big = set(slots[big].tolist())
        self._overlay: dict = {}
        self._ocells: dict = {}
        self._grid_built = True

    def _grid_remove(self, s: int) -> None:
        self._gstale[s] = True
        self._big.discard(s)
        for k in self._ocells.pop(s, ()):
            b = self._overlay[k]
            b.discard(s)
            if not b:
                del self._overlay[k]

    def _grid_insert_query(self, s: int) -> np.ndarray:
        """Insert slot s (bounds already set) into the overlay; return its candidate slots."""
        keys, _, big = _bp.cell_keys(self._lo[s:s + 1], self._hi[s:s + 1], self._cell,
                                     _bp._MAX_CELLS_PER_BODY)
        if big[0]:
            self._big.add(s)
            return np.flatnonzero(self._alive)
        kl = keys.tolist()
        ov = self._overlay
        m = set(self._big)
        for k in kl:
            b = ov.get(k)
            if b is None:
                ov[k] = {s}
            else:
                m.update(b)
                b.add(s)
        self._ocells[s] = kl
        lo = np.searchsorted(self._gkeys, keys, side="left")
        hi = np.searchsorted(self._gkeys, keys, side="right")
        parts = [self._gslot[x:y] for x, y in zip(lo.tolist(), hi.tolist()) if y > x]
        if parts:
            c = np.concatenate(parts)
            parts = [c[~self._gstale[c]]]
        if m:
            parts.append(np.fromiter(m, dtype=np.int64, count=len(m)))
        return np.concatenate(parts) if parts else np.empty(0, dtype=np.int64)

    def _update_incremental(self) -> None:
        dirty = np.array(sorted(self._dirty), dtype=np.int64)
        self._kill_rows(dirty)
        if not self._grid_built or len(self._ocells) > max(64, len(self._slot) // 4):
            # (re)build the static part from the current bounds; dirty slots
            # are re-inserted below through the overlay
            self._build_grid()
        for s in dirty.tolist():
            self._grid_remove(s)
        live = dirty[self._alive[dirty]]
        if live.size:
            lo, hi = self._bounds(live)
            self._lo[live] = lo
            self._hi[live] = hi
        X, Y = [], []
        for s in live.tolist():
            cand = self._grid_insert_query(s)
            cand = cand[cand != s]
            ov = np.all((self._lo[cand] <= self._hi[s]) & (self._hi[cand] >= self._lo[s]), axis=1)
            cand = cand[ov]
            X.append(np.full(cand.shape[0], s, dtype=np.int64))
            Y.append(cand)
        self._dirty.clear()
        if not X:
            return
        X = np.concatenate(X)
        Y = np.concatenate(Y)
        # a pair of two updated bodies (or a body listed in two cells) appears
        # more than once: keep one copy
        cap = np.int64(self._R.shape[0])
        key = np.unique(np.minimum(X, Y) * cap + np.maximum(X, Y))
        A, B = self._orient(key // cap, key % cap)
        keep = _bp.relative_filter(self._P, self._V, self._A, self._R, self._T, A, B,
                                   self._epoch, self._epoch + self._slack + self._h)
        A, B = A[keep], B[keep]
        self._store(A, B, self._evaluate(A, B, None, self._h + self._slack))

    def _flush(self) -> bool:
        """Bring pair records up to date; True if only a few bodies changed
        (the last query's sorted rows can then be merged instead of re-sorted)."""
        n = len(self._slot)
        if self._need_full or len(self._dirty) > max(8, self._full_frac * n):
            self._rebuild_all()
            return False
        if self._dirty:
            self._changed = np.array(sorted(self._dirty), dtype=np.int64)
            self._update_incremental()
        else:
            self._changed = np.empty(0, dtype=np.int64)
        return True

    # ------------------------------------------------------------------ query
    def predictions(self) -> PairPredictions:
        """Pairs touching within ``[time, time + horizon]``, soonest first, with ids.

        ``i``/``j`` hold body ids (``i`` sorts before ``j``); ``ttc`` is relative to
        :attr:`time`; the arrays are read-only (shared with the cache).  Cached
        until the scene changes.  After a small update at
        an unchanged time, the previous sorted rows are merged with the new ones
        (O(K) copies, no sort); otherwise everything is re-sorted.
        """
        if self._cache is not None and self._cache[0] == self._version:
            return self._cache[1]
        small = self._flush()
        out = self._out
        if (small and out is not None and out[0] == self._now and out[1] == self._epoch):
            rows = self._merge(out[2], self._changed, self._new_rows)
        else:
            rows = self._sort(self._resolve(*self._live_rows()))
        self._new_rows = []
        if self._rdead > max(1024, self._rn // 2):
            self._compact()
        self._out = (self._now, self._epoch, rows)
        res = self._publish(rows)
        self._cache = (self._version, res)
        return res

    def _compact(self) -> None:
        A, B, tp, tau, pt, nm, cs = self._live_rows()
        self._clear_records(max(256, 2 * A.size))
        self._store(A, B, (np.ones(A.size, dtype=bool), tp, tau, pt, nm, cs))
        self._new_rows = []

    def _resolve(self, A, B, tp, tau, pt, nm, cs):
        """Records -> reportable rows ``(A, B, ttc, pt, nm, cs)`` at the scene time."""
        ttc = tau - (self._now - tp)
        past = np.flatnonzero(ttc < 0.0)
        if past.size:
            # contact already happened since t_p: first contact from now, evaluated at now
            Ap, Bp = A[past], B[past]
            hit, _, tau2, pt2, nm2, cs2 = self._evaluate(Ap, Bp, np.full(past.size, self._now), self._h)
            fut = np.flatnonzero(ttc >= 0.0)
            A = np.concatenate([A[fut], Ap[hit]])
            B = np.concatenate([B[fut], Bp[hit]])
            ttc = np.concatenate([ttc[fut], tau2])
            pt = np.concatenate([pt[fut], pt2])
            nm = np.concatenate([nm[fut], nm2])
            cs = np.concatenate([cs[fut], cs2])
        k = np.flatnonzero(ttc <= self._h)
        return A[k], B[k], ttc[k], pt[k], nm[k], cs[k]

    def _pair_key(self, A, B):
        return self._rank[A] * np.int64(self._R.shape[0]) + self._rank[B]

    def _sort(self, rows):
        """Sort rows by (ttc, id_a, id_b): pair-rank order, then a stable sort on
        ttc (np.lexsort is several times slower)."""
        A, B, ttc = rows[0], rows[1], rows[2]
        if ttc.size == 0:
            return rows
        self._ensure_rank()
        o = np.argsort(self._pair_key(A, B), kind="stable")
        o = o[np.argsort(ttc[o], kind="stable")]
        return tuple(x[o] for x in rows)

    def _merge(self, old, changed, new_rows):
        """Previous sorted rows minus those of changed bodies, plus the new
        records' rows inserted in order.  Keys (ttc, rank_a, rank_b) are unique
        per pair, so this equals a full sort."""
        A, B = old[0], old[1]
        if changed.size:
            if changed.size == 1:
                drop = (A == changed[0]) | (B == changed[0])
            else:
                drop = np.isin(A, changed) | np.isin(B, changed)
            if drop.any():
                keep = ~drop
                old = tuple(x[keep] for x in old)
        if not new_rows:
            return old
        idx = np.concatenate(new_rows)
        new = self._sort(self._resolve(*(getattr(self, nm)[idx] for nm in self._REC)))
        if new[2].size == 0:
            return old
        self._ensure_rank()
        ttc_o = old[2]
        lo = np.searchsorted(ttc_o, new[2], side="left")
        hi = np.searchsorted(ttc_o, new[2], side="right")
        pos = lo.copy()
        key_new = self._pair_key(new[0], new[1])
        for k in np.flatnonzero(hi > lo).tolist():  # equal times: place by id order
            pos[k] = lo[k] + np.searchsorted(self._pair_key(old[0][lo[k]:hi[k]], old[1][lo[k]:hi[k]]),
                                             key_new[k])
        return tuple(np.insert(x, pos, y, axis=0) for x, y in zip(old, new))

    def _publish(self, rows) -> PairPredictions:
        A, B, ttc, pt, nm, cs = rows
        if ttc.size == 0:
            return PairPredictions.empty(self._dim, id_dtype=object)
        for x in rows:
            x.flags.writeable = False  # shared with the merge cache
        return PairPredictions(self._ids[A], self._ids[B], ttc, pt, nm, cs)

    def full_recomputation(self) -> PairPredictions:
        """Predictions recomputed from the stored states alone (no caches touched).

        Applies exactly the rule of the module docstring to every stored body;
        used by tests to prove the incremental path is bitwise equal to it.
        """
        _, A, B = self._pairs_full()
        hit, tp, tau, pt, nm, cs = self._evaluate(A, B, None, self._h + self._slack)
        return self._publish(self._sort(self._resolve(A[hit], B[hit], tp, tau, pt, nm, cs)))
