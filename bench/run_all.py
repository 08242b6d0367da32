#!/usr/bin/env python3
"""Regenerate every benchmark table and plot the README and docs/ show.

    scripts/bench.sh [--quick] [--out DIR] [--only SECTION ...] [--list]
    .venv/bin/python bench/run_all.py --render-only [--out DIR]   # re-render from results.json

Each section runs one script of bench/ (the first three in this process, the
others as a subprocess, the way they run on their own) and writes its files
into --out (default bench/results/, with --quick bench/results/quick/); --list
prints the sections and their files.  The default run is every section but
first_run.  Every run also writes machine.md (the machine and its load, the
section wall times), results.json (everything the files are rendered from)
and summary.md (one page: the headline tables, each section's exit code and
file, and a reading of the results).  Every number in those files comes from
a run (this one; with --only, the other sections keep the figures of the
earlier run into the same directory, and summary.md names each section's
run); nothing is typed in.  A full run into the default directory also
copies the uncertainty plot to docs/uncertainty_bench.png, where
docs/uncertainty.md shows it.

--quick runs every section on small sizes (see docs/benchmarks.md for what
each section reduces): a few minutes.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
os.environ.setdefault("MPLBACKEND", "Agg")
os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")

import _common  # noqa: E402
import machine  # noqa: E402
from _common import fmt_ms, fmt_ns, fmt_ulp, md_table  # noqa: E402

DOCS_UNCERTAINTY_PNG = _common.ROOT / "docs" / "uncertainty_bench.png"


@dataclass(frozen=True)
class Section:
    """One benchmark section.

    ``module``: a bench/ module driven in this process (``run``, ``write_markdown``,
    ``plot``); otherwise ``runs`` lists the argument lists of ``script`` (one
    subprocess each; ``{out}`` is the output directory) and ``quick_runs`` their
    --quick counterparts; the output is written to ``<name>.md`` (unless
    ``own_md``: the script writes it itself).
    """

    name: str
    title: str
    about: str
    files: tuple[str, ...]
    module: str | None = None
    script: str | None = None
    runs: tuple[tuple[str, ...], ...] = ((),)
    quick_runs: tuple[tuple[str, ...], ...] = (("--quick",),)
    quick_note: str = ""
    timeout_s: float = 3600.0
    own_md: bool = False
    default: bool = True
    extra: dict = field(default_factory=dict)


SECTIONS: tuple[Section, ...] = (
    # accuracy first: its mpmath reference workers fork before numba starts threads
    Section(
        "accuracy",
        "Run time against error",
        "every first-contact solver on the accuracy tests' stress "
        "families against an mpmath reference: ns/pair, error in ulp, missed and spurious contacts",
        ("accuracy_vs_time.md", "accuracy_vs_time.png", "accuracy_vs_time_families.png"),
        module="accuracy_vs_time",
        quick_note="12 cases per family instead of 300",
    ),
    Section(
        "scale",
        "Scale",
        "predict_all_pairs against all pairs: time, cull rate, peak memory and one-body "
        "Scene updates against N; the stages of a node frame",
        ("scale.md", "scale.png"),
        module="scale",
        quick_note="smaller N",
    ),
    Section("node", "Node through DDS",
            "collision_node latency and sustained rate through DDS on localhost against N",
            ("node.md", "node.png"), module="node_latency",
            quick_note="100 bodies only, 2 s instead of 5 s per size"),
    Section(
        "uncertainty",
        "Collision probability against Monte Carlo",
        "collision probability per pair against plain Monte Carlo (1e3 to 1e5 samples, 1e6-sample "
        "reference) on nine families, with its PASS/FAIL checks",
        ("uncertainty.md", "uncertainty_bench.png"),
        script="bench_uncertainty.py",
        runs=(("--out", "{out}/uncertainty_bench.png"),),
        quick_runs=(("--quick", "--out", "{out}/uncertainty_bench.png"),),
        quick_note="2 random pairs per family instead of 5",
    ),
    Section(
        "core",
        "Narrow phase against baselines",
        "ns/pair against batched companion eigenvalues and a "
        "numpy.roots loop, small batches, one pair per call, numba cold compile against a cached "
        "start",
        ("core.md",),
        script="bench_core.py",
        quick_note="20,000 pairs instead of 200,000, fewer repeats",
    ),
    Section(
        "fallback",
        "Exact fallback",
        "rows the fast path leaves to the robust solver and the robust "
        "solver to the exact fallback, and the slowest fallback row",
        ("fallback.md",),
        script="fallback.py",
        quick_note="20,000 pairs and 300 per family instead of 200,000 and 2,000",
    ),
    Section(
        "scene",
        "Whole-scene prediction",
        "predict_all_pairs against all pairs, a large scene, Scene "
        "one-body updates, cull rates, grid against sweep, peak memory",
        ("scene.md",),
        script="bench_scene.py",
        quick_note="small scenes",
    ),
    Section(
        "scene_updates",
        "Node-side work per message",
        "decode, ingest, predict, encode per message "
        "without DDS: a one-body update against a whole tracker array and a full recomputation",
        ("scene_updates.md",),
        script="bench_scene_updates.py",
        quick_note="2,000 bodies, fewer repetitions",
    ),
    Section(
        "uncertainty_scene",
        "Scene with covariance",
        "a scene with covariance on every body against "
        "the same scene exact, frame by frame, the per-body stream (--stream) and the "
        "completion's CPU per frame (--completion)",
        ("uncertainty_scene.md",),
        script="bench_uncertainty_scene.py",
        runs=((), ("--stream",), ("--completion",)),
        quick_runs=(("--quick",), ("--stream", "--updates", "100"),
                    ("--completion", "--frames", "120")),
        quick_note="5 frames instead of 30; the stream 100 updates instead of 600; 3 completed "
                   "frames instead of 15",
    ),
    Section(
        "node_targets",
        "Node stream scenarios",
        "the node's latency through DDS in the stream "
        "scenarios (per-body streams, markers on and off, large arrays) against their targets",
        ("node_targets.md",),
        script="bench_node.py",
        runs=(("--targets",),),
        quick_runs=(("--targets", "--quick"),),
        quick_note="3 s per scenario instead of 10 s",
    ),
    Section(
        "node_qos",
        "Best-effort against reliable inputs",
        "best-effort (with the shipped profile) "
        "against reliable KEEP_LAST 1 state subscriptions at 1,000, 5,000 and 10,000 bodies",
        ("node_qos.md",),
        script="bench_node.py",
        runs=(("--qos",),),
        quick_runs=(("--qos", "--quick"),),
        quick_note="3 s per run instead of 10 s",
    ),
    Section(
        "node_covariance",
        "Node with covariance",
        "node latency through DDS without and with a "
        "covariance (position sigma 0.2 m) on every body",
        ("node_covariance.md",),
        script="bench_node.py",
        runs=(("--covariance", "0.2", "--bodies", "100", "1000"),),
        quick_runs=(("--covariance", "0.2", "--bodies", "100", "--quick"),),
        quick_note="100 bodies only, 3 s instead of 10 s",
    ),
    Section(
        "probabilities",
        "Probabilities at tracker scale, live",
        "1,000 bodies with covariance at 30 Hz through DDS: both topics' latency, placeholders "
        "and stated bounds, where the completions' latency goes, and sampled rows against "
        "10^6-sample Monte Carlo",
        ("probabilities.md",),
        script="bench_probabilities.py",
        runs=(("--seconds", "20", "--out", "{out}/probabilities.md"),),
        quick_runs=(("--seconds", "5", "--check", "5", "--samples", "100000", "--out",
                     "{out}/probabilities.md"),),
        quick_note="5 s instead of 20 s; 5 rows against 10^5-sample Monte Carlo",
        own_md=True,
    ),
    Section(
        "static",
        "Static geometry",
        "first contact with maps, polygons and walls against an exact reference on the hard "
        "cases, against Box2D's b2TimeOfImpact and a nav2-style fixed step, and the edge "
        "kernel's ns per pair beside the circle-circle kernels",
        ("static.md",),
        script="bench_static.py",
        runs=(("--out", "{out}"),),
        quick_runs=(("--out", "{out}", "--quick"),),
        quick_note="300 rows per family, 20,000 kernel pairs",
        own_md=True,
    ),
    Section(
        "static_node",
        "Node with a large map",
        "1,000 bodies in a 4,000 x 4,000-cell map through DDS against the same without the "
        "map; a new map indexed while the stream runs",
        ("static_node.md",),
        script="bench_static_node.py",
        runs=(("--out", "{out}"),),
        quick_runs=(("--out", "{out}", "--quick"),),
        quick_note="5 s streams instead of 20 s",
        own_md=True,
    ),
    Section(
        "ego",
        "Ego-centred prediction",
        "node work per frame (decode, merge, predict, encode) with one ego body against all "
        "pairs on the same 10,000-body frames",
        ("ego.md",),
        script="bench_ego.py",
        runs=(("--out", "{out}"),),
        quick_runs=(("--out", "{out}", "--quick"),),
        quick_note="20 frames instead of 60",
        own_md=True,
    ),
    Section(
        "transport",
        "Large-frame delivery",
        "delivery of large frames between two processes with and "
        "without the shipped Fast DDS profile, and the node's loss count",
        ("transport.md",),
        script="transport_delivery.py",
        quick_note="60 frames, sizes 400 and 1200 KB",
    ),
    Section(
        "replay",
        "Corpus replay",
        "corpus replay with 1 and 2 local workers and on a Dask "
        "LocalCluster, Dask overhead per bag, one replay's throughput and profile",
        ("replay.md",),
        script="bench_replay_corpus.py",
        quick_runs=(("--corpus", "tests/data", "--bags", "3", "--repeat", "1"),),
        quick_note="the 3 test bags of tests/data, one run per configuration, instead of a "
                   "recorded "
        "40-bag corpus (bench/.cache/corpus, recorded on first use: minutes) and the best of 2",
    ),
    Section(
        "first_run",
        "First run",
        "a fresh clone: scripts/demo.sh to its first prediction, then "
        "scripts/test.sh, against their targets",
        ("first_run.md",),
        script="first_run.py",
        runs=(("--out", "{out}"),),
        quick_runs=(("--out", "{out}", "--skip-tests"),),
        quick_note="no test run (--skip-tests)",
        own_md=True,
        default=False,
        timeout_s=7200.0,
    ),
)
BY_NAME = {s.name: s for s in SECTIONS}
DEFAULT_SECTIONS = tuple(s.name for s in SECTIONS if s.default)


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


def _module(sec: Section):
    import importlib

    return importlib.import_module(sec.module)


# ----------------------------------------------------------------- script sections


def _scrub(text: str) -> str:
    """Output without this machine's paths: the repo root dropped, temp dirs as <tmp>."""
    import re

    root = str(_common.ROOT)
    text = text.replace(root + "/", "").replace(root, ".")
    tmp = re.escape(tempfile.gettempdir().rstrip("/"))
    return re.sub(tmp + r"/[^\s'\":,)\]]*", "<tmp>", text)


