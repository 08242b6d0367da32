"""Node latency through real DDS on localhost: input arrival to prediction publication.

    .venv/bin/python bench/bench_node.py [--bodies 100 1000] [--seconds 10] [--rate 30] [--quick]

For each scene size, collision_node runs as its own process (as users run it);
this script publishes a CircleStateArray of N moving bodies at --rate Hz, each
stamped with the send time, and receives the predictions. Because the node's
reference time is the newest stamp, each prediction's header.stamp names the
input it answers, so

- end-to-end latency = receive time of the prediction - time of the publish
  call of its input (DDS -> node -> DDS, on one machine; the input's bytes are
  built before that call, so building them is not counted);
- node latency = the node's own figure (callback entry -> publish), read from
  its /diagnostics (p50/p99 over its last 1000 updates).

Also reports the sustained rate: inputs sent as fast as possible for a few
seconds, predictions received per second. Prints a markdown table; --json
writes the figures for bench/results.
"""
from __future__ import annotations

import argparse
import json
import os
import signal
import struct
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")

import rclpy  # noqa: E402
from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402

from circle_collision_msgs.msg import CircleStateArray, CollisionPredictionArray  # noqa: E402
from circle_collision_ros.pipeline.cdr_codec import encode_state_array  # noqa: E402
from circle_collision_ros.demo.demo_scene import SyntheticScene  # noqa: E402
from circle_collision_ros.pipeline.state_batch import StateBatch  # noqa: E402


def scene_bytes(scene: SyntheticScene, stamp_ns: int) -> bytes:
    """The scene as serialized CircleStateArray bytes, every state stamped `stamp_ns`."""
    n = scene.count
    batch = StateBatch(ids=[f"b{k:05d}" for k in range(n)], frames=["map"] * n,
                       stamp_ns=np.full(n, stamp_ns, dtype=np.int64), radius=scene.radii,
                       position=scene.p, velocity=scene.v, acceleration=scene.a,
                       remove=np.zeros(n, dtype=bool))
    return encode_state_array(batch, stamp_ns, "map")


def _stamp_of(data: bytes) -> int:
    """header.stamp of serialized bytes (int32 sec, uint32 nanosec after the 4-byte CDR header)."""
    sec, nanosec = struct.unpack_from("<iI", data, 4)
    return sec * 1_000_000_000 + nanosec


def _percentiles(values: list[float]) -> tuple[float, float]:
    if not values:
        return float("nan"), float("nan")
    arr = np.array(values) * 1e3
    return float(np.percentile(arr, 50)), float(np.percentile(arr, 99))


