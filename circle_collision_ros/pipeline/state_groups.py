"""Many single CircleState messages ingested as a few batches (per-body streams at scene scale).

A node fed by one CircleState stream per body takes thousands of small
messages a second; decoding and merging them one by one costs more than the
prediction. The node therefore ingests each run of single-state messages it
takes in one go as a StateGroup, and replay rebuilds the same runs from the
recording (consecutive CircleState records with one log time), so both do the
same work in the same order.

Rule: the run is split into waves, wave k holding each body's k-th state of
the run, in arrival order; waves are merged in order, then bodies are expired
once at the run's receive time. So every body's states are merged in the order
they arrived, and no batch holds an id twice (which check_batch would reject
as a duplicate). Effects across bodies within one run (which of two new ids
fills the last max_bodies place) follow wave order, identically live and in replay. A message that
is not plain little-endian CDR,
or is malformed, goes through state_codec.decode_states alone (same acceptance,
same error).
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from circle_collision_msgs.msg import CircleState
from circle_collision_ros.pipeline.cdr import CdrError
from circle_collision_ros.pipeline.predictor import CollisionPredictor, IntakeReport
from circle_collision_ros.pipeline.state_batch import StateBatch, covariance_columns
from circle_collision_ros.pipeline.state_codec import (COVARIANCE_SIZE, decode_state_row,
                                                       decode_states)


class GroupOutcome(NamedTuple):
    """Per message of the group: its report (None if undecodable) or the decoding error."""

    reports: list[IntakeReport | None]
    errors: list[CdrError | None]


def ingest_single_states(predictor: CollisionPredictor, messages: list[bytes], now_ns: int,
                         array_frame: str = "", *, uncertainty: bool = True) -> GroupOutcome:
    """Decode and merge a run of serialized CircleState messages received at `now_ns`.

    uncertainty : False for the layout before CircleState had `covariance` (replay
        of old recordings; see pipeline/cdr.py).

    Returns per message the share of the intake it caused; expiry at `now_ns`
    is reported on the first message. Raises what predictor.receive_batch raises.
    """
    rows: list[tuple] = []
    owner: list[int] = []
    errors: list[CdrError | None] = [None] * len(messages)
    for k, data in enumerate(messages):
        row = decode_state_row(data, uncertainty)
        if row is None:
            try:
                batch = decode_states(data, CircleState, uncertainty=uncertainty)
            except CdrError as exc:
                errors[k] = exc
                continue
            if len(batch) != 1:  # cannot happen for CircleState; keep the rule explicit
                errors[k] = CdrError(f"expected one CircleState, decoded {len(batch)}")
                continue
            row = (
                int(batch.stamp_ns[0]),
                batch.frames[0],
                batch.ids[0],
                (float(batch.radius[0]), *batch.position[0].tolist(), *batch.velocity[0].tolist(),
                 *batch.acceleration[0].tolist()),
                bool(batch.remove[0]),
                _covariance_values(batch),
            )
        rows.append(row)
        owner.append(k)
    reports: list[IntakeReport | None] = [
        None if errors[k] else IntakeReport() for k in range(len(messages))
    ]
    if not rows:
        return GroupOutcome(reports, errors)
    stamps = np.array([r[0] for r in rows], dtype=np.int64)
    numbers = np.array([r[3] for r in rows], dtype=np.float64).reshape(len(rows), 10)
    ids = [r[2] for r in rows]
    batch = StateBatch(ids=ids, frames=[r[1] or array_frame for r in rows], stamp_ns=stamps,
                       radius=numbers[:, 0], position=numbers[:, 1:4], velocity=numbers[:, 4:7],
                       acceleration=numbers[:, 7:10],
                       remove=np.array([r[4] for r in rows], dtype=bool),
                       **covariance_columns([r[5] for r in rows]))
    seen: dict[str, int] = {}
    wave = np.array(
        [seen.__setitem__(i, seen.get(i, -1) + 1) or seen[i] for i in ids], dtype=np.int64
    )
    for w in range(int(wave.max()) + 1):
        take = np.flatnonzero(wave == w)
        report = predictor.ingest(batch if take.size == len(batch) else batch.select(take), now_ns)
        _share(report, [owner[t] for t in take.tolist()], reports)
    expired = predictor.expire(now_ns)
    reports[owner[0]].expired = expired
    return GroupOutcome(reports, errors)


def _covariance_values(batch: StateBatch) -> tuple:
    """The state's covariance as received: () if none, its 36 values, or a wrong-length stand-in."""
    if batch.covariance is None:
        return ()
    size = int(batch.covariance_size[0])
    return tuple(batch.covariance[0].tolist()) if size == COVARIANCE_SIZE else (0.0,) * size


def _share(report: IntakeReport, owners: list[int], reports: list[IntakeReport | None]) -> None:
    """Attribute a wave's report to its messages (one state each): counts to the first message,
    each rejection to the message that carried the state (index 0 of that message)."""
    target = reports[owners[0]]
    target.accepted += report.accepted
    target.removed += report.removed
    target.ignored += report.ignored
    target.covariance_ignored += report.covariance_ignored
    for rejection in report.rejected:
        owner = owners[rejection.index] if 0 <= rejection.index < len(owners) else owners[0]
        reports[owner].rejected.append(type(rejection)(0, rejection.body_id, rejection.reason))
