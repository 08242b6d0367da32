"""collision_node over real DDS on localhost.

Guarantees proved here:
- as a separate process (as users run it) and in-process, predictions for
  published states equal the core narrow phase on every pair;
- several topics (arrays and single states) merge into one scene by id;
- the service answers good requests with the same predictions and bad ones with
  success=false and a message naming every bad circle; circles without a stamp
  are taken at the request time; it never raises;
- parameters: valid run-time changes apply, invalid ones are refused with a
  reason, read-only ones cannot change;
- every bad-input class is rejected while the rest of the scene is still
  predicted, no NaN is ever published, and the node survives a 50,000-body array;
- markers and diagnostics are published (tests/node/test_stream.py: stream rules); a period
  in which collision_probabilities published nothing it was given reports WARN, once.
"""
from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable

import pytest
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from visualization_msgs.msg import MarkerArray

from circle_collision_msgs.msg import CircleState, CircleStateArray, CollisionPredictionArray
from circle_collision_msgs.srv import PredictCollisions
from circle_collision_ros.node.collision_node import CollisionNode
from tests.node.conftest import reader_matched, spin_until
from tests.node_helpers import (BASE_NS, assert_no_nan, contacts_of, expected_contacts,
                                    random_states, state, state_array)


def _now_ns(node) -> int:
    return node.get_clock().now().nanoseconds


class Harness:
    """A client node that publishes states and collects what the collision node sends."""

    def __init__(self, client, collision_node=None) -> None:
        self.client = client
        self.extra = (collision_node,) if collision_node is not None else ()
        self.predictions: list[CollisionPredictionArray] = []
        self.markers: list[MarkerArray] = []
        self.diagnostics: list[DiagnosticArray] = []
        client.create_subscription(CollisionPredictionArray, "collision_predictions",
                                   self.predictions.append, 50)
        client.create_subscription(MarkerArray, "collision_node/markers", self.markers.append, 10)
        client.create_subscription(DiagnosticArray, "/diagnostics", self.diagnostics.append, 10)
        qos = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)
        self.pub = client.create_publisher(CircleStateArray, "circle_states", qos)

    def wait_matched(self) -> None:
        assert spin_until(self.client, lambda: self.pub.get_subscription_count() > 0, 60.0,
                          self.extra), "collision_node never subscribed"
        for node in self.extra:  # in-process: also the node's (best-effort) reader side
            assert spin_until(self.client, reader_matched(node, "circle_states"), 60.0, self.extra)

    def send(self, msg, until=None, timeout: float = 15.0, pub=None) -> None:
        """Publish `msg` and wait for a prediction.

        The node's subscription is best-effort, and DDS may report a match to the
        publisher before the subscriber side has matched, so the first sample can
        be lost: re-send each second. A re-sent state has the same stamp, which the
        node ignores if the first one did arrive, so this never doubles an input.
        """
        count = len(self.predictions)
        done = until or (lambda: len(self.predictions) > count)
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            (pub or self.pub).publish(msg)
            if spin_until(self.client, done, min(1.0, deadline - time.monotonic()), self.extra):
                return
        raise AssertionError("no prediction arrived")


@pytest.fixture
def in_process(ros_context, ros_node):
    node = CollisionNode(context=ros_context, parameter_overrides=_in_process_parameters())
    harness = Harness(ros_node, node)
    harness.wait_matched()
    yield node, harness
    node.destroy_node()


def _in_process_parameters() -> list[Parameter]:
    return [Parameter("horizon", value=5.0), Parameter("frame_id", value="map"),
            Parameter("marker_rate", value=100.0),
            # Expiry runs on a timer: on a busy machine a test's own pauses must not expire its
            # bodies.
            Parameter("stale_timeout", value=60.0),
            Parameter("single_state_topics", value=["robot_1/circle_state"]),
            Parameter("state_topics", value=["circle_states", "lidar/circle_states"])]


