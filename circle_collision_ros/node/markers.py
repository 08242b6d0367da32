"""RViz / Foxglove markers for the scene and its predicted contacts.

Namespaces: `bodies` (one cylinder or sphere per body, coloured by its most
urgent contact) and `contacts` (a small sphere at each predicted contact
point). Marker ids are stable: the same body or pair keeps its id for the life
of the node, so displays track them across updates. Each array starts with a
DELETEALL so bodies and contacts that disappeared do not linger.
"""
from __future__ import annotations

from builtin_interfaces.msg import Duration, Time
from geometry_msgs.msg import Point, Pose, Quaternion, Vector3
from std_msgs.msg import ColorRGBA, Header
from visualization_msgs.msg import Marker, MarkerArray

from circle_collision_msgs.msg import CollisionPrediction
from circle_collision_ros.pipeline.prediction_messages import ScenePrediction


class Urgency:
    """Colour bands by time to collision (s)."""

    CRITICAL_S = 1.0
    WARNING_S = 3.0
    CRITICAL = ColorRGBA(r=0.9, g=0.1, b=0.1, a=0.9)
    WARNING = ColorRGBA(r=1.0, g=0.55, b=0.0, a=0.8)
    NOTICE = ColorRGBA(r=0.95, g=0.85, b=0.1, a=0.7)
    CLEAR = ColorRGBA(r=0.3, g=0.6, b=0.9, a=0.5)

    @classmethod
    def colour(cls, ttc: float) -> ColorRGBA:
        if ttc < cls.CRITICAL_S:
            return cls.CRITICAL
        if ttc < cls.WARNING_S:
            return cls.WARNING
        if ttc != float("inf"):
            return cls.NOTICE
        return cls.CLEAR


class StableIds:
    """Hands out a fixed small integer per key (body id or id pair)."""

    def __init__(self) -> None:
        self._ids: dict = {}

    def __call__(self, key) -> int:
        return self._ids.setdefault(key, len(self._ids))


class MarkerBuilder:
    """Builds MarkerArrays with ids that stay stable across calls."""

    CONTACT_DIAMETER_M = 0.3
    FLAT_HEIGHT_M = 0.05

    def __init__(self, dimensions: int) -> None:
        self.dimensions = dimensions
        self._body_ids = StableIds()
        self._pair_ids = StableIds()

    def build(self, prediction: ScenePrediction) -> MarkerArray:
        snapshot = prediction.snapshot
        sec, nanosec = prediction.stamp
        header = Header(stamp=Time(sec=sec, nanosec=nanosec), frame_id=prediction.frame_id)
        soonest: dict[str, float] = {}
        contacts = [row for row in prediction.rows() if row[2] != CollisionPrediction.NO_CONTACT]
        for id_a, id_b, _, ttc, *_ in contacts:
            for body in (id_a, id_b):
                soonest[body] = min(soonest.get(body, float("inf")), ttc)
        markers = [Marker(header=header, action=Marker.DELETEALL)]
        shape = Marker.SPHERE if self.dimensions == 3 else Marker.CYLINDER
        for k, body in enumerate(snapshot.ids):
            pos = snapshot.positions[k]
            diameter = max(2.0 * float(snapshot.radii[k]), 1e-3)  # a point still shows
            markers.append(Marker(
                header=header, ns="bodies", id=self._body_ids(body), type=shape, action=Marker.ADD,
                pose=Pose(position=Point(x=float(pos[0]), y=float(pos[1]),
                                         z=float(pos[2]) if self.dimensions == 3 else 0.0),
                          orientation=Quaternion(w=1.0)),
                scale=Vector3(x=diameter, y=diameter,
                              z=diameter if self.dimensions == 3 else self.FLAT_HEIGHT_M),
                color=Urgency.colour(soonest.get(body, float("inf"))), lifetime=Duration()))
        d = self.CONTACT_DIAMETER_M
        for id_a, id_b, _, ttc, _, point, *_ in contacts:
            markers.append(Marker(
                header=header, ns="contacts", id=self._pair_ids((id_a, id_b)), type=Marker.SPHERE,
                action=Marker.ADD, pose=Pose(position=Point(x=point[0], y=point[1], z=point[2]),
                                             orientation=Quaternion(w=1.0)),
                scale=Vector3(x=d, y=d, z=d), color=Urgency.colour(ttc)))
        return MarkerArray(markers=markers)
