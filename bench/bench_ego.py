"""Ego-centred prediction: the node's work per frame with one ego body against all pairs.

    .venv/bin/python bench/bench_ego.py [--bodies 10000] [--frames 60] [--quick] [--out DIR]

One process, the same frames for both: N bodies (bench_scene.make_scene: uniform in a square
of side sqrt(N) * 10 m, |v| <= 3 m/s, |a| <= 0.5 m/s^2) moving every frame at 30 Hz, as
CircleStateArray bytes. Per frame, the work the node does from the message to the bytes it
publishes: decode, merge (CollisionPredictor.receive_batch), predict, encode (to_cdr). One
predictor answers all pairs; the other has ego_ids = one body (the body with the most
contacts in the first frame). The two alternate frame by frame, so the machine's load moves
both alike. Prints the median and p90 per frame and the ratio (target: ego <= 1/10 of all
pairs), and checks that the ego rows are the all-pairs rows with the ego body. Writes
bench/results/ego.md.
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
from circle_collision_ros.pipeline.state_codec import decode_states, encode_state_array

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


def work(predictor: CollisionPredictor, data: bytes, now_ns: int) -> tuple[float, bytes]:
    """One frame's node work; (seconds, published bytes)."""
    started = time.perf_counter()
    predictor.receive_batch(decode_states(data, CircleStateArray), now_ns)
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
    data = frames(opts.bodies, count + 3)
    config = PredictorConfig(horizon=5.0, frame_id="map", use_covariance=False,
                             max_bodies=opts.bodies)
    everyone = CollisionPredictor(config)
    everyone.receive_batch(decode_states(data[0], CircleStateArray), T0)
    rows = list(everyone.predict().rows())
    tally: dict[str, int] = {}
    for row in rows:
        for body in (row.id_a, row.id_b):
            tally[body] = tally.get(body, 0) + 1
    ego_id = max(sorted(tally), key=tally.get)
    ego = CollisionPredictor(replace(config, ego_ids=(ego_id,)))
    for k in range(3):  # warm both (compiled paths, caches)
        work(everyone, data[k], T0 + k * FRAME_NS)
        work(ego, data[k], T0 + k * FRAME_NS)
    t_all, t_ego = [], []
    for k in range(3, count + 3):
        now = T0 + k * FRAME_NS
        a, _ = work(everyone, data[k], now)
        b, _ = work(ego, data[k], now)
        t_all.append(a)
        t_ego.append(b)
    # the ego rows are the all-pairs rows with the ego body (last frame)
    expected = [r for r in everyone.predict().rows() if ego_id in (r.id_a, r.id_b)]
    assert list(ego.predict().rows()) == expected, "ego rows differ from the filtered rows"
    med_all, med_ego = float(np.median(t_all)), float(np.median(t_ego))
    p90_all, p90_ego = float(np.percentile(t_all, 90)), float(np.percentile(t_ego, 90))
    ratio = med_ego / med_all
    table = md_table(
        ["predictor", "median ms/frame", "p90 ms/frame", "rows (last frame)"],
        [["all pairs", f"{med_all * 1e3:.2f}", f"{p90_all * 1e3:.2f}",
          len(list(everyone.predict().rows()))],
         [f"ego_ids = [{ego_id}]", f"{med_ego * 1e3:.2f}", f"{p90_ego * 1e3:.2f}",
          len(expected)]])
    text = (f"# Ego-centred prediction: node work per frame\n\n`bench/bench_ego.py`: "
            f"{opts.bodies} bodies, {count} frames at 30 Hz, decode + merge + predict + encode "
            f"per frame, both predictors on the same frames, alternating.\n\n{table}\n"
            f"ego / all pairs: {ratio:.3f} (target <= 0.1: {'met' if ratio <= 0.1 else 'NOT met'})"
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
