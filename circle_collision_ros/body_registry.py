"""The scene's bodies: the latest accepted state per id, and their common time.

Deterministic by construction, so that replaying the same inputs reproduces
the same scene bit for bit:

- a body's state is replaced only by a strictly newer header stamp (an older
  or equal one arriving late is ignored, which also makes duplicates harmless);
- the reference time is the newest stamp ever accepted (integer ns, monotone);
- staleness is judged on the receiving clock passed in by the caller (the node's
  clock live, the recorded receive time in replay), never read here;
- bodies are ordered by id when exported, independent of arrival order.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class BodyState:
    """One body's state as received: stamp (ns since epoch) and SI quantities."""

    stamp_ns: int
    received_ns: int
    radius: float
    position: tuple[float, float, float]
    velocity: tuple[float, float, float]
    acceleration: tuple[float, float, float]


@dataclass(frozen=True)
class SceneSnapshot:
    """All bodies propagated to `reference_ns`, ordered by id; arrays are (N, D) and (N,)."""

    reference_ns: int
    ids: list[str]
    positions: np.ndarray
    velocities: np.ndarray
    accelerations: np.ndarray
    radii: np.ndarray


class UpdateResult:
    """What an update did with one state."""

    ACCEPTED = "accepted"
    NOT_NEWER = "not newer than the body's current state"
    REMOVED = "removed"
    UNKNOWN_REMOVAL = "removal of an unknown id"
    FULL = "scene full"


class BodyRegistry:
    """Latest state per body id, with removal, expiry and propagation.

    Parameters
    ----------
    max_bodies : new ids beyond this many are refused (UpdateResult.FULL), which
        bounds memory and compute when a source floods the node.
    """

    def __init__(self, max_bodies: int) -> None:
        self.max_bodies = max_bodies
        self._bodies: dict[str, BodyState] = {}
        self.reference_ns: int | None = None

    def __len__(self) -> int:
        return len(self._bodies)

    def __contains__(self, body_id: str) -> bool:
        return body_id in self._bodies

    def update(self, body_id: str, state: BodyState) -> str:
        """Store `state` if it is newer than what `body_id` has; returns an UpdateResult."""
        old = self._bodies.get(body_id)
        if old is not None and state.stamp_ns <= old.stamp_ns:
            return UpdateResult.NOT_NEWER
        if old is None and len(self._bodies) >= self.max_bodies:
            return UpdateResult.FULL
        self._bodies[body_id] = state
        if self.reference_ns is None or state.stamp_ns > self.reference_ns:
            self.reference_ns = state.stamp_ns
        return UpdateResult.ACCEPTED

    def remove(self, body_id: str, stamp_ns: int) -> str:
        """Remove `body_id` unless its current state is newer than the removal."""
        old = self._bodies.get(body_id)
        if old is None:
            return UpdateResult.UNKNOWN_REMOVAL
        if stamp_ns < old.stamp_ns:
            return UpdateResult.NOT_NEWER
        del self._bodies[body_id]
        return UpdateResult.REMOVED

    def expire(self, now_ns: int, stale_timeout_s: float) -> list[str]:
        """Drop bodies not received within `stale_timeout_s` of `now_ns`; returns their ids."""
        limit = now_ns - int(round(stale_timeout_s * 1e9))
        stale = [body_id for body_id, s in self._bodies.items() if s.received_ns < limit]
        for body_id in stale:
            del self._bodies[body_id]
        return stale

    def clear(self) -> None:
        self._bodies.clear()
        self.reference_ns = None

    def snapshot(self, dimensions: int) -> SceneSnapshot:
        """Every body propagated to the reference time (exact under the model).

        p + v dt + a dt^2/2 and v + a dt with dt = (reference - stamp) >= 0, so a
        body's prediction does not depend on when other bodies were stamped.
        """
        ids = sorted(self._bodies)
        ref = self.reference_ns if self.reference_ns is not None else 0
        n = len(ids)
        stamps = np.fromiter((self._bodies[i].stamp_ns for i in ids), dtype=np.int64, count=n)
        radii = np.fromiter((self._bodies[i].radius for i in ids), dtype=np.float64, count=n)
        p = np.array([self._bodies[i].position for i in ids], dtype=np.float64).reshape(n, 3)
        v = np.array([self._bodies[i].velocity for i in ids], dtype=np.float64).reshape(n, 3)
        a = np.array([self._bodies[i].acceleration for i in ids], dtype=np.float64).reshape(n, 3)
        # Integer subtraction first: stamps ~1.7e18 ns would lose sub-us detail as floats.
        dt = ((ref - stamps).astype(np.float64) * 1e-9)[:, None]
        p = p + dt * (v + (0.5 * dt) * a)
        v = v + dt * a
        d = dimensions
        return SceneSnapshot(ref, ids, p[:, :d].copy(), v[:, :d].copy(), a[:, :d].copy(), radii)
