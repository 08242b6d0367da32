"""The single-bag replay engine: recorded inputs through CollisionPredictor, recorded
predictions compared.

replay_bag opens one recording, feeds its recorded inputs in recorded order and
with their recorded receive times through the same CollisionPredictor the node
uses, and compares every recorded prediction with the recomputed one, field by
field (floats must be bit-identical). The `replay` command (replay.py), the
corpus runner (corpus.py) and the pytest plugin (pytest_plugin.py) all call it.

Recorded bytes are untrusted: they are decoded by pipeline/state_codec,
pipeline/odometry and pipeline/prediction_codec, never by rclpy's deserializer.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Callable
from dataclasses import dataclass, field, fields

from nav_msgs.msg import Odometry

from circle_collision_msgs.msg import CircleState, CircleStateArray
from circle_collision_ros.pipeline.cdr import CdrError, decode_string
from circle_collision_ros.pipeline.odometry import ODOMETRY_TYPE, OdometrySource, odometry_batch
from circle_collision_ros.pipeline.prediction_codec import (PredictionArray,
                                                            decode_prediction_array,
                                                            peek_prediction_array)
from circle_collision_ros.pipeline.prediction_messages import ScenePrediction
from circle_collision_ros.pipeline.predictor import (RUNTIME_FIELDS, CollisionPredictor,
                                                     PredictorConfig)
from circle_collision_ros.pipeline.static_scene import (STATIC_TYPES, StaticObstacles,
                                                        StaticSettings, build_index)
from circle_collision_ros.pipeline.state_batch import StateBatch
from circle_collision_ros.pipeline.state_codec import StateDecoder, decode_states
from circle_collision_ros.pipeline.state_groups import ingest_single_states
from circle_collision_ros.recording.bag_reader import (RECORDED_TYPES, BagContents, BagError,
                                                       BagRecord, open_bag)
from circle_collision_ros.recording.ros_type_definitions import DefinitionFormat


class RecordedTypes:
    """Type names as they appear in a recording (rosbag2 form)."""

    STATE_ARRAY = "circle_collision_msgs/msg/CircleStateArray"
    STATE = "circle_collision_msgs/msg/CircleState"
    ODOMETRY = ODOMETRY_TYPE
    PREDICTIONS = "circle_collision_msgs/msg/CollisionPredictionArray"
    CONFIG = "std_msgs/msg/String"
    INPUTS = {STATE_ARRAY: CircleStateArray, STATE: CircleState, ODOMETRY: Odometry}


class RecordedLayout:
    """Which layout of our interfaces a recorded schema describes (pipeline/cdr.py, "Two layouts").

    An older recording embeds CircleState without `covariance` and
    CollisionPrediction without `collision_probability`; replay decodes its inputs and
    writes its predictions in that layout, so it compares bit for bit. A schema that
    names neither type (empty: not recorded by us) is taken as the current layout.
    """

    _FIELD = {
        "circle_collision_msgs/CircleState": "covariance",
        "circle_collision_msgs/CollisionPrediction": "collision_probability",
    }
    _cache: dict[str, bool] = {}

    @classmethod
    def has_uncertainty(cls, schema: str) -> bool:
        known = cls._cache.get(schema)
        if known is None:
            known = cls._cache[schema] = cls._parse(schema)
        return known

    @classmethod
    def _parse(cls, schema: str) -> bool:
        sections = schema.split(DefinitionFormat.SEPARATOR + "\n")
        for section in sections[1:]:
            head, _, text = section.partition("\n")
            field = cls._FIELD.get(head.removeprefix(DefinitionFormat.DEPENDENCY_PREFIX).strip())
            if field is not None:
                return any(
                    line.split("#", 1)[0].split()[1:2] == [field] for line in text.splitlines()
                )
        # The root type is CircleState itself (single-state topics)
        if any(
            line.split("#", 1)[0].split()[1:2] == ["remove"] for line in sections[0].splitlines()
        ):
            return any(
                line.split("#", 1)[0].split()[1:2] == ["covariance"]
                for line in sections[0].splitlines()
            )
        return True


def odometry_from_json(text: str) -> dict[str, OdometrySource]:
    """Odometry topic -> OdometrySource from the node's recorded configuration."""
    return {
        topic: OdometrySource(**source)
        for topic, source in json.loads(text).get("odometry", {}).items()
    }


