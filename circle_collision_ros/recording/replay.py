"""replay: re-run a recorded collision_node session offline, or republish its inputs.

`replay BAG` feeds the recorded inputs, in recorded order and with their
recorded receive times, through the same CollisionPredictor the node uses, and
compares every recorded prediction with the recomputed one, field by field
(floats must be bit-identical). It prints messages replayed, pairs compared and
the largest time difference, and exits 1 on any mismatch.

`replay DIR...` (several bags, parent folders, globs) replays a whole corpus in
parallel, locally or on a Dask cluster, and prints one summary (corpus.py).

`replay BAG --publish` instead republishes the recorded inputs on their topics
at the recorded pace (scaled by --rate), so a live node can be tested against
a recording.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import struct
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field, fields

from nav_msgs.msg import Odometry

from circle_collision_msgs.msg import CircleState, CircleStateArray
from circle_collision_ros.recording.bag_reader import (RECORDED_TYPES, BagContents, BagError, BagRecord,
                                                      open_bag)
from circle_collision_ros.pipeline.cdr_codec import (CDR_BE, CdrError, decode_states, encode_state,
                                                    encode_state_array)
from circle_collision_ros.pipeline.odometry import (ODOMETRY_TYPE, OdometrySource,
                                                   odometry_batch)
from circle_collision_ros.pipeline.state_batch import StateBatch
from circle_collision_ros.pipeline.predictor import RUNTIME_FIELDS, CollisionPredictor, PredictorConfig
from circle_collision_ros.pipeline.state_groups import ingest_single_states
from circle_collision_ros.recording.ros_type_definitions import DefinitionFormat
from circle_collision_ros.recording.prediction_cdr import (PredictionArray, decode_prediction_array, decode_string,
                                                           peek_prediction_array)


class RecordedTypes:
    """Type names as they appear in a recording (rosbag2 form)."""

    STATE_ARRAY = "circle_collision_msgs/msg/CircleStateArray"
    STATE = "circle_collision_msgs/msg/CircleState"
    ODOMETRY = ODOMETRY_TYPE
    PREDICTIONS = "circle_collision_msgs/msg/CollisionPredictionArray"
    CONFIG = "std_msgs/msg/String"
    INPUTS = {STATE_ARRAY: CircleStateArray, STATE: CircleState, ODOMETRY: Odometry}


class RecordedLayout:
    """Which layout of our interfaces a recorded schema text describes (see cdr_codec, "Two layouts").

    A recording made before issue 18 embeds CircleState without `covariance` and
    CollisionPrediction without `collision_probability`; replay decodes its inputs and
    writes its predictions in that layout, so it compares bit for bit. A schema that
    names neither type (empty: not recorded by us) is taken as the current layout.
    """

    _FIELD = {"circle_collision_msgs/CircleState": "covariance",
              "circle_collision_msgs/CollisionPrediction": "collision_probability"}
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
                return any(line.split("#", 1)[0].split()[1:2] == [field] for line in text.splitlines())
        # The root type is CircleState itself (single-state topics)
        if any(line.split("#", 1)[0].split()[1:2] == ["remove"] for line in sections[0].splitlines()):
            return any(line.split("#", 1)[0].split()[1:2] == ["covariance"] for line in sections[0].splitlines())
        return True


def odometry_from_json(text: str) -> dict[str, OdometrySource]:
    """Odometry topic -> OdometrySource from the node's recorded configuration."""
    return {topic: OdometrySource(**source) for topic, source in json.loads(text).get("odometry", {}).items()}


def decode_input(record: BagRecord, odometry: dict[str, OdometrySource]) -> StateBatch | None:
    """The StateBatch the node made of a recorded input, or None if it rejected it undecoded."""
    try:
        if record.type_name == RecordedTypes.ODOMETRY:
            source = odometry.get(record.topic)
            return odometry_batch(record.data, source) if source is not None else None
        return decode_states(record.data, RecordedTypes.INPUTS[record.type_name],
                             uncertainty=RecordedLayout.has_uncertainty(record.schema))
    except CdrError:
        return None  # the node rejected it the same way; nothing entered the scene


def config_from_json(text: str) -> PredictorConfig:
    """PredictorConfig from the node's recorded configuration (unknown keys ignored)."""
    values = json.loads(text)
    names = {f.name for f in fields(PredictorConfig)}
    return PredictorConfig(**{k: v for k, v in values.items() if k in names})


@dataclass
class ReplayReport:
    """What a replay compared."""

    inputs: int = 0
    predictions: int = 0
    coalesced: int = 0  # inputs answered together with newer ones (all but one per prediction)
    pairs_compared: int = 0
    max_time_difference: float = 0.0
    mismatches: list[str] = field(default_factory=list)
    truncated: str | None = None  # what cut the bag short (tolerant reading), else None

    @property
    def ok(self) -> bool:
        return not self.mismatches


def compare_predictions(recorded: PredictionArray, replayed: PredictionArray,
                        where: str, report: ReplayReport) -> None:
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
    if [(p.id_a, p.id_b) for p in recorded.predictions] != [(p.id_a, p.id_b) for p in replayed.predictions]:
        report.mismatches.append(f"{where}: prediction order differs")


