"""The node's static obstacles, the world they build, and their rows in a prediction.

``StaticObstacles`` keeps the named obstacles as they arrive (the occupancy map, polygons
from topics, keep-out zones from parameters) and numbers each change (``version``);
``build_index`` turns one such state into a ``core.static.StaticIndex``, which is the slow
part (a 4000 x 4000 map: its boundary and grid), so the node runs it off the prediction
path and hands the finished index to ``CollisionPredictor.set_static`` between predictions.

``StaticCache.rows`` answers every body of a scene against an index, evaluating only the
bodies that changed: the rows of ``collision_predictions`` for contacts with static
geometry (id_a the body, id_b the obstacle's name).  Bodies with covariance are evaluated
on their mean state.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from circle_collision_ros.core.scene.store import propagate_ns
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
           "StaticRows", "StaticCache", "build_index", "STATIC_TYPES"]

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


class StaticCache:
    """Static rows of a scene, recomputed only for the bodies that changed.

    The rule is the scene's pair rule for one body (docs/scene.md, "The prediction rule"):
    a body's stored state at its stamp ``T`` is evaluated at its body time
    ``t_b = max(E, T)`` (E the epoch of the reference time R, S the slack), propagated by
    the scene's formula, over ``H + S``, giving ``tau``.  With ``d = R - t_b`` it reports
    ``ttc = tau - d`` when ``tau > d`` (``tau`` itself when ``t_b == R``); a contact that
    began before R (``tau <= d``) is evaluated again at R over H.  So a body's answer is a
    pure function of its stored state, R, H, S and the world: a body whose state, body time
    and world are unchanged keeps its ``tau``, and incremental, full and replayed
    predictions agree bit for bit.
    """

    def __init__(self) -> None:
        self._ids = np.empty(0, dtype=object)
        self._id_list: list = []
        # (index, H + S): a change of either recomputes all; the index itself is held (an
        # id() could be reused by a new index once the old one is freed)
        self._key: tuple | None = None
        self._state = np.empty((0, 8))  # T, t_b, p(2), v(2), a(2)... as float64 for compare
        self._radius = np.empty(0)
        self._tau = np.empty(0)
        self._ob = np.empty(0, np.int32)
        self._kind = np.empty(0, np.int8)
        self._point = np.empty((0, 2))
        self._normal = np.empty((0, 2))
        self._speed = np.empty(0)
        self.evaluated = 0  # bodies evaluated by the last call (diagnostics, tests)

    def rows(self, states: tuple, reference_ns: int, epoch_ns: int, slack_s: float,
             horizon: float, index: StaticIndex) -> StaticRows:
        """``states`` = ``Scene.stored_states()`` (ids sorted); rows by (time, body id)."""
        ids, P, V, A, Rad, T = states
        n = len(ids)
        if n == 0:
            self.__init__()
            return _empty_rows()
        tb = np.maximum(np.int64(epoch_ns), T)
        state = np.empty((n, 8))
        state[:, 0] = T
        state[:, 1] = tb
        state[:, 2:4], state[:, 4:6], state[:, 6:8] = P[:, :2], V[:, :2], A[:, :2]
        key = (index, horizon + slack_s)
        ids_arr = np.array(ids, dtype=object)
        dirty = np.ones(n, bool)
        keep = np.zeros(n, np.int64)
        if (self._key is not None and self._key[0] is index and self._key[1] == key[1]
                and len(self._ids)):
            if ids == self._id_list:  # the same bodies (tracker frames): rows align
                pos = np.arange(n)
                same = (self._state == state).all(axis=1) & (self._radius == Rad)
            else:
                pos = np.searchsorted(self._ids, ids_arr)
                pos = np.minimum(pos, len(self._ids) - 1)
                same = ((self._ids[pos] == ids_arr) & (self._state[pos] == state).all(axis=1)
                        & (self._radius[pos] == Rad))
            dirty = ~same
            keep = pos
        tau = np.empty(n)
        ob = np.empty(n, np.int32)
        kind = np.empty(n, np.int8)
        point = np.empty((n, 2))
        normal = np.empty((n, 2))
        speed = np.empty(n)
        old = ~dirty
        if old.any():
            k = keep[old]
            tau[old], ob[old], kind[old] = self._tau[k], self._ob[k], self._kind[k]
            point[old], normal[old], speed[old] = self._point[k], self._normal[k], self._speed[k]
        rows = np.flatnonzero(dirty)
        self.evaluated = len(rows)
        if len(rows):
            p, v = propagate_ns(P[rows, :2], V[rows, :2], A[rows, :2], tb[rows] - T[rows])
            c = time_to_static(p, v, A[rows, :2], Rad[rows], index, horizon + slack_s)
            tau[rows], ob[rows], kind[rows] = c.time, c.obstacle, c.kind
            point[rows], normal[rows], speed[rows] = c.point, c.normal, c.closing_speed
            # an inside row's point is the centre at its body time
            inside = c.kind == KIND_INSIDE
            point[rows[inside]] = p[inside]
        self._ids, self._key, self._state, self._radius = ids_arr, key, state, Rad.copy()
        self._id_list = list(ids)
        self._tau, self._ob, self._kind = tau, ob, kind
        self._point, self._normal, self._speed = point, normal, speed

        d = (reference_ns - tb).astype(np.float64) * 1e-9
        ttc = np.where(tb == reference_ns, tau, tau - d)
        contact_ns = tb + np.round(np.where(np.isfinite(tau), tau, 0.0) * 1e9).astype(np.int64)
        kind_r, ob_r = kind.copy(), ob.copy()
        point_r, normal_r, speed_r = point.copy(), normal.copy(), speed.copy()
        past = np.flatnonzero((tb != reference_ns) & (tau <= d))
        if len(past):  # contacts that began before R: evaluated at R over H
            p, v = propagate_ns(P[past, :2], V[past, :2], A[past, :2], reference_ns - T[past])
            c = time_to_static(p, v, A[past, :2], Rad[past], index, horizon)
            ttc[past], ob_r[past], kind_r[past] = c.time, c.obstacle, c.kind
            point_r[past], normal_r[past], speed_r[past] = c.point, c.normal, c.closing_speed
            inside = c.kind == KIND_INSIDE
            point_r[past[inside]] = p[inside]
            contact_ns[past] = reference_ns + np.round(
                np.where(np.isfinite(c.time), c.time, 0.0) * 1e9).astype(np.int64)
        hit = np.flatnonzero(ttc <= horizon)  # NaN and inf rows are no contact
        if hit.size == 0:
            return _empty_rows()
        # ids are sorted, so a stable sort on the time orders by (time, id)
        k = hit[np.argsort(ttc[hit], kind="stable")]
        inside = kind_r[k] == KIND_INSIDE
        m = len(k)
        out_point = np.zeros((m, 3))
        out_normal = np.zeros((m, 3))
        out_point[:, :2] = point_r[k]
        out_normal[:, :2] = np.where(inside[:, None], 0.0, normal_r[k])
        closing = np.where(inside, 0.0, speed_r[k])
        names = index.world.names
        return StaticRows([ids[j] for j in k.tolist()], [names[o] for o in ob_r[k].tolist()],
                          ttc[k] == 0.0, ttc[k], contact_ns[k], out_point, out_normal, closing)


def _empty_rows() -> StaticRows:
    z = np.zeros(0)
    return StaticRows([], [], np.zeros(0, bool), z, np.zeros(0, np.int64), np.zeros((0, 3)),
                      np.zeros((0, 3)), z.copy())
