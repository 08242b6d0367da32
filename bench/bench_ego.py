"""Ego-centred prediction: the node's work per frame with one ego body against all pairs.

    .venv/bin/python bench/bench_ego.py [--bodies 10000] [--frames 60] [--quick] [--out DIR]

One process, the same frames for both: N bodies (bench_scene.make_scene: uniform in a square
of side sqrt(N) * 10 m, |v| <= 3 m/s, |a| <= 0.5 m/s^2) moving every frame at 30 Hz, as
CircleStateArray bytes. Per frame, the work the node does from the message to the bytes it
publishes: decode, merge (CollisionPredictor.receive_batch), predict, encode (to_cdr). One
predictor answers all pairs; the other has ego_ids = one body (the body with the most
contacts in the first frame). Each has its own StateDecoder, as each node's subscription
has. The two take turns in blocks of 5 frames (the headline figure), so the machine's load
moves both alike while each starts a frame from its own caches, as a node running one of them
does; then frame by frame, where each starts from the caches the other filled (a cost no
single node pays, printed for comparison). Prints the median and p90 per frame and the ratio
of medians (target: ego <= 1/10 of all pairs), and checks that the ego rows are the all-pairs
rows with the ego body. Writes bench/results/ego.md.
"""
from __future__ import annotations

import argparse
import math
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from _common import HERE, md_table  # noqa: F401 (sets sys.path for the package)
from bench_scene import make_scene
import machine

from circle_collision_msgs.msg import CircleStateArray
from circle_collision_ros.pipeline.predictor import CollisionPredictor, PredictorConfig
from circle_collision_ros.pipeline.state_batch import StateBatch
from circle_collision_ros.pipeline.state_codec import StateDecoder, encode_state_array

T0 = 1_700_000_000 * 1_000_000_000
FRAME_NS = 33_333_333


def frames(n: int, count: int, seed: int = 1) -> list[bytes]:
    """``count`` CircleStateArray frames of n bodies moving under constant acceleration."""
    rng = np.random.default_rng(seed)
    p, v, a, r = make_scene(n, math.sqrt(n) * 10.0, rng)
    ids = [f"b{k:05d}" for k in range(n)]
    out = []
    for f in range(count):
        t = f * FRAME_NS * 1e-9
        z = np.zeros((n, 1))
        pos = p + t * (v + 0.5 * t * a)
        vel = v + t * a
        stamp = T0 + f * FRAME_NS
        batch = StateBatch(ids=ids, frames=["map"] * n, stamp_ns=np.full(n, stamp, np.int64),
                           radius=r, position=np.hstack([pos, z]), velocity=np.hstack([vel, z]),
                           acceleration=np.hstack([a, z]), remove=np.zeros(n, bool))
        out.append(encode_state_array(batch, stamp, "map"))
    return out


def work(predictor: CollisionPredictor, decode: StateDecoder, data: bytes,
         now_ns: int) -> tuple[float, bytes]:
    """One frame's node work, decoding as the node's subscription does (a StateDecoder per
    topic); (seconds, published bytes)."""
    started = time.perf_counter()
    predictor.receive_batch(decode(data), now_ns)
    out = predictor.predict().to_cdr()
    return time.perf_counter() - started, out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--bodies", type=int, default=10_000)
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--quick", action="store_true", help="20 frames")
    parser.add_argument("--out", default=str(HERE / "results"), help="results directory")
    opts = parser.parse_args()
    count = 20 if opts.quick else opts.frames
    info = machine.collect()
    started = time.perf_counter()
    data = frames(opts.bodies, 2 * count + 3)
    config = PredictorConfig(horizon=5.0, frame_id="map", use_covariance=False,
                             max_bodies=opts.bodies)
    everyone = CollisionPredictor(config)
    everyone.receive_batch(StateDecoder(CircleStateArray)(data[0]), T0)
    rows = list(everyone.predict().rows())
    tally: dict[str, int] = {}
    for row in rows:
        for body in (row.id_a, row.id_b):
            tally[body] = tally.get(body, 0) + 1
    ego_id = max(sorted(tally), key=tally.get)
    ego = CollisionPredictor(replace(config, ego_ids=(ego_id,)))
    # one decoder each: each predictor stands for a node with its own subscription
    decode_all, decode_ego = StateDecoder(CircleStateArray), StateDecoder(CircleStateArray)
    for k in range(3):  # warm both (compiled paths, caches)
        work(everyone, decode_all, data[k], T0 + k * FRAME_NS)
        work(ego, decode_ego, data[k], T0 + k * FRAME_NS)
    schedules = {"blocks of 5 frames": (3, 5), "frame by frame": (3 + count, 1)}
    times: dict[str, tuple[list, list]] = {}
    for name, (first, block) in schedules.items():
        t_all, t_ego = [], []
        for start in range(first, first + count, block):
            turn = range(start, min(start + block, first + count))
            t_all += [work(everyone, decode_all, data[k], T0 + k * FRAME_NS)[0] for k in turn]
            t_ego += [work(ego, decode_ego, data[k], T0 + k * FRAME_NS)[0] for k in turn]
        times[name] = (t_all, t_ego)
    # the ego rows are the all-pairs rows with the ego body (last frame)
    expected = [r for r in everyone.predict().rows() if ego_id in (r.id_a, r.id_b)]
    assert list(ego.predict().rows()) == expected, "ego rows differ from the filtered rows"
    table_rows, ratios = [], {}
    for name, (t_all, t_ego) in times.items():
        ratios[name] = float(np.median(t_ego)) / float(np.median(t_all))
        for label, t, n_rows in (("all pairs", t_all, len(list(everyone.predict().rows()))),
                                 (f"ego_ids = [{ego_id}]", t_ego, len(expected))):
            table_rows.append([name, label, f"{np.median(t) * 1e3:.2f}",
                               f"{np.percentile(t, 90) * 1e3:.2f}", n_rows])
    table = md_table(["turns", "predictor", "median ms/frame", "p90 ms/frame",
                      "rows (last frame)"], table_rows)
    headline = ratios["blocks of 5 frames"]
    text = (f"# Ego-centred prediction: node work per frame\n\n`bench/bench_ego.py`: "
            f"{opts.bodies} bodies, {count} frames per schedule at 30 Hz, decode + merge + "
            f"predict + encode per frame, both predictors on the same frames, taking turns.\n\n"
            f"{table}\n"
            f"ego / all pairs, blocks of 5 frames: {headline:.3f} (target <= 0.1: "
            f"{'met' if headline <= 0.1 else 'NOT met'}); frame by frame: "
            f"{ratios['frame by frame']:.3f} (each predictor starting from the other's caches)"
            "; the ego rows equal the all-pairs rows with the ego body.\n\n## Machine\n\n")
    info = machine.finish(info, time.perf_counter() - started, {})
    text += machine.table(info)
    out = Path(opts.out) / "ego.md"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(text)
    print(text)
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
