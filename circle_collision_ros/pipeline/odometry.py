"""nav_msgs/Odometry as an input: one robot per topic, decoded from CDR bytes.

A fleet that already publishes each robot's Odometry needs no message of ours
(`odometry_topics`). Each message becomes a one-state StateBatch, the same form
CircleState bytes decode to, so it takes the same intake path (validation,
frame check, latest-by-stamp merge, recording, replay):

- id: the topic's namespace (`/robot_1/odom` -> `robot_1`, `/fleet/r2/odom` ->
  `fleet/r2`); a topic at the root (`/odom`) gives its own name (`odom`). The
  id is fixed by the configuration, not by the message: `child_frame_id` is
  `base_link` on most robots and would merge a fleet into one body.
- radius: `odometry_radius`, or the topic's entry of `odometry_radii`.
- position: `pose.pose.position`; stamp and frame: the message header.
- velocity: `twist.twist.linear`, which REP-105 gives in the `child_frame_id`
  (body) frame, rotated by `pose.pose.orientation` into `header.frame_id`.
  Acceleration: zero (Odometry has none).
- covariance: the position block (x, y, z rows and columns) of
  `pose.covariance`, which is in header.frame_id like the pose; the linear
  block of `twist.covariance`, which is in child_frame_id like the twist,
  rotated into header.frame_id as R S R^T by the same orientation; no cross
  terms (Odometry carries none). Each block must be finite, symmetric and PSD
  (core.uncertainty.covariance_problem), else the message is rejected naming
  the field. Both blocks zero (most drivers) is an exact state.
- orientation: a quaternion whose norm is within QuaternionRule.TOLERANCE of 1
  is normalised (float32 round trips and integration drift stay usable); zero,
  non-finite or further from unit is rejected as a whole message (OdometryError):
  its velocity direction would be a guess.

Decoding follows pipeline/cdr.py's rules (XCDR1, both byte orders, every read
bounds-checked, strings NUL-terminated inside the buffer); untrusted bytes
never reach rclpy's deserializer.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from circle_collision_ros.core.uncertainty.covariance import covariance_problem
from circle_collision_ros.pipeline.cdr import (CDR_BE, CDR_LE, ORIGIN, CdrError, align, read_string,
                                               read_u32)
from circle_collision_ros.pipeline.state_batch import StateBatch

ODOMETRY_TYPE = "nav_msgs/msg/Odometry"
# After child_frame_id (8-aligned): pose (position 3, orientation 4), covariance 36,
# twist (linear 3, angular 3), covariance 36: 85 float64, fixed-size arrays without a length.
_DOUBLES = 85
_POSITION, _ORIENTATION, _LINEAR = slice(0, 3), slice(3, 7), slice(43, 46)
_POSE_COVARIANCE, _TWIST_COVARIANCE = slice(7, 43), slice(49, 85)


class OdometryError(CdrError):
    """An Odometry message that decodes but cannot be used (bad orientation)."""


class QuaternionRule:
    """|1 - norm| at most TOLERANCE is normalised; beyond, or zero/non-finite, is rejected."""

    TOLERANCE = 1e-3


class OdometryFields(NamedTuple):
    """What the node uses of one Odometry message."""

    stamp_ns: int
    frame_id: str
    child_frame_id: str
    position: tuple[float, float, float]
    orientation: tuple[float, float, float, float]  # x, y, z, w as received
    linear: tuple[float, float, float]  # m/s in child_frame_id
    # 6x6 row-major (x, y, z, rot x, rot y, rot z)
    pose_covariance: tuple[float, ...] = (0.0,) * 36
    twist_covariance: tuple[float, ...] = (0.0,) * 36  # 6x6 row-major, in child_frame_id


@dataclass(frozen=True)
class OdometrySource:
    """How one Odometry topic becomes one body."""

    body_id: str
    radius: float


def decode_odometry(data: bytes) -> OdometryFields:
    """The used fields of serialized nav_msgs/Odometry bytes.

    Raises
    ------
    CdrError
        If the bytes are not well-formed Odometry CDR (either byte order).
    """
    if len(data) < ORIGIN + 8 or bytes(data[:2]) not in (CDR_LE, CDR_BE):
        raise CdrError(
            f"not plain CDR Odometry (encapsulation {bytes(data[:2]).hex() or 'missing'}, "
            f"{len(data)} bytes)"
        )
    be = bytes(data[:2]) == CDR_BE
    buf = np.frombuffer(data, dtype=np.uint8)
    sec = int(read_u32(buf, ORIGIN, be))
    sec = sec - 2**32 if sec >= 2**31 else sec  # int32
    nanosec = int(read_u32(buf, ORIGIN + 4, be))
    frame_off, frame_len, pos = read_string(buf, ORIGIN + 8, be)
    if frame_off < 0:
        raise CdrError("truncated or malformed Odometry header.frame_id")
    child_off, child_len, pos = read_string(buf, pos, be)
    if child_off < 0:
        raise CdrError("truncated or malformed Odometry child_frame_id")
    pos = int(align(pos, 8))
    if pos + 8 * _DOUBLES > len(data):
        raise CdrError(
            f"truncated Odometry: pose and twist need {8 * _DOUBLES} bytes at {pos}, "
            f"{len(data) - pos} remain"
        )
    values = np.frombuffer(data, dtype=">f8" if be else "<f8", count=_DOUBLES, offset=pos).tolist()
    try:
        frame = bytes(data[frame_off : frame_off + frame_len]).decode()
        child = bytes(data[child_off : child_off + child_len]).decode()
    except UnicodeDecodeError as exc:
        raise CdrError(f"an Odometry frame id is not UTF-8 ({exc.reason})") from exc
    return OdometryFields(sec * 1_000_000_000 + nanosec, frame, child, tuple(values[_POSITION]),
                          tuple(values[_ORIENTATION]), tuple(values[_LINEAR]),
                          tuple(values[_POSE_COVARIANCE]), tuple(values[_TWIST_COVARIANCE]))


def unit_quaternion(q: tuple[float, float, float, float], field: str = "pose.orientation",
                    error: type[CdrError] = OdometryError) -> tuple[float, float, float, float]:
    """q normalised, under QuaternionRule; raises ``error`` naming ``field`` and the problem
    (an OccupancyGrid's origin takes the same rule)."""
    norm = math.sqrt(sum(c * c for c in q)) if all(math.isfinite(c) for c in q) else math.nan
    if not math.isfinite(norm) or norm == 0.0:
        raise error(f"{field} {q} is zero or not finite")
    if abs(norm - 1.0) > QuaternionRule.TOLERANCE:
        raise error(
            f"{field} {q} is not a unit quaternion (norm {norm:.6g}; "
            f"accepted within {QuaternionRule.TOLERANCE:g} of 1)"
        )
    return q[0] / norm, q[1] / norm, q[2] / norm, q[3] / norm


def rotate(
    q: tuple[float, float, float, float], v: tuple[float, float, float]
) -> tuple[float, float, float]:
    """v rotated by the unit quaternion q = (x, y, z, w): v + 2w (u x v) + 2 u x (u x v)."""
    x, y, z, w = q
    tx, ty, tz = (2.0 * (y * v[2] - z * v[1]), 2.0 * (z * v[0] - x * v[2]),
                  2.0 * (x * v[1] - y * v[0]))
    return (v[0] + w * tx + (y * tz - z * ty), v[1] + w * ty + (z * tx - x * tz),
            v[2] + w * tz + (x * ty - y * tx))


def rotation_matrix(q: tuple[float, float, float, float]) -> np.ndarray:
    """3x3 matrix of the unit quaternion q = (x, y, z, w): R v = rotate(q, v)."""
    x, y, z, w = q
    return np.array(
        [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
         [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
         [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]
    )


def odometry_covariance(
    odom: OdometryFields, q: tuple[float, float, float, float]
) -> np.ndarray | None:
    """(36,) row-major 6x6 covariance of (position, velocity) in header.frame_id, or None if exact.

    Raises OdometryError naming the field whose block is not finite/symmetric/PSD.
    """
    pose = np.array(odom.pose_covariance).reshape(6, 6)[:3, :3]
    twist = np.array(odom.twist_covariance).reshape(6, 6)[:3, :3]
    if not pose.any() and not twist.any():
        return None
    for field, block in (("pose.covariance", pose), ("twist.covariance", twist)):
        problem = covariance_problem(block)
        if problem:
            raise OdometryError(f"{field} (x, y, z block) {problem.removeprefix('covariance ')}")
    rot = rotation_matrix(q)
    velocity = rot @ twist @ rot.T
    out = np.zeros((6, 6))
    out[:3, :3] = pose
    out[3:, 3:] = 0.5 * (velocity + velocity.T)  # exactly symmetric after rounding
    return out.reshape(36)


def odometry_batch(data: bytes, source: OdometrySource) -> StateBatch:
    """A one-state StateBatch from Odometry bytes (see the module docstring for the rules).

    Raises
    ------
    CdrError
        Malformed bytes; OdometryError (a CdrError) for an unusable orientation.
    """
    odom = decode_odometry(data)
    q = unit_quaternion(odom.orientation)
    velocity = rotate(q, odom.linear)
    covariance = odometry_covariance(odom, q)
    return StateBatch(
        ids=[source.body_id],
        frames=[odom.frame_id],
        stamp_ns=np.array([odom.stamp_ns], dtype=np.int64),
        radius=np.array([source.radius], dtype=np.float64),
        position=np.array([odom.position], dtype=np.float64),
        velocity=np.array([velocity], dtype=np.float64),
        acceleration=np.zeros((1, 3), dtype=np.float64),
        remove=np.zeros(1, dtype=bool),
        covariance=None if covariance is None else covariance[None, :],
        covariance_size=None if covariance is None else np.array([36], dtype=np.int64),
    )


def body_id_of_topic(resolved_topic: str) -> str:
    """The body id of an Odometry topic: its namespace, or its name at the root."""
    namespace, _, name = resolved_topic.strip("/").rpartition("/")
    return namespace or name


def odometry_sources(
    resolved_topics: list[str], radius: float, radii: list[float]
) -> dict[str, OdometrySource]:
    """Topic -> OdometrySource for the node's odometry parameters.

    Raises
    ------
    ValueError
        odometry_radii neither empty nor one per topic, or two topics giving one id.
    """
    if radii and len(radii) != len(resolved_topics):
        raise ValueError(
            f"odometry_radii has {len(radii)} entries for {len(resolved_topics)} "
            "odometry_topics (give none, or one per topic)"
        )
    sources: dict[str, OdometrySource] = {}
    seen: dict[str, str] = {}
    for k, topic in enumerate(resolved_topics):
        body_id = body_id_of_topic(topic)
        if body_id in seen:
            raise ValueError(
                f"odometry_topics {seen[body_id]} and {topic} give the same body id "
                f"'{body_id}' (the id is the topic's namespace)"
            )
        seen[body_id] = topic
        sources[topic] = OdometrySource(body_id, float(radii[k]) if radii else float(radius))
    return sources
