"""pipeline/static_inputs.py: OccupancyGrid and PolygonStamped bytes to the node's static inputs.

Guarantees proved here:
- valid bytes of either byte order (rclpy's serialize_message for little endian,
  an independent big-endian writer below) decode to exactly the fields rclpy's
  deserialize_message gives (resolution and points as float32 widened; yaw
  from the quaternion; z of polygon points ignored);
- the map's data is a read-only int8 view of the received bytes (no copy),
  also for a 4000 x 4000 map;
- every truncation is a plain CdrError (never IndexError, struct.error or a
  StaticInputError); random and mutated bytes give a result or CdrError;
- each rule (resolution, origin, orientation: non-unit, zero, non-finite,
  tilted; size cap, overflow, data length; polygon: non-finite point, too few
  vertices, equal consecutive vertices, zero area, point cap) is refused with
  StaticInputError naming the field and the value; an empty polygon is valid;
- every polygon accepted here builds a core.static.world.StaticWorld;
- an obstacle's name is its topic's namespace, as odometry's body id.
"""
from __future__ import annotations

import array
import math
import struct

import numpy as np
import pytest
from geometry_msgs.msg import Point32, PolygonStamped
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from nav_msgs.msg import OccupancyGrid
from rclpy.serialization import deserialize_message, serialize_message

from circle_collision_ros.core.static.world import Polygon, StaticWorld
from circle_collision_ros.pipeline.cdr import CdrError
from circle_collision_ros.pipeline.odometry import body_id_of_topic
from circle_collision_ros.pipeline.static_inputs import (MAX_GRID_CELLS, MAX_POLYGON_POINTS,
                                                         StaticInputError, decode_occupancy_grid,
                                                         decode_polygon_stamped, obstacle_name)
from tests.stress import examples


def f32(x: float) -> float:
    """x rounded to float32, as the wire carries it."""
    return struct.unpack("<f", struct.pack("<f", x))[0]


def grid(width=3, height=2, data=(0, 100, -1, 50, 1, 127), resolution=0.05,
         origin=(-10.5, 4.25, 0.5), q=(0.0, 0.0, 0.0, 1.0), stamp=(1_700_000_000, 5),
         load=(1_699_999_999, 7), frame="map") -> OccupancyGrid:
    msg = OccupancyGrid()
    msg.header.stamp.sec, msg.header.stamp.nanosec = stamp
    msg.header.frame_id = frame
    info = msg.info
    info.map_load_time.sec, info.map_load_time.nanosec = load
    info.resolution, info.width, info.height = resolution, width, height
    p, o = info.origin.position, info.origin.orientation
    p.x, p.y, p.z = origin
    o.x, o.y, o.z, o.w = q
    msg.data = array.array("b", bytes(np.asarray(data, dtype=np.int8)))
    return msg


def polygon(points=((0.0, 0.0, 0.0), (2.0, 0.0, 0.5), (2.0, 1.5, 1.0), (0.25, 1.0, 0.0)),
            stamp=(1_700_000_000, 5), frame="map") -> PolygonStamped:
    msg = PolygonStamped()
    msg.header.stamp.sec, msg.header.stamp.nanosec = stamp
    msg.header.frame_id = frame
    msg.polygon.points = [Point32(x=float(x), y=float(y), z=float(z)) for x, y, z in points]
    return msg


class Writer:
    """An independent XCDR1 writer (alignment from the header's end), either byte order."""

    def __init__(self, be: bool) -> None:
        self.o = ">" if be else "<"
        self.out = bytearray(b"\x00\x00\x00\x00" if be else b"\x00\x01\x00\x00")

    def put(self, fmt: str, *values, size: int) -> None:
        self.out.extend(b"\x00" * ((-(len(self.out) - 4)) % size))
        self.out.extend(struct.pack(self.o + fmt, *values))

    def header(self, sec: int, nanosec: int, frame: str) -> None:
        self.put("iI", sec, nanosec, size=4)
        self.put("I", len(frame.encode()) + 1, size=4)
        self.out.extend(frame.encode() + b"\x00")


