"""Run time against error: every first-contact solver on the same stress families.

    .venv/bin/python bench/accuracy_vs_time.py [--quick] [--cases N] [--out DIR]

(normally driven by ``bench/run_all.py``).  The stress families and the
mpmath ground truth are the accuracy tests' own
(``tests/core/test_narrow_phase_accuracy.FAMILIES`` with the same per-family
seeds, ``tests/core/reference.reference`` from the exact binary64 inputs).
The reference is computed once per case and reused for every method.

Per method x family:

* ns/pair: best of several timed calls on the family's cases tiled to a few
  thousand rows (so small families still give stable timings); the same
  rows for every method, measured in the same run.
* error: ``|t - t_ref| / ulp(t_ref) * |cos|`` over the contacts both agree on
  (``cos`` = angle between centre line and relative velocity at contact, the
  condition normalisation of the accuracy tests); ``t_ref == 0`` counts
  0 ulp if the method returns exactly 0, else infinity.
* missed / spurious: contact vs no contact against the reference, except the
  cases the reference flags ambiguous (exact minimum gap within 1e-9 R^2).
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing
import os
import time
from pathlib import Path

import numpy as np

import _common  # noqa: F401  (sys.path for the repo root and bench/)
from _common import best_of, fmt_ns, fmt_ulp, md_table, pyplot

from baselines import ttc_companion_eigvals, ttc_ferrari, ttc_lecture, ttc_numpy_roots_loop
from tests.core.reference import reference
from tests.core.narrow.test_narrow_phase_accuracy import FAMILIES, case_error, family_cases

ZERO_FLOOR = 0.1  # where 0-ulp results are drawn on the log axis
INF_CAP = 1e21  # where infinite errors (wrong "already touching") and anything larger are drawn


# ---------------------------------------------------------------- methods


def _ours():
    from circle_collision_ros.core import time_to_collision

    return time_to_collision


def _ours_serial(*args, horizon=math.inf):
    from circle_collision_ros.core.narrow.batch import ttc_kernel

    vecs = [np.ascontiguousarray(x, dtype=np.float64) for x in args]
    n = vecs[3].shape[0]
    out = np.empty(n)
    ttc_kernel(*vecs, np.full(n, float(horizon)), out)
    return out


def _ours_threaded(*args, horizon=math.inf):
    return _ours()(*args, horizon=horizon)


def methods() -> list[dict]:
    """Methods in plot/table order; ``loop``: Python loop per pair (timed on fewer rows)."""
    import numba

    from circle_collision_ros.core.narrow.batch import PARALLEL_MIN_ROWS

    nt = numba.get_num_threads()
    return [
        dict(key="roots_loop", name="numpy.roots loop", fn=ttc_numpy_roots_loop, loop=True,
             marker="v"),
        dict(key="eigvals", name="companion eigvals (batched)", fn=ttc_companion_eigvals,
             loop=False, marker="s"),
        dict(key="ferrari", name="Ferrari closed form (vectorised)", fn=ttc_ferrari, loop=False,
             marker="D"),
        dict(key="lecture", name="seed lecture (absolute coeffs, 1e-6 tol)", fn=ttc_lecture,
             loop=False, marker="X"),
        dict(key="ours_serial", name="ours (numba, serial kernel)", fn=_ours_serial, loop=False,
             marker="o"),
        dict(
            key="ours_threaded",
            name=f"ours (time_to_collision, {nt} threads >= {PARALLEL_MIN_ROWS} rows if a core is "
                 "free)",
            fn=_ours_threaded,
            loop=False,
            marker="*",
        ),
    ]


# ---------------------------------------------------------------- reference


def _ref_job(job):
    row, H, known = job
    if not math.isnan(known):
        return float(known), 1.0, False
    r = reference(*row, horizon=H)
    return r.t, r.cos, bool(r.ambiguous)


def references(cases: dict, jobs: int) -> dict:
    """name -> (t_ref, cos, ambiguous) arrays; mpmath, the slow part (forked workers)."""
    flat = []
    for name, (args, H, known) in cases.items():
        n = args[3].shape[0]
        flat += [(name, ([x[i] for x in args], H, known[i])) for i in range(n)]
    payload = [j for _, j in flat]
    if jobs > 1:
        # fork before any numba threads exist in this process (references run first)
        with multiprocessing.get_context("fork").Pool(jobs) as pool:
            res = pool.map(_ref_job, payload, chunksize=4)
    else:
        res = [_ref_job(j) for j in payload]
    out: dict = {}
    k = 0
    for name, (args, H, known) in cases.items():
        n = args[3].shape[0]
        part = res[k : k + n]
        k += n
        out[name] = (np.array([p[0] for p in part]), np.array([p[1] for p in part]),
                     np.array([p[2] for p in part], dtype=bool))
    return out


# ---------------------------------------------------------------- scoring


def score(got: np.ndarray, ref) -> dict:
    """Condition-normalised ulp error and missed/spurious counts (see module doc)."""
    t_ref, cos, amb = ref
    got = np.where(np.isnan(got), np.inf, got)  # NaN = no answer = no contact
    errs = []
    missed = spurious = contacts = 0
    for g, t, c, a in zip(got, t_ref, cos, amb):
        if a:
            continue
        if math.isinf(t) != math.isinf(g):
            if math.isinf(g):
                missed += 1
            else:
                spurious += 1
            continue
        if math.isinf(g):
            continue
        contacts += 1
        errs.append(case_error(g, t, c))
    errs_a = np.array(errs) if errs else np.array([np.nan])
    return dict(contacts=contacts, missed=missed, spurious=spurious, ambiguous=int(np.sum(amb)),
                median_ulp=float(np.median(errs_a)) if errs else float("nan"),
                worst_ulp=float(np.max(errs_a)) if errs else float("nan"),
                errors=[float(e) for e in errs])


# ---------------------------------------------------------------- timing


def time_method(fn, args, H, *, loop: bool, quick: bool) -> dict:
    """ns/pair on the family's rows tiled to ``rows`` (>= the family size)."""
    n = args[3].shape[0]
    fn(*(x[: min(n, 8)] for x in args), horizon=H)  # warm up (numba cache load, imports)
    t0 = time.perf_counter()
    fn(*args, horizon=H)
    per_row = max((time.perf_counter() - t0) / n, 1e-9)
    target = (0.004 if quick else 0.03) if loop else (0.005 if quick else 0.02)
    cap = (1000 if quick else 3000) if loop else (20_000 if quick else 65_536)
    floor = n if loop else min(8192, cap)  # >= 4096 rows: the threaded path engages
    rows = int(min(cap, max(floor, target / per_row)))
    if loop:
        rows = min(rows, n * max(1, int(round(rows / n))))
    idx = np.arange(rows) % n
    tiled = tuple(np.ascontiguousarray(x[idx]) for x in args)
    best, med = best_of(lambda: fn(*tiled, horizon=H), 2 if (loop or quick) else 5)
    return dict(ns_per_pair=1e9 * best / rows, ns_per_pair_median=1e9 * med / rows, rows=rows)


