"""collision_node: circle states in, predicted times to collision out.

Subscribes to CircleStateArray (`state_topics`), CircleState
(`single_state_topics`) and nav_msgs/Odometry (`odometry_topics`, one robot per
topic: pipeline/odometry.py) topics, keeps the latest state per body id, and
publishes `collision_predictions` (CollisionPredictionArray) on every change or
at `publish_rate`, and with covariance on each prediction completed on
`collision_probabilities` (node/probabilities.py); serves `predict_collisions`
(stateless); publishes `~/markers` for RViz/Foxglove and a DiagnosticArray on
`/diagnostics` (1 Hz).

A managed (lifecycle) node, as nav2's servers are (docs/node.md, "Lifecycle"):
- configure: parameters validated, the predictor built, record_path opened, the kernels
  ready (kernels.prepare), the (lifecycle) publishers, the service and the static world
  created; no subscription, no timer.
- activate: publishers enabled; inputs (states, single states, odometry, map and polygons)
  subscribed; publish, expiry and diagnostics timers, marker and completion threads started.
- deactivate: the reverse of activate (pending completions and a clearing marker array are
  published first); the scene is kept, and bodies gone stale meanwhile expire on the first
  expiry tick after the next activation. The service refuses while inactive.
- cleanup: everything configure created is dropped, the bag closed; shutdown (any state)
  releases whatever exists. Failures of configure return FAILURE with the reason logged.
- autostart (default true): configure and activate in the constructor, so a plain
  `ros2 run` behaves as an unmanaged node; a refused configuration raises its reason.

The path of a message: raw bytes (recorded as received) -> decode ->
CollisionPredictor.receive_batch -> CollisionPredictor.predict -> CDR bytes ->
publish (and record the same bytes).

Stream rules (README, "Real-time behaviour"):
- Coalescing: a callback takes every input already waiting on every input
  subscription (rmw take, oldest first per topic) and ingests each, then
  predicts once for the newest state of every body. Under a backlog the node
  therefore never answers a stale frame, and never skips one either: every
  taken input is ingested. Inputs and predictions are recorded in that order,
  so replay reproduces the same coalescing.
- Expiry runs on its own timer (EXPIRY_PERIOD_S), whatever publish_rate is: a
  scene changed by expiry is published (possibly empty) within stale_timeout +
  EXPIRY_PERIOD_S + compute time after its sources go silent.
- Markers are drawn on their own thread (node/markers.py); the prediction path
  only hands over a reference.
- Health: latency is measured from the rmw receive timestamp of the oldest
  input a prediction answers to its publication (queue wait included).
"""
from __future__ import annotations

import functools
import gc
import json
import os
import sys
import time
from collections import deque
from collections.abc import Callable
from dataclasses import asdict, dataclass

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from nav_msgs.msg import Odometry
from rcl_interfaces.msg import SetParametersResult
from rclpy.clock import ClockChange, JumpThreshold
from rclpy.duration import Duration
from rclpy.exceptions import InvalidHandle, NameValidationException, ParameterException
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from rclpy.qos import (DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy,
                       qos_profile_system_default)
from rclpy.qos_overriding_options import QoSOverridingOptions
from rclpy.serialization import serialize_message
from std_msgs.msg import Header, String
from visualization_msgs.msg import MarkerArray

from circle_collision_msgs.msg import CircleState, CircleStateArray, CollisionPredictionArray
from circle_collision_msgs.srv import PredictCollisions
from circle_collision_ros.node import parameters as node_parameters
from circle_collision_ros.recording.bag_recorder import (BagRecorder, RecordingError,
                                                         qos_profiles_yaml)
from circle_collision_ros.pipeline import kernels
from circle_collision_ros.pipeline.cdr import CdrError
from circle_collision_ros.pipeline.state_codec import StateDecoder
from circle_collision_ros.pipeline.odometry import odometry_batch, odometry_sources
from circle_collision_ros.pipeline.state_batch import StateBatch
from circle_collision_ros.pipeline.state_groups import ingest_single_states
from circle_collision_ros.cli import TransportProfile, parse_args, spin_node
from circle_collision_ros.node.input_loss import InputLossMonitor
from circle_collision_ros.node.activity import NodeActivity
from circle_collision_ros.node.markers import MarkerPublisher
from circle_collision_ros.node.probabilities import ProbabilityPublisher, lag_problem
from circle_collision_ros.node.static_inputs import StaticInputs
from circle_collision_ros.pipeline.static_scene import StaticSettings
from circle_collision_ros.pipeline.predictor import (RUNTIME_FIELDS, CollisionPredictor,
                                                     IntakeReport, PredictorConfig, predict_once)


class Qos:
    """QoS defaults (each overridable the ROS way: qos_overrides.<topic>.<entity>.<policy>).

    Functions, not shared instances: rclpy applies QoS overrides by mutating
    the profile it is given, which would leak one node's overrides into the next.
    """

    @staticmethod
    def states(reliability: str) -> QoSProfile:
        """Whole-scene topics (arrays, one robot's odometry): each frame supersedes the last.

        best_effort matches both reliable and best-effort publishers; reliable keeps only
        the newest frame, so a slow node never works through a queue of stale ones
        (README, "Large scenes").
        """
        if reliability == "reliable":
            return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                              reliability=ReliabilityPolicy.RELIABLE,
                              durability=DurabilityPolicy.VOLATILE)
        return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=50,
                          reliability=ReliabilityPolicy.BEST_EFFORT,
                          durability=DurabilityPolicy.VOLATILE)

    @staticmethod
    def single_states(reliability: str) -> QoSProfile:
        # One topic carries every body's own stream (300 bodies at 30 Hz: 9,000/s); the queue
        # must outlast a prediction cycle or KEEP_LAST overwrites states before they are taken.
        policy = (
            ReliabilityPolicy.RELIABLE
            if reliability == "reliable"
            else ReliabilityPolicy.BEST_EFFORT
        )
        return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=2000, reliability=policy,
                          durability=DurabilityPolicy.VOLATILE)

    @staticmethod
    def predictions() -> QoSProfile:
        return QoSProfile(
            history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE
        )

    @staticmethod
    def services() -> QoSProfile:
        # The default service queue (depth 10) dropped 177 of 200 concurrent requests
        # (tests/reliability/test_faults_node.py::test_service_flood): callers waited forever.
        return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000,
                          reliability=ReliabilityPolicy.RELIABLE,
                          durability=DurabilityPolicy.VOLATILE)

    @staticmethod
    def markers() -> QoSProfile:
        return QoSProfile(
            history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE
        )


