"""Builders and checks shared by the node tests."""
from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point, Vector3
from std_msgs.msg import Header

from circle_collision_msgs.msg import CircleState, CircleStateArray, CollisionPredictionArray
from tests.scene_rule import rule_contacts

BASE_NS = 1_700_000_000 * 1_000_000_000


def ns_time(ns: int) -> Time:
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def state(body_id: str, p, v=(0.0, 0.0, 0.0), a=(0.0, 0.0, 0.0), r: float = 0.5,
          stamp_ns: int = BASE_NS, frame: str = "map", remove: bool = False) -> CircleState:
    return CircleState(
        header=Header(stamp=ns_time(stamp_ns), frame_id=frame),
        id=body_id,
        radius=r,
        position=Point(x=float(p[0]), y=float(p[1]), z=float(p[2]) if len(p) > 2 else 0.0),
        velocity=Vector3(x=float(v[0]), y=float(v[1]), z=float(v[2]) if len(v) > 2 else 0.0),
        acceleration=Vector3(x=float(a[0]), y=float(a[1]), z=float(a[2]) if len(a) > 2 else 0.0),
        remove=remove,
    )


def state_array(states: Sequence[CircleState], frame: str = "map") -> CircleStateArray:
    return CircleStateArray(
        header=Header(stamp=states[0].header.stamp if states else Time(), frame_id=frame),
        circles=list(states),
    )


def random_states(
    n: int, seed: int, stamp_ns: int = BASE_NS, spread: float = 20.0, dimensions: int = 2
) -> list[CircleState]:
    rng = np.random.default_rng(seed)
    out = []
    for k in range(n):
        p, v, a = rng.uniform(-spread, spread, 3), rng.uniform(-3, 3, 3), rng.uniform(-0.5, 0.5, 3)
        if dimensions == 2:
            p[2] = v[2] = a[2] = 0.0
        out.append(
            state(f"b{k:03d}", p, v, a, r=float(rng.uniform(0.3, 2.0)),
                  stamp_ns=stamp_ns - int(rng.integers(0, 50_000_000)))
        )
    return out


def expected_contacts(
    states: Sequence[CircleState], horizon: float, dimensions: int = 2
) -> dict[tuple[str, str], float]:
    """Ground truth the node must match: the scene's published rule on every pair
    (tests/scene_rule.py; states with the newest stamp are propagated to it, pairs
    with older stamps are evaluated at their pair time and shifted)."""
    T = np.array(
        [s.header.stamp.sec * 10**9 + s.header.stamp.nanosec for s in states], dtype=np.int64
    )
    P = np.array([[s.position.x, s.position.y, s.position.z] for s in states]).reshape(-1, 3)
    V = np.array([[s.velocity.x, s.velocity.y, s.velocity.z] for s in states]).reshape(-1, 3)
    A = np.array([[s.acceleration.x, s.acceleration.y, s.acceleration.z] for s in states]).reshape(
        -1, 3
    )
    R = np.array([s.radius for s in states])
    d = dimensions
    return rule_contacts([s.id for s in states], P[:, :d], V[:, :d], A[:, :d], R, T, horizon)


def contacts_of(msg: CollisionPredictionArray) -> dict[tuple[str, str], float]:
    return {(p.id_a, p.id_b): p.time_to_collision for p in msg.predictions if p.status != 0}


def assert_no_nan(msg: CollisionPredictionArray) -> None:
    for p in msg.predictions:
        values = [p.time_to_collision, p.closing_speed, p.contact_point.x, p.contact_point.y,
                  p.contact_point.z, p.normal.x, p.normal.y, p.normal.z]
        assert not any(math.isnan(x) for x in values), p
