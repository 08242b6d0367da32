"""collision_node as a stream component, over DDS on localhost (counts and contents, not timings).

Guarantees proved here (README, "Real-time behaviour"):
- coalescing: inputs that queued while the node was busy are all ingested and
  answered by ONE prediction for the newest state of every body; no stale
  frame is answered from behind a backlog, none is skipped; replay of the
  recording reproduces the same coalescing bit for bit;
- inputs overwritten in the node's queue are counted (writers' sequence numbers);
- expiry runs on its own timer: with publish_rate 0 and silent sources, the
  changed (empty) prediction is still published;
- markers: a body removed right after a drawing is deleted from the display,
  and marker ids are reused, bounded by the live scene;
- per-body streams (one CircleState publisher per body) and a 1,000-body array
  stream with markers on (stress run) end with exactly the live bodies (no ghosts),
  freshest states.

Waits are on conditions (the node's reader matched, a probe reader beside the node's
holding every sample sent, the marker thread idle), never on fixed pauses.
"""

from __future__ import annotations


import pytest
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from visualization_msgs.msg import MarkerArray

from circle_collision_msgs.msg import CircleState, CircleStateArray, CollisionPredictionArray
from circle_collision_ros.node.collision_node import CollisionNode
from circle_collision_ros.pipeline.predictor import PredictorConfig, predict_once
from circle_collision_ros.recording.bag_reader import RECORDED_TYPES, open_bag
from circle_collision_ros.recording.replay_engine import RecordedTypes, replay_offline
from tests.node.conftest import reader_matched, spin_until
from tests.node_helpers import contacts_of, random_states, state, state_array

RELIABLE = QoSProfile(depth=5000, reliability=ReliabilityPolicy.RELIABLE)


def scene_of(node):
    """The node's scene (len, `in`): the predictor once it holds the scene, else its registry."""
    return getattr(node.predictor, "registry", node.predictor)


def _now(node) -> int:
    return node.get_clock().now().nanoseconds


def _stamp(msg) -> int:
    return msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec


class Client:
    """Publishes states, collects predictions, markers and diagnostics."""

    def __init__(self, client, node) -> None:
        self.client, self.node = client, node
        self.predictions: list[CollisionPredictionArray] = []
        self.markers: list[MarkerArray] = []
        self.diagnostics: list[dict[str, str]] = []
        client.create_subscription(
            CollisionPredictionArray, "collision_predictions", self.predictions.append, 1000
        )
        client.create_subscription(MarkerArray, "collision_node/markers", self.markers.append,
                                   QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE))
        client.create_subscription(
            DiagnosticArray,
            "/diagnostics",
            lambda m: self.diagnostics.append({kv.key: kv.value for kv in m.status[0].values}),
            10,
        )

    def publisher(self, msg_type, topic: str):
        pub = self.client.create_publisher(msg_type, topic, RELIABLE)
        assert spin_until(self.client, lambda: pub.get_subscription_count() > 0, 60.0, (self.node,))
        # The publisher may see the match before the node's (best-effort) reader does.
        assert self.spin(60.0, reader_matched(self.node, topic))
        return pub

    def probe(self, msg_type, topic: str, depth: int) -> list:
        """A reader of `topic` beside the node's, in the same participant and with the same
        best-effort QoS: once it holds a sample, DDS has delivered that sample to the node's
        reader too (call before `publisher`, so both readers match the writer)."""
        received: list = []
        self.client.create_subscription(
            msg_type,
            topic,
            received.append,
            QoSProfile(depth=depth, reliability=ReliabilityPolicy.BEST_EFFORT),
            raw=True,
        )
        return received

    def spin(self, seconds: float, until=lambda: False) -> bool:
        return spin_until(self.client, until, seconds, (self.node,))

    def spin_client_only(self, until, timeout: float = 30.0) -> bool:
        """Let DDS deliver into the node's queue while the node does not run (a busy node),
        until `until()`."""
        return spin_until(self.client, until, timeout)


def frame(n: int, seed: int, stamp_ns: int, spread: float = 20.0) -> list[CircleState]:
    """n random bodies b000.., all stamped `stamp_ns` (a tracker frame)."""
    states = random_states(n, seed=seed, spread=spread)
    for s in states:
        s.header.stamp.sec, s.header.stamp.nanosec = divmod(stamp_ns, 10**9)
    return states


