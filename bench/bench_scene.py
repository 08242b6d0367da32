#!/usr/bin/env python3
"""Benchmark whole-scene prediction; prints figures, asserts exactness.

Usage::

    python bench/bench_scene.py            # full run (~1-2 min)
    python bench/bench_scene.py --quick    # a few seconds, smaller scenes

Figures: speed-up of ``predict_all_pairs`` over the narrow phase on all pairs
(same run, identical pair sets/times asserted), 10k-body full prediction time,
``Scene`` one-body update median, cull rates vs N and horizon, grid vs sweep,
and a dense stress scene with peak traced memory.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
import tracemalloc

import numpy as np

from circle_collision_ros.core import broad as bp
from circle_collision_ros.core.scene.all_pairs import narrow_on_pairs, predict_all_pairs
from circle_collision_ros.core.scene import Scene


def make_scene(n, side, rng, dim=2, r=(0.3, 2.0), vmax=3.0, amax=0.5):
    """Uniform positions in a square/cube of ``side`` m; |v| <= vmax, |a| <= amax."""
    p = rng.uniform(0.0, side, (n, dim))

    def rand_vec(mag):
        d = rng.normal(size=(n, dim))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        return d * rng.uniform(0.0, mag, (n, 1))

    return p, rand_vec(vmax), rand_vec(amax), rng.uniform(r[0], r[1], n)


def all_pairs_narrow(p, v, a, r, h, block=1 << 18):
    """Narrow phase on every pair i < j, in chunks; returns sorted (i, j, ttc)."""
    n = r.shape[0]
    Is, Js, Ts = [], [], []
    # enumerate i<j row blocks without building the N^2 index arrays at once
    i0 = 0
    while i0 < n - 1:
        cnt = 0
        i1 = i0
        while i1 < n - 1 and cnt < block:
            cnt += n - 1 - i1
            i1 += 1
        I = np.concatenate([np.full(n - 1 - i, i, dtype=np.int64) for i in range(i0, i1)])
        J = np.concatenate([np.arange(i + 1, n, dtype=np.int64) for i in range(i0, i1)])
        t = narrow_on_pairs(p[I], v[I], a[I], r[I], p[J], v[J], a[J], r[J], h)
        m = t <= h
        Is.append(I[m])
        Js.append(J[m])
        Ts.append(t[m])
        i0 = i1
    I = np.concatenate(Is) if Is else np.empty(0, np.int64)
    J = np.concatenate(Js) if Js else np.empty(0, np.int64)
    T = np.concatenate(Ts) if Ts else np.empty(0)
    o = np.lexsort((J, I, T))
    return I[o], J[o], T[o]


def best_of(fn, repeat):
    ts = []
    out = None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        ts.append(time.perf_counter() - t0)
    return min(ts), statistics.median(ts), out


def section(title):
    print(f"\n== {title}")


def bench_speedup(n, side, h, rng, repeat):
    section(f"speed-up vs narrow phase on all pairs: N={n}, {side:g} m square, horizon {h:g} s")
    p, v, a, r = make_scene(n, side, rng)
    predict_all_pairs(p, v, a, r, h)  # warm-up (numba cache load)
    t_fast, t_fast_med, res = best_of(lambda: predict_all_pairs(p, v, a, r, h), repeat)
    t0 = time.perf_counter()
    I, J, T = all_pairs_narrow(p, v, a, r, h)
    t_all = time.perf_counter() - t0
    assert np.array_equal(res.i, I) and np.array_equal(res.j, J), "pair sets differ"
    assert np.array_equal(res.ttc, T), "times differ"
    print(f"pairs in contact: {len(res)}; identical pair set and bitwise-equal ttc: yes")
    print(f"all-pairs narrow phase ({n * (n - 1) // 2} pairs): {t_all * 1e3:.1f} ms")
    print(f"predict_all_pairs: best {t_fast * 1e3:.2f} ms, median {t_fast_med * 1e3:.2f} ms")
    print(f"speed-up (best): {t_all / t_fast:.1f}x")
    return t_all / t_fast


def bench_full(n, side, h, rng, repeat):
    section(f"full prediction: N={n}, {side:g} m square, horizon {h:g} s")
    p, v, a, r = make_scene(n, side, rng)
    for m in ("grid", "sweep"):
        predict_all_pairs(p, v, a, r, h, method=m)
        tb, tm, (res, st) = best_of(
            lambda: predict_all_pairs(p, v, a, r, h, method=m, return_stats=True), repeat
        )
        print(
            f"{m:5s}: best {tb * 1e3:.1f} ms, median {tm * 1e3:.1f} ms; "
            f"bound pairs {st['n_box']}, narrow-phase pairs {st['n_candidates']}, contacts "
            f"{len(res)}"
        )
    # broad phase alone, both generators
    lo, hi = bp.swept_bounds(p, v, a, r, 0.0, h)
    kw = dict(p=p, v=v, a=a, r=r, tref=np.zeros(n), t_start=0.0, t_end=h)
    for m in ("grid", "sweep"):
        tb, tm, _ = best_of(lambda: bp.candidate_pairs(lo, hi, method=m, **kw), repeat)
        print(f"  pair generation only, {m:5s}: best {tb * 1e3:.2f} ms, median {tm * 1e3:.2f} ms")


T0_NS = 1_700_000_000 * 10**9


def bench_scene_update(n, side, h, rng, updates):
    section(f"Scene: N={n}, one-body update (upsert + predictions()), horizon {h:g} s")
    p, v, a, r = make_scene(n, side, rng)
    sc = Scene(h, 2)
    ids_all = [f"b{k:06d}" for k in range(n)]
    stamp = T0_NS
    t0 = time.perf_counter()
    sc.upsert_many(ids_all, p, v, a, r, stamp)
    res = sc.predictions()
    print(f"initial build: {(time.perf_counter() - t0) * 1e3:.1f} ms, {len(res)} contacts")
    ids = rng.integers(0, n, updates)
    q, w, e, s = make_scene(updates, side, rng)
    ts_up, ts_all = [], []
    for k in range(updates):
        stamp += 1000  # a newer stamp (1 us): the reference time moves, cached times shift
        t0 = time.perf_counter()
        sc.upsert(ids_all[int(ids[k])], q[k], w[k], e[k], s[k], stamp_ns=stamp)
        sc._flush()
        t1 = time.perf_counter()
        sc.predictions()
        t2 = time.perf_counter()
        ts_up.append(t1 - t0)
        ts_all.append(t2 - t0)
    print(
        f"update only (upsert + re-pair): median {statistics.median(ts_up) * 1e3:.3f} ms, "
        f"p90 {np.percentile(ts_up, 90) * 1e3:.3f} ms"
    )
    print(
        f"update + predictions(): median {statistics.median(ts_all) * 1e3:.3f} ms, "
        f"p90 {np.percentile(ts_all, 90) * 1e3:.3f} ms"
    )
    t0 = time.perf_counter()
    stamp = (stamp // sc._slack_ns + 1) * sc._slack_ns
    sc.upsert(ids_all[0], q[0], w[0], e[0], s[0], stamp_ns=stamp)
    sc.predictions()
    print(
        f"epoch roll (full rebuild, every {sc.slack:g} s of stamp time): "
        f"{(time.perf_counter() - t0) * 1e3:.1f} ms"
    )
    assert _same(sc.predictions(), sc.full_recomputation()), "incremental != full recomputation"
    print("incremental == full recomputation: yes")
    return statistics.median(ts_all)


def bench_stream(n, side, h, rng, ticks, frac):
    """Node-like stream: every 0.1 s tick, ``frac`` of the bodies report states
    stamped within the last tick; the reference time moves to the newest stamp."""
    section(f"Scene stream: N={n}, tick 0.1 s, {frac:.0%} of bodies updated per tick")
    p, v, a, r = make_scene(n, side, rng)
    sc = Scene(h, 2)
    ids_all = np.array([f"b{k:06d}" for k in range(n)], dtype=object)
    newest = T0_NS
    sc.upsert_many(ids_all.tolist(), p, v, a, r, newest - 100_000_000)
    sc.predictions()
    k = max(1, int(frac * n))
    ts = []
    for _ in range(ticks):
        ids = rng.choice(n, k, replace=False)
        q, w, e, s = make_scene(k, side, rng)
        t0 = time.perf_counter()
        newest += 100_000_000
        stamps = newest - rng.integers(0, 100_000_000, k)
        sc.upsert_many(ids_all[ids].tolist(), q, w, e, s, stamps)
        res = sc.predictions()
        ts.append(time.perf_counter() - t0)
    print(
        f"tick median {statistics.median(ts) * 1e3:.1f} ms, max {max(ts) * 1e3:.1f} ms "
        f"({len(res)} contacts)"
    )


def _same(x, y):
    return (
        len(x) == len(y)
        and list(x.id_a) == list(y.id_a)
        and list(x.id_b) == list(y.id_b)
        and np.array_equal(x.ttc, y.ttc)
    )


def bench_cull(ns, hs, side, rng):
    section(f"cull rate = narrow-phase pairs / all pairs ({side:g} m square)")
    print(
        f"{'N':>7} {'horizon':>8} {'bound pairs':>12} {'narrow pairs':>13} {'rate':>10} "
        f"{'contacts':>9}"
    )
    for n in ns:
        p, v, a, r = make_scene(n, side, rng)
        for h in hs:
            res, st = predict_all_pairs(p, v, a, r, h, return_stats=True)
            allp = n * (n - 1) // 2
            print(
                f"{n:7d} {h:8g} {st['n_box']:12d} {st['n_candidates']:13d} "
                f"{st['n_candidates'] / allp:10.2e} {len(res):9d}"
            )


def bench_generators(rng, quick):
    """Pair generation alone (bounds + relative test fused), grid vs sweep."""
    section("broad phase pair generation: grid vs sweep (best of 5, ms)")
    k = 0.3 if quick else 1.0
    cases = []
    n = int(10000 * k)
    cases.append(("uniform 1 km", make_scene(n, 1000.0, rng)))
    p, v, a, r = make_scene(n, 1.0, rng)
    centres = rng.uniform(0, 1000, (20, 2))
    p = centres[rng.integers(0, 20, n)] + rng.normal(0, 15, (n, 2))
    cases.append(("20 clusters (sigma 15 m)", (p, v, a, r)))
    p, v, a, r = make_scene(n, 1.0, rng)
    p = np.column_stack([rng.uniform(0, 1000, n), rng.uniform(0, 20, n)])
    cases.append(("corridor 1 km x 20 m", (p, v, a, r)))
    p, v, a, r = make_scene(n, 1.0, rng)
    p = np.column_stack([rng.uniform(0, 1000, n), rng.uniform(490, 510, n)])
    p[::2] = p[::2, ::-1]  # half on a perpendicular corridor: bad case for one sweep axis
    cases.append(("cross of two corridors", (p, v, a, r)))
    p, v, a, r = make_scene(n, 1000.0, rng)
    r[: n // 100] = 40.0  # a few large bodies
    cases.append(("uniform + 1% r=40 m", (p, v, a, r)))
    cases.append(("dense 2000 in 20 m", make_scene(int(2000 * k), 20.0, rng)))
    cases.append(("3-D 3000 in 300 m cube", make_scene(int(3000 * k), 300.0, rng, dim=3)))
    print(f"{'scene':28s} {'N':>6} {'grid':>8} {'sweep':>8} {'pairs':>8}")
    for name, (p, v, a, r) in cases:
        h = 5.0
        m = r.shape[0]
        lo, hi = bp.swept_bounds(p, v, a, r, 0.0, h)
        kw = dict(p=p, v=v, a=a, r=r, tref=np.zeros(m), t_start=0.0, t_end=h)
        out = {}
        for meth in ("grid", "sweep"):
            bp.candidate_pairs(lo, hi, method=meth, **kw)
            tb, _, (I, J, _) = best_of(lambda: bp.candidate_pairs(lo, hi, method=meth, **kw), 5)
            out[meth] = (tb, I.size)
        assert out["grid"][1] == out["sweep"][1]
        print(
            f"{name:28s} {m:6d} {out['grid'][0] * 1e3:8.2f} {out['sweep'][0] * 1e3:8.2f} "
            f"{out['grid'][1]:8d}"
        )


def bench_dense(n, side, h, rng, check):
    section(f"dense stress: N={n} in {side:g} m x {side:g} m, horizon {h:g} s")
    p, v, a, r = make_scene(n, side, rng)
    predict_all_pairs(p, v, a, r, h)
    tracemalloc.start()
    t0 = time.perf_counter()
    res, st = predict_all_pairs(p, v, a, r, h, return_stats=True)
    t = time.perf_counter() - t0
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    allp = n * (n - 1) // 2
    print(
        f"time {t * 1e3:.0f} ms; bound pairs {st['n_box']} ({st['n_box'] / allp:.0%}), "
        f"narrow pairs {st['n_candidates']}, contacts {len(res)}; "
        f"peak traced memory {peak / 2**20:.1f} MiB"
    )
    if check:
        t0 = time.perf_counter()
        I, J, T = all_pairs_narrow(p, v, a, r, h)
        t_all = time.perf_counter() - t0
        assert np.array_equal(res.i, I) and np.array_equal(res.j, J) and np.array_equal(res.ttc, T)
        print(f"equals all-pairs narrow phase: yes ({t_all * 1e3:.0f} ms for all pairs)")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="small scenes, a few seconds")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    t_start = time.perf_counter()
    if args.quick:
        ratio = bench_speedup(1000, 1000.0 * (1000 / 3000) ** 0.5, 5.0, rng, 3)
        bench_full(3000, 1000.0, 5.0, rng, 3)
        bench_scene_update(3000, 1000.0, 5.0, rng, 50)
        bench_cull([1000, 3000], [1.0, 5.0], 1000.0, rng)
        bench_dense(500, 10.0, 5.0, rng, check=True)
        bench_generators(rng, True)
    else:
        ratio = bench_speedup(3000, 1000.0, 5.0, rng, 5)
        assert ratio >= 20.0, f"speed-up {ratio:.1f}x < 20x"
        bench_full(10000, 1000.0, 5.0, rng, 7)
        med = bench_scene_update(10000, 1000.0, 5.0, rng, 300)
        print(f"one-body update target <= 1 ms: {'met' if med <= 1e-3 else 'NOT met'}")
        bench_stream(10000, 1000.0, 5.0, rng, 30, 0.01)
        bench_stream(10000, 1000.0, 5.0, rng, 30, 1.0)
        bench_cull([1000, 3000, 10000, 30000], [1.0, 5.0, 20.0], 1000.0, rng)
        bench_dense(2000, 20.0, 5.0, rng, check=True)
        bench_generators(rng, False)
        section("3-D: N=3000 in a 300 m cube")
        p, v, a, r = make_scene(3000, 300.0, rng, dim=3)
        predict_all_pairs(p, v, a, r, 5.0)
        tb, tm, (res, st) = best_of(
            lambda: predict_all_pairs(p, v, a, r, 5.0, return_stats=True), 5
        )
        print(f"best {tb * 1e3:.1f} ms; narrow pairs {st['n_candidates']}, contacts {len(res)}")
    print(f"\ntotal bench time {time.perf_counter() - t_start:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