@dataclass
class Counters:
    """Totals since start, reported on /diagnostics."""

    messages: int = 0
    accepted: int = 0
    rejected: int = 0
    ignored: int = 0
    removed: int = 0
    expired: int = 0
    published: int = 0
    coalesced: int = 0  # inputs answered by a prediction together with newer inputs
    errors: int = 0
    clock_jumps_back: int = 0
    covariance_ignored: int = 0  # states whose covariance use_covariance=False dropped


@dataclass
class InputTopic:
    """One input: resolved topic, message type, its decoder, its QoS (a fresh profile per call:
    rclpy applies QoS overrides by changing the profile it is given), and the rclpy subscription
    while the node is active."""

    topic: str
    msg_type: type
    decode: Callable[[bytes], StateBatch]
    subscription: object = None
    qos: Callable[[], QoSProfile] | None = None


@dataclass
class Unanswered:
    """Inputs ingested since the last publication."""

    inputs: int = 0
    oldest_received_ns: int | None = None  # rmw receive time (system clock)
    changed: bool = False

    def note(self, received_ns: int, changed: bool, inputs: int = 1) -> None:
        """`inputs` inputs ingested, the first of them received at `received_ns`."""
        self.inputs += inputs
        if self.oldest_received_ns is None:
            self.oldest_received_ns = received_ns
        self.changed = self.changed or changed


