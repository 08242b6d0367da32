"""Scale: whole-scene prediction time, cull rate and memory against N.

    .venv/bin/python bench/scale.py [--quick] [--out DIR]

(normally driven by ``bench/run_all.py``).  Scenes come from
``bench/bench_scene.make_scene`` (uniform positions, r in [0.3, 2] m,
|v| <= 3 m/s, |a| <= 0.5 m/s^2) at two densities and two horizons.  Per N:

* all-pairs narrow phase (``bench_scene.all_pairs_narrow``: every i < j pair,
  chunked) -- only up to ``ALL_PAIRS_MAX`` bodies, it is O(N^2);
* our broad phase + narrow phase (``predict_all_pairs``), best of a few;
* cull rate = pairs given to the narrow phase / all pairs (``return_stats``);
* peak memory of one ``predict_all_pairs`` call: rise of the process's peak
  RSS over its RSS before the call (after ``malloc_trim``; VmHWM reset through
  /proc/self/clear_refs; covers numba's own allocations) and tracemalloc's
  peak (Python/numpy heap only);
* incremental ``Scene``: one body re-reported (upsert) + ``predictions()``,
  median and p90 over many updates;
* the stages of ``predict_all_pairs`` (broad phase, narrow phase, the rest)
  and the broad phase's share, printed per N;
* the stages of the node's work on one frame of 5,000 moving bodies
  (``node_frame_split``: decode, intake, broad phase, rest of prediction,
  encode) and the broad phase's share of it.

``--n 5000 20000`` runs only those body counts and writes nothing.
"""

from __future__ import annotations

import argparse
import ctypes
import json
import math
import re
import statistics
import time
import tracemalloc
from pathlib import Path

import numpy as np

import _common
from _common import best_of, fmt_ms, md_table, pyplot

from bench_scene import all_pairs_narrow, make_scene
from circle_collision_ros.core.scene.all_pairs import predict_all_pairs
from circle_collision_ros.core.scene import Scene

# bodies per km^2: the scale scene (3,000 bodies in 1 km^2) and 10x that
DENSITIES = {"3k/km2": 3000.0, "30k/km2": 30000.0}
HORIZONS = (1.0, 5.0)
NS_FULL = (100, 300, 1000, 3000, 10000, 20000)
NS_QUICK = (100, 300, 1000)
ALL_PAIRS_MAX = 3000
ALL_PAIRS_MAX_QUICK = 1000
NODE_FRAME_BODIES = 5000  #: the node frame of the broad phase's share


def _status_kb(field: str) -> int:
    try:
        txt = Path("/proc/self/status").read_text()
    except OSError:
        return -1
    m = re.search(rf"{field}:\s+(\d+)", txt)
    return int(m.group(1)) if m else -1


def _malloc_trim() -> None:
    """Return freed heap pages to the OS, so the RSS before a call is not inflated by
    memory that earlier calls freed (glibc keeps it resident otherwise)."""
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass


def peak_memory(fn) -> tuple[float, float]:
    """(peak RSS rise MiB, tracemalloc peak MiB) of one call of ``fn``."""
    _malloc_trim()
    rss_ok = True
    try:
        Path("/proc/self/clear_refs").write_text("5")  # reset VmHWM to the current RSS
    except OSError:
        rss_ok = False
    before = _status_kb("VmRSS")
    tracemalloc.start()
    fn()
    _, traced = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    hwm = _status_kb("VmHWM")
    rise = (hwm - before) / 1024.0 if (rss_ok and hwm >= 0 and before >= 0) else float("nan")
    return max(rise, 0.0), traced / 2**20


def stage_split(p, v, a, r, h, repeat: int) -> dict:
    """Best-of-``repeat`` ms of predict_all_pairs' stages, run as it runs them:
    broad phase (swept bounds + candidate pairs), narrow phase (pair rows +
    time_to_collision), the rest (hit filter, sort, contact details)."""
    from circle_collision_ros.core import broad as bp
    from circle_collision_ros.core.scene import all_pairs as pp

    n = r.shape[0]
    tref = np.zeros(n)

    def broad():
        lo, hi = bp.swept_bounds(p, v, a, r, 0.0, h)
        return bp.candidate_pairs(lo, hi, p=p, v=v, a=a, r=r, tref=tref, t_start=0.0, t_end=h)

    I, J, _ = broad()

    def narrow():
        return pp.narrow_on_pairs(*pp._pair_rows(p, v, a, r, I, J), h)

    ttc = narrow()
    tb = best_of(broad, repeat)[0]
    tn = best_of(narrow, repeat)[0]
    tt = best_of(lambda: predict_all_pairs(p, v, a, r, h), repeat)[0]
    return dict(stage_broad_ms=tb * 1e3, stage_narrow_ms=tn * 1e3,
                stage_rest_ms=max(tt - tb - tn, 0.0) * 1e3, stage_total_ms=tt * 1e3,
                narrow_rows=int(ttc.shape[0]))


