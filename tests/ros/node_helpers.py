"""Builders and checks shared by the node tests."""
from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point, Vector3
from std_msgs.msg import Header

from circle_collision_msgs.msg import CircleState, CircleStateArray, CollisionPredictionArray
from circle_collision_ros.core import time_to_collision

BASE_NS = 1_700_000_000 * 1_000_000_000


def ns_time(ns: int) -> Time:
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def state(body_id: str, p, v=(0.0, 0.0, 0.0), a=(0.0, 0.0, 0.0), r: float = 0.5,
          stamp_ns: int = BASE_NS, frame: str = "map", remove: bool = False) -> CircleState:
    return CircleState(header=Header(stamp=ns_time(stamp_ns), frame_id=frame), id=body_id,
                       radius=r, position=Point(x=float(p[0]), y=float(p[1]), z=float(p[2]) if len(p) > 2 else 0.0),
                       velocity=Vector3(x=float(v[0]), y=float(v[1]), z=float(v[2]) if len(v) > 2 else 0.0),
                       acceleration=Vector3(x=float(a[0]), y=float(a[1]), z=float(a[2]) if len(a) > 2 else 0.0),
                       remove=remove)


def state_array(states: Sequence[CircleState], frame: str = "map") -> CircleStateArray:
    return CircleStateArray(header=Header(stamp=states[0].header.stamp if states else Time(),
                                          frame_id=frame), circles=list(states))


def random_states(n: int, seed: int, stamp_ns: int = BASE_NS, spread: float = 20.0,
                  dimensions: int = 2) -> list[CircleState]:
    rng = np.random.default_rng(seed)
    out = []
    for k in range(n):
        p, v, a = rng.uniform(-spread, spread, 3), rng.uniform(-3, 3, 3), rng.uniform(-0.5, 0.5, 3)
        if dimensions == 2:
            p[2] = v[2] = a[2] = 0.0
        out.append(state(f"b{k:03d}", p, v, a, r=float(rng.uniform(0.3, 2.0)),
                         stamp_ns=stamp_ns - int(rng.integers(0, 50_000_000))))
    return out


def expected_contacts(states: Sequence[CircleState], horizon: float,
                      dimensions: int = 2) -> dict[tuple[str, str], float]:
    """Ground truth the node must match: every pair through the core narrow phase.

    States are propagated to the newest stamp (the node's documented reference
    time) with the same exact formula, then each pair is solved on its own.
    """
    ref = max(s.header.stamp.sec * 10**9 + s.header.stamp.nanosec for s in states)
    ids = sorted(s.id for s in states)
    by_id = {s.id: s for s in states}
    P, V, A, R = [], [], [], []
    for body in ids:
        s = by_id[body]
        dt = float(ref - (s.header.stamp.sec * 10**9 + s.header.stamp.nanosec)) * 1e-9
        p = np.array([s.position.x, s.position.y, s.position.z])
        v = np.array([s.velocity.x, s.velocity.y, s.velocity.z])
        a = np.array([s.acceleration.x, s.acceleration.y, s.acceleration.z])
        P.append(p + dt * (v + (0.5 * dt) * a))
        V.append(v + dt * a)
        A.append(a)
        R.append(s.radius)
    P, V, A, R = (np.array(x) for x in (P, V, A, R))
    P, V, A = P[:, :dimensions], V[:, :dimensions], A[:, :dimensions]
    out = {}
    for i in range(len(ids)):
        for j in range(i + 1, len(ids)):
            t = float(time_to_collision(P[i], V[i], A[i], R[i], P[j], V[j], A[j], R[j], horizon))
            if math.isfinite(t):
                out[(ids[i], ids[j])] = t
    return out


def contacts_of(msg: CollisionPredictionArray) -> dict[tuple[str, str], float]:
    return {(p.id_a, p.id_b): p.time_to_collision for p in msg.predictions if p.status != 0}


def assert_no_nan(msg: CollisionPredictionArray) -> None:
    for p in msg.predictions:
        values = [p.time_to_collision, p.closing_speed, p.contact_point.x, p.contact_point.y,
                  p.contact_point.z, p.normal.x, p.normal.y, p.normal.z]
        assert not any(math.isnan(x) for x in values), p
