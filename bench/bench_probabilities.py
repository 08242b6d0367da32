#!/usr/bin/env python3
"""Probabilities at tracker scale, live: collision_predictions and collision_probabilities.

    .venv/bin/python bench/bench_probabilities.py [--bodies 1000] [--rate 30] [--seconds 10]
                                                  [--sigma 0.3] [--velocity-sigma 0.2]
                                                  [--check 20] [--samples 1000000]

collision_node runs as its own process with its default parameters (covariance on,
uncertain_pair_budget 4, markers on). This script publishes CircleStateArray frames of
--bodies moving bodies at --rate Hz, every body with a diagonal covariance (position sigma
--sigma m, velocity sigma --velocity-sigma m/s), each frame stamped with its send time, and
receives both topics. Per topic it prints:

- latency: receive time minus the message's header stamp (= the send time of the frame it
  answers; DDS both ways and the node included), p50 / p99 / max;
- uncertain rows published, placeholders (probability 1.0 with bound 1.0), and the share with a
  stated bound <= 0.01;
- frames answered (a topic may answer fewer frames than were sent: the node coalesces inputs,
  and collision_probabilities completes the newest prediction only);
- per third of the run: rows per collision_predictions message (the scene's work) and
  collision_probabilities latency (the scene brings more pairs within reach as it runs);
- where the probabilities' latency goes: per frame answered on both topics, the exact answer's
  latency and the completion after it (probabilities receive time minus the exact answer's),
  p50 / p90 / p99, and the frames whose probabilities came later than one frame period
  (1 / --rate), with how many of those followed another such frame (a completion that overran
  delays the next one);
- what the node's /diagnostics said over the measured frames: its count of late completions
  (``probabilities_late``: published after the next prediction was handed over) and
  superseded predictions, and how many of its reports were WARN for falling behind.

Then --check rows sampled from the last collision_probabilities messages are checked against an
independent --samples Monte Carlo on the same states (core.narrow.time_to_collision on sampled
relative states): |P - MC| <= stated bound + 4 standard errors.

Writes what it prints to bench/results/probabilities.md (--out; "" prints only).
"""

from __future__ import annotations

import argparse
import sys
import threading
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import ROOT  # noqa: E402
from bench_node import ArrayFrames  # noqa: E402  (sets the ROS environment defaults first)

import rclpy  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402

from circle_collision_msgs.msg import CircleStateArray, CollisionPredictionArray  # noqa: E402
from circle_collision_ros.core.narrow import time_to_collision  # noqa: E402
from circle_collision_ros.demo.demo_scene import SyntheticScene  # noqa: E402
from circle_collision_ros.pipeline.prediction_codec import decode_prediction_array  # noqa: E402
from circle_collision_ros.pipeline.state_batch import StateBatch  # noqa: E402
from circle_collision_ros.pipeline.state_codec import encode_state_array  # noqa: E402

TOPICS = ("collision_predictions", "collision_probabilities")


class CovarianceFrames(ArrayFrames):
    """ArrayFrames whose bodies carry diag(sigma^2 x3, velocity_sigma^2 x3)."""

    def __init__(self, scene: SyntheticScene, sigma: float, velocity_sigma: float) -> None:
        self.block = np.diag([sigma**2] * 3 + [velocity_sigma**2] * 3)
        super().__init__(scene, sigma)

    def _encode(self, scene: SyntheticScene, stamps: np.ndarray, stamp_ns: int) -> bytes:
        n = scene.count
        batch = StateBatch(ids=self._ids, frames=["map"] * n, stamp_ns=stamps, radius=scene.radii,
                           position=scene.p, velocity=scene.v, acceleration=scene.a,
                           remove=np.zeros(n, dtype=bool),
                           covariance=np.tile(self.block.ravel(), (n, 1)),
                           covariance_size=np.full(n, 36, dtype=np.int64))
        return encode_state_array(batch, stamp_ns, "map")


