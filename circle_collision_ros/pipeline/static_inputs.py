"""Static geometry inputs: nav_msgs/OccupancyGrid and geometry_msgs/PolygonStamped from CDR bytes.

A map or a polygon obstacle arrives rarely and is checked once, so the fixed
fields are read with ``struct`` (each read bounds-checked) and only the bulk
arrays go through numpy:

- OccupancyGrid ``data`` (sequence<int8>) becomes a read-only int8 view of the
  received bytes (``np.frombuffer``, no copy: a 4000 x 4000 map costs
  microseconds). The view keeps the buffer alive; a caller that passes a
  bytearray or memoryview must not change it while the map is in use.
- PolygonStamped ``polygon.points`` (sequence<Point32>, float32 x y z)
  becomes an (n, 2) float64 array of x, y (the one copy, float32 widened
  exactly); z is not read: the obstacle is a prism over all heights.

Rules for a map (StaticInputError naming the field and the value):

- ``info.resolution`` (float32 on the wire, widened exactly: 0.05 arrives as
  0.0500000007...) finite and > 0; ``info.origin.position`` finite;
- ``info.origin.orientation`` a rotation about z only: a quaternion whose norm
  is within QuaternionRule.TOLERANCE of 1 is normalised (odometry's rule;
  zero, non-finite or further from unit is rejected), then its (x, y) part
  must be at most MAX_TILT (a tilted map is rejected; 1e-3 is a tilt of about
  0.11 degrees); yaw = atan2(2(wz + xy), 1 - 2(y^2 + z^2)) in (-pi, pi];
- width and height > 0 and width * height at most MAX_GRID_CELLS (computed on
  Python ints: no overflow), and ``len(data) == width * height``.

Rules for a polygon:

- no points: valid, it means "remove this obstacle";
- x and y of every point finite (the first bad point is named);
- at most MAX_POLYGON_POINTS points; the loop (a last point repeating the first
  is not a vertex of its own) has at least 3 vertices, no two consecutive ones
  equal, and a non-zero area (|shoelace sum| > 1e-12 * sum of |products|, the
  rule of core.static.world, so every polygon accepted here builds a world).
  The vertices are returned as received, closing point included.

An obstacle's name is its topic's namespace, the rule odometry uses for a
body id (`obstacle_name`).

Decoding follows pipeline/cdr.py's rules (XCDR1, both byte orders, alignment
from the end of the encapsulation header, every read bounds-checked, strings
NUL-terminated inside the buffer): malformed or truncated bytes raise CdrError
saying where; untrusted bytes never reach rclpy's deserializer.
"""
from __future__ import annotations

import math
import struct
from typing import NamedTuple

import numpy as np

from circle_collision_ros.pipeline.cdr import (CDR_BE, CDR_LE, ORIGIN, CdrError, align, read_string,
                                               read_u32)
from circle_collision_ros.pipeline.odometry import (QuaternionRule, body_id_of_topic,
                                                    unit_quaternion)

OCCUPANCY_GRID_TYPE = "nav_msgs/msg/OccupancyGrid"
POLYGON_STAMPED_TYPE = "geometry_msgs/msg/PolygonStamped"

#: Largest map accepted, in cells (a 16384 x 16384 grid; 256 MB of data).
MAX_GRID_CELLS = 2**28
#: Most points accepted in one polygon.
MAX_POLYGON_POINTS = 100_000
#: Largest |(x, y)| of the normalised map orientation: a rotation about z only.
MAX_TILT = QuaternionRule.TOLERANCE
#: Relative tolerance of the zero-area test (core.static.world's).
AREA_TOLERANCE = 1e-12


class StaticInputError(CdrError):
    """A map or polygon message that decodes but cannot be used (the message names the field)."""


class OccupancyGridMsg(NamedTuple):
    """What the node uses of one OccupancyGrid message."""

    stamp_ns: int  # header.stamp
    frame_id: str
    map_load_time_ns: int  # info.map_load_time
    resolution: float  # m per cell side
    width: int  # cells along the grid's x
    height: int  # cells along the grid's y
    origin_x: float  # m, map position of cell (0, 0)'s corner
    origin_y: float
    origin_z: float
    yaw: float  # rad, the grid's rotation about z, in (-pi, pi]
    data: np.ndarray  # (width * height,) int8, row-major data[iy * width + ix]; a read-only view