@pytest.fixture(scope="module")
def shared_in_process():
    """The in_process node, one for the tests that need no fresh node: each sends only a and b
    (newer stamps each time; a bad state is never accepted), or calls the service, and changes
    no parameter. In a namespace of its own, so the other tests' inputs never reach its queue."""
    import rclpy
    from rclpy.context import Context

    context = Context()
    rclpy.init(context=context)
    client = rclpy.create_node("test_client", namespace="/shared", context=context)
    node = CollisionNode(
        context=context, namespace="/shared", parameter_overrides=_in_process_parameters()
    )
    try:
        harness = Harness(client, node)
        harness.wait_matched()
        yield node, harness
    finally:
        node.destroy_node()
        client.destroy_node()
        context.try_shutdown()


def _answered(harness: Harness, states) -> Callable[[], bool]:
    """A new prediction stamped with the newest of `states` (not one left from an earlier send)."""
    count, newest = len(harness.predictions), max(_ns(s.header.stamp) for s in states)
    return lambda: (
        len(harness.predictions) > count and _ns(harness.predictions[-1].header.stamp) == newest
    )


def _ns(stamp) -> int:
    return stamp.sec * 10**9 + stamp.nanosec


def _stamped_now(states, client) -> list[CircleState]:
    now = _now_ns(client)
    for s in states:
        t = now - (BASE_NS - (s.header.stamp.sec * 10**9 + s.header.stamp.nanosec))
        s.header.stamp.sec, s.header.stamp.nanosec = divmod(t, 10**9)
    return states