def decode_input(record: BagRecord, odometry: dict[str, OdometrySource],
                 decoders: dict | None = None) -> StateBatch | None:
    """The StateBatch the node made of a recorded input, or None if it rejected it undecoded.

    decoders : a StateDecoder per (topic, type, layout), kept by the caller across records as
        the node keeps one per subscription (the same batches, bit for bit, read faster).
    """
    try:
        if record.type_name == RecordedTypes.ODOMETRY:
            source = odometry.get(record.topic)
            return odometry_batch(record.data, source) if source is not None else None
        msg_type = RecordedTypes.INPUTS[record.type_name]
        uncertainty = RecordedLayout.has_uncertainty(record.schema)
        if decoders is None:
            return decode_states(record.data, msg_type, uncertainty=uncertainty)
        key = (record.topic, record.type_name, uncertainty)
        decoder = decoders.get(key)
        if decoder is None:
            decoder = decoders[key] = StateDecoder(msg_type, uncertainty=uncertainty)
        return decoder(record.data)
    except CdrError:
        return None  # the node rejected it the same way; nothing entered the scene


def static_from_json(text: str) -> StaticSettings | None:
    """The node's static settings from its recorded configuration (None: no static inputs)."""
    values = json.loads(text).get("static")
    if not values:
        return None
    values = dict(values, polygon_topics=tuple(values.get("polygon_topics", ())))
    names = {f.name for f in fields(StaticSettings)}
    return StaticSettings(**{k: v for k, v in values.items() if k in names})


class StaticReplay:
    """The static world as the node had it: every recorded map and polygon message taken by the
    node's own rules (pipeline.static_scene), and each version applied where the node recorded
    that it applied it (``<node>/static_applied``), whatever the indexing took live."""

    MARKER_SUFFIX = "/static_applied"

    def __init__(self, settings: StaticSettings) -> None:
        self.settings = settings
        self.obstacles = StaticObstacles.from_settings(settings)
        self.versions = {self.obstacles.version: self.obstacles.copy()}

    def take(self, record: BagRecord, predictor: CollisionPredictor) -> None:
        taken = self.obstacles.take(record.type_name, record.topic, record.data, self.settings,
                                    predictor.frame_id)
        if not taken.reason:
            if not predictor.frame_id:
                predictor.frame_id = taken.frame_id
            self.versions[self.obstacles.version] = self.obstacles.copy()

    def apply(self, record: BagRecord, predictor: CollisionPredictor) -> str:
        """Apply the recorded version; a reason if the recording names one never taken."""
        version = json.loads(decode_string(record.data)).get("version")
        world = self.versions.get(version)
        if world is None:
            return f"static world version {version!r} applied but never received"
        predictor.set_static(build_index(world.world()))
        self.versions = {v: w for v, w in self.versions.items() if v >= version}
        return ""


def config_from_json(text: str) -> PredictorConfig:
    """PredictorConfig from the node's recorded configuration (unknown keys ignored)."""
    values = json.loads(text)
    names = {f.name for f in fields(PredictorConfig)}
    if "ego_ids" in values:
        values["ego_ids"] = tuple(values["ego_ids"])
    return PredictorConfig(**{k: v for k, v in values.items() if k in names})


@dataclass
class ReplayReport:
    """What a replay compared."""

    inputs: int = 0
    predictions: int = 0
    coalesced: int = 0  # inputs answered together with newer ones (all but one per prediction)
    completions: int = 0  # collision_probabilities messages compared
    pairs_compared: int = 0
    max_time_difference: float = 0.0
    mismatches: list[str] = field(default_factory=list)
    truncated: str | None = None  # what cut the bag short (tolerant reading), else None

    @property
    def ok(self) -> bool:
        return not self.mismatches


