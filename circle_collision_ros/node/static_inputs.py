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
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor

from geometry_msgs.msg import PolygonStamped
from nav_msgs.msg import OccupancyGrid
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from visualization_msgs.msg import MarkerArray

from circle_collision_ros.core.static import StaticIndex
from circle_collision_ros.node.static_markers import static_markers
from circle_collision_ros.pipeline.static_inputs import OCCUPANCY_GRID_TYPE, POLYGON_STAMPED_TYPE
from circle_collision_ros.pipeline.static_scene import (
    StaticObstacles,
    StaticSettings,
    build_index,
)

__all__ = ["StaticInputs"]


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
        self.obstacles = StaticObstacles.from_settings(settings)
        self.rejected = 0
        self.applied_version = 0
        self.index_s_last = 0.0
        self._lock = threading.Lock()
        self._pending: tuple | None = None  # (version, index or exception, seconds)
        self._worker = ThreadPoolExecutor(1, thread_name_prefix="static_index")
        self._guard = node.create_guard_condition(self._on_index_ready)
        self._node = node
        # transient local: a display that joins later gets the current world
        self._markers_pub = node.create_publisher(MarkerArray, "~/static_markers", QoSProfile(
            history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
            durability=DurabilityPolicy.TRANSIENT_LOCAL))
        # (topic, type, callback, QoS) of each input, subscribed from configure to cleanup:
        # the world is current when the node activates, and a map is indexed once
        self._inputs: list[tuple] = []
        if settings.map_topic:
            topic = node.resolve_topic_name(settings.map_topic)
            self._inputs.append((topic, OccupancyGrid, functools.partial(self._on_map, topic),
                                 self.MAP_QOS))
        for t in settings.polygon_topics:
            topic = node.resolve_topic_name(t)
            self._inputs.append((topic, PolygonStamped,
                                 functools.partial(self._on_polygon, topic),
                                 QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                                            reliability=ReliabilityPolicy.RELIABLE)))
        self.topics = [(topic, msg_type) for topic, msg_type, _, _ in self._inputs]
        self._markers: bytes | None = None  # of the applied world (CDR), sent while active
        self._active = False
        if self.obstacles.version:  # the parameters' polygons: indexed before any input
            index, self._markers, _ = _timed_build(self.obstacles, self._frame(), node)
            self._apply(index, self.obstacles.version)
            self.applied_version = self.obstacles.version
        self._subscriptions = [
            node.create_subscription(msg_type, topic, callback, qos, raw=True)
            for topic, msg_type, callback, qos in self._inputs]

    # -- inputs ---------------------------------------------------------------------------------
    def _take(self, type_name: str, topic: str, data: bytes) -> bool:
        """One map or polygon message (pipeline.static_scene's rules); False if rejected."""
        taken = self.obstacles.take(type_name, topic, data, self.settings, self._frame())
        if taken.reason:
            self.rejected += 1
            self._warn(f"static:{topic}", taken.reason)
            return False
        if not self._frame():
            self._adopt_frame(taken.frame_id)
        return True

    def on_map_bytes(self, topic: str, data: bytes) -> bool:
        """Decode, check and take one map; False (with a warning) if rejected."""
        return self._take(OCCUPANCY_GRID_TYPE, topic, data)

    def on_polygon_bytes(self, topic: str, data: bytes) -> bool:
        """Decode, check and take one polygon; False (with a warning) if rejected."""
        return self._take(POLYGON_STAMPED_TYPE, topic, data)

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
        snapshot = self.obstacles.copy()
        future = self._worker.submit(_timed_build, snapshot, self._frame(), self._node)
        future.add_done_callback(functools.partial(self._on_built, snapshot.version))

    def _on_built(self, version: int, future: Future) -> None:
        try:
            result = future.result()
        except Exception as exc:  # noqa: BLE001 - reported, never fatal
            result = (exc, None, 0.0)
        with self._lock:
            if self._pending is None or self._pending[0] < version:
                self._pending = (version, *result)
        self._guard.trigger()

    def _on_index_ready(self) -> None:
        with self._lock:
            pending, self._pending = self._pending, None
        if pending is None or pending[0] <= self.applied_version:
            return  # an older build finished after a newer one was applied
        version, index, markers, seconds = pending
        if isinstance(index, Exception):
            self._warn("static_index", f"indexing the static world failed: {index}")
            return
        self.applied_version = version
        self.index_s_last = seconds
        self._markers = markers
        if self._active:
            self._markers_pub.publish(markers)
        self._apply(index, version)

    def activate(self) -> None:
        """The node's activation: the display gets the world the node holds, and each new
        one from now on."""
        self._active = True
        if self._markers is not None:
            self._markers_pub.publish(self._markers)

    def deactivate(self) -> None:
        """The node's deactivation: the inputs are still taken and indexed (the world stays
        current), nothing is published."""
        self._active = False

    def close(self) -> None:
        """Unsubscribe, let a build in progress finish (its guard must still exist when it
        signals), then release the guard and the marker publisher (the node's cleanup)."""
        self._active = False
        for sub in self._subscriptions:
            self._node.destroy_subscription(sub)
        self._subscriptions = []
        self._worker.shutdown(wait=True, cancel_futures=True)
        self._node.destroy_guard_condition(self._guard)
        self._node.destroy_publisher(self._markers_pub)


def _timed_build(obstacles: StaticObstacles, frame_id: str, node: Node) -> tuple:
    """(index, its markers, seconds): both built here, on the worker, so the executor only
    swaps a reference and publishes."""
    started = time.perf_counter()
    world = obstacles.world()
    index = build_index(world)
    markers = static_markers(world if not world.empty else None, frame_id,
                             node.get_clock().now().to_msg())
    return index, markers, time.perf_counter() - started