PredictionHook = Callable[[int, PredictionArray, PredictionArray], None]
"""on_prediction(log_time_ns, recorded, replayed), called once per compared prediction."""


def replay_offline(records, config: PredictorConfig | None = None,
                   on_prediction: PredictionHook | None = None) -> ReplayReport:
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
    unanswered = 0  # inputs since the last prediction: the node coalesced them into the next one
    run: list[bytes] = []  # consecutive CircleState records of one log time: one node drain
    run_time = -1
    run_layout = True

    def flush() -> None:
        nonlocal run
        if run:
            ingest_single_states(predictor, run, run_time, uncertainty=run_layout)
            run = []

    for record in records:
        if run and not (record.type_name == RecordedTypes.STATE and record.log_time_ns == run_time):
            flush()
        if record.type_name == RecordedTypes.CONFIG:
            text = decode_string(record.data)
            recorded = config_from_json(text)
            odometry = odometry_from_json(text) or odometry
            if predictor is None:
                predictor = CollisionPredictor(recorded)
            else:
                predictor.reconfigure(**{k: getattr(recorded, k) for k in RUNTIME_FIELDS})
            continue
        if predictor is None:
            predictor = CollisionPredictor(PredictorConfig())  # bag without a config record
        if record.type_name == RecordedTypes.STATE:
            run.append(record.data)
            run_time = record.log_time_ns
            run_layout = RecordedLayout.has_uncertainty(record.schema)
            report.inputs += 1
            unanswered += 1
        elif record.type_name in RecordedTypes.INPUTS:
            batch = decode_input(record, odometry)
            if batch is not None:
                predictor.receive_batch(batch, record.log_time_ns)
            report.inputs += 1
            unanswered += 1
        elif record.type_name == RecordedTypes.PREDICTIONS:
            report.coalesced += max(0, unanswered - 1)
            unanswered = 0
            # Untrusted bytes: decoded by prediction_cdr, never by rclpy's deserializer.
            horizon, entries = peek_prediction_array(record.data)
            predictor.expire(record.log_time_ns)
            # The same bytes the node publishes. Equal bytes are equal fields (the node
            # records its own encoder's output, padding included); only a difference
            # needs decoding and the field-by-field comparison that says what differs.
            layout = RecordedLayout.has_uncertainty(record.schema)
            replayed_bytes = predictor.predict(horizon=horizon).to_cdr(uncertainty=layout)
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


def load_bag(path: str | os.PathLike[str], tolerant: bool = False) -> tuple[BagContents, list[BagRecord]]:
    """Open a recording and read its records; BagError if it holds no circle states to replay."""
    bag = open_bag(path, tolerant=tolerant, message_types=RECORDED_TYPES | {RecordedTypes.CONFIG})
    records = list(bag.records())
    if not any(r.type_name in RecordedTypes.INPUTS for r in records):
        # One line, also when truncated (tests/reliability/test_fuzz_replay.py).
        note = f" (truncated: {bag.problem})" if bag.truncated else ""
        raise BagError(f"{bag.path}: no recorded circle states to replay{note}")
    return bag, records


def replay_bag(path: str | os.PathLike[str], *, tolerant: bool = False,
               on_prediction: PredictionHook | None = None) -> ReplayReport:
    """Replay one recording offline (the single-bag engine the corpus runner and pytest plugin call).

    Raises BagError when the bag cannot be read; a message that does not
    decode as its recorded type raises as its decoder does.
    """
    bag, records = load_bag(path, tolerant)
    report = replay_offline(records, on_prediction=on_prediction)
    report.truncated = bag.problem if bag.truncated else None
    return report


def current_layout_bytes(record: BagRecord) -> bytes:
    """The record's input bytes in the current interface layout (republishing an older recording).

    A CircleState(Array) recorded before issue 18 is decoded by its recorded layout and
    written again with an empty covariance (the same states; the array header's frame is
    carried by each state, as the node reads it). Anything else is returned unchanged.
    """
    if record.type_name not in (RecordedTypes.STATE, RecordedTypes.STATE_ARRAY) \
            or RecordedLayout.has_uncertainty(record.schema):
        return record.data
    batch = decode_states(record.data, RecordedTypes.INPUTS[record.type_name], uncertainty=False)
    if record.type_name == RecordedTypes.STATE:
        return encode_state(batch)
    order = ">" if record.data[:2] == CDR_BE else "<"
    sec, nanosec = struct.unpack_from(f"{order}iI", record.data, 4)
    return encode_state_array(batch, sec * 1_000_000_000 + nanosec, "")


def _wait_for_subscribers(node, publishers: dict, timeout_s: float) -> list[str]:
    """Wait until every publisher has a matched subscription or `timeout_s` passes;
    returns the topics still without one."""
    deadline = time.monotonic() + timeout_s
    while True:
        missing = [t for t, pub in publishers.items() if pub.get_subscription_count() == 0]
        if not missing or time.monotonic() >= deadline:
            return missing
        time.sleep(0.05)