def run_script(sec: Section, quick: bool, out: Path, log=print) -> dict:
    """Run the section's script once per argument list; their output, exit codes and wall times."""
    env = dict(os.environ, MPLBACKEND="Agg", ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
               PYTHONUNBUFFERED="1")
    env.pop("ROS_STATIC_PEERS", None)
    runs = []
    if sec.own_md:  # an earlier run's file must not stand in for this run's
        (out / sec.files[0]).unlink(missing_ok=True)
    for args in sec.quick_runs if quick else sec.runs:
        args = [a.replace("{out}", str(out)) for a in args]
        cmd = [sys.executable, str(_common.HERE / sec.script), *args]
        shown = " ".join([".venv/bin/python", f"bench/{sec.script}", *(_scrub(a) for a in args)])
        log(f"   $ {shown}")
        t0 = time.perf_counter()
        try:
            proc = subprocess.run(cmd, cwd=str(_common.ROOT), env=env, capture_output=True,
                                  text=True, timeout=sec.timeout_s)
            rc, stdout, stderr = proc.returncode, proc.stdout, proc.stderr
        except subprocess.TimeoutExpired as e:
            rc = "timeout"
            stdout = (
                (e.stdout or b"").decode(errors="replace")
                if isinstance(e.stdout, bytes)
                else (e.stdout or "")
            )
            stderr = f"timed out after {sec.timeout_s:.0f} s"
        wall = time.perf_counter() - t0
        log(f"     exit {rc}, {wall:.1f} s")
        if rc != 0:
            for line in (stderr or stdout).strip().splitlines()[-15:]:
                log(f"     | {line}")
        runs.append(
            dict(command=shown, exit=rc, wall_s=round(wall, 1), stdout=_scrub(stdout),
                 stderr_tail=_scrub("\n".join(stderr.strip().splitlines()[-30:])))
        )
    return dict(runs=runs)


