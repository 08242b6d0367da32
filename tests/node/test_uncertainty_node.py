"""Uncertain states through a live collision_node over real DDS on localhost.

Guarantees proved here:
- every bad-covariance class (wrong length, NaN, not symmetric, not PSD) is rejected per
  body, on the topic (a /rosout warning naming topic, id and the reason) and through the
  service (success false, the message names circles[k], id and reason); the other bodies
  are still predicted and the node keeps answering;
- two bodies whose mean paths miss by 10 cm with 0.3 m position sigma are reported with a
  probability strictly between 0 and 1 (NO_CONTACT: the mean paths miss), with its bound
  and a finite plausible time; through the service the same pair gets the same fields;
- an all-zero covariance is an exact state: a node fed zero covariances publishes bytes
  identical to a node fed none (same stamps), probability 1.0 / bound 0 / plausible = ttc;
- Odometry covariance over DDS: the stored covariance is the pose position block and the
  twist linear block rotated by the orientation (R S R^T), cross terms zero;
- a run with covariance is recorded (the new schema: mcap-ros2-support and rosbags read the
  covariance and probability fields back from the file alone) and replays bit-identically;
- a 1,000-body tracker frame with covariance on every body, more uncertain pairs than the
  budget: no row is a placeholder (1.0 +- 1.0), and every row's interval meets the answer of
  a node that evaluates every pair fully (|p - q| <= both bounds); collision_probabilities
  then carries exactly that node's bytes (every pair fully evaluated, >= 99 % of the bounds
  <= 0.01);
- a recorded run with deferred pairs records its completions, and replay recomputes each
  one bit for bit (an altered completion is reported).
"""
from __future__ import annotations

import math
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from nav_msgs.msg import Odometry
from rcl_interfaces.msg import Log
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy

from circle_collision_msgs.msg import CircleStateArray, CollisionPredictionArray
from circle_collision_msgs.srv import PredictCollisions
from circle_collision_ros.node.collision_node import CollisionNode
from circle_collision_ros.recording.bag_reader import open_bag
from circle_collision_ros.recording.replay_engine import RecordedTypes, load_bag, replay_offline
from tests.node.conftest import reader_matched, spin_until
from tests.node_helpers import assert_no_nan, contacts_of, random_states, state, state_array

SIGMA = 0.3  # m, position standard deviation of the near-miss bodies
RELIABLE = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)


def _covariance(position_sigma: float, velocity_sigma: float = 0.0) -> list[float]:
    return np.diag([position_sigma ** 2] * 3 + [velocity_sigma ** 2] * 3).ravel().tolist()


BAD_COVARIANCES = [
    ("wrong length", [0.01] * 7, "covariance has 7 values"),
    ("nan", [math.nan if k == 7 else (0.01 if k % 7 == 0 else 0.0) for k in range(36)],
     "not finite"),
    ("not symmetric", (np.eye(6) * 0.01 + np.triu(np.full((6, 6), 0.001), 1)).ravel().tolist(),
     "not symmetric"),
    ("not PSD", np.diag([0.01, -0.04, 0.0, 0.01, 0.01, 0.0]).ravel().tolist(),
     "not positive semi-definite"),
]


def _now_ns(node) -> int:
    return node.get_clock().now().nanoseconds


def _stamped(states, ns: int):
    for s in states:
        s.header.stamp.sec, s.header.stamp.nanosec = divmod(ns, 10**9)
    return states


class Client:
    """Publisher, prediction collectors (messages and raw bytes) and a /rosout listener."""

    def __init__(self, ros_node, node, topic: str = "circle_states",
                 predictions: str = "collision_predictions") -> None:
        self.ros_node, self.node = ros_node, node
        self.predictions: list[CollisionPredictionArray] = []
        self.raw: list[bytes] = []
        self.logs: list[str] = []
        ros_node.create_subscription(
            CollisionPredictionArray, predictions, self.predictions.append, 50
        )
        ros_node.create_subscription(
            CollisionPredictionArray, predictions, self.raw.append, 50, raw=True
        )
        ros_node.create_subscription(Log, "/rosout", lambda m: self.logs.append(m.msg), 100)
        self.pub = ros_node.create_publisher(CircleStateArray, topic, RELIABLE)
        assert spin_until(ros_node, lambda: self.pub.get_subscription_count() > 0, 60.0, self.extra)
        # best-effort subscription: the reader side must have matched too
        (reader,) = [
            n
            for n in self.extra
            if any(sub.topic_name == n.resolve_topic_name(topic) for sub in n.subscriptions)
        ]
        assert spin_until(ros_node, reader_matched(reader, topic), 60.0, self.extra)

    @property
    def extra(self):
        return tuple(self.node) if isinstance(self.node, (list, tuple)) else (self.node,)

    def send(self, msg, until=None, timeout: float = 20.0) -> None:
        """Publish (re-sent each second: a best-effort first sample may be lost; the same stamp
        is ignored by the node if it did arrive) until a new prediction arrives."""
        count, raw = len(self.predictions), len(self.raw)
        done = until or (lambda: len(self.predictions) > count and len(self.raw) > raw)
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            self.pub.publish(msg)
            if spin_until(self.ros_node, done, min(1.0, deadline - time.monotonic()), self.extra):
                return
        raise AssertionError("no prediction arrived")

    def call(self, request):
        client = self.ros_node.create_client(PredictCollisions, "predict_collisions")
        assert spin_until(self.ros_node, client.service_is_ready, 15.0, self.extra)
        future = client.call_async(request)
        assert spin_until(self.ros_node, future.done, 30.0, self.extra)
        return future.result()


