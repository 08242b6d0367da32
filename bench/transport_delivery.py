"""Frames delivered across two processes, by message size, QoS and transport profile.

    .venv/bin/python bench/transport_delivery.py [--sizes-kb 100 400 600 1200] [--count 150]
        [--rate 30] [--quick] [--json FILE]

A publisher process (reliable, depth 10, as a tracker typically publishes) sends
--count CircleStateArray messages of each size at --rate Hz; a subscriber process
counts the frames it receives. Rows compare, in the same run:

- Fast DDS defaults (FASTDDS_DEFAULT_PROFILES_FILE unset on both sides, SKIP_DEFAULT_XML_FILE=1);
- the shipped profile (config/fastdds_large_scenes.xml) on both sides;
- the shipped profile on the subscriber only (what a user gets who runs our node but
  not the profile in their own publisher), and on the publisher only;

each with a best-effort subscriber (the node's default) and a reliable KEEP_LAST 1
subscriber. This is the transport alone: the subscriber does no work.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import NamedTuple

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")

BYTES_PER_BODY = 120  # a CircleStateArray element with a 6-character id and "map" frame
TOPIC = "transport_probe"


def _profile_env(use_profile: bool) -> dict[str, str]:
    from circle_collision_ros.cli import TransportProfile

    env = dict(os.environ)
    env.pop(TransportProfile.DEPRECATED_ENV, None)
    if use_profile:
        env[TransportProfile.ENV] = str(TransportProfile.path())
        env.pop("SKIP_DEFAULT_XML_FILE", None)
    else:
        env.pop(TransportProfile.ENV, None)
        env["SKIP_DEFAULT_XML_FILE"] = "1"  # no DEFAULT_FASTDDS_PROFILES.xml from the cwd either
    return env


def publish(bodies: int, count: int, rate: float, wait_s: float, topic: str = TOPIC) -> None:
    """Publisher role: wait for a subscriber, send `count` frames stamped 1..count, exit."""
    import struct

    import numpy as np
    import rclpy
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    from circle_collision_msgs.msg import CircleStateArray
    from circle_collision_ros.pipeline.state_codec import encode_state_array
    from circle_collision_ros.pipeline.state_batch import StateBatch

    rclpy.init()
    node = rclpy.create_node("transport_probe_publisher")
    pub = node.create_publisher(
        CircleStateArray, topic, QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
    )
    rng = np.random.default_rng(1)
    batch = StateBatch(ids=[f"b{k:05d}" for k in range(bodies)], frames=["map"] * bodies,
                       stamp_ns=np.ones(bodies, dtype=np.int64), radius=np.full(bodies, 0.3),
                       position=rng.uniform(0, 100, (bodies, 3)),
                       velocity=rng.normal(size=(bodies, 3)), acceleration=np.zeros((bodies, 3)),
                       remove=np.zeros(bodies, dtype=bool))
    template = encode_state_array(batch, 0, "map")
    frames = []
    for k in range(1, count + 1):  # only header.stamp differs: patch it into a copy
        frame = bytearray(template)
        struct.pack_into("<iI", frame, 4, 0, k)
        frames.append(bytes(frame))
    deadline = time.monotonic() + wait_s
    while pub.get_subscription_count() == 0 and time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.05)
    time.sleep(0.5)  # let the reader's side of the match settle too
    period = 1.0 / rate
    start = time.monotonic()
    for k, frame in enumerate(frames):
        pub.publish(frame)
        pause = start + (k + 1) * period - time.monotonic()
        if pause > 0:
            time.sleep(pause)
    time.sleep(1.0)  # reliable writers may still be resending
    node.destroy_node()
    rclpy.shutdown()


def subscribe(reliable: bool, seconds: float) -> None:
    """Subscriber role: count distinct frames (by header stamp) until SIGINT or `seconds`, print
    JSON.

    Also feeds the node's InputLossMonitor, so each row shows whether the node's
    loss signal accounts for every frame that did not arrive.
    """
    import struct

    import rclpy
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

    from circle_collision_msgs.msg import CircleStateArray
    from circle_collision_ros.node.input_loss import InputLossMonitor

    rclpy.init()
    node = rclpy.create_node("transport_probe_subscriber")
    if reliable:
        qos = QoSProfile(
            history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE
        )
    else:
        qos = QoSProfile(
            history=HistoryPolicy.KEEP_LAST, depth=50, reliability=ReliabilityPolicy.BEST_EFFORT
        )
    seen: set[int] = set()
    monitor = InputLossMonitor()

    def on_frame(data: bytes, info) -> None:
        seen.add(struct.unpack_from("<iI", data, 4)[1])
        monitor.observe(TOPIC, len(data), info, time.monotonic_ns())

    node.create_subscription(CircleStateArray, TOPIC, on_frame, qos, raw=True)
    end = time.monotonic() + seconds
    try:
        while time.monotonic() < end:
            rclpy.spin_once(node, timeout_sec=0.05)
    except KeyboardInterrupt:  # the publisher is done: report
        pass
    first, last = (min(seen), max(seen)) if seen else (0, 0)
    print(
        json.dumps(
            {"received": len(seen), "detected_missing": monitor.missing, "first": first,
             "last": last}
        ),
        flush=True,
    )
    node.destroy_node()
    rclpy.shutdown()


class Delivery(NamedTuple):
    """One measurement: frames sent and received, and what the loss monitor accounted for."""

    sent: int
    received: int
    detected_missing: int  # gaps in the writer's sequence numbers seen by InputLossMonitor
    undetectable: int  # lost before the first or after the last received frame

    @property
    def accounted(self) -> bool:
        """Every frame that did not arrive was counted, or could not be (no later frame came)."""
        return self.received + self.detected_missing + self.undetectable == self.sent


def run_pair(
    size_kb: float, count: int, rate: float, pub_profile: bool, sub_profile: bool, reliable: bool
) -> Delivery:
    """One measurement: both roles as separate processes."""
    bodies = max(1, int(size_kb * 1000 / BYTES_PER_BODY))
    me = [sys.executable, str(Path(__file__).resolve())]
    sub = subprocess.Popen(
        me + ["--role", "sub", "--seconds", "600"] + (["--reliable"] if reliable else []),
        env=_profile_env(sub_profile),
        stdout=subprocess.PIPE,
        text=True,
    )
    pub = subprocess.Popen(
        me + ["--role", "pub", "--bodies", str(bodies), "--count", str(count), "--rate", str(rate)],
        env=_profile_env(pub_profile),
    )
    pub.wait(timeout=count / rate + 120)
    sub.send_signal(signal.SIGINT)
    out, _ = sub.communicate(timeout=30)
    row = json.loads(out.strip().splitlines()[-1])
    undetectable = (row["first"] - 1) + (count - row["last"]) if row["received"] else count
    return Delivery(count, row["received"], row["detected_missing"], undetectable)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--role", choices=("pub", "sub"), help=argparse.SUPPRESS)
    parser.add_argument("--bodies", type=int, default=0, help=argparse.SUPPRESS)
    parser.add_argument("--seconds", type=float, default=0.0, help=argparse.SUPPRESS)
    parser.add_argument("--reliable", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--topic", default=TOPIC, help=argparse.SUPPRESS)
    parser.add_argument("--sizes-kb", type=float, nargs="+", default=[100, 400, 600, 1200])
    parser.add_argument("--count", type=int, default=150)
    parser.add_argument("--rate", type=float, default=30.0)
    parser.add_argument("--quick", action="store_true", help="60 frames, sizes 400 and 1200 KB")
    parser.add_argument("--json", help="also write the rows to this file")
    opts = parser.parse_args()
    if opts.role == "pub":
        publish(opts.bodies, opts.count, opts.rate, wait_s=10.0, topic=opts.topic)
        return 0
    if opts.role == "sub":
        # stopped with SIGINT by its parent, also when the shell started us with it ignored
        signal.signal(signal.SIGINT, signal.default_int_handler)
        subscribe(opts.reliable, opts.seconds)
        return 0
    if opts.quick:
        opts.count, opts.sizes_kb = 60, [400, 1200]
    setups = [("Fast DDS defaults", False, False), ("shipped profile, both sides", True, True),
              ("shipped profile, subscriber only", False, True),
              ("shipped profile, publisher only", True, False)]
    rows = []
    print(
        "| message | set-up | best-effort reader | reliable KEEP_LAST 1 reader |\n|---|---|---|---|"
    )

    def cell(d: Delivery) -> str:
        check = "" if d.accounted else " (loss count off!)"
        return f"{d.received} / {d.sent}, {d.detected_missing} counted missing{check}"

    for size in opts.sizes_kb:
        for label, pub_profile, sub_profile in setups:
            best = run_pair(size, opts.count, opts.rate, pub_profile, sub_profile, reliable=False)
            rel = run_pair(size, opts.count, opts.rate, pub_profile, sub_profile, reliable=True)
            rows.append(
                {"size_kb": size, "setup": label, "best_effort": best._asdict(),
                 "reliable": rel._asdict()}
            )
            print(f"| {size:g} KB | {label} | {cell(best)} | {cell(rel)} |", flush=True)
    if opts.json:
        Path(opts.json).write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
