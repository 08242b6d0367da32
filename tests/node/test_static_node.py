"""Static geometry through the live node over real DDS on localhost.

Guarantees proved here:
- an OccupancyGrid published transient-local before the node starts reaches it, and a
  robot heading for a wall (CircleState and Odometry) gets the exact time, id_b 'map';
- a polygon obstacle on a topic (named by its namespace) is added, answered, and removed
  by an empty polygon; keep-out zones from the parameters are answered from the start;
- the service answers against the node's static world;
- the static world is drawn on ~/static_markers (transient local, one LINE_LIST per obstacle);
- bad maps (wrong frame, size not width*height, resolution <= 0, NaN origin) each get a
  warning naming the reason, never crash the node, and leave the world as it was;
- static inputs in 3-D are refused at start-up;
- managed: the static inputs are taken from configure to cleanup, so a polygon sent while
  the node is inactive is in the world at activation, the transient-local map is indexed once
  (not again at each activation), and ~/static_markers is published only while active.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from geometry_msgs.msg import Point32, PolygonStamped
from nav_msgs.msg import OccupancyGrid, Odometry
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import serialize_message

from circle_collision_msgs.msg import CircleStateArray, CollisionPredictionArray
from circle_collision_msgs.srv import PredictCollisions
from circle_collision_ros.core.static import GridFrame, Segments, StaticIndex, StaticWorld
from circle_collision_ros.core.static import time_to_static
from circle_collision_ros.node.collision_node import CollisionNode
from tests.node.conftest import reader_matched, spin_until
from tests.node_helpers import ns_time, state, state_array

RES = 0.0625  # dyadic: cell corners are exact, so the expected times are exact
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)


def _grid(now_ns: int, frame: str = "map", width: int = 160, height: int = 96,
          resolution: float = RES, origin=(-2.0, -3.0)) -> OccupancyGrid:
    """A room: walls on the border, free inside."""
    data = np.zeros((height, width), np.int8)
    data[0, :] = data[-1, :] = data[:, 0] = data[:, -1] = 100
    msg = OccupancyGrid()
    msg.header.stamp = ns_time(now_ns)
    msg.header.frame_id = frame
    msg.info.resolution = resolution
    msg.info.width, msg.info.height = width, height
    msg.info.origin.position.x, msg.info.origin.position.y = origin
    msg.info.origin.orientation.w = 1.0
    msg.data = data.ravel().tolist()
    return msg


def _polygon(now_ns: int, points, frame: str = "map") -> PolygonStamped:
    msg = PolygonStamped()
    msg.header.stamp = ns_time(now_ns)
    msg.header.frame_id = frame
    msg.polygon.points = [Point32(x=float(x), y=float(y), z=0.0) for x, y in points]
    return msg


def _client(ros_node) -> tuple[list, object, object]:
    """The test's side: the predictions it receives, and its state and crate publishers."""
    predictions: list[CollisionPredictionArray] = []
    ros_node.create_subscription(CollisionPredictionArray, "collision_predictions",
                                 predictions.append, 50)
    qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
    return (predictions, ros_node.create_publisher(CircleStateArray, "circle_states", qos),
            ros_node.create_publisher(PolygonStamped, "crate/polygon", qos))


def _rows(msg: CollisionPredictionArray) -> dict:
    return {(p.id_a, p.id_b): p for p in msg.predictions}


