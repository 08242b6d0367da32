"""Corrupted CircleStateArray contents through CollisionPredictor (the node's own path, no DDS).

Guarantees proved here, over sequences of randomly corrupted messages (every
field, every bad-value class, see tests/reliability/corrupt.py):
- the bytes decode, and exactly the states the oracle calls bad are rejected;
- the scene and its predictions are bit-identical to those of a twin predictor
  fed only the good states of the same messages (so bad states have no effect
  on the rest), and nothing predicted is NaN;
- removals, late and duplicated states are counted the same way.
A body far outside the core's input range (radius 1e160) used to be accepted
and silently hid two overlapping pairs; see test_huge_radius_is_rejected.
Example counts: a quick sample by default, the full counts under --stress (tests/stress.py).
"""
from __future__ import annotations

import math

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from circle_collision_msgs.msg import CircleStateArray
from circle_collision_ros.pipeline.state_codec import decode_states
from circle_collision_ros.pipeline.predictor import CollisionPredictor, PredictorConfig
from tests.reliability.conftest import tally
from tests.stress import examples
from tests.reliability.corrupt import corrupted_message
from tests.reliability.wire import Body, encode_array
from tests.node_helpers import BASE_NS

STEP_NS = 100_000_000


def _rows(predictor: CollisionPredictor) -> tuple[list, bytes]:
    prediction = predictor.predict()
    rows = list(prediction.rows())
    for row in rows:
        numbers = [row[3], *row[5], *row[6], row[7]]
        assert not any(math.isnan(x) for x in numbers), row
    return rows, prediction.to_cdr()


@st.composite
def message_sequences(draw):
    dims = draw(st.sampled_from([2, 3]))
    messages = []
    previous: tuple = ()
    for step in range(draw(st.integers(1, 3))):
        now = BASE_NS + step * STEP_NS
        bodies, bad = draw(corrupted_message("b", now, dimensions=dims, removable=previous))
        messages.append((now, bodies, bad))
        previous = tuple(b.id for k, b in enumerate(bodies) if k not in bad and not b.remove)
    return dims, messages


@settings(max_examples=examples(60, 600), deadline=None,
          suppress_health_check=[HealthCheck.too_slow])
@given(message_sequences())
def test_bad_states_rejected_exactly_and_without_effect(seq) -> None:
    dims, messages = seq
    config = PredictorConfig(horizon=5.0, dimensions=dims, frame_id="map")
    mixed, twin = CollisionPredictor(config), CollisionPredictor(config)
    tally("sequences")
    for now, bodies, bad in messages:
        tally("messages")
        tally("states", len(bodies))
        tally("bad_states", len(bad))
        report = mixed.receive_batch(
            decode_states(encode_array(bodies, now), CircleStateArray), now
        )
        good = [b for k, b in enumerate(bodies) if k not in bad]
        clean = twin.receive_batch(decode_states(encode_array(good, now), CircleStateArray), now)
        assert sorted(r.index for r in report.rejected) == bad, [r.reason for r in report.rejected]
        assert all(r.reason for r in report.rejected)
        assert not clean.rejected
        assert (report.accepted, report.removed, report.ignored) == (clean.accepted, clean.removed,
                                                                     clean.ignored)
        rows, data = _rows(mixed)
        twin_rows, twin_data = _rows(twin)
        assert rows == twin_rows
        assert data == twin_data  # the published bytes too
        assert mixed.reference_ns == twin.reference_ns
        tally("contacts_compared", len(rows))


def test_huge_radius_is_rejected() -> None:
    """A radius of 1e160 (finite, beyond the core's range) overlapping two bodies used to be
    accepted and predicted as no contact at all; now it is rejected with a reason."""
    now = BASE_NS
    bodies = [Body("big", 1e160, (0.0, 0.0, 0.0), stamp_ns=now),
              Body("b", 0.5, (3.0, 0.0, 0.0), stamp_ns=now),
              Body("c", 0.5, (-3.0, 0.0, 0.0), stamp_ns=now)]
    predictor = CollisionPredictor(PredictorConfig(horizon=5.0, frame_id="map"))
    report = predictor.receive_batch(
        decode_states(encode_array(bodies, now), CircleStateArray), now
    )
    assert [(r.body_id, r.reason) for r in report.rejected] == [
        ("big", "radius is 1e+160, beyond 1e+12")
    ]
    assert report.accepted == 2


def test_huge_acceleration_with_old_stamp_stays_predictable() -> None:
    """The bound also keeps propagation to the reference time finite: the worst accepted
    state (|a| = 1e12, stamp 1 ns after the epoch) propagates to ~1e30 m, not inf/NaN."""
    now = BASE_NS
    bodies = [Body("old", 1.0, (0.0, 0.0, 0.0), a=(1e12, -1e12, 0.0), stamp_ns=1),
              Body("a", 0.5, (0.0, 0.0, 0.0), v=(1.0, 0.0, 0.0), stamp_ns=now),
              Body("b", 0.5, (3.0, 0.0, 0.0), stamp_ns=now)]
    predictor = CollisionPredictor(PredictorConfig(horizon=5.0, frame_id="map"))
    report = predictor.receive_batch(
        decode_states(encode_array(bodies, now), CircleStateArray), now
    )
    assert report.accepted == 3
    rows, _ = _rows(predictor)
    assert [(r[0], r[1], r[3]) for r in rows] == [("a", "b", 2.0)]
