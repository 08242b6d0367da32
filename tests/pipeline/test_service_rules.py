"""The predict_collisions service's rules (predict_once, the stateless path).

Guarantees proved here (README, "Service"):
- circles with a zero header.stamp are taken as stamped at the request time,
  so `ros2 service call` without stamps works; the result equals the same
  request with the stamps filled in by hand;
- a refusal names every bad circle with every reason (a zero stamp never hides
  a negative radius);
- the horizon follows the parameter's rule: 0 = the node's horizon, otherwise
  [0.001, 3600] s; an empty request is refused, and so is one of more circles than
  max_bodies (the paths the node compiled are for that many), with a message saying so;
- topics still refuse zero stamps, and the reason says how to stamp.
"""
from __future__ import annotations

import math

import pytest

from circle_collision_ros.pipeline.predictor import (CollisionPredictor, PredictorConfig,
                                                     predict_once)
from circle_collision_ros.pipeline.state_batch import StateBatch
from tests.node_helpers import BASE_NS, contacts_of, state


def _unstamped(*states):
    for s in states:
        s.header.stamp.sec = s.header.stamp.nanosec = 0
    return list(states)


def test_zero_stamps_are_taken_at_request_time() -> None:
    request_ns = BASE_NS + 123_456_789
    ok, message, out = predict_once(_unstamped(state("a", (0, 0), (1, 0, 0)), state("b", (5, 0))),
                                    PredictorConfig(), horizon=10.0, request_time_ns=request_ns)
    assert ok, message
    msg = out.to_message()
    assert msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec == request_ns
    assert contacts_of(msg) == {("a", "b"): 4.0}
    # Mixed: a stamped circle and an unstamped one (taken at request time).
    ok, message, out = predict_once(
        [state("a", (0, 0), (1, 0, 0), stamp_ns=request_ns - 1_000_000_000)]
        + _unstamped(state("b", (5, 0))),
        PredictorConfig(),
        horizon=10.0,
        request_time_ns=request_ns,
    )
    assert ok, message
    assert contacts_of(out.to_message()) == {("a", "b"): 3.0}  # a moved 1 m in the second before


def test_every_reason_of_every_bad_circle_is_reported() -> None:
    bad = _unstamped(state("a", (0, 0), r=-1.0), state("b", (1, 1)), state("c", (2, 2), r=math.nan))
    bad[2].velocity.x = math.inf
    bad[2].header.frame_id = "odom"
    ok, message, out = predict_once(bad, PredictorConfig(frame_id="map"), request_time_ns=0)
    assert not ok and out is None
    parts = message.split(" | ")
    assert parts[0].startswith(
        "circles[0] (id 'a'): radius is negative (-1.0); header.stamp is zero"
    )
    assert parts[1].startswith("circles[1] (id 'b'): header.stamp is zero")
    assert parts[2].startswith(
        "circles[2] (id 'c'): radius is nan; velocity.x is inf; frame 'odom'"
    )
    # With a request time the zero stamps are fine, and the real problems remain.
    ok, message, _ = predict_once(bad, PredictorConfig(frame_id="map"), request_time_ns=BASE_NS)
    assert not ok and message.split(" | ")[0] == "circles[0] (id 'a'): radius is negative (-1.0)"
    assert "stamp" not in message and len(message.split(" | ")) == 2


@pytest.mark.parametrize(
    "horizon, accepted",
    [(0.0, True), (3600.0, True), (1e-3, True), (3600.5, False), (1e7, False), (-2.0, False),
     (math.inf, False), (math.nan, False), (1e-4, False)],
)
def test_horizon_rule_is_the_parameter_rule(horizon, accepted) -> None:
    ok, message, out = predict_once([state("a", (0, 0), (1, 0, 0)), state("b", (5, 0))],
                                    PredictorConfig(horizon=5.0), horizon=horizon)
    assert ok == accepted, message
    if accepted:
        assert out.to_message().horizon == (horizon or 5.0)
    else:
        assert "horizon must be 0" in message and "3600" in message


def test_empty_request_is_refused() -> None:
    ok, message, out = predict_once([], PredictorConfig(), horizon=1.0)
    assert not ok and out is None and message == "the request has no circles"


def test_topics_refuse_zero_stamps_and_say_how_to_stamp() -> None:
    predictor = CollisionPredictor(PredictorConfig(frame_id="map"))
    report = predictor.receive_batch(
        StateBatch.from_messages(_unstamped(state("a", (0, 0)))), BASE_NS
    )
    assert report.accepted == 0
    assert "header: {stamp: now}" in report.rejected[0].reason


def test_requests_beyond_max_bodies_are_refused() -> None:
    circles = [state(f"c{k}", (3.0 * k, 0.0)) for k in range(5)]
    ok, message, out = predict_once(circles, PredictorConfig(max_bodies=4), horizon=1.0)
    assert not ok and out is None
    assert message == "the request has 5 circles; this node predicts at most max_bodies = 4"
    ok, message, out = predict_once(circles[:4], PredictorConfig(max_bodies=4), horizon=1.0)
    assert ok and out is not None, message