def write_script_markdown(sec: Section, res: dict, out: Path) -> Path:
    p = out / sec.files[0]
    if sec.own_md and p.exists():  # the script wrote it (if it got that far: else its output below)
        return p
    txt = [
        f"# {sec.title}\n",
        f"Section `{sec.name}` of bench/run_all.py: {sec.about}. The script's own "
        "output, as printed in this run (machine and load: machine.md).\n",
    ]
    for r in res["runs"]:
        txt += [
            f"## `{r['command']}`\n",
            f"Exit code {r['exit']}, wall time {r['wall_s']} s.\n",
            "```text\n" + (r["stdout"].rstrip() or "(no output)") + "\n```\n",
        ]
        if r["exit"] != 0 and r["stderr_tail"]:
            txt += ["Last lines of its error output:\n", "```text\n" + r["stderr_tail"] + "\n```\n"]
    for f in sec.files[1:]:
        if f.endswith(".png") and (out / f).exists():
            txt.append(f"![{sec.title}]({f})\n")
    p.write_text("\n".join(txt))
    return p


def _exit_summary(res: dict) -> str:
    codes = [r["exit"] for r in res["runs"]]
    return "0" if all(c == 0 for c in codes) else ", ".join(str(c) for c in codes)


# ----------------------------------------------------------------- summary


