#!/usr/bin/env python3
"""A 1,000-body scene with covariance on every body vs the same scene exact.

    .venv/bin/python bench/bench_uncertainty_scene.py [--bodies 1000] [--frames 30] [--sigma 0.2]
                                                      [--velocity-sigma 0.1] [--horizon 5]
                                                      [--budget 8] [--cpu-time]

Both runs see the same frames of the same synthetic scene (the node benchmark's density,
~333 m^2 per body, every body moved and stamped anew each frame, so every frame is a full
recomputation), in the same process, interleaved frame by frame so machine load hits both
alike. Timed per frame, node-side work without DDS:

- "scene": ``CollisionPredictor.receive_batch`` + ``predict`` (covariance on: the exact path
  plus ``Scene.uncertain_pairs``: inflated broad phase and the core's probabilities at R);
- "pipeline": the same + ``to_cdr()`` (the bytes the node publishes).

Prints medians, the ratio covariance/exact (target <= 3x), how much of the covariance run is
the core's ``uncertain_pairs`` (the per-pair mathematics) and how much the node side (inflated
broad phase, propagation to R, joining the rows), and how many pairs the uncertain path
evaluated and reported. --cpu-time times each step by the thread's CPU time
(time.thread_time) instead of the wall clock, with numba's threads off (their work would not
be counted): on a shared machine the wall-clock medians swing with other processes' load,
the CPU time much less. --budget is the node's ``uncertain_pair_budget`` (default: the node's
default; 0: every pair gets the full evaluation); the deferred pairs are counted. The node latency
with covariance through DDS is
``bench/bench_node.py --covariance SIGMA`` (same run, on and off).

    .venv/bin/python bench/bench_uncertainty_scene.py --stream [--bodies 300] [--updates 600]

the per-body stream instead (the node-streams targets' shape): the scene is filled once, then
one body at a time gets a newer state (new stamp, so R moves with every update), exact and
with covariance interleaved; prints the median and p99 node-side time per update (intake +
predict + to_cdr), the ratio, and how many uncertain pairs each update gave the core (only
the updated body's pairs: Scene.uncertain_pairs keeps every other pair's answer).
"""

from __future__ import annotations

import argparse
import contextlib
import math
import statistics
import sys
import time

import numpy as np

from circle_collision_ros.core import uncertainty
from circle_collision_ros.core.parallel_policy import threads_forced
from circle_collision_ros.demo.demo_scene import SyntheticScene
from circle_collision_ros.node.parameters import SPECS
from circle_collision_ros.pipeline.predictor import CollisionPredictor, PredictorConfig
from circle_collision_ros.pipeline.state_batch import StateBatch

BASE_NS = 1_700_000_000 * 1_000_000_000
NODE_BUDGET = SPECS["uncertain_pair_budget"].default


def covariance_rows(n: int, sigma: float, velocity_sigma: float) -> np.ndarray:
    """(n, 36): diagonal position variance sigma^2 and velocity variance velocity_sigma^2."""
    return np.tile(np.diag([sigma**2] * 3 + [velocity_sigma**2] * 3).ravel(), (n, 1))


def frame(scene: SyntheticScene, stamp_ns: int, covariance: np.ndarray | None) -> StateBatch:
    n = scene.count
    return StateBatch(
        ids=[f"b{k:05d}" for k in range(n)],
        frames=["map"] * n,
        stamp_ns=np.full(n, stamp_ns, dtype=np.int64),
        radius=scene.radii.copy(),
        position=scene.p.copy(),
        velocity=scene.v.copy(),
        acceleration=scene.a.copy(),
        remove=np.zeros(n, dtype=bool),
        covariance=covariance,
        covariance_size=None if covariance is None else np.full(n, 36, dtype=np.int64),
    )