def test_separate_process_predicts_like_the_core(ros_node) -> None:
    exe = os.path.join(sys.prefix, "lib", "circle_collision_ros", "collision_node")
    proc = subprocess.Popen([exe, "--ros-args", "-p", "horizon:=5.0"], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    try:
        harness = Harness(ros_node)
        harness.wait_matched()
        states = _stamped_now(random_states(40, seed=11), ros_node)
        harness.send(state_array(states))
        out = harness.predictions[-1]
        assert contacts_of(out) == expected_contacts(states, 5.0)
        assert_no_nan(out)
    except AssertionError as exc:
        proc.kill()
        pytest.fail(f"{exc}\ncollision_node output:\n{proc.communicate(timeout=20)[0]}")
    proc.send_signal(signal.SIGINT)
    output = proc.communicate(timeout=20)[0]
    assert proc.returncode == 0, output
    assert "Traceback" not in output


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_shutdown_releases_markers_before_the_context(ros_node, sig) -> None:
    """Ctrl-C/SIGTERM with markers on: the marker thread is joined and the display cleared
    (a final DELETEALL reaches subscribers) while the context is valid; the log has no
    "markers not published: publisher's context is invalid" (rclpy's signal handler used
    to shut the context down before the node was destroyed)."""
    exe = os.path.join(sys.prefix, "lib", "circle_collision_ros", "collision_node")
    proc = subprocess.Popen([exe, "--ros-args", "-p", "horizon:=5.0", "-p", "marker_rate:=20.0"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        harness = Harness(ros_node)
        harness.wait_matched()
        states = _stamped_now(random_states(40, seed=12), ros_node)
        harness.send(state_array(states))
        assert spin_until(ros_node, lambda: any(len(a.markers) > 1 for a in harness.markers), 15.0)
        # keep the marker thread drawing while the signal arrives
        for k in range(5):
            harness.pub.publish(state_array(_stamped_now(random_states(40, seed=13 + k), ros_node)))
            spin_until(ros_node, lambda: False, 0.02)
        drawn = len(harness.markers)
    except AssertionError as exc:
        proc.kill()
        pytest.fail(f"{exc}\ncollision_node output:\n{proc.communicate(timeout=20)[0]}")
    proc.send_signal(sig)
    output = proc.communicate(timeout=20)[0]
    assert proc.returncode == 0, output
    assert "markers not published" not in output and "context is invalid" not in output, output
    assert "Traceback" not in output, output
    # the last array, received after the signal, clears the display
    assert spin_until(
        ros_node,
        lambda: (
            len(harness.markers) > drawn and [m.action for m in harness.markers[-1].markers] == [3]
        ),
        10.0,
    ), [[m.action for m in a.markers][:3] for a in harness.markers[drawn:]]


def test_sigint_stops_a_node_started_with_sigint_ignored(ros_node) -> None:
    """A process started in the background by a non-interactive shell (`nohup ... &`, a test
    loop run with `&`) inherits SIGINT ignored, and Python keeps it so; the node still stops
    on SIGINT (Ctrl-C, `ros2 launch`), as with rclpy's own handlers. (It used to spin on and
    fail the shutdown tests of such runs with a timeout.)"""
    exe = os.path.join(sys.prefix, "lib", "circle_collision_ros", "collision_node")
    proc = subprocess.Popen([exe, "--ros-args", "-p", "horizon:=5.0"], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN))
    try:
        Harness(ros_node).wait_matched()
        proc.send_signal(signal.SIGINT)
        output = proc.communicate(timeout=20)[0]
    except (AssertionError, subprocess.TimeoutExpired) as exc:
        proc.kill()
        pytest.fail(f"{exc!r}\ncollision_node output:\n{proc.communicate(timeout=20)[0]}")
    assert proc.returncode == 0, output
    assert "Traceback" not in output, output


def test_in_process_merges_topics_by_id(in_process, ros_node) -> None:
    node, harness = in_process
    states = _stamped_now([state("a", (0, 0), (1, 0, 0)), state("b", (10, 0))], ros_node)
    harness.send(state_array(states))
    assert contacts_of(harness.predictions[-1]) == {}  # 9 s > horizon of 5 s
    lidar = ros_node.create_publisher(CircleStateArray, "lidar/circle_states", 10)
    single = ros_node.create_publisher(CircleState, "robot_1/circle_state", 10)
    assert spin_until(ros_node,
                      lambda: lidar.get_subscription_count() and single.get_subscription_count(),
                      15.0, (node,))
    # Stamped like a and b: waiting for the new subscriptions to match can take seconds on a
    # loaded machine, and states stamped "now" after that would meet a and b after they passed.
    c, d = [state("c", (3, 0), (-1, 0, 0))], [state("d", (0, 4), (1, -1, 0))]
    for s in c + d:
        s.header.stamp = states[0].header.stamp
    harness.send(state_array(c), pub=lidar)
    harness.send(d[0], pub=single)
    out = harness.predictions[-1]
    assert contacts_of(out) == expected_contacts(states + c + d, 5.0)
    assert {("a", "c"), ("a", "d")} <= set(contacts_of(out))
    assert all(body in node.predictor for body in "abcd")


def test_markers_and_diagnostics_are_published(in_process, ros_node) -> None:
    node, harness = in_process
    harness.send(
        state_array(_stamped_now([state("a", (0, 0), (1, 0, 0)), state("b", (3, 0))], ros_node))
    )
    assert spin_until(ros_node, lambda: harness.markers and harness.diagnostics, 15.0, (node,))
    markers = harness.markers[-1].markers
    assert markers[0].action == markers[0].DELETEALL
    assert {(m.ns, m.action) for m in markers[1:]} == {("bodies", 0), ("contacts", 0)}
    assert sorted(m.id for m in markers if m.ns == "bodies") == [0, 1]
    values = {kv.key: kv.value for kv in harness.diagnostics[-1].status[0].values}
    assert values["bodies"] == "2" and int(values["predictions_published"]) >= 1
    assert float(values["latency_ms_p99"]) > 0.0 and "inputs_coalesced" in values
    assert values["probabilities_late"] == "0"  # node/probabilities.py counts them


def test_completions_falling_behind_show_on_diagnostics(in_process, ros_node) -> None:
    """A diagnostics period in which predictions were superseded and no completion published
    (node/probabilities.py, tests/node/test_probabilities.py) reports WARN naming the counts,
    once: the next period is OK again.  The counters are advanced by hand: making a real node
    fall behind takes a machine-dependent load."""
    from diagnostic_msgs.msg import DiagnosticStatus

    node, harness = in_process
    assert spin_until(ros_node, lambda: harness.diagnostics, 15.0, (node,))
    seen = len(harness.diagnostics)
    node.probabilities.superseded += 3
    node.probabilities.late += 2

    def reports():
        return [d.status[0] for d in harness.diagnostics[seen:]]

    assert spin_until(ros_node, lambda: len(reports()) >= 2, 15.0, (node,))
    warned = [r for r in reports() if r.level == DiagnosticStatus.WARN]
    assert len(warned) == 1, [r.message for r in reports()]
    assert "3 predictions got none" in warned[0].message
    assert reports()[-1].level == DiagnosticStatus.OK and reports()[-1].message == "ok"
    values = {kv.key: kv.value for kv in reports()[-1].values}
    assert values["probabilities_late"] == "2" and values["probabilities_superseded"] == "3"


def test_parameters_validated_and_applied(in_process) -> None:
    node, _ = in_process
    bad = node.set_parameters([Parameter("horizon", value=-1.0)])[0]
    assert not bad.successful and "horizon" in bad.reason
    assert not node.set_parameters([Parameter("stale_timeout", value=math.nan)])[0].successful
    assert node.predictor.config.horizon == 5.0
    assert node.set_parameters([Parameter("horizon", value=2.5)])[0].successful
    assert node.predictor.config.horizon == 2.5
    assert node.set_parameters([Parameter("report_all_pairs", value=True)])[0].successful
    assert node.predictor.config.report_all_pairs
    assert not node.set_parameters([Parameter("dimensions", value=3)])[0].successful  # read-only
    assert node.set_parameters([Parameter("publish_rate", value=20.0)])[0].successful
    assert node._publish_timer is not None


def test_publish_rate_mode_publishes_without_new_input(in_process, ros_node) -> None:
    node, harness = in_process
    harness.send(state_array(_stamped_now([state("a", (0, 0))], ros_node)))
    node.set_parameters([Parameter("publish_rate", value=20.0)])
    count = len(harness.predictions)
    # Counted, not timed: 5 more predictions with no input sent (a deadline only against a hang).
    assert spin_until(ros_node, lambda: len(harness.predictions) - count >= 5, 30.0, (node,)), (
        len(harness.predictions) - count
    )


@pytest.mark.parametrize(
    "field, value, reason",
    [("radius", -1.0, "radius is negative"), ("radius", math.nan, "radius is nan"),
     ("position.x", math.inf, "position.x is inf"), ("id", "", "empty id"),
     ("frame", "odom", "not the scene frame"), ("stamp", 0, "stamp is zero"),
     ("stamp", 10**6, "in the future"), ("duplicate", None, "more than once")],
)
def test_bad_input_rejected_rest_predicted(shared_in_process, field, value, reason) -> None:
    node, harness = shared_in_process
    ros_node = harness.client
    good = [state("a", (0, 0), (1, 0, 0)), state("b", (3, 0))]
    bad = state("bad", (50, 50))
    if field == "radius":
        bad.radius = value
    elif field == "position.x":
        bad.position.x = value
    elif field == "id":
        bad.id = value
    elif field == "frame":
        bad.header.frame_id = value
    states = _stamped_now(good + [bad], ros_node)
    if field == "stamp":
        bad.header.stamp.sec = value if value == 0 else bad.header.stamp.sec + value
        bad.header.stamp.nanosec = 0
    if field == "duplicate":
        states.append(state("bad", (60, 60), stamp_ns=_now_ns(ros_node)))
    rejected_before = node.counters.rejected
    harness.send(state_array(states), until=_answered(harness, good))
    out = harness.predictions[-1]
    assert contacts_of(out) == {("a", "b"): pytest.approx(2.0)}
    assert_no_nan(out)
    assert node.counters.rejected > rejected_before
    assert "bad" not in node.predictor


def test_empty_array_does_not_break_the_node(shared_in_process) -> None:
    node, harness = shared_in_process
    messages = node.counters.messages
    harness.send(CircleStateArray(), until=lambda: node.counters.messages > messages)
    states = _stamped_now([state("a", (0, 0), (1, 0, 0)), state("b", (3, 0))], harness.client)
    harness.send(state_array(states), until=_answered(harness, states))
    assert contacts_of(harness.predictions[-1]) == {("a", "b"): pytest.approx(2.0)}


@pytest.mark.stress
def test_huge_array_is_survived(in_process, ros_node) -> None:
    node, harness = in_process
    # The expiry timer would drop bodies if the 50,000-state message took longer than
    # stale_timeout to process on a busy machine; this test is about surviving it.
    node.set_parameters(
        [Parameter("marker_rate", value=0.0), Parameter("stale_timeout", value=120.0)]
    )
    huge = random_states(50_000, seed=2, spread=5_000.0)
    harness.send(state_array(_stamped_now(huge, ros_node)), timeout=120.0)
    out = harness.predictions[-1]
    assert node.predictor.bodies == 10_000  # max_bodies
    assert node.counters.rejected >= 40_000
    assert_no_nan(out)
    # Still alive and predicting: two known bodies (new ids would be refused, the scene is full).
    harness.send(
        state_array(
            _stamped_now([state("b000", (0, 0), (1, 0, 0)), state("b001", (3, 0))], ros_node)
        )
    )
    assert ("b000", "b001") in contacts_of(harness.predictions[-1])


def test_service_good_and_bad_requests(shared_in_process) -> None:
    node, harness = shared_in_process
    ros_node = harness.client
    client = ros_node.create_client(PredictCollisions, "predict_collisions")
    assert spin_until(ros_node, client.service_is_ready, 15.0, (node,))

    def call(request):
        future = client.call_async(request)
        assert spin_until(ros_node, future.done, 15.0, (node,))
        return future.result()

    states = random_states(30, seed=4)
    good = call(PredictCollisions.Request(circles=states, horizon=0.0))
    assert good.success and good.message == ""
    assert {
        (p.id_a, p.id_b): p.time_to_collision for p in good.predictions if p.status
    } == expected_contacts(states, 5.0)
    bad_states = [state("a", (0, 0)), state("b", (1, 1), r=math.nan)]
    bad = call(PredictCollisions.Request(circles=bad_states, horizon=1.0))
    assert not bad.success and bad.message.startswith("circles[1] (id 'b'): radius is nan")
    assert not call(PredictCollisions.Request(circles=states, horizon=-2.0)).success
    assert not call(PredictCollisions.Request(circles=states, horizon=math.inf)).success
    empty = call(PredictCollisions.Request(circles=[], horizon=1.0))
    assert not empty.success and empty.message == "the request has no circles"
    assert not call(PredictCollisions.Request(circles=states, horizon=1e7)).success  # cap: 3600 s


def test_service_takes_unstamped_circles_at_request_time(shared_in_process) -> None:
    """What `ros2 service call /predict_collisions ...` without stamps sends."""
    node, harness = shared_in_process
    ros_node = harness.client
    client = ros_node.create_client(PredictCollisions, "predict_collisions")
    assert spin_until(ros_node, client.service_is_ready, 15.0, (node,))
    circles = [state("a", (0, 0), (1, 0, 0)), state("b", (5, 0)), state("c", (0, 9), r=-1.0)]
    for c in circles:
        c.header.stamp.sec = c.header.stamp.nanosec = 0
    before = _now_ns(ros_node)
    future = client.call_async(PredictCollisions.Request(circles=circles[:2], horizon=10.0))
    assert spin_until(ros_node, future.done, 15.0, (node,))
    answer = future.result()
    assert answer.success, answer.message
    assert {(p.id_a, p.id_b): p.time_to_collision for p in answer.predictions} == {("a", "b"): 4.0}
    contact_ns = (
        answer.predictions[0].contact_time.sec * 10**9 + answer.predictions[0].contact_time.nanosec
    )
    assert before + 4_000_000_000 <= contact_ns <= _now_ns(ros_node) + 4_000_000_000
    future = client.call_async(PredictCollisions.Request(circles=circles, horizon=10.0))
    assert spin_until(ros_node, future.done, 15.0, (node,))
    assert future.result().message == "circles[2] (id 'c'): radius is negative (-1.0)"


def test_params_file_and_qos_override(tmp_path) -> None:
    """config/collision_node.yaml loads with --params-file; QoS overrides apply the ROS way."""
    from pathlib import Path

    from rclpy.context import Context
    import rclpy
    from rclpy.qos import ReliabilityPolicy as RP

    params = Path(__file__).resolve().parents[2] / "config" / "collision_node.yaml"
    overrides = tmp_path / "qos.yaml"
    overrides.write_text(
        "collision_node:\n  ros__parameters:\n    horizon: 7.5\n"
        "    qos_overrides:\n      /circle_states:\n        subscription:\n"
        "          reliability: reliable\n"
    )
    context = Context()
    rclpy.init(
        context=context,
        args=["collision_node", "--ros-args", "--params-file", str(params), "--params-file",
              str(overrides)],
    )
    try:
        node = CollisionNode(context=context)
        assert node.predictor.config.horizon == 7.5 and node.predictor.config.stale_timeout == 2.0
        (sub,) = [s for s in node.subscriptions if s.topic_name == "/circle_states"]
        assert sub.qos_profile.reliability == RP.RELIABLE
        node.destroy_node()
    finally:
        context.try_shutdown()


def test_best_effort_publishers_are_accepted(shared_in_process) -> None:
    node, harness = shared_in_process
    best_effort = harness.client.create_publisher(
        CircleStateArray,
        "circle_states",
        QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT),
    )
    try:
        states = _stamped_now([state("a", (0, 0), (1, 0, 0)), state("b", (3, 0))], harness.client)
        harness.send(state_array(states), until=_answered(harness, states), pub=best_effort)
        assert contacts_of(harness.predictions[-1]) == {("a", "b"): pytest.approx(2.0)}
    finally:
        harness.client.destroy_publisher(best_effort)


INTERRUPTED_START = """
import sys
from circle_collision_ros.pipeline import predictor


# Ctrl-C while numba's kernels load (minutes on a cold cache)
def interrupted(self, *args, **kwargs):
    raise KeyboardInterrupt


predictor.CollisionPredictor.warm_up = interrupted
from circle_collision_ros.node import collision_node
sys.exit(collision_node.main(["collision_node"]))
"""


def test_ctrl_c_during_start_up_exits_cleanly() -> None:
    """Ctrl-C before the node is built (its warm-up loads or compiles the kernels first):
    rclpy's shutdown destroys the half-built node, which has no markers or recorder yet.
    That used to end in an AttributeError traceback and exit code 1; now exit code 0."""
    run = subprocess.run(
        [sys.executable, "-c", INTERRUPTED_START], capture_output=True, text=True, timeout=120
    )
    assert run.returncode == 0, run.stdout + run.stderr
    assert "Traceback" not in run.stderr, run.stderr


def test_unusable_record_path_is_refused_before_the_kernels(ros_context, tmp_path,
                                                            monkeypatch) -> None:
    """A record_path that cannot be recorded to stops the node before it prepares (on a first
    start: compiles) its kernels, not minutes later; a usable one is opened before them and
    recorded to once the node has started."""
    from circle_collision_ros.pipeline import kernels

    prepared = []
    real_prepare = kernels.prepare
    monkeypatch.setattr(kernels, "prepare",
                        lambda predictor, **kw: prepared.append(1) or real_prepare(predictor, **kw))
    full = tmp_path / "full"
    full.mkdir()
    (full / "something").write_text("x")
    with pytest.raises(ValueError, match="record_path"):
        CollisionNode(context=ros_context,
                      parameter_overrides=[Parameter("record_path", value=str(full))])
    assert prepared == []
    bag = tmp_path / "bag"
    node = CollisionNode(context=ros_context,
                         parameter_overrides=[Parameter("record_path", value=str(bag)),
                                              Parameter("marker_rate", value=0.0)])
    try:
        assert prepared == [1] and (bag / "metadata.yaml").exists()
    finally:
        node.destroy_node()
    from circle_collision_ros.recording.bag_reader import open_bag

    topics = open_bag(bag).topics
    assert "/circle_states" in topics and "/collision_predictions" in topics