class PolygonMsg(NamedTuple):
    """What the node uses of one PolygonStamped message."""

    stamp_ns: int  # header.stamp
    frame_id: str
    vertices: np.ndarray  # (n, 2) float64, m: x, y of polygon.points (z ignored); n = 0: remove


def obstacle_name(topic: str) -> str:
    """An obstacle's name from its resolved topic: the namespace, or the name at the root
    (`/shelf_3/polygon` -> `shelf_3`, `/map` -> `map`), as odometry.body_id_of_topic."""
    return body_id_of_topic(topic)


def _unpack(data: bytes, pos: int, fmt: str, be: bool, size: int, what: str) -> tuple[tuple, int]:
    """(values, next position) of ``fmt`` aligned to ``size`` at pos; CdrError when past the end."""
    layout = struct.Struct((">" if be else "<") + fmt)
    pos = int(align(pos, size))
    if pos + layout.size > len(data):
        raise CdrError(
            f"truncated {what}: needs {layout.size} bytes at byte {pos}, "
            f"{max(len(data) - pos, 0)} remain"
        )
    return layout.unpack_from(data, pos), pos + layout.size


def _header(data: bytes, kind: str) -> tuple[bool, np.ndarray, int, str, int]:
    """(big endian, uint8 view, header.stamp in ns, header.frame_id, next position)."""
    if len(data) < ORIGIN or bytes(data[:2]) not in (CDR_LE, CDR_BE):
        raise CdrError(
            f"not plain CDR {kind} (encapsulation {bytes(data[:2]).hex() or 'missing'}, "
            f"{len(data)} bytes)"
        )
    be = bytes(data[:2]) == CDR_BE
    buf = np.frombuffer(data, dtype=np.uint8)
    (sec, nanosec), pos = _unpack(data, ORIGIN, "iI", be, 4, f"{kind} header.stamp")
    frame_off, frame_len, pos = read_string(buf, pos, be)
    if frame_off < 0:
        raise CdrError(f"truncated or malformed {kind} header.frame_id")
    try:
        frame = bytes(data[frame_off : frame_off + frame_len]).decode()
    except UnicodeDecodeError as exc:
        raise CdrError(f"{kind} header.frame_id is not UTF-8 ({exc.reason})") from exc
    return be, buf, sec * 1_000_000_000 + nanosec, frame, int(pos)


def _sequence(data: bytes, buf: np.ndarray, pos: int, be: bool, item: int, what: str,
              kind: str) -> tuple[int, int]:
    """(element count, offset of the first element) of a sequence of ``item``-byte elements
    (aligned to at most 4) at pos; CdrError when the count or the elements pass the end."""
    pos = int(align(pos, 4))
    if pos + 4 > len(data):
        raise CdrError(f"truncated {kind}: {what} length at byte {pos} is past the end")
    count = int(read_u32(buf, pos, be))
    start = pos + 4
    if start + count * item > len(data):
        raise CdrError(
            f"truncated {kind}: {what} has {count} elements ({count * item} bytes) at byte "
            f"{start}, {len(data) - start} remain"
        )
    return count, start


def decode_occupancy_grid(buf: bytes) -> OccupancyGridMsg:
    """The used fields of serialized nav_msgs/OccupancyGrid bytes (module docstring: the rules).

    Raises
    ------
    CdrError
        If the bytes are not well-formed OccupancyGrid CDR (either byte order);
        StaticInputError (a CdrError) for a map that cannot be used.
    """
    kind = "OccupancyGrid"
    be, raw, stamp_ns, frame, pos = _header(buf, kind)
    (load_sec, load_nanosec, resolution, width, height), pos = _unpack(
        buf, pos, "iIfII", be, 4, f"{kind} info (map_load_time, resolution, width, height)"
    )
    origin, pos = _unpack(buf, pos, "7d", be, 8, f"{kind} info.origin")
    count, start = _sequence(buf, raw, pos, be, 1, "data", kind)
    resolution = float(resolution)
    if not (math.isfinite(resolution) and resolution > 0.0):
        raise StaticInputError(f"info.resolution must be finite and > 0, got {resolution}")
    if not all(math.isfinite(c) for c in origin[:3]):
        raise StaticInputError(f"info.origin.position {origin[:3]} is not finite")
    yaw = map_yaw(origin[3:])
    if width == 0 or height == 0:
        raise StaticInputError(
            f"info.width x info.height is {width} x {height}: a map needs at least one cell"
        )
    cells = width * height  # Python ints: exact
    if cells > MAX_GRID_CELLS:
        raise StaticInputError(
            f"info.width x info.height = {width} x {height} = {cells} cells, more than the "
            f"{MAX_GRID_CELLS} accepted"
        )
    if count != cells:
        raise StaticInputError(f"data has {count} values, width*height = {cells}")
    data = np.frombuffer(buf, dtype=np.int8, count=count, offset=start)
    data.flags.writeable = False
    return OccupancyGridMsg(stamp_ns, frame, load_sec * 1_000_000_000 + load_nanosec, resolution,
                            width, height, origin[0], origin[1], origin[2], yaw, data)


