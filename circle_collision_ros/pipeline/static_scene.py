"""The node's static obstacles, the world they build, and their rows in a prediction.

``StaticObstacles`` keeps the named obstacles as they arrive (the occupancy map, polygons
from topics, keep-out zones from parameters) and numbers each change (``version``);
``build_index`` turns one such state into a ``core.static.StaticIndex``, which is the slow
part (a 4000 x 4000 map: its boundary and grid), so the node runs it off the prediction
path and hands the finished index to ``CollisionPredictor.set_static`` between predictions.

``static_rows`` answers every body of a snapshot against an index: the rows of
``collision_predictions`` for contacts with static geometry (id_a the body, id_b the
obstacle's name).  Bodies with covariance are evaluated on their mean state.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from circle_collision_ros.core.scene import SceneSnapshot
from circle_collision_ros.core.static import (
    GridFrame,
    OccupancyMap,
    Polygon,
    StaticIndex,
    StaticWorld,
    occupied_cells,
    time_to_static,
)
from circle_collision_ros.core.static.query import KIND_INSIDE
from circle_collision_ros.pipeline.cdr import CdrError
from circle_collision_ros.pipeline.static_inputs import (
    OCCUPANCY_GRID_TYPE,
    POLYGON_STAMPED_TYPE,
    decode_occupancy_grid,
    decode_polygon_stamped,
    obstacle_name,
)

__all__ = ["MAP_NAME", "StaticSettings", "parse_static_polygons", "StaticObstacles", "Taken",
           "StaticRows", "build_index", "static_rows", "STATIC_TYPES"]

#: id_b of contacts with the occupancy map.
MAP_NAME = "map"
#: The message types of static inputs (rosbag2 names).
STATIC_TYPES = (OCCUPANCY_GRID_TYPE, POLYGON_STAMPED_TYPE)


@dataclass(frozen=True)
class StaticSettings:
    """The node's static parameters (recorded with its configuration, for replay)."""

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


class Taken(NamedTuple):
    """Outcome of one static message: ``reason`` is "" when accepted; ``frame_id`` is the
    message's frame (the scene adopts it when it has none yet)."""

    reason: str
    frame_id: str


@dataclass
class StaticObstacles:
    """Named obstacles by source; ``version`` counts changes (0: none yet)."""

    occupancy: OccupancyMap | None = None
    polygons: dict = field(default_factory=dict)  # name -> (n, 2) float64 vertices
    version: int = 0

    def set_map(self, occupied: np.ndarray, frame: GridFrame) -> None:
        """A new map replaces the old one."""
        self.occupancy = OccupancyMap(MAP_NAME, occupied, frame)
        self.version += 1

    def set_polygon(self, name: str, vertices: np.ndarray) -> None:
        """Add or replace polygon ``name``; no vertices removes it (a no-op if absent)."""
        if name == MAP_NAME:
            raise ValueError(f"a polygon cannot be named {MAP_NAME!r}: that names the map")
        if len(vertices) == 0:
            if self.polygons.pop(name, None) is None:
                return
        else:
            StaticWorld.build([Polygon(name, vertices)])  # validates, with its message
            self.polygons[name] = np.array(vertices, dtype=np.float64)
        self.version += 1

    @classmethod
    def from_settings(cls, settings: StaticSettings) -> "StaticObstacles":
        """The keep-out zones of the parameters, one version each; ValueError naming a bad one."""
        out = cls()
        for name, vertices in parse_static_polygons(settings.static_polygons).items():
            try:
                out.set_polygon(name, vertices)
            except ValueError as exc:
                raise ValueError(f"static_polygons[{name!r}]: {exc}") from None
        return out

    def copy(self) -> "StaticObstacles":
        """A copy that later changes leave alone (the map's arrays are never modified)."""
        return StaticObstacles(self.occupancy, dict(self.polygons), self.version)

    def take(self, type_name: str, topic: str, data: bytes, settings: StaticSettings,
             scene_frame: str) -> Taken:
        """Decode, check and apply one map or polygon message as received on ``topic``.

        The node and replay share this, so both number the versions alike.  A message in
        another frame than ``scene_frame`` (when set) or that cannot be used changes nothing.
        """
        try:
            if type_name == OCCUPANCY_GRID_TYPE:
                msg = decode_occupancy_grid(data)
                occupied = occupied_cells(msg.data, msg.width, msg.height,
                                          settings.map_occupied_threshold,
                                          settings.map_unknown_is_occupied)
                frame = GridFrame(msg.resolution, msg.origin_x, msg.origin_y, msg.yaw)
            elif type_name == POLYGON_STAMPED_TYPE:
                msg = decode_polygon_stamped(data)
            else:
                raise ValueError(f"not a static input type: {type_name}")
        except (CdrError, ValueError) as exc:
            return Taken(f"{topic}: rejected: {exc}", "")
        if scene_frame and msg.frame_id != scene_frame:
            return Taken(f"{topic}: frame '{msg.frame_id}' is not the scene frame "
                         f"'{scene_frame}' (no tf); message ignored", msg.frame_id)
        try:
            if type_name == OCCUPANCY_GRID_TYPE:
                self.set_map(occupied, frame)
            else:
                self.set_polygon(obstacle_name(topic), msg.vertices)
        except ValueError as exc:
            return Taken(f"{topic}: rejected: {exc}", msg.frame_id)
        return Taken("", msg.frame_id)

    def world(self) -> StaticWorld:
        """The obstacles as one world: the map first, then polygons by name (a fixed order, so
        ties between obstacles break the same way live and in replay)."""
        obs = [self.occupancy] if self.occupancy is not None else []
        obs += [Polygon(n, self.polygons[n]) for n in sorted(self.polygons)]
        return StaticWorld.build(obs)


