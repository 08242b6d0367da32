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

import struct

import numpy as np
from builtin_interfaces.msg import Time

from circle_collision_ros.core.static import StaticWorld

__all__ = ["STATIC_MARKER_NAMESPACE", "LINE_WIDTH_M", "GREY", "static_markers"]

STATIC_MARKER_NAMESPACE = "static"
LINE_WIDTH_M = 0.03
GREY = (0.55, 0.55, 0.6, 1.0)  # RGBA
# visualization_msgs/Marker constants (kept here so encoding needs no message objects)
_LINE_LIST, _ADD, _DELETEALL = 5, 0, 3


class _Cdr:
    """A little-endian CDR buffer; alignment counts from the end of the 4-byte
    encapsulation header (as pipeline/cdr.py and node/markers.py)."""

    def __init__(self) -> None:
        self.buf = bytearray(b"\x00\x01\x00\x00")

    def align(self, n: int) -> None:
        self.buf += b"\0" * ((-(len(self.buf) - 4)) % n)

    def pack(self, fmt: str, size: int, *values) -> None:
        self.align(size)
        self.buf += struct.pack("<" + fmt, *values)

    def string(self, value: str) -> None:
        data = value.encode()
        self.pack("I", 4, len(data) + 1)
        self.buf += data + b"\0"

    def marker(self, stamp: Time, frame_id: str, marker_id: int, marker_type: int,
               action: int, points: np.ndarray | None = None, text: str = "") -> None:
        """One visualization_msgs/Marker (field order of its definition)."""
        self.pack("iI", 4, stamp.sec, stamp.nanosec)
        self.string(frame_id)
        self.string(STATIC_MARKER_NAMESPACE)
        self.pack("iii", 4, marker_id, marker_type, action)
        self.pack("7d", 8, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0)  # pose: identity
        width = LINE_WIDTH_M if points is not None else 0.0
        self.pack("3d", 8, width, 0.0, 0.0)  # scale.x is a LINE_LIST's line width
        self.pack("4f", 4, *(GREY if points is not None else (0.0,) * 4))
        self.pack("iI", 4, 0, 0)  # lifetime 0: forever (deletions are explicit)
        self.buf += b"\0"  # frame_locked
        count = 0 if points is None else len(points)
        self.pack("I", 4, count)  # points: geometry_msgs/Point, 3 float64 each
        if count:
            self.align(8)
            self.buf += np.ascontiguousarray(points, dtype="<f8").tobytes()
        self.pack("I", 4, 0)  # colors
        self.string("")  # texture_resource
        self.pack("iI", 4, 0, 0)  # texture.header.stamp
        self.string("")  # texture.header.frame_id
        self.string("")  # texture.format
        self.pack("I", 4, 0)  # texture.data
        self.pack("I", 4, 0)  # uv_coordinates
        self.string(text)
        self.string("")  # mesh_resource
        self.string("")  # mesh_file.filename
        self.pack("I", 4, 0)  # mesh_file.data
        self.buf += b"\0"  # mesh_use_embedded_materials


def static_markers(world: StaticWorld | None, frame_id: str, stamp: Time) -> bytes:
    """Serialized visualization_msgs/MarkerArray: DELETEALL, then one LINE_LIST marker per
    obstacle of ``world`` (none for None), its points the obstacle's edges, z = 0."""
    names = [] if world is None else list(world.names)
    out = _Cdr()
    out.pack("I", 4, 1 + len(names))
    out.marker(stamp, frame_id, 0, 0, _DELETEALL)
    for k, name in enumerate(names):
        edges = world.edge_obstacle == k
        points = np.zeros((2 * int(np.count_nonzero(edges)), 3))
        points[0::2, :2] = world.starts[edges]
        points[1::2, :2] = world.ends[edges]
        out.marker(stamp, frame_id, k, _LINE_LIST, _ADD, points, name)
    return bytes(out.buf)
