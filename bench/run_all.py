#!/usr/bin/env python3
"""Regenerate every benchmark table and plot (issue #7).

    scripts/bench.sh [--quick] [--out DIR] [--only accuracy|scale|node ...]
    .venv/bin/python bench/run_all.py --render-only [--out DIR]   # re-render from results.json

Sections (each its own module in bench/):

1. accuracy_vs_time -- run time against error of every first-contact solver
   on the accuracy tests' stress families, against the mpmath reference;
2. scale            -- scene prediction time / cull rate / memory / Scene
   update against N;
3. node_latency     -- collision_node latency and sustained rate through DDS.

Writes into --out (default bench/results/, or bench/results/quick/ with
--quick): machine.md, accuracy_vs_time.md, scale.md, node.md, summary.md,
results.json and PNG plots, plus the README's benchmark section (a full run
into the default directory rewrites it in README.md between its markers;
other runs write README_SECTION.md beside their results).  Every number in
those files comes from this run; nothing is typed in.  Full run: a few
minutes on 2 cores; --quick: well under a minute.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
os.environ.setdefault("MPLBACKEND", "Agg")
os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")

import _common  # noqa: E402
import machine  # noqa: E402
from _common import fmt_ms, fmt_ns, fmt_ulp, md_table  # noqa: E402

SECTIONS = ("accuracy", "scale", "node")


def _module(section: str):
    if section == "accuracy":
        import accuracy_vs_time as m
    elif section == "scale":
        import scale as m
    else:
        import node_latency as m
    return m


def _rel(p: Path, base: Path) -> str:
    try:
        return str(p.resolve().relative_to(base.resolve()))
    except ValueError:
        return str(p)


def _strip_errors(acc: dict) -> None:
    for fam in acc["results"].values():
        for v in fam.values():
            if isinstance(v, dict):
                v.pop("errors", None)


# ----------------------------------------------------------------- summary


def _scale_compact(sc: dict) -> str:
    """One row per density/horizon: all-pairs vs ours at the largest all-pairs N, ours at the largest N."""
    rows = []
    for d in sc["densities"]:
        for h in sc["horizons"]:
            rs = [r for r in sc["rows"] if r["density"] == d and r["horizon"] == h]
            if not rs:
                continue
            ap = [r for r in rs if r["all_pairs_ms"]]
            big = rs[-1]
            a = ap[-1] if ap else None
            rows.append([d, f"{h:g}",
                         f"{a['n']}: {fmt_ms(a['all_pairs_ms'])} vs {fmt_ms(a['broad_ms'])} "
                         f"({a['all_pairs_ms'] / a['broad_ms']:.0f}x)" if a else "-",
                         f"{big['n']}: {fmt_ms(big['broad_ms'])}", f"{big['cull_rate']:.1e}",
                         f"{big['broad_peak_rss_mib']:.1f}", fmt_ms(big["update_median_ms"])])
    return md_table(["density (bodies/km^2)", "horizon s", "N: all-pairs ms vs predict_all_pairs ms",
                     "N: predict_all_pairs ms", "cull rate", "peak RSS rise MiB", "1-body update ms"],
                    rows, "lrlrrrr")


def _node_compact(nd: dict) -> str:
    import node_latency

    return node_latency.table(nd)


def _png_ref(out: Path, name: str, readme: bool) -> str:
    p = out / name
    if readme:
        return _rel(p, _common.ROOT)
    return name


def summary_markdown(res: dict, out: Path) -> str:
    info = res["machine"]
    parts = [f"# Benchmark summary ({'quick' if res['quick'] else 'full'} run)\n",
             f"Machine: {machine.one_line(info)} (details: machine.md). Run wall time "
             f"{info.get('wall_s', '?')} s. Ratios compare methods measured in the same run.\n"]
    if "accuracy" in res:
        import accuracy_vs_time as acc

        a = res["accuracy"]
        parts += ["## Run time against error\n",
                  f"{a['cases_per_family']} cases x {len(a['families'])} stress families, mpmath reference "
                  "(details: accuracy_vs_time.md).\n", acc.headline_table(a),
                  "\nMissed / spurious contacts per family:\n", acc.miss_table(a),
                  "\n![run time against error](accuracy_vs_time.png)\n",
                  "![per family](accuracy_vs_time_families.png)\n"]
    if "scale" in res:
        parts += ["## Scale\n", "Details: scale.md.\n", _scale_compact(res["scale"]), "\n![scale](scale.png)\n"]
    if "node" in res:
        parts += ["## Node through DDS (localhost)\n", "Details: node.md.\n", _node_compact(res["node"]),
                  "\n![node](node.png)\n"]
    return "\n".join(parts)


def _reading(res: dict) -> str:
    """The interpretation paragraph, every figure taken from ``res``."""
    s = []
    if "accuracy" in res:
        a = res["accuracy"]
        tot = a["totals"]
        ours = tot["ours_serial"]
        names = {m["key"]: m["name"] for m in a["methods"]}
        med = "ns_per_pair_median_family"
        ratios = ", ".join(f"{names[k]} {tot[k][med] / ours[med]:.1f}x"
                           for k in ("roots_loop", "eigvals", "ferrari", "lecture"))
        slowest = max(a["families"], key=lambda f: a["results"][f]["ours_serial"]["ns_per_pair"])
        s.append(f"**Accuracy and speed.** On the {len(a['families'])} stress families ours (serial kernel) "
                 f"took {fmt_ns(ours[med])} ns/pair in the median family; the other methods took, relative "
                 f"to it, {ratios} (median family; same run, same rows). Its mean over the families, "
                 f"{fmt_ns(ours['ns_per_pair'])} ns/pair, is set by the slowest family, {slowest} "
                 f"({fmt_ns(a['results'][slowest]['ours_serial']['ns_per_pair'])} ns/pair), whose rows the "
                 "exact fallback decides where the others return wrong times. Its worst condition-normalised error was "
                 f"{fmt_ulp(ours['worst_finite_ulp'])} ulp (median {fmt_ulp(ours['median_ulp'])}) with "
                 f"{ours['missed']} missed and {ours['spurious']} spurious contacts. ")
        worst = []
        for k in ("roots_loop", "eigvals", "ferrari", "lecture"):
            t = tot[k]
            bad = sorted((f for f in a["families"]
                          if a["results"][f][k]["missed"] + a["results"][f][k]["spurious"] > 0
                          or a["results"][f][k]["worst_ulp"] > 1e3),
                         key=lambda f: -a["results"][f][k]["worst_ulp"])
            worst.append(f"{names[k]}: worst {fmt_ulp(t['worst_finite_ulp'])} ulp, "
                         f"{t['missed']} missed / {t['spurious']} spurious"
                         + (f", {t['wrong_t0']} wrong t=0" if t["wrong_t0"] else "")
                         + (f" (> 1e3 ulp or missed/spurious in: {', '.join(bad)})" if bad else ""))
        s.append("The power-basis solvers lose digits where the expanded quartic is ill-conditioned: "
                 + "; ".join(worst) + ". ")
        thr = tot["ours_threaded"]["ns_per_pair"] / ours["ns_per_pair"]
        same = all(a["results"][f].get("_serial_equals_threaded", True) for f in a["families"])
        per = sorted((a["results"][f]["ours_threaded"]["ns_per_pair"] / a["results"][f]["ours_serial"]["ns_per_pair"], f)
                     for f in a["families"])
        s.append(f"The threaded path (time_to_collision at >= 4096 rows, when a core is free) took {thr:.2f}x the serial "
                 f"kernel's time per pair on average ({'bitwise-identical answers' if same else 'ANSWERS DIFFER'}); "
                 f"per family from {per[0][0]:.2f}x ({per[0][1]}) to {per[-1][0]:.2f}x ({per[-1][1]})"
                 + (": with the cores shared with other work, extra threads bought little in this run."
                    if thr > 0.8 else "."))
    if "scale" in res:
        sc = res["scale"]
        ap = [r for r in sc["rows"] if r["all_pairs_ms"]]
        if ap:
            nmax = max(r["n"] for r in ap)
            sp = [r["all_pairs_ms"] / r["broad_ms"] for r in ap if r["n"] == nmax]
            big = max(r["n"] for r in sc["rows"])
            bt = [r["broad_ms"] for r in sc["rows"] if r["n"] == big]
            up = [r["update_median_ms"] for r in sc["rows"] if r["n"] == big]
            same = all(r["identical"] for r in ap)
            s.append(f"\n\n**Scale.** At N = {nmax} the broad phase is {min(sp):.0f}-{max(sp):.0f}x faster than "
                     f"the narrow phase on all pairs ({'identical pairs and bitwise-equal times' if same else 'RESULTS DIFFER'}); "
                     f"all-pairs was not run above N = {sc['all_pairs_max']}. At N = {big}, predict_all_pairs took "
                     f"{fmt_ms(min(bt))}-{fmt_ms(max(bt))} ms across the two densities and horizons, and a one-body "
                     f"Scene update with predictions() {fmt_ms(min(up))}-{fmt_ms(max(up))} ms (median).")
        if "node_frame" in sc:
            import scale

            s.append(" Stages of a " + scale.node_frame_line(sc["node_frame"]) + " (in process, no DDS).")
    if "node" in res and res["node"]["rows"]:
        nd = sorted(res["node"]["rows"], key=lambda r: r["bodies"])
        lat = "; ".join(f"N = {r['bodies']}: p50 {fmt_ms(r['e2e_p50_ms'])} / p99 {fmt_ms(r['e2e_p99_ms'])} ms, "
                        f"{r['answered']}/{r['sent']} answered, {r['burst_predictions_per_s']:.0f} predictions/s "
                        f"sustained" for r in nd)
        lim = []
        for r in nd:
            ratio = r["burst_predictions_per_s"] / max(r["burst_sent_per_s"], 1e-9)
            lim.append(f"N = {r['bodies']}: {'the client' if ratio > 0.9 else 'the node'} "
                       f"({r['burst_predictions_per_s']:.0f} out of {r['burst_sent_per_s']:.0f} inputs/s answered)")
        s.append(f"\n\n**Node.** End-to-end through DDS on localhost: {lat}. In the burst the limit was "
                 + "; ".join(lim) + " (out ~ in: the Python client that builds and publishes the messages is the limit; out < in: "
                 "inputs arrived faster than predictions could be made, and the node coalesced them: it ingests "
                 "every input waiting, then answers once for the newest state of every body, so a burst of "
                 "whole-scene frames gets fewer, fresh answers; the node's input queue is KEEP_LAST 50).")
        slow = [r for r in nd if r["e2e_p99_ms"] > 2.0 * r["node_p99_ms"]]
        if slow:
            s.append(" At " + ", ".join(f"N = {r['bodies']}" for r in slow) + " the end-to-end p99 is more than "
                     "twice the node's own p99: the client builds each next message in the thread that also "
                     "receives the answers, so part of that tail is likely the client's, not the node's.")
    s.append("\n\n**Caveats.** The machine is a shared, noisy 2-core VM (see machine.md for its load): "
             "absolute times move between runs, ratios within a run are the meaningful figures. Timings are "
             "best of a few repeats on each family's cases tiled to >= 8192 rows (numpy.roots loop: fewer "
             "rows). The all-pairs reference timing includes building the N^2 index arrays. The lecture "
             "formulation is literal (absolute coordinates, 1e-6 tolerances, no overlap case), so bodies "
             "already overlapping count as wrong t=0 or missed by design.")
    return "".join(s)


def readme_section(res: dict, out: Path) -> str:
    pngs = {k: _png_ref(out, k, True) for k in ("accuracy_vs_time.png", "accuracy_vs_time_families.png",
                                                 "scale.png", "node.png")}
    rel_out = _rel(out, _common.ROOT)
    parts = ["## Benchmarks\n",
             "Everything below is regenerated by one command (it bootstraps the venv first; 2-core machine: "
             "a few minutes, `--quick` under a minute):\n",
             "```bash\nscripts/bench.sh            # full run -> bench/results/ and this README section\n"
             "scripts/bench.sh --quick    # smoke run -> bench/results/quick/\n"
             "scripts/bench.sh --only accuracy scale   # a subset\n```\n",
             f"Results of the run below: `{rel_out}/` (summary.md, accuracy_vs_time.md, scale.md, node.md; "
             f"machine.md records the machine). Machine: {machine.one_line(res['machine'])}; this "
             f"{'quick' if res['quick'] else 'full'} run took {res['machine'].get('wall_s', '?')} s.\n"]
    if "accuracy" in res:
        import accuracy_vs_time as acc

        a = res["accuracy"]
        parts += [f"### Run time against error ({a['cases_per_family']} cases x {len(a['families'])} stress "
                  "families, mpmath reference)\n",
                  "Error in ulp of the exact time for the binary64 inputs, scaled by |cos| of the contact "
                  "angle (as in the accuracy tests); missed/spurious exclude cases whose exact minimum gap is "
                  "within 1e-9 R^2 of zero.\n",
                  acc.headline_table(a),
                  f"\n![run time against error]({pngs['accuracy_vs_time.png']})\n",
                  f"Per family: ![per family]({pngs['accuracy_vs_time_families.png']})\n"]
    if "scale" in res:
        parts += ["### Scale\n", _scale_compact(res["scale"]), f"\n![scale]({pngs['scale.png']})\n"]
    if "node" in res:
        parts += ["### Node latency through DDS (localhost)\n", _node_compact(res["node"]),
                  f"\n![node]({pngs['node.png']})\n"]
    parts += ["### Reading the results\n", _reading(res) + "\n"]
    return "\n".join(parts)


# ----------------------------------------------------------------- main


def render(res: dict, out: Path, readme_path: Path) -> list[Path]:
    files = [machine.write_markdown(res["machine"], out)]
    for sec in SECTIONS:
        if sec in res:
            m = _module(sec)
            files.append(m.write_markdown(res[sec], out))
            files += m.plot(res[sec], out)
    (out / "summary.md").write_text(summary_markdown(res, out))
    files.append(out / "summary.md")
    section = readme_section(res, out)
    if readme_path.name == "README.md":
        splice_readme(readme_path, section)
    else:
        readme_path.write_text(section)
    files.append(readme_path)
    return files


README_BEGIN, README_END = "<!-- bench:begin (generated by bench/run_all.py) -->", "<!-- bench:end -->"


def splice_readme(readme: Path, section: str) -> None:
    """Replace the README's benchmark section (between the markers) with `section`."""
    text = readme.read_text()
    begin, end = text.find(README_BEGIN), text.find(README_END)
    if begin < 0 or end < begin:
        raise SystemExit(f"{readme}: benchmark markers not found; add {README_BEGIN} ... {README_END}")
    readme.write_text(text[:begin + len(README_BEGIN)] + "\n" + section.strip() + "\n" + text[end:])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    ap.add_argument("--quick", action="store_true", help="small sizes: under a minute")
    ap.add_argument("--out", help="output directory (default bench/results/, --quick: bench/results/quick/)")
    ap.add_argument("--only", nargs="+", choices=SECTIONS, help="run only these sections")
    ap.add_argument("--cases", type=int, help="cases per stress family (default 300, quick 12)")
    ap.add_argument("--jobs", type=int, help="processes for the mpmath reference (default min(2, CPUs))")
    ap.add_argument("--render-only", action="store_true", help="re-render tables/plots from <out>/results.json")
    args = ap.parse_args(argv)
    default_out = _common.HERE / "results" / ("quick" if args.quick else "")
    out = Path(args.out) if args.out else default_out
    out.mkdir(parents=True, exist_ok=True)
    full_default = (not args.quick) and args.out is None and not args.only
    # A full run into the default place updates the README itself; others write a side file.
    readme_path = (_common.ROOT / "README.md") if full_default or (
        args.render_only and args.out is None and not args.quick) else out / "README_SECTION.md"

    if args.render_only:
        res = json.loads((out / "results.json").read_text())
        for f in render(res, out, readme_path):
            print(f"wrote {_rel(f, _common.ROOT)}")
        return 0

    t_start = time.perf_counter()
    res: dict = {"quick": bool(args.quick), "machine": machine.collect(sys.argv if argv is None else
                                                                     ["bench/run_all.py", *argv])}
    walls = {}
    for sec in SECTIONS:  # accuracy first: its reference workers fork before numba starts threads
        if args.only and sec not in args.only:
            continue
        print(f"== {sec}", flush=True)
        t0 = time.perf_counter()
        m = _module(sec)
        if sec == "accuracy":
            res[sec] = m.run(args.quick, args.cases, args.jobs, log=lambda s: print(s, flush=True))
            _strip_errors(res[sec])
        else:
            res[sec] = m.run(args.quick, log=lambda s: print(s, flush=True))
        walls[sec] = time.perf_counter() - t0
        print(f"   ({walls[sec]:.1f} s)", flush=True)
    machine.finish(res["machine"], time.perf_counter() - t_start, walls)
    (out / "results.json").write_text(json.dumps(res, indent=1, default=float))
    files = render(res, out, readme_path)
    for f in files:
        print(f"wrote {_rel(f, _common.ROOT)}")
    print(f"total {time.perf_counter() - t_start:.1f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
