"""Node latency through real DDS on localhost: input arrival to prediction publication.

    .venv/bin/python bench/bench_node.py [--bodies 100 1000] [--seconds 10] [--rate 30] [--quick]

For each scene size, collision_node runs as its own process (as users run it);
this script publishes a CircleStateArray of N moving bodies at --rate Hz, each
stamped with the send time, and receives the predictions. Because the node's
reference time is the newest stamp, each prediction's header.stamp names the
input it answers, so

- end-to-end latency = receive time of the prediction - stamp of its input
  (publisher -> DDS -> node -> DDS -> subscriber, on one machine);
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
from circle_collision_ros.demo_scene import SyntheticScene  # noqa: E402
from circle_collision_ros.prediction_messages import ns_to_time  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from tests.ros.node_helpers import state  # noqa: E402


def _scene_message(scene: SyntheticScene, stamp_ns: int) -> CircleStateArray:
    msg = CircleStateArray()
    msg.header.stamp = ns_to_time(stamp_ns)
    msg.header.frame_id = "map"
    msg.circles = [state(f"b{k:05d}", scene.p[k], scene.v[k], scene.a[k], float(scene.radii[k]),
                         stamp_ns=stamp_ns) for k in range(scene.count)]
    return msg


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
    diagnostics: dict[str, str] = {}

    def on_prediction(msg: CollisionPredictionArray) -> None:
        now = time.time_ns()
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        latencies.append((now - stamp) * 1e-9)
        received.append(now)

    def on_diagnostics(msg: DiagnosticArray) -> None:
        for status in msg.status:
            if "collision prediction" in status.name:
                diagnostics.update({kv.key: kv.value for kv in status.values})

    client.create_subscription(CollisionPredictionArray, "collision_predictions", on_prediction, 100)
    client.create_subscription(DiagnosticArray, "/diagnostics", on_diagnostics, 10)
    pub = client.create_publisher(CircleStateArray, "circle_states",
                                  QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE))
    scene = SyntheticScene(bodies, size=max(60.0, 6.0 * np.sqrt(bodies)), dimensions=2, seed=bodies)
    try:
        deadline = time.monotonic() + 60
        while pub.get_subscription_count() == 0 and time.monotonic() < deadline:
            rclpy.spin_once(client, timeout_sec=0.1)
        # Warm-up: the first messages may meet cold caches; not measured.
        for _ in range(10):
            pub.publish(_scene_message(scene, time.time_ns()))
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
                pub.publish(_scene_message(scene, time.time_ns()))
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
            pub.publish(_scene_message(scene, time.time_ns()))
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
