"""Replay's own decoder for recorded predictions and config strings (rclpy never sees bag bytes).

Guarantees proved here:
- on every recorded prediction of the test bags (Fast CDR bytes with garbage
  padding, from a node before issue 18: the layout without the probability
  fields) the decoder (uncertainty=False) gives exactly the fields
  mcap-ros2-support decodes by the schema recorded in the file; on the node's
  own encoder output and on rclpy's bytes (current layout) exactly the fields
  rclpy's deserializer gives;
- every truncation of a valid message, and random corruption, ends in
  CdrError or a well-formed result, never another exception (and never rclpy).
"""
from __future__ import annotations

import random
from pathlib import Path

import pytest
from rclpy.serialization import deserialize_message, serialize_message
from std_msgs.msg import String

from circle_collision_msgs.msg import CollisionPredictionArray
from circle_collision_ros.pipeline.cdr_codec import CdrError
from circle_collision_ros.recording.prediction_cdr import (PairPrediction, PredictionArray,
                                                           decode_prediction_array, decode_string)
from circle_collision_ros.recording.replay import RecordedTypes, load_bag, replay_bag

DATA = Path(__file__).resolve().parents[1] / "data"


def _as_rows(msg, uncertainty: bool = True) -> PredictionArray:
    """Our rows from a message object (rclpy's, or mcap-ros2-support's dynamic one)."""
    return PredictionArray(
        (msg.header.stamp.sec, msg.header.stamp.nanosec, msg.header.frame_id), msg.horizon,
        tuple(PairPrediction(p.id_a, p.id_b, p.status, p.time_to_collision,
                             (p.contact_time.sec, p.contact_time.nanosec),
                             (p.contact_point.x, p.contact_point.y, p.contact_point.z),
                             (p.normal.x, p.normal.y, p.normal.z), p.closing_speed,
                             *((p.collision_probability, p.collision_probability_bound,
                                p.plausible_time_to_collision) if uncertainty else ()))
              for p in msg.predictions))


def _recorded(name: str, type_name: str) -> list[bytes]:
    return [r.data for r in load_bag(DATA / name)[1] if r.type_name == type_name]


@pytest.mark.parametrize("bag", ["plain_2d", "spheres_3d", "bad_inputs_2d"])
def test_decoder_agrees_with_the_recorded_schema_and_rclpy(bag: str) -> None:
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    with open(next((DATA / bag).glob("*.mcap")), "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        recorded = [(m.data, ros_msg) for _, _, m, ros_msg in
                    reader.iter_decoded_messages(topics=["/collision_predictions"])]
    assert len(recorded) > 20
    for data, by_schema in recorded:  # the old layout, decoded by the file's own schema
        assert not hasattr(by_schema.predictions[0] if by_schema.predictions else by_schema, "collision_probability")
        assert decode_prediction_array(data, uncertainty=False) == _as_rows(by_schema, uncertainty=False)
    predictor_bytes = [p.to_cdr() for p in _replayed_predictions(bag)]
    assert len(predictor_bytes) > 20
    for data in predictor_bytes:  # the current layout: the node's encoder, and rclpy's bytes
        msg = deserialize_message(data, CollisionPredictionArray)
        assert decode_prediction_array(data) == _as_rows(msg)
        again = serialize_message(msg)
        assert decode_prediction_array(again) == _as_rows(msg)


def _replayed_predictions(bag: str) -> list:
    """The predictions replay recomputes for `bag` (ScenePrediction objects)."""
    from circle_collision_ros.pipeline.predictor import CollisionPredictor

    out = []
    original = CollisionPredictor.predict

    def keep(self, *args, **kwargs):
        out.append(original(self, *args, **kwargs))
        return out[-1]

    CollisionPredictor.predict = keep
    try:
        assert replay_bag(DATA / bag).ok
    finally:
        CollisionPredictor.predict = original
    return out


def test_config_strings_decode_like_rclpy() -> None:
    recorded = _recorded("plain_2d", RecordedTypes.CONFIG)
    assert recorded
    for data in recorded:
        assert decode_string(data) == deserialize_message(data, String).data
    assert decode_string(serialize_message(String(data="héllo"))) == "héllo"


def test_truncated_and_corrupted_bytes_are_cdr_errors() -> None:
    data = max(_recorded("spheres_3d", RecordedTypes.PREDICTIONS), key=len)  # the old layout
    full = decode_prediction_array(data, uncertainty=False)
    for cut in range(len(data)):
        try:
            decoded = decode_prediction_array(data[:cut], uncertainty=False)
        except CdrError:
            continue
        assert len(decoded.predictions) == len(full.predictions)  # only trailing padding was cut
    rng = random.Random(7)
    for _ in range(3000):
        damaged = bytearray(data)
        for _ in range(rng.randint(1, 4)):
            damaged[rng.randrange(len(damaged))] = rng.randrange(256)
        try:
            decode_prediction_array(bytes(damaged))
        except CdrError:
            pass
    with pytest.raises(CdrError, match="not little-endian"):
        decode_prediction_array(b"\x00\x00\x00\x00" + data[4:])
    with pytest.raises(CdrError):
        decode_string(b"\x00\x01\x00\x00\xff\xff\xff\x7fabc")
