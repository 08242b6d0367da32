"""From received circle states to a CollisionPredictionArray, without a ROS graph.

This is the one path every prediction takes: the live node calls it from its
callbacks, the `replay` tool calls it with recorded messages and receive times,
and the service calls its stateless variant. Given the same messages and the
same `now_ns` values in the same order it returns the same predictions, bit for
bit (see body_registry for why).

    states -> state_validation.check_state -> BodyRegistry (latest per id)
           -> snapshot at the reference time -> core.predict_all_pairs
           -> prediction_messages.build_prediction_array
"""
from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from circle_collision_msgs.msg import CircleState, CollisionPredictionArray
from circle_collision_ros.body_registry import BodyRegistry, BodyState, UpdateResult
from circle_collision_ros.core import predict_all_pairs
from circle_collision_ros.prediction_messages import build_prediction_array
from circle_collision_ros.state_validation import (Rejection, check_state, duplicate_ids,
                                                   stamp_ns, state_frame)


@dataclass(frozen=True)
class PredictorConfig:
    """Settings of the prediction (the node's parameters of the same names).

    horizon : s, finite and > 0. stale_timeout : s. dimensions : 2 (circles,
    z ignored) or 3 (spheres). frame_id : "" adopts the first frame seen.
    """

    horizon: float = 5.0
    dimensions: int = 2
    frame_id: str = ""
    stale_timeout: float = 2.0
    report_all_pairs: bool = False
    max_bodies: int = 10_000


@dataclass
class IntakeReport:
    """Outcome of one message: counts, and the rejected states with reasons."""

    accepted: int = 0
    removed: int = 0
    ignored: int = 0  # not newer than the body's current state (late or duplicated)
    rejected: list[Rejection] = field(default_factory=list)
    expired: list[str] = field(default_factory=list)

    @property
    def changed(self) -> bool:
        """Whether the scene differs from before the message."""
        return bool(self.accepted or self.removed or self.expired)


@dataclass
class PredictionStats:
    """Figures of the last prediction, for diagnostics."""

    bodies: int = 0
    contacts: int = 0
    candidate_pairs: int = 0
    compute_s: float = 0.0


def _body_state(state: CircleState, received_ns: int) -> BodyState:
    p, v, a = state.position, state.velocity, state.acceleration
    return BodyState(stamp_ns(state), received_ns, float(state.radius),
                     (p.x, p.y, p.z), (v.x, v.y, v.z), (a.x, a.y, a.z))


class CollisionPredictor:
    """Stateful scene prediction from CircleState messages (no rclpy node needed)."""

    def __init__(self, config: PredictorConfig) -> None:
        self.config = config
        self.frame_id = config.frame_id
        self.registry = BodyRegistry(config.max_bodies)
        self.stats = PredictionStats()
        self.last_snapshot = None  # the SceneSnapshot of the last predict(), for markers

    def warm_up(self) -> None:
        """Run the core once on a tiny scene so the first real message pays no JIT/cache load."""
        d = self.config.dimensions
        z = np.zeros((2, d))
        predict_all_pairs(np.eye(2, d), z, z, np.ones(2), self.config.horizon)

    def reconfigure(self, **changes) -> None:
        """Apply run-time changes (horizon, stale_timeout, report_all_pairs)."""
        self.config = replace(self.config, **changes)

    def ingest(self, states: Sequence[CircleState], now_ns: int | None,
               array_frame: str = "") -> IntakeReport:
        """Validate `states` (one message) and merge the good ones into the scene.

        now_ns : receiving clock (ns) used for the future-stamp check and as the
            bodies' receive time for expiry; None skips the future check (service).
        """
        report = IntakeReport()
        received = now_ns if now_ns is not None else 0
        dups = duplicate_ids(states)
        for index, state in enumerate(states):
            if state.id in dups:
                report.rejected.append(Rejection(index, state.id, "id appears more than once in the message"))
                continue
            reason = check_state(state, frame_id=self.frame_id, now_ns=now_ns, array_frame=array_frame)
            if reason is not None:
                report.rejected.append(Rejection(index, state.id, reason))
                continue
            if state.remove:
                outcome = self.registry.remove(state.id, stamp_ns(state))
                report.removed += outcome == UpdateResult.REMOVED
                report.ignored += outcome != UpdateResult.REMOVED
                continue
            outcome = self.registry.update(state.id, _body_state(state, received))
            if outcome == UpdateResult.ACCEPTED:
                report.accepted += 1
                if not self.frame_id:
                    self.frame_id = state_frame(state, array_frame)  # adopt the first frame seen
            elif outcome == UpdateResult.FULL:
                report.rejected.append(Rejection(
                    index, state.id, f"scene is full (max_bodies={self.config.max_bodies})"))
            else:
                report.ignored += 1
        return report

    def receive(self, states: Sequence[CircleState], now_ns: int, array_frame: str = "") -> IntakeReport:
        """One received message: ingest its states, then expire stale bodies at `now_ns`."""
        report = self.ingest(states, now_ns, array_frame)
        report.expired = self.expire(now_ns)
        return report

    def expire(self, now_ns: int) -> list[str]:
        """Drop bodies not received within stale_timeout of `now_ns`."""
        return self.registry.expire(now_ns, self.config.stale_timeout)

    def predict(self, horizon: float | None = None) -> CollisionPredictionArray:
        """Predictions for the current scene, counted from the reference time."""
        started = time.perf_counter()
        horizon = self.config.horizon if horizon is None else horizon
        snapshot = self.last_snapshot = self.registry.snapshot(self.config.dimensions)
        pairs = predict_all_pairs(snapshot.positions, snapshot.velocities,
                                  snapshot.accelerations, snapshot.radii, horizon)
        out = build_prediction_array(snapshot, pairs, horizon, self.frame_id,
                                     self.config.report_all_pairs)
        self.stats = PredictionStats(bodies=len(snapshot.ids), contacts=len(pairs.ttc),
                                     candidate_pairs=int(getattr(pairs, "candidate_pairs", -1)),
                                     compute_s=time.perf_counter() - started)
        return out


def predict_once(states: Sequence[CircleState], config: PredictorConfig,
                 horizon: float | None = None) -> tuple[bool, str, CollisionPredictionArray | None]:
    """Stateless prediction for one set of states (the service).

    All states are propagated to the newest stamp among them. Returns
    (success, message, predictions); the message names the first bad state.
    """
    predictor = CollisionPredictor(replace(config, max_bodies=max(len(states), 1)))
    report = predictor.ingest(states, now_ns=None)
    if report.rejected:
        bad = report.rejected[0]
        more = f" (and {len(report.rejected) - 1} more)" if len(report.rejected) > 1 else ""
        return False, f"circles[{bad.index}] (id '{bad.body_id}'): {bad.reason}{more}", None
    removals = sum(1 for s in states if s.remove)
    if removals:
        return False, f"{removals} circle(s) have remove=true, which a stateless request cannot use", None
    if report.ignored:
        return False, "duplicate ids in the request", None
    return True, "", predictor.predict(horizon)
