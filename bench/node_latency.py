"""Node: input-to-output latency and sustained rate against N through real DDS.

    .venv/bin/python bench/node_latency.py [--quick] [--out DIR] [--targets]

(normally driven by ``bench/run_all.py``). ``--targets`` also runs
``bench_node.py --targets`` (the stream scenarios: per-body streams,
markers on/off in the same run, 5,000 and 10,000 bodies) and adds that table
to node.md.  Drives ``bench/bench_node.py``
as a subprocess (``--json``), one collision_node process per scene size, in
an environment with ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` (localhost
discovery only; ``ROS_DOMAIN_ID`` is passed through from the caller).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import _common
from _common import fmt_ms, md_table, pyplot

BODIES_FULL = (100, 300, 1000, 3000)
BODIES_QUICK = (100,)
SECONDS_FULL = 5.0
SECONDS_QUICK = 2.0
RATE_HZ = 30.0


def run(quick: bool = False, bodies=None, seconds=None, rate: float = RATE_HZ, log=print) -> dict:
    bodies = list(bodies or (BODIES_QUICK if quick else BODIES_FULL))
    seconds = seconds or (SECONDS_QUICK if quick else SECONDS_FULL)
    env = dict(os.environ)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"  # never multicast
    env.pop("ROS_STATIC_PEERS", None)
    rows = []
    errors = []
    for n in bodies:  # one subprocess per size: a failure at one size keeps the others
        with tempfile.TemporaryDirectory() as tmp:
            js = Path(tmp) / "node.json"
            cmd = [sys.executable, str(_common.HERE / "bench_node.py"), "--bodies", str(n),
                   "--seconds", str(seconds), "--rate", str(rate), "--json", str(js)]
            t0 = time.perf_counter()
            try:
                proc = subprocess.run(cmd, env=env, cwd=str(_common.ROOT), capture_output=True,
                                      text=True, timeout=120 + 4 * seconds)
                ok = proc.returncode == 0 and js.exists()
                msg = (proc.stderr or proc.stdout)[-800:]
            except subprocess.TimeoutExpired as e:
                ok, msg = False, f"timeout after {e.timeout:.0f} s"
            wall = time.perf_counter() - t0
            if ok:
                for r in json.loads(js.read_text()):
                    r["wall_s"] = wall
                    rows.append(r)
                    log(
                        f"  N={n:5d}: e2e p50 {r['e2e_p50_ms']:.2f} ms, p99 {r['e2e_p99_ms']:.2f} "
                        "ms, "
                        f"answered {r['answered']}/{r['sent']}, burst out "
                        f"{r['burst_predictions_per_s']:.0f}/s "
                        f"({wall:.0f} s)"
                    )
            else:
                errors.append(dict(bodies=n, error=msg))
                log(f"  N={n}: FAILED: {msg}")
    return dict(rows=rows, errors=errors, seconds=seconds, rate_hz=rate, bodies=bodies,
                domain_id=env.get("ROS_DOMAIN_ID", "0"))


def run_targets(seconds: float, log=print) -> dict:
    """bench_node.py --targets in a subprocess; its rows and markdown table."""
    env = dict(os.environ)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env.pop("ROS_STATIC_PEERS", None)
    with tempfile.TemporaryDirectory() as tmp:
        js = Path(tmp) / "targets.json"
        cmd = [sys.executable, str(_common.HERE / "bench_node.py"), "--targets", "--seconds",
               str(seconds), "--json", str(js)]
        proc = subprocess.run(cmd, env=env, cwd=str(_common.ROOT), capture_output=True, text=True,
                              timeout=600 + 10 * seconds)
        if proc.returncode != 0 or not js.exists():
            log(f"  targets: FAILED: {(proc.stderr or proc.stdout)[-800:]}")
            return dict(rows=[], table="", error=(proc.stderr or proc.stdout)[-800:])
        table_lines = [line for line in proc.stdout.splitlines() if line.startswith("|")]
        log("\n".join(table_lines))
        return dict(rows=json.loads(js.read_text()), table="\n".join(table_lines), seconds=seconds)


def _f(x):
    return fmt_ms(x) if isinstance(x, (int, float)) and not math.isnan(x) else "n/a"


def table(res: dict) -> str:
    rows = []
    for r in res["rows"]:
        rows.append(
            [r["bodies"], f"{r['rate_hz']:.0f}", f"{r['answered']}/{r['sent']}",
             _f(r["e2e_p50_ms"]), _f(r["e2e_p99_ms"]), _f(r["node_p50_ms"]), _f(r["node_p99_ms"]),
             r["candidate_pairs"], f"{r['burst_sent_per_s']:.0f}",
             f"{r['burst_predictions_per_s']:.0f}"]
        )
    for e in res["errors"]:
        rows.append([e["bodies"], "failed", "-", "-", "-", "-", "-", "-", "-", "-"])
    return md_table(
        ["bodies", "input Hz", "answered/sent", "end-to-end p50 ms", "end-to-end p99 ms",
         "node p50 ms", "node p99 ms", "candidate pairs", "burst in/s", "burst out/s"],
        rows,
    )


def write_markdown(res: dict, out: Path) -> Path:
    p = out / "node.md"
    txt = [
        "# Node: latency and sustained rate through real DDS (localhost)\n",
        "bench/bench_node.py per scene size: collision_node as its own process, a client "
        "publishing "
        f"CircleStateArray at {res['rate_hz']:.0f} Hz for {res['seconds']:g} s (density 3,000 "
        "bodies/km^2), "
        "stamped with the send time. End-to-end = prediction received - input stamp (publisher -> "
        "DDS -> "
        "node -> DDS -> subscriber); node = the node's own callback-to-publish figure from "
        "/diagnostics. "
        "Burst: inputs published as fast as the Python client can build them, predictions received "
        "per "
        "second (sustained rate; limited by the client when burst in/s ~ burst out/s).\n",
        table(res),
    ]
    if res["errors"]:
        txt.append("\nFailures:\n")
        txt += [
            f"- N={e['bodies']}: "
            f"`{e['error'].strip().splitlines()[-1] if e['error'].strip() else '?'}`"
            for e in res["errors"]
        ]
    if res.get("targets", {}).get("table"):
        txt += [
            "\n## Stream scenarios against their targets (bench/bench_node.py --targets)\n",
            "Per input: client publish call -> the node's publication of the first prediction that "
            "answers it (rmw source timestamp of the prediction; inbound DDS hop, queue wait and "
            "coalescing included). Ingested/coalesced/missing: the node's /diagnostics. The "
            "1,000-body "
            "rows run markers on and off in the same run; the ratio is of their p99s. This machine "
            "(2 cores) is shared: read ratios, not absolute figures.\n",
            res["targets"]["table"],
        ]
    txt.append("\n![node latency](node.png)\n")
    p.write_text("\n".join(txt))
    return p


def plot(res: dict, out: Path) -> list[Path]:
    plt = pyplot()
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.2))
    rows = sorted(res["rows"], key=lambda r: r["bodies"])
    n = [r["bodies"] for r in rows]
    for key, style, lab in (("e2e_p50_ms", "o-", "end-to-end p50"),
                            ("e2e_p99_ms", "o--", "end-to-end p99"),
                            ("node_p50_ms", "s-", "node p50"), ("node_p99_ms", "s--", "node p99")):
        ys = [r[key] for r in rows]
        ax1.plot(n, ys, style, label=lab)
    ax1.set_title(f"input-to-output latency ({res['rate_hz']:.0f} Hz input)", fontsize=10)
    ax1.set_ylabel("ms")
    ax2.plot(n, [r["burst_sent_per_s"] for r in rows], "o-", label="inputs sent /s (client limit)")
    ax2.plot(n, [r["burst_predictions_per_s"] for r in rows], "s-", label="predictions received /s")
    ax2.set_title("sustained rate (inputs as fast as the client can publish)", fontsize=10)
    ax2.set_ylabel("messages / s")
    return [_common.save_log_log_vs_n(fig, (ax1, ax2), out / "node.png", 7)]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--bodies", type=int, nargs="+")
    ap.add_argument("--seconds", type=float)
    ap.add_argument("--out", default=str(_common.HERE / "results"))
    ap.add_argument("--targets", action="store_true", help="also run the stream target scenarios")
    a = ap.parse_args(argv)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    res = run(a.quick, a.bodies, a.seconds)
    if a.targets:
        res["targets"] = run_targets(a.seconds or (SECONDS_QUICK if a.quick else 10.0))
    (out / "node.json").write_text(json.dumps(res, indent=1))
    write_markdown(res, out)
    plot(res, out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