def monte_carlo(frame: dict, a: int, b: int, block: np.ndarray, horizon: float,
                samples: int, seed: int) -> tuple[float, float]:
    """(P, standard error): contact within the horizon of bodies a and b of a sent frame, both
    with covariance `block`, sampled in relative coordinates (independent bodies: the relative
    state's covariance is the sum)."""
    rng = np.random.default_rng(seed)
    D = 2
    sigma = (block + block)[np.ix_([0, 1, 3, 4], [0, 1, 3, 4])]
    z = rng.multivariate_normal(np.zeros(2 * D), sigma, size=samples)
    dp = frame["p"][a, :D] - frame["p"][b, :D] + z[:, :D]
    dv = frame["v"][a, :D] - frame["v"][b, :D] + z[:, D:]
    da = np.broadcast_to(frame["a"][a, :D] - frame["a"][b, :D], dp.shape)
    zero = np.zeros_like(dp)
    r = np.full(samples, frame["r"][a] + frame["r"][b])
    t = time_to_collision(dp, dv, np.ascontiguousarray(da), r, zero, zero, zero,
                          np.zeros(samples), horizon)
    p = float(np.mean(t <= horizon))
    return p, float(np.sqrt(max(p * (1 - p), 1.0 / samples) / samples))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--bodies", type=int, default=1000)
    parser.add_argument("--rate", type=float, default=30.0)
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--sigma", type=float, default=0.3)
    parser.add_argument("--velocity-sigma", type=float, default=0.2)
    parser.add_argument("--check", type=int, default=20)
    parser.add_argument("--samples", type=int, default=1_000_000)
    parser.add_argument("--out", default=str(Path(__file__).resolve().parent / "results"
                                             / "probabilities.md"))
    opts = parser.parse_args()
    lines: list[str] = []

    def say(text: str = "") -> None:
        print(text)
        lines.append(text)

    import os
    import signal
    import subprocess

    exe = os.path.join(sys.prefix, "lib", "circle_collision_ros", "collision_node")
    node = subprocess.Popen([exe, "--ros-args", "--log-level", "warn", "-p", "max_bodies:=100000"])
    rclpy.init()
    client = rclpy.create_node("bench_probabilities")
    lock = threading.Lock()
    received: dict[str, list[tuple[int, bytes]]] = {t: [] for t in TOPICS}

    def on_message(topic: str, data: bytes) -> None:
        now = time.time_ns()
        with lock:
            received[topic].append((now, data))

    for topic in TOPICS:
        client.create_subscription(CollisionPredictionArray, topic,
                                   lambda data, t=topic: on_message(t, data),
                                   QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE),
                                   raw=True)
    reports: list[dict[str, str]] = []  # the node's /diagnostics, values and message

    def on_diagnostics(msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name.endswith(": collision prediction"):
                with lock:
                    reports.append({**{kv.key: kv.value for kv in status.values},
                                    "message": status.message})

    client.create_subscription(DiagnosticArray, "/diagnostics", on_diagnostics, 10)
    pub = client.create_publisher(CircleStateArray, "circle_states",
                                  QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE))
    executor = SingleThreadedExecutor()
    executor.add_node(client)
    threading.Thread(target=executor.spin, daemon=True).start()
    try:
        deadline = time.monotonic() + 300  # a first start compiles
        while pub.get_subscription_count() == 0 and time.monotonic() < deadline:
            time.sleep(0.1)
        time.sleep(1.0)
        scene = SyntheticScene(opts.bodies, size=float(np.sqrt(opts.bodies * 333.0)),
                               dimensions=2, seed=opts.bodies)
        frames = CovarianceFrames(scene, opts.sigma, opts.velocity_sigma)
        period = 1.0 / opts.rate
        for _ in range(10):  # warm-up, not measured
            pub.publish(frames.bytes(scene, time.time_ns()))
            time.sleep(period)
        time.sleep(1.0)
        with lock:
            for t in TOPICS:
                received[t].clear()
            reports.clear()
        sent: dict[int, dict] = {}
        start = time.monotonic()
        next_send = start
        while time.monotonic() - start < opts.seconds:
            if time.monotonic() >= next_send:
                scene.step(period)
                stamp = time.time_ns()
                data = frames.bytes(scene, stamp)
                pub.publish(data)
                sent[stamp] = {"p": scene.p.copy(), "v": scene.v.copy(), "a": scene.a.copy(),
                               "r": scene.radii.copy()}
                next_send += period
            time.sleep(max(0.0, min(0.002, next_send - time.monotonic())))
        time.sleep(2.0)
    finally:
        executor.shutdown()
        node.send_signal(signal.SIGINT)
        try:
            node.wait(timeout=30)
        except subprocess.TimeoutExpired:
            node.kill()
        client.destroy_node()
        rclpy.try_shutdown()

    say(f"{opts.bodies} bodies in CircleStateArray frames at {opts.rate:g} Hz for "
          f"{opts.seconds:g} s ({len(sent)} frames), position sigma {opts.sigma} m, velocity "
          f"sigma {opts.velocity_sigma} m/s on every body; node defaults")
    say("| topic | frames answered | latency p50 ms | p99 ms | max ms | uncertain rows | "
          "placeholders | bound <= 0.01 |")
    say("|---|---:|---:|---:|---:|---:|---:|---:|")
    decoded = {}
    for topic in TOPICS:
        msgs = [(t, decode_prediction_array(d)) for t, d in received[topic]]
        msgs = [(t, m) for t, m in msgs if m.header[0] * 10**9 + m.header[1] in sent]
        decoded[topic] = msgs
        lat = np.array([(t - (m.header[0] * 10**9 + m.header[1])) * 1e-6 for t, m in msgs]
                       or [np.nan])
        rows = [p for _, m in msgs for p in m.predictions]
        bound = np.array([p.collision_probability_bound for p in rows])
        prob = np.array([p.collision_probability for p in rows])
        holders = int(np.count_nonzero((prob == 1.0) & (bound == 1.0)))
        tight = 100.0 * np.count_nonzero(bound <= 0.01) / max(bound.size, 1)
        say(f"| {topic} | {len(msgs)} | {np.percentile(lat, 50):.1f} | "
              f"{np.percentile(lat, 99):.1f} | {lat.max():.1f} | {bound.size} | {holders} | "
              f"{tight:.2f} % |")
    say("\nBy third of the run: the completion's work grows with the pairs the scene brings within "
        "reach of each other (rows per collision_predictions message):")
    say("| third | collision_predictions rows per message | collision_probabilities p50 ms | "
        "p99 ms |")
    say("|---|---:|---:|---:|")
    order = sorted(sent)
    cuts = [order[len(order) * i // 3] for i in range(3)] + [order[-1] + 1]
    for i in range(3):
        def within(m, i=i):
            return cuts[i] <= m.header[0] * 10**9 + m.header[1] < cuts[i + 1]
        rows = [len(m.predictions) for _, m in decoded["collision_predictions"] if within(m)]
        lat = [(t - (m.header[0] * 10**9 + m.header[1])) * 1e-6
               for t, m in decoded["collision_probabilities"] if within(m)] or [np.nan]
        say(f"| {i + 1} | {np.mean(rows) if rows else np.nan:.0f} | "
            f"{np.percentile(lat, 50):.1f} | {np.percentile(lat, 99):.1f} |")
    exact_at = {m.header[0] * 10**9 + m.header[1]: t for t, m in decoded["collision_predictions"]}
    both = [(exact_at[s] - s, t - exact_at[s], t - s) for t, m in decoded["collision_probabilities"]
            for s in [m.header[0] * 10**9 + m.header[1]] if s in exact_at]
    if both:
        exact_ms, after_ms, total_ms = (np.array(x) * 1e-6 for x in zip(*both))
        late = total_ms > 1e3 / opts.rate
        say(f"\nWhere the probabilities' latency goes ({len(both)} frames answered on both "
            "topics):")
        say("| part | p50 ms | p90 ms | p99 ms |")
        say("|---|---:|---:|---:|")
        for name, x in (("exact answer (collision_predictions)", exact_ms),
                        ("completion after it", after_ms), ("collision_probabilities", total_ms)):
            say(f"| {name} | {np.percentile(x, 50):.1f} | {np.percentile(x, 90):.1f} | "
                f"{np.percentile(x, 99):.1f} |")
        say(f"frames later than one period ({1e3 / opts.rate:.1f} ms): {int(late.sum())}, of which "
            f"{int((late[1:] & late[:-1]).sum())} right after another late one")
    if len(reports) >= 2:
        first, last = reports[0], reports[-1]

        def grew(key: str) -> int:
            return int(last[key]) - int(first[key])

        behind = sum("falls behind" in r["message"] for r in reports[1:])
        say(f"node /diagnostics over the run ({len(reports) - 1} reports): "
            f"{grew('probabilities_late')} of {grew('probabilities_published')} completions late, "
            f"{grew('probabilities_superseded')} predictions superseded; WARN for falling behind "
            f"in {behind} reports")
    msgs = decoded["collision_probabilities"][-5:]
    if opts.check and msgs:
        rng = np.random.default_rng(7)
        pool = [(m, p) for _, m in msgs for p in m.predictions]
        picks = rng.choice(len(pool), size=min(opts.check, len(pool)), replace=False)
        block = np.diag([opts.sigma**2] * 3 + [opts.velocity_sigma**2] * 3)
        bad = 0
        say(f"\n{len(picks)} rows of the last {len(msgs)} collision_probabilities messages vs "
              f"{opts.samples:,}-sample Monte Carlo on the same states:")
        say("| pair | P | bound | MC | MC se | within bound + 4 se |")
        say("|---|---:|---:|---:|---:|:---|")
        for k, j in enumerate(picks.tolist()):
            m, row = pool[j]
            frame = sent[m.header[0] * 10**9 + m.header[1]]
            a, b = int(row.id_a[1:]), int(row.id_b[1:])
            mc, se = monte_carlo(frame, a, b, block, m.horizon, opts.samples, seed=k)
            ok = abs(row.collision_probability - mc) <= row.collision_probability_bound + 4 * se
            bad += not ok
            say(f"| {row.id_a}-{row.id_b} | {row.collision_probability:.4f} | "
                  f"{row.collision_probability_bound:.4f} | {mc:.4f} | {se:.4f} | "
                  f"{'yes' if ok else 'NO'} |")
        say(f"rows outside: {bad} of {len(picks)}")
    if opts.out:
        # path arguments inside the repository (run_all's --out) shown relative to it
        command = " ".join(["bench/bench_probabilities.py",
                            *(a.replace(f"{ROOT}/", "") for a in sys.argv[1:])])
        text = "\n".join(lines)
        Path(opts.out).write_text(f"# Probabilities at tracker scale, live\n\n"
                                  f"`.venv/bin/python {command}`\n\n{text}\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