def displayed(arrays: list[MarkerArray]) -> dict[tuple[str, int], tuple]:
    """What RViz shows after applying `arrays` in order: (ns, id) -> position."""
    shown: dict[tuple[str, int], tuple] = {}
    for array in arrays:
        for m in array.markers:
            if m.action == m.DELETEALL:
                shown.clear()
            elif m.action == m.DELETE:
                shown.pop((m.ns, m.id), None)
            else:
                shown[(m.ns, m.id)] = (m.pose.position.x, m.pose.position.y)
    return shown


@pytest.fixture
def make_node(ros_context, ros_node):
    nodes = []

    def make(**params) -> tuple[CollisionNode, Client]:
        overrides = {"frame_id": "map", "marker_rate": 0.0, **params}
        node = CollisionNode(
            context=ros_context,
            parameter_overrides=[Parameter(k, value=v) for k, v in overrides.items()],
        )
        nodes.append(node)
        return node, Client(ros_node, node)

    yield make
    for node in nodes:
        node.destroy_node()


def test_backlog_is_coalesced_into_one_fresh_prediction(make_node, ros_node, tmp_path) -> None:
    """40 frames queue while the node is busy: all are ingested, one prediction answers the newest.

    Before: the node answered every queued frame oldest first (40 stale predictions).
    """
    node, client = make_node(record_path=str(tmp_path / "bag"), stale_timeout=60.0)
    probe = client.probe(CircleStateArray, "circle_states", depth=50)
    pub = client.publisher(CircleStateArray, "circle_states")
    start = _now(ros_node)
    frames = []
    for k in range(40):
        states = frame(30, seed=k, stamp_ns=start + k * 1_000_000)
        frames.append(states)
        pub.publish(state_array(states))
    # all 40 now wait in the node's input queue (the probe beside it has them)
    assert client.spin_client_only(lambda: len(probe) == 40), len(probe)
    before, published = len(client.predictions), node.counters.published
    assert client.spin(10.0, lambda: node.counters.messages >= 40)
    assert node.counters.published - published == 1  # one answer for the 40, published at once
    assert client.spin(10.0, lambda: len(client.predictions) > before)
    answers = client.predictions[before:]
    assert node.counters.messages == 40 and node.counters.accepted > 0
    assert len(answers) == 1, [_stamp(a) for a in answers]
    assert node.counters.coalesced == 39
    newest = max(_stamp(s) for s in frames[-1])
    assert _stamp(answers[0]) == newest
    # The newest state of every body: the same as a fresh prediction over the last frame's
    # 30 bodies plus nothing else (every frame carries the same ids b000..b029).
    ok, _, expected = predict_once(frames[-1], PredictorConfig(horizon=5.0))
    assert ok and contacts_of(answers[0]) == contacts_of(expected.to_message())

    node.destroy_node()  # closes the bag
    records = list(
        open_bag(tmp_path / "bag", message_types=RECORDED_TYPES | {RecordedTypes.CONFIG}).records()
    )
    report = replay_offline(records)
    assert report.ok, report.mismatches[:3]
    assert report.inputs == 40 and report.predictions >= 1 and report.coalesced >= 39


def test_queue_overrun_is_counted_as_missing(make_node, ros_node) -> None:
    """More single states than the queue holds arrive while the node is busy.

    The overwritten ones are counted.
    """
    node, client = make_node(single_state_topics=["body_states"], state_topics=["unused_states"])
    depth = node._drain_limit - 50  # the single-state queue (the array topic holds 50)
    probe = client.probe(CircleState, "body_states", depth=depth + 1000)
    pub = client.publisher(CircleState, "body_states")
    start = _now(ros_node)
    # A first sample starts the writer's count (earlier ones may predate the subscription).
    pub.publish(state("b000", (0.0, 0.0), stamp_ns=start))
    assert client.spin(10.0, lambda: node.counters.messages == 1)
    sent = 1 + depth + 300
    for k in range(1, sent):
        pub.publish(state(f"b{k % 100:03d}", (3.0 * (k % 100), 0.0), stamp_ns=start + k * 1000))
    # every state sent has reached the node's queue (the probe beside it has them all)
    assert client.spin_client_only(lambda: len(probe) == sent), (len(probe), sent)
    assert client.spin(10.0, lambda: node.counters.messages + node.input_loss.missing >= sent)
    assert node.counters.messages + node.input_loss.missing == sent
    assert node.input_loss.missing == 300 and node.counters.coalesced == depth - 1
    assert client.spin(
        10.0,
        lambda: (
            client.diagnostics
            and int(client.diagnostics[-1]["inputs_missing"]) == node.input_loss.missing
        ),
    )