# ---------------------------------------------------------------- run


def run(quick: bool = False, cases: int | None = None, jobs: int | None = None,
        families: list[str] | None = None, log=print) -> dict:
    n = cases or (12 if quick else 300)
    jobs = jobs or min(2, os.cpu_count() or 1)
    fams = families or list(FAMILIES)
    t0 = time.perf_counter()
    data = {name: family_cases(name, n) for name in fams}
    refs = references(data, jobs)
    t_ref = time.perf_counter() - t0
    log(
        f"  references: {sum(a[3].shape[0] for a, _, _ in data.values())} cases in {t_ref:.1f} s "
        f"({jobs} processes)"
    )
    ms = methods()
    res: dict = {"cases_per_family": n, "families": fams, "reference_seconds": t_ref,
                 "methods": [{k: m[k] for k in ("key", "name", "marker", "loop")} for m in ms],
                 "results": {}}
    for name in fams:
        args, H, _ = data[name]
        row = {}
        outs = {}
        for m in ms:
            got = np.asarray(m["fn"](*args, horizon=H), dtype=np.float64)
            outs[m["key"]] = got
            s = score(got, refs[name])
            s.update(time_method(m["fn"], args, H, loop=m["loop"], quick=quick))
            row[m["key"]] = s
        row["_serial_equals_threaded"] = bool(
            np.array_equal(outs["ours_serial"], outs["ours_threaded"])
        )
        res["results"][name] = row
        log(
            f"  {name:18s} "
            + "  ".join(
                f"{m['key']}={row[m['key']]['ns_per_pair']:.0f}ns/"
                f"{fmt_ulp(row[m['key']]['worst_ulp'])}u/"
                f"{row[m['key']]['missed']}m{row[m['key']]['spurious']}s"
                for m in ms
            )
        )
    res["totals"] = totals(res)
    return res