@pytest.fixture
def collision_node(ros_context):
    node = CollisionNode(
        context=ros_context,
        parameter_overrides=[Parameter("horizon", value=5.0), Parameter("frame_id", value="map"),
                             Parameter("marker_rate", value=20.0),
                             Parameter("stale_timeout", value=60.0)],
    )
    yield node
    node.destroy_node()


@pytest.mark.parametrize(
    "name, values, reason", BAD_COVARIANCES, ids=[c[0] for c in BAD_COVARIANCES]
)
def test_bad_covariance_rejected_on_topic_and_service(
    collision_node, ros_node, name, values, reason
) -> None:
    client = Client(ros_node, collision_node)
    good = [state("a", (0, 0), (1, 0, 0)), state("b", (3, 0))]
    bad = state("bad", (50, 50))
    bad.covariance = values
    rejected = collision_node.counters.rejected
    client.send(state_array(_stamped(good + [bad], _now_ns(ros_node))))
    out = client.predictions[-1]
    assert contacts_of(out) == {("a", "b"): pytest.approx(2.0)}
    assert_no_nan(out)
    assert collision_node.counters.rejected > rejected and "bad" not in collision_node.predictor
    assert spin_until(
        ros_node,
        lambda: any("/circle_states" in m and "id 'bad'" in m and reason in m for m in client.logs),
        10.0,
        client.extra,
    ), client.logs
    answer = client.call(PredictCollisions.Request(circles=good + [bad], horizon=0.0))
    assert not answer.success
    assert (
        answer.message.startswith("circles[2] (id 'bad'): covariance") and reason in answer.message
    )
    # alive: the node still predicts a newer frame and the service still answers
    client.send(state_array(_stamped(good, _now_ns(ros_node))))
    assert contacts_of(client.predictions[-1]) == {("a", "b"): pytest.approx(2.0)}
    assert client.call(PredictCollisions.Request(circles=good, horizon=0.0)).success


def _near_miss(ns: int):
    """a moves along +x; b sits 1.1 m above a's path: radii 0.5, the mean paths miss by 0.1 m."""
    a = state("a", (0, 0), (1, 0, 0), stamp_ns=ns)
    b = state("b", (2, 1.1), stamp_ns=ns)
    a.covariance = b.covariance = _covariance(SIGMA)
    return [a, b]


def test_near_miss_with_large_covariance_is_reported_with_its_probability(
    collision_node, ros_node
) -> None:
    client = Client(ros_node, collision_node)
    states = _near_miss(_now_ns(ros_node))
    client.send(
        state_array(states), until=lambda: any(len(p.predictions) for p in client.predictions)
    )
    out = next(p for p in reversed(client.predictions) if p.predictions)
    (row,) = out.predictions
    assert (row.id_a, row.id_b, row.status) == ("a", "b", row.NO_CONTACT)
    assert row.time_to_collision == math.inf
    assert 0.0 < row.collision_probability < 1.0
    assert 0.0 <= row.collision_probability_bound < 0.01
    assert 0.0 <= row.plausible_time_to_collision <= 5.0
    answer = client.call(PredictCollisions.Request(circles=states, horizon=0.0))
    assert answer.success, answer.message
    (same,) = answer.predictions
    assert (same.collision_probability, same.collision_probability_bound,
            same.plausible_time_to_collision) == (
        row.collision_probability,
        row.collision_probability_bound,
        row.plausible_time_to_collision,
    )
    # Exact states of the same scene: nothing within the horizon, nothing reported.
    exact = _near_miss(_now_ns(ros_node))
    for s in exact:
        s.covariance = []
    assert client.call(PredictCollisions.Request(circles=exact, horizon=0.0)).predictions == []


