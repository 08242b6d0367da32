"""demo_scene: publishes a synthetic, reproducible scene of moving circles.

N bodies move with constant accelerations inside a square area; a body that
leaves the area is re-seeded (same id, new state) at a random point on the
border heading inwards. The motion is a pure function of `seed` and the tick
count, so the same parameters give the same scene; only the header stamps come
from the clock. In 2-D the area sits in a room (`room`): walls on `map`
(OccupancyGrid, transient local) a few metres outside it, and a crate on
`crate/polygon` (PolygonStamped). `bad_fraction` > 0 mixes in malformed states (for tests and
recordings of the node's input checks).
"""
from __future__ import annotations

import math
import sys
from typing import Any, NamedTuple

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point, Point32, PolygonStamped, Vector3
from nav_msgs.msg import OccupancyGrid
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Header

from circle_collision_msgs.msg import CircleState, CircleStateArray
from circle_collision_ros.cli import parse_args, spin_node


class BadInput:
    """Malformed-state classes, applied in turn when `bad_fraction` > 0."""

    KINDS = ("nan_position", "negative_radius", "empty_id", "wrong_frame", "zero_stamp",
             "inf_velocity")

    @staticmethod
    def apply(kind: str, state: CircleState) -> None:
        if kind == "nan_position":
            state.position.x = math.nan
        elif kind == "negative_radius":
            state.radius = -1.0
        elif kind == "empty_id":
            state.id = ""
        elif kind == "wrong_frame":
            state.header.frame_id = "some_other_frame"
        elif kind == "zero_stamp":
            state.header.stamp = Time()
        elif kind == "inf_velocity":
            state.velocity.y = math.inf


class SyntheticScene:
    """The demo's motion model, ROS-free: arrays of N bodies in a square of `size` m."""

    def __init__(self, count: int, size: float, dimensions: int, seed: int, max_speed: float = 3.0,
                 max_accel: float = 0.5, radius_range: tuple[float, float] = (0.3, 2.0)) -> None:
        self.rng = np.random.default_rng(seed)
        self.count, self.size, self.dimensions = count, size, dimensions
        self.max_speed, self.max_accel, self.radius_range = max_speed, max_accel, radius_range
        self.radii = self.rng.uniform(*radius_range, count)
        self.p = self.rng.uniform(0.0, size, (count, 3))
        self.v = self._random_vectors(count, max_speed)
        self.a = self._random_vectors(count, max_accel)
        if dimensions == 2:
            self.p[:, 2] = self.v[:, 2] = self.a[:, 2] = 0.0

    def _random_vectors(self, n: int, max_norm: float) -> np.ndarray:
        d = self.rng.normal(size=(n, 3))
        if self.dimensions == 2:
            d[:, 2] = 0.0
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        return d * self.rng.uniform(0.0, max_norm, (n, 1))

    def step(self, dt: float) -> None:
        """Advance by dt s (exact for constant acceleration), then re-seed leavers."""
        self.p += dt * (self.v + 0.5 * dt * self.a)
        self.v += dt * self.a
        speed = np.linalg.norm(self.v, axis=1, keepdims=True)
        too_fast = speed[:, 0] > self.max_speed  # keep accelerating bodies plausible
        self.v[too_fast] *= self.max_speed / speed[too_fast]
        out = (
            np.any((self.p < 0.0) | (self.p > self.size), axis=1)
            if self.dimensions == 3
            else np.any((self.p[:, :2] < 0.0) | (self.p[:, :2] > self.size), axis=1)
        )
        for k in np.flatnonzero(out):
            self._reseed(k)

    def _reseed(self, k: int) -> None:
        self.p[k] = self.rng.uniform(0.0, self.size, 3)
        axis = int(self.rng.integers(0, 2))
        self.p[k, axis] = 0.0 if self.rng.random() < 0.5 else self.size
        toward_centre = np.full(3, self.size / 2.0) - self.p[k]
        if self.dimensions == 2:
            toward_centre[2] = 0.0
            self.p[k, 2] = 0.0
        toward_centre /= np.linalg.norm(toward_centre)
        self.v[k] = toward_centre * self.rng.uniform(0.2, 1.0) * self.max_speed
        self.a[k] = self._random_vectors(1, self.max_accel)[0]


class DemoParam(NamedTuple):
    """One demo_scene parameter: name, default, meaning (shown by --help)."""

    name: str
    default: Any
    meaning: str


DEMO_PARAMS: tuple[DemoParam, ...] = (
    DemoParam("count", 40, "number of bodies"),
    DemoParam("area_size", 60.0, "side of the square area in m"),
    DemoParam("dimensions", 2, "2: circles in the plane, 3: spheres"),
    DemoParam("seed", 1, "random seed: the same seed gives the same motion"),
    DemoParam("rate", 30.0, "messages per second (Hz)"),
    DemoParam("frame_id", "map", "frame of every state"),
    DemoParam("topic", "circle_states", "CircleStateArray topic to publish on"),
    DemoParam(
        "bad_fraction", 0.0, "fraction of states made malformed (0..1), to exercise input checks"
    ),
    DemoParam("room", True, "2-D: also publish the room (walls on 'map', a crate polygon)"),
)