def scene_update(p, v, a, r, h, rng, updates: int) -> dict:
    n, dim = p.shape
    sc = Scene(h, dim)
    t0 = time.perf_counter()
    stamp = 1_700_000_000 * 10**9
    sc.upsert_many([f"b{k:06d}" for k in range(n)], p, v, a, r, stamp)
    sc.predictions()
    build = time.perf_counter() - t0
    side = float(np.ptp(p[:, 0])) if n > 1 else 1.0
    q, w, e, s = make_scene(updates, side, rng)
    ids = rng.integers(0, n, updates)
    ts = []
    for k in range(updates):
        t0 = time.perf_counter()
        sc.upsert(f"b{int(ids[k]):06d}", q[k], w[k], e[k], float(s[k]), stamp_ns=stamp + k + 1)
        sc.predictions()
        ts.append(time.perf_counter() - t0)
    return dict(scene_build_ms=build * 1e3, update_median_ms=statistics.median(ts) * 1e3,
                update_p90_ms=float(np.percentile(ts, 90)) * 1e3)


def node_frame_split(n: int = 5000, frames: int = 30) -> dict:
    """Median ms per stage of the node's work on one CircleStateArray frame of n
    moving bodies, in process (no DDS): the scene and frame rate of
    bench_node.py's array targets (3,000 bodies/km^2, 30 Hz, every body moves).

    Stages: decode (cdr_codec.decode_states), intake (validation + merge into
    the scene: CollisionPredictor.receive_batch), broad phase (swept bounds +
    candidate pairs inside the scene's prediction, timed by wrapping those two
    broad_phase functions), the rest of the prediction (narrow phase, pair
    records, order) and encoding (ScenePrediction.to_cdr).  The target: the
    broad phase is not the largest share of this frame at 5,000 bodies."""
    from circle_collision_msgs.msg import CircleStateArray
    from circle_collision_ros.core import broad as bp
    from circle_collision_ros.demo.demo_scene import SyntheticScene
    from circle_collision_ros.pipeline.state_codec import decode_states, encode_state_array
    from circle_collision_ros.pipeline.predictor import CollisionPredictor, PredictorConfig
    from circle_collision_ros.pipeline.state_batch import StateBatch

    scene = SyntheticScene(n, size=math.sqrt(n * 333.0), dimensions=2, seed=n)
    ids = [f"b{k:05d}" for k in range(n)]
    t0_ns = 1_700_000_000 * 10**9
    period_ns = 33_333_333
    warm = 5
    data = []
    for k in range(frames + warm):
        scene.step(period_ns * 1e-9)
        stamp = t0_ns + k * period_ns
        batch = StateBatch(ids=ids, frames=["map"] * n, stamp_ns=np.full(n, stamp, dtype=np.int64),
                           radius=scene.radii, position=scene.p, velocity=scene.v,
                           acceleration=scene.a, remove=np.zeros(n, dtype=bool))
        data.append(encode_state_array(batch, stamp, "map"))
    predictor = CollisionPredictor(PredictorConfig(max_bodies=max(10_000, n)))
    predictor.warm_up()
    broad_s = [0.0]
    originals = bp.swept_bounds, bp.candidate_pairs

    def timed(fn):
        def call(*args, **kwargs):
            t = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                broad_s[0] += time.perf_counter() - t

        return call

    stages = {
        name: [] for name in ("decode", "intake", "broad phase", "rest of prediction", "encode")
    }
    bp.swept_bounds, bp.candidate_pairs = (timed(f) for f in originals)
    try:
        for k, msg in enumerate(data):
            broad_s[0] = 0.0
            t0 = time.perf_counter()
            batch = decode_states(msg, CircleStateArray)
            t1 = time.perf_counter()
            predictor.receive_batch(batch, t0_ns + k * period_ns)
            t2 = time.perf_counter()
            prediction = predictor.predict()
            t3 = time.perf_counter()
            prediction.to_cdr()
            t4 = time.perf_counter()
            if k >= warm:
                for name, sec in zip(
                    stages, (t1 - t0, t2 - t1, broad_s[0], t3 - t2 - broad_s[0], t4 - t3)
                ):
                    stages[name].append(sec * 1e3)
    finally:
        bp.swept_bounds, bp.candidate_pairs = originals
    med = {name: statistics.median(v) for name, v in stages.items()}
    total = sum(med.values())
    largest = max(med, key=med.get)
    return dict(n=n, frames=frames, stage_ms=med, total_ms=total,
                broad_share=med["broad phase"] / max(total, 1e-12), largest=largest)