def _nodes(ros_context, namespaces, **parameters) -> list[CollisionNode]:
    """One node per namespace, markers off; ``parameters``: name -> namespace -> value."""
    return [
        CollisionNode(
            context=ros_context,
            namespace=ns,
            parameter_overrides=[Parameter("horizon", value=5.0),
                                 Parameter("frame_id", value="map"),
                                 Parameter("marker_rate", value=0.0),
                                 Parameter("stale_timeout", value=60.0)]
            + [Parameter(name, value=values[ns]) for name, values in parameters.items()],
        )
        for ns in namespaces
    ]


def test_zero_covariance_publishes_the_bytes_of_no_covariance(ros_context, ros_node) -> None:
    nodes = _nodes(ros_context, ("/exact", "/zero"))
    try:
        exact = Client(ros_node, nodes, "/exact/circle_states", "/exact/collision_predictions")
        zero = Client(ros_node, nodes, "/zero/circle_states", "/zero/collision_predictions")
        ns = _now_ns(ros_node)
        states = [state("a", (0, 0), (1, 0, 0), stamp_ns=ns), state("b", (3, 0.5), stamp_ns=ns),
                  state("c", (9, 9), (-1, -1, 0), stamp_ns=ns - 7),
                  state("d", (2.0, 0), stamp_ns=ns)]
        exact.send(state_array(states))
        for s in states:
            s.covariance = [0.0] * 36
        zero.send(state_array(states))
        assert exact.raw[-1] == zero.raw[-1]
        rows = exact.predictions[-1].predictions
        assert rows and all(
            (p.collision_probability, p.collision_probability_bound, p.plausible_time_to_collision)
            == (1.0, 0.0, p.time_to_collision)
            for p in rows
        )
    finally:
        for node in nodes:
            node.destroy_node()


def test_odometry_covariance_is_rotated_into_the_header_frame(ros_context, ros_node) -> None:
    node = CollisionNode(
        context=ros_context,
        parameter_overrides=[Parameter("odometry_topics", value=["robot_1/odom"]),
                             Parameter("frame_id", value="map"),
                             Parameter("stale_timeout", value=60.0),
                             Parameter("dimensions", value=3)],
    )
    try:
        pub = ros_node.create_publisher(Odometry, "robot_1/odom", RELIABLE)
        assert spin_until(ros_node, lambda: pub.get_subscription_count() > 0, 60.0, (node,))
        yaw = math.pi / 2  # the robot faces +y: its body x (forward) is the map's y
        msg = Odometry()
        msg.header.frame_id, msg.child_frame_id = "map", "base_link"
        msg.pose.pose.orientation.z, msg.pose.pose.orientation.w = (
            math.sin(yaw / 2),
            math.cos(yaw / 2),
        )
        msg.twist.twist.linear.x = 1.0
        pose = np.diag([0.04, 0.09, 0.01, 1.0, 1.0, 1.0])
        twist = np.diag([0.25, 0.01, 0.0, 2.0, 2.0, 2.0])  # forward speed the most uncertain
        msg.pose.covariance, msg.twist.covariance = pose.ravel().tolist(), twist.ravel().tolist()
        deadline = time.monotonic() + 20.0
        while "robot_1" not in node.predictor and time.monotonic() < deadline:
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(_now_ns(ros_node), 10**9)
            pub.publish(msg)
            spin_until(ros_node, lambda: "robot_1" in node.predictor, 1.0, (node,))
        assert "robot_1" in node.predictor
        scene = node.predictor._scene
        stored = scene._C[scene._slot["robot_1"]]
        assert np.array_equal(stored[:3, :3], pose[:3, :3])
        assert not stored[:3, 3:].any() and not stored[3:, :3].any()
        assert stored[3:, 3:] == pytest.approx(np.diag([0.01, 0.25, 0.0]), abs=1e-16)
    finally:
        node.destroy_node()


def _recording_node(ros_context, bag: Path, **parameters) -> CollisionNode:
    """A node recording to `bag`, markers off, with `parameters` on top of the defaults here."""
    return CollisionNode(
        context=ros_context,
        parameter_overrides=[Parameter("horizon", value=5.0), Parameter("frame_id", value="map"),
                             Parameter("marker_rate", value=0.0),
                             Parameter("stale_timeout", value=60.0),
                             Parameter("record_path", value=str(bag))]
        + [Parameter(name, value=value) for name, value in parameters.items()],
    )