def totals(res: dict) -> dict:
    """Per method: mean ns/pair over families, pooled median/worst error, missed/spurious sums."""
    out = {}
    for m in res["methods"]:
        k = m["key"]
        rows = [res["results"][f][k] for f in res["families"]]
        errs = np.array([e for r in rows for e in r["errors"]])
        finite = errs[np.isfinite(errs)]
        out[k] = dict(
            ns_per_pair=float(np.mean([r["ns_per_pair"] for r in rows])),
            ns_per_pair_median_family=float(np.median([r["ns_per_pair"] for r in rows])),
            median_ulp=float(np.median(errs)) if errs.size else float("nan"),
            worst_ulp=float(np.max(errs)) if errs.size else float("nan"),
            worst_finite_ulp=float(np.max(finite)) if finite.size else float("nan"),
            wrong_t0=int(np.sum(np.isinf(errs))),
            over_4ulp=int(np.sum(errs > 4.0)),
            contacts=int(errs.size),
            missed=int(sum(r["missed"] for r in rows)),
            spurious=int(sum(r["spurious"] for r in rows)),
            families_with_misses=int(sum((r["missed"] + r["spurious"]) > 0 for r in rows)),
        )
    return out


# ---------------------------------------------------------------- report


def headline_table(res: dict) -> str:
    tot = res["totals"]
    base = tot["ours_serial"]["ns_per_pair"]
    base_med = tot["ours_serial"]["ns_per_pair_median_family"]
    rows = []
    for m in res["methods"]:
        t = tot[m["key"]]
        rows.append(
            [m["name"], fmt_ns(t["ns_per_pair"]), fmt_ns(t["ns_per_pair_median_family"]),
             f"{t['ns_per_pair'] / base:.2f}", f"{t['ns_per_pair_median_family'] / base_med:.2f}",
             fmt_ulp(t["median_ulp"]), fmt_ulp(t["worst_finite_ulp"]), t["wrong_t0"],
             t["over_4ulp"], t["missed"], t["spurious"]]
        )
    return md_table(
        ["method", "ns/pair (mean of families)", "ns/pair (median family)", "x ours serial (mean)",
         "x ours serial (median family)", "median err (ulp)", "worst finite err (ulp)", "wrong t=0",
         "contacts > 4 ulp", "missed", "spurious"],
        rows,
    )


def family_table(res: dict) -> str:
    rows = []
    for f in res["families"]:
        for m in res["methods"]:
            r = res["results"][f][m["key"]]
            rows.append(
                [f, m["name"], fmt_ns(r["ns_per_pair"]), fmt_ulp(r["median_ulp"]),
                 fmt_ulp(r["worst_ulp"]), r["contacts"], r["missed"], r["spurious"], r["ambiguous"]]
            )
    return md_table(
        ["family", "method", "ns/pair", "median err (ulp)", "worst err (ulp)", "contacts", "missed",
         "spurious", "ambiguous (exempt)"],
        rows,
        "llrrrrrrr",
    )