def _scale_compact(sc: dict) -> str:
    """One row per density/horizon: all-pairs vs ours at the largest all-pairs N, ours at the
    largest N."""
    rows = []
    for d in sc["densities"]:
        for h in sc["horizons"]:
            rs = [r for r in sc["rows"] if r["density"] == d and r["horizon"] == h]
            if not rs:
                continue
            ap = [r for r in rs if r["all_pairs_ms"]]
            big = rs[-1]
            a = ap[-1] if ap else None
            rows.append(
                [
                    d,
                    f"{h:g}",
                    f"{a['n']}: {fmt_ms(a['all_pairs_ms'])} vs {fmt_ms(a['broad_ms'])} "
                    f"({a['all_pairs_ms'] / a['broad_ms']:.0f}x)"
                    if a
                    else "-",
                    f"{big['n']}: {fmt_ms(big['broad_ms'])}",
                    f"{big['cull_rate']:.1e}",
                    f"{big['broad_peak_rss_mib']:.1f}",
                    fmt_ms(big["update_median_ms"]),
                ]
            )
    return md_table(
        ["density (bodies/km^2)", "horizon s", "N: all-pairs ms vs predict_all_pairs ms",
         "N: predict_all_pairs ms", "cull rate", "peak RSS rise MiB", "1-body update ms"],
        rows,
        "lrlrrrr",
    )


def _node_compact(nd: dict) -> str:
    import node_latency

    return node_latency.table(nd)