def map_yaw(q: tuple[float, float, float, float]) -> float:
    """Yaw (rad, in (-pi, pi]) of a map orientation q = (x, y, z, w), which must be a rotation
    about z; raises StaticInputError naming info.origin.orientation otherwise."""
    q = tuple(float(c) for c in q)
    x, y, z, w = unit_quaternion(q, "info.origin.orientation", StaticInputError)
    tilt = math.hypot(x, y)
    if tilt > MAX_TILT:
        raise StaticInputError(
            f"info.origin.orientation {q} tilts the map (|(x, y)| = {tilt:.6g} after "
            f"normalising; a map may only rotate about z, |(x, y)| <= {MAX_TILT:g})"
        )
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def decode_polygon_stamped(buf: bytes) -> PolygonMsg:
    """The used fields of serialized geometry_msgs/PolygonStamped bytes (module docstring: the
    rules); vertices (n, 2) float64 in m, z ignored, n = 0 for an empty polygon (remove).

    Raises
    ------
    CdrError
        If the bytes are not well-formed PolygonStamped CDR (either byte order);
        StaticInputError (a CdrError) for a polygon that cannot be used.
    """
    kind = "PolygonStamped"
    be, raw, stamp_ns, frame, pos = _header(buf, kind)
    count, start = _sequence(buf, raw, pos, be, 12, "polygon.points", kind)
    if count > MAX_POLYGON_POINTS:
        raise StaticInputError(
            f"polygon.points has {count} points, more than the {MAX_POLYGON_POINTS} accepted"
        )
    points = np.frombuffer(buf, dtype=">f4" if be else "<f4", count=3 * count, offset=start)
    vertices = points.reshape(count, 3)[:, :2].astype(np.float64)
    check_polygon(vertices)
    return PolygonMsg(stamp_ns, frame, vertices)


def check_polygon(vertices: np.ndarray) -> None:
    """Raise StaticInputError unless (n, 2) vertices are empty or a usable polygon (the module
    docstring's rules), naming the problem."""
    finite = np.isfinite(vertices).all(axis=1)
    if not finite.all():
        k = int(np.argmin(finite))
        raise StaticInputError(
            f"polygon.points[{k}] has a non-finite coordinate "
            f"(x {vertices[k, 0]}, y {vertices[k, 1]})"
        )
    if len(vertices) == 0:
        return
    loop = vertices
    if len(loop) >= 2 and np.array_equal(loop[0], loop[-1]):
        loop = loop[:-1]  # the closing point repeats the first vertex
    if len(loop) < 3:
        raise StaticInputError(
            f"polygon.points has {len(vertices)} point{'s' * (len(vertices) != 1)}, "
            f"{len(loop)} distinct: a polygon needs at least 3 vertices (send no points to "
            "remove the obstacle)"
        )
    nxt = np.roll(loop, -1, axis=0)
    same = np.all(loop == nxt, axis=1)
    if same.any():
        k = int(np.argmax(same))
        raise StaticInputError(
            f"polygon.points[{k}] and the next point are equal ({loop[k, 0]}, {loop[k, 1]})"
        )
    products = loop[:, 0] * nxt[:, 1], nxt[:, 0] * loop[:, 1]
    area2 = float(np.sum(products[0] - products[1]))
    scale = float(np.sum(np.abs(products[0]) + np.abs(products[1])))
    if not abs(area2) > AREA_TOLERANCE * scale:
        raise StaticInputError(
            f"polygon.points has zero area (its {len(loop)} vertices are collinear, or its "
            f"signed area cancels: shoelace sum {area2:g})"
        )