class CollisionNode(LifecycleNode):
    """The ROS face of CollisionPredictor, a managed (lifecycle) node; see the module docstring."""

    WARN_THROTTLE_S = 2.0
    LATENCY_WINDOW = 1000
    EXPIRY_PERIOD_S = 0.05
    DIAGNOSTICS_PERIOD_S = 1.0
    #: How long a deactivation or shutdown waits for subscribers to acknowledge the final
    #: markers (DELETEALL), s.
    SHUTDOWN_ACK_S = 1.0

    def __init__(self, **kwargs) -> None:
        super().__init__("collision_node", **kwargs)
        self._forget_configuration()
        self._active = False
        self._quiet = False  # autostart and destroy_node: transitions not logged one by one
        self._transition_error: BaseException | None = None
        self._bags_opened = 0
        #: Set on the executable's node (main, _started_node): a configuration requested later
        #: through the lifecycle services freezes what it created, as start-up does.
        self.freeze_gc_after_configure = False
        node_parameters.declare_all(self)
        self.add_pre_set_parameters_callback(node_parameters.coerce_integers)
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)
        # What Fast DDS loaded at rclpy.init (cli.use_large_scene_transport sets it before).
        self._transport_profile = (
            os.environ.get(TransportProfile.ENV)
            or os.environ.get(TransportProfile.DEPRECATED_ENV)
            or ""
        )
        if node_parameters.value_of(self, "autostart"):
            self._autostart()

    def _forget_configuration(self) -> None:
        """Everything configure creates, absent (unconfigured)."""
        self.predictor: CollisionPredictor | None = None
        self._recorder: BagRecorder | None = None
        self._recording_error = ""
        self._static_recording = False
        self._qos_unknown: set[str] = set()
        self.counters = Counters()
        # Receive (rmw timestamp of the oldest input answered) to publish, s.
        self.latencies_s: deque[float] = deque(maxlen=self.LATENCY_WINDOW)
        self._unanswered = Unanswered()
        self._last_drain_ns = 0
        self.input_loss = InputLossMonitor()
        self._unmatched_publishers: list[str] = []
        # (count, read at, kinds)
        self._publisher_info: dict[str, tuple[int, float, dict[str, int]]] = {}
        self._last_warning: dict[str, float] = {}
        self._predictions_pub = self._probabilities_pub = None
        self._markers_pub = self._diagnostics_pub = None
        # the prediction path's busy flag: markers and completions step aside meanwhile
        self.activity = NodeActivity()
        self.markers: MarkerPublisher | None = None
        self.probabilities: ProbabilityPublisher | None = None
        # Counts of the side threads of earlier activations (diagnostics report totals).
        self._side_totals = {"markers_drawn": 0, "probabilities_published": 0,
                             "probabilities_superseded": 0, "probabilities_late": 0}
        # (published, late, superseded) completions at the previous diagnostics report
        self._lag_seen = (0, 0, 0)
        self._inputs: list[InputTopic] = []
        self._odometry_sources: dict = {}
        self.static: StaticInputs | None = None
        self._drain_limit = 1
        self._service = None
        self._clock_jump_handle = None
        self._publish_timer = None
        self._expiry_timer = None
        self._diagnostics_timer = None
        self._qos_timer = None

    # -- lifecycle (docs/node.md, "Lifecycle") --------------------------------------------------
    def _autostart(self) -> None:
        """autostart: configure and activate now; a failure raises what configure met (the
        start-up refuses with the same one-line reason as before the node was managed)."""
        self._quiet = True
        try:
            if self.trigger_configure() != TransitionCallbackReturn.SUCCESS:
                raise self._transition_error or RuntimeError("configure failed")
            if self.trigger_activate() != TransitionCallbackReturn.SUCCESS:
                raise self._transition_error or RuntimeError("activate failed")
        finally:
            self._quiet = False

    @property
    def lifecycle_state(self) -> str:
        """The lifecycle state's label: unconfigured, inactive, active, finalized, or a
        transition state (configuring, ...)."""
        machine = getattr(self, "_state_machine", None)
        return machine.current_state[1] if machine is not None else "unconfigured"

    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Parameters read and validated, the predictor built, the bag opened, the kernels
        ready, publishers, service and static world created; no subscription yet."""
        self._transition_error = None
        try:
            self._configure()
        except Exception as exc:  # refused with the reason: FAILURE, back to unconfigured
            self._transition_error = exc
            if not self._quiet:
                self.get_logger().error(f"configure failed: {_reason(exc)}")
            self._cleanup()
            return TransitionCallbackReturn.FAILURE
        if self.freeze_gc_after_configure:
            gc.collect()
            gc.freeze()
        return super().on_configure(state)

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Publishers enabled, then inputs subscribed and timers started."""
        self._transition_error = None
        result = super().on_activate(state)  # the lifecycle publishers publish from now on
        if result != TransitionCallbackReturn.SUCCESS:
            return result
        try:
            self._activate()
        except Exception as exc:
            self._transition_error = exc
            self.get_logger().error(f"activate failed: {_reason(exc)}")
            self._deactivate()
            super().on_deactivate(state)
            return TransitionCallbackReturn.FAILURE
        self._note("active")
        return result

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Inputs unsubscribed, timers stopped, pending completions and a clearing marker array
        published; then the publishers are disabled. The scene is kept."""
        self._deactivate()
        result = super().on_deactivate(state)
        self._note(f"inactive: {len(self.predictor)} bodies kept")
        return result

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        """The scene, publishers, service and static world dropped; the bag closed."""
        self._cleanup()
        self._note("cleaned up: unconfigured")
        return super().on_cleanup(state)

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        """From any primary state: whatever exists is released; the bag is closed."""
        self._release(state)
        self._note("shut down: finalized")
        return super().on_shutdown(state)

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        """A transition raised: release everything and go back to unconfigured."""
        self.get_logger().error(f"lifecycle transition from '{state.label}' failed; "
                                "releasing everything (unconfigured)")
        self._release(state)
        return super().on_error(state)

    def _release(self, state: LifecycleState | None = None) -> None:
        """Deactivate (if active) and clean up: a node in any state ends with nothing held."""
        if self._active:
            self._deactivate()
            try:
                LifecycleNode.on_deactivate(self, state or LifecycleState("active", 3))
            except Exception:  # noqa: BLE001 - publishers already gone
                pass
        self._cleanup()

    def _note(self, text: str) -> None:
        if not self._quiet:
            self.get_logger().info(text)

    def _configure(self) -> None:
        """configure's work; raises (ValueError, OSError, rclpy's name and parameter errors)
        with the reason. Cheap checks come first: nothing is opened or compiled for a
        configuration that is refused."""
        p = lambda name: node_parameters.value_of(self, name)  # noqa: E731
        for spec in node_parameters.PARAMS:
            reason = node_parameters.validate(spec.name, p(spec.name))
            if reason:
                raise ValueError(f"parameter {reason}")
        settings = StaticSettings(p("map_topic"), p("map_occupied_threshold"),
                                  p("map_unknown_is_occupied"), tuple(p("polygon_topics")),
                                  p("static_polygons"))
        if settings.used and p("dimensions") != 2:
            raise ValueError("static inputs (map_topic, polygon_topics, static_polygons) need "
                             f"dimensions = 2; this node predicts in {p('dimensions')}-D")
        reliability = p("state_reliability")
        # a decoder per topic: a tracker's next frame is read at its layout (StateDecoder)
        inputs = [InputTopic(self.resolve_topic_name(t), CircleStateArray,
                             StateDecoder(CircleStateArray),
                             qos=functools.partial(Qos.states, reliability))
                  for t in p("state_topics")]
        inputs += [InputTopic(self.resolve_topic_name(t), CircleState, StateDecoder(CircleState),
                              qos=functools.partial(Qos.single_states, reliability))
                   for t in p("single_state_topics")]
        odometry = odometry_sources([self.resolve_topic_name(t) for t in p("odometry_topics")],
                                    p("odometry_radius"), p("odometry_radii"))
        inputs += [InputTopic(topic, Odometry, functools.partial(odometry_batch, source=source),
                              qos=functools.partial(Qos.states, reliability))
                   for topic, source in odometry.items()]

        self._forget_configuration()
        self.predictor = CollisionPredictor(
            PredictorConfig(horizon=p("horizon"), dimensions=p("dimensions"),
                            frame_id=p("frame_id"), stale_timeout=p("stale_timeout"),
                            report_all_pairs=p("report_all_pairs"), max_bodies=p("max_bodies"),
                            probability_threshold=p("probability_threshold"),
                            uncertain_pair_budget=p("uncertain_pair_budget"),
                            probability_tolerance=p("probability_tolerance"),
                            use_covariance=p("use_covariance"),
                            ego_ids=tuple(p("ego_ids")))
        )
        # An unusable record_path refuses the configuration before a first start's compile
        if p("record_path"):
            self._recorder = self._open_bag(self._bag_path(p("record_path")))
            self._bags_opened += 1
        # numba's compile (first start) or cache load, before the first message can arrive
        kernels.prepare(self.predictor, log=self.get_logger().info, static=settings.used)

        overrides = QoSOverridingOptions.with_default_policies()
        self._predictions_pub = self.create_lifecycle_publisher(
            CollisionPredictionArray, "collision_predictions", Qos.predictions(),
            qos_overriding_options=overrides)
        self._probabilities_pub = self.create_lifecycle_publisher(
            CollisionPredictionArray, "collision_probabilities", Qos.predictions(),
            qos_overriding_options=overrides)
        self._markers_pub = self.create_lifecycle_publisher(MarkerArray, "~/markers",
                                                            Qos.markers())
        self._diagnostics_pub = self.create_lifecycle_publisher(
            DiagnosticArray, "/diagnostics", qos_profile_system_default
        )
        self._inputs = inputs
        self._odometry_sources = odometry
        # Static geometry (maps, polygons): indexed off the prediction path
        # (node/static_inputs). Its world and subscriptions live from configure to cleanup;
        # its markers are published while active.
        if settings.used:
            self.static = StaticInputs(self, settings, lambda: self.predictor.frame_id,
                                       self._adopt_frame, self._on_static_world, self._warn,
                                       self._record_static)
        # While inactive the service refuses (see _on_predict_request).
        self._service = self.create_service(PredictCollisions, "predict_collisions",
                                            self._on_predict_request, qos_profile=Qos.services())
        # A clock that jumps back (use_sim_time with a looping bag, a restarted simulator)
        # would leave bodies "received in the future" that never expire and make every
        # new state look late: the scene is cleared instead (docs/reliability.md).
        self._clock_jump_handle = self.get_clock().create_jump_callback(
            JumpThreshold(
                min_forward=None, min_backward=Duration(nanoseconds=-1), on_clock_change=True
            ),
            post_callback=self._on_clock_jump,
        )
        if self._recorder is not None:
            self._start_recording()
        self.get_logger().info(
            f"predicting for {p('dimensions')}-D bodies on {list(p('state_topics'))}"
            f" + {list(p('single_state_topics'))} + odometry {list(self._odometry_sources)}"
            f", horizon {p('horizon')} s"
        )

    def _bag_path(self, record_path: str) -> str:
        """record_path for the first bag this node opens; <record_path>_<n> for its n-th (a
        configuration after a cleanup: record_path is read-only and the first bag is kept)."""
        return record_path if self._bags_opened == 0 else f"{record_path}_{self._bags_opened + 1}"

    def _activate(self) -> None:
        p = lambda name: node_parameters.value_of(self, name)  # noqa: E731
        # A publisher's samples sent while inactive were never meant for this node: its
        # sequence numbers start a new count (node/input_loss.py).
        for stats in self.input_loss.topics.values():
            stats.publishers.clear()
        self._unanswered = Unanswered()
        self.markers = MarkerPublisher(p("dimensions"), p("marker_rate"), self._markers_pub.publish,
                                       on_error=lambda text: self._warn("markers", text),
                                       activity=self.activity)
        # With covariance on, each prediction is completed on its own thread: every deferred
        # uncertain pair evaluated in full (node/probabilities.py)
        self.probabilities = ProbabilityPublisher(
            self._probabilities_pub.publish,
            lambda data, log_ns: self._record(self._probabilities_pub.topic_name, data, log_ns),
            on_error=lambda text: self._warn("probabilities", text), activity=self.activity,
        )
        self._active = True
        for source in self._inputs:
            self._subscribe(source)
        # Everything a callback may take in one go: what the input queues can hold.
        self._drain_limit = sum(s.subscription.qos_profile.depth for s in self._inputs) or 1
        if self.static is not None:
            self.static.activate()
        self._set_publish_rate(p("publish_rate"))
        self._expiry_timer = self.create_timer(self.EXPIRY_PERIOD_S, self._on_expiry_timer)
        self._diagnostics_timer = self.create_timer(self.DIAGNOSTICS_PERIOD_S,
                                                    self._publish_diagnostics)
        # Input publishers may appear after start: look for their QoS off the message path.
        if self._recorder is not None and self._qos_unknown:
            self._qos_timer = self.create_timer(1.0, self._record_offered_qos)

    def _deactivate(self) -> None:
        """Stop taking inputs and publishing; publish what is owed (completions, a clearing
        marker array) while the publishers are still enabled. Idempotent."""
        self._active = False
        for source in self._inputs:
            if source.subscription is not None:
                self.destroy_subscription(source.subscription)
                source.subscription = None
        if self.static is not None:
            self.static.deactivate()
        for name in ("_publish_timer", "_expiry_timer", "_diagnostics_timer", "_qos_timer"):
            timer = getattr(self, name, None)
            if timer is not None:
                self.destroy_timer(timer)
                setattr(self, name, None)
        if self.probabilities is not None:
            self.probabilities.close()  # publishes and records what it was given
            self._side_totals["probabilities_published"] += self.probabilities.published
            self._side_totals["probabilities_superseded"] += self.probabilities.superseded
            self._side_totals["probabilities_late"] += self.probabilities.late
            self.probabilities = None
        if self.markers is not None:
            self.markers.close()  # clears the display while the publisher is enabled
            self._side_totals["markers_drawn"] += self.markers.drawn
            self.markers = None
            try:  # ... and delivered: the process may exit right after
                self._markers_pub.wait_for_all_acked(Duration(seconds=self.SHUTDOWN_ACK_S))
            except Exception as exc:  # e.g. the context was shut down from outside
                self.get_logger().warning(f"final markers not acknowledged: {exc!r}")

    def _cleanup(self) -> None:
        """Drop everything configure created; close the bag. Idempotent; also after a
        configuration that stopped half-way."""
        if self._active:
            self._deactivate()
        if self.static is not None:
            self.static.close()  # waits for an index being built: it signals a guard condition
            self.static = None
        if self._clock_jump_handle is not None:
            self._clock_jump_handle.unregister()
        if self._service is not None:
            self.destroy_service(self._service)
        for pub in (self._predictions_pub, self._probabilities_pub, self._markers_pub,
                    self._diagnostics_pub):
            if pub is not None:
                self.destroy_lifecycle_publisher(pub)
        if self._recorder is not None:
            try:
                self._recorder.close()
            except RecordingError as exc:
                self.get_logger().error(f"closing the recording failed: {exc}")
        self._forget_configuration()

    # -- static world ---------------------------------------------------------------------------
    def _adopt_frame(self, frame_id: str) -> None:
        """A static input arrived before any state: its frame becomes the scene's."""
        self.predictor.frame_id = frame_id

    def _on_static_world(self, index, version: int) -> None:
        """A newly indexed static world (executor thread, between predictions): predict
        against it from now on, record that it applies here, and publish."""
        with self.activity.busy():
            self.predictor.set_static(index)
            now_ns = self._drain_clock()
            if self._static_recording:
                self._record_static_applied(version, now_ns)
            if self._active and len(self.predictor):
                self._publish(now_ns)

    def _record_static_applied(self, version: int, log_ns: int) -> None:
        data = serialize_message(String(data=json.dumps({"version": version})))
        self._record(self._static_topic, data, log_ns)

    def _record_static(self, topic: str, data: bytes) -> None:
        if self._static_recording:
            self._record(topic, data, self.get_clock().now().nanoseconds)

    @property
    def _static_topic(self) -> str:
        # Recorded only: where each static world version starts to apply, for replay.
        return f"{self.get_fully_qualified_name()}/static_applied"

    # -- inputs ---------------------------------------------------------------------------------
    def _subscribe(self, source: InputTopic) -> None:
        """Subscribe to raw bytes of `source` (its topic is resolved: one name for warnings,
        recording and replay)."""
        # raw=True: the exact received bytes are what a recording must keep; the two-argument
        # callback receives the rmw MessageInfo (receive timestamp, writer sequence number).
        source.subscription = self.create_subscription(
            source.msg_type,
            source.topic,
            functools.partial(self._on_input, source),
            source.qos(),
            raw=True,
            qos_overriding_options=QoSOverridingOptions.with_default_policies(),
        )

    def _on_input(self, source: InputTopic, data: bytes, info: dict) -> None:
        """Ingest this input and every input already waiting, then publish once (on-change mode)."""
        if not self._active:  # taken by the executor just before a deactivation
            return
        with self.activity.busy():
            now_ns = self._drain_clock()
            taken = [(source, data, info)]
            self._take_waiting(taken)
            self._ingest_all(taken, now_ns)
            if self._publish_timer is None and self._unanswered.changed:
                self._publish(now_ns)

    def _drain_clock(self) -> int:
        """The receive time of one drain: the clock, but never equal to the previous drain's.

        Replay tells one drain's run of single states from the next by their log time
        (pipeline/state_groups); only a stopped clock (sim time) could repeat it.
        """
        now_ns = max(self.get_clock().now().nanoseconds, self._last_drain_ns + 1)
        self._last_drain_ns = now_ns
        return now_ns

    def _take_waiting(self, taken: list) -> None:
        """Append what waits on every input subscription (at most what the queues hold)."""
        budget = self._drain_limit
        while budget > 0:
            before = len(taken)
            for source in self._inputs:
                if source.subscription is None:  # deactivated
                    return
                handle = source.subscription.handle
                room = budget - (len(taken) - before)
                try:
                    # held for the whole run of takes (entering costs more than a take)
                    with handle:
                        take = handle.take_message
                        msg_type = source.msg_type
                        while room > 0:
                            message = take(msg_type, True)
                            if message is None:
                                break
                            taken.append((source, message[0], message[1]))
                            room -= 1
                except InvalidHandle:  # destroyed during shutdown
                    return
            if len(taken) == before:
                return
            budget -= len(taken) - before

    def _ingest_all(self, taken: list, now_ns: int) -> None:
        """Record every taken input in order, then merge.

        Arrays are merged one by one, runs of single states together.
        """
        run: list = []
        for source, data, info in taken:
            received_ns = (info or {}).get("received_timestamp") or time.time_ns()
            self.counters.messages += 1
            self.input_loss.observe(source.topic, len(data), info, received_ns)
            # Before decoding: even garbage is kept for debugging. The recording's order is the
            # order of ingestion, and its log time the clock the scene was told.
            self._record(source.topic, data, now_ns, (info or {}).get("source_timestamp") or None)
            if source.msg_type is CircleState:
                run.append((source, data, received_ns))
                continue
            self._ingest_run(run, now_ns)
            run = []
            self._ingest_message(source, data, received_ns, now_ns)
        self._ingest_run(run, now_ns)

    def _ingest_message(
        self, source: InputTopic, data: bytes, received_ns: int, now_ns: int
    ) -> None:
        topic, changed = source.topic, False
        try:
            report = self.predictor.receive_batch(source.decode(data), now_ns)
            changed = report.changed
            self._account(topic, report)
        except CdrError as exc:  # a malformed payload must not stop the node
            self.counters.rejected += 1
            self._warn(topic, f"{topic}: rejected {source.msg_type.__name__}: {exc}")
        except Exception as exc:  # a bug must cost one message, not the node
            self.counters.errors += 1
            self._warn("receive", f"{topic}: message skipped: {exc!r}")
        self._unanswered.note(received_ns, changed)

    def _ingest_run(self, run: list, now_ns: int) -> None:
        """Consecutive single-state messages of one drain, merged as one group (state_groups)."""
        if not run:
            return
        changed = False
        try:
            outcome = ingest_single_states(self.predictor, [data for _, data, _ in run], now_ns)
            for (source, _, _), report, error in zip(run, outcome.reports, outcome.errors):
                if error is not None:
                    self.counters.rejected += 1
                    self._warn(source.topic, f"{source.topic}: rejected CircleState: {error}")
                elif (
                    report.accepted
                    or report.removed
                    or report.ignored
                    or report.rejected
                    or report.expired
                ):  # (a wave's counts sit on its first message)
                    changed = changed or report.changed
                    self._account(source.topic, report)
        except Exception as exc:  # a bug must cost these messages, not the node
            self.counters.errors += 1
            self._warn("receive", f"{len(run)} single-state message(s) skipped: {exc!r}")
        self._unanswered.note(run[0][2], changed, len(run))

    def _account(self, topic: str, report: IntakeReport) -> None:
        c = self.counters
        c.accepted += report.accepted
        c.removed += report.removed
        c.ignored += report.ignored
        c.expired += len(report.expired)
        c.rejected += len(report.rejected)
        c.covariance_ignored += report.covariance_ignored
        if report.covariance_ignored:
            self._warn(f"{topic} covariance", f"{topic}: covariance of "
                       f"{report.covariance_ignored} state(s) ignored (use_covariance is false): "
                       "predicted on the mean states, without probabilities")
        if report.rejected:
            shown = "; ".join(f"id '{r.body_id}': {r.reason}" for r in report.rejected[:3])
            more = f" (+{len(report.rejected) - 3} more)" if len(report.rejected) > 3 else ""
            self._warn(topic, f"{topic}: rejected {len(report.rejected)} state(s): {shown}{more}")

    def _warn(self, key: str, text: str) -> None:
        """A warning per key (topic) at most every WARN_THROTTLE_S."""
        now = time.monotonic()
        if now - self._last_warning.get(key, -1e9) >= self.WARN_THROTTLE_S:
            self._last_warning[key] = now
            self.get_logger().warning(text)

    # -- outputs --------------------------------------------------------------------------------
    def _on_publish_timer(self) -> None:
        with self.activity.busy():
            now_ns = self.get_clock().now().nanoseconds
            self.counters.expired += len(self.predictor.expire(now_ns))
            self._publish(now_ns)

    def _on_expiry_timer(self) -> None:
        """Bodies whose sources went silent leave the scene, and the changed scene is published."""
        now_ns = self.get_clock().now().nanoseconds
        expired = self.predictor.expire(now_ns)
        if expired:
            self.counters.expired += len(expired)
            with self.activity.busy():
                self._publish(now_ns)

    def _publish(self, now_ns: int) -> None:
        try:
            prediction = self.predictor.predict()
            data = prediction.to_cdr()
        except Exception as exc:  # never let one bad scene stop the stream
            self.counters.errors += 1
            self._warn(
                "predict",
                f"prediction failed, scene of {self.predictor.bodies} bodies skipped: {exc!r}",
            )
            return
        self._predictions_pub.publish(data)
        published_ns = time.time_ns()  # the rmw receive timestamps are system-clock times too
        # Log time = the clock reading the prediction was computed at, so replay can
        # recompute it at the same instant (expiry depends on it).
        self._record(self._predictions_pub.topic_name, data, now_ns)
        self.counters.published += 1
        pending = self._unanswered
        if pending.oldest_received_ns is not None:
            self.latencies_s.append(max(0, published_ns - pending.oldest_received_ns) * 1e-9)
        self.counters.coalesced += max(0, pending.inputs - 1)
        self._unanswered = Unanswered()
        self.markers.offer(prediction)
        if self.predictor.config.use_covariance:
            self.probabilities.offer(prediction, data, now_ns)

    def _on_predict_request(
        self, request: PredictCollisions.Request, response: PredictCollisions.Response
    ) -> PredictCollisions.Response:
        if not self._active:  # the service exists from configure on, and answers when active
            response.success = False
            response.message = (f"{self.get_name()} is {self.lifecycle_state}: "
                                "predict_collisions answers only while the node is active")
            return response
        try:
            ok, message, prediction = predict_once(
                request.circles,
                self.predictor.config,
                request.horizon,
                request_time_ns=self.get_clock().now().nanoseconds,
                static=self.predictor.static,
                ego_ids=tuple(request.ego_ids),
            )
            response.success, response.message = ok, message
            response.predictions = (
                prediction.to_message().predictions if prediction is not None else []
            )
        except Exception as exc:  # the caller gets an answer, never a dead service
            response.success, response.message = False, f"internal error: {exc!r}"
        return response

    def _on_clock_jump(self, jump) -> None:
        backwards = (
            jump.delta.nanoseconds < 0 and jump.clock_change == ClockChange.ROS_TIME_NO_CHANGE
        )
        if not backwards and jump.clock_change not in (
            ClockChange.ROS_TIME_ACTIVATED,
            ClockChange.ROS_TIME_DEACTIVATED,
        ):
            return
        if self.predictor is None:  # unconfigured
            return
        bodies = self.predictor.bodies
        self.predictor.clear()
        self._last_drain_ns = 0
        if backwards:
            self.counters.clock_jumps_back += 1
            self.get_logger().warning(
                f"clock jumped back by {-jump.delta.nanoseconds * 1e-9:.3f} s: scene of {bodies} "
                "bodies cleared, predicting again from the next states"
            )

    def _publish_diagnostics(self) -> None:
        c, s, totals = self.counters, self.predictor.stats, self._side_totals
        lat = np.array(self.latencies_s) if self.latencies_s else np.zeros(1)
        level = DiagnosticStatus.OK if c.errors == 0 else DiagnosticStatus.WARN
        values = {
            "bodies": self.predictor.bodies,
            "messages": c.messages,
            "states_accepted": c.accepted,
            "states_rejected": c.rejected,
            "states_ignored_not_newer": c.ignored,
            "covariances_ignored": c.covariance_ignored,
            "bodies_removed": c.removed,
            "bodies_expired": c.expired,
            "predictions_published": c.published,
            "inputs_coalesced": c.coalesced,
            "inputs_missing": self.input_loss.missing,
            "candidate_pairs": s.candidate_pairs,
            "contacts": s.contacts,
            "uncertain_pairs_deferred": s.uncertain_deferred,
            "compute_ms_last": f"{s.compute_s * 1e3:.3f}",
            # From the rmw receive timestamp of the oldest input answered to publication:
            # queue wait, coalescing, decoding, prediction and encoding included.
            "latency_ms_p50": f"{np.percentile(lat, 50) * 1e3:.3f}",
            "latency_ms_p99": f"{np.percentile(lat, 99) * 1e3:.3f}",
            "latency_ms_max": f"{lat.max() * 1e3:.3f}",
            "probabilities_published": totals["probabilities_published"]
            + self.probabilities.published,
            "probabilities_superseded": totals["probabilities_superseded"]
            + self.probabilities.superseded,
            "probabilities_late": totals["probabilities_late"] + self.probabilities.late,
            "probabilities_ms_last": f"{self.probabilities.last_compute_s * 1e3:.3f}",
            "probabilities_delay_ms_last": f"{self.probabilities.last_delay_s * 1e3:.3f}",
            "static_world_version": self.static.applied_version if self.static else 0,
            "static_inputs_rejected": self.static.rejected if self.static else 0,
            "static_index_ms_last": f"{self.static.index_s_last * 1e3:.3f}" if self.static
            else "0.000",
            "markers_drawn": totals["markers_drawn"] + self.markers.drawn,
            "marker_ms_last": f"{self.markers.last_cost_s * 1e3:.3f}",
            "errors": c.errors,
            "clock_jumps_back": c.clock_jumps_back,
        }
        values.update(self._transport_values())
        self.input_loss.forget_silent(time.time_ns())
        losses = self.input_loss.new_losses()
        for line in losses:
            self._warn("input_loss", line)
        # A failed recording must show where operators look, not only once in the log
        # (tests/reliability/test_faults_recording.py::test_recording_directory_removed).
        recording_error = self._recording_error or (
            self._recorder.error if self._recorder else None
        )
        if self._recorder is None:
            values["recording"] = "off"
        elif recording_error:
            values["recording"] = f"failed: {recording_error}"
        else:
            values["recording"] = f"ok: {self._recorder.path}"
        problems = [f"{c.errors} prediction errors"] if c.errors else []
        if recording_error:
            level = DiagnosticStatus.WARN
            problems.append("recording failed, predictions continue")
        if losses or self._unmatched_publishers:
            level = DiagnosticStatus.WARN
            problems += losses + self._unmatched_publishers
        lag = tuple(int(values[f"probabilities_{k}"]) for k in ("published", "late", "superseded"))
        behind = lag_problem(*(now - seen for now, seen in zip(lag, self._lag_seen)))
        self._lag_seen = lag
        if behind:
            level = DiagnosticStatus.WARN
            problems.append(f"{behind} since the last report")
            self._warn("probabilities lag", f"{behind} in the last {self.DIAGNOSTICS_PERIOD_S:g} s "
                       "(fewer bodies with covariance, a lower input rate or more cores keep up; "
                       "docs/node.md)")
        status = DiagnosticStatus(level=level, name=f"{self.get_name()}: collision prediction",
                                  message="; ".join(problems) or "ok",
                                  hardware_id=self.get_fully_qualified_name(),
                                  values=[KeyValue(key=k, value=str(v)) for k, v in values.items()])
        self._diagnostics_pub.publish(
            DiagnosticArray(header=Header(stamp=self.get_clock().now().to_msg()), status=[status])
        )

    def _transport_values(self) -> dict[str, str]:
        """What the transport delivers: profile in force, largest input, publishers and their QoS.

        Also sets _unmatched_publishers: best-effort publishers a reliable subscription
        (state_reliability:=reliable) can never receive from.
        """
        reliable = node_parameters.value_of(self, "state_reliability") == "reliable"
        summary, unmatched = [], []
        for source in self._inputs:
            kinds = self._publisher_kinds(source.topic)
            shown = ", ".join(f"{n} {k}" for k, n in sorted(kinds.items())) or "none"
            summary.append(f"{source.topic}: {shown}")
            if reliable and kinds.get("best_effort"):
                unmatched.append(
                    f"{source.topic}: {kinds['best_effort']} best-effort publisher(s) cannot "
                    "reach this node's reliable subscription (state_reliability)"
                )
        self._unmatched_publishers = unmatched
        largest = max((t.largest_bytes for t in self.input_loss.topics.values()), default=0)
        return {"transport_profile": self._transport_profile or "Fast DDS defaults",
                "largest_input_kb": f"{largest / 1024:.1f}", "input_publishers": "; ".join(summary)}

    #: Publisher QoS lists older than this are read again even if the count is unchanged, s.
    PUBLISHER_INFO_REFRESH_S = 10.0

    def _publisher_kinds(self, topic: str) -> dict[str, int]:
        """How many publishers on `topic` offer each reliability, listed again only when their
        count changed (or every PUBLISHER_INFO_REFRESH_S): listing the QoS of hundreds of
        per-body publishers is slow enough to delay predictions if done every second."""
        count = self.count_publishers(topic)
        now = time.monotonic()
        cached = self._publisher_info.get(topic)
        if cached is None or cached[0] != count or now - cached[1] > self.PUBLISHER_INFO_REFRESH_S:
            kinds: dict[str, int] = {}
            for info in self.get_publishers_info_by_topic(topic):
                kind = info.qos_profile.reliability.name.lower()
                kinds[kind] = kinds.get(kind, 0) + 1
            cached = self._publisher_info[topic] = (count, now, kinds)
        return cached[2]

    # -- recording ------------------------------------------------------------------------------
    @staticmethod
    def _open_bag(path: str) -> BagRecorder:
        """The bag at ``path``; an unusable one refuses start-up (no silent non-recording)."""
        try:
            return BagRecorder(path)
        except RecordingError as exc:
            raise ValueError(f"record_path: {exc}") from exc

    def _start_recording(self) -> None:
        """Declare the recorded topics in the opened bag and record the configuration."""
        try:
            for source in self._inputs:
                self._recorder.add_topic(
                    source.topic, _ros_type_name(source.msg_type), self._offered_qos(source.topic)
                )
            for pub in (self._predictions_pub, self._probabilities_pub):
                self._recorder.add_topic(pub.topic_name, _ros_type_name(CollisionPredictionArray),
                                         qos_profiles_yaml([pub.qos_profile]))
            # Recorded, not published: offered as `ros2 bag play` should replay it.
            self._recorder.add_topic(
                self._config_topic, "std_msgs/msg/String", qos_profiles_yaml([Qos.predictions()])
            )
            if self.static is not None:
                for topic, msg_type in self.static.topics:
                    self._recorder.add_topic(topic, _ros_type_name(msg_type),
                                             self._offered_qos(topic))
                self._recorder.add_topic(self._static_topic, "std_msgs/msg/String",
                                         qos_profiles_yaml([Qos.predictions()]))
        except RecordingError as exc:
            raise ValueError(f"record_path: {exc}") from exc
        # Input publishers may appear later: looked for while active (_record_offered_qos).
        self._qos_unknown = {s.topic for s in self._inputs if not self._offered_qos(s.topic)}
        self._record_config()
        self._static_recording = self.static is not None
        if self._static_recording and self.static.applied_version:  # the parameters' polygons
            self._record_static_applied(self.static.applied_version,
                                        self.get_clock().now().nanoseconds)
        self.get_logger().info(f"recording to {self._recorder.path}")

    def _offered_qos(self, topic: str) -> str:
        """rosbag2's offered_qos_profiles of the publishers on `topic` now ("" if none)."""
        return qos_profiles_yaml(
            [info.qos_profile for info in self.get_publishers_info_by_topic(topic)]
        )

    def _record_offered_qos(self) -> None:
        """Timer while recording: fill offered_qos_profiles once a topic's publishers are seen."""
        for topic in sorted(self._qos_unknown):
            offered = self._offered_qos(topic)
            if offered and self._recorder is not None and not self._recording_error:
                try:
                    self._recorder.set_offered_qos(topic, offered)
                except RecordingError as exc:
                    self._recording_error = self._recording_error or str(exc)
                self._qos_unknown.discard(topic)
        if not self._qos_unknown and self._qos_timer is not None:
            self.destroy_timer(self._qos_timer)
            self._qos_timer = None

    @property
    def _config_topic(self) -> str:
        # Recorded only (not published): the configuration in force, for replay.
        return f"{self.get_fully_qualified_name()}/config"

    def _record_config(self) -> None:
        if self._recorder is None or self._recording_error:
            return
        config = dict(asdict(self.predictor.config),
                      publish_rate=node_parameters.value_of(self, "publish_rate"),
                      probabilities_topic=self._probabilities_pub.topic_name,
                      odometry={t: asdict(s) for t, s in self._odometry_sources.items()},
                      static=asdict(self.static.settings) if self.static is not None else None)
        data = serialize_message(String(data=json.dumps(config, sort_keys=True)))
        self._record(self._config_topic, data, self.get_clock().now().nanoseconds)
        try:  # also as bag metadata, for tools that look there rather than at topics
            self._recorder.write_config(config)
        except RecordingError as exc:
            self._recording_error = self._recording_error or str(exc)

    def _record(
        self, topic: str, data: bytes, log_time_ns: int, publish_time_ns: int | None = None
    ) -> None:
        """publish_time_ns: the writer's source timestamp of an input, when rmw gives it."""
        if self._recorder is None or self._recording_error:
            return
        try:
            self._recorder.write(topic, data, log_time_ns, publish_time_ns)
        except RecordingError as exc:  # keep predicting; say so loudly, once
            self._recording_error = str(exc)
            self.get_logger().error(f"recording stopped, predictions continue: {exc}")

    def destroy_node(self) -> None:
        """The shutdown transition (from a primary state), then the node.

        Also called on a node whose __init__ did not finish (Ctrl-C during the warm-up, a
        start-up error: rclpy's shutdown destroys every node of the context), possibly in the
        middle of a transition: then only what exists is released. A second call does
        nothing (the state machine is gone after the first).
        """
        if getattr(self, "_destroyed", False):
            return
        self._destroyed = True
        if hasattr(self, "_active"):
            self._quiet = True
            if self.lifecycle_state in ("unconfigured", "inactive", "active"):
                try:
                    self.trigger_shutdown()
                except Exception as exc:  # noqa: BLE001 - released below either way
                    self.get_logger().warning(f"shutdown transition failed: {exc!r}")
            self._release()
        machine = getattr(self, "_state_machine", None)
        super().destroy_node()
        if machine is not None:
            machine.destroy_when_not_in_use()

    # -- parameters -----------------------------------------------------------------------------
    def _validate_parameters(self, params) -> SetParametersResult:
        for param in params:
            reason = node_parameters.validate(param.name, param.value)
            if reason:
                return SetParametersResult(successful=False, reason=reason)
        return SetParametersResult(successful=True)

    def _apply_parameters(self, params) -> None:
        """Unconfigured, a change is only stored (configure reads it); inactive, it reaches the
        predictor; the timers and marker thread exist only while active."""
        if self.predictor is None:
            return
        changes = {p.name: p.value for p in params if p.name in RUNTIME_FIELDS}
        if changes:
            self.predictor.reconfigure(**changes)
        for param in params:
            if param.name == "publish_rate" and self._active:
                self._set_publish_rate(param.value)
            elif param.name == "marker_rate" and self.markers is not None:
                self.markers.set_rate(param.value)
        if changes or any(p.name == "publish_rate" for p in params):
            self._record_config()  # replay must know what was in force from here on

    def _set_publish_rate(self, rate_hz: float) -> None:
        if self._publish_timer is not None:
            self.destroy_timer(self._publish_timer)
            self._publish_timer = None
        if rate_hz > 0.0:
            self._publish_timer = self.create_timer(1.0 / rate_hz, self._on_publish_timer)


