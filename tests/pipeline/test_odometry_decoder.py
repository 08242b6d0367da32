"""pipeline/odometry.py: nav_msgs/Odometry bytes to a one-body StateBatch.

Guarantees proved here:
- valid bytes of either byte order (rclpy's serialize_message for little endian,
  an independent big-endian writer below) decode to exactly the fields rclpy's
  deserialize_message gives;
- every truncation, random bytes and hypothesis-mutated bytes give a result or
  CdrError, never another exception;
- velocity: twist.twist.linear rotated by the orientation into header.frame_id
  (checked against an independent rotation-matrix computation in mpmath);
  acceleration is zero;
- quaternion rule: within 1e-3 of unit is normalised; zero, NaN, inf or further
  from unit is refused with OdometryError naming pose.orientation;
- ids: the topic's namespace (the name at the root); two topics with one id
  and a radii list of the wrong length are refused.
"""
from __future__ import annotations

import math
import struct

import mpmath
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from nav_msgs.msg import Odometry
from rclpy.serialization import deserialize_message, serialize_message

from circle_collision_ros.pipeline.cdr import CdrError
from circle_collision_ros.pipeline.odometry import (OdometryError, OdometrySource, body_id_of_topic,
                                                    decode_odometry, odometry_batch,
                                                    odometry_sources)
from tests.stress import examples

SOURCE = OdometrySource("robot_1", 0.4)


def odometry(p=(1.0, 2.0, 0.0), q=(0.0, 0.0, 0.0, 1.0), v=(0.5, 0.0, 0.0), stamp=(1_700_000_000, 5),
             frame="map", child="base_link") -> Odometry:
    msg = Odometry()
    msg.header.stamp.sec, msg.header.stamp.nanosec = stamp
    msg.header.frame_id, msg.child_frame_id = frame, child
    msg.pose.pose.position.x, msg.pose.pose.position.y, msg.pose.pose.position.z = p
    o = msg.pose.pose.orientation
    o.x, o.y, o.z, o.w = q
    msg.twist.twist.linear.x, msg.twist.twist.linear.y, msg.twist.twist.linear.z = v
    msg.twist.twist.angular.z = 0.25
    # Symmetric PSD with (nearly) all-distinct entries: a misplaced offset shows.
    a = np.arange(36.0).reshape(6, 6) / 10.0
    msg.pose.covariance = (a @ a.T).ravel().tolist()
    msg.twist.covariance = (a.T @ a / 7.0).ravel().tolist()
    return msg


def big_endian(msg: Odometry) -> bytes:
    """An independent XCDR1 big-endian writer for Odometry (alignment from the header's end)."""
    out = bytearray(b"\x00\x00\x00\x00")

    def pad(n: int) -> None:
        out.extend(b"\x00" * ((-(len(out) - 4)) % n))

    def string(s: str) -> None:
        pad(4)
        out.extend(struct.pack(">I", len(s.encode()) + 1) + s.encode() + b"\x00")

    pad(4)
    out.extend(struct.pack(">iI", msg.header.stamp.sec, msg.header.stamp.nanosec))
    string(msg.header.frame_id)
    string(msg.child_frame_id)
    pad(8)
    p, o = msg.pose.pose.position, msg.pose.pose.orientation
    t = msg.twist.twist
    out.extend(struct.pack(">7d", p.x, p.y, p.z, o.x, o.y, o.z, o.w))
    out.extend(struct.pack(">36d", *msg.pose.covariance))
    out.extend(
        struct.pack(
            ">6d", t.linear.x, t.linear.y, t.linear.z, t.angular.x, t.angular.y, t.angular.z
        )
    )
    out.extend(struct.pack(">36d", *msg.twist.covariance))
    return bytes(out)


def _fields_of(msg: Odometry):
    p, o, v = msg.pose.pose.position, msg.pose.pose.orientation, msg.twist.twist.linear
    return (msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec, msg.header.frame_id,
            msg.child_frame_id, (p.x, p.y, p.z), (o.x, o.y, o.z, o.w), (v.x, v.y, v.z),
            tuple(msg.pose.covariance), tuple(msg.twist.covariance))