def test_expiry_publishes_without_new_input(make_node, ros_node) -> None:
    """publish_rate 0 and silent sources: the empty prediction is published after stale_timeout.

    Before: nothing was published until new input arrived (the OVERLAPPING answer stayed the latest
    word).
    """
    node, client = make_node(stale_timeout=0.5)
    pub = client.publisher(CircleStateArray, "circle_states")
    now = _now(ros_node)
    pub.publish(state_array([state("a", (0, 0), stamp_ns=now), state("h", (0.5, 0), stamp_ns=now)]))
    assert client.spin(10.0, lambda: any(p.predictions for p in client.predictions))
    overlapping = client.predictions[-1]
    assert [(p.id_a, p.id_b, p.status) for p in overlapping.predictions] == [("a", "h", 2)]
    count = len(client.predictions)
    assert client.spin(15.0, lambda: len(client.predictions) > count), "expiry published nothing"
    assert client.predictions[-1].predictions == []
    assert len(scene_of(node)) == 0 and node.counters.expired == 2


def test_body_removed_right_after_a_drawing_is_deleted(make_node, ros_node) -> None:
    """marker_rate 1 Hz; b is removed 0.1 s after a drawing: the display must lose b.

    Before: the removal fell inside the 1/marker_rate gap, no later drawing came, b stayed forever.
    """
    node, client = make_node(marker_rate=1.0, stale_timeout=120.0)
    pub = client.publisher(CircleStateArray, "circle_states")
    now = _now(ros_node)
    pub.publish(state_array([state("a", (0, 0), stamp_ns=now), state("b", (5, 0), stamp_ns=now)]))
    assert client.spin(10.0, lambda: len(displayed(client.markers)) == 2)
    later = now + 1_000_000
    pub.publish(state_array([state("b", (5, 0), stamp_ns=later, remove=True)]))
    assert client.spin(10.0, lambda: len(scene_of(node)) == 1)
    # Nothing is left to draw (a drawing comes only with a new prediction, and none will):
    # what the display shows once the last drawing has arrived is what it keeps showing.
    assert node.markers.wait_idle(15.0)
    drawn = node.markers.drawn
    assert client.spin(15.0, lambda: set(displayed(client.markers)) == {("bodies", 0)}), displayed(
        client.markers
    )
    assert node.markers.wait_idle(0.0) and node.markers.drawn == drawn
    shown = displayed(client.markers)
    assert set(shown) == {("bodies", 0)} and shown[("bodies", 0)] == (0.0, 0.0)


def test_marker_ids_are_bounded_by_the_live_scene(make_node, ros_node) -> None:
    """A tracker issues 300 ids, 10 live at a time: marker ids stay below 10 (+ a few in flux).

    Before: the id tables kept every id ever seen (ids grew to 299).
    """
    node, client = make_node(marker_rate=1000.0, stale_timeout=30.0)
    pub = client.publisher(CircleStateArray, "circle_states")
    t = _now(ros_node)
    live: list[str] = []
    for wave in range(30):
        t += 1_000_000
        new = [f"track{wave * 10 + k}" for k in range(10)]
        states = [state(i, (3.0 * k, 10.0 * wave), stamp_ns=t) for k, i in enumerate(new)]
        states += [state(i, (0, 0), stamp_ns=t, remove=True) for i in live]
        live = new
        pub.publish(state_array(states))
        # each wave ingested and drawn on its own (none coalesced with the next)
        assert client.spin(10.0, lambda: node.counters.messages >= wave + 1), wave
        assert node.markers.wait_idle(10.0), wave
    assert node.counters.messages == 30
    assert all(i in scene_of(node) for i in live) and len(scene_of(node)) == 10
    last_wave = {(3.0 * k, 10.0 * 29) for k in range(10)}
    assert client.spin(15.0, lambda: set(displayed(client.markers).values()) == last_wave)
    ids = [m.id for a in client.markers for m in a.markers if m.ns == "bodies"]
    assert max(ids) < 20
    assert node.markers.wait_idle(5.0)
    assert len(node.markers.builder.body_ids) == 10
    assert sorted(displayed(client.markers)) == [("bodies", k) for k in range(10)]