def node_frame_line(nf: dict) -> str:
    parts = ", ".join(f"{k} {v:.2f}" for k, v in nf["stage_ms"].items())
    return (
        f"node frame, {nf['n']} moving bodies (median of {nf['frames']}): {parts} ms; "
        f"broad-phase share {nf['broad_share']:.0%}, largest stage: {nf['largest']}"
    )


def run(quick: bool = False, log=print, ns=None) -> dict:
    ns = ns or (NS_QUICK if quick else NS_FULL)
    ap_max = ALL_PAIRS_MAX_QUICK if quick else ALL_PAIRS_MAX
    repeat = 2 if quick else 3
    updates = 20 if quick else 100
    rows = []
    warm = make_scene(50, 50.0, np.random.default_rng(0))
    predict_all_pairs(*warm, 1.0)
    all_pairs_narrow(*warm, 1.0)
    for dname, dens in DENSITIES.items():
        for h in HORIZONS:
            for n in ns:
                rng = np.random.default_rng([n, int(dens), int(h * 10)])
                side = 1000.0 * math.sqrt(n / dens)
                p, v, a, r = make_scene(n, side, rng)
                allp = n * (n - 1) // 2
                tb, tm = best_of(lambda: predict_all_pairs(p, v, a, r, h), repeat)
                res, st = predict_all_pairs(p, v, a, r, h, return_stats=True)
                rss, traced = peak_memory(lambda: predict_all_pairs(p, v, a, r, h))
                row = dict(density=dname, horizon=h, n=n, side_m=side, all_pairs=allp,
                           broad_ms=tb * 1e3, broad_median_ms=tm * 1e3, bound_pairs=st["n_box"],
                           candidates=st["n_candidates"],
                           cull_rate=st["n_candidates"] / max(allp, 1), contacts=len(res),
                           broad_peak_rss_mib=rss, broad_traced_mib=traced)
                if n <= ap_max:
                    t0 = time.perf_counter()
                    I, J, T = all_pairs_narrow(p, v, a, r, h)
                    t_all = time.perf_counter() - t0
                    if n < 1000:
                        t_all = min(
                            t_all, best_of(lambda: all_pairs_narrow(p, v, a, r, h), repeat)[0]
                        )
                    row.update(
                        all_pairs_ms=t_all * 1e3,
                        identical=bool(
                            np.array_equal(res.i, I)
                            and np.array_equal(res.j, J)
                            and np.array_equal(res.ttc, T)
                        ),
                    )
                else:
                    row.update(all_pairs_ms=None, identical=None)
                row.update(scene_update(p, v, a, r, h, rng, updates))
                row.update(stage_split(p, v, a, r, h, repeat))
                rows.append(row)
                st = row
                log(
                    f"  {dname:8s} h={h:g} N={n:6d}: predict_all_pairs {tb * 1e3:8.2f} ms"
                    + (f", all pairs {row['all_pairs_ms']:9.1f} ms" if row["all_pairs_ms"] else "")
                    + f", cull {row['cull_rate']:.2e}, rss +{rss:.1f} MiB, update "
                      f"{row['update_median_ms']:.3f} ms"
                    + f" | stages: broad {st['stage_broad_ms']:.2f} ms, narrow "
                      f"{st['stage_narrow_ms']:.2f} ms"
                    + f", rest {st['stage_rest_ms']:.2f} ms (broad share "
                    + f"{st['stage_broad_ms'] / max(st['stage_total_ms'], 1e-9):.0%})"
                )
    nf = node_frame_split(NODE_FRAME_BODIES, 10 if quick else 30)
    log("  " + node_frame_line(nf))
    return dict(rows=rows, all_pairs_max=ap_max, densities=DENSITIES, horizons=list(HORIZONS),
                ns=list(ns), repeat=repeat, updates=updates, node_frame=nf)


def table(res: dict) -> str:
    rows = []
    for r in res["rows"]:
        speed = f"{r['all_pairs_ms'] / r['broad_ms']:.1f}" if r["all_pairs_ms"] else "-"
        rows.append(
            [r["density"], f"{r['horizon']:g}", r["n"],
             fmt_ms(r["all_pairs_ms"]) if r["all_pairs_ms"] else "-", fmt_ms(r["broad_ms"]), speed,
             f"{r['cull_rate']:.2e}", r["candidates"], r["contacts"],
             f"{r['broad_peak_rss_mib']:.1f}", f"{r['broad_traced_mib']:.1f}",
             fmt_ms(r["update_median_ms"]), fmt_ms(r["update_p90_ms"]),
             {True: "yes", False: "NO", None: "-"}[r["identical"]]]
        )
    return md_table(
        ["density", "horizon s", "N", "all-pairs narrow ms", "predict_all_pairs ms", "speed-up",
         "cull rate", "narrow-phase pairs", "contacts", "peak RSS rise MiB", "traced peak MiB",
         "1-body update ms (median)", "(p90)", "same result"],
        rows,
        "lrrrrrrrrrrrrl",
    )


