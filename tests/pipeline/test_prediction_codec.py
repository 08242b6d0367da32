"""CollisionPredictionArray codec (pipeline/prediction_codec.py): the node's compiled encoder
and replay's own decoder for recorded predictions and config strings (rclpy never sees bag bytes).

Guarantees proved here for the encoder, on random predictions (2-D and 3-D, empty, with
report_all_pairs NO_CONTACT rows, non-ASCII and empty ids, empty and long frame ids):
- the bytes equal those of the straightforward struct-based writer the node used
  before (kept below as the reference), byte for byte, padding included;
- the layout before the probability fields (uncertainty=False, what old recordings hold) is the
  same bytes without the three probability fields;
- the one-pass encoder of exact contacts (the node's common case) writes the same
  bytes as the general path, and a non-finite row sends it to the general path;
- the bytes equal rclpy's serialize_message of the same message object (except
  alignment padding, which Fast CDR leaves uninitialised; ours is zero), and
  rclpy's deserialize_message gives back exactly that message.

And for the decoder:
- on every recorded prediction of the test bags (Fast CDR bytes with garbage
  padding, from a node before the probability fields: the layout without the probability
  fields) the decoder (uncertainty=False) gives exactly the fields
  mcap-ros2-support decodes by the schema recorded in the file; on the node's
  own encoder output and on rclpy's bytes (current layout) exactly the fields
  rclpy's deserializer gives;
- every truncation of a valid message, and random corruption, ends in
  CdrError or a well-formed result, never another exception (and never rclpy).
"""
from __future__ import annotations

import dataclasses
import random
import struct
from pathlib import Path

import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from std_msgs.msg import String

from circle_collision_msgs.msg import CollisionPrediction, CollisionPredictionArray
from circle_collision_ros.pipeline.cdr import CdrError, decode_string
from circle_collision_ros.pipeline.prediction_codec import (PairPrediction, PredictionArray,
                                                            decode_prediction_array,
                                                            encode_contact_rows,
                                                            encode_prediction_array)
from circle_collision_ros.pipeline.predictor import CollisionPredictor, PredictorConfig
from circle_collision_ros.pipeline.state_batch import StateBatch
from circle_collision_ros.recording.replay_engine import RecordedTypes, load_bag, replay_bag
from tests.node_helpers import BASE_NS, random_states


# ---------------------------------------------------------------- encoder


def reference_encoding(
    stamp, frame_id: str, horizon: float, rows, uncertainty: bool = True
) -> tuple[bytes, list[int]]:
    """Little-endian XCDR1 written field by field with struct (the pre-compiled encoder),
    and the positions of its alignment padding."""
    buf = bytearray(b"\x00\x01\x00\x00")
    padding: list[int] = []

    def pad(n):
        k = (-(len(buf) - 4)) % n
        padding.extend(range(len(buf), len(buf) + k))
        buf.extend(b"\x00" * k)

    def u32(v):
        pad(4)
        buf.extend(struct.pack("<I", v))

    def string(s: str):
        b = s.encode()
        u32(len(b) + 1)
        buf.extend(b + b"\x00")

    def f64s(*v):
        pad(8)
        buf.extend(struct.pack(f"<{len(v)}d", *v))

    def time(sec, nanosec):
        pad(4)
        buf.extend(struct.pack("<iI", sec, nanosec))

    time(*stamp)
    string(frame_id)
    f64s(horizon)
    rows = list(rows)
    u32(len(rows))
    for r in rows:
        string(r.id_a)
        string(r.id_b)
        buf.append(r.status)
        f64s(r.time_to_collision)
        time(*r.contact_time)
        f64s(*r.contact_point, *r.normal, r.closing_speed)
        if uncertainty:
            f64s(r.collision_probability, r.collision_probability_bound,
                 r.plausible_time_to_collision)
    return bytes(buf), padding


def predictions(seed: int, n: int, dimensions: int, report_all: bool, frame: str):
    states = random_states(n, seed=seed, dimensions=dimensions, spread=12.0)
    rng = np.random.default_rng(seed)
    for s in states:
        # non-ASCII, long, and unchanged ids
        s.id = rng.choice(["", "körper_", "b", "x" * 40]) + s.id
    seen = set()
    states = [s for s in states if not (s.id in seen or seen.add(s.id))]
    predictor = CollisionPredictor(
        PredictorConfig(horizon=float(rng.uniform(0.5, 6.0)), dimensions=dimensions,
                        report_all_pairs=report_all, frame_id=frame)
    )
    for s in states:
        s.header.frame_id = frame
    predictor.receive_batch(StateBatch.from_messages(states), BASE_NS)
    return predictor.predict()