def test_per_body_streams_end_with_the_live_bodies_and_their_newest_states(
    make_node, ros_node
) -> None:
    """120 publishers, one per body, on one single_state_topics topic; 20 bodies then leave."""
    node, client = make_node(
        single_state_topics=["body_states"], state_topics=["unused_states"], stale_timeout=30.0
    )
    bodies = 120
    pubs = [ros_node.create_publisher(CircleState, "body_states", RELIABLE) for _ in range(bodies)]
    assert client.spin(60.0, lambda: all(p.get_subscription_count() > 0 for p in pubs))
    assert client.spin(60.0, reader_matched(node, "body_states", publishers=bodies))
    rounds = 15
    last = {}
    sent = 0
    for r in range(rounds):
        now = _now(ros_node)
        for k, pub in enumerate(pubs):
            stamp = now + k
            s = state(f"b{k:03d}", (4.0 * k + 0.01 * r, 0.0), (0.0, 1.0, 0.0), stamp_ns=stamp)
            pub.publish(s)
            last[s.id] = s
            sent += 1
        client.spin(0.02)
    gone = [f"b{k:03d}" for k in range(0, bodies, 6)]
    for k in range(0, bodies, 6):
        pubs[k].publish(state(f"b{k:03d}", (0, 0), stamp_ns=_now(ros_node), remove=True))
        sent += 1
    assert client.spin(20.0, lambda: node.counters.messages + node.input_loss.missing >= sent)
    assert node.counters.messages == sent, (node.counters.messages, node.input_loss.missing)
    assert node.counters.accepted == bodies * rounds and node.counters.removed == len(gone)
    live = sorted(set(last) - set(gone))
    expected_ok, _, expected = predict_once([last[i] for i in live], PredictorConfig(horizon=5.0))
    want = (contacts_of(expected.to_message()), max(_stamp(last[i]) for i in live))
    # the node has answered everything; its last answer reaches the client
    client.spin(
        15.0,
        lambda: (
            bool(client.predictions)
            and (contacts_of(client.predictions[-1]), _stamp(client.predictions[-1])) == want
        ),
    )
    out = client.predictions[-1]
    assert expected_ok and contacts_of(out) == want[0]
    assert _stamp(out) == want[1]
    assert not {i for pair in contacts_of(out) for i in pair} & set(gone)  # no ghosts
    assert len(scene_of(node)) == len(live)


@pytest.mark.stress
def test_thousand_body_arrays_with_markers(make_node, ros_node) -> None:
    """1,000-body arrays at ~30 Hz with default markers, then half the bodies leave: no ghosts."""
    node, client = make_node(marker_rate=10.0, stale_timeout=30.0)
    pub = client.publisher(CircleStateArray, "circle_states")
    start = _now(ros_node)
    frames = 45
    states = []
    for k in range(frames):
        states = frame(1000, seed=100 + k, stamp_ns=start + k * 33_000_000, spread=300.0)
        pub.publish(state_array(states))
        client.spin(0.03)
    assert client.spin(30.0, lambda: node.counters.messages >= frames)
    newest = max(_stamp(s) for s in states)
    assert client.spin(10.0, lambda: _stamp(client.predictions[-1]) == newest)
    assert node.counters.messages == frames
    ok, _, expected = predict_once(states, PredictorConfig(horizon=5.0, max_bodies=1000))
    assert ok and contacts_of(client.predictions[-1]) == contacts_of(expected.to_message())
    assert client.spin(
        10.0, lambda: sum(1 for ns, _ in displayed(client.markers) if ns == "bodies") == 1000
    )

    t = max(_stamp(s) for s in states) + 1_000_000
    leaving = states[::2]
    pub.publish(state_array([state(s.id, (0, 0), stamp_ns=t, remove=True) for s in leaving]))
    assert client.spin(20.0, lambda: len(scene_of(node)) == 500)
    assert client.spin(
        30.0, lambda: sum(1 for ns, _ in displayed(client.markers) if ns == "bodies") == 500
    )
    client.spin(0.5)
    shown = displayed(client.markers)
    assert sum(1 for ns, _ in shown if ns == "bodies") == 500
    assert max(i for ns, i in shown if ns == "bodies") < 1000
    gone = {s.id for s in leaving}
    assert not {i for pair in contacts_of(client.predictions[-1]) for i in pair} & gone
    assert len(node.markers.builder.body_ids) == 500