def _reading(res: dict) -> str:
    """The interpretation paragraph, every figure taken from ``res``."""
    s = []
    if "accuracy" in res:
        a = res["accuracy"]
        tot = a["totals"]
        ours = tot["ours_serial"]
        names = {m["key"]: m["name"] for m in a["methods"]}
        med = "ns_per_pair_median_family"
        ratios = ", ".join(
            f"{names[k]} {tot[k][med] / ours[med]:.1f}x"
            for k in ("roots_loop", "eigvals", "ferrari", "lecture")
        )
        slowest = max(a["families"], key=lambda f: a["results"][f]["ours_serial"]["ns_per_pair"])
        s.append(
            f"**Accuracy and speed.** On the {len(a['families'])} stress families ours (serial "
            "kernel) "
            f"took {fmt_ns(ours[med])} ns/pair in the median family; the other methods took, "
            "relative "
            f"to it, {ratios} (median family; same run, same rows). Its mean over the families, "
            f"{fmt_ns(ours['ns_per_pair'])} ns/pair, is set by the slowest family, {slowest} "
            f"({fmt_ns(a['results'][slowest]['ours_serial']['ns_per_pair'])} ns/pair), whose rows "
            "the "
            "exact fallback decides where the others return wrong times. Its worst "
            "condition-normalised error was "
            f"{fmt_ulp(ours['worst_finite_ulp'])} ulp (median {fmt_ulp(ours['median_ulp'])}) with "
            f"{ours['missed']} missed and {ours['spurious']} spurious contacts. "
        )
        worst = []
        for k in ("roots_loop", "eigvals", "ferrari", "lecture"):
            t = tot[k]
            bad = sorted(
                (
                    f
                    for f in a["families"]
                    if a["results"][f][k]["missed"] + a["results"][f][k]["spurious"] > 0
                    or a["results"][f][k]["worst_ulp"] > 1e3
                ),
                key=lambda f: -a["results"][f][k]["worst_ulp"],
            )
            worst.append(
                f"{names[k]}: worst {fmt_ulp(t['worst_finite_ulp'])} ulp, "
                f"{t['missed']} missed / {t['spurious']} spurious"
                + (f", {t['wrong_t0']} wrong t=0" if t["wrong_t0"] else "")
                + (f" (> 1e3 ulp or missed/spurious in: {', '.join(bad)})" if bad else "")
            )
        s.append(
            "The power-basis solvers lose digits where the expanded quartic is ill-conditioned: "
            + "; ".join(worst)
            + ". "
        )
        thr = tot["ours_threaded"]["ns_per_pair"] / ours["ns_per_pair"]
        same = all(a["results"][f].get("_serial_equals_threaded", True) for f in a["families"])
        per = sorted(
            (
                a["results"][f]["ours_threaded"]["ns_per_pair"]
                / a["results"][f]["ours_serial"]["ns_per_pair"],
                f,
            )
            for f in a["families"]
        )
        s.append(
            "The threaded path (time_to_collision at >= 4096 rows, when a core is free) took "
            f"{thr:.2f}x the serial "
            "kernel's time per pair on average "
            f"({'bitwise-identical answers' if same else 'ANSWERS DIFFER'}); "
            f"per family from {per[0][0]:.2f}x ({per[0][1]}) to {per[-1][0]:.2f}x ({per[-1][1]})"
            + (
                ": with the cores shared with other work, extra threads bought little in this run."
                if thr > 0.8
                else "."
            )
        )
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
            s.append(
                f"\n\n**Scale.** At N = {nmax} the broad phase is {min(sp):.0f}-{max(sp):.0f}x "
                "faster than "
                "the narrow phase on all pairs "
                f"({'identical pairs and bitwise-equal times' if same else 'RESULTS DIFFER'}); "
                f"all-pairs was not run above N = {sc['all_pairs_max']}. At N = {big}, "
                "predict_all_pairs took "
                f"{fmt_ms(min(bt))}-{fmt_ms(max(bt))} ms across the two densities and horizons, "
                "and a one-body "
                f"Scene update with predictions() {fmt_ms(min(up))}-{fmt_ms(max(up))} ms (median)."
            )
        if "node_frame" in sc:
            import scale

            s.append(
                " Stages of a " + scale.node_frame_line(sc["node_frame"]) + " (in process, no DDS)."
            )
    if "node" in res and res["node"]["rows"]:
        nd = sorted(res["node"]["rows"], key=lambda r: r["bodies"])
        lat = "; ".join(
            f"N = {r['bodies']}: p50 {fmt_ms(r['e2e_p50_ms'])} / p99 {fmt_ms(r['e2e_p99_ms'])} ms, "
            f"{r['answered']}/{r['sent']} answered, {r['burst_predictions_per_s']:.0f} "
            "predictions/s "
            f"sustained"
            for r in nd
        )
        lim = []
        for r in nd:
            ratio = r["burst_predictions_per_s"] / max(r["burst_sent_per_s"], 1e-9)
            lim.append(
                f"N = {r['bodies']}: {'the client' if ratio > 0.9 else 'the node'} "
                f"({r['burst_predictions_per_s']:.0f} out of {r['burst_sent_per_s']:.0f} inputs/s "
                "answered)"
            )
        s.append(
            f"\n\n**Node.** End-to-end through DDS on localhost: {lat}. In the burst the limit was "
            + "; ".join(lim)
            + " (out ~ in: the Python client that builds and publishes the messages is the limit; "
              "out < in: "
            "inputs arrived faster than predictions could be made, and the node coalesced them: it "
            "ingests "
            "every input waiting, then answers once for the newest state of every body, so a burst "
            "of "
            "whole-scene frames gets fewer, fresh answers; the node's input queue is KEEP_LAST 50)."
        )
        slow = [r for r in nd if r["e2e_p99_ms"] > 2.0 * r["node_p99_ms"]]
        if slow:
            s.append(
                " At "
                + ", ".join(f"N = {r['bodies']}" for r in slow)
                + " the end-to-end p99 is more than "
                "twice the node's own p99: the client builds each next message in the thread that "
                "also "
                "receives the answers, so part of that tail is likely the client's, not the node's."
            )
    s.append(
        "\n\n**Caveats.** The machine is a shared, noisy 2-core VM (see machine.md for its load): "
        "absolute times move between runs, ratios within a run are the meaningful figures. Timings "
        "are "
        "best of a few repeats on each family's cases tiled to >= 8192 rows (numpy.roots loop: "
        "fewer "
        "rows). The all-pairs reference timing includes building the N^2 index arrays. The lecture "
        "formulation is literal (absolute coordinates, 1e-6 tolerances, no overlap case), so "
        "bodies "
        "already overlapping count as wrong t=0 or missed by design."
    )
    return "".join(s)