CASES = [
    (seed, n, dim, report_all, frame)
    for seed, (n, dim, report_all, frame) in enumerate(
        [(0, 2, False, "map"), (1, 2, True, "map"), (2, 3, True, ""), (30, 2, False, "map"),
         (30, 2, True, "a_frame_with_an_odd_length"), (40, 3, False, "odom"), (60, 2, False, "m"),
         (25, 3, True, "wörld"), (90, 2, True, "map"), (200, 2, False, "map")]
    )
]


@pytest.mark.parametrize("seed, n, dim, report_all, frame", CASES)
def test_compiled_encoder_equals_reference_and_rclpy(seed, n, dim, report_all, frame) -> None:
    prediction = predictions(seed, n, dim, report_all, frame)
    data = prediction.to_cdr()
    reference, padding = reference_encoding(
        prediction.stamp, prediction.frame_id, prediction.horizon, prediction.rows()
    )
    assert data == reference
    old, _ = reference_encoding(prediction.stamp, prediction.frame_id, prediction.horizon,
                                prediction.rows(), uncertainty=False)
    assert prediction.to_cdr(uncertainty=False) == old
    message = prediction.to_message()
    # Fast CDR leaves alignment padding uninitialised: compare every other byte.
    theirs = bytearray(serialize_message(message))
    for k in padding:
        theirs[k] = 0
    assert data == bytes(theirs)
    assert deserialize_message(data, CollisionPredictionArray) == message


def test_cases_cover_empty_contacts_and_no_contact_rows() -> None:
    kinds = [predictions(*case) for case in CASES]
    assert any(len(p.columns) == 0 for p in kinds)
    assert any(len(p.contacts) > 20 for p in kinds)
    assert any((p.columns.status == 0).any() for p in kinds)  # NO_CONTACT rows
    assert any((p.columns.status == 2).any() for p in kinds)  # OVERLAPPING rows


def test_encoded_ids_survive_churn() -> None:
    """The scene keeps ids UTF-8-encoded for the encoder (core/scene.py, SceneContacts.id_utf8) in a
    blob that grows and drops the ids of removed bodies: through 60 rounds of bodies replaced by
    new (ASCII and non-ASCII) ids, every publication equals the reference writer, and an older
    prediction encodes the same bytes after the scene has moved on."""
    predictor = CollisionPredictor(PredictorConfig(horizon=5.0, frame_id="map", stale_timeout=1e-3))
    rng = np.random.default_rng(7)
    kept = []
    for k in range(60):
        states = random_states(40, seed=k, spread=8.0, stamp_ns=BASE_NS + k * 10_000_000)
        for j, s in enumerate(states):
            s.id = f"{'ü' * int(rng.integers(0, 3))}r{k}_{j}" + "x" * int(rng.integers(0, 30))
            s.header.frame_id = "map"
        # stale_timeout 1 ms: the last round's bodies expire, their ids' bytes become garbage
        predictor.receive_batch(StateBatch.from_messages(states), BASE_NS + k * 10_000_000)
        prediction = predictor.predict()
        data = prediction.to_cdr()
        assert len(prediction.contacts) > 0
        assert (
            data
            == reference_encoding(
                prediction.stamp, prediction.frame_id, prediction.horizon, prediction.rows()
            )[0]
        )
        if k % 20 == 0:
            kept.append((prediction, data))
    for prediction, data in kept:
        assert prediction.to_cdr() == data


