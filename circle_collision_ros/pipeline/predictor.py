"""From received circle states to predictions, without a ROS graph.

This is the one path every prediction takes: the live node calls it from its
callbacks with the received bytes, the `replay` tool calls it with recorded
bytes and receive times, and the service calls its stateless variant. Given the
same inputs and the same `now_ns` values in the same order it returns the same
predictions, bit for bit: the scene is one `core.Scene`, whose stream and
prediction rules (and why incremental equals full recomputation) are in
circle_collision_ros/core/scene.py.

    bytes -> state_codec.decode_states -> StateBatch -> state_validation.check_batch
          -> core.Scene.merge (removals, latest per id, max_bodies)
          -> core.Scene.predictions (only the pairs of changed bodies re-evaluated)
          -> ScenePrediction (.to_cdr() / .to_message())
"""
from __future__ import annotations

import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from circle_collision_msgs.msg import CircleState, CircleStateArray
from circle_collision_ros.core.parallel_policy import threads_forced
from circle_collision_ros.core.scene import Scene, SceneSnapshot
from circle_collision_ros.core.warm_up import warm_large_frames, warm_scenes, warm_uncertain
from circle_collision_ros.pipeline.state_codec import (StateDecoder, decode_states,
                                                       encode_state, encode_state_array)
from circle_collision_ros.core.static import StaticIndex
from circle_collision_ros.pipeline.prediction_messages import ScenePrediction
from circle_collision_ros.pipeline.static_scene import StaticCache
from circle_collision_ros.pipeline.state_batch import StateBatch
from circle_collision_ros.pipeline.state_validation import Rejection, check_batch


@dataclass(frozen=True)
class PredictorConfig:
    """Settings of the prediction (the node's parameters of the same names).

    horizon : s, finite and > 0. stale_timeout : s (expiry of bodies and of
    remembered removals). dimensions : 2 (circles, z ignored) or 3 (spheres).
    frame_id : "" adopts the first frame seen. probability_threshold : in (0, 1];
    an uncertain pair whose mean paths miss is reported when its probability of
    contact reaches it (a deferred pair: the top of its interval), and the plausible
    time is when the overlap probability does.
    uncertain_pair_budget : at most this many uncertain pairs get the full probability
    evaluation per prediction (0: all); the rest are deferred, reported with a cheap
    certified interval of their states (core.uncertainty.uncertain_pairs(max_evaluated=...)).
    A count, not a time: replay reproduces it bit for bit. use_covariance : False predicts
    every body on its mean state: covariances are dropped at intake (counted in
    IntakeReport.covariance_ignored) and the probability kernels are never needed (a first
    start compiles fewer). probability_tolerance : in [0, 0.1]; the stated bound a full
    evaluation may reach where that saves work (core.uncertainty.uncertain_pairs(tolerance=...));
    0 (here, and for recordings made before it existed): every pair at the per-pair accuracy.
    ego_ids : ids of the ego bodies; when given, only pairs with at least one of them are
    evaluated and reported (core.Scene's ego rule: the broad phase skips the others), and only
    they are answered against static geometry; empty: every pair and every body.
    """

    horizon: float = 5.0
    dimensions: int = 2
    frame_id: str = ""
    stale_timeout: float = 2.0
    report_all_pairs: bool = False
    max_bodies: int = 10_000
    probability_threshold: float = 0.01
    uncertain_pair_budget: int = 0
    use_covariance: bool = True
    probability_tolerance: float = 0.0
    ego_ids: tuple = ()


#: The PredictorConfig fields that may change while running (node parameters
#: applied at run time, and replayed from a recording's config records).
RUNTIME_FIELDS = ("horizon", "stale_timeout", "report_all_pairs", "probability_threshold")
#: What CollisionPredictor.warm_up can prepare (pipeline.kernels compiles each in a process).
WARM_UP_PATHS = ("exact", "large", "threads", "uncertain", "uncertain_threads", "messages")


@dataclass
class IntakeReport:
    """Outcome of one message: counts, and the rejected states with reasons."""

    accepted: int = 0
    removed: int = 0
    ignored: int = 0  # not newer than the body's state or its removal; unknown-id removals
    covariance_ignored: int = 0  # accepted states whose covariance use_covariance=False dropped
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
    # pairs the narrow phase evaluated (only changed bodies' pairs when incremental)
    candidate_pairs: int = 0
    uncertain_deferred: int = 0  # uncertain pairs not fully evaluated (uncertain_pair_budget)
    compute_s: float = 0.0