def test_map_before_start_robots_polygons_and_service(ros_context, ros_node) -> None:
    now = ros_node.get_clock().now().nanoseconds
    map_pub = ros_node.create_publisher(OccupancyGrid, "map", LATCHED)
    map_pub.publish(_grid(now))  # before the node exists: transient local must deliver it
    node = CollisionNode(
        context=ros_context,
        parameter_overrides=[
            Parameter("map_topic", value="map"),
            Parameter("polygon_topics", value=["crate/polygon"]),
            Parameter("static_polygons", value='{"keep_out": [[3, 1], [4, 1], [4, 2], [3, 2]]}'),
            Parameter("odometry_topics", value=["robot/odom"]),
            Parameter("odometry_radius", value=0.25),
            Parameter("frame_id", value="map"), Parameter("horizon", value=10.0),
            Parameter("stale_timeout", value=600.0)],
    )
    predictions, states, crate = _client(ros_node)
    odom = ros_node.create_publisher(Odometry, "robot/odom", QoSProfile(
        depth=10, reliability=ReliabilityPolicy.RELIABLE))
    try:
        # the map arrives and is indexed off the prediction path
        assert spin_until(ros_node, lambda: node.static.applied_version >= 2, 30.0, (node,))
        assert spin_until(ros_node, reader_matched(node, "circle_states"), 30.0, (node,))
        assert spin_until(ros_node, reader_matched(node, "robot/odom"), 30.0, (node,))
        # 'a' heads +x at 1 m/s toward the east wall: its inner face is at x = -2 + 159 * RES
        wall_x = -2.0 + 159 * RES
        states.publish(state_array([state("a", (0.0, 0.0), (1.0, 0.0), r=0.5, stamp_ns=now),
                                    state("b", (3.5, 0.0), (0.0, 1.0), r=0.25, stamp_ns=now)]))
        assert spin_until(ros_node, lambda: any(("a", "map") in _rows(m) for m in predictions),
                          20.0, (node,))
        last = _rows(predictions[-1])
        assert last[("a", "map")].time_to_collision == wall_x - 0.5
        assert last[("a", "map")].normal.x == 1.0
        # 'b' heads +y into the keep-out zone (y = 1) from the parameters
        assert last[("b", "keep_out")].time_to_collision == 0.75
        # a robot on odometry heading -y to the south wall (inner face y = -3 + RES)
        msg = Odometry()
        msg.header.stamp = ns_time(now)
        msg.header.frame_id, msg.child_frame_id = "map", "base_link"
        msg.pose.pose.position.x, msg.pose.pose.position.y = -1.0, 0.0
        msg.pose.pose.orientation.w = 1.0
        msg.twist.twist.linear.y = -2.0
        odom.publish(msg)
        assert spin_until(ros_node, lambda: ("robot", "map") in _rows(predictions[-1]), 20.0,
                          (node,))
        assert _rows(predictions[-1])[("robot", "map")].time_to_collision == (
            (0.0 - (-3.0 + RES)) - 0.25) / 2.0
        # a crate on a polygon topic, in a's way; then removed by an empty polygon
        assert spin_until(ros_node, lambda: crate.get_subscription_count() > 0, 20.0, (node,))
        crate.publish(_polygon(now, [(1.0, -0.5), (1.5, -0.5), (1.5, 0.5), (1.0, 0.5)]))
        assert spin_until(ros_node, lambda: ("a", "crate") in _rows(predictions[-1]), 20.0,
                          (node,))
        assert _rows(predictions[-1])[("a", "crate")].time_to_collision == 0.5
        crate.publish(_polygon(now, []))
        assert spin_until(ros_node, lambda: ("a", "crate") not in _rows(predictions[-1])
                          and ("a", "map") in _rows(predictions[-1]), 20.0, (node,))
        # the world is drawn, transient local: a display joining now gets it
        from visualization_msgs.msg import Marker, MarkerArray

        drawn: list = []
        ros_node.create_subscription(MarkerArray, "/collision_node/static_markers", drawn.append,
                                     LATCHED)
        assert spin_until(ros_node, lambda: bool(drawn), 20.0, (node,))
        lines = [m for m in drawn[-1].markers if m.type == Marker.LINE_LIST]
        assert drawn[-1].markers[0].action == Marker.DELETEALL
        assert sorted(m.text for m in lines) == ["keep_out", "map"]
        assert all(len(m.points) % 2 == 0 and m.points for m in lines)
        # the service answers against the same world
        client = ros_node.create_client(PredictCollisions, "predict_collisions")
        assert client.wait_for_service(timeout_sec=20.0)
        request = PredictCollisions.Request(
            circles=[state("s", (0.0, 0.0), (-1.0, 0.0), r=0.5, stamp_ns=now)])
        future = client.call_async(request)
        assert spin_until(ros_node, future.done, 20.0, (node,))
        response = future.result()
        assert response.success, response.message
        (row,) = [p for p in response.predictions if p.id_b == "map"]
        assert row.time_to_collision == 0.0 - (-2.0 + RES) - 0.5
    finally:
        node.destroy_node()


