"""The static world: named obstacles as edges and corner points, with what is solid.

Three kinds of obstacle, each named (the name is what a contact reports):

* ``Polygon``: a closed simple polygon, convex or not; its inside is solid.  Vertices in
  either order (stored counter-clockwise, so the solid lies left of every edge).
* ``Segments``: bare walls of zero thickness, touched from either side.
* ``OccupancyMap``: the occupied cells of a grid, as the merged boundary edges of
  ``occupancy.boundary_edges`` (solid on their left).

Geometry is kept exactly as given, in float64 (map edges are the cell corners rounded once
to the map frame, see ``occupancy``): the contact times are exact for these coordinates.
A world is immutable; a new map or polygon builds a new world (off the prediction path),
and ``StaticIndex`` indexes it once.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple, Sequence, Union

import numpy as np

from circle_collision_ros.core.static.occupancy import GridFrame, boundary_edges

__all__ = ["Polygon", "Segments", "OccupancyMap", "Obstacle", "StaticWorld"]


class Polygon(NamedTuple):
    """A solid simple polygon: ``vertices`` (n >= 3, 2) in metres, no repeated last vertex."""

    name: str
    vertices: np.ndarray


class Segments(NamedTuple):
    """Two-sided walls: ``starts`` and ``ends`` (m, 2) in metres."""

    name: str
    starts: np.ndarray
    ends: np.ndarray


class OccupancyMap(NamedTuple):
    """Occupied cells ``occupied[iy, ix]`` (bool) of a grid placed by ``frame``."""

    name: str
    occupied: np.ndarray
    frame: GridFrame


Obstacle = Union[Polygon, Segments, OccupancyMap]


def _points(name: str, what: str, x, shape_tail: tuple) -> np.ndarray:
    a = np.asarray(x, dtype=np.float64)
    if a.ndim != 1 + len(shape_tail) or a.shape[1:] != shape_tail:
        tail = ", ".join(map(str, shape_tail))
        raise ValueError(f"obstacle {name!r}: {what} must have shape (n, {tail}), got {a.shape}")
    if not np.isfinite(a).all():
        raise ValueError(f"obstacle {name!r}: {what} has a non-finite coordinate")
    return a


def _polygon_loop(p: Polygon) -> np.ndarray:
    """The vertices counter-clockwise, validated (exact orientation from the shoelace sum
    of exact products is not needed: a simple polygon's area sign is far from rounding)."""
    v = _points(p.name, "vertices", p.vertices, (2,))
    if len(v) >= 2 and np.array_equal(v[0], v[-1]):
        v = v[:-1]
    if len(v) < 3:
        raise ValueError(f"polygon {p.name!r}: needs at least 3 distinct vertices, got {len(v)}")
    nxt = np.roll(v, -1, axis=0)
    if (np.all(v == nxt, axis=1)).any():
        raise ValueError(f"polygon {p.name!r}: two consecutive vertices are equal")
    area2 = float(np.sum(v[:, 0] * nxt[:, 1] - nxt[:, 0] * v[:, 1]))
    scale = float(np.sum(np.abs(v[:, 0] * nxt[:, 1]) + np.abs(nxt[:, 0] * v[:, 1])))
    if not abs(area2) > 1e-12 * scale:
        raise ValueError(f"polygon {p.name!r}: zero area (its vertices are collinear)")
    return v if area2 > 0 else v[::-1].copy()


@dataclass(frozen=True)
class StaticWorld:
    """Edges and points of every obstacle, flat, plus what is needed to test solidity.

    ``starts``/``ends`` (E, 2): edges; ``solid_side`` (E,): +1 = solid on the left of
    start -> end (polygon and map edges), 0 = two-sided wall; ``edge_obstacle`` (E,) and
    ``point_obstacle`` (P,): index into ``names``; ``points`` (P, 2): corner features
    (polygon vertices, wall endpoints, map boundary corners).  ``polygons``: per solid
    polygon (obstacle index, first edge, edge count); ``maps``: (obstacle index, occupied,
    frame).
    """

    names: tuple
    starts: np.ndarray
    ends: np.ndarray
    solid_side: np.ndarray
    edge_obstacle: np.ndarray
    points: np.ndarray
    point_obstacle: np.ndarray
    polygons: np.ndarray  # (K, 3) int64: obstacle, first edge, count
    maps: tuple = field(default=())

    @classmethod
    def build(cls, obstacles: Sequence[Obstacle]) -> "StaticWorld":
        """One world from named obstacles (names must be unique and non-empty)."""
        names: list = []
        starts, ends, sides, eob, pts, pob, polys, maps = [], [], [], [], [], [], [], []
        n_edges = 0
        for ob in obstacles:
            if not isinstance(ob.name, str) or not ob.name:
                raise ValueError(f"obstacle names must be non-empty strings, got {ob.name!r}")
            if ob.name in names:
                raise ValueError(f"obstacle name {ob.name!r} is used twice")
            k = len(names)
            names.append(ob.name)
            if isinstance(ob, Polygon):
                v = _polygon_loop(ob)
                s, e = v, np.roll(v, -1, axis=0)
                polys.append((k, n_edges, len(v)))
                side, p = 1, v
            elif isinstance(ob, Segments):
                s = _points(ob.name, "starts", ob.starts, (2,))
                e = _points(ob.name, "ends", ob.ends, (2,))
                if s.shape != e.shape:
                    raise ValueError(f"segments {ob.name!r}: {len(s)} starts but {len(e)} ends")
                if (np.all(s == e, axis=1)).any():
                    raise ValueError(f"segments {ob.name!r}: a segment has equal ends")
                side = 0
                p = np.unique(np.concatenate([s, e]), axis=0)
            elif isinstance(ob, OccupancyMap):
                edges = boundary_edges(ob.occupied, ob.frame)
                s, e = edges.start, edges.end
                side = 1
                p = s  # closed boundary loops: every corner starts exactly one edge
                maps.append((k, np.ascontiguousarray(ob.occupied, dtype=np.bool_), ob.frame))
            else:
                raise TypeError(f"not an obstacle: {type(ob).__name__}")
            starts.append(s)
            ends.append(e)
            sides.append(np.full(len(s), side, np.int8))
            eob.append(np.full(len(s), k, np.int32))
            pts.append(p)
            pob.append(np.full(len(p), k, np.int32))
            n_edges += len(s)

        def cat(parts, shape, dtype):
            return (np.ascontiguousarray(np.concatenate(parts), dtype=dtype) if parts
                    else np.empty(shape, dtype))

        return cls(
            names=tuple(names),
            starts=cat(starts, (0, 2), np.float64),
            ends=cat(ends, (0, 2), np.float64),
            solid_side=cat(sides, (0,), np.int8),
            edge_obstacle=cat(eob, (0,), np.int32),
            points=cat(pts, (0, 2), np.float64),
            point_obstacle=cat(pob, (0,), np.int32),
            polygons=np.array(polys, np.int64).reshape(-1, 3),
            maps=tuple(maps),
        )

    @property
    def empty(self) -> bool:
        """No geometry at all."""
        return len(self.starts) == 0 and len(self.points) == 0

    def bounds(self) -> tuple:
        """(xmin, ymin, xmax, ymax) over every edge; NaNs when empty."""
        if not len(self.starts):
            return (math.nan,) * 4
        lo = np.minimum(self.starts.min(axis=0), self.ends.min(axis=0))
        hi = np.maximum(self.starts.max(axis=0), self.ends.max(axis=0))
        return float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])