class CollisionPredictor:
    """Stateful scene prediction from circle states (no rclpy node needed)."""

    def __init__(self, config: PredictorConfig) -> None:
        self.config = config
        self.frame_id = config.frame_id
        # The sweep broad phase (the Scene's default; the grid finds the same pairs): measured
        # faster for whole tracker-array frames and for epoch moves, with the same output bytes
        # (bench/bench_node.py's density).
        self._scene = Scene(config.horizon, config.dimensions, max_bodies=config.max_bodies,
                            ego_ids=tuple(config.ego_ids) or None)
        self._static: StaticIndex | None = None
        self._static_cache = StaticCache()
        self.stats = PredictionStats()

    @property
    def static(self) -> StaticIndex | None:
        """The static world predictions are made against (None: none)."""
        return self._static

    def _static_bodies(self) -> tuple:
        """The stored states answered against static geometry: the ego bodies, or all."""
        states = self._scene.stored_states()
        if not self.config.ego_ids:
            return states
        ego = set(self.config.ego_ids)
        keep = np.array([i in ego for i in states[0]], dtype=bool)
        ids = [i for i in states[0] if i in ego]
        return (ids, *(x[keep] for x in states[1:]))

    def set_static(self, index: StaticIndex | None) -> None:
        """Predict against ``index`` from the next prediction on (None: no static geometry).

        Built elsewhere (``static_scene.build_index``, off the prediction path); 2-D only.
        """
        if index is not None and self.config.dimensions != 2:
            raise ValueError("static geometry needs dimensions = 2 (circles); this predictor "
                             f"predicts in {self.config.dimensions}-D")
        self._static = index

    @property
    def bodies(self) -> int:
        """Bodies in the scene."""
        return len(self._scene)

    def __len__(self) -> int:
        return len(self._scene)

    def __contains__(self, body_id: str) -> bool:
        return body_id in self._scene

    @property
    def reference_ns(self) -> int | None:
        """Newest accepted stamp since the scene was last empty (predictions count from it)."""
        return self._scene.reference_ns

    def snapshot(self) -> SceneSnapshot:
        """Every body propagated to the reference time, ordered by id."""
        return self._scene.snapshot()

    def clear(self) -> None:
        """Forget every body and remembered removal (e.g. after the clock jumped back)."""
        self._scene.clear()

    def warm_up(self, paths: Iterable[str] = WARM_UP_PATHS) -> None:
        """Run every compiled kernel a message can reach once, on tiny scenes, so the first real
        message pays no numba compile or cache load (the node prepares them before it subscribes,
        through ``pipeline.kernels.prepare``, which compiles cold paths in parallel processes).

        ``paths`` (any of WARM_UP_PATHS): ``exact`` the scene's serial kernels; ``large`` those of
        frames of ``Scene.COMPILED_ROWS`` pairs or more (the vectorised path); ``threads`` the
        threaded twins the policy picks for large frames, and the message path with them;
        ``uncertain`` the probability of contact and messages with covariance;
        ``uncertain_threads`` the same with threads; ``messages`` decoding and encoding."""
        unknown = set(paths) - set(WARM_UP_PATHS)
        if unknown:
            raise ValueError(
                f"warm_up: unknown paths {sorted(unknown)}; expected some of {WARM_UP_PATHS}"
            )
        d, horizon = self.config.dimensions, self.config.horizon
        threshold = self.config.probability_threshold
        for path in paths:
            threaded = path in ("threads", "uncertain_threads")
            if path in ("exact", "threads"):
                warm_scenes(d, horizon, threaded, large=threaded)
            if path == "large":
                warm_large_frames(d, horizon)
            if path in ("uncertain", "uncertain_threads"):
                warm_uncertain(d, horizon, threshold, threaded)
            with threads_forced(threaded):
                if path in ("messages", "threads"):
                    self._warm_up_messages(uncertain=False)
                if path in ("uncertain", "uncertain_threads"):
                    self._warm_up_messages(uncertain=True)

    def warm_up_codec(self) -> None:
        """Compile (or load) the decoders and encoders of the message path without evaluating
        a pair: its bodies are never a candidate pair, so this can run beside the compile of
        the scene's evaluating kernels (pipeline.kernels' ``codec`` job)."""
        self._warm_up_messages(uncertain=False, apart=True)

    def _warm_up_messages(self, uncertain: bool, apart: bool = False) -> None:
        """The message path on throwaway predictors: decoding both input types (``uncertain``:
        with covariance) and both output encoders (contact rows, and the column layout that
        uncertain pairs and report_all_pairs take). Left to the first messages, these would
        compile (or load from the cache) while the node is already subscribed, and its first
        answers would come late (bench/bench_node.py's first scenario shows it).
        ``apart``: bodies far apart, so that no pair is a candidate (warm_up_codec)."""
        t = 1_000_000_000
        n = 3
        position = np.zeros((n, 3))
        # a and c overlap, b approaches a; apart: 1 km from each other
        position[:, 0] = (0.0, 1e3, 2e3) if apart else (0.0, 3.0, 0.5)
        velocity = np.zeros((n, 3))
        velocity[1, 0] = -1.0
        acceleration = np.zeros((n, 3))
        acceleration[1, 1] = 0.2  # an accelerating uncertain pair takes its own method
        covariance = np.zeros((n, 36))
        covariance[:, ::7] = 0.01  # the 6x6 diagonal
        def states(with_covariance: bool) -> StateBatch:
            return StateBatch(ids=["a", "b", "c"], frames=["map"] * n,
                              stamp_ns=np.full(n, t, np.int64), radius=np.ones(n),
                              position=position, velocity=velocity, acceleration=acceleration,
                              remove=np.zeros(n, dtype=bool),
                              covariance=covariance if with_covariance else None,
                              covariance_size=np.full(n, 36, np.int64) if with_covariance
                              else None)

        runs = [(states(uncertain), report_all, True) for report_all in (False, True)]
        if not uncertain:  # states with covariance on a predictor that drops it (and validates it)
            runs.append((states(True), False, False))
        for batch, report_all, use in runs:
            predictor = CollisionPredictor(
                replace(self.config, frame_id="map", report_all_pairs=report_all, max_bodies=n,
                        use_covariance=use)
            )
            # a subscription's decoder: a first message parsed, the next (its values moved)
            # read at the same layout
            decode = StateDecoder(CircleStateArray)
            decode(encode_state_array(batch, t, "map"))
            later = replace(batch, stamp_ns=batch.stamp_ns + 1, position=batch.position + 0.5)
            predictor.receive_batch(decode(encode_state_array(later, t + 1, "map")), t + 1)
            prediction = predictor.predict()
            prediction.to_cdr()
            # replay of recordings made before the probability fields
            prediction.to_cdr(uncertainty=False)
            one = replace(batch.select(np.array([1])), stamp_ns=np.array([t + 2], np.int64))
            predictor.receive_batch(decode_states(encode_state(one), CircleState), t + 2)
            predictor.predict().to_cdr()

    def reconfigure(self, **changes) -> None:
        """Apply run-time changes (RUNTIME_FIELDS)."""
        unknown = set(changes) - set(RUNTIME_FIELDS)
        if unknown:
            raise ValueError(f"not changeable at run time: {sorted(unknown)}")
        self.config = replace(self.config, **changes)
        self._scene.set_horizon(self.config.horizon)

    def ingest(self, batch: StateBatch, now_ns: int | None) -> IntakeReport:
        """Validate one message's states and merge the good ones into the scene.

        now_ns : receiving clock (ns) used for the future-stamp check and as the
            bodies' receive time for expiry; None skips the future check (service).
        """
        check = check_batch(
            batch, frame_id=self.frame_id, now_ns=now_ns, dimensions=self.config.dimensions
        )
        report = IntakeReport(rejected=check.rejections)
        if len(batch) == 0:
            return report
        if check.rejections:  # the good rows only
            good = np.flatnonzero(check.good)
            if good.size == 0:
                return report
            batch = batch.select(good)
            uncertain = check.uncertain[good] if check.uncertain is not None else None
            block = check.covariance[good] if check.covariance is not None else None
        else:  # every row (the usual message): no copies
            good = None
            uncertain = check.uncertain
            block = check.covariance
        if not self.frame_id:
            self.frame_id = check.frame_id  # adopt the first frame seen
        covariances = None  # exact states: the scene's exact path alone
        if uncertain is not None and uncertain.any():
            if self.config.use_covariance:
                covariances = block
            else:
                report.covariance_ignored = int(np.count_nonzero(uncertain))
        merged = self._scene.merge(batch.ids, batch.stamp_ns, batch.position, batch.velocity,
                                   batch.acceleration, batch.radius, batch.remove,
                                   now_ns if now_ns is not None else 0, covariances)
        report.accepted = int(merged.accepted.size)
        report.removed = int(merged.removed.size)
        report.ignored = int(merged.not_newer.size + merged.removal_ignored.size)
        report.rejected += [
            Rejection(int(good[k]) if good is not None else k, batch.ids[k],
                      f"scene is full (max_bodies={self.config.max_bodies})")
            for k in merged.full.tolist()
        ]
        return report

    def receive_batch(self, batch: StateBatch, now_ns: int) -> IntakeReport:
        """One received message: ingest its states, then expire stale bodies at `now_ns`."""
        report = self.ingest(batch, now_ns)
        report.expired = self.expire(now_ns)
        return report

    def expire(self, now_ns: int) -> list[str]:
        """Drop bodies (and remembered removals) not received within stale_timeout of `now_ns`."""
        return self._scene.expire(now_ns, int(round(self.config.stale_timeout * 1e9)))

    def predict(self, horizon: float | None = None) -> ScenePrediction:
        """Predictions for the current scene, counted from the reference time.

        A horizon other than the configured one becomes the scene's horizon
        (replay passes the recorded one); changing it rebuilds every pair.
        """
        started = time.perf_counter()
        horizon = self.config.horizon if horizon is None else float(horizon)
        self._scene.set_horizon(horizon)
        contacts = self._scene.predictions()
        uncertainty = self._scene.uncertain_pairs(
            self.config.probability_threshold, contacts, self.config.uncertain_pair_budget or None,
            self.config.probability_tolerance,
        )
        capture = self._scene.capture()
        static = None
        if self._static is not None and len(self._scene):
            static = self._static_cache.rows(self._static_bodies(),
                                             self._scene.reference_ns, self._scene.epoch_ns,
                                             self._scene.slack, horizon, self._static)
        prediction = ScenePrediction(contacts, capture, horizon, self.frame_id,
                                     self.config.report_all_pairs, uncertainty,
                                     self.config.probability_threshold, static)
        self.stats = PredictionStats(bodies=len(self._scene), contacts=len(contacts),
                                     candidate_pairs=self._scene.evaluated_pairs,
                                     uncertain_deferred=uncertainty.deferred,
                                     compute_s=time.perf_counter() - started)
        return prediction