def grid_bytes(msg: OccupancyGrid, be: bool = True, data_count: int | None = None) -> bytes:
    """msg written by Writer; data_count overrides the data sequence's length field."""
    w = Writer(be)
    w.header(msg.header.stamp.sec, msg.header.stamp.nanosec, msg.header.frame_id)
    i = msg.info
    w.put("iIfII", i.map_load_time.sec, i.map_load_time.nanosec, i.resolution, i.width, i.height,
          size=4)
    p, o = i.origin.position, i.origin.orientation
    w.put("7d", p.x, p.y, p.z, o.x, o.y, o.z, o.w, size=8)
    w.put("I", len(msg.data) if data_count is None else data_count, size=4)
    w.out.extend(bytes(msg.data))
    return bytes(w.out)


def polygon_bytes(points, be: bool = True, stamp=(3, 4), frame="map") -> bytes:
    """PolygonStamped written by Writer from an (n, 3) array (fast for large n)."""
    w = Writer(be)
    w.header(*stamp, frame)
    pts = np.asarray(points, dtype=np.float32).reshape(-1, 3)
    w.put("I", len(pts), size=4)
    w.out.extend(pts.astype(">f4" if be else "<f4").tobytes())
    return bytes(w.out)


def grid_fields(msg: OccupancyGrid) -> tuple:
    """The decoder's fields (yaw and data apart) as rclpy gives them."""
    i = msg.info
    p = i.origin.position
    return (msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec, msg.header.frame_id,
            i.map_load_time.sec * 10**9 + i.map_load_time.nanosec, i.resolution, i.width,
            i.height, p.x, p.y, p.z)


# ---------------------------------------------------------------- OccupancyGrid: round trips


@pytest.mark.parametrize("frame", ["map", "", "ü/world", "x" * 13])
@pytest.mark.parametrize("stamp", [(1_700_000_000, 5), (-5, 999_999_999), (0, 0)])
def test_grid_both_byte_orders_decode_to_what_rclpy_reads(frame, stamp) -> None:
    msg = grid(width=4, height=3, data=list(range(-6, 6)), resolution=0.1,
               origin=(1e6 + 0.1, -3.5, 2.0), stamp=stamp, load=(stamp[0] - 1, 3), frame=frame)
    le = serialize_message(msg)
    back = deserialize_message(le, OccupancyGrid)
    for data in (le, grid_bytes(msg, be=True), grid_bytes(msg, be=False)):
        got = decode_occupancy_grid(data)
        assert tuple(got[:9]) == grid_fields(back)
        assert got.resolution == f32(0.1) and got.yaw == 0.0
        assert got.data.dtype == np.int8 and got.data.tolist() == list(back.data)
        assert got.data.tolist() == list(range(-6, 6))
    assert le[:2] == b"\x00\x01" and grid_bytes(msg)[:2] == b"\x00\x00"


def test_identity_quaternion_gives_yaw_exactly_zero() -> None:
    got = decode_occupancy_grid(serialize_message(grid(q=(0.0, 0.0, 0.0, 1.0))))
    assert got.yaw == 0.0 and math.copysign(1.0, got.yaw) == 1.0
    assert decode_occupancy_grid(serialize_message(grid(q=(0.0, 0.0, 0.0, -1.0)))).yaw == 0.0


@pytest.mark.parametrize("yaw", [0.3, -1.2, math.pi / 2, -math.pi / 2, 3.0, -3.0, 1e-9])
def test_yaw_of_a_rotation_about_z(yaw) -> None:
    q = (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))
    for data in (serialize_message(grid(q=q)), grid_bytes(grid(q=q), be=True)):
        assert decode_occupancy_grid(data).yaw == pytest.approx(yaw, rel=1e-15, abs=1e-15)
    # -q is the same rotation
    minus = tuple(-c for c in q)
    assert decode_occupancy_grid(serialize_message(grid(q=minus))).yaw == pytest.approx(
        yaw, rel=1e-15, abs=1e-15)