def miss_table(res: dict) -> str:
    ms = res["methods"]
    rows = []
    for f in res["families"]:
        rows.append(
            [f]
            + [
                f"{res['results'][f][m['key']]['missed']} / "
                f"{res['results'][f][m['key']]['spurious']}"
                for m in ms
            ]
        )
    rows.append(
        ["**total**"]
        + [
            f"**{res['totals'][m['key']]['missed']} / {res['totals'][m['key']]['spurious']}**"
            for m in ms
        ]
    )
    return md_table(["family"] + [m["name"] for m in ms], rows)


def write_markdown(res: dict, out: Path) -> Path:
    p = out / "accuracy_vs_time.md"
    n = res["cases_per_family"]
    txt = [
        "# Run time against error\n",
        f"{n} cases per stress family ({len(res['families'])} families, the accuracy tests' "
        "generators and "
        "seeds), mpmath reference from the exact binary64 inputs. Error = |t - t_ref| / ulp(t_ref) "
        "x |cos| "
        "(condition-normalised as in tests/core/test_narrow_phase_accuracy.py) over the contacts "
        "method and "
        "reference agree on; `inf` = reported a positive time for bodies already touching at t = 0 "
        "(or the "
        "reverse). Missed/spurious: contact vs no contact against the reference, cases whose exact "
        "minimum "
        "gap is within 1e-9 R^2 of zero exempt. ns/pair: best of repeated calls on the family's "
        "cases "
        "tiled to >= 8192 rows (Python-loop method: fewer rows), all methods in the same run.\n",
        "## All families\n",
        headline_table(res),
        "\n## Missed / spurious contacts per family (missed / spurious)\n",
        miss_table(res),
        "\n## Per family\n",
        family_table(res),
        "\n![run time against error](accuracy_vs_time.png)\n",
    ]
    p.write_text("\n".join(txt))
    return p