def test_covariance_run_is_recorded_read_independently_and_replayed(
    ros_context, ros_node, tmp_path: Path
) -> None:
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    from rosbags.highlevel import AnyReader

    bag = tmp_path / "bag"
    node = _recording_node(ros_context, bag)
    try:
        client = Client(ros_node, node)
        base = _now_ns(ros_node)
        for k in range(5):
            states = _near_miss(base + k * 50_000_000)
            # exact, hits a
            states.append(state("c", (0, -3), (1, 1, 0), stamp_ns=base + k * 50_000_000))
            states[0].covariance = _covariance(SIGMA, 0.05 * k)
            client.send(state_array(states))
        assert any(
            p.collision_probability < 1.0 for out in client.predictions for p in out.predictions
        )
    finally:
        node.destroy_node()
    contents = open_bag(bag)
    report = replay_offline(
        open_bag(
            bag,
            message_types={RecordedTypes.STATE_ARRAY, RecordedTypes.PREDICTIONS,
                           RecordedTypes.CONFIG},
        ).records()
    )
    assert report.ok and report.predictions >= 5, report.mismatches[:3]
    assert contents.topics["/circle_states"].message_count >= 5
    with open(next(bag.glob("*.mcap")), "rb") as stream:
        reader = make_reader(stream, validate_crcs=True, decoder_factories=[DecoderFactory()])
        by_topic: dict[str, list] = {}
        for _, channel, _, msg in reader.iter_decoded_messages():
            by_topic.setdefault(channel.topic, []).append(msg)
    last = by_topic["/circle_states"][-1]
    assert (
        list(last.circles[0].covariance) == _covariance(SIGMA, 0.2)
        and list(last.circles[2].covariance) == []
    )
    rows = [p for out in by_topic["/collision_predictions"] for p in out.predictions]
    assert any(0.0 < p.collision_probability < 1.0 for p in rows)
    with AnyReader([bag]) as reader:
        conns = [c for c in reader.connections if c.topic == "/collision_predictions"]
        decoded = [
            reader.deserialize(raw, conn.msgtype)
            for conn, _, raw in reader.messages(connections=conns)
        ]
    assert [
        [
            (p.id_a, p.id_b, p.collision_probability, p.plausible_time_to_collision)
            for p in m.predictions
        ]
        for m in decoded
    ] == [
        [
            (p.id_a, p.id_b, p.collision_probability, p.plausible_time_to_collision)
            for p in m.predictions
        ]
        for m in by_topic["/collision_predictions"]
    ]


def test_use_covariance_false_predicts_mean_states_and_says_so(ros_context, ros_node) -> None:
    """use_covariance:=false: covariances are dropped at intake, so the node publishes the bytes
    a node fed the same states without covariance publishes (same stamps); /rosout names the
    topic, the counters count the dropped covariances, the service says so in its message, and
    the parameter cannot be changed at run time."""
    nodes = _nodes(ros_context, ("/ignoring", "/plain"),
                   use_covariance={"/ignoring": False, "/plain": True},
                   max_bodies={"/ignoring": 40, "/plain": 40})
    try:
        ignoring, plain_node = nodes
        assert ignoring.predictor.config.use_covariance is False
        assert not ignoring.set_parameters([Parameter("use_covariance", value=True)])[0].successful
        with_cov = Client(ros_node, nodes, "/ignoring/circle_states",
                          "/ignoring/collision_predictions")
        without = Client(ros_node, nodes, "/plain/circle_states", "/plain/collision_predictions")
        ns = _now_ns(ros_node)
        states = _near_miss(ns) + [state("c", (0, 0.9), stamp_ns=ns)]  # c touches a at once
        states[2].covariance = _covariance(0.1, 0.1)
        with_cov.send(state_array(states))
        assert ignoring.counters.covariance_ignored == 3
        rows = with_cov.predictions[-1].predictions
        assert [(p.id_a, p.id_b) for p in rows] == [("a", "c")]  # the near miss is not listed
        assert all(p.collision_probability_bound == 0.0 for p in rows)
        plain = [state(s.id, (s.position.x, s.position.y), (s.velocity.x, 0, 0), stamp_ns=ns)
                 for s in states]
        without.send(state_array(plain))
        assert with_cov.raw[-1] == without.raw[-1]
        assert spin_until(ros_node, lambda: any(
            "/ignoring/circle_states" in m and "covariance of 3 state(s) ignored" in m
            for m in with_cov.logs), 10.0, with_cov.extra), with_cov.logs
        client = ros_node.create_client(PredictCollisions, "/ignoring/predict_collisions")
        assert spin_until(ros_node, client.service_is_ready, 15.0, with_cov.extra)
        future = client.call_async(PredictCollisions.Request(circles=states, horizon=0.0))
        assert spin_until(ros_node, future.done, 30.0, with_cov.extra)
        answer = future.result()
        assert answer.success and "covariance of 3 circle(s) ignored" in answer.message
        assert [(p.id_a, p.id_b) for p in answer.predictions] == [("a", "c")]
    finally:
        for node in nodes:
            node.destroy_node()


