"""Every circle_collision_msgs interface builds, imports and round-trips.

Guarantees proved here: the generated types import from the venv install;
serialize/deserialize through rclpy.serialization is lossless for every field
(including +inf and the status constants); the same messages cross real DDS on
localhost between a publisher and a subscriber, and a real service call returns
the response the server built.
"""
from __future__ import annotations

import math

import pytest
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point, Vector3
from rclpy.serialization import deserialize_message, serialize_message
from std_msgs.msg import Header

from circle_collision_msgs.msg import (CircleState, CircleStateArray, CollisionPrediction,
                                       CollisionPredictionArray)
from circle_collision_msgs.srv import PredictCollisions
from tests.node.conftest import spin_until


def _state(i: int) -> CircleState:
    return CircleState(
        header=Header(stamp=Time(sec=100 + i, nanosec=250_000_000), frame_id="map"),
        id=f"body-{i}", radius=0.5 + i,
        position=Point(x=1.0e6 + i, y=-2.5, z=0.125),
        velocity=Vector3(x=1.0, y=-1.0, z=0.0),
        acceleration=Vector3(x=0.0, y=-9.81, z=1e-12),
        remove=bool(i % 2),
        # float64[<=36]
        covariance=[0.01 * (i + 1) + k / 1024.0 for k in range(36)] if i % 3 else [])


def _prediction() -> CollisionPrediction:
    return CollisionPrediction(
        id_a="a", id_b="b", status=CollisionPrediction.CONTACT, time_to_collision=1.5,
        contact_time=Time(sec=7, nanosec=5), contact_point=Point(x=1.0, y=2.0, z=3.0),
        normal=Vector3(x=0.0, y=1.0, z=0.0), closing_speed=2.25, collision_probability=0.75,
        collision_probability_bound=1e-9, plausible_time_to_collision=1.25)


SAMPLES = [
    _state(3),
    CircleStateArray(header=Header(frame_id="map"), circles=[_state(i) for i in range(4)]),
    _prediction(),
    CollisionPredictionArray(
        header=Header(stamp=Time(sec=1, nanosec=2), frame_id="map"), horizon=5.0,
        predictions=[_prediction(),
                     CollisionPrediction(id_a="c", id_b="d", status=CollisionPrediction.NO_CONTACT,
                                         time_to_collision=math.inf, collision_probability=0.02,
                                         plausible_time_to_collision=math.inf)]),
    PredictCollisions.Request(circles=[_state(1), _state(2)], horizon=0.0),
    PredictCollisions.Response(success=False, message="circles[1] (id 'x'): radius is -1",
                               predictions=[_prediction()]),
]


def test_covariance_is_a_sequence_of_at_most_36() -> None:
    """The bound is enforced where bytes are made: rclpy refuses to serialize (so to publish or
    call with) 37 values; assignment checks it only with ROS_PYTHON_CHECK_FIELDS. Raw bytes
    claiming more are the decoder's business (tests/reliability/test_fuzz_cdr.py)."""
    state = CircleState(covariance=[1.0] * 36)
    assert len(state.covariance) == 36 and len(CircleState().covariance) == 0
    assert len(deserialize_message(serialize_message(state), CircleState).covariance) == 36
    with pytest.raises(Exception, match="serialize"):
        serialize_message(CircleState(covariance=[1.0] * 37))


def test_status_constants() -> None:
    assert (CollisionPrediction.NO_CONTACT, CollisionPrediction.CONTACT,
            CollisionPrediction.OVERLAPPING) == (0, 1, 2)


@pytest.mark.parametrize("msg", SAMPLES, ids=lambda m: type(m).__name__)
def test_serialization_round_trip(msg) -> None:
    data = serialize_message(msg)
    back = deserialize_message(data, type(msg))
    assert back == msg
    # No byte-equality check on re-serialization: Fast CDR leaves alignment
    # padding bytes uninitialised, so equal messages may serialize to different
    # bytes. Replay therefore compares decoded field values, never raw bytes.


@pytest.mark.parametrize("msg", SAMPLES[:4], ids=lambda m: type(m).__name__)
def test_publish_subscribe_over_dds(ros_node, msg) -> None:
    topic = f"roundtrip_{type(msg).__name__.lower()}"
    received = []
    ros_node.create_subscription(type(msg), topic, received.append, 10)
    pub = ros_node.create_publisher(type(msg), topic, 10)

    def delivered() -> bool:
        if not received:
            pub.publish(msg)  # re-send until discovery has matched the endpoints
        return bool(received)

    assert spin_until(ros_node, delivered, timeout=15.0), f"{topic}: nothing received"
    assert received[0] == msg


def test_service_call_over_dds(ros_node) -> None:
    def handle(request, response):
        response.success = True
        response.message = f"{len(request.circles)} circles, horizon {request.horizon}"
        response.predictions = [_prediction()]
        return response

    ros_node.create_service(PredictCollisions, "roundtrip_predict", handle)
    client = ros_node.create_client(PredictCollisions, "roundtrip_predict")
    assert spin_until(ros_node, client.service_is_ready, timeout=15.0)
    future = client.call_async(
        PredictCollisions.Request(circles=[_state(0), _state(1)], horizon=2.0)
    )
    assert spin_until(ros_node, future.done, timeout=15.0)
    result = future.result()
    assert result.success and result.message == "2 circles, horizon 2.0"
    assert result.predictions == [_prediction()]