def test_yaw_pi_and_the_tolerances() -> None:
    assert abs(decode_occupancy_grid(serialize_message(grid(q=(0.0, 0.0, 1.0, 0.0)))).yaw) \
        == pytest.approx(math.pi, rel=1e-15)
    # norm within 1e-3 of 1: normalised; a tilt within 1e-3: accepted, yaw still about z
    s, c = math.sin(0.35), math.cos(0.35)
    got = decode_occupancy_grid(serialize_message(grid(q=(0.0, 0.0, 1.0009 * s, 1.0009 * c))))
    assert got.yaw == pytest.approx(0.7, rel=1e-14)
    got = decode_occupancy_grid(serialize_message(grid(q=(9e-4, 0.0, s, math.sqrt(c * c - 81e-8)))))
    assert got.yaw == pytest.approx(0.7, abs=1e-5)


def test_data_is_a_read_only_view_of_the_bytes() -> None:
    data = serialize_message(grid())
    got = decode_occupancy_grid(data)
    assert np.shares_memory(got.data, np.frombuffer(data, dtype=np.uint8))
    assert got.data.base is not None and not got.data.flags.writeable
    with pytest.raises(ValueError):
        got.data[0] = 1
    assert got.data.tolist() == [0, 100, -1, 50, 1, 127]


def test_a_4000_by_4000_map_decodes_without_a_copy() -> None:
    cells = np.random.default_rng(3).integers(-1, 101, 4000 * 4000, dtype=np.int8)
    msg = grid(width=4000, height=4000, data=cells, resolution=0.0625)
    for data in (serialize_message(msg), grid_bytes(msg, be=True)):
        got = decode_occupancy_grid(data)
        assert (got.width, got.height, got.resolution) == (4000, 4000, 0.0625)
        assert np.shares_memory(got.data, np.frombuffer(data, dtype=np.uint8))
        assert np.array_equal(got.data, cells)


# ---------------------------------------------------------------- OccupancyGrid: refusals


@pytest.mark.parametrize(
    "changes, field, words",
    [
        ({"resolution": 0.0}, r"info\.resolution", "got 0.0"),
        ({"resolution": -0.05}, r"info\.resolution", "got -0.05"),
        ({"resolution": math.nan}, r"info\.resolution", "got nan"),
        ({"resolution": math.inf}, r"info\.resolution", "got inf"),
        ({"origin": (math.nan, 0.0, 0.0)}, r"info\.origin\.position", "(nan, 0.0, 0.0)"),
        ({"origin": (0.0, -math.inf, 0.0)}, r"info\.origin\.position", "-inf"),
        ({"origin": (0.0, 0.0, math.inf)}, r"info\.origin\.position", "inf"),
        ({"q": (0.0, 0.0, 0.0, 0.0)}, r"info\.origin\.orientation", "zero or not finite"),
        ({"q": (0.0, 0.0, math.nan, 1.0)}, r"info\.origin\.orientation", "zero or not finite"),
        ({"q": (0.0, 0.0, 0.0, math.inf)}, r"info\.origin\.orientation", "zero or not finite"),
        ({"q": (0.0, 0.0, 0.0, 2.0)}, r"info\.origin\.orientation",
         "not a unit quaternion (norm 2"),
        ({"q": (0.0, 0.0, 0.0, 1.0011)}, r"info\.origin\.orientation", "not a unit quaternion"),
        ({"q": (math.sin(0.1), 0.0, 0.0, math.cos(0.1))}, r"info\.origin\.orientation",
         "tilts the map (|(x, y)| = 0.0998"),
        ({"q": (0.0, 0.0011, 0.0, 1.0)}, r"info\.origin\.orientation", "tilts the map"),
        ({"q": (0.5, 0.5, 0.5, 0.5)}, r"info\.origin\.orientation", "tilts the map"),
        ({"width": 0, "data": ()}, r"info\.width x info\.height", "0 x 2"),
        ({"height": 0, "data": ()}, r"info\.width x info\.height", "3 x 0"),
        ({"width": 2**14, "height": 2**14 + 1, "data": ()}, r"info\.width x info\.height",
         f"16384 x 16385 = {2**28 + 2**14} cells, more than the {2**28} accepted"),
        ({"width": 2**32 - 1, "height": 2**32 - 1, "data": ()}, r"info\.width x info\.height",
         f"= {(2**32 - 1) ** 2} cells"),
        ({"data": (1, 2, 3, 4, 5)}, "data", "data has 5 values, width*height = 6"),
        ({"data": tuple(range(7))}, "data", "data has 7 values, width*height = 6"),
        ({"data": ()}, "data", "data has 0 values, width*height = 6"),
    ],
)
def test_unusable_maps_are_refused_naming_the_field(changes, field, words) -> None:
    msg = grid(**changes)
    for data in (serialize_message(msg), grid_bytes(msg, be=True)):
        with pytest.raises(StaticInputError, match=field) as info:
            decode_occupancy_grid(data)
        assert words in str(info.value)
    assert MAX_GRID_CELLS == 2**28


