"""collision_node as a managed (lifecycle) node, driven over real DDS on localhost.

The transitions are requested as `ros2 lifecycle set` requests them: the node's
`get_available_transitions` names the transition by label, and `change_state`
(lifecycle_msgs/srv/ChangeState) is called with it; `get_state` answers the state.

Guarantees proved here:
- autostart (the default) configures and activates at start: get_state answers `active`;
- autostart:=false starts unconfigured: no subscription, no publisher of ours, nothing
  published, no service;
- configure -> inactive: publishers and the service exist but a published state gets no
  prediction, nothing is published, and the service refuses naming the state;
- activate -> predictions flow; deactivate -> inputs are not taken, nothing is published
  (the markers are cleared first), and the scene keeps its bodies: after the next activation
  a prediction lists a pair whose other body was sent only before the deactivation;
- cleanup -> unconfigured, the bodies gone; shutdown -> finalized;
- a refused configuration (bad parameter, unusable record_path) answers success=false,
  logs the reason and leaves the node unconfigured;
- with record_path, cleanup and shutdown each leave a complete bag (read back strictly
  and replayed bit for bit, across a deactivation); a configuration after a cleanup records
  to <record_path>_2.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest
from diagnostic_msgs.msg import DiagnosticArray
from lifecycle_msgs.srv import ChangeState, GetAvailableTransitions, GetState
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from visualization_msgs.msg import MarkerArray

from circle_collision_msgs.msg import CircleStateArray, CollisionPredictionArray
from circle_collision_msgs.srv import PredictCollisions
from circle_collision_ros.node.collision_node import CollisionNode
from circle_collision_ros.recording.bag_reader import open_bag
from circle_collision_ros.recording.replay_engine import replay_bag
from tests.node.conftest import reader_matched, spin_until
from tests.node_helpers import contacts_of, state, state_array

NODE = "/collision_node"
QUIET_S = 1.5  # how long "nothing arrives" is watched


class Lifecycle:
    """What `ros2 lifecycle get` / `ros2 lifecycle set` do, from `client` to the node."""

    def __init__(self, client, server=None) -> None:
        """server: the node in this process (spun with the client), or None (another process)."""
        self.client, self.extra = client, (server,) if server is not None else ()
        self._get = client.create_client(GetState, f"{NODE}/get_state")
        self._change = client.create_client(ChangeState, f"{NODE}/change_state")
        self._transitions = client.create_client(GetAvailableTransitions,
                                                 f"{NODE}/get_available_transitions")

    def _call(self, service, request):
        assert spin_until(self.client, service.service_is_ready, 20.0, self.extra), (
            service.srv_name)
        future = service.call_async(request)
        # configure may load (or, after a code change, compile) the kernels
        assert spin_until(self.client, future.done, 300.0, self.extra), service.srv_name
        return future.result()

    def state(self) -> str:
        return self._call(self._get, GetState.Request()).current_state.label

    def set(self, label: str) -> bool:
        """`ros2 lifecycle set /collision_node <label>`: True if the transition succeeded."""
        available = self._call(self._transitions, GetAvailableTransitions.Request())
        matching = [t.transition for t in available.available_transitions
                    if t.transition.label == label]
        assert matching, f"'{label}' is not available in state '{self.state()}'"
        return self._call(self._change, ChangeState.Request(transition=matching[0])).success


class Observer:
    """A client node publishing states and collecting all the collision node publishes."""

    def __init__(self, client, server=None) -> None:
        self.client, self.server = client, server
        self.extra = (server,) if server is not None else ()
        self.predictions: list[CollisionPredictionArray] = []
        self.markers: list[MarkerArray] = []
        self.diagnostics: list[DiagnosticArray] = []
        client.create_subscription(CollisionPredictionArray, "collision_predictions",
                                   self.predictions.append, 50)
        client.create_subscription(MarkerArray, "collision_node/markers", self.markers.append, 50)
        client.create_subscription(DiagnosticArray, "/diagnostics", self.diagnostics.append, 50)
        self.pub = client.create_publisher(
            CircleStateArray, "circle_states", QoSProfile(depth=50,
                                                          reliability=ReliabilityPolicy.RELIABLE))

    def now_ns(self) -> int:
        return self.client.get_clock().now().nanoseconds

    def received(self) -> tuple[int, int, int]:
        return len(self.predictions), len(self.markers), len(self.diagnostics)

    def spin(self, seconds: float) -> None:
        spin_until(self.client, lambda: False, seconds, self.extra)

    def send(self, states, timeout: float = 15.0) -> CollisionPredictionArray:
        """Publish until a prediction listing every body of `states` arrives (the node's reader
        is best-effort: the first sample after a match can be lost; a repeat is ignored)."""
        ids = {s.id for s in states}
        count = len(self.predictions)

        def answered() -> bool:
            return any(ids <= _bodies(m) for m in self.predictions[count:])

        matched = (reader_matched(self.server, "circle_states") if self.server is not None
                   else lambda: self.pub.get_subscription_count() > 0)
        assert spin_until(self.client, matched, 30.0, self.extra), "the node never subscribed"
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            self.pub.publish(state_array(states))
            if spin_until(self.client, answered, min(1.0, deadline - time.monotonic()),
                          self.extra):
                return next(m for m in self.predictions[count:] if ids <= _bodies(m))
        raise AssertionError(f"no prediction listing {sorted(ids)}")

    def publish_unanswered(self, states) -> None:
        """Publish `states` (a few times) and check that nothing at all comes back."""
        before = self.received()
        for _ in range(3):
            self.pub.publish(state_array(states))
            self.spin(QUIET_S / 3)
        assert self.received() == before, "published while not active"


def _bodies(msg: CollisionPredictionArray) -> set[str]:
    return {p.id_a for p in msg.predictions} | {p.id_b for p in msg.predictions}


def _pairs(msg: CollisionPredictionArray) -> set[frozenset]:
    return {frozenset(pair) for pair in contacts_of(msg)}


def _managed(context, *extra: Parameter) -> CollisionNode:
    # Expiry runs on a timer: on a busy machine the test's own pauses must not expire bodies.
    return CollisionNode(context=context, parameter_overrides=[
        Parameter("autostart", value=False), Parameter("frame_id", value="map"),
        Parameter("stale_timeout", value=120.0), Parameter("marker_rate", value=50.0), *extra])


def _ours(topics) -> set[str]:
    """Topics of the collision node's own (not rclpy's parameter or lifecycle events)."""
    return {t for t in topics if t != "/parameter_events" and not t.endswith("transition_event")}


def test_autostart_node_is_active(ros_context, ros_node) -> None:
    node = CollisionNode(context=ros_context)
    try:
        assert Lifecycle(ros_node, node).state() == "active"
        assert node.get_parameter("autostart").value is True
        assert not node.set_parameters([Parameter("autostart", value=False)])[0].successful
    finally:
        node.destroy_node()


def test_unconfigured_node_holds_nothing_and_publishes_nothing(ros_context, ros_node) -> None:
    node = _managed(ros_context)
    try:
        lifecycle, observer = Lifecycle(ros_node, node), Observer(ros_node, node)
        assert lifecycle.state() == "unconfigured"
        assert node.predictor is None
        assert _ours([s.topic_name for s in node.subscriptions]) == set()
        assert _ours([p.topic_name for p in node.publishers]) == set()
        assert ros_node.count_subscribers("/circle_states") == 0
        assert not [s for s in node.services if s.srv_name == "/predict_collisions"]
        observer.publish_unanswered([state("a", (0, 0), stamp_ns=observer.now_ns())])
        assert lifecycle.set("shutdown")
        assert lifecycle.state() == "finalized"
    finally:
        node.destroy_node()


def test_transitions_drive_the_stream(ros_context, ros_node) -> None:
    node = _managed(ros_context)
    lifecycle, observer = Lifecycle(ros_node, node), Observer(ros_node, node)
    service = ros_node.create_client(PredictCollisions, "predict_collisions")

    def call_service():
        assert spin_until(ros_node, service.service_is_ready, 20.0, (node,))
        future = service.call_async(PredictCollisions.Request(
            circles=[state("s", (0, 0), stamp_ns=observer.now_ns()),
                     state("t", (0.5, 0), stamp_ns=observer.now_ns())], horizon=1.0))
        assert spin_until(ros_node, future.done, 20.0, (node,))
        return future.result()

    try:
        # configure: publishers and service exist, nothing is subscribed or published
        assert lifecycle.set("configure")
        assert lifecycle.state() == "inactive"
        assert node.predictor is not None and len(node.predictor) == 0
        assert _ours([s.topic_name for s in node.subscriptions]) == set()
        assert {"/collision_predictions", "/diagnostics"} <= {p.topic_name
                                                             for p in node.publishers}
        observer.publish_unanswered([state("x", (9, 9), stamp_ns=observer.now_ns())])
        refused = call_service()
        assert not refused.success and "inactive" in refused.message, refused.message
        assert node.counters.messages == 0

        # activate: predictions flow, and the service answers
        assert lifecycle.set("activate")
        assert lifecycle.state() == "active"
        now = observer.now_ns()
        first = observer.send([state("a", (0, 0), stamp_ns=now),
                               state("b", (0.5, 0), stamp_ns=now)])
        assert _pairs(first) == {frozenset("ab")}
        assert call_service().success
        assert spin_until(ros_node, lambda: observer.markers and observer.diagnostics, 15.0,
                          (node,))

        # deactivate: the markers are cleared, then nothing is taken or published
        assert lifecycle.set("deactivate")
        assert lifecycle.state() == "inactive"
        assert spin_until(ros_node, lambda: [m.action for m in observer.markers[-1].markers]
                          == [3], 10.0, (node,)), "the display was not cleared"
        observer.spin(0.3)  # anything published before the deactivation has arrived
        messages = node.counters.messages
        observer.publish_unanswered([state("c", (0, -0.5), stamp_ns=observer.now_ns())])
        assert node.counters.messages == messages
        assert "a" in node.predictor and "b" in node.predictor and "c" not in node.predictor

        # activate again: the kept scene meets a new body; c (sent while inactive) never came
        assert lifecycle.set("activate")
        later = observer.send([state("d", (0, 0.6), stamp_ns=observer.now_ns())])
        assert {frozenset("ad"), frozenset("bd")} <= _pairs(later)
        assert frozenset("ab") in _pairs(later) and "c" not in _bodies(later)

        # deactivate + cleanup: the bodies are gone, back to unconfigured
        assert lifecycle.set("deactivate") and lifecycle.set("cleanup")
        assert lifecycle.state() == "unconfigured"
        assert node.predictor is None
        assert _ours([p.topic_name for p in node.publishers]) == set()
        observer.publish_unanswered([state("e", (5, 5), stamp_ns=observer.now_ns())])

        # a new configuration starts from an empty scene
        assert lifecycle.set("configure") and lifecycle.set("activate")
        now = observer.now_ns()
        fresh = observer.send([state("f", (0, 0), stamp_ns=now), state("h", (0, 0.4),
                                                                         stamp_ns=now)])
        assert _bodies(fresh) == {"f", "h"} and "a" not in node.predictor

        # shutdown (from active): finalized, nothing left
        assert lifecycle.set("shutdown")
        assert lifecycle.state() == "finalized"
        assert _ours([s.topic_name for s in node.subscriptions]) == set()
        observer.publish_unanswered([state("g", (0, 0.3), stamp_ns=observer.now_ns())])
    finally:
        node.destroy_node()


@pytest.mark.parametrize("problem", ["parameter", "record_path"])
def test_refused_configuration_answers_failure_with_the_reason(ros_context, ros_node, tmp_path,
                                                               capfd, problem) -> None:
    if problem == "parameter":
        extra, reason = Parameter("horizon", value="soon"), "horizon must be a finite number"
    else:
        full = tmp_path / "full"
        full.mkdir()
        (full / "something").write_text("x")
        extra, reason = Parameter("record_path", value=str(full)), "record_path"
    node = _managed(ros_context, extra)
    try:
        lifecycle = Lifecycle(ros_node, node)
        assert not lifecycle.set("configure")
        assert lifecycle.state() == "unconfigured"
        assert node.predictor is None
        assert _ours([p.topic_name for p in node.publishers]) == set()
        logged: list[str] = []
        assert spin_until(
            ros_node, lambda: logged.append(capfd.readouterr().err) or reason in "".join(logged),
            10.0), logged
    finally:
        node.destroy_node()


def test_recording_is_complete_after_cleanup_and_shutdown(ros_context, ros_node,
                                                          tmp_path) -> None:
    bag = tmp_path / "bag"
    node = _managed(ros_context, Parameter("record_path", value=str(bag)))
    try:
        lifecycle, observer = Lifecycle(ros_node, node), Observer(ros_node, node)
        assert lifecycle.set("configure") and lifecycle.set("activate")
        now = observer.now_ns()
        observer.send([state("a", (0, 0), stamp_ns=now), state("b", (0.5, 0), stamp_ns=now)])
        assert lifecycle.set("deactivate") and lifecycle.set("activate")
        observer.send([state("d", (0, 0.6), stamp_ns=observer.now_ns())])
        assert lifecycle.set("deactivate") and lifecycle.set("cleanup")
        # cleanup closed the bag: it reads strictly (a truncated file would raise) and replays
        first = open_bag(bag)
        assert "/circle_states" in first.topics and "/collision_predictions" in first.topics
        report = replay_bag(bag)
        assert report.ok and report.predictions >= 2 and report.inputs >= 2, report.mismatches

        # record_path is read-only: the next configuration records beside the first bag
        assert lifecycle.set("configure")
        second = tmp_path / "bag_2"
        assert (second / "metadata.yaml").exists()
        assert lifecycle.set("shutdown")  # from inactive
        assert lifecycle.state() == "finalized"
        assert open_bag(second).config is not None
        assert "/collision_predictions" in open_bag(second).topics
        assert open_bag(bag).message_count == first.message_count  # the first bag untouched
    finally:
        node.destroy_node()


def test_managed_executable_stops_cleanly_on_ctrl_c(ros_node, tmp_path) -> None:
    """The executable with autostart:=false, driven from another process as `ros2 lifecycle
    set` drives it, then Ctrl-C while active: exit code 0, no traceback, the bag complete."""
    exe = os.path.join(sys.prefix, "lib", "circle_collision_ros", "collision_node")
    bag = tmp_path / "bag"
    proc = subprocess.Popen([exe, "--ros-args", "-p", "autostart:=false", "-p", "frame_id:=map",
                             "-p", f"record_path:={bag}", "-p", "stale_timeout:=120.0"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        lifecycle, observer = Lifecycle(ros_node), Observer(ros_node)
        assert lifecycle.state() == "unconfigured"
        assert not bag.exists()
        assert lifecycle.set("configure") and lifecycle.set("activate")
        now = observer.now_ns()
        observer.send([state("a", (0, 0), stamp_ns=now), state("b", (0.5, 0), stamp_ns=now)])
    except AssertionError as exc:
        proc.kill()
        pytest.fail(f"{exc}\ncollision_node output:\n{proc.communicate(timeout=20)[0]}")
    proc.send_signal(signal.SIGINT)
    output = proc.communicate(timeout=30)[0]
    assert proc.returncode == 0, output
    assert "Traceback" not in output, output
    assert replay_bag(bag).ok and open_bag(bag).message_count > 0