def write_markdown(res: dict, out: Path) -> Path:
    p = out / "scale.md"
    txt = [
        "# Scale: whole-scene prediction against N\n",
        "Uniform scenes (bench/bench_scene.make_scene: r 0.3-2 m, |v| <= 3 m/s, |a| <= 0.5 m/s^2) "
        "at "
        f"{' and '.join(res['densities'])} bodies, horizons "
        f"{' and '.join(f'{h:g} s' for h in res['horizons'])}. "
        "All-pairs narrow phase (every i < j pair through time_to_collision, chunked) is run only "
        "up to "
        f"N = {res['all_pairs_max']} (O(N^2)); predict_all_pairs is best of {res['repeat']}. Cull "
        "rate = "
        "pairs given to the narrow phase / all pairs. Peak RSS rise: VmHWM after one "
        "predict_all_pairs call "
        "minus RSS before (after malloc_trim; VmHWM reset via /proc/self/clear_refs; includes "
        "numba allocations); traced peak: "
        "tracemalloc (Python/numpy heap only). 1-body update: Scene.upsert of one body + "
        "predictions(), "
        f"over {res['updates']} updates. 'same result': pair set and times bitwise equal to all "
        "pairs.\n",
        table(res),
        "\nWhere a node frame's time goes (bench/scale.py node_frame_split: in process, no DDS; "
        "the scene of bench_node.py's array targets): "
        + node_frame_line(res["node_frame"])
        + ".\n",
        "\n![scale](scale.png)\n",
    ]
    p.write_text("\n".join(txt))
    return p


def plot(res: dict, out: Path) -> list[Path]:
    plt = pyplot()
    fig, axes = plt.subplots(2, 2, figsize=(12, 9))
    (ax_t, ax_c), (ax_m, ax_u) = axes
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    configs = [(d, h) for d in res["densities"] for h in res["horizons"]]
    for k, (d, h) in enumerate(configs):
        rows = [r for r in res["rows"] if r["density"] == d and r["horizon"] == h]
        n = [r["n"] for r in rows]
        c = colors[k % len(colors)]
        lab = f"{d}, {h:g} s"
        ax_t.plot(
            n, [r["broad_ms"] for r in rows], "o-", color=c, label=f"predict_all_pairs, {lab}"
        )
        ap = [(r["n"], r["all_pairs_ms"]) for r in rows if r["all_pairs_ms"]]
        if ap:
            ax_t.plot(*zip(*ap), "s--", color=c, alpha=0.7, label=f"all-pairs narrow, {lab}")
        ax_c.plot(n, [r["cull_rate"] for r in rows], "o-", color=c, label=lab)
        ax_m.plot(n, [max(r["broad_peak_rss_mib"], 0.05) for r in rows], "o-", color=c,
                  label=f"RSS rise, {lab}")
        ax_m.plot(n, [max(r["broad_traced_mib"], 0.05) for r in rows], "^:", color=c, alpha=0.7,
                  label=f"tracemalloc, {lab}")
        ax_u.plot(n, [r["update_median_ms"] for r in rows], "o-", color=c, label=f"median, {lab}")
        ax_u.plot(n, [r["update_p90_ms"] for r in rows], "v:", color=c, alpha=0.6)
    ax_t.set_title(
        f"scene prediction time (all-pairs only up to N = {res['all_pairs_max']})", fontsize=10
    )
    ax_t.set_ylabel("ms (best of runs)")
    ax_c.set_title("cull rate = narrow-phase pairs / all pairs", fontsize=10)
    ax_m.set_title("peak memory of one predict_all_pairs call (floor 0.05 MiB)", fontsize=10)
    ax_m.set_ylabel("MiB")
    ax_u.set_title("Scene: one-body update + predictions() (dotted: p90)", fontsize=10)
    ax_u.set_ylabel("ms")
    return [_common.save_log_log_vs_n(fig, axes.flat, out / "scale.png", 6)]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", default=str(_common.HERE / "results"))
    ap.add_argument(
        "--n", type=int, nargs="*", help="only these body counts (printed, nothing written)"
    )
    a = ap.parse_args(argv)
    if a.n:
        run(a.quick, ns=tuple(a.n))
        return 0
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    res = run(a.quick)
    (out / "scale.json").write_text(json.dumps(res, indent=1))
    write_markdown(res, out)
    plot(res, out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