def test_a_data_length_past_the_end_is_malformed_not_unusable() -> None:
    for count in (7, 2**32 - 1):
        with pytest.raises(CdrError, match=r"truncated OccupancyGrid: data has") as info:
            decode_occupancy_grid(grid_bytes(grid(), data_count=count))
        assert type(info.value) is CdrError


# ---------------------------------------------------------------- PolygonStamped


@pytest.mark.parametrize("frame", ["map", "", "ü", "x" * 13])
def test_polygon_both_byte_orders_decode_to_what_rclpy_reads(frame) -> None:
    pts = [(0.1, -0.2, 5.0), (3.3, 0.0, -1.0), (1e6 + 0.5, 7.7, 0.0), (-2.0, 1e-30, 3.0)]
    msg = polygon(pts, stamp=(-5, 999_999_999), frame=frame)
    le = serialize_message(msg)
    back = deserialize_message(le, PolygonStamped)
    want = [[p.x, p.y] for p in back.polygon.points]
    assert want == [[f32(x), f32(y)] for x, y, _ in pts]
    for data in (le, polygon_bytes(pts, be=True, stamp=(-5, 999_999_999), frame=frame),
                 polygon_bytes(pts, be=False, stamp=(-5, 999_999_999), frame=frame)):
        got = decode_polygon_stamped(data)
        assert got.stamp_ns == -5 * 10**9 + 999_999_999 and got.frame_id == frame
        assert got.vertices.dtype == np.float64 and got.vertices.shape == (4, 2)
        assert got.vertices.tolist() == want


def test_z_is_ignored() -> None:
    flat = decode_polygon_stamped(serialize_message(polygon(((0, 0, 0), (1, 0, 0), (0, 1, 0)))))
    tall = decode_polygon_stamped(serialize_message(polygon(((0, 0, 9), (1, 0, -3), (0, 1, 1e30)))))
    nan_z = decode_polygon_stamped(polygon_bytes([(0, 0, math.nan), (1, 0, math.inf), (0, 1, 0)]))
    assert flat.vertices.tolist() == tall.vertices.tolist() == nan_z.vertices.tolist()


def test_an_empty_polygon_is_valid() -> None:
    for data in (serialize_message(polygon(())), polygon_bytes(np.empty((0, 3)), be=True)):
        got = decode_polygon_stamped(data)
        assert got.vertices.shape == (0, 2) and got.vertices.dtype == np.float64
        assert got.frame_id == "map"