#: After the publisher sees a match, the subscriber's side of a best-effort match
#: may still be settling (the first sample can be lost): a short grace period.
MATCH_GRACE_S = 0.3


def republish(records: list[BagRecord], rate: float, wait_s: float = 10.0) -> int:
    """Publish recorded inputs on their topics at recorded pace / rate; returns count.

    Publishing starts once every input topic has a subscriber (the node), or after
    `wait_s` seconds with a note on stderr naming the topics nobody listens to."""
    import rclpy
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    from circle_collision_ros.cli import apply_ros_environment_defaults

    apply_ros_environment_defaults()
    rclpy.init()
    node = rclpy.create_node("replay")
    qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
    publishers = {}
    sent = 0
    try:
        inputs = [r for r in records if r.type_name in RecordedTypes.INPUTS]
        for r in inputs:
            if r.topic not in publishers:
                publishers[r.topic] = node.create_publisher(RecordedTypes.INPUTS[r.type_name], r.topic, qos)
        missing = _wait_for_subscribers(node, publishers, wait_s)
        if missing:
            print(f"replay: no subscriber on {', '.join(missing)} after {wait_s:g} s; publishing anyway",
                  file=sys.stderr)
        time.sleep(MATCH_GRACE_S)
        start_wall = time.monotonic()
        start_log = inputs[0].log_time_ns if inputs else 0
        for r in inputs:
            delay = (r.log_time_ns - start_log) * 1e-9 / rate - (time.monotonic() - start_wall)
            if delay > 0:
                time.sleep(delay)
            try:
                data = current_layout_bytes(r)  # the recorded bytes, unchanged unless recorded in
            except CdrError:                    # an older layout (then the same states, re-encoded)
                data = r.data  # malformed as recorded: sent as recorded, the node rejects it as before
            publishers[r.topic].publish(data)
            sent += 1
    except KeyboardInterrupt:
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return sent


def main(args: list[str] | None = None) -> int:
    from circle_collision_ros.recording import corpus  # imports this module

    parser = argparse.ArgumentParser(prog="replay", description=__doc__.splitlines()[0])
    parser.add_argument("bag", nargs="+",
                        help="bag directory (metadata.yaml + .mcap) or .mcap file; several, parent "
                             "folders (searched recursively) or globs replay a corpus")
    parser.add_argument("--publish", action="store_true",
                        help="republish the recorded inputs on their topics instead of comparing")
    parser.add_argument("--rate", type=float, default=1.0,
                        help="pace factor for --publish (2 = twice as fast; default 1)")
    parser.add_argument("--wait-for-subscribers", type=float, default=10.0, metavar="SECONDS",
                        help="with --publish: wait up to this long for a subscriber on every input "
                             "topic before the first message (default 10)")
    parser.add_argument("--tolerant", action="store_true",
                        help="read a truncated bag (e.g. after a hard kill) up to its last chunk")
    corpus.add_arguments(parser)
    opts = parser.parse_args(sys.argv[1:] if args is None else args)
    if not (opts.rate > 0 and math.isfinite(opts.rate)):
        parser.error("--rate must be a positive number")
    if not (opts.wait_for_subscribers >= 0 and math.isfinite(opts.wait_for_subscribers)):
        parser.error("--wait-for-subscribers must be a number of seconds >= 0")
    if corpus.is_corpus_run(opts):
        if opts.publish:
            parser.error("--publish takes one bag")
        return corpus.run(opts)
    opts.bag = opts.bag[0]
    try:
        bag, records = load_bag(opts.bag, opts.tolerant)
        truncated_note = (f"replay: {opts.bag}: truncated ({bag.problem}); using what was complete"
                          if bag.truncated else "")
        if opts.publish:
            if truncated_note:
                print(truncated_note, file=sys.stderr)
            print(f"replay: published {republish(records, opts.rate, opts.wait_for_subscribers)} input messages")
            return 0
        report = replay_offline(records)
        if truncated_note:  # only now: an error above must stay a single line
            print(truncated_note, file=sys.stderr)
    except BagError as exc:
        print(f"replay: {exc}", file=sys.stderr)
        return 2
    except Exception as exc:  # a message that does not decode as its recorded type, etc.
        print(f"replay: {opts.bag}: cannot replay: {exc!r}", file=sys.stderr)
        return 2
    print(f"messages replayed: {report.inputs} inputs, {report.predictions} predictions")
    print(f"pairs compared: {report.pairs_compared}")
    print(f"largest time difference: {report.max_time_difference!r} s")
    if report.predictions == 0:
        print("replay: the bag holds no recorded predictions to compare", file=sys.stderr)
        return 1
    if not report.ok:
        print(f"MISMATCH: {len(report.mismatches)} difference(s); first: "
              + "; ".join(report.mismatches[:5]), file=sys.stderr)
        return 1
    print("replay: all predictions identical")
    return 0


if __name__ == "__main__":
    sys.exit(main())