def test_kept_rows_follow_their_ids_when_the_blob_is_compacted() -> None:
    """Pairs that stay (overlapping bodies never updated) keep their rows' places in the id blob
    between queries; churn (bodies with long ids added and removed while the reference time moves)
    makes the blob drop removed ids and move the live ones: every publication still names its
    pairs right (equal to the reference writer)."""
    from circle_collision_msgs.msg import CircleState

    def state(body_id: str, x: float, stamp_ns: int, remove: bool = False) -> CircleState:
        s = CircleState(id=body_id, radius=1.0, remove=remove)
        s.header.frame_id = "map"
        s.header.stamp.sec, s.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
        s.position.x = x
        return s

    predictor = CollisionPredictor(PredictorConfig(horizon=5.0, frame_id="map", stale_timeout=1e3))
    churn = [f"early{j}_" + "x" * 40 for j in range(10)]  # ahead of the staying ids in the blob
    stay = [state(f"stay{k:02d}", 10.0 * (k // 2) + 1.5 * (k % 2), BASE_NS) for k in range(20)]
    predictor.receive_batch(
        StateBatch.from_messages(
            [state(i, 1000.0 + 10.0 * j, BASE_NS) for j, i in enumerate(churn)] + stay
        ),
        BASE_NS,
    )
    serial = predictor._scene._utf8_serial
    for k in range(1, 80):
        stamp = BASE_NS + k * 1_000_000
        gone = [state(i, 0.0, stamp, remove=True) for i in churn]
        churn = [f"churn{k}_{j}_" + "x" * 40 for j in range(6)]
        new = [state(i, 1000.0 + 10.0 * j, stamp) for j, i in enumerate(churn)]
        predictor.receive_batch(StateBatch.from_messages(gone + new), stamp)
        prediction = predictor.predict()
        assert len(prediction.contacts) == 10  # the staying pairs, overlapping
        assert (
            prediction.to_cdr()
            == reference_encoding(
                prediction.stamp, prediction.frame_id, prediction.horizon, prediction.rows()
            )[0]
        )
    assert predictor._scene._utf8_serial > serial  # the blob was compacted on the way


@pytest.mark.parametrize("seed, n, dim, report_all, frame", [c for c in CASES if not c[3]])
def test_exact_contacts_encoder_equals_the_columns_path(seed, n, dim, report_all, frame) -> None:
    """The node's common case (exact contacts only) is written by one compiled pass straight from
    the scene's rows (prediction_codec.encode_contact_rows); its bytes equal the general path's
    (ScenePrediction.columns + encode_prediction_array), and to_cdr takes it."""
    prediction = predictions(seed, n, dim, report_all, frame)
    fast = encode_contact_rows(prediction.stamp, prediction.frame_id, prediction.horizon,
                               prediction.contacts, CollisionPrediction.CONTACT,
                               CollisionPrediction.OVERLAPPING)
    general = encode_prediction_array(
        prediction.stamp, prediction.frame_id, prediction.horizon, prediction.columns
    )
    assert fast is not None and fast == general == prediction.to_cdr()


@pytest.mark.parametrize(
    "field, value",
    [("closing_speed", np.nan), ("ttc", np.inf), ("point", np.nan), ("normal", -np.inf),
     ("point", np.inf)],
)
def test_non_finite_contact_row_takes_the_general_path(field, value) -> None:
    """A contact row with a non-finite value is left out (the "never publishes NaN" guarantee):
    the one-pass encoder refuses it and to_cdr falls back to the columns path, which drops it."""
    prediction = predictions(200, 200, 2, False, "map")
    c = prediction.contacts
    assert len(c) > 3
    column = getattr(c, field).copy()
    if column.ndim == 2:
        column[1, -1] = value  # one coordinate of a point or normal
    else:
        column[1] = value
    bad = dataclasses.replace(prediction, contacts=dataclasses.replace(c, **{field: column}))
    assert (
        encode_contact_rows(bad.stamp, bad.frame_id, bad.horizon, bad.contacts,
                            CollisionPrediction.CONTACT, CollisionPrediction.OVERLAPPING)
        is None
    )
    rows = list(bad.rows())
    assert len(rows) == len(c) - 1
    assert bad.to_cdr() == reference_encoding(bad.stamp, bad.frame_id, bad.horizon, rows)[0]


@pytest.mark.parametrize("seed, n, dim, report_all, frame", [c for c in CASES if c[1] >= 25])
def test_uncertain_rows_encode_from_the_scenes_ids(seed, n, dim, report_all, frame) -> None:
    """With covariance on most bodies, the published rows are the contacts then the probable
    uncertain pairs (NO_CONTACT). Without report_all_pairs rows to_cdr writes them in one
    compiled pass from the scene's rows and UTF-8 ids (prediction_codec.encode_contact_rows with the
    uncertain join); the bytes equal the reference writer's (rows() in publication order), the
    general path's (ScenePrediction.columns + encode_prediction_array), and rclpy's."""
    states = random_states(n, seed=seed, dimensions=dim, spread=6.0)
    rng = np.random.default_rng(seed)
    seen = set()
    for s in states:
        s.id = rng.choice(["", "körper_", "b", "x" * 40]) + s.id
        s.header.frame_id = frame
        if rng.random() < 0.8:
            sigma = float(rng.uniform(0.05, 0.6))
            s.covariance = np.diag([sigma**2] * 3 + [(sigma / 2) ** 2] * 3).ravel().tolist()
    states = [s for s in states if not (s.id in seen or seen.add(s.id))]
    predictor = CollisionPredictor(
        PredictorConfig(horizon=5.0, dimensions=dim, report_all_pairs=report_all, frame_id=frame,
                        uncertain_pair_budget=3)
    )
    predictor.receive_batch(StateBatch.from_messages(states), BASE_NS)
    prediction = predictor.predict()
    columns = prediction.columns
    extra = len(columns) - len(prediction.contacts)
    assert (
        extra > 0
        and (columns.status[len(prediction.contacts) :] == CollisionPrediction.NO_CONTACT).all()
    )
    data = prediction.to_cdr()
    if not (report_all and n <= 100):
        u = prediction.uncertainty
        found, extra = prediction._uncertain_join
        assert data == encode_contact_rows(
            prediction.stamp,
            prediction.frame_id,
            prediction.horizon,
            prediction.contacts,
            CollisionPrediction.CONTACT,
            CollisionPrediction.OVERLAPPING,
            (found, u.probability, u.probability_bound, u.plausible_ttc, extra, u.id_utf8),
            CollisionPrediction.NO_CONTACT,
        )
    reference, padding = reference_encoding(
        prediction.stamp, prediction.frame_id, prediction.horizon, prediction.rows()
    )
    assert data == reference
    assert data == encode_prediction_array(
        prediction.stamp, prediction.frame_id, prediction.horizon, columns
    )
    message = prediction.to_message()
    theirs = bytearray(serialize_message(message))
    for k in padding:
        theirs[k] = 0
    assert data == bytes(theirs)
    # the uncertain rows after the contacts (report_all_pairs rows follow them) are ordered by
    # (plausible time, id_a, id_b)
    probable = len(prediction.contacts) + prediction._uncertain_join[1].size
    rows = list(prediction.rows())[len(prediction.contacts) : probable]
    assert len(rows) > 1
    keys = [(r.plausible_time_to_collision, r.id_a, r.id_b) for r in rows]
    assert keys == sorted(keys)


# ---------------------------------------------------------------- decoder

DATA = Path(__file__).resolve().parents[1] / "data"


def _as_rows(msg, uncertainty: bool = True) -> PredictionArray:
    """Our rows from a message object (rclpy's, or mcap-ros2-support's dynamic one)."""
    return PredictionArray(
        (msg.header.stamp.sec, msg.header.stamp.nanosec, msg.header.frame_id),
        msg.horizon,
        tuple(
            PairPrediction(
                p.id_a,
                p.id_b,
                p.status,
                p.time_to_collision,
                (p.contact_time.sec, p.contact_time.nanosec),
                (p.contact_point.x, p.contact_point.y, p.contact_point.z),
                (p.normal.x, p.normal.y, p.normal.z),
                p.closing_speed,
                *(
                    (p.collision_probability, p.collision_probability_bound,
                     p.plausible_time_to_collision)
                    if uncertainty
                    else ()
                ),
            )
            for p in msg.predictions
        ),
    )


def _recorded(name: str, type_name: str) -> list[bytes]:
    return [r.data for r in load_bag(DATA / name)[1] if r.type_name == type_name]


@pytest.mark.parametrize("bag", ["plain_2d", "spheres_3d", "bad_inputs_2d"])
def test_decoder_agrees_with_the_recorded_schema_and_rclpy(bag: str) -> None:
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    with open(next((DATA / bag).glob("*.mcap")), "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        recorded = [
            (m.data, ros_msg)
            for _, _, m, ros_msg in reader.iter_decoded_messages(topics=["/collision_predictions"])
        ]
    assert len(recorded) > 20
    for data, by_schema in recorded:  # the old layout, decoded by the file's own schema
        assert not hasattr(
            by_schema.predictions[0] if by_schema.predictions else by_schema,
            "collision_probability",
        )
        assert decode_prediction_array(data, uncertainty=False) == _as_rows(
            by_schema, uncertainty=False
        )
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