def test_a_closing_point_is_kept_and_the_loop_must_still_be_a_polygon() -> None:
    closed = ((0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 0))
    got = decode_polygon_stamped(serialize_message(polygon(closed)))
    assert got.vertices.tolist() == [[0, 0], [1, 0], [0, 1], [0, 0]]
    with pytest.raises(StaticInputError, match="has 3 points, 2 distinct: a polygon needs"):
        decode_polygon_stamped(serialize_message(polygon(((0, 0, 0), (1, 0, 0), (0, 0, 0)))))


@pytest.mark.parametrize(
    "points, words",
    [
        ([(0, 0, 0)], "polygon.points has 1 point, 1 distinct: a polygon needs at least 3 "
                      "vertices (send no points to remove the obstacle)"),
        ([(0, 0, 0), (1, 1, 0)], "polygon.points has 2 points, 2 distinct: a polygon needs"),
        ([(0, 0, 0), (1, 1, 0), (2, 2, 0)], "zero area (its 3 vertices are collinear"),
        ([(0, 0, 0), (1, 0, 0), (3, 0, 0), (-5, 0, 0)], "zero area (its 4 vertices are collinear"),
        ([(1e6, 1e6, 0), (1e6 + 1, 1e6 + 1, 0), (1e6 + 2, 1e6 + 2, 0)], "zero area"),
        ([(0, 0, 0), (1, 1, 0), (1, 0, 0), (0, 1, 0)], "zero area"),  # a bow tie: signed area 0
        ([(0, 0, 0), (1, 0, 0), (1, 0, 0), (0, 1, 0)], "polygon.points[1] and the next point are "
                                                       "equal (1.0, 0.0)"),
        ([(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 1, 0), (0, 0, 0)], "polygon.points[2] and the next"),
        ([(0, 0, 0), (1, 0, 0), (math.nan, 1, 0)], "polygon.points[2] has a non-finite coordinate "
                                                    "(x nan, y 1.0)"),
        ([(0, 0, 0), (1, -math.inf, 0), (0, 1, 0)], "polygon.points[1] has a non-finite"),
        ([(math.inf, 0, 0)], "polygon.points[0] has a non-finite coordinate (x inf, y 0.0)"),
    ],
)
def test_unusable_polygons_are_refused_naming_the_problem(points, words) -> None:
    for data in (serialize_message(polygon(points)) if np.isfinite(points).all()
                 else polygon_bytes(points, be=False), polygon_bytes(points, be=True)):
        with pytest.raises(StaticInputError) as info:
            decode_polygon_stamped(data)
        assert words in str(info.value)


def test_the_point_cap() -> None:
    t = np.linspace(0.0, 2 * math.pi, MAX_POLYGON_POINTS, endpoint=False)
    circle = np.stack([100 * np.cos(t), 100 * np.sin(t), np.zeros_like(t)], axis=1)
    assert decode_polygon_stamped(polygon_bytes(circle)).vertices.shape == (MAX_POLYGON_POINTS, 2)
    over = np.concatenate([circle, [[0.0, 0.0, 0.0]]])
    for be in (True, False):
        with pytest.raises(StaticInputError,
                           match=f"polygon.points has {MAX_POLYGON_POINTS + 1} points, more than "
                                 f"the {MAX_POLYGON_POINTS} accepted"):
            decode_polygon_stamped(polygon_bytes(over, be=be))


def test_accepted_polygons_build_a_static_world() -> None:
    rng = np.random.default_rng(11)
    built = 0
    for n in range(3, 40):
        for _ in range(5):
            pts = rng.integers(-3, 4, size=(n, 3)).astype(float) * rng.choice([1.0, 1e-3, 1e4])
            try:
                got = decode_polygon_stamped(polygon_bytes(pts))
            except StaticInputError:
                continue
            StaticWorld.build([Polygon("p", got.vertices)])
            built += 1
    assert built > 50