def main(args: list[str] | None = None) -> int:
    argv = sys.argv if args is None else args
    # A thread waiting for the interpreter lock (the prediction path, woken by a message while
    # the marker thread computes) gets it after at most this long instead of 5 ms.
    sys.setswitchinterval(0.0005)
    parse_args(argv, __doc__.splitlines()[0])
    return spin_node(_started_node, argv, "collision_node")


def _started_node() -> CollisionNode:
    """The node, with everything alive at start-up moved out of the cyclic collector's sight.

    rclpy and numba's compiled kernels leave ~10^5 objects that live until exit; one full
    collection scanning them took ~0.4 s on this machine, a stall of the stream whenever it
    struck. Frozen (gc.freeze), collections scan only what the stream itself allocates.
    """
    node = CollisionNode()
    gc.collect()
    gc.freeze()
    node.freeze_gc_after_configure = True  # autostart:=false: each later configure does too
    return node


def _reason(exc: BaseException) -> str:
    """The one-line reason of a refused transition (the message of an expected error)."""
    expected = (ValueError, OSError, RecordingError, ParameterException, NameValidationException)
    return str(exc) if isinstance(exc, expected) else repr(exc)


def _ros_type_name(msg_type: type) -> str:
    """'circle_collision_msgs/msg/CircleStateArray' for the class (rosbag2's type names)."""
    return f"{msg_type.__module__.split('.')[0]}/msg/{msg_type.__name__}"


if __name__ == "__main__":
    sys.exit(main())
