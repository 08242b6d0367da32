"""Markers of the static world: one LINE_LIST per obstacle, for RViz and Foxglove.

Published on ``~/static_markers`` with transient-local durability (a display that joins
late gets the current world), once per applied world version: a DELETEALL, then the edges
of every obstacle (map boundaries, polygons, walls) in the scene frame, grey, on the ground.
Rarely sent and drawn off the prediction path by the executor between predictions.
"""
from __future__ import annotations

import time

from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point
from std_msgs.msg import ColorRGBA, Header
from visualization_msgs.msg import Marker, MarkerArray

from circle_collision_ros.core.static import StaticWorld

__all__ = ["STATIC_MARKER_NAMESPACE", "static_markers"]

STATIC_MARKER_NAMESPACE = "static"
LINE_WIDTH_M = 0.03
YIELD_EVERY = 256  # edges between two hand-overs of the GIL (~0.5 ms of Python)
GREY = ColorRGBA(r=0.55, g=0.55, b=0.6, a=1.0)


def static_markers(world: StaticWorld | None, frame_id: str, stamp: Time) -> MarkerArray:
    """DELETEALL, then one LINE_LIST marker per obstacle of ``world`` (none for None)."""
    header = Header(stamp=stamp, frame_id=frame_id)
    out = [Marker(header=header, ns=STATIC_MARKER_NAMESPACE, action=Marker.DELETEALL)]
    if world is None:
        return MarkerArray(markers=out)
    for k, name in enumerate(world.names):
        edges = world.edge_obstacle == k
        starts, ends = world.starts[edges], world.ends[edges]
        points = []
        for k, ((x0, y0), (x1, y1)) in enumerate(zip(starts.tolist(), ends.tolist())):
            points.append(Point(x=x0, y=y0, z=0.0))
            points.append(Point(x=x1, y=y1, z=0.0))
            if k % YIELD_EVERY == YIELD_EVERY - 1:
                # this runs on the indexing thread: hand the GIL to the executor often, or a
                # prediction waits up to the interpreter's switch interval each time
                time.sleep(0)
        marker = Marker(header=header, ns=STATIC_MARKER_NAMESPACE, id=k, type=Marker.LINE_LIST,
                        action=Marker.ADD, points=points, color=GREY, text=name)
        marker.scale.x = LINE_WIDTH_M
        marker.pose.orientation.w = 1.0
        out.append(marker)
    return MarkerArray(markers=out)
