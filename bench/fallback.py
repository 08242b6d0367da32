"""How often the narrow phase needs its exact-rational fallback, and what one such row costs.

Usage::

    .venv/bin/python bench/fallback.py            # bench_core mix (200,000 pairs) + 14 families x
    2000
    .venv/bin/python bench/fallback.py --quick    # 20,000 pairs, 300 per family

For each mix it prints the rows, the share the SIMD fast path leaves to the
robust solver, the rows the robust solver leaves UNDECIDED (decided exactly
by ``core.narrow_exact``), their share, and the slowest single fallback row
(wall time of ``exact_first_contact`` on it).  Mixes: bench/bench_core.py's
2-D mix (H = 10 s and H = inf), the accuracy families of
tests/core/narrow/test_narrow_phase_accuracy.py (also run by scripts/bench.sh), and
the defect-class generators of tests/core/narrow/test_narrow_phase_exact.py
(which exist to hit the fallback), and all pairs of two scale-bench scenes.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, ROOT)

from circle_collision_ros.core.narrow import batch as npz  # noqa: E402
from circle_collision_ros.core.narrow.exact import exact_first_contact  # noqa: E402
from circle_collision_ros.core.narrow.fast import UNDECIDED  # noqa: E402
from tests.core.narrow.test_narrow_phase_accuracy import FAMILIES, family_cases, mixed_pairs  # noqa: E402
from tests.core.narrow.test_narrow_phase_exact import GENS  # noqa: E402

sys.path.insert(0, HERE)
from bench_scene import make_scene  # noqa: E402


def fallback_stats(args, H):
    """(rows, fast-path undecided, exact-fallback rows, worst fallback row [s]:
    wall time and CPU time of the process -- the CPU figure is the one to
    quote on a shared, busy machine)."""
    args = tuple(np.ascontiguousarray(x, dtype=np.float64) for x in args)
    n = args[3].shape[0]
    D = args[0].shape[1]
    out = np.empty(n)
    n_fast = 0
    if math.isfinite(H):
        Hs = np.full(n, H)
        for i0 in range(0, n, npz._BLOCK):
            i1 = min(n, i0 + npz._BLOCK)
            npz.fast_rows(*args, Hs, i0, out, i0, i1 - i0, (0.0,) * D)
        n_fast = int(np.sum(out == UNDECIDED))
    n_und = npz._KERNELS[(D, False)](*args, float(H), out)
    worst = worst_cpu = 0.0
    for i in np.flatnonzero(out == UNDECIDED):
        row = [x[i] for x in args]
        t0, c0 = time.perf_counter(), time.process_time()
        exact_first_contact(*row, H)
        worst = max(worst, time.perf_counter() - t0)
        worst_cpu = max(worst_cpu, time.process_time() - c0)
    return n, n_fast, int(n_und), worst, worst_cpu


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--quick", action="store_true")
    a = ap.parse_args()
    n_mix = 20_000 if a.quick else 200_000
    n_fam = 300 if a.quick else 2000
    mixes = [
        (f"bench_core mix H=10 ({n_mix})", mixed_pairs(n_mix, 2, 1), 10.0),
        (f"bench_core mix H=inf ({n_mix})", mixed_pairs(n_mix, 2, 1), math.inf),
    ]
    for name in FAMILIES:
        args, H, _known = family_cases(name, n_fam)
        mixes.append((f"family {name}", args, H))
    # scale-bench scenes (bench/scale.py: uniform, |v| <= 3 m/s, |a| <= 0.5 m/s^2): every pair
    # of a 1000-body scene at its dense and sparse density, horizon 5 s
    for side in (100.0, 1000.0):
        p, v, acc, r = make_scene(1000, side, np.random.default_rng(3))
        i, j = np.triu_indices(1000, 1)
        mixes.append(
            (f"scene 1000 bodies, {side:g} m side",
             (p[i], v[i], acc[i], r[i], p[j], v[j], acc[j], r[j]), 5.0)
        )
    rng = np.random.default_rng(17)
    for cls, gen in GENS.items():
        rows = gen(rng, 100, 2)
        args = tuple(np.array([r[k] for r in rows], dtype=float) for k in range(8))
        mixes.append((f"defect class {cls} (adversarial)", args, math.inf))
    fallback_stats(mixes[0][1], 10.0)  # load compiled code
    print(
        f"{'mix':40s} {'rows':>8s} {'fast undec.':>12s} {'exact rows':>11s} {'exact %':>9s} "
        f"{'worst row (wall / CPU)':>24s}"
    )
    tot = tot_und = 0
    worst_all = worst_all_cpu = 0.0
    for name, args, H in mixes:
        n, n_fast, n_und, worst, worst_cpu = fallback_stats(args, H)
        if not name.startswith("defect class"):
            tot += n
            tot_und += n_und
            worst_all = max(worst_all, worst)
            worst_all_cpu = max(worst_all_cpu, worst_cpu)
        fast = f"{100.0 * n_fast / n:.2f} %" if math.isfinite(H) else "-"
        print(
            f"{name:40s} {n:8d} {fast:>12s} {n_und:11d} {100.0 * n_und / n:8.3f}% "
            f"{worst * 1e3:11.2f} / {worst_cpu * 1e3:6.2f} ms"
        )
    print(
        f"benchmark mixes and families: {tot_und} of {tot} rows to the exact fallback "
        f"({100.0 * tot_und / tot:.4f} %), worst fallback row {worst_all * 1e3:.2f} ms wall, "
        f"{worst_all_cpu * 1e3:.2f} ms CPU"
    )


if __name__ == "__main__":
    main()
