"""metadata.yaml of a recording carries offered_qos_profiles as rosbag2 writes them.

`ros2 bag play` chooses each topic's QoS from `offered_qos_profiles` in
metadata.yaml. Guarantees proved here, with a live node and a publisher that
appears only after the recording started:
- each input topic lists the QoS its publishers offer (reliability, durability,
  rosbag2's field names and duration form), once they are seen;
- the node's own output lists the profile it publishes with;
- rosbags (an independent reader) parses them.
"""
from __future__ import annotations

import time
from pathlib import Path

import yaml
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from circle_collision_msgs.msg import CircleStateArray
from circle_collision_ros.node.collision_node import CollisionNode
from tests.node.conftest import spin_until
from tests.node_helpers import state, state_array

PROFILE_KEYS = ["history", "depth", "reliability", "durability", "deadline", "lifespan",
                "liveliness", "liveliness_lease_duration", "avoid_ros_namespace_conventions"]


def test_offered_qos_profiles_in_metadata(ros_context, ros_node, tmp_path: Path) -> None:
    bag = tmp_path / "bag"
    node = CollisionNode(
        context=ros_context, parameter_overrides=[Parameter("record_path", value=str(bag))]
    )
    try:
        spin_until(ros_node, lambda: False, 1.5, (node,))  # recording runs without publishers first
        pub = ros_node.create_publisher(
            CircleStateArray,
            "circle_states",
            QoSProfile(depth=7, reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.TRANSIENT_LOCAL),
        )
        stamp = ros_node.get_clock().now().nanoseconds
        pub.publish(
            state_array([state("a", (0, 0), stamp_ns=stamp), state("b", (5, 0), stamp_ns=stamp)])
        )
        deadline = time.monotonic() + 20
        metadata = bag / "metadata.yaml"

        def listed() -> bool:
            topics = yaml.safe_load(metadata.read_text())["rosbag2_bagfile_information"][
                "topics_with_message_count"
            ]
            return any(
                t["topic_metadata"]["name"] == "/circle_states"
                and t["topic_metadata"]["offered_qos_profiles"]
                for t in topics
            )

        assert spin_until(ros_node, listed, deadline - time.monotonic(), (node,)), (
            metadata.read_text()
        )
    finally:
        node.destroy_node()
    info = yaml.safe_load(metadata.read_text())["rosbag2_bagfile_information"]
    qos = {
        t["topic_metadata"]["name"]: t["topic_metadata"]["offered_qos_profiles"]
        for t in info["topics_with_message_count"]
    }
    (offered,) = qos["/circle_states"]
    assert list(offered) == PROFILE_KEYS
    assert (offered["reliability"], offered["durability"]) == ("reliable", "transient_local")
    assert set(offered["deadline"]) == {"sec", "nsec"}
    (own,) = qos["/collision_predictions"]
    assert (own["history"], own["depth"], own["reliability"]) == ("keep_last", 10, "reliable")
    assert qos["/collision_node/config"][0]["reliability"] == "reliable"

    from rosbags.rosbag2 import Reader

    with Reader(bag) as reader:
        by_topic = {c.topic: c.ext.offered_qos_profiles for c in reader.connections}
    assert by_topic["/circle_states"][0].reliability.name.lower() == "reliable"