def compare_predictions(
    recorded: PredictionArray, replayed: PredictionArray, where: str, report: ReplayReport
) -> None:
    """Field-by-field comparison; exact, because replay must be bit-identical."""
    if (recorded.header, recorded.horizon) != (replayed.header, replayed.horizon):
        report.mismatches.append(f"{where}: header/horizon differ")
    a = {(p.id_a, p.id_b): p for p in recorded.predictions}
    b = {(p.id_a, p.id_b): p for p in replayed.predictions}
    for key in sorted(a.keys() | b.keys()):
        if key not in a or key not in b:
            side = "replay only" if key not in a else "recording only"
            report.mismatches.append(f"{where}: pair {key} {side}")
            continue
        report.pairs_compared += 1
        ta, tb = a[key].time_to_collision, b[key].time_to_collision
        if math.isfinite(ta) and math.isfinite(tb):
            report.max_time_difference = max(report.max_time_difference, abs(ta - tb))
        if a[key] != b[key]:
            report.mismatches.append(f"{where}: pair {key} differs (ttc {ta!r} vs {tb!r})")
    if [(p.id_a, p.id_b) for p in recorded.predictions] != [
        (p.id_a, p.id_b) for p in replayed.predictions
    ]:
        report.mismatches.append(f"{where}: prediction order differs")


def compare_completion(record: BagRecord, candidates: list[ScenePrediction],
                       report: ReplayReport) -> None:
    """A recorded collision_probabilities message against the completion of the replayed
    prediction it completes: one of `candidates` (the predictions replayed at its log time;
    more than one only when the clock stood still between them), newest first."""
    report.completions += 1
    where = f"probabilities #{report.completions}"
    if not candidates:
        report.mismatches.append(f"{where}: no prediction at its log time {record.log_time_ns}")
        return
    newest = None
    for prediction in reversed(candidates):
        completed = prediction.completed()
        data = completed.to_cdr()
        if data == record.data:
            report.pairs_compared += len(completed.columns)
            return
        newest = newest or data
    before = len(report.mismatches)
    compare_predictions(decode_prediction_array(record.data), decode_prediction_array(newest),
                        where, report)
    if len(report.mismatches) == before:  # equal fields, other bytes (padding)
        report.mismatches.append(f"{where}: bytes differ")


PredictionHook = Callable[[int, PredictionArray, PredictionArray], None]
"""on_prediction(log_time_ns, recorded, replayed), called once per compared prediction."""