@pytest.mark.parametrize(
    "frame, child",
    [("map", "base_link"), ("", ""), ("odom", "robot_7/base_footprint"), ("ü", "x" * 13)],
)
def test_both_byte_orders_decode_to_what_rclpy_reads(frame, child) -> None:
    msg = odometry(p=(1e6 + 0.1, -3.5, 2.0), q=(0.1, 0.2, 0.3, math.sqrt(1 - 0.14)),
                   v=(1.5, -0.25, 0.125), stamp=(-5, 999_999_999), frame=frame, child=child)
    le = serialize_message(msg)
    assert tuple(decode_odometry(le)) == _fields_of(deserialize_message(le, Odometry))
    assert tuple(decode_odometry(big_endian(msg))) == _fields_of(msg)


def test_every_truncation_is_a_cdr_error() -> None:
    for data in (serialize_message(odometry()), big_endian(odometry(frame="a_long_frame_name"))):
        for cut in range(len(data) - 1):
            with pytest.raises(CdrError):
                odometry_batch(data[:cut], SOURCE)
        assert len(odometry_batch(data, SOURCE)) == 1


@settings(
    max_examples=examples(300, 1500), deadline=None, suppress_health_check=[HealthCheck.too_slow]
)
@given(
    st.binary(max_size=900)
    | st.builds(lambda data, k, b: data[: k % len(data)] + bytes([b]) + data[k % len(data) + 1 :],
                st.sampled_from([serialize_message(odometry()), big_endian(odometry())]),
                st.integers(0, 10_000), st.integers(0, 255))
)
def test_garbage_is_a_result_or_cdr_error(data: bytes) -> None:
    try:
        batch = odometry_batch(data, SOURCE)
    except CdrError:
        return
    assert len(batch) == 1 and batch.ids == ["robot_1"]