def summary_markdown(res: dict, out: Path) -> str:
    info = res["machine"]
    docs = "docs/benchmarks.md"
    if out.resolve().is_relative_to(_common.ROOT.resolve()):
        docs = f"[{docs}]({os.path.relpath(_common.ROOT / docs, out)})"
    parts = [
        f"# Benchmark summary ({'quick' if res['quick'] else 'full'} run)\n",
        f"Regenerated by `scripts/bench.sh{' --quick' if res['quick'] else ''}` (bench/run_all.py; "
        "what "
        f"each section measures: {docs}). Latest run: {machine.one_line(info)} "
        f"(details: [machine.md](machine.md)), wall time {info.get('wall_s', '?')} s. Ratios "
        "compare "
        "methods measured in the same run.\n",
    ]
    ran = [s for s in SECTIONS if s.name in res]
    rows = []
    for s in ran:
        ok = _exit_summary(res[s.name]) if s.script else "-"
        run = res.get("section_runs", {}).get(s.name, {})
        rows.append(
            [f"`{s.name}`", s.about, ", ".join(f"[{f}]({f})" for f in s.files), ok,
             run.get("wall_s", "?"),
             f"{run.get('date_utc', '?')}, load {run.get('loadavg_start', '?')}"]
        )
    parts += [
        "## Sections\n",
        "Each section's figures come from the run named in its row (a run with `--only` "
        "replaces those sections and keeps the others).\n",
        md_table(
            ["section", "what", "files", "exit code", "wall s", "run (UTC), load average at start"],
            rows,
            "lllrrl",
        ),
    ]
    if "accuracy" in res:
        import accuracy_vs_time as acc

        a = res["accuracy"]
        parts += [
            "## Run time against error\n",
            f"{a['cases_per_family']} cases x {len(a['families'])} stress families, mpmath "
            "reference "
            "(details: [accuracy_vs_time.md](accuracy_vs_time.md)).\n",
            acc.headline_table(a),
            "\nMissed / spurious contacts per family:\n",
            acc.miss_table(a),
            "\n![run time against error](accuracy_vs_time.png)\n",
            "![per family](accuracy_vs_time_families.png)\n",
        ]
    if "scale" in res:
        parts += [
            "## Scale\n",
            "Details: [scale.md](scale.md).\n",
            _scale_compact(res["scale"]),
            "\n![scale](scale.png)\n",
        ]
    if "node" in res:
        parts += [
            "## Node through DDS (localhost)\n",
            "Details: [node.md](node.md).\n",
            _node_compact(res["node"]),
            "\n![node](node.png)\n",
        ]
    if "uncertainty" in res and (out / "uncertainty_bench.png").exists():
        parts += [
            "## Collision probability against Monte Carlo\n",
            "Table and checks: [uncertainty.md](uncertainty.md).\n",
            "![collision probability against Monte Carlo](uncertainty_bench.png)\n",
        ]
    if any(k in res for k in ("accuracy", "scale", "node")):
        parts += ["## Reading the results\n", _reading(res) + "\n"]
    return "\n".join(parts)


# ----------------------------------------------------------------- main


def render(res: dict, out: Path) -> list[Path]:
    files = [machine.write_markdown(res["machine"], out)]
    for sec in SECTIONS:
        if sec.name not in res:
            continue
        if sec.module:
            m = _module(sec)
            files.append(m.write_markdown(res[sec.name], out))
            files += m.plot(res[sec.name], out)
        else:
            files.append(write_script_markdown(sec, res[sec.name], out))
            files += [out / f for f in sec.files[1:] if (out / f).exists()]
    (out / "summary.md").write_text(summary_markdown(res, out))
    files.append(out / "summary.md")
    return files


