"""A scene's prediction as published: rows, message objects, or CDR bytes.

One row generator feeds both the message builder (service, tests) and the CDR
encoder (the node's publications), so the two can never disagree.

Guarantee: nothing published is NaN. Contacts carry finite times and details;
NO_CONTACT entries carry time +inf and zeros elsewhere, as the message
definition documents.
"""
from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point, Vector3
from std_msgs.msg import Header

from circle_collision_msgs.msg import CollisionPrediction, CollisionPredictionArray
from circle_collision_ros.pipeline.body_registry import SceneSnapshot
from circle_collision_ros.pipeline.cdr_codec import encode_prediction_array


class ReportAll:
    """`report_all_pairs` lists every pair only up to this many bodies (N^2/2 messages)."""

    MAX_BODIES = 100


def split_ns(ns: int) -> tuple[int, int]:
    """(sec, nanosec) of a time in ns, as builtin_interfaces/Time holds it."""
    return divmod(ns, 1_000_000_000)


def ns_to_time(ns: int) -> Time:
    sec, nanosec = split_ns(ns)
    return Time(sec=sec, nanosec=nanosec)


_ZERO3 = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class ScenePrediction:
    """What one prediction found: the scene snapshot and its contacts (a core PairPredictions)."""

    snapshot: SceneSnapshot
    pairs: object
    horizon: float
    frame_id: str
    report_all_pairs: bool

    def rows(self) -> Iterator[tuple]:
        """(id_a, id_b, status, ttc, (sec, nanosec), point, normal, closing_speed) per entry.

        Contacts come sorted by time as the core returns them; with
        report_all_pairs (and at most ReportAll.MAX_BODIES bodies) every other
        pair follows as NO_CONTACT in index order.
        """
        snap, pairs = self.snapshot, self.pairs
        ids = snap.ids
        i, j = pairs.i, pairs.j
        gap0 = np.linalg.norm(snap.positions[i] - snap.positions[j], axis=1) - (snap.radii[i] + snap.radii[j])
        # The core reports only finite contacts with finite details; this mask is the
        # last line of defence behind the "never publishes NaN" guarantee.
        finite = np.isfinite(pairs.ttc) & np.isfinite(pairs.closing_speed) \
            & np.isfinite(pairs.point).all(axis=1) & np.isfinite(pairs.normal).all(axis=1)
        d = snap.positions.shape[1]
        point = np.zeros((len(pairs.ttc), 3))
        normal = np.zeros((len(pairs.ttc), 3))
        point[:, :d], normal[:, :d] = pairs.point, pairs.normal
        contact_ns = snap.reference_ns + np.round(np.where(finite, pairs.ttc, 0.0) * 1e9).astype(np.int64)
        overlapping = (pairs.ttc == 0.0) & (gap0 < 0.0)
        for k in np.flatnonzero(finite).tolist():
            status = CollisionPrediction.OVERLAPPING if overlapping[k] else CollisionPrediction.CONTACT
            yield (ids[i[k]], ids[j[k]], status, float(pairs.ttc[k]), split_ns(int(contact_ns[k])),
                   tuple(point[k].tolist()), tuple(normal[k].tolist()), float(pairs.closing_speed[k]))
        if self.report_all_pairs and len(ids) <= ReportAll.MAX_BODIES:
            in_contact = set(zip(i.tolist(), j.tolist()))
            for a in range(len(ids)):
                for b in range(a + 1, len(ids)):
                    if (a, b) not in in_contact:
                        yield (ids[a], ids[b], CollisionPrediction.NO_CONTACT, math.inf, (0, 0),
                               _ZERO3, _ZERO3, 0.0)

    @property
    def stamp(self) -> tuple[int, int]:
        return split_ns(self.snapshot.reference_ns)

    def to_message(self) -> CollisionPredictionArray:
        """As a message object (service responses, tests)."""
        predictions = [
            CollisionPrediction(id_a=a, id_b=b, status=status, time_to_collision=ttc,
                                contact_time=Time(sec=t[0], nanosec=t[1]),
                                contact_point=Point(x=p[0], y=p[1], z=p[2]),
                                normal=Vector3(x=n[0], y=n[1], z=n[2]), closing_speed=closing)
            for a, b, status, ttc, t, p, n, closing in self.rows()]
        sec, nanosec = self.stamp
        return CollisionPredictionArray(header=Header(stamp=Time(sec=sec, nanosec=nanosec),
                                                      frame_id=self.frame_id),
                                        horizon=float(self.horizon), predictions=predictions)

    def to_cdr(self) -> bytes:
        """As serialized bytes, without building message objects (the node's path)."""
        rows = ((a.encode(), b.encode(), *rest) for a, b, *rest in self.rows())
        return encode_prediction_array(self.stamp, self.frame_id, float(self.horizon), rows)
