"""From received circle states to predictions, without a ROS graph.

This is the one path every prediction takes: the live node calls it from its
callbacks with the received bytes, the `replay` tool calls it with recorded
bytes and receive times, and the service calls its stateless variant. Given the
same inputs and the same `now_ns` values in the same order it returns the same
predictions, bit for bit (see body_registry for why).

    bytes -> cdr_codec.decode_states -> StateBatch -> state_validation.check_batch
          -> BodyRegistry.merge (latest per id) -> snapshot at the reference time
          -> core.predict_all_pairs -> ScenePrediction (.to_cdr() / .to_message())
"""
from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from circle_collision_msgs.msg import CircleState
from circle_collision_ros.pipeline.body_registry import BodyRegistry
from circle_collision_ros.core import predict_all_pairs
from circle_collision_ros.pipeline.prediction_messages import ScenePrediction
from circle_collision_ros.pipeline.state_batch import StateBatch
from circle_collision_ros.pipeline.state_validation import Rejection, check_batch


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


class CollisionPredictor:
    """Stateful scene prediction from circle states (no rclpy node needed)."""

    def __init__(self, config: PredictorConfig) -> None:
        self.config = config
        self.frame_id = config.frame_id
        self.registry = BodyRegistry(config.max_bodies)
        self.stats = PredictionStats()

    def warm_up(self) -> None:
        """Run the core once on a tiny scene so the first real message pays no JIT/cache load."""
        d = self.config.dimensions
        z = np.zeros((2, d))
        predict_all_pairs(np.eye(2, d), z, z, np.ones(2), self.config.horizon)

    def reconfigure(self, **changes) -> None:
        """Apply run-time changes (horizon, stale_timeout, report_all_pairs)."""
        self.config = replace(self.config, **changes)

    def ingest(self, batch: StateBatch, now_ns: int | None) -> IntakeReport:
        """Validate one message's states and merge the good ones into the scene.

        now_ns : receiving clock (ns) used for the future-stamp check and as the
            bodies' receive time for expiry; None skips the future check (service).
        """
        check = check_batch(batch, frame_id=self.frame_id, now_ns=now_ns)
        report = IntakeReport(rejected=check.rejections)
        good = check.good
        if good.any() and not self.frame_id:
            self.frame_id = check.frame_id  # adopt the first frame seen
        updates = np.flatnonzero(good & ~batch.remove)
        merged = self.registry.merge(batch, updates, now_ns if now_ns is not None else 0)
        report.accepted = int(merged.accepted.size)
        report.ignored = int(merged.not_newer.size)
        report.rejected += [Rejection(int(k), batch.ids[k],
                                      f"scene is full (max_bodies={self.config.max_bodies})")
                            for k in merged.full.tolist()]
        for k in np.flatnonzero(good & batch.remove).tolist():
            if self.registry.remove(batch.ids[k], int(batch.stamp_ns[k])):
                report.removed += 1
            else:
                report.ignored += 1  # unknown id, or older than the body's state
        return report

    def receive_batch(self, batch: StateBatch, now_ns: int) -> IntakeReport:
        """One received message: ingest its states, then expire stale bodies at `now_ns`."""
        report = self.ingest(batch, now_ns)
        report.expired = self.expire(now_ns)
        return report

    def receive(self, states: Sequence[CircleState], now_ns: int, array_frame: str = "") -> IntakeReport:
        """receive_batch for message objects (array_frame: the enclosing array's frame)."""
        return self.receive_batch(StateBatch.from_messages(states, array_frame), now_ns)

    def expire(self, now_ns: int) -> list[str]:
        """Drop bodies not received within stale_timeout of `now_ns`."""
        return self.registry.expire(now_ns, self.config.stale_timeout)

    def predict(self, horizon: float | None = None) -> ScenePrediction:
        """Predictions for the current scene, counted from the reference time."""
        started = time.perf_counter()
        horizon = self.config.horizon if horizon is None else horizon
        snapshot = self.registry.snapshot(self.config.dimensions)
        pairs, core_stats = predict_all_pairs(snapshot.positions, snapshot.velocities,
                                              snapshot.accelerations, snapshot.radii, horizon,
                                              return_stats=True)
        self.stats = PredictionStats(bodies=len(snapshot.ids), contacts=len(pairs.ttc),
                                     candidate_pairs=core_stats["n_candidates"],
                                     compute_s=time.perf_counter() - started)
        return ScenePrediction(snapshot, pairs, horizon, self.frame_id, self.config.report_all_pairs)


class HorizonLimits:
    """The horizons accepted, in s: the `horizon` parameter's range, also for the service.

    Above an hour a "time to collision" under constant acceleration says
    nothing about real motion, and bounds the work one request can ask for.
    """

    MIN_S = 1e-3
    MAX_S = 3600.0


def predict_once(states: Sequence[CircleState], config: PredictorConfig,
                 horizon: float | None = None, request_time_ns: int = 0
                 ) -> tuple[bool, str, ScenePrediction | None]:
    """Stateless prediction for one set of states (the service).

    Rules (README, "Service"):
    - horizon None or 0 uses config.horizon; any other value must lie in
      [HorizonLimits.MIN_S, HorizonLimits.MAX_S], as for the parameter;
    - an empty request is refused (there is no scene to predict);
    - a circle with a zero header.stamp is taken as stamped at `request_time_ns`
      (`ros2 service call` cannot fill in the time); if that is 0 too it is refused;
    - `remove: true` is refused (nothing persists between requests);
    - all states are propagated to the newest stamp among them.
    Returns (success, message, prediction); a refusal names every bad circle
    with every reason ("circles[k] (id 'x'): reason; reason | circles[j] ...").
    """
    if horizon is None or horizon == 0.0:
        horizon = config.horizon
    if not (HorizonLimits.MIN_S <= horizon <= HorizonLimits.MAX_S):  # also false for NaN
        return (False, f"horizon must be 0 (the node's horizon, {config.horizon} s) or in "
                f"[{HorizonLimits.MIN_S}, {HorizonLimits.MAX_S}] s, got {horizon}", None)
    if not states:
        return False, "the request has no circles", None
    batch = StateBatch.from_messages(states)
    unstamped = batch.stamp_ns == 0
    if unstamped.any() and request_time_ns > 0:
        batch = replace(batch, stamp_ns=np.where(unstamped, np.int64(request_time_ns), batch.stamp_ns))
    predictor = CollisionPredictor(replace(config, max_bodies=len(states)))
    report = predictor.ingest(batch, now_ns=None)
    reasons: dict[int, list[str]] = {r.index: [r.reason] for r in report.rejected}
    for k, s in enumerate(states):
        if s.remove:
            reasons.setdefault(k, []).append("remove=true cannot be used in a stateless request")
    if reasons:
        return False, " | ".join(f"circles[{k}] (id '{states[k].id}'): {'; '.join(reasons[k])}"
                                 for k in sorted(reasons)), None
    return True, "", predictor.predict(horizon)