def section_list() -> str:
    rows = []
    for s in SECTIONS:
        how = f"bench/{s.module}.py" if s.module else f"bench/{s.script}"
        rows.append(
            f"  {s.name:18s} {how:32s} -> "
            f"{', '.join(s.files)}{'' if s.default else '   (not default)'}"
        )
    return "\n".join(rows)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__.splitlines()[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=__doc__ + "\nsections (script -> files in --out):\n" + section_list(),
    )
    ap.add_argument(
        "--quick", action="store_true", help="small sizes in every section: a few minutes"
    )
    ap.add_argument(
        "--out", help="output directory (default bench/results/, --quick: bench/results/quick/)"
    )
    ap.add_argument("--only", nargs="+", choices=[s.name for s in SECTIONS], metavar="SECTION",
                    help="run only these sections (default: all but first_run)")
    ap.add_argument(
        "--list", action="store_true", help="list the sections and the files each writes"
    )
    ap.add_argument(
        "--cases", type=int, help="accuracy: cases per stress family (default 300, quick 12)"
    )
    ap.add_argument("--jobs", type=int,
                    help="accuracy: processes for the mpmath reference (default min(2, CPUs))")
    ap.add_argument(
        "--render-only", action="store_true", help="re-render the files from <out>/results.json"
    )
    args = ap.parse_args(argv)
    if args.list:
        print(section_list())
        return 0
    default_out = _common.HERE / "results" / ("quick" if args.quick else "")
    out = (Path(args.out) if args.out else default_out).resolve()
    out.mkdir(parents=True, exist_ok=True)

    if args.render_only:
        res = json.loads((out / "results.json").read_text())
        for f in render(res, out):
            print(f"wrote {_rel(f, _common.ROOT)}")
        return 0

    t_start = time.perf_counter()
    res: dict = {
        "quick": bool(args.quick),
        "machine": machine.collect(sys.argv if argv is None else ["bench/run_all.py", *argv]),
    }
    res["machine"]["command"] = " ".join(_scrub(a) for a in res["machine"]["command"].split())
    walls = {}
    failed = []
    log = lambda s: print(s, flush=True)  # noqa: E731
    for sec in SECTIONS:
        if (args.only and sec.name not in args.only) or (not args.only and not sec.default):
            continue
        print(f"== {sec.name}", flush=True)
        load0 = " ".join(f"{x:.2f}" for x in os.getloadavg())
        t0 = time.perf_counter()
        if sec.module:
            m = _module(sec)
            if sec.name == "accuracy":
                res[sec.name] = m.run(args.quick, args.cases, args.jobs, log=log)
                _strip_errors(res[sec.name])
            else:
                res[sec.name] = m.run(args.quick, log=log)
        else:
            res[sec.name] = run_script(sec, args.quick, out, log=log)
            if _exit_summary(res[sec.name]) != "0":
                failed.append(sec.name)
        walls[sec.name] = time.perf_counter() - t0
        res.setdefault("section_runs", {})[sec.name] = dict(date_utc=res["machine"]["date_utc"],
                                                            loadavg_start=load0,
                                                            wall_s=round(walls[sec.name], 1))
        print(f"   ({walls[sec.name]:.1f} s)", flush=True)
    # an earlier run's results in the same place keep the sections not run now (--only)
    old = out / "results.json"
    if old.exists():
        try:
            prev = json.loads(old.read_text())
        except ValueError:
            prev = {}
        if prev.get("quick") == res["quick"]:
            for sec in SECTIONS:
                if sec.name not in walls and sec.name in prev:
                    res[sec.name] = prev[sec.name]
                    if sec.name in prev.get("section_runs", {}):
                        res.setdefault("section_runs", {})[sec.name] = prev["section_runs"][
                            sec.name
                        ]
    machine.finish(res["machine"], time.perf_counter() - t_start, walls)
    (out / "results.json").write_text(json.dumps(res, indent=1, default=float))
    files = render(res, out)
    if (
        "uncertainty" in res
        and not args.quick
        and out == default_out.resolve()
        and (out / "uncertainty_bench.png").exists()
    ):
        shutil.copyfile(out / "uncertainty_bench.png", DOCS_UNCERTAINTY_PNG)
        files.append(DOCS_UNCERTAINTY_PNG)
    for f in files:
        print(f"wrote {_rel(f, _common.ROOT)}")
    print(f"total {time.perf_counter() - t_start:.1f} s")
    if failed:
        print(f"sections with a nonzero exit code: {', '.join(failed)} (see their .md files)")
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