def stream(
    n: int, updates: int, sigma: float, velocity_sigma: float, horizon: float, budget: int
) -> None:
    """One-body updates in an n-body scene, exact and with covariance interleaved."""
    scene = SyntheticScene(n, size=float(np.sqrt(n * 333.0)), dimensions=2, seed=n)
    config = PredictorConfig(horizon=horizon, max_bodies=max(10_000, n), stale_timeout=3600.0,
                             uncertain_pair_budget=budget)
    runs = {
        "exact": (CollisionPredictor(config), None),
        "covariance": (CollisionPredictor(config), covariance_rows(n, sigma, velocity_sigma)),
    }
    for predictor, c in runs.values():
        predictor.receive_batch(frame(scene, BASE_NS, c), BASE_NS)
        predictor.predict().to_cdr()
    times = {name: [] for name in runs}
    given, listed, deferred = [], [], []
    step_ns = 1_000_000_000 // (30 * n)  # every body at 30 Hz, sources evenly spread
    for k in range(updates):
        stamp = BASE_NS + (k + 1) * step_ns
        b = k % n
        scene.step(step_ns * 1e-9)
        for name, (predictor, c) in runs.items():
            one = frame(scene, stamp, c).select(np.array([b]))
            t0 = time.perf_counter()
            predictor.receive_batch(one, stamp)
            prediction = predictor.predict()
            prediction.to_cdr()
            if k >= 50:  # the first updates meet cold caches
                times[name].append(time.perf_counter() - t0)
                if c is not None:
                    given.append(predictor._scene.uncertain_evaluated)
                    listed.append(len(prediction.uncertainty))
                    deferred.append(prediction.uncertainty.deferred)
    med = {k: statistics.median(v) * 1e3 for k, v in times.items()}
    p99 = {k: float(np.percentile(v, 99)) * 1e3 for k, v in times.items()}
    print(
        f"{n} bodies, one-body updates (new stamp each), {len(times['exact'])} timed, horizon "
        f"{horizon} s, "
        f"covariance: position sigma {sigma} m, velocity sigma {velocity_sigma} m/s on every body; "
        f"uncertain_pair_budget {budget}"
    )
    print("| per update | exact ms | covariance ms | ratio |")
    print("|---|---:|---:|---:|")
    for label, d in (("median", med), ("p99", p99)):
        print(
            f"| {label} | {d['exact']:.3f} | {d['covariance']:.3f} | "
            f"{d['covariance'] / d['exact']:.1f}x |"
        )
    print(
        f"uncertain pairs listed (median): {statistics.median(listed):.0f}; given to the core per "
        "update: "
        f"median {statistics.median(given):.0f}, max {max(given)}; deferred (median) "
        f"{statistics.median(deferred):.0f}"
    )


def completion(n: int, frames: int, every: int, sigma: float, velocity_sigma: float,
               horizon: float, budget: int) -> None:
    """The completion's CPU per frame (see the docstring)."""
    from circle_collision_ros.core.scene.uncertain import COMPLETION_STEP, complete_uncertainty

    scene = SyntheticScene(n, size=float(np.sqrt(n * 333.0)), dimensions=2, seed=n)
    config = PredictorConfig(horizon=horizon, max_bodies=max(10_000, n), stale_timeout=3600.0,
                             uncertain_pair_budget=budget,
                             probability_tolerance=SPECS["probability_tolerance"].default)
    predictor = CollisionPredictor(config)
    cov = covariance_rows(n, sigma, velocity_sigma)
    period_ns = 1_000_000_000 // 30
    kept = []
    for k in range(frames):
        if k:
            scene.step(period_ns * 1e-9)
        stamp = BASE_NS + k * period_ns
        predictor.receive_batch(frame(scene, stamp, cov), stamp)
        u = predictor.predict().uncertainty
        if k % every == every // 2 and u.pending is not None:
            kept.append((k, u))

    def cpu(u, pause) -> float:
        best = math.inf
        for _ in range(3):
            t = time.thread_time()
            complete_uncertainty(u, pause=pause)
            best = min(best, time.thread_time() - t)
        return best * 1e3

    print(f"{n} bodies at 30 Hz, {frames} frames, every {every}th completed "
          f"({len(kept)} frames); covariance: position sigma {sigma} m, velocity sigma "
          f"{velocity_sigma} m/s on every body; uncertain_pair_budget {budget}, "
          f"probability_tolerance {config.probability_tolerance}; thread CPU time, best of 3, "
          "numba threads off")
    print(f"| frame | deferred rows | one block ms | steps of {COMPLETION_STEP} ms | us per row |")
    print("|---:|---:|---:|---:|---:|")
    block, steps = [], []
    with threads_forced(False):
        complete_uncertainty(kept[0][1])  # first calls: caches
        for k, u in kept:
            block.append(cpu(u, None))
            steps.append(cpu(u, lambda: None))
            rows = u.pending.rows.size
            print(f"| {k} | {rows} | {block[-1]:.1f} | {steps[-1]:.1f} | "
                  f"{1e3 * block[-1] / rows:.0f} |")
    print(f"per frame, in the node's steps: p50 {np.percentile(steps, 50):.1f} ms, largest "
          f"{max(steps):.1f} ms of CPU (two threads share it: {np.percentile(steps, 50) / 2:.1f} "
          f"and {max(steps) / 2:.1f} ms at best, against a {1e3 / 30:.1f} ms frame period)")