def build_index(world: StaticWorld) -> StaticIndex | None:
    """The index of ``world``; None for an empty world (predictions then skip static work)."""
    return None if world.empty else StaticIndex.build(world)


class StaticRows(NamedTuple):
    """Contacts with static geometry, sorted by (time, body id); arrays of K rows."""

    id_a: list  # body ids
    id_b: list  # obstacle names
    overlapping: np.ndarray  # (K,) bool
    ttc: np.ndarray  # (K,) s from the reference time
    contact_ns: np.ndarray  # (K,) int64
    point: np.ndarray  # (K, 3) m
    normal: np.ndarray  # (K, 3) unit (zero for a centre inside a solid)
    closing_speed: np.ndarray  # (K,) m/s

    def __len__(self) -> int:
        return len(self.id_a)


def static_rows(snapshot: SceneSnapshot, index: StaticIndex, horizon: float) -> StaticRows:
    """Every body of ``snapshot`` (2-D) against ``index`` over [0, horizon].

    A centre that starts inside a solid has no single contact point: its row carries the
    centre as the point and a zero normal and closing speed (documented in the interface
    table), never NaN.
    """
    n = len(snapshot.ids)
    if n == 0:
        return _empty_rows()
    p = np.ascontiguousarray(snapshot.positions[:, :2])
    v = np.ascontiguousarray(snapshot.velocities[:, :2])
    a = np.ascontiguousarray(snapshot.accelerations[:, :2])
    c = time_to_static(p, v, a, snapshot.radii, index, horizon)
    hit = np.flatnonzero(c.time <= horizon)  # NaN and inf rows are no contact
    if hit.size == 0:
        return _empty_rows()
    ids = snapshot.ids
    # the snapshot is in id order, so a stable sort on the time orders by (time, id)
    k = hit[np.argsort(c.time[hit], kind="stable")]
    ttc = c.time[k]
    inside = c.kind[k] == KIND_INSIDE
    point = np.zeros((len(k), 3))
    normal = np.zeros((len(k), 3))
    point[:, :2] = np.where(inside[:, None], p[k], c.point[k])
    normal[:, :2] = np.where(inside[:, None], 0.0, c.normal[k])
    closing = np.where(inside, 0.0, c.closing_speed[k])
    names = index.world.names
    contact_ns = snapshot.reference_ns + np.round(ttc * 1e9).astype(np.int64)
    return StaticRows([ids[j] for j in k.tolist()], [names[o] for o in c.obstacle[k].tolist()],
                      ttc == 0.0, ttc, contact_ns, point, normal, closing)


def _empty_rows() -> StaticRows:
    z = np.zeros(0)
    return StaticRows([], [], np.zeros(0, bool), z, np.zeros(0, np.int64), np.zeros((0, 3)),
                      np.zeros((0, 3)), z.copy())
