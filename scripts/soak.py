#!/usr/bin/env python3
"""Soak test: collision_node under a steady synthetic load for a long time.

    .venv/bin/python scripts/soak.py [--seconds 600] [--bodies 1000] [--rate 30] [--json out.json]

Runs collision_node (its own process, as users run it) and a SyntheticScene
publisher process (tests/reliability/scene_publisher.py: every body in one
CircleStateArray per tick, stamped with the send time), and listens to
`collision_predictions` and `/diagnostics` here. Reports:

- RSS of the node over time (VmRSS from /proc/<pid>/status);
- dropped inputs: messages sent vs messages the node received (/diagnostics);
- dropped output: predictions the node published vs predictions received here,
  and inputs received by the node without a prediction;
- publication gaps: the longest interval between two received predictions;
- latency = receive time - header.stamp (the stamp is that of the newest input),
  percentiles overall and for the first and last third of the run.

Checks (exit 1 if any fails): RSS growth < 5 % from the end of the warm-up to the
end, no dropped output, no latency drift (p50 of the last third <= 2 x that of
the first third + 10 ms), and the node still running. ROS traffic stays on this
machine (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST); ROS_DOMAIN_ID defaults to 99.
"""
from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.setdefault("ROS_DOMAIN_ID", "99")
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from tests.reliability.node_process import Client, NodeProcess, stamp_of  # noqa: E402


def _percentiles(values_s) -> dict:
    if len(values_s) == 0:
        return {"p50_ms": None, "p99_ms": None, "max_ms": None}
    arr = np.asarray(values_s) * 1e3
    return {"p50_ms": round(float(np.percentile(arr, 50)), 3),
            "p99_ms": round(float(np.percentile(arr, 99)), 3), "max_ms": round(float(arr.max()), 3)}


