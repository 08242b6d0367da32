"""The node's static world: map and polygon inputs, indexed off the prediction path.

Sources (2-D only; node parameters):

- ``map_topic``: ``nav_msgs/OccupancyGrid``, subscribed transient-local as map servers
  publish, so a map published before the node started arrives too. A new map replaces the
  old one. Occupied: value >= ``map_occupied_threshold``; unknown (-1) is free unless
  ``map_unknown_is_occupied``. The grid's origin pose (with a rotation about z) is honoured.
- ``polygon_topics``: ``geometry_msgs/PolygonStamped``, one obstacle per topic, named by the
  topic's namespace (as odometry names robots); an empty polygon removes it.
- ``static_polygons``: keep-out zones from the parameters, named.

Bytes are decoded by the bounds-checked decoders of ``pipeline.static_inputs``; a message
whose frame is not the scene's, or that cannot be used, is rejected with a warning naming
the topic and the reason, and the world keeps its previous state.

Each accepted change numbers a new version of the obstacles; one worker thread builds its
index (the map's boundary and the grid: the slow part), and the executor applies the
newest finished index between predictions (a guard condition), then publishes. So no
prediction waits for indexing, and a prediction uses exactly one complete world. While
recording, each applied version is recorded (``<node>/static_applied``), so replay applies
the same world at the same point.
"""
from __future__ import annotations

import functools
import json
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
from geometry_msgs.msg import PolygonStamped
from nav_msgs.msg import OccupancyGrid
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from circle_collision_ros.core.static import GridFrame, StaticIndex, occupied_cells
from circle_collision_ros.pipeline.cdr import CdrError
from circle_collision_ros.pipeline.static_inputs import (
    decode_occupancy_grid,
    decode_polygon_stamped,
    obstacle_name,
)
from circle_collision_ros.pipeline.static_scene import StaticObstacles, build_index

__all__ = ["StaticInputs", "StaticSettings", "parse_static_polygons"]


@dataclass(frozen=True)
class StaticSettings:
    """The static parameters of the node."""

    map_topic: str = ""
    map_occupied_threshold: int = 65
    map_unknown_is_occupied: bool = False
    polygon_topics: tuple = ()
    static_polygons: str = ""

    @property
    def used(self) -> bool:
        return bool(self.map_topic or self.polygon_topics or self.static_polygons.strip())


