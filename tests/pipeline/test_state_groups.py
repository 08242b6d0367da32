"""Runs of single CircleState messages merged as one group (pipeline/state_groups).

Guarantees proved here:
- the group decoder reads exactly what cdr_codec.decode_states reads (valid
  messages, bit for bit), and refuses exactly what it refuses (fuzzed bytes);
- a group with several states of one body merges them in arrival order: the
  scene equals one-by-one ingestion at the same receive time, and nothing is
  rejected as a duplicate.
"""
from __future__ import annotations

import numpy as np
from rclpy.serialization import serialize_message

from circle_collision_msgs.msg import CircleState
from circle_collision_ros.pipeline.cdr import CdrError
from circle_collision_ros.pipeline.state_codec import decode_state_row, decode_states
from circle_collision_ros.pipeline.predictor import CollisionPredictor, PredictorConfig
from circle_collision_ros.pipeline.state_groups import ingest_single_states
from tests.node_helpers import BASE_NS, random_states, state


def _as_row(data: bytes) -> tuple:
    b = decode_states(data, CircleState)
    cov = (
        () if b.covariance is None else tuple(b.covariance[0].tolist())[: int(b.covariance_size[0])]
    )
    return (
        int(b.stamp_ns[0]),
        b.frames[0],
        b.ids[0],
        tuple(np.concatenate([b.radius, b.position[0], b.velocity[0], b.acceleration[0]]).tolist()),
        bool(b.remove[0]),
        cov,
    )


def test_group_decoder_matches_decode_states_on_valid_messages() -> None:
    states = random_states(200, seed=3)
    for k, s in enumerate(states):
        s.header.frame_id = "m" * (k % 9)  # every string length residue
        s.id = "x" * (1 + k % 11)
        s.remove = bool(k % 5 == 0)
        if k % 3 == 0:  # every residue of the covariance's alignment, with and without values
            s.covariance = np.random.default_rng(k).normal(size=36).tolist()
    for s in states:
        data = serialize_message(s)
        row = decode_state_row(data, True)
        assert row is not None
        expected = _as_row(data)
        assert row[:3] == expected[:3] and row[4:] == expected[4:]
        assert np.array_equal(np.array(row[3]).view(np.int64), np.array(expected[3]).view(np.int64))


def test_group_decoder_refuses_what_decode_states_refuses() -> None:
    rng = np.random.default_rng(5)
    base = bytearray(serialize_message(state("body", (1, 2), (3, 4))))
    for _ in range(3000):
        data = bytearray(base)
        for _ in range(int(rng.integers(1, 4))):
            data[int(rng.integers(0, len(data)))] = int(rng.integers(0, 256))
        data = bytes(data[: int(rng.integers(0, len(data) + 1))])
        try:
            expected = _as_row(data)
        except CdrError:
            expected = None
        row = decode_state_row(data, True)
        if row is None:
            continue  # the group falls back to decode_states: same outcome by construction
        assert expected is not None, data
        assert row[:3] == expected[:3] and row[4] == expected[4]
        assert np.array_equal(np.array(row[3]).view(np.int64), np.array(expected[3]).view(np.int64))


def test_group_equals_one_by_one_ingestion_with_repeated_bodies() -> None:
    now = BASE_NS + 10**9
    messages = []
    for k in range(60):  # 20 bodies, three states each, interleaved; one removal
        body = f"b{k % 20:02d}"
        messages.append(
            serialize_message(
                state(body, (3.0 * (k % 20), 0.0), (-1.0 * (k % 2), 0, 0),
                      stamp_ns=BASE_NS + k * 1000, remove=(k == 45))
            )
        )
    grouped = CollisionPredictor(PredictorConfig())
    outcome = ingest_single_states(grouped, messages, now)
    assert not any(outcome.errors)
    assert sum(len(r.rejected) for r in outcome.reports) == 0
    assert (
        sum(r.accepted for r in outcome.reports) == 59
        and sum(r.removed for r in outcome.reports) == 1
    )
    single = CollisionPredictor(PredictorConfig())
    for data in messages:
        single.receive_batch(decode_states(data, CircleState), now)
    a, b = grouped.predict().to_message(), single.predict().to_message()
    assert a == b and len(a.predictions) > 0