def measure(bodies: int, seconds: float, rate: float) -> dict:
    """One scene size: start a node, drive it, collect latencies."""
    exe = os.path.join(sys.prefix, "lib", "circle_collision_ros", "collision_node")
    node_proc = subprocess.Popen([exe, "--ros-args", "-p", "marker_rate:=0.0", "-p", "max_bodies:=100000",
                                  "--log-level", "warn"])
    rclpy.init()
    client = rclpy.create_node("bench_node_client")
    latencies: list[float] = []
    received: list[int] = []
    published_at: dict[int, int] = {}  # input stamp -> wall time of the publish call
    diagnostics: dict[str, str] = {}

    def on_prediction(data: bytes) -> None:
        now = time.time_ns()
        sent = published_at.get(_stamp_of(data))
        if sent is not None:
            latencies.append((now - sent) * 1e-9)
        received.append(now)

    def publish(stamp_ns: int) -> None:
        data = scene_bytes(scene, stamp_ns)
        published_at[stamp_ns] = time.time_ns()
        pub.publish(data)

    def on_diagnostics(msg: DiagnosticArray) -> None:
        for status in msg.status:
            if "collision prediction" in status.name:
                diagnostics.update({kv.key: kv.value for kv in status.values})

    # Raw: only the stamp is read, so the client's own decoding adds nothing to the figures.
    client.create_subscription(CollisionPredictionArray, "collision_predictions", on_prediction, 100,
                               raw=True)
    client.create_subscription(DiagnosticArray, "/diagnostics", on_diagnostics, 10)
    pub = client.create_publisher(CircleStateArray, "circle_states",
                                  QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE))
    # The density of the scale scene (3,000 bodies per km^2): ~333 m^2 per body.
    scene = SyntheticScene(bodies, size=float(np.sqrt(bodies * 333.0)), dimensions=2, seed=bodies)
    try:
        deadline = time.monotonic() + 60
        while pub.get_subscription_count() == 0 and time.monotonic() < deadline:
            rclpy.spin_once(client, timeout_sec=0.1)
        # Warm-up: the first messages may meet cold caches; not measured.
        for _ in range(10):
            publish(time.time_ns())
            rclpy.spin_once(client, timeout_sec=1.0 / rate)
        end = time.monotonic() + 1.0
        while time.monotonic() < end:
            rclpy.spin_once(client, timeout_sec=0.05)
        latencies.clear()
        sent = 0
        period = 1.0 / rate
        start = time.monotonic()
        next_send = start
        while time.monotonic() - start < seconds:
            if time.monotonic() >= next_send:
                scene.step(period)
                publish(time.time_ns())
                sent += 1
                next_send += period
            rclpy.spin_once(client, timeout_sec=max(0.0, min(0.005, next_send - time.monotonic())))
        end = time.monotonic() + 2.0
        while time.monotonic() < end and len(latencies) < sent:
            rclpy.spin_once(client, timeout_sec=0.05)
        paced = list(latencies)
        diag_paced = dict(diagnostics)
        # Sustained: send as fast as the publisher can (each message still built from the scene).
        received.clear()
        burst_start = time.monotonic()
        burst_sent = 0
        while time.monotonic() - burst_start < min(3.0, seconds):
            publish(time.time_ns())
            burst_sent += 1
            rclpy.spin_once(client, timeout_sec=0.0)
        burst_time = time.monotonic() - burst_start
        end = time.monotonic() + 3.0
        while time.monotonic() < end:
            rclpy.spin_once(client, timeout_sec=0.05)
        e2e50, e2e99 = _percentiles(paced)
        return {
            "bodies": bodies, "rate_hz": rate, "sent": sent, "answered": len(paced),
            "e2e_p50_ms": e2e50, "e2e_p99_ms": e2e99,
            "node_p50_ms": float(diag_paced.get("latency_ms_p50", "nan")),
            "node_p99_ms": float(diag_paced.get("latency_ms_p99", "nan")),
            "candidate_pairs": int(diag_paced.get("candidate_pairs", "-1")),
            "contacts": int(diag_paced.get("contacts", "-1")),
            "burst_sent_per_s": burst_sent / burst_time,
            "burst_predictions_per_s": len(received) / burst_time,
        }
    finally:
        client.destroy_node()
        rclpy.try_shutdown()
        node_proc.send_signal(signal.SIGINT)
        try:
            node_proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            node_proc.kill()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--bodies", type=int, nargs="+", default=[100, 1000])
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--rate", type=float, default=30.0)
    parser.add_argument("--quick", action="store_true", help="3 s per size")
    parser.add_argument("--json", help="also write the figures to this file")
    opts = parser.parse_args()
    seconds = 3.0 if opts.quick else opts.seconds
    rows = [measure(n, seconds, opts.rate) for n in opts.bodies]
    print(f"| bodies | input Hz | answered/sent | end-to-end p50 ms | p99 ms | node p50 ms | node p99 ms"
          f" | candidate pairs | burst in/s | burst out/s |")
    print("|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        print(f"| {r['bodies']} | {r['rate_hz']:.0f} | {r['answered']}/{r['sent']} | {r['e2e_p50_ms']:.2f} |"
              f" {r['e2e_p99_ms']:.2f} | {r['node_p50_ms']:.2f} | {r['node_p99_ms']:.2f} |"
              f" {r['candidate_pairs']} | {r['burst_sent_per_s']:.0f} | {r['burst_predictions_per_s']:.0f} |")
    if opts.json:
        Path(opts.json).write_text(json.dumps(rows, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