class Room:
    """The demo's static world around the area [0, size]^2 (2-D): an occupancy grid of border
    walls ``MARGIN`` m outside it with a partition wall, and a crate polygon in the middle."""

    RESOLUTION = 0.25  # m per cell (dyadic: cell corners are exact)
    MARGIN = 4.0  # m from the area's edge to the inner face of the walls
    THICKNESS = 1.0  # m

    def __init__(self, size: float) -> None:
        self.size = size

    def grid(self, stamp: Time, frame_id: str) -> OccupancyGrid:
        res, margin, wall = self.RESOLUTION, self.MARGIN, self.THICKNESS
        n = int(math.ceil((self.size + 2.0 * (margin + wall)) / res))
        k = int(round(wall / res))
        data = np.zeros((n, n), np.int8)
        data[:k, :] = data[-k:, :] = data[:, :k] = data[:, -k:] = 100
        # a partition wall from the north wall, a third of the way across, two thirds long
        col = n // 3
        data[n - (2 * n) // 3:, col:col + k] = 100
        msg = OccupancyGrid()
        msg.header = Header(stamp=stamp, frame_id=frame_id)
        msg.info.resolution = res
        msg.info.width = msg.info.height = n
        msg.info.origin.position.x = msg.info.origin.position.y = -(margin + wall)
        msg.info.origin.orientation.w = 1.0
        msg.data = data.ravel().tolist()
        return msg

    def crate(self, stamp: Time, frame_id: str) -> PolygonStamped:
        c, h = 0.6 * self.size, 0.06 * self.size
        msg = PolygonStamped()
        msg.header = Header(stamp=stamp, frame_id=frame_id)
        msg.polygon.points = [Point32(x=float(x), y=float(y), z=0.0) for x, y in
                              ((c - h, c - h), (c + h, c - h), (c + h, c + h), (c - h, c + h))]
        return msg


def _help_epilog() -> str:
    rows = "\n".join(f"  {p.name:<13} {p.default!r:<16} {p.meaning}" for p in DEMO_PARAMS)
    return (
        "ROS parameters (set after --ros-args with -p name:=value):\n"
        f"  {'name':<13} {'default':<16} meaning\n{rows}\n\n"
        "Example: demo_scene --ros-args -p count:=200 -p rate:=10.0"
    )


class DemoScenePublisher(Node):
    """Publishes SyntheticScene as CircleStateArray on `topic` at `rate` Hz."""

    def __init__(self) -> None:
        super().__init__("demo_scene")
        for param in DEMO_PARAMS:
            self.declare_parameter(param.name, param.default)
        g = lambda name: self.get_parameter(name).value  # noqa: E731
        self.scene = SyntheticScene(g("count"), g("area_size"), g("dimensions"), g("seed"))
        self.frame_id, self.rate, self.bad_fraction = g("frame_id"), g("rate"), g("bad_fraction")
        self._bad_rng = np.random.default_rng(g("seed") + 1)
        self._bad_kind = 0
        self.publisher = self.create_publisher(
            CircleStateArray,
            g("topic"),
            QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE),
        )
        self.ticks = 0
        self.create_timer(1.0 / self.rate, self._tick)
        self.room = Room(g("area_size")) if g("room") and g("dimensions") == 2 else None
        if self.room is not None:
            # the map transient local, as map servers publish it; the crate resent each second
            # (polygon subscriptions are volatile, so they match any publisher)
            latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                                 durability=DurabilityPolicy.TRANSIENT_LOCAL)
            self.map_publisher = self.create_publisher(OccupancyGrid, "map", latched)
            self.map_publisher.publish(self.room.grid(self.get_clock().now().to_msg(),
                                                      self.frame_id))
            self.crate_publisher = self.create_publisher(
                PolygonStamped, "crate/polygon",
                QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE))
            self.create_timer(1.0, self._publish_crate)
        # One line, so whoever started the demo knows what to subscribe to.
        self.get_logger().info(
            f"publishing {self.scene.count} {self.scene.dimensions}-D bodies as "
            "CircleStateArray on "
            f"{self.publisher.topic_name} (frame '{self.frame_id}') at {self.rate:g} Hz"
        )

    def _publish_crate(self) -> None:
        self.crate_publisher.publish(self.room.crate(self.get_clock().now().to_msg(),
                                                     self.frame_id))

    def _tick(self) -> None:
        if self.ticks:
            self.scene.step(1.0 / self.rate)
        self.ticks += 1
        stamp = self.get_clock().now().to_msg()
        s = self.scene
        circles = []
        for k in range(s.count):
            circles.append(
                CircleState(
                    header=Header(stamp=stamp, frame_id=self.frame_id),
                    id=f"body_{k:04d}",
                    radius=float(s.radii[k]),
                    position=Point(x=float(s.p[k, 0]), y=float(s.p[k, 1]), z=float(s.p[k, 2])),
                    velocity=Vector3(x=float(s.v[k, 0]), y=float(s.v[k, 1]), z=float(s.v[k, 2])),
                    acceleration=Vector3(
                        x=float(s.a[k, 0]), y=float(s.a[k, 1]), z=float(s.a[k, 2])
                    ),
                )
            )
            if self.bad_fraction > 0.0 and self._bad_rng.random() < self.bad_fraction:
                BadInput.apply(BadInput.KINDS[self._bad_kind % len(BadInput.KINDS)], circles[-1])
                self._bad_kind += 1
        self.publisher.publish(
            CircleStateArray(header=Header(stamp=stamp, frame_id=self.frame_id), circles=circles)
        )


def main(args: list[str] | None = None) -> int:
    argv = sys.argv if args is None else args
    parse_args(argv, __doc__.splitlines()[0], epilog=_help_epilog())
    return spin_node(DemoScenePublisher, argv, "demo_scene")


if __name__ == "__main__":
    sys.exit(main())