def parse_static_polygons(text: str) -> dict:
    """``{"name": [[x, y], ...], ...}`` (JSON) -> name -> (n, 2) array; ValueError naming
    what is wrong.  Empty text: none."""
    if not text.strip():
        return {}
    try:
        value = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ValueError(f"static_polygons is not JSON ({exc.msg} at character {exc.pos}); "
                         'expected {"name": [[x, y], [x, y], [x, y]], ...}') from None
    if not isinstance(value, dict):
        raise ValueError("static_polygons must be a JSON object of name: [[x, y], ...]")
    out = {}
    for name, points in value.items():
        try:
            arr = np.array(points, dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError(f"static_polygons[{name!r}]: not a list of [x, y] numbers") from None
        if arr.ndim != 2 or arr.shape[1] != 2:
            raise ValueError(f"static_polygons[{name!r}]: expected [[x, y], ...], got shape "
                             f"{arr.shape}")
        out[name] = arr
    return out


class StaticInputs:
    """Subscriptions, the obstacles, and the off-path index of one node."""

    MAP_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                         reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)

    def __init__(self, node: Node, settings: StaticSettings, frame: Callable[[], str],
                 adopt_frame: Callable[[str], None], apply: Callable[[StaticIndex | None, int],
                                                                    None],
                 warn: Callable[[str, str], None],
                 record: Callable[[str, bytes], None] | None = None) -> None:
        """``frame()``: the scene's frame ("" before one is known; ``adopt_frame`` sets it);
        ``apply(index, version)`` runs on the executor with each newest finished index;
        ``record(topic, data)`` keeps every received message as received."""
        self.settings = settings
        self._frame = frame
        self._adopt_frame = adopt_frame
        self._apply = apply
        self._warn = warn
        self._record = record or (lambda topic, data: None)
        self.obstacles = StaticObstacles()
        for name, vertices in parse_static_polygons(settings.static_polygons).items():
            try:
                self.obstacles.set_polygon(name, vertices)
            except ValueError as exc:
                raise ValueError(f"static_polygons[{name!r}]: {exc}") from None
        self.rejected = 0
        self.applied_version = 0
        self.index_s_last = 0.0
        self._lock = threading.Lock()
        self._pending: tuple | None = None  # (version, index or exception, seconds)
        self._worker = ThreadPoolExecutor(1, thread_name_prefix="static_index")
        self._guard = node.create_guard_condition(self._on_index_ready)
        self.topics: list[tuple[str, type]] = []
        if settings.map_topic:
            topic = node.resolve_topic_name(settings.map_topic)
            node.create_subscription(OccupancyGrid, topic, functools.partial(self._on_map, topic),
                                     self.MAP_QOS, raw=True)
            self.topics.append((topic, OccupancyGrid))
        for t in settings.polygon_topics:
            topic = node.resolve_topic_name(t)
            node.create_subscription(PolygonStamped, topic,
                                     functools.partial(self._on_polygon, topic),
                                     QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                                                reliability=ReliabilityPolicy.RELIABLE), raw=True)
            self.topics.append((topic, PolygonStamped))
        if self.obstacles.version:  # the parameters' polygons: indexed before any input
            self._apply(build_index(self.obstacles.world()), self.obstacles.version)
            self.applied_version = self.obstacles.version

    # -- inputs ---------------------------------------------------------------------------------
    def _check_frame(self, topic: str, frame_id: str) -> bool:
        scene = self._frame()
        if not scene:
            self._adopt_frame(frame_id)
            return True
        if frame_id != scene:
            self.rejected += 1
            self._warn(f"static_frame:{topic}",
                       f"{topic}: frame '{frame_id}' is not the scene frame '{scene}' (no tf); "
                       "message ignored")
            return False
        return True

    def on_map_bytes(self, topic: str, data: bytes) -> bool:
        """Decode, check and take one map; False (with a warning) if rejected."""
        try:
            msg = decode_occupancy_grid(data)
            occupied = occupied_cells(msg.data, msg.width, msg.height,
                                      self.settings.map_occupied_threshold,
                                      self.settings.map_unknown_is_occupied)
            frame = GridFrame(msg.resolution, msg.origin_x, msg.origin_y, msg.yaw)
        except (CdrError, ValueError) as exc:
            self.rejected += 1
            self._warn(f"static_map:{topic}", f"{topic}: map rejected: {exc}")
            return False
        if not self._check_frame(topic, msg.frame_id):
            return False
        self.obstacles.set_map(occupied, frame)
        return True

    def on_polygon_bytes(self, topic: str, data: bytes) -> bool:
        """Decode, check and take one polygon; False (with a warning) if rejected."""
        name = obstacle_name(topic)
        try:
            msg = decode_polygon_stamped(data)
            if not self._check_frame(topic, msg.frame_id):
                return False
            self.obstacles.set_polygon(name, msg.vertices)
        except (CdrError, ValueError) as exc:
            self.rejected += 1
            self._warn(f"static_polygon:{topic}", f"{topic}: polygon rejected: {exc}")
            return False
        return True

    def _on_map(self, topic: str, data: bytes) -> None:
        self._record(topic, data)
        if self.on_map_bytes(topic, data):
            self._rebuild()

    def _on_polygon(self, topic: str, data: bytes) -> None:
        self._record(topic, data)
        version = self.obstacles.version
        if self.on_polygon_bytes(topic, data) and self.obstacles.version != version:
            self._rebuild()

    # -- indexing off the prediction path ------------------------------------------------------
    def _rebuild(self) -> None:
        # the worker gets its own copy of the obstacles: callbacks keep changing them
        snapshot = StaticObstacles(self.obstacles.occupancy, dict(self.obstacles.polygons),
                                   self.obstacles.version)
        future = self._worker.submit(_timed_build, snapshot)
        future.add_done_callback(functools.partial(self._on_built, snapshot.version))

    def _on_built(self, version: int, future: Future) -> None:
        try:
            result = future.result()
        except Exception as exc:  # noqa: BLE001 - reported, never fatal
            result = (exc, 0.0)
        with self._lock:
            if self._pending is None or self._pending[0] < version:
                self._pending = (version, *result)
        self._guard.trigger()

    def _on_index_ready(self) -> None:
        with self._lock:
            pending, self._pending = self._pending, None
        if pending is None or pending[0] <= self.applied_version:
            return  # an older build finished after a newer one was applied
        version, index, seconds = pending
        if isinstance(index, Exception):
            self._warn("static_index", f"indexing the static world failed: {index}")
            return
        self.applied_version = version
        self.index_s_last = seconds
        self._apply(index, version)

    def wait_idle(self, timeout: float = 10.0) -> None:
        """Tests: wait until every submitted build finished (not until applied)."""
        self._worker.submit(lambda: None).result(timeout)

    def close(self) -> None:
        self._worker.shutdown(wait=False, cancel_futures=True)


def _timed_build(obstacles: StaticObstacles) -> tuple:
    started = time.perf_counter()
    index = build_index(obstacles.world())
    return index, time.perf_counter() - started