class HorizonLimits:
    """The horizons accepted, in s: the `horizon` parameter's range, also for the service.

    Above an hour a "time to collision" under constant acceleration says
    nothing about real motion, and bounds the work one request can ask for.
    """

    MIN_S = 1e-3
    MAX_S = 3600.0


def predict_once(states: Sequence[CircleState], config: PredictorConfig,
                 horizon: float | None = None,
                 request_time_ns: int = 0,
                 static: StaticIndex | None = None,
                 ego_ids: Sequence[str] = ()) -> tuple[bool, str, ScenePrediction | None]:
    """Stateless prediction for one set of states (the service).

    Rules (README, "Service"):
    - horizon None or 0 uses config.horizon; any other value must lie in
      [HorizonLimits.MIN_S, HorizonLimits.MAX_S], as for the parameter;
    - an empty request is refused (there is no scene to predict), and one of more than
      config.max_bodies circles (the node's compiled paths are prepared for that many);
    - a circle with a zero header.stamp is taken as stamped at `request_time_ns`
      (`ros2 service call` cannot fill in the time); if that is 0 too it is refused;
    - `remove: true` is refused (nothing persists between requests);
    - times count from the newest stamp among them (the rule of core/scene.py);
    - ``static``: the node's current static world, answered against as well;
    - ``ego_ids``: only pairs with one of these bodies, and only they against static geometry
      (empty: every pair and body; an id not among the circles is refused).
    Returns (success, message, prediction); a refusal names every bad circle
    with every reason ("circles[k] (id 'x'): reason; reason | circles[j] ...").
    """
    if horizon is None or horizon == 0.0:
        horizon = config.horizon
    if not (HorizonLimits.MIN_S <= horizon <= HorizonLimits.MAX_S):  # also false for NaN
        return (
            False,
            f"horizon must be 0 (the node's horizon, {config.horizon} s) or in "
            f"[{HorizonLimits.MIN_S}, {HorizonLimits.MAX_S}] s, got {horizon}",
            None,
        )
    if not states:
        return False, "the request has no circles", None
    if len(states) > config.max_bodies:
        # the node prepares its compiled paths for at most max_bodies bodies: a larger request
        # could meet a cold compile inside the executor that also answers the streams
        return (False, f"the request has {len(states)} circles; this node predicts at most "
                f"max_bodies = {config.max_bodies}", None)
    batch = StateBatch.from_messages(states)
    unstamped = batch.stamp_ns == 0
    if unstamped.any() and request_time_ns > 0:
        batch = replace(
            batch, stamp_ns=np.where(unstamped, np.int64(request_time_ns), batch.stamp_ns)
        )
    missing = sorted(set(ego_ids) - {s.id for s in states})
    if missing:
        return False, f"ego_ids not among the circles: {', '.join(map(repr, missing))}", None
    predictor = CollisionPredictor(replace(config, max_bodies=len(states), horizon=horizon,
                                           ego_ids=tuple(ego_ids)))
    predictor.set_static(static)
    report = predictor.ingest(batch, now_ns=None)
    reasons: dict[int, list[str]] = {r.index: [r.reason] for r in report.rejected}
    for k, s in enumerate(states):
        if s.remove:
            reasons.setdefault(k, []).append("remove=true cannot be used in a stateless request")
    if reasons:
        return (
            False,
            " | ".join(
                f"circles[{k}] (id '{states[k].id}'): {'; '.join(reasons[k])}"
                for k in sorted(reasons)
            ),
            None,
        )
    note = (f"covariance of {report.covariance_ignored} circle(s) ignored (use_covariance is "
            "false): predicted on the mean states" if report.covariance_ignored else "")
    return True, note, predictor.predict(horizon)
