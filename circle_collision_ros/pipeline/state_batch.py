"""A batch of received circle states as arrays: the form the node works on.

Building Python message objects costs ~30 us per CircleState in rclpy, which
alone would exceed the latency budget at 1,000 bodies; the node therefore
decodes the received CDR bytes straight into a StateBatch (state_codec), and
message objects (service requests, tests) are converted with from_messages.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from circle_collision_msgs.msg import CircleState


@dataclass(frozen=True)
class StateBatch:
    """N states: ids, frames (own header's, else the array's), stamps in ns, SI arrays.

    ids, frames : sequences of str, never changed once in a batch (the decoders give tuples,
        which a stream's next messages may share: state_codec.StateDecoder).

    covariance : (N, 36) row-major 6x6 over (x, y, z, vx, vy, vz), zeros where a
        state gave none; covariance_size : (N,) how many values each state gave
        (0 or 36 are valid; validation rejects the rest). Both None when no
        state of the batch gave any (the common, exact case costs nothing).
    """

    ids: Sequence[str]
    frames: Sequence[str]
    stamp_ns: np.ndarray      # (N,) int64
    radius: np.ndarray        # (N,) float64, m
    position: np.ndarray      # (N, 3) m
    velocity: np.ndarray      # (N, 3) m/s
    acceleration: np.ndarray  # (N, 3) m/s^2
    remove: np.ndarray        # (N,) bool
    covariance: np.ndarray | None = None       # (N, 36) float64
    covariance_size: np.ndarray | None = None  # (N,) int64

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
            ids=tuple(s.id for s in states),
            frames=tuple(s.header.frame_id or array_frame for s in states),
            stamp_ns=np.array([s.header.stamp.sec * 1_000_000_000 + s.header.stamp.nanosec
                               for s in states], dtype=np.int64),
            radius=np.array([s.radius for s in states], dtype=np.float64),
            position=vectors[:, 0:3], velocity=vectors[:, 3:6], acceleration=vectors[:, 6:9],
            remove=np.array([s.remove for s in states], dtype=bool),
            **covariance_columns([s.covariance for s in states]))

    def select(self, rows: np.ndarray) -> "StateBatch":
        """The states at `rows` (an index array), in that order."""
        index = rows.tolist()
        given = self.covariance is not None
        return StateBatch(ids=tuple(self.ids[k] for k in index),
                          frames=tuple(self.frames[k] for k in index),
                          stamp_ns=self.stamp_ns[rows], radius=self.radius[rows],
                          position=self.position[rows], velocity=self.velocity[rows],
                          acceleration=self.acceleration[rows], remove=self.remove[rows],
                          covariance=self.covariance[rows] if given else None,
                          covariance_size=self.covariance_size[rows] if given else None)


#: Indices into the 6x6 covariance of the rows/columns a D-dimensional scene uses.
USED_COVARIANCE_AXES = {2: (0, 1, 3, 4), 3: (0, 1, 2, 3, 4, 5)}


def covariance_block(covariance: np.ndarray, dimensions: int) -> np.ndarray:
    """(N, 36) row-major 6x6 covariances -> (N, 2D, 2D) over (position, velocity) of used axes."""
    axes = np.array(USED_COVARIANCE_AXES[dimensions])
    return covariance.reshape(-1, 6, 6)[:, axes[:, None], axes[None, :]]


def covariance_columns(values: Sequence[Sequence[float]]) -> dict:
    """StateBatch's covariance fields from per-state value lists (any lengths)."""
    sizes = np.fromiter(map(len, values), dtype=np.int64, count=len(values))
    if not sizes.any():
        return {"covariance": None, "covariance_size": None}
    cov = np.zeros((len(values), 36))
    for k in np.flatnonzero(sizes == 36).tolist():
        cov[k] = values[k]
    return {"covariance": cov, "covariance_size": sizes}
