"""The static world's marker array (node/static_markers.py), read back by rclpy.

Guarantee: the raw CDR bytes are a valid visualization_msgs/MarkerArray that rclpy's own
deserializer reads as DELETEALL, then one LINE_LIST per obstacle whose id is the obstacle's
index (distinct ids: RViz replaces markers of equal id) and whose points are its edges.
"""
from __future__ import annotations

import numpy as np
from builtin_interfaces.msg import Time
from rclpy.serialization import deserialize_message
from visualization_msgs.msg import Marker, MarkerArray

from circle_collision_ros.core.static import (
    GridFrame,
    OccupancyMap,
    Polygon,
    Segments,
    StaticWorld,
)
from circle_collision_ros.node.static_markers import (
    GREY,
    LINE_WIDTH_M,
    STATIC_MARKER_NAMESPACE,
    static_markers,
)

STAMP = Time(sec=1_700_000_123, nanosec=456_789)


def _read(world, frame="map") -> MarkerArray:
    return deserialize_message(static_markers(world, frame, STAMP), MarkerArray)


def test_every_obstacle_is_one_line_list_of_its_edges_with_its_own_id():
    occupied = np.zeros((6, 8), dtype=bool)
    occupied[2, 1:7] = True
    world = StaticWorld.build([
        OccupancyMap("map", occupied, GridFrame(resolution=0.5, origin_x=-2.0, origin_y=1.0)),
        Polygon("crate", np.array([[0.0, 0], [1, 0], [1, 1], [0, 1]])),
        Polygon("box", np.array([[5.0, 5], [6, 5], [6, 6], [5, 6]])),  # as many edges
        Segments("rail", np.array([[-1.0, -1.0]]), np.array([[3.0, -1.0]])),
    ])
    msg = _read(world, "odom")
    first, lines = msg.markers[0], msg.markers[1:]
    assert first.action == Marker.DELETEALL and first.ns == STATIC_MARKER_NAMESPACE
    assert [m.id for m in lines] == [0, 1, 2, 3]
    assert [m.text for m in lines] == list(world.names)
    for k, m in enumerate(lines):
        assert (m.type, m.action, m.ns) == (Marker.LINE_LIST, Marker.ADD, STATIC_MARKER_NAMESPACE)
        assert (m.header.frame_id, m.header.stamp.sec, m.header.stamp.nanosec) == (
            "odom", STAMP.sec, STAMP.nanosec)
        assert m.scale.x == LINE_WIDTH_M and m.pose.orientation.w == 1.0
        assert (m.color.r, m.color.g, m.color.b, m.color.a) == tuple(
            np.float32(GREY).tolist())
        edges = world.edge_obstacle == k
        got = np.array([[p.x, p.y, p.z] for p in m.points])
        assert got.shape == (2 * int(edges.sum()), 3) and got.shape[0] > 0
        assert (got[0::2, :2] == world.starts[edges]).all()
        assert (got[1::2, :2] == world.ends[edges]).all()
        assert (got[:, 2] == 0.0).all()
        assert m.lifetime.sec == 0 and not m.frame_locked and not m.colors


def test_an_empty_world_is_a_deleteall_alone():
    msg = _read(None)
    assert [m.action for m in msg.markers] == [Marker.DELETEALL]
