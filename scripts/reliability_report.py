#!/usr/bin/env python3
"""Regenerate docs/reliability.md from actual runs.

    .venv/bin/python scripts/reliability_report.py [--soak-json docs/soak_600s.json] [--no-run]

Runs `pytest tests/reliability` with a junit XML (unless --no-run and
docs/reliability_junit.xml exists), reads per-test outcome, duration and the
tallies the tests record (examples, messages, measured figures), adds the
long soak's JSON written by `scripts/soak.py --json` if present, and writes
docs/reliability.md. Nothing in the tables is typed in: every number comes
from those files. The report and the junit XML carry no timestamps, host
names or machine paths: commands are shown relative to the repository and
temporary paths as <tmp>.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import subprocess
import sys
import tempfile
import xml.etree.ElementTree as ET
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
JUNIT = DOCS / "reliability_junit.xml"

# What each test tries (the "what" column); figures come from the run.
WHAT = {"test_fuzz_core": "core: time_to_collision / predict_all_pairs fuzzing",
        "test_fuzz_cdr": "state_codec.decode_states on random/mutated/truncated/valid bytes",
        "test_fuzz_messages": "corrupted CircleStateArray contents -> CollisionPredictor",
        "test_fuzz_node": "corrupted arrays and garbage bytes -> live node over DDS",
        "test_fuzz_replay": "damaged MCAP files -> replay",
        "test_faults_node": "live node: publisher killed, bursts, reordering, service flood",
        "test_faults_clock": "live node: stamps and /clock jumping",
        "test_faults_recording": "live node: SIGKILL while recording, bag directory removed",
        "test_soak_short": "30 s soak (scripts/soak.py checks)"}

# Bugs this work found, the fix, and the test that proves it (its outcome comes from the run).
FIXES = [
    (
        "pipeline/state_codec.py",
        "SIGSEGV: non-little-endian payloads were handed to rclpy's deserializer, which "
        "crashes on e.g. the 4-byte CircleState 00 00 90 fa (a live node died, exit -11); now only "
        "plain CDR LE/BE is decoded, by our kernels",
        "test_fuzz_cdr::test_rclpy_crashers_are_cdr_errors_and_crash_rclpy",
    ),
    ("pipeline/state_codec.py", "ValueError (not CdrError) for 2-3 byte CircleState buffers",
     "test_fuzz_cdr::test_short_buffers_are_cdr_errors"),
    (
        "state_validation.py",
        "finite values beyond the core's input range accepted: a 1e160 radius hid "
        "two overlapping pairs; now magnitudes beyond 1e12 are rejected",
        "test_fuzz_messages::test_huge_radius_is_rejected",
    ),
    (
        "core/scene/",
        "after a tracker's stamps jumped back, the reference time stayed in the old "
        "future: every body propagated ~30 s ahead, contacts missed",
        "test_faults_clock::test_stamps_jump_backwards",
    ),
    (
        "collision_node.py",
        "use_sim_time, /clock jumping back: all new states ignored (node silent) and "
        "old bodies never expired; now the scene is cleared at the jump",
        "test_faults_clock::test_sim_time_clock_jumps",
    ),
    ("collision_node.py", "service queue depth 10: 177 of 200 concurrent requests never answered",
     "test_faults_node::test_service_flood"),
    ("collision_node.py", "a failed recording was only logged once, never shown on /diagnostics",
     "test_faults_recording::test_recording_directory_removed"),
    ("replay.py", "--tolerant on a bag with no complete chunk printed two error lines",
     "test_fuzz_replay::test_hundreds_of_damaged_bags_in_a_worker"),
]

DECISIONS = """\
## Decided behaviour (what the tests hold the node to)

- **Undecodable payloads** (any bytes that are not a CDR CircleState(Array)) are rejected as a
  whole and counted in `states_rejected`; only little- and big-endian plain CDR are decoded, by
  our bounds-checked kernels. rclpy's deserializer is never given untrusted bytes: it can crash
  the process (SIGSEGV) on a 4-byte payload.
- **Magnitudes**: radius, position, velocity and acceleration beyond 1e12 (SI) are rejected like
  non-finite values (`state_validation.ValueLimits`), which keeps every accepted state, even
  propagated over the largest stamp difference, inside the core's documented input range.