def test_tracker_frame_beyond_the_budget_has_no_placeholder_rows(ros_context, ros_node) -> None:
    """1,000 bodies, position sigma 0.3 m and velocity sigma 0.2 m/s each (a tracker frame),
    through a node with the default budget and one that evaluates every pair (budget 0)."""
    nodes = _nodes(ros_context, ("/budget", "/all"),
                   uncertain_pair_budget={"/budget": 4, "/all": 0})
    try:
        clients = [Client(ros_node, nodes, f"{ns}/circle_states", f"{ns}/collision_predictions")
                   for ns in ("/budget", "/all")]
        completions: list[bytes] = []
        ros_node.create_subscription(CollisionPredictionArray, "/budget/collision_probabilities",
                                     completions.append, RELIABLE, raw=True)
        states = random_states(1000, seed=34, stamp_ns=_now_ns(ros_node), spread=60.0)
        for s in states:
            s.covariance = _covariance(0.3, 0.2)
        for client in clients:
            client.send(state_array(states), timeout=60.0)
        budget, everything = (client.predictions[-1].predictions for client in clients)
        # the completion of the budget node's prediction: the bytes of the node that evaluates
        # every pair (same stamp, same rows, same bits), every bound within 0.01
        assert spin_until(ros_node, lambda: completions, 30.0, clients[0].extra)
        assert completions[-1] == clients[1].raw[-1]
        assert nodes[0].probabilities.completed >= 1
        bounds = np.array([r.collision_probability_bound for r in everything])
        assert bounds.size > 1000 and np.mean(bounds <= 0.01) >= 0.99
        assert nodes[0].predictor.stats.uncertain_deferred > 20
        assert nodes[1].predictor.stats.uncertain_deferred == 0
        full = {(r.id_a, r.id_b): r for r in everything}
        compared = 0
        for row in budget:
            p, b = row.collision_probability, row.collision_probability_bound
            assert not (p == 1.0 and b == 1.0), (row.id_a, row.id_b)
            other = full.get((row.id_a, row.id_b))
            if other is not None:
                q, e = other.collision_probability, other.collision_probability_bound
                assert abs(p - q) <= b + e + 1e-12, (row.id_a, row.id_b, p, b, q, e)
                compared += 1
        assert compared > 20
    finally:
        for node in nodes:
            node.destroy_node()


def test_completions_are_recorded_and_replayed(ros_context, ros_node, tmp_path: Path) -> None:
    """Budget 1 with dozens of uncertain pairs: each recorded collision_probabilities message
    is recomputed by replay from the prediction with its log time, bit for bit."""
    bag = tmp_path / "bag"
    node = _recording_node(ros_context, bag, uncertain_pair_budget=1)
    completions: list[bytes] = []
    try:
        client = Client(ros_node, node)
        ros_node.create_subscription(CollisionPredictionArray, "collision_probabilities",
                                     completions.append, RELIABLE, raw=True)
        base = _now_ns(ros_node)
        for k in range(4):
            states = random_states(40, seed=k, stamp_ns=base + k * 40_000_000, spread=6.0)
            for s in states:
                s.covariance = _covariance(0.3, 0.2)
            client.send(state_array(states))
            assert spin_until(ros_node, lambda: len(completions) > k, 20.0, client.extra)
        assert node.probabilities.completed >= 1
    finally:
        node.destroy_node()
    _, records = load_bag(bag)
    recorded = [r for r in records if r.topic == "/collision_probabilities"]
    assert [r.data for r in recorded] == completions[:len(recorded)] and len(recorded) >= 4
    report = replay_offline(records)
    assert report.ok and report.completions == len(recorded), report.mismatches[:3]
    run = subprocess.run([sys.executable, "-m", "circle_collision_ros.recording.replay",
                          str(bag)], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    assert f", {len(recorded)} probability completions" in run.stdout, run.stdout
    # a completion that is not the prediction's: the main topic's bytes in its place
    main = {r.log_time_ns: r.data for r in records if r.topic == "/collision_predictions"}
    changed = [r._replace(data=main[r.log_time_ns]) if r is recorded[-1] else r for r in records]
    assert main[recorded[-1].log_time_ns] != recorded[-1].data
    bad = replay_offline(changed)
    assert not bad.ok and any("probabilities #" in m for m in bad.mismatches), bad.mismatches