def soak(seconds: float, bodies: int, rate: float, warmup: float, log_dir: Path,
         rss_limit_pct: float = 5.0, marker_rate: float = 10.0) -> dict:
    node = NodeProcess(log_dir / "collision_node.log", max_bodies=max(10_000, bodies),
                       marker_rate=marker_rate)
    client = Client("soak_listener", raw_predictions=True)
    rss: list[tuple[float, int]] = []
    publisher = None
    try:
        client.wait_matched()
        rss.append((0.0, node.rss_kb()))
        publisher = subprocess.Popen(
            [sys.executable, "-m", "tests.reliability.scene_publisher", "--count", str(bodies),
             "--rate", str(rate), "--seconds", str(seconds), "--prefix", "soak_"],
            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        start = time.monotonic()
        next_sample = start + 1.0
        while publisher.poll() is None and time.monotonic() - start < seconds + 60:
            client.spin(0.2)
            if time.monotonic() >= next_sample:
                rss.append((round(time.monotonic() - start, 1), node.rss_kb()))
                next_sample += 1.0
        out, err = publisher.communicate(timeout=60)
        sent = json.loads(out.strip().splitlines()[-1]) if out.strip() else {"messages": 0}
        client.spin(3.0)  # the last predictions and a /diagnostics after the last input
        diag = client.last_diagnostics(timeout=5.0)
        alive = node.alive()
    finally:
        if publisher is not None and publisher.poll() is None:
            publisher.kill()
        client.close()
        code = node.stop()
    t0 = min((t for t, _ in client.predictions), default=0.0)
    recv = np.array([t for t, _ in client.predictions])
    lat = np.array([t - stamp_of(m) * 1e-9 for t, m in client.predictions])
    keep = recv >= t0 + warmup
    recv_w, lat_w = recv[keep], lat[keep]
    third = len(lat_w) // 3
    first, last = _percentiles(lat_w[:third]), _percentiles(lat_w[-third:] if third else [])
    gaps = np.diff(recv_w) if len(recv_w) > 1 else np.zeros(1)
    samples = [kb for t, kb in rss if t >= warmup]
    head, tail = samples[:5], samples[-5:]
    rss_start = int(np.median(head)) if head else 0
    rss_end = int(np.median(tail)) if tail else 0
    growth = 100.0 * (rss_end - rss_start) / rss_start if rss_start else float("nan")
    node_messages = int(diag.get("messages", 0))
    published = int(diag.get("predictions_published", 0))
    # The node answers a backlog with one prediction for the newest state (README, "Real-time
    # behaviour"): an input is accounted for when answered or coalesced into a later answer.
    coalesced = int(diag.get("inputs_coalesced", 0))
    received = len(client.predictions)
    result = {
        "command": " ".join(
            [sys.executable, "scripts/soak.py", "--seconds", str(seconds), "--bodies", str(bodies),
             "--rate", str(rate), "--marker-rate", str(marker_rate)]
        ),
        "marker_rate_hz": marker_rate,
        "seconds": seconds,
        "bodies": bodies,
        "rate_hz": rate,
        "warmup_s": warmup,
        "cpu_count": os.cpu_count(),
        "loadavg_end": list(os.getloadavg()),
        "inputs_sent": sent.get("messages", 0),
        "publisher_late_ticks": sent.get("late_ticks", 0),
        "inputs_received_by_node": node_messages,
        "dropped_inputs": sent.get("messages", 0) - node_messages,
        "states_accepted": int(diag.get("states_accepted", 0)),
        "predictions_published": published,
        "predictions_received": received,
        "dropped_output": published - received,
        "inputs_coalesced": coalesced,
        # <= 0: expiry may publish without a new input
        "inputs_without_prediction": node_messages - published - coalesced,
        "max_gap_s": round(float(gaps.max()), 3),
        "latency_all": _percentiles(lat_w),
        "latency_first_third": first,
        "latency_last_third": last,
        "node_latency_ms_p50_p99": [diag.get("latency_ms_p50"), diag.get("latency_ms_p99")],
        "rss_kb_start": rss_start,
        "rss_kb_end": rss_end,
        "rss_kb_max": max(kb for _, kb in rss),
        "rss_growth_pct": round(growth, 2),
        "rss_samples": rss,
        "node_alive_at_end": alive,
        "node_exit_code": code,
        "node_errors": int(diag.get("errors", 0)),
    }
    checks = {
        "node_survived": alive and code == 0,
        "rss_growth_below_limit": growth < rss_limit_pct,
        "no_dropped_output": result["dropped_output"] == 0
        and result["inputs_without_prediction"] <= 0,
        "no_latency_drift": bool(
            first["p50_ms"] is not None
            and last["p50_ms"] is not None
            and last["p50_ms"] <= 2.0 * first["p50_ms"] + 10.0
        ),
        "predictions_flowed": received > 0.5 * sent.get("messages", 0) > 0,
    }
    result["checks"] = checks
    result["ok"] = all(checks.values())
    return result


def _interrupt(signum, frame):
    raise KeyboardInterrupt  # run the finally blocks: stop the node and the publisher


def main() -> int:
    signal.signal(signal.SIGTERM, _interrupt)
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=600.0)
    ap.add_argument("--bodies", type=int, default=1000)
    ap.add_argument("--rate", type=float, default=30.0)
    ap.add_argument("--warmup", type=float, default=None,
                    help="s excluded from the checks (default 10%%, >= 5 s)")
    ap.add_argument("--marker-rate", type=float, default=10.0,
                    help="node marker_rate (default: the node's 10 Hz)")
    ap.add_argument("--json", type=Path, help="write the figures here")
    opts = ap.parse_args()
    warmup = opts.warmup if opts.warmup is not None else max(5.0, 0.1 * opts.seconds)
    with tempfile.TemporaryDirectory(prefix="soak_") as tmp:
        result = soak(
            opts.seconds, opts.bodies, opts.rate, warmup, Path(tmp), marker_rate=opts.marker_rate
        )
        if not result["checks"]["node_survived"]:
            print(Path(tmp, "collision_node.log").read_text()[-3000:], file=sys.stderr)
    summary = {k: v for k, v in result.items() if k != "rss_samples"}
    print(json.dumps(summary, indent=1))
    if opts.json:
        opts.json.parent.mkdir(parents=True, exist_ok=True)
        opts.json.write_text(json.dumps(result, indent=1))
    print(
        "soak: "
        + (
            "OK"
            if result["ok"]
            else "FAILED: " + ", ".join(k for k, v in result["checks"].items() if not v)
        ),
        file=sys.stderr,
    )
    return 0 if result["ok"] else 1


if __name__ == "__main__":
    sys.exit(main())
