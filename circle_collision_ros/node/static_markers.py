"""Markers of the static world: one LINE_LIST per obstacle, for RViz and Foxglove.

Published on ``~/static_markers`` with transient-local durability (a display that joins
late gets the current world), once per applied world version: a DELETEALL, then the edges
of every obstacle (map boundaries, polygons, walls) in the scene frame, grey, on the ground,
marker id = the obstacle's index in the world and text = its name.

The array is serialized straight to CDR bytes (published raw), the points as one numpy
block per obstacle. Building a ``geometry_msgs/Point`` object per edge end in Python ran
on the indexing thread but held the GIL the prediction path needs, for long enough on a
large map to show as prediction latency at every map change (bench/bench_static_node.py
measures the frames during indexing).
"""
from __future__ import annotations

import numpy as np
from builtin_interfaces.msg import Time

from circle_collision_ros.core.static import StaticWorld
from circle_collision_ros.pipeline.cdr import CdrWriter

__all__ = ["STATIC_MARKER_NAMESPACE", "LINE_WIDTH_M", "GREY", "static_markers"]

STATIC_MARKER_NAMESPACE = "static"
LINE_WIDTH_M = 0.03
GREY = (0.55, 0.55, 0.6, 1.0)  # RGBA
# visualization_msgs/Marker constants (kept here so encoding needs no message objects)
_LINE_LIST, _ADD, _DELETEALL = 5, 0, 3


def _marker(out: CdrWriter, stamp: Time, frame: bytes, marker_id: int, marker_type: int,
            action: int, points: np.ndarray | None = None, text: str = "") -> None:
    """One visualization_msgs/Marker (field order of its definition) into ``out``."""
    out.time(stamp.sec, stamp.nanosec)
    out.string(frame)
    out.string(STATIC_MARKER_NAMESPACE.encode())
    for value in (marker_id, marker_type, action):  # int32 fields, all >= 0
        out.u32(value)
    out.f64s(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0)  # pose: identity
    out.f64s(LINE_WIDTH_M if points is not None else 0.0, 0.0, 0.0)  # a LINE_LIST's width
    out.f32s(*(GREY if points is not None else (0.0,) * 4))
    out.time(0, 0)  # lifetime 0: forever (deletions are explicit)
    out.u8(0)  # frame_locked
    out.u32(0 if points is None else len(points))  # points: geometry_msgs/Point, 3 float64
    if points is not None and len(points):
        out.f64_array(points)
    out.u32(0)  # colors
    out.string(b"")  # texture_resource
    out.time(0, 0)  # texture.header.stamp
    out.string(b"")  # texture.header.frame_id
    out.string(b"")  # texture.format
    out.u32(0)  # texture.data
    out.u32(0)  # uv_coordinates
    out.string(text.encode())
    out.string(b"")  # mesh_resource
    out.string(b"")  # mesh_file.filename
    out.u32(0)  # mesh_file.data
    out.u8(0)  # mesh_use_embedded_materials


def static_markers(world: StaticWorld | None, frame_id: str, stamp: Time) -> bytes:
    """Serialized visualization_msgs/MarkerArray: DELETEALL, then one LINE_LIST marker per
    obstacle of ``world`` (none for None), its points the obstacle's edges, z = 0."""
    names = [] if world is None else list(world.names)
    frame = frame_id.encode()
    out = CdrWriter()
    out.u32(1 + len(names))
    _marker(out, stamp, frame, 0, 0, _DELETEALL)
    for k, name in enumerate(names):
        edges = world.edge_obstacle == k
        points = np.zeros((2 * int(np.count_nonzero(edges)), 3))
        points[0::2, :2] = world.starts[edges]
        points[1::2, :2] = world.ends[edges]
        _marker(out, stamp, frame, k, _LINE_LIST, _ADD, points, name)
    return bytes(out.buf)