def test_bad_maps_are_rejected_with_a_reason(ros_context, ros_node) -> None:
    node = CollisionNode(context=ros_context, parameter_overrides=[
        Parameter("map_topic", value="map"), Parameter("frame_id", value="map")])
    warnings: list[str] = []
    node._warn = lambda key, text: warnings.append(text)  # noqa: SLF001 - observe only
    node.static._warn = node._warn
    try:
        now = ros_node.get_clock().now().nanoseconds
        topic = node.resolve_topic_name("map")
        good = _grid(now)
        cases = {
            "frame": _grid(now, frame="odom"),
            "resolution": _grid(now, resolution=-1.0),
            "origin": _grid(now, origin=(math.nan, 0.0)),
        }
        bad_size = _grid(now)
        bad_size.info.width = 10  # data has 160 * 96 values
        cases["width*height"] = bad_size
        for expected, msg in cases.items():
            before = node.static.obstacles.version
            assert not node.static.on_map_bytes(topic, serialize_message(msg))
            assert node.static.obstacles.version == before
            assert expected in warnings[-1], (expected, warnings[-1])
        assert not node.static.on_map_bytes(topic, b"\x00\x01\x00\x00garbage")
        assert node.static.on_map_bytes(topic, serialize_message(good))
        assert node.static.rejected == len(cases) + 1
    finally:
        node.destroy_node()


def test_static_inputs_in_3d_are_refused_at_start(ros_context) -> None:
    with pytest.raises(ValueError, match="dimensions = 2"):
        CollisionNode(context=ros_context, parameter_overrides=[
            Parameter("map_topic", value="map"), Parameter("dimensions", value=3)])


def test_the_static_rows_equal_the_core_answer() -> None:
    """The node's rows come from core.static: same time as a direct query (no ROS)."""
    world = StaticWorld.build([Segments("w", np.array([[1.0, -1.0]]), np.array([[1.0, 1.0]]))])
    c = time_to_static([[0.0, 0.0]], [[1.0, 0.0]], [[0.0, 0.0]], 0.25, StaticIndex.build(world),
                       5.0)
    assert c.time[0] == 0.75
    assert GridFrame(RES).resolution == RES


