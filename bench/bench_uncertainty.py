"""Collision probability, ours vs plain Monte Carlo, per pair.

    .venv/bin/python bench/bench_uncertainty.py [--pairs N] [--quick] [--out
    docs/uncertainty_bench.png]

Families (``FAMILIES``; 2-D unless marked 3-D, horizon 3 s, each with N
random variations of the geometry and of a correlated position/velocity
covariance): head-on; crossing; near-miss with sigma comparable to the miss
distance; overlapping at the start; very large sigma; tiny sigma (must
approach the exact answer); accelerating crossing (da != 0: bracket or
RQMC); head-on and crossing in 3-D.

Per pair: ours = ``uncertain_pairs`` (one row, threshold 0.01); plain Monte
Carlo with 1e3, 1e4, 1e5 samples (seeded numpy normals through the exact
batched solver ``time_to_collision``); the reference is MC with 1e6 samples
(other seed) and its standard error SE_ref = sqrt(p (1 - p) / 1e6).  Times
are per pair, the best of 3 calls for ours and for each MC size (sampling
included; the best of 3 for both, so that a burst of load on the shared
machine during one MC call does not inflate the ratio), single-threaded
(numba.set_num_threads(1)), all measured in the same run (the machine is
shared: compare ratios, not absolute times).

Targets checked per family: |ours - ref| <= max(0.005, 3 SE_ref) on every
pair; our stated bound never exceeded (|ours - ref| <= bound + 3 SE_ref:
the reference's own noise cannot be checked below that); ours >= 100x
faster per pair than MC with 1e5 samples while our error (|ours - ref|)
is no larger than MC 1e5's.
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numba
import numpy as np

import _common  # noqa: F401  (sys.path for the repo root and bench/)
from _common import ROOT, md_table, pyplot

from circle_collision_ros.core import time_to_collision
from circle_collision_ros.core.uncertainty import uncertain_pairs

H = 3.0
THRESHOLD = 0.01
MC_SIZES = (1_000, 10_000, 100_000)
REF_SIZE = 1_000_000


def _cov(rng, D, sp, sv):
    """A random correlated (2D, 2D) covariance with position sigma ~sp and velocity sigma ~sv."""
    B = rng.normal(size=(2 * D, 2 * D))
    B[:D] *= sp
    B[D:] *= sv
    C = B @ B.T / (2 * D)
    return 0.5 * (C + C.T)


def _family(name, rng, D=2):
    """(pa, va, aa, ra, cov_a, pb, vb, ab, rb, cov_b) of one random pair of family ``name``."""
    z = np.zeros(D)
    e = np.eye(D)
    j = rng.normal(size=D) * 0.05
    ra, rb = 0.5, 0.5
    sp, sv = 0.3, 0.1
    aa = z.copy()
    if name.startswith("head-on"):
        pa, va, pb, vb = -4 * e[0] + j, 2 * e[0], 4 * e[0], -1.5 * e[0]
    elif name.startswith("crossing"):
        pa, va, pb, vb = -4 * e[0] + j, 2 * e[0], -4 * e[1], 2 * e[1]
    elif name == "near-miss":
        miss = 1.0 + rng.uniform(0.2, 0.4)
        pa, va, pb, vb = -4 * e[0], 2 * e[0], 4 * e[0] + miss * e[1], -1.5 * e[0]
        sp = miss - 1.0
    elif name == "overlap at start":
        pa, va, pb, vb = z + j, -1 * e[0], 0.8 * e[0], 1 * e[0] + 0.5 * e[1]
    elif name == "large sigma":
        pa, va, pb, vb = -4 * e[0] + j, 2 * e[0], 4 * e[0] + 2 * e[1], -1.5 * e[0]
        sp, sv = 5.0, 1.0
    elif name == "tiny sigma":
        pa, va, pb, vb = -4 * e[0], 2 * e[0], 4 * e[0] + rng.uniform(0.9, 1.1) * e[1], -1.5 * e[0]
        sp, sv = 1e-4, 1e-5
    elif name == "accelerating":
        pa, va, pb, vb = -4 * e[0] + j, 1 * e[0], -4 * e[1], 2 * e[1]
        aa = 1.0 * e[0] + 0.5 * e[1]
    else:
        raise ValueError(name)
    ca = _cov(rng, D, sp, sv)
    cb = _cov(rng, D, sp, sv)
    return pa, va, aa, ra, ca, pb, vb, z, rb, cb


FAMILIES = [("head-on", 2), ("crossing", 2), ("near-miss", 2), ("overlap at start", 2),
            ("large sigma", 2), ("tiny sigma", 2), ("accelerating", 2), ("head-on 3-D", 3),
            ("crossing 3-D", 3)]


def monte_carlo(pair, n, seed, repeat=1):
    """(estimate, seconds): n samples of (dp, dv) through the exact batched solver;
    seconds = the best of ``repeat`` identical calls (same seed, same estimate)."""
    best = math.inf
    for _ in range(repeat):
        p, t = _monte_carlo_once(pair, n, seed)
        best = min(best, t)
    return p, best


def _monte_carlo_once(pair, n, seed):
    pa, va, aa, ra, ca, pb, vb, ab, rb, cb = pair
    D = pa.shape[0]
    t0 = time.perf_counter()
    rng = np.random.default_rng(seed)
    L = (
        np.linalg.cholesky(ca + cb + 1e-300 * np.eye(2 * D))
        if np.any(ca + cb)
        else np.zeros((2 * D, 2 * D))
    )
    y = rng.standard_normal((n, 2 * D)) @ L.T
    dp = (pa - pb) + y[:, :D]
    dv = (va - vb) + y[:, D:]
    zeros = np.zeros((n, D))
    t = time_to_collision(dp, dv, np.broadcast_to(aa - ab, (n, D)), np.full(n, ra + rb), zeros,
                          zeros, zeros, np.zeros(n), H)
    p = float(np.count_nonzero(t <= H)) / n
    return p, time.perf_counter() - t0


def ours(pair):
    """(probability, bound, seconds per pair: best of 3)."""
    args = [np.asarray(x, dtype=np.float64)[None] for x in pair]
    best = math.inf
    for _ in range(3):
        t0 = time.perf_counter()
        r = uncertain_pairs(*args, H, THRESHOLD)
        best = min(best, time.perf_counter() - t0)
    return float(r.collision_probability[0]), float(r.collision_probability_bound[0]), best


def run(pairs: int, seed: int = 18):
    rows = []
    for fi, (name, D) in enumerate(FAMILIES):
        rng = np.random.default_rng(seed + 100 * fi)
        recs = []
        for k in range(pairs):
            pair = _family(name.replace(" 3-D", ""), rng, D)
            ref, _ = monte_carlo(pair, REF_SIZE, seed=10_000 + 97 * fi + k)
            se_ref = math.sqrt(max(ref * (1 - ref), 1.0 / REF_SIZE) / REF_SIZE)
            p, b, t_ours = ours(pair)
            mc = [monte_carlo(pair, n, seed=20_000 + 97 * fi + k + n, repeat=3) for n in MC_SIZES]
            recs.append(
                dict(ref=ref, se_ref=se_ref, ours=p, bound=b, t_ours=t_ours,
                     mc=[(abs(q - ref), t) for q, t in mc])
            )
        rows.append((name, recs))
    return rows


def summarize(rows):
    table = []
    checks = []
    for name, recs in rows:
        err = max(abs(r["ours"] - r["ref"]) for r in recs)
        t_o = float(np.mean([r["t_ours"] for r in recs]))
        bound = max(r["bound"] for r in recs)
        mc_err = [max(r["mc"][j][0] for r in recs) for j in range(len(MC_SIZES))]
        mc_t = [float(np.mean([r["mc"][j][1] for r in recs])) for j in range(len(MC_SIZES))]
        ok_acc = all(abs(r["ours"] - r["ref"]) <= max(0.005, 3 * r["se_ref"]) for r in recs)
        ok_bound = all(abs(r["ours"] - r["ref"]) <= r["bound"] + 3 * r["se_ref"] for r in recs)
        speed = mc_t[2] / t_o
        ok_speed = speed >= 100 and err <= max(mc_err[2], 3 * max(r["se_ref"] for r in recs))
        refs = [r["ref"] for r in recs]
        table.append(
            [name, f"{min(refs):.4f}-{max(refs):.4f}", f"{t_o * 1e6:,.0f}", f"{err:.1e}",
             f"{bound:.1e}"]
            + [f"{t * 1e6:,.0f} / {e:.1e}" for t, e in zip(mc_t, mc_err)]
            + [f"{speed:,.0f}x"]
        )
        checks.append((name, ok_acc, ok_bound, ok_speed))
    header = (
        ["family", "P (ref, 1e6 MC)", "ours us/pair", "ours max err", "ours max bound"]
        + [f"MC {n:.0e} us/pair / max err" for n in MC_SIZES]
        + ["MC 1e5 / ours"]
    )
    return md_table(header, table), checks


def plot(rows, path: Path):
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7.5, 5))
    markers = "osD^v<>ph"
    for fi, (name, recs) in enumerate(rows):
        m = markers[fi % len(markers)]
        t_o = np.mean([r["t_ours"] for r in recs]) * 1e6
        e_o = max(max(abs(r["ours"] - r["ref"]) for r in recs), 1e-6)
        ax.scatter([t_o], [e_o], marker=m, color="C0", label="ours" if fi == 0 else None)
        for j, n in enumerate(MC_SIZES):
            t = np.mean([r["mc"][j][1] for r in recs]) * 1e6
            e = max(max(r["mc"][j][0] for r in recs), 1e-6)
            ax.scatter(
                [t], [e], marker=m, color=f"C{j + 1}", label=f"MC {n:.0e}" if fi == 0 else None
            )
    ax.axhline(0.005, color="grey", ls="--", lw=0.8)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("time per pair [us] (same run)")
    ax.set_ylabel("max |P - P_ref| per family (floor 1e-6)")
    ax.set_title(
        "Collision probability within 3 s: ours vs plain Monte Carlo\n"
        "(marker = family; reference: 1e6-sample MC)",
        fontsize=10,
    )
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def main(argv=None):
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--pairs", type=int, default=5, help="random pairs per family (default 5)")
    ap.add_argument("--quick", action="store_true", help="2 pairs per family")
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "uncertainty_bench.png")
    a = ap.parse_args(argv)
    pairs = 2 if a.quick else a.pairs
    # one thread for every method: ours is serial per pair, and on a shared
    # machine the threaded solver's launches wait for time slices, which
    # would make MC look slower than it is
    numba.set_num_threads(1)
    # warm-up: compile every kernel outside the timings
    for name, D in FAMILIES:
        ours(_family(name.replace(" 3-D", ""), np.random.default_rng(0), D))
    monte_carlo(_family("head-on", np.random.default_rng(0)), 1000, 0)
    rows = run(pairs)
    table, checks = summarize(rows)
    print(table)
    # the baseline's own state: MC streams ~10 MB per 1e5-sample call, so memory traffic
    # from other work on the host slows it more than ours (cache-resident); a run whose
    # MC took much longer per sample than usual overstates the ratios
    for D in (2, 3):
        t = [r["mc"][2][1] for name, recs in rows for r in recs if dict(FAMILIES)[name] == D]
        print(
            f"MC 1e5 in {D}-D: {np.median(t) / MC_SIZES[2] * 1e9:.0f} ns per sample (median over "
            "pairs)"
        )
    for name, ok_acc, ok_bound, ok_speed in checks:
        print(
            f"{name:18s} accuracy {'PASS' if ok_acc else 'FAIL'}  bound "
            f"{'PASS' if ok_bound else 'FAIL'}"
            f"  >=100x MC1e5 at <= its error {'PASS' if ok_speed else 'FAIL'}"
        )
    print(f"plot: {plot(rows, a.out)}")
    return 0 if all(all(c[1:]) for c in checks) else 1


if __name__ == "__main__":
    raise SystemExit(main())
