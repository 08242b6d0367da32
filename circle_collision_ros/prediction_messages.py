"""Core prediction results to circle_collision_msgs messages.

Guarantee: nothing published here is NaN. Contacts carry finite times and
details; NO_CONTACT entries carry time +inf and zeros elsewhere (as the message
definition documents).
"""
from __future__ import annotations

import math

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point, Vector3
from std_msgs.msg import Header

from circle_collision_msgs.msg import CollisionPrediction, CollisionPredictionArray
from circle_collision_ros.body_registry import SceneSnapshot


class ReportAll:
    """`report_all_pairs` lists every pair only up to this many bodies (N^2/2 messages)."""

    MAX_BODIES = 100


def ns_to_time(ns: int) -> Time:
    sec, nanosec = divmod(ns, 1_000_000_000)
    return Time(sec=sec, nanosec=nanosec)


def _vec3(values: np.ndarray) -> tuple[float, float, float]:
    """(D,) -> three floats, z = 0 in 2-D."""
    return (float(values[0]), float(values[1]), float(values[2]) if values.shape[0] > 2 else 0.0)


def build_prediction_array(snapshot: SceneSnapshot, pairs, horizon: float, frame_id: str,
                           report_all_pairs: bool) -> CollisionPredictionArray:
    """Message for `pairs` (a core PairPredictions for `snapshot`'s bodies).

    Contacts come sorted by time as the core returns them; with
    `report_all_pairs` (and at most ReportAll.MAX_BODIES bodies) every other
    pair follows as NO_CONTACT in index order.
    """
    ids = snapshot.ids
    out = CollisionPredictionArray(header=Header(stamp=ns_to_time(snapshot.reference_ns),
                                                 frame_id=frame_id),
                                   horizon=float(horizon))
    gap0 = np.linalg.norm(snapshot.positions[pairs.i] - snapshot.positions[pairs.j], axis=1) \
        - (snapshot.radii[pairs.i] + snapshot.radii[pairs.j])
    # The core reports only finite contacts with finite details; this mask is the
    # last line of defence behind the "never publishes NaN" guarantee.
    finite = np.isfinite(pairs.ttc) & np.isfinite(pairs.closing_speed) \
        & np.isfinite(pairs.point).all(axis=1) & np.isfinite(pairs.normal).all(axis=1)
    predictions = []
    for k in np.flatnonzero(finite).tolist():
        ttc = float(pairs.ttc[k])
        status = CollisionPrediction.OVERLAPPING if (ttc == 0.0 and gap0[k] < 0.0) \
            else CollisionPrediction.CONTACT
        px, py, pz = _vec3(pairs.point[k])
        nx, ny, nz = _vec3(pairs.normal[k])
        predictions.append(CollisionPrediction(
            id_a=ids[pairs.i[k]], id_b=ids[pairs.j[k]], status=status, time_to_collision=ttc,
            contact_time=ns_to_time(snapshot.reference_ns + int(round(ttc * 1e9))),
            contact_point=Point(x=px, y=py, z=pz), normal=Vector3(x=nx, y=ny, z=nz),
            closing_speed=float(pairs.closing_speed[k])))
    if report_all_pairs and len(ids) <= ReportAll.MAX_BODIES:
        in_contact = set(zip(pairs.i.tolist(), pairs.j.tolist()))
        for a in range(len(ids)):
            for b in range(a + 1, len(ids)):
                if (a, b) not in in_contact:
                    predictions.append(CollisionPrediction(
                        id_a=ids[a], id_b=ids[b], status=CollisionPrediction.NO_CONTACT,
                        time_to_collision=math.inf))
    out.predictions = predictions
    return out
