"""replay: re-run a recorded collision_node session offline, or republish its inputs.

`replay BAG` feeds the recorded inputs, in recorded order and with their
recorded receive times, through the same CollisionPredictor the node uses, and
compares every recorded prediction with the recomputed one, field by field
(floats must be bit-identical; the engine is replay_engine.py). It prints
messages replayed, pairs compared and the largest time difference, and exits 1
on any mismatch.

`replay DIR...` (several bags, parent folders, globs) replays a whole corpus in
parallel, locally or on a Dask cluster, and prints one summary (corpus.py).

`replay BAG --publish` instead republishes the recorded inputs on their topics
at the recorded pace (scaled by --rate), so a live node can be tested against
a recording.
"""
from __future__ import annotations

import argparse
import math
import struct
import signal
import sys
import time

from circle_collision_ros.pipeline.cdr import CDR_BE, CdrError
from circle_collision_ros.pipeline.state_codec import (decode_states, encode_state,
                                                       encode_state_array)
from circle_collision_ros.recording import corpus
from circle_collision_ros.recording.bag_reader import BagError, BagRecord
from circle_collision_ros.recording.replay_engine import (RecordedLayout, RecordedTypes, load_bag,
                                                          replay_offline)


def current_layout_bytes(record: BagRecord) -> bytes:
    """The record's input bytes in the current interface layout (republishing an older recording).

    A CircleState(Array) recorded before CircleState had `covariance` is decoded by its
    recorded layout and written again with an empty covariance (the same states; the array
    header's frame is carried by each state, as the node reads it). Anything else is returned
    unchanged.
    """
    if record.type_name not in (
        RecordedTypes.STATE,
        RecordedTypes.STATE_ARRAY,
    ) or RecordedLayout.has_uncertainty(record.schema):
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
                publishers[r.topic] = node.create_publisher(
                    RecordedTypes.INPUTS[r.type_name], r.topic, qos
                )
        missing = _wait_for_subscribers(node, publishers, wait_s)
        if missing:
            print(
                f"replay: no subscriber on {', '.join(missing)} after {wait_s:g} s; "
                "publishing anyway",
                file=sys.stderr,
            )
        time.sleep(MATCH_GRACE_S)
        start_wall = time.monotonic()
        start_log = inputs[0].log_time_ns if inputs else 0
        for r in inputs:
            delay = (r.log_time_ns - start_log) * 1e-9 / rate - (time.monotonic() - start_wall)
            if delay > 0:
                time.sleep(delay)
            try:
                data = current_layout_bytes(r)  # the recorded bytes, unchanged unless recorded in
            except CdrError:  # an older layout (then the same states, re-encoded)
                # malformed as recorded: sent as recorded, the node rejects it as before
                data = r.data
            publishers[r.topic].publish(data)
            sent += 1
    except KeyboardInterrupt:
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return sent


def main(args: list[str] | None = None) -> int:
    # Ctrl-C ends a replay with its partial summary also when the shell started it with SIGINT
    # ignored (a background job of a script): Python keeps an inherited SIG_IGN otherwise.
    signal.signal(signal.SIGINT, signal.default_int_handler)
    parser = argparse.ArgumentParser(prog="replay", description=__doc__.splitlines()[0])
    parser.add_argument(
        "bag",
        nargs="+",
        help="bag directory (metadata.yaml + .mcap) or .mcap file; several, parent "
        "folders (searched recursively) or globs replay a corpus",
    )
    parser.add_argument("--publish", action="store_true",
                        help="republish the recorded inputs on their topics instead of comparing")
    parser.add_argument("--rate", type=float, default=1.0,
                        help="pace factor for --publish (2 = twice as fast; default 1)")
    parser.add_argument(
        "--wait-for-subscribers",
        type=float,
        default=10.0,
        metavar="SECONDS",
        help="with --publish: wait up to this long for a subscriber on every input "
        "topic before the first message (default 10)",
    )
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
        truncated_note = (
            f"replay: {opts.bag}: truncated ({bag.problem}); using what was complete"
            if bag.truncated
            else ""
        )
        if opts.publish:
            if truncated_note:
                print(truncated_note, file=sys.stderr)
            print(
                f"replay: published "
                f"{republish(records, opts.rate, opts.wait_for_subscribers)} input messages"
            )
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
    print(f"messages replayed: {report.inputs} inputs, {report.predictions} predictions"
          + (f", {report.completions} probability completions" if report.completions else ""))
    print(f"pairs compared: {report.pairs_compared}")
    print(f"largest time difference: {report.max_time_difference!r} s")
    if report.predictions == 0:
        print("replay: the bag holds no recorded predictions to compare", file=sys.stderr)
        return 1
    if not report.ok:
        print(
            f"MISMATCH: {len(report.mismatches)} difference(s); first: "
            + "; ".join(report.mismatches[:5]),
            file=sys.stderr,
        )
        return 1
    print("replay: all predictions identical")
    return 0


if __name__ == "__main__":
    sys.exit(main())