# ---------------------------------------------------------------- malformed bytes, both types


def _small_messages() -> list[tuple[bytes, object]]:
    g, p = grid(frame="a_long_frame_name"), polygon(frame="a_long_frame_name")
    return [(serialize_message(g), decode_occupancy_grid),
            (grid_bytes(g, be=True), decode_occupancy_grid),
            (serialize_message(grid(frame="")), decode_occupancy_grid),
            (serialize_message(p), decode_polygon_stamped),
            (polygon_bytes([[0, 0, 0], [1, 0, 0], [0, 1, 0]], be=True), decode_polygon_stamped),
            (serialize_message(polygon((), frame="")), decode_polygon_stamped)]


# ids by position: serialized bytes carry padding that differs between processes, and
# pytest-xdist's workers must collect the same test ids
@pytest.mark.parametrize("data, decode", _small_messages(),
                         ids=[f"message{k}" for k in range(len(_small_messages()))])
def test_every_truncation_is_a_cdr_error(data, decode) -> None:
    # Fast DDS may pad the payload to a multiple of 4: those trailing bytes are not read.
    decode(data)
    needed = next(n for n in range(len(data), -1, -1) if not _decodes(decode, data[:n]))
    assert len(data) - needed <= 4
    for cut in range(needed + 1):
        with pytest.raises(CdrError) as info:
            decode(data[:cut])
        assert type(info.value) is CdrError, f"cut at {cut}: {info.value}"
    for kind in (bytearray, memoryview):  # any bytes-like buffer
        decode(kind(data))


def _decodes(decode, data: bytes) -> bool:
    try:
        decode(data)
    except CdrError:
        return False
    return True


@pytest.mark.parametrize("decode", [decode_occupancy_grid, decode_polygon_stamped])
def test_bad_encapsulation_and_frame_ids(decode) -> None:
    data = serialize_message(grid() if decode is decode_occupancy_grid else polygon())
    for head in (b"\x00\x02", b"\x00\x03", b"\x01\x01"):
        with pytest.raises(CdrError, match="not plain CDR"):
            decode(head + data[2:])
    with pytest.raises(CdrError, match="encapsulation missing"):
        decode(b"")
    bad = data.replace(b"map\x00", b"m\xffp\x00", 1)
    with pytest.raises(CdrError, match="header.frame_id is not UTF-8"):
        decode(bad)
    unterminated = data.replace(b"map\x00", b"mapX", 1)
    with pytest.raises(CdrError, match="malformed .*header.frame_id"):
        decode(unterminated)


@settings(
    max_examples=examples(300, 1500), deadline=None, suppress_health_check=[HealthCheck.too_slow]
)
@given(
    st.sampled_from([decode_occupancy_grid, decode_polygon_stamped]),
    st.binary(max_size=300)
    | st.builds(lambda data, k, b: data[: k % len(data)] + bytes([b]) + data[k % len(data) + 1 :],
                st.sampled_from([m for m, _ in _small_messages()]),
                st.integers(0, 10_000), st.integers(0, 255)),
)
def test_garbage_is_a_result_or_cdr_error(decode, data: bytes) -> None:
    try:
        got = decode(data)
    except CdrError:
        return
    if decode is decode_occupancy_grid:
        assert got.data.shape == (got.width * got.height,) and got.resolution > 0
        assert -math.pi <= got.yaw <= math.pi
    else:
        assert got.vertices.ndim == 2 and np.isfinite(got.vertices).all()


def test_obstacle_names_follow_the_odometry_rule() -> None:
    for topic, name in [("/shelf_3/polygon", "shelf_3"), ("/fleet/zone_a/map", "fleet/zone_a"),
                        ("/map", "map"), ("map", "map"), ("/a/b/c/d", "a/b/c")]:
        assert obstacle_name(topic) == name == body_id_of_topic(topic)