- **Stamps jumping backwards** (a tracker's clock reset): the old states stay until they expire
  (`stale_timeout`, receive time), because the new ones look late; when the scene has become empty
  the reference time is forgotten, so predictions continue at the new stamps instead of being
  propagated into the old future.
- **`use_sim_time` and a `/clock` jumping backwards** (a looping bag, a restarted simulator):
  the scene is cleared at the jump, with a warning and the `clock_jumps_back` diagnostics
  counter; prediction resumes with the next states. A forward jump needs nothing special: bodies
  not refreshed expire at the next input. `/diagnostics` runs on the node's clock, so under sim
  time it is published only while `/clock` advances.
- **Input stops** (publisher dead) with `publish_rate` 0: nothing more is published (the last
  prediction's stamp ages) and the bodies expire with the next input; with `publish_rate` > 0
  expiry runs on the timer.
- **Service**: requests are queued up to 1,000 deep (the default depth 10 lost most of a flood).
- **Recording**: a failure (disk full, directory removed) stops the recording, never the
  predictions; it is logged once and shown on `/diagnostics` (`recording: failed: ...`, level WARN).
  After SIGKILL a bag reads up to its last complete chunk (`open_bag(tolerant=True)`,
  `replay --tolerant`).
"""


_TMP = re.compile(
    "(?:"
    + "|".join(
        sorted({re.escape(tempfile.gettempdir().rstrip("/")), "/tmp", "/var/tmp"}, key=len,
               reverse=True)
    )
    + r")/[^\s'\":,;)\]|`]*"
)


def clean(text: str) -> str:
    """``text`` without machine paths: the repository's own relative, temporary ones as <tmp>."""
    text = text.replace(str(ROOT) + "/", "").replace(str(ROOT), ".")
    text = _TMP.sub("<tmp>", text)
    # an interpreter outside the repository: just its name
    return re.sub(r"(?<![\w.<>-])/(?:[\w.+-]+/)+(python[\d.]*)\b", r"\1", text)


def sanitize_junit(path: Path) -> None:
    """Drop the run's timestamp and host name from the junit XML and clean the paths in it."""
    tree = ET.parse(path)
    for el in tree.getroot().iter():
        for attr in ("timestamp", "hostname"):
            el.attrib.pop(attr, None)
        for k, v in list(el.attrib.items()):
            el.set(k, clean(v))
        if el.text:
            el.text = clean(el.text)
    tree.write(path, encoding="utf-8", xml_declaration=True)


def run_pytest(extra: list[str]) -> int:
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    cmd = [sys.executable, "-m", "pytest", "tests/reliability", "-q", "-p", "no:cacheprovider",
           f"--junitxml={JUNIT}", "-o", "junit_family=xunit1", *extra]
    print("+", clean(" ".join(cmd)), flush=True)
    return subprocess.run(cmd, cwd=ROOT, env=env).returncode


def read_junit(path: Path) -> tuple[list[dict], dict]:
    root = ET.parse(path).getroot()
    suite = root if root.tag == "testsuite" else root.find("testsuite")
    cases = []
    for tc in suite.iter("testcase"):
        outcome = "passed"
        for tag in ("failure", "error", "skipped"):
            el = tc.find(tag)
            if el is not None:
                outcome = tag
                if tag == "skipped" and "xfail" in (el.get("type", "") + el.get("message", "")):
                    outcome = "xfailed"
        props = {p.get("name"): p.get("value") for p in tc.iter("property")}
        skipped = tc.find("skipped")
        reason = (skipped.get("message", "") if skipped is not None else "").removeprefix(
            "reason: "
        )
        cases.append(
            {"reason": reason, "module": tc.get("classname", "").split(".")[-1],
             "name": tc.get("name"), "time": float(tc.get("time", 0.0)), "outcome": outcome,
             "props": props}
        )
    totals = {k: suite.get(k) for k in ("tests", "failures", "errors", "skipped", "time")}
    return cases, totals


def _fmt_props(props: dict) -> str:
    return clean(", ".join(f"{k}={v}" for k, v in props.items())) or "-"


def render(cases: list[dict], totals: dict, soak: dict | None, soak_path: Path | None) -> str:
    lines = [
        "# Reliability",
        "",
        "Generated by `scripts/reliability_report.py` from a run of `pytest tests/reliability` "
        f"(junit: `{JUNIT.relative_to(ROOT)}`) and the soak's JSON; do not edit by hand.",
        "",
        f"Run on {os.cpu_count()} cores, Python {platform.python_version()}: "
        f"{totals['tests']} tests, {totals['failures']} failed, {totals['errors']} errors, "
        f"{totals['skipped']} skipped/xfailed, {float(totals['time']):.0f} s in all.",
        "",
    ]
    by_module: dict[str, list[dict]] = {}
    for c in cases:
        by_module.setdefault(c["module"], []).append(c)
    lines += [
        "## Summary by area",
        "",
        "| area | what was tried | tests | held | time (s) |",
        "|---|---|---|---|---|",
    ]
    for module, items in by_module.items():
        held = sum(c["outcome"] in ("passed", "xfailed") for c in items)
        lines.append(
            f"| `{module}` | {WHAT.get(module, '')} | {len(items)} | {held}/{len(items)} | "
            f"{sum(c['time'] for c in items):.1f} |"
        )
    lines += [
        "",
        "## Every test: how much was tried, and the outcome",
        "",
        "| test | outcome | time (s) | tallies and measured figures |",
        "|---|---|---|---|",
    ]
    for c in cases:
        lines.append(
            f"| `{c['module']}::{c['name']}` | {c['outcome']} | {c['time']:.1f} | "
            f"{_fmt_props(c['props'])} |"
        )
    lines += [""]
    if soak:
        lines += [
            f"## Long soak (`{clean(str(soak_path)) if soak_path else ''}`)",
            "",
            f"Command: `{clean(soak['command'])}` "
            f"({soak['cpu_count']} cores, load average at the end {soak['loadavg_end'][0]:.2f}).",
            "",
            "| figure | value |",
            "|---|---|",
        ]
        rows = [
            (
                "bodies x rate",
                f"{soak['bodies']} x {soak['rate_hz']} Hz for {soak['seconds']} s "
                f"(warm-up {soak['warmup_s']} s, node marker_rate {soak.get('marker_rate_hz')})",
            ),
            (
                "inputs sent / received by the node",
                f"{soak['inputs_sent']} / {soak['inputs_received_by_node']}"
                f" (dropped {soak['dropped_inputs']})",
            ),
            (
                "predictions published / received",
                f"{soak['predictions_published']} / {soak['predictions_received']}"
                f" (dropped output {soak['dropped_output']}, inputs without "
                f"prediction {soak['inputs_without_prediction']})",
            ),
            ("max gap between predictions", f"{soak['max_gap_s']} s"),
            (
                "RSS start / end / max (after warm-up)",
                f"{soak['rss_kb_start']} / {soak['rss_kb_end']} / "
                f"{soak['rss_kb_max']} kB, growth {soak['rss_growth_pct']} %",
            ),
            (
                "latency p50 / p99, first third",
                f"{soak['latency_first_third']['p50_ms']} / "
                f"{soak['latency_first_third']['p99_ms']} ms",
            ),
            (
                "latency p50 / p99, last third",
                f"{soak['latency_last_third']['p50_ms']} / "
                f"{soak['latency_last_third']['p99_ms']} ms",
            ),
            (
                "latency p50 / p99, all",
                f"{soak['latency_all']['p50_ms']} / {soak['latency_all']['p99_ms']} ms",
            ),
            (
                "node's own latency p50 / p99 (last 1000)",
                " / ".join(map(str, soak["node_latency_ms_p50_p99"])) + " ms",
            ),
            (
                "checks",
                ", ".join(f"{k}: {'ok' if v else 'FAILED'}" for k, v in soak["checks"].items()),
            ),
        ]
        lines += [f"| {a} | {b} |" for a, b in rows]
        samples = soak.get("rss_samples", [])
        if samples:
            step = max(1, len(samples) // 12)
            lines += [
                "",
                "RSS over time (s: kB): "
                + ", ".join(f"{t:.0f}: {kb}" for t, kb in samples[::step]),
                "",
            ]
    else:
        lines += [
            "## Long soak",
            "",
            "No soak JSON given (`scripts/soak.py --json docs/soak_600s.json`).",
            "",
        ]
    outcome = {f"{c['module']}::{c['name'].split('[')[0]}": c["outcome"] for c in cases}
    lines += [
        "## Bugs found and fixed (outside core/)",
        "",
        "| file | bug | proved by | outcome now |",
        "|---|---|---|---|",
    ]
    lines += [
        f"| `{f}` | {what} | `{test}` | {outcome.get(test, 'not run')} |" for f, what, test in FIXES
    ]
    known = [c for c in cases if c["outcome"] == "xfailed"]
    lines += ["", "## Known bugs left open (strict xfail, so a fix shows up as XPASS)", ""]
    lines += [f"- `{c['module']}::{c['name']}`: {clean(c.get('reason', ''))}" for c in known] or [
        "- none"
    ]
    lines += ["", DECISIONS]
    return "\n".join(lines) + "\n"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--soak-json", type=Path, default=DOCS / "soak_600s.json")
    ap.add_argument("--no-run", action="store_true", help="reuse docs/reliability_junit.xml")
    ap.add_argument("pytest_args", nargs="*", help="extra pytest arguments")
    opts = ap.parse_args()
    DOCS.mkdir(exist_ok=True)
    code = 0
    if not (opts.no_run and JUNIT.exists()):
        code = run_pytest(opts.pytest_args)
    sanitize_junit(JUNIT)
    cases, totals = read_junit(JUNIT)
    soak_path = opts.soak_json if opts.soak_json and opts.soak_json.exists() else None
    soak = json.loads(soak_path.read_text()) if soak_path else None
    (DOCS / "reliability.md").write_text(
        render(cases, totals, soak, soak_path.resolve() if soak_path else None)
    )
    print(
        f"wrote {(DOCS / 'reliability.md').relative_to(ROOT)} ({len(cases)} tests; pytest exit "
        f"{code})"
    )
    return code


if __name__ == "__main__":
    sys.exit(main())