def run_frames(frames, scene, exact, uncertain, cov, times, core_s, core_per_frame, evaluated,
               deferred, reported, contacts, bounds, clock) -> None:
    """The timed frames: exact and covariance interleaved frame by frame (see the docstring)."""
    for k in range(frames + 2):  # two warm-up frames (numba caches, first allocation), not counted
        stamp = BASE_NS + k * 33_000_000
        scene.step(0.033)
        for name, predictor, c in (("exact", exact, None), ("covariance", uncertain, cov)):
            batch = frame(scene, stamp, c)
            core_s[0] = 0.0
            t0 = clock()
            predictor.receive_batch(batch, stamp)
            prediction = predictor.predict()
            t1 = clock()
            prediction.to_cdr()
            t2 = clock()
            if k >= 2:
                times[f"{name} scene"].append(t1 - t0)
                times[f"{name} pipeline"].append(t2 - t0)
                if c is not None:
                    core_per_frame.append(core_s[0])
                    u = prediction.uncertainty
                    evaluated.append(len(u))
                    deferred.append(u.deferred)
                    reported.append(len(prediction.columns))
                    contacts.append(len(prediction.contacts))
                    bounds.append(_uncertain_bounds(prediction))


def _uncertain_bounds(prediction) -> tuple[np.ndarray, np.ndarray]:
    """(probability, bound) of the published rows of uncertain pairs."""
    u, col = prediction.uncertainty, prediction.columns
    pairs = set(zip(u.id_a.tolist(), u.id_b.tolist()))
    rows = [k for k, pair in enumerate(zip(col.id_a, col.id_b)) if pair in pairs]
    return col.probability[rows], col.probability_bound[rows]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--bodies", type=int, default=1000)
    parser.add_argument("--frames", type=int, default=30)
    parser.add_argument("--sigma", type=float, default=0.2, help="position sigma, m (every axis)")
    parser.add_argument("--velocity-sigma", type=float, default=0.1, help="velocity sigma, m/s")
    parser.add_argument("--horizon", type=float, default=5.0)
    parser.add_argument(
        "--budget",
        type=int,
        default=None,
        help="uncertain_pair_budget (default: the node parameter's default; 0: no limit)",
    )
    parser.add_argument("--quick", action="store_true", help="5 frames")
    parser.add_argument("--cpu-time", action="store_true",
                        help="time by the thread's CPU time, numba threads off (see the docstring)")
    parser.add_argument(
        "--stream", action="store_true", help="one-body updates (see the docstring)"
    )
    parser.add_argument("--updates", type=int, default=600, help="with --stream")
    parser.add_argument("--completion", action="store_true",
                        help="the completion's CPU per frame (see the docstring)")
    parser.add_argument("--every", type=int, default=40, help="with --completion")
    opts = parser.parse_args()
    budget = NODE_BUDGET if opts.budget is None else opts.budget
    if opts.completion:
        given = set(sys.argv)
        completion(opts.bodies, opts.frames if "--frames" in given else 600, opts.every,
                   opts.sigma if "--sigma" in given else 0.3,
                   opts.velocity_sigma if "--velocity-sigma" in given else 0.2, opts.horizon,
                   budget)
        return 0
    if opts.stream:
        stream(300 if opts.bodies == 1000 and "--bodies" not in sys.argv else opts.bodies,
               opts.updates, opts.sigma, opts.velocity_sigma, opts.horizon, budget)
        return 0
    frames = 5 if opts.quick else opts.frames
    n = opts.bodies
    scene = SyntheticScene(n, size=float(np.sqrt(n * 333.0)), dimensions=2, seed=n)
    budget = NODE_BUDGET if opts.budget is None else opts.budget
    config = PredictorConfig(horizon=opts.horizon, max_bodies=max(10_000, n), stale_timeout=3600.0,
                             uncertain_pair_budget=budget)
    exact, uncertain = CollisionPredictor(config), CollisionPredictor(config)
    cov = covariance_rows(n, opts.sigma, opts.velocity_sigma)
    times = {"exact scene": [], "covariance scene": [], "exact pipeline": [],
             "covariance pipeline": []}
    core_per_frame: list[float] = []
    evaluated, reported, contacts, deferred, bounds = [], [], [], [], []
    core_s = [0.0]
    core_call = uncertainty.uncertain_pairs
    clock = time.thread_time if opts.cpu_time else time.perf_counter

    def timed_core(*args, **kwargs):  # the scene calls it through the module: time the core's share
        t = clock()
        try:
            return core_call(*args, **kwargs)
        finally:
            core_s[0] += clock() - t

    uncertainty.uncertain_pairs = timed_core
    with threads_forced(False) if opts.cpu_time else contextlib.nullcontext():
        run_frames(frames, scene, exact, uncertain, cov, times, core_s, core_per_frame, evaluated,
                   deferred, reported, contacts, bounds, clock)
    med = {k: statistics.median(v) * 1e3 for k, v in times.items()}
    print(
        f"{n} bodies, {frames} frames (every body moved and restamped each frame), horizon "
        f"{opts.horizon} s, covariance: position sigma {opts.sigma} m, velocity sigma "
        f"{opts.velocity_sigma} m/s on every body; uncertain_pair_budget {budget}"
        + ("; thread CPU time, numba threads off" if opts.cpu_time else "")
    )
    print("| step | exact ms (median) | covariance ms (median) | ratio | target |")
    print("|---|---:|---:|---:|---:|")
    for step in ("scene", "pipeline"):
        e, c = med[f"exact {step}"], med[f"covariance {step}"]
        print(f"| {step} | {e:.2f} | {c:.2f} | {c / e:.2f}x | <= 3x |")
    core_ms = statistics.median(core_per_frame) * 1e3
    print(
        f"of the covariance scene step: core.uncertainty.uncertain_pairs {core_ms:.2f} ms, the "
        "rest "
        "(exact path + inflated broad phase + propagation + rows) "
        f"{med['covariance scene'] - core_ms:.2f} ms "
        f"= {(med['covariance scene'] - core_ms) / med['exact scene']:.2f}x the exact step"
    )
    print(
        f"uncertain pairs evaluated per frame (median): {statistics.median(evaluated):.0f}; rows "
        f"published: {statistics.median(reported):.0f} (of which mean contacts "
        f"{statistics.median(contacts):.0f}); deferred (budget) {statistics.median(deferred):.0f}"
    )
    p = np.concatenate([np.empty(0)] + [b[0] for b in bounds])
    e = np.concatenate([np.empty(0)] + [b[1] for b in bounds])
    print(
        f"published uncertain rows: {p.size}; placeholders (1.0 +- 1.0): "
        f"{np.count_nonzero((p == 1.0) & (e == 1.0))}; bound <= 0.01: "
        f"{100.0 * np.count_nonzero(e <= 0.01) / max(p.size, 1):.1f} % (target >= 99 %); bound "
        f"median {np.median(e) if e.size else float('nan'):.3f}, p90 "
        f"{np.percentile(e, 90) if e.size else float('nan'):.3f}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