def _rotation_reference(q, v):
    """R(q) v with the rotation matrix of the normalised quaternion, in 60-digit arithmetic."""
    mpmath.mp.dps = 60
    x, y, z, w = (mpmath.mpf(c) for c in q)
    n = mpmath.sqrt(x * x + y * y + z * z + w * w)
    x, y, z, w = x / n, y / n, z / n, w / n
    m = [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
         [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
         [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]
    return [float(sum(m[i][j] * mpmath.mpf(v[j]) for j in range(3))) for i in range(3)]


def test_velocity_is_rotated_into_the_header_frame() -> None:
    s = math.sqrt(0.5)
    yaw90 = odometry_batch(
        serialize_message(odometry(q=(0.0, 0.0, s, s), v=(2.0, 0.0, 0.0))), SOURCE
    )
    assert yaw90.velocity[0].tolist() == pytest.approx([0.0, 2.0, 0.0], abs=1e-15)
    assert yaw90.acceleration.tolist() == [[0.0, 0.0, 0.0]]
    assert yaw90.position.tolist() == [[1.0, 2.0, 0.0]] and yaw90.radius.tolist() == [0.4]
    assert yaw90.frames == ["map"] and yaw90.stamp_ns.tolist() == [1_700_000_000 * 10**9 + 5]
    rng = np.random.default_rng(5)
    for _ in range(200):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        q *= 1.0 + rng.uniform(-9e-4, 9e-4)  # within the tolerance: normalised
        v = rng.uniform(-5, 5, 3)
        got = odometry_batch(serialize_message(odometry(q=tuple(q), v=tuple(v))), SOURCE).velocity[
            0
        ]
        assert got.tolist() == pytest.approx(_rotation_reference(q, v), rel=1e-14, abs=1e-14)


@pytest.mark.parametrize(
    "q, words",
    [
        ((0.0, 0.0, 0.0, 0.0), "zero or not finite"),
        ((math.nan, 0.0, 0.0, 1.0), "zero or not finite"),
        ((0.0, 0.0, math.inf, 1.0), "zero or not finite"),
        ((0.0, 0.0, 0.0, 2.0), "not a unit quaternion (norm 2"),
        ((0.0, 0.0, 0.0, 1.0011), "not a unit quaternion"),
    ],
)
def test_bad_quaternions_are_refused(q, words) -> None:
    with pytest.raises(OdometryError, match=r"pose\.orientation") as info:
        odometry_batch(serialize_message(odometry(q=q)), SOURCE)
    assert words in str(info.value)


def test_ids_and_radii_from_topics() -> None:
    assert body_id_of_topic("/robot_1/odom") == "robot_1"
    assert body_id_of_topic("/fleet/r2/odom") == "fleet/r2"
    assert body_id_of_topic("/odom") == "odom"
    sources = odometry_sources(["/a/odom", "/b/odom"], 0.5, [])
    assert sources == {"/a/odom": OdometrySource("a", 0.5), "/b/odom": OdometrySource("b", 0.5)}
    assert odometry_sources(["/a/odom", "/b/odom"], 0.5, [1.0, 2.0])["/b/odom"].radius == 2.0
    with pytest.raises(ValueError, match="odometry_radii has 1 entries for 2"):
        odometry_sources(["/a/odom", "/b/odom"], 0.5, [1.0])
    with pytest.raises(ValueError, match="same body id 'a'"):
        odometry_sources(["/a/odom", "/a/odometry"], 0.5, [])


def test_covariance_position_block_and_rotated_twist_block() -> None:
    """pose.covariance's x/y/z block as is (header frame); twist.covariance's linear
    block rotated into the header frame (R S R^T, R from an independent mpmath rotation about z
    by the yaw); no cross terms."""
    yaw = 0.7
    q = (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))
    msg = odometry(q=q)
    pose = np.zeros((6, 6))
    pose[:3, :3] = [[0.04, 0.01, 0.0], [0.01, 0.09, 0.0], [0.0, 0.0, 0.01]]
    pose[3:, 3:] = np.eye(3) * 5.0  # orientation variances: not used
    twist = np.zeros((6, 6))
    twist[:3, :3] = [[0.25, 0.0, 0.0], [0.0, 0.01, 0.0], [0.0, 0.0, 0.0]]  # along the body's x
    twist[3:, 3:] = np.eye(3) * 7.0  # angular rates: not used
    msg.pose.covariance, msg.twist.covariance = pose.ravel().tolist(), twist.ravel().tolist()
    batch = odometry_batch(serialize_message(msg), SOURCE)
    got = batch.covariance[0].reshape(6, 6)
    assert batch.covariance_size.tolist() == [36]
    assert np.array_equal(got[:3, :3], pose[:3, :3])
    assert not got[:3, 3:].any() and not got[3:, :3].any()
    c, s_ = mpmath.cos(mpmath.mpf(yaw)), mpmath.sin(mpmath.mpf(yaw))
    rot = mpmath.matrix([[c, -s_, 0], [s_, c, 0], [0, 0, 1]])
    want = rot * mpmath.matrix(twist[:3, :3].tolist()) * rot.T
    for i in range(3):
        for j in range(3):
            assert abs(got[3 + i, 3 + j] - float(want[i, j])) <= 1e-15
    assert np.array_equal(got[3:, 3:], got[3:, 3:].T)  # exactly symmetric
    # the velocity's main uncertainty now lies along the rotated body x axis
    w, v = np.linalg.eigh(got[3:5, 3:5])
    assert abs(abs(v[:, 1] @ [math.cos(yaw), math.sin(yaw)]) - 1.0) < 1e-12


def test_zero_covariance_is_exact_and_bad_blocks_name_their_field() -> None:
    msg = odometry()
    msg.pose.covariance, msg.twist.covariance = [0.0] * 36, [0.0] * 36
    assert odometry_batch(serialize_message(msg), SOURCE).covariance is None
    for field, values, reason in [
        ("pose", np.diag([1.0, -1.0, 1.0, 0, 0, 0]), "not positive semi-definite"),
        ("twist", np.triu(np.ones((6, 6))), "not symmetric"),
        ("pose", np.diag([math.nan, 1.0, 1.0, 0, 0, 0]), "not finite"),
    ]:
        msg = odometry()
        msg.pose.covariance, msg.twist.covariance = [0.0] * 36, [0.0] * 36
        getattr(msg, field).covariance = values.ravel().tolist()
        with pytest.raises(OdometryError, match=rf"{field}\.covariance .*{reason}"):
            odometry_batch(serialize_message(msg), SOURCE)