def test_static_world_is_recorded_and_replays_bit_for_bit(ros_context, ros_node,
                                                           tmp_path) -> None:
    """A map published before recording starts, a polygon added and removed, all recorded:
    replay applies each world version where the node did and matches every prediction; the
    map is readable by the independent mcap_ros2 decoder; a tampered version is reported."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    from circle_collision_ros.recording.replay_engine import load_bag, replay_offline

    now = ros_node.get_clock().now().nanoseconds
    map_pub = ros_node.create_publisher(OccupancyGrid, "map", LATCHED)
    map_pub.publish(_grid(now))
    bag = tmp_path / "bag"
    node = CollisionNode(context=ros_context, parameter_overrides=[
        Parameter("map_topic", value="map"), Parameter("polygon_topics", value=["crate/polygon"]),
        Parameter("static_polygons", value='{"keep_out": [[3, 1], [4, 1], [4, 2], [3, 2]]}'),
        Parameter("frame_id", value="map"), Parameter("stale_timeout", value=600.0),
        Parameter("horizon", value=10.0), Parameter("record_path", value=str(bag))])
    predictions, states, crate = _client(ros_node)
    try:
        assert spin_until(ros_node, lambda: node.static.applied_version >= 2, 30.0, (node,))
        assert spin_until(ros_node, reader_matched(node, "circle_states"), 30.0, (node,))
        states.publish(state_array([state("a", (0.0, 0.0), (1.0, 0.0), r=0.5, stamp_ns=now),
                                    state("b", (3.5, 0.0), (0.0, 1.0), r=0.25, stamp_ns=now)]))
        assert spin_until(ros_node, lambda: any(("a", "map") in _rows(m) for m in predictions),
                          20.0, (node,))
        assert spin_until(ros_node, lambda: crate.get_subscription_count() > 0, 20.0, (node,))
        crate.publish(_polygon(now, [(1.0, -0.5), (1.5, -0.5), (1.5, 0.5), (1.0, 0.5)]))
        assert spin_until(ros_node, lambda: ("a", "crate") in _rows(predictions[-1]), 20.0,
                          (node,))
        crate.publish(_polygon(now, []))
        assert spin_until(ros_node, lambda: ("a", "crate") not in _rows(predictions[-1]), 20.0,
                          (node,))
        states.publish(state_array([state("a", (0.0, 0.25), (1.0, 0.0), r=0.5,
                                          stamp_ns=now + 10**8)]))
        assert spin_until(ros_node, lambda: _rows(predictions[-1])[("a", "map")]
                          .time_to_collision < 9.0 and len(predictions) >= 4, 20.0, (node,))
    finally:
        node.destroy_node()
    _, records = load_bag(bag)
    report = replay_offline(records)
    assert report.ok, report.mismatches
    assert report.predictions >= 4
    with open(next(bag.glob("*.mcap")), "rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        maps = [m for _, channel, _, m in reader.iter_decoded_messages()
                if channel.topic == "/map"]
    assert len(maps) == 1 and maps[0].info.width == 160 and maps[0].info.resolution == RES
    # a recording that names a version it never received is reported, not trusted
    tampered = [r._replace(data=serialize_message(type(_string())(data='{"version": 99}')))
                if r.topic.endswith("/static_applied") else r for r in records]
    assert any("never received" in m for m in replay_offline(tampered).mismatches)


def test_static_world_stays_current_while_inactive(ros_context, ros_node) -> None:
    from visualization_msgs.msg import MarkerArray

    from tests.node.test_lifecycle import Lifecycle

    now = ros_node.get_clock().now().nanoseconds
    map_pub = ros_node.create_publisher(OccupancyGrid, "map", LATCHED)
    map_pub.publish(_grid(now))
    node = CollisionNode(context=ros_context, parameter_overrides=[
        Parameter("autostart", value=False), Parameter("map_topic", value="map"),
        Parameter("polygon_topics", value=["crate/polygon"]), Parameter("frame_id", value="map"),
        Parameter("stale_timeout", value=600.0), Parameter("horizon", value=10.0)])
    lifecycle = Lifecycle(ros_node, node)
    drawn: list = []
    ros_node.create_subscription(MarkerArray, "/collision_node/static_markers", drawn.append,
                                 LATCHED)
    predictions, states, crate = _client(ros_node)
    try:
        assert lifecycle.set("configure")
        # inactive: the map arrives and is indexed, a polygon is taken; nothing is drawn
        assert spin_until(ros_node, lambda: node.static.applied_version >= 1, 30.0, (node,))
        assert spin_until(ros_node, lambda: crate.get_subscription_count() > 0, 20.0, (node,))
        crate.publish(_polygon(now, [(1.0, -0.5), (1.5, -0.5), (1.5, 0.5), (1.0, 0.5)]))
        assert spin_until(ros_node, lambda: node.static.applied_version >= 2, 20.0, (node,))
        spin_until(ros_node, lambda: False, 0.5, (node,))
        assert not drawn and not predictions
        # active: the world held (map and crate) is drawn and answered
        assert lifecycle.set("activate")
        assert spin_until(ros_node, lambda: bool(drawn), 20.0, (node,))
        assert sorted(m.text for m in drawn[-1].markers[1:]) == ["crate", "map"]
        assert spin_until(ros_node, reader_matched(node, "circle_states"), 30.0, (node,))
        states.publish(state_array([state("a", (0.0, 0.0), (1.0, 0.0), r=0.5, stamp_ns=now)]))
        assert spin_until(ros_node, lambda: predictions and ("a", "crate") in _rows(
            predictions[-1]), 20.0, (node,))
        assert _rows(predictions[-1])[("a", "crate")].time_to_collision == 0.5
        # deactivate and activate again: the map is not delivered and indexed again
        version = node.static.applied_version
        assert lifecycle.set("deactivate") and lifecycle.set("activate")
        spin_until(ros_node, lambda: False, 1.0, (node,))
        assert node.static.applied_version == version
    finally:
        node.destroy_node()


def _string():
    from std_msgs.msg import String

    return String()
