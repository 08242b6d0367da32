"""The scene's slot store: allocation and growth of the per-body arrays, ids and their
UTF-8 blob, the uncertain flags, and each body's swept bounds.

A part of ``Scene`` (scene.py declares and initialises the state in ``Scene.clear``).
``propagate_ns`` is the one propagation of stored states (integer ns differences).
"""
from __future__ import annotations

import numpy as np

from circle_collision_ros.core import broad as _broad
from circle_collision_ros.core.scene import kernels as _sk

__all__ = ["StoreMixin", "propagate_ns", "EMPTY_I"]


def propagate_ns(P, V, A, dt_ns):
    """States moved by ``dt_ns`` (int64 ns, >= 0): ``p + dt (v + (dt/2) a)``, ``v + dt a``."""
    # Integer subtraction first (by the caller): stamps ~1.7e18 ns would lose detail as floats.
    dt = (np.asarray(dt_ns).astype(np.float64) * 1e-9)[:, None]
    return P + dt * (V + (0.5 * dt) * A), V + dt * A


EMPTY_I = np.empty(0, dtype=np.int64)


class StoreMixin:
    """Scene's slots: allocation, ids (UTF-8), uncertain flags, swept bounds."""

    def _set_uncertain(self, slots, flags) -> None:
        """_U[slots] = flags, counting the uncertain bodies: an exact scene skips the
        uncertain query in O(1) instead of a pass over every slot."""
        if flags is False and self._n_uncertain == 0:
            return  # no body is uncertain: every flag is False already
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
                             ("_recv", np.int64), ("_alive", bool), ("_ego", bool),
                             ("_rank", np.int64),
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
            _sk.swept_bound_rows(
                self._P, self._V, self._A, self._R, slots, t0, t1, self._lo, self._hi
            )
        else:
            self._lo[slots], self._hi[slots] = _broad.swept_bounds(
                self._P[slots], self._V[slots], self._A[slots], self._R[slots], t0, t1
            )
