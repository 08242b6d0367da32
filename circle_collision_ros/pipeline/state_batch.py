"""A batch of received circle states as arrays: the form the node works on.

Building Python message objects costs ~30 us per CircleState in rclpy, which
alone would exceed the latency budget at 1,000 bodies; the node therefore
decodes the received CDR bytes straight into a StateBatch (cdr_codec), and
message objects (service requests, tests) are converted with from_messages.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from circle_collision_msgs.msg import CircleState


@dataclass(frozen=True)
class StateBatch:
    """N states: ids, frames (own header's, else the array's), stamps in ns, SI arrays."""

    ids: list[str]
    frames: list[str]
    stamp_ns: np.ndarray      # (N,) int64
    radius: np.ndarray        # (N,) float64, m
    position: np.ndarray      # (N, 3) m
    velocity: np.ndarray      # (N, 3) m/s
    acceleration: np.ndarray  # (N, 3) m/s^2
    remove: np.ndarray        # (N,) bool

    def __len__(self) -> int:
        return len(self.ids)

    @staticmethod
    def from_messages(states: Sequence[CircleState], array_frame: str = "") -> "StateBatch":
        n = len(states)
        vectors = np.array([(s.position.x, s.position.y, s.position.z,
                             s.velocity.x, s.velocity.y, s.velocity.z,
                             s.acceleration.x, s.acceleration.y, s.acceleration.z) for s in states],
                           dtype=np.float64).reshape(n, 9)
        return StateBatch(
            ids=[s.id for s in states],
            frames=[s.header.frame_id or array_frame for s in states],
            stamp_ns=np.array([s.header.stamp.sec * 1_000_000_000 + s.header.stamp.nanosec
                               for s in states], dtype=np.int64),
            radius=np.array([s.radius for s in states], dtype=np.float64),
            position=vectors[:, 0:3], velocity=vectors[:, 3:6], acceleration=vectors[:, 6:9],
            remove=np.array([s.remove for s in states], dtype=bool))
