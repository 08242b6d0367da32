"""nav_msgs/Odometry input over real DDS: two robots, recording, replay.

Guarantees proved here:
- two robots publishing Odometry on `<robot>/odom` on a collision course, one
  rotated 90 degrees with its velocity in its body frame, are predicted to touch
  at the time the core gives for the world-frame velocities (body ids = topic
  namespaces, radii from odometry_radii);
- bad orientations (zero, NaN, norm 2) and a foreign header.frame_id are
  rejected with a warning and never change the scene; the node keeps predicting;
- the run is recorded (Odometry schema readable by the independent mcap_ros2
  decoder) and replays bit-identically through the same intake path.
"""
from __future__ import annotations

import math
from pathlib import Path

import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from nav_msgs.msg import Odometry
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy

from circle_collision_msgs.msg import CollisionPredictionArray
from circle_collision_ros.core import time_to_collision
from circle_collision_ros.node.collision_node import CollisionNode
from circle_collision_ros.recording.bag_reader import open_bag
from circle_collision_ros.recording.replay_engine import RecordedTypes, replay_offline
from tests.node.conftest import reader_matched, spin_until

S = math.sqrt(0.5)


def _odometry(now_ns: int, p, q, v, frame: str = "map") -> Odometry:
    msg = Odometry()
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(now_ns, 10**9)
    msg.header.frame_id, msg.child_frame_id = frame, "base_link"
    msg.pose.pose.position.x, msg.pose.pose.position.y = p
    o = msg.pose.pose.orientation
    o.x, o.y, o.z, o.w = q
    msg.twist.twist.linear.x, msg.twist.twist.linear.y = v
    return msg


def test_two_robots_collision_bad_orientations_and_replay(
    ros_context, ros_node, tmp_path: Path
) -> None:
    bag = tmp_path / "bag"
    node = CollisionNode(
        context=ros_context,
        parameter_overrides=[Parameter("odometry_topics", value=["robot_1/odom", "robot_2/odom"]),
                             Parameter("odometry_radii", value=[0.5, 0.25]),
                             Parameter("frame_id", value="map"), Parameter("horizon", value=10.0),
                             Parameter("record_path", value=str(bag))],
    )
    predictions: list[CollisionPredictionArray] = []
    ros_node.create_subscription(
        CollisionPredictionArray, "collision_predictions", predictions.append, 50
    )
    qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
    pub1 = ros_node.create_publisher(Odometry, "robot_1/odom", qos)
    pub2 = ros_node.create_publisher(Odometry, "robot_2/odom", qos)
    try:
        assert spin_until(ros_node,
                          lambda: pub1.get_subscription_count() and pub2.get_subscription_count(),
                          60.0, (node,))
        # best-effort subscriptions: each sample below is sent once, so the readers must have
        # matched
        matched1, matched2 = (
            reader_matched(node, "robot_1/odom"),
            reader_matched(node, "robot_2/odom"),
        )
        assert spin_until(ros_node, lambda: matched1() and matched2(), 60.0, (node,))
        now = ros_node.get_clock().now().nanoseconds
        # robot_1 heads +x at 1 m/s; robot_2 faces +y (yaw 90 deg) and drives forward
        # (body x) at 1 m/s, i.e. +y in the map: they meet near (5, 0).
        pub1.publish(_odometry(now, (0.0, 0.0), (0.0, 0.0, 0.0, 1.0), (1.0, 0.0)))
        pub2.publish(_odometry(now, (5.0, -5.0), (0.0, 0.0, S, S), (1.0, 0.0)))

        def pair():
            for out in predictions:
                for p in out.predictions:
                    if (p.id_a, p.id_b) == ("robot_1", "robot_2"):
                        return p
            return None

        assert spin_until(ros_node, lambda: pair() is not None, 20.0, (node,)), (
            f"no robot pair predicted; {node.counters}"
        )
        world_v2 = (1.0 - 2.0 * S * S, 2.0 * S * S, 0.0)  # what the rotation gives, independently
        want = float(
            time_to_collision((0.0, 0.0), (1.0, 0.0), (0.0, 0.0), 0.5, (5.0, -5.0), world_v2[:2],
                              (0.0, 0.0), 0.25, 10.0)
        )
        assert want == pytest.approx(5.0 - 0.75 / math.sqrt(2.0), rel=1e-12)
        assert pair().time_to_collision == want

        rejected = node.counters.rejected
        later = now + 100_000_000
        bad = [(0.0, 0.0, 0.0, 0.0), (math.nan, 0.0, 0.0, 1.0), (0.0, 0.0, 0.0, 2.0)]
        for q in bad:
            pub2.publish(_odometry(later, (5.0, -5.0), q, (1.0, 0.0)))
        pub1.publish(_odometry(later, (0.0, 0.0), (0.0, 0.0, 0.0, 1.0), (1.0, 0.0), frame="odom"))
        assert spin_until(
            ros_node, lambda: node.counters.rejected >= rejected + 4, 20.0, (node,)
        ), node.counters
        assert node.predictor.bodies == 2
        snapshot = node.predictor.snapshot()
        assert snapshot.velocities.tolist()[1] == pytest.approx([0.0, 1.0], abs=1e-15)  # unchanged
        # Still predicting: a good, newer state of robot_1 is used.
        count = len(predictions)
        pub1.publish(_odometry(later + 1, (1.0, 0.0), (0.0, 0.0, 0.0, 1.0), (1.0, 0.0)))
        assert spin_until(ros_node, lambda: len(predictions) > count, 20.0, (node,))
    finally:
        node.destroy_node()  # closes the recording

    contents = open_bag(
        bag, message_types={RecordedTypes.ODOMETRY, RecordedTypes.PREDICTIONS, RecordedTypes.CONFIG}
    )
    odom = [r for r in contents.records() if r.type_name == RecordedTypes.ODOMETRY]
    assert len(odom) == 7 and {r.topic for r in odom} == {"/robot_1/odom", "/robot_2/odom"}
    report = replay_offline(contents.records())
    assert report.ok and report.predictions >= 2 and report.inputs == 7, report.mismatches
    with open(next(bag.glob("*.mcap")), "rb") as stream:  # an independent reader decodes the schema
        reader = make_reader(stream, validate_crcs=True, decoder_factories=[DecoderFactory()])
        decoded = [m for _, ch, _, m in reader.iter_decoded_messages(topics=["/robot_2/odom"])]
    assert decoded[0].pose.pose.orientation.z == S and decoded[0].twist.twist.linear.x == 1.0