def replay_offline(
    records, config: PredictorConfig | None = None, on_prediction: PredictionHook | None = None
) -> ReplayReport:
    """Re-run recorded records (BagRecord iterable, recorded order) through CollisionPredictor.

    Each input is received at its recorded log time; each recorded prediction is
    recomputed at its log time (the node records predictions with the clock
    reading it computed them at) and compared.

    Coalescing needs no extra record: the node records every input as it
    takes it and each prediction after the inputs it answers, all on one
    thread, so log-time order (ties in file order) is the node's order of work.
    The inputs between two predictions are the ones the node coalesced; a run
    of CircleState records with one log time is one drain's group, merged as
    the node merged it (pipeline/state_groups).
    """
    report = ReplayReport()
    predictor = CollisionPredictor(config) if config is not None else None
    odometry: dict[str, OdometrySource] = {}
    decoders: dict = {}  # a StateDecoder per input topic, as the node keeps
    probabilities_topic = None  # the node's collision_probabilities (its recorded config)
    # the predictions of the newest log time: a completion carries its prediction's log time
    same_time: list[ScenePrediction] = []
    same_time_ns = None
    unanswered = 0  # inputs since the last prediction: the node coalesced them into the next one
    run: list[bytes] = []  # consecutive CircleState records of one log time: one node drain
    run_time = -1
    run_layout = True
    static: StaticReplay | None = None

    def flush() -> None:
        nonlocal run
        if run:
            ingest_single_states(predictor, run, run_time, uncertainty=run_layout)
            run = []

    for record in records:
        if run and not (record.type_name == RecordedTypes.STATE and record.log_time_ns == run_time):
            flush()
        if record.type_name == RecordedTypes.CONFIG and record.topic.endswith(
                StaticReplay.MARKER_SUFFIX):
            if static is None or predictor is None:
                report.mismatches.append(f"{record.topic}: a static world applied without a "
                                         "recorded static configuration")
            else:
                problem = static.apply(record, predictor)
                if problem:
                    report.mismatches.append(f"{record.topic}: {problem}")
            continue
        if record.type_name == RecordedTypes.CONFIG:
            text = decode_string(record.data)
            recorded = config_from_json(text)
            odometry = odometry_from_json(text) or odometry
            probabilities_topic = json.loads(text).get("probabilities_topic", probabilities_topic)
            settings = static_from_json(text)
            if settings is not None and static is None:
                static = StaticReplay(settings)
            if predictor is None:
                predictor = CollisionPredictor(recorded)
            else:
                predictor.reconfigure(**{k: getattr(recorded, k) for k in RUNTIME_FIELDS})
            continue
        if predictor is None:
            predictor = CollisionPredictor(PredictorConfig())  # bag without a config record
        if record.type_name in STATIC_TYPES:
            if static is not None:
                static.take(record, predictor)
            continue
        if record.type_name == RecordedTypes.STATE:
            run.append(record.data)
            run_time = record.log_time_ns
            run_layout = RecordedLayout.has_uncertainty(record.schema)
            report.inputs += 1
            unanswered += 1
        elif record.type_name in RecordedTypes.INPUTS:
            batch = decode_input(record, odometry, decoders)
            if batch is not None:
                predictor.receive_batch(batch, record.log_time_ns)
            report.inputs += 1
            unanswered += 1
        elif record.type_name == RecordedTypes.PREDICTIONS and record.topic == probabilities_topic:
            candidates = same_time if same_time_ns == record.log_time_ns else []
            compare_completion(record, candidates, report)
        elif record.type_name == RecordedTypes.PREDICTIONS:
            report.coalesced += max(0, unanswered - 1)
            unanswered = 0
            # Untrusted bytes: decoded by prediction_codec, never by rclpy's deserializer.
            horizon, entries = peek_prediction_array(record.data)
            predictor.expire(record.log_time_ns)
            # The same bytes the node publishes. Equal bytes are equal fields (the node
            # records its own encoder's output, padding included); only a difference
            # needs decoding and the field-by-field comparison that says what differs.
            layout = RecordedLayout.has_uncertainty(record.schema)
            prediction = predictor.predict(horizon=horizon)
            replayed_bytes = prediction.to_cdr(uncertainty=layout)
            if same_time_ns != record.log_time_ns:
                same_time, same_time_ns = [], record.log_time_ns
            same_time.append(prediction)
            report.predictions += 1
            if replayed_bytes == record.data:
                report.pairs_compared += entries
                if on_prediction is not None:
                    recorded = decode_prediction_array(record.data, uncertainty=layout)
                    on_prediction(record.log_time_ns, recorded, recorded)
            else:
                recorded = decode_prediction_array(record.data, uncertainty=layout)
                replayed = decode_prediction_array(replayed_bytes, uncertainty=layout)
                compare_predictions(recorded, replayed, f"prediction #{report.predictions}", report)
                if on_prediction is not None:
                    on_prediction(record.log_time_ns, recorded, replayed)
    flush()
    return report


def load_bag(
    path: str | os.PathLike[str], tolerant: bool = False
) -> tuple[BagContents, list[BagRecord]]:
    """Open a recording and read its records; BagError if it holds no circle states to replay."""
    bag = open_bag(path, tolerant=tolerant,
                   message_types=RECORDED_TYPES | {RecordedTypes.CONFIG, *STATIC_TYPES})
    records = list(bag.records())
    if not any(r.type_name in RecordedTypes.INPUTS for r in records):
        # One line, also when truncated (tests/reliability/test_fuzz_replay.py).
        note = f" (truncated: {bag.problem})" if bag.truncated else ""
        raise BagError(f"{bag.path}: no recorded circle states to replay{note}")
    return bag, records


def replay_bag(path: str | os.PathLike[str], *, tolerant: bool = False,
               on_prediction: PredictionHook | None = None) -> ReplayReport:
    """Replay one recording offline (the single-bag engine that the corpus runner and plugin call).

    Raises BagError when the bag cannot be read; a message that does not
    decode as its recorded type raises as its decoder does.
    """
    bag, records = load_bag(path, tolerant)
    report = replay_offline(records, on_prediction=on_prediction)
    report.truncated = bag.problem if bag.truncated else None
    return report
