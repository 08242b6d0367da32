"""ego_ids in the live node over real DDS, and the service's ego_ids.

Guarantees proved here: with the ego_ids parameter the node publishes only pairs with an ego
body, and only ego bodies against static geometry; the service's ego_ids answers the same
way for the request's circles, and its default (empty) answers every pair.
"""
from __future__ import annotations

from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy

from circle_collision_msgs.msg import CircleStateArray, CollisionPredictionArray
from circle_collision_msgs.srv import PredictCollisions
from circle_collision_ros.node.collision_node import CollisionNode
from tests.node.conftest import reader_matched, spin_until
from tests.node_helpers import state, state_array


def _scene(now: int) -> list:
    # a meets b and c, b meets c; d heads for the keep-out zone
    return [state("a", (0.0, 0.0), (1.0, 0.0), r=0.5, stamp_ns=now),
            state("b", (3.0, 0.0), (0.0, 0.0), r=0.5, stamp_ns=now),
            state("c", (3.0, 3.0), (0.0, -1.0), r=0.5, stamp_ns=now),
            state("d", (0.0, 6.0), (0.0, 1.0), r=0.5, stamp_ns=now)]


def test_ego_ids_parameter_and_service(ros_context, ros_node) -> None:
    node = CollisionNode(context=ros_context, parameter_overrides=[
        Parameter("ego_ids", value=["a", "d"]), Parameter("frame_id", value="map"),
        Parameter("static_polygons", value='{"zone": [[-1, 8], [1, 8], [1, 9], [-1, 9]]}'),
        Parameter("stale_timeout", value=600.0)])
    predictions: list[CollisionPredictionArray] = []
    ros_node.create_subscription(CollisionPredictionArray, "collision_predictions",
                                 predictions.append, 50)
    pub = ros_node.create_publisher(CircleStateArray, "circle_states",
                                    QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
    try:
        assert spin_until(ros_node, reader_matched(node, "circle_states"), 30.0, (node,))
        now = ros_node.get_clock().now().nanoseconds
        pub.publish(state_array(_scene(now)))
        assert spin_until(ros_node, lambda: bool(predictions), 20.0, (node,))
        rows = {(p.id_a, p.id_b): p.time_to_collision for p in predictions[-1].predictions}
        # (b, c) meet too, but neither is an ego body; d reaches the zone
        assert rows.keys() == {("a", "b"), ("a", "c"), ("d", "zone")}
        assert rows[("a", "b")] == 2.0 and rows[("d", "zone")] == 1.5
        client = ros_node.create_client(PredictCollisions, "predict_collisions")
        assert client.wait_for_service(timeout_sec=20.0)
        for ego, expected in ((["b"], {("a", "b"), ("b", "c")}),
                              ([], {("a", "b"), ("b", "c"), ("a", "c"), ("d", "zone")})):
            future = client.call_async(PredictCollisions.Request(circles=_scene(now),
                                                                 ego_ids=ego))
            assert spin_until(ros_node, future.done, 20.0, (node,))
            response = future.result()
            assert response.success, response.message
            assert {(p.id_a, p.id_b) for p in response.predictions} == expected
    finally:
        node.destroy_node()