def plot(res: dict, out: Path) -> list[Path]:
    plt = pyplot()
    ms = res["methods"]
    colors = {m["key"]: c for m, c in zip(ms, plt.rcParams["axes.prop_cycle"].by_key()["color"])}

    def y_of(v):
        if v != v:  # no contact to get wrong in this family: drawn as 0
            return ZERO_FLOOR
        return min(max(v, ZERO_FLOOR), INF_CAP)

    def decorate(ax, title):
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_ylim(ZERO_FLOOR / 3, INF_CAP * 30)
        ax.axhline(ZERO_FLOOR, color="0.75", lw=0.8, ls=":")
        ax.axhline(4.0, color="tab:green", lw=0.8, ls="--")
        ax.axhline(INF_CAP, color="tab:red", lw=0.8, ls=":")
        ax.set_title(title, fontsize=9)
        ax.tick_params(labelsize=7)
        ax.grid(True, which="major", alpha=0.3)

    paths = []
    fams = res["families"]
    ncol = 4
    nrow = math.ceil((len(fams) + 1) / ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(4.0 * ncol, 3.2 * nrow), squeeze=False)
    for ax, f in zip(axes.flat, fams):
        for m in ms:
            r = res["results"][f][m["key"]]
            y = y_of(r["worst_ulp"])
            bad = r["missed"] + r["spurious"]
            ax.scatter(r["ns_per_pair"], y, marker=m["marker"], s=60, color=colors[m["key"]],
                       edgecolors="red" if bad else "none", linewidths=2.0 if bad else 0, zorder=3)
            if bad:
                ax.annotate(f"{r['missed']}m/{r['spurious']}s", (r["ns_per_pair"], y), fontsize=7,
                            color="red", xytext=(4, -10), textcoords="offset points")
        decorate(ax, f)
    for ax in axes[-1]:
        ax.set_xlabel("ns per pair (log)", fontsize=8)
    for ax in axes[:, 0]:
        ax.set_ylabel("worst error, ulp x |cos| (log)", fontsize=8)
    leg_ax = axes.flat[len(fams)]
    leg_ax.axis("off")
    for m in ms:
        leg_ax.scatter([], [], marker=m["marker"], s=60, color=colors[m["key"]], label=m["name"])
    leg_ax.scatter([], [], marker="o", s=60, facecolors="none", edgecolors="red", linewidths=2,
                   label="red ring: missed/spurious\ncontacts (count: m/s)")
    leg_ax.legend(loc="center", fontsize=7, frameon=False)
    leg_ax.text(
        0.0,
        -0.05,
        f"0 ulp (or no contacts) drawn at {ZERO_FLOOR:g} (dotted grey);\n"
        f"inf (wrong t=0) and >= {INF_CAP:.0e} drawn at {INF_CAP:.0e} (dotted red);\n"
        "dashed green: 4 ulp. Bottom-left is best.",
        fontsize=7,
        transform=leg_ax.transAxes,
        va="top",
    )
    for ax in list(axes.flat)[len(fams) + 1 :]:
        ax.axis("off")
    fig.suptitle(
        f"Run time against worst error per stress family ({res['cases_per_family']} cases each, "
        "mpmath reference)",
        fontsize=11,
    )
    fig.tight_layout()
    p = out / "accuracy_vs_time_families.png"
    fig.savefig(p, dpi=90)
    plt.close(fig)
    paths.append(p)

    # headline: all families pooled; filled marker = worst, hollow = median, joined by a line
    fig, ax = plt.subplots(figsize=(10.5, 5.4))
    tot = res["totals"]
    for k, m in enumerate(ms):
        t = tot[m["key"]]
        x = t["ns_per_pair"]
        y = y_of(t["worst_finite_ulp"])
        ymed = y_of(t["median_ulp"])
        bad = t["missed"] + t["spurious"]
        ax.plot([x, x], [ymed, y], color=colors[m["key"]], lw=1.2, zorder=2)
        ax.scatter(x, ymed, marker=m["marker"], s=70, facecolors="white",
                   edgecolors=colors[m["key"]], linewidths=1.5, zorder=3)
        ax.scatter(x, y, marker=m["marker"], s=110, color=colors[m["key"]],
                   edgecolors="red" if bad else "none", linewidths=2.0 if bad else 0, zorder=4,
                   label=m["name"])
        note = f"{t['missed']} missed / {t['spurious']} spurious" if bad else ""
        if t["wrong_t0"]:
            note += f"{', ' if note else ''}{t['wrong_t0']} wrong t=0"
        if note:
            ax.annotate(note, (x, y), fontsize=7, color="red", xytext=(8, -12 - 11 * (k % 3)),
                        textcoords="offset points")
    decorate(ax, "")
    ax.set_xlabel("ns per pair, mean over families (log)")
    ax.set_ylabel(
        "error over all families, ulp x |cos| (log)\nfilled: worst finite, hollow: median"
    )
    ax.set_title(
        f"Run time against error, {len(res['families'])} stress families x "
        f"{res['cases_per_family']} cases (bottom-left is best)\n"
        f"0 ulp drawn at {ZERO_FLOOR:g}; >= {INF_CAP:.0e} drawn at {INF_CAP:.0e} (dotted red); "
        "dashed: 4 ulp; red ring: missed/spurious contacts",
        fontsize=9,
    )
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
    fig.tight_layout()
    p = out / "accuracy_vs_time.png"
    fig.savefig(p, dpi=100)
    plt.close(fig)
    paths.append(p)
    return paths


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--cases", type=int)
    ap.add_argument("--jobs", type=int)
    ap.add_argument("--family", action="append")
    ap.add_argument("--out", default=str(_common.HERE / "results"))
    a = ap.parse_args(argv)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    res = run(a.quick, a.cases, a.jobs, a.family)
    for k in res["results"].values():
        for m in list(k):
            if isinstance(k[m], dict):
                k[m].pop("errors", None)
    (out / "accuracy_vs_time.json").write_text(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
