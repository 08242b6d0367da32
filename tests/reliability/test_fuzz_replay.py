"""Truncated, bit-flipped, spliced and foreign MCAP files through `replay`.

Guarantees proved here:
- hypothesis-driven damage to the recorded test bags, run through the real
  `replay` CLI in a subprocess with a timeout: it ends (no hang), never prints
  a traceback, and an error (exit 2) is one line naming the file; exit 0/1 only
  when the damage left a readable bag;
- the same contract over many cases (50 by default, 400 under --stress) run
  through replay's main() in a worker process
  (tests/reliability/replay_worker.py), including well-formed
  bags whose payloads are garbage; a crash of the worker would fail the test
  and name the case. Before the fix, a truncated bag with no complete chunk,
  replayed with --tolerant, printed two lines.
Case counts: a quick sample by default, the full counts under --stress (tests/stress.py).
"""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tests.reliability.conftest import tally
from tests.stress import examples

ROOT = Path(__file__).resolve().parents[2]
REPLAY = [sys.executable, "-m", "circle_collision_ros.recording.replay"]
SOURCE = next((ROOT / "tests" / "data" / "plain_2d").glob("*.mcap")).read_bytes()
WORKER_CASES = examples(50, 400)


def _check(run: subprocess.CompletedProcess, target: Path) -> None:
    assert "Traceback" not in run.stderr and "Traceback" not in run.stdout
    assert run.returncode in (0, 1, 2), run
    if run.returncode == 2:
        lines = run.stderr.strip().splitlines()
        assert len(lines) == 1 and str(target) in lines[0], lines


@settings(max_examples=examples(3, 15), deadline=None, suppress_health_check=list(HealthCheck))
@given(st.sampled_from(["truncate", "flip", "truncate_tolerant", "flip_tolerant"]),
       st.integers(0, len(SOURCE) - 1),
       st.lists(st.integers(0, 8 * len(SOURCE) - 1), min_size=1, max_size=8))
def test_damaged_bag_through_the_cli(tmp_path_factory, how, cut, bits) -> None:
    data = bytearray(SOURCE)
    if how.startswith("truncate"):
        data = data[:cut]
    else:
        for bit in bits:
            data[bit // 8] ^= 1 << (bit % 8)
    target = tmp_path_factory.mktemp("cli") / "bag.mcap"
    target.write_bytes(bytes(data))
    args = REPLAY + [str(target)] + (["--tolerant"] if how.endswith("tolerant") else [])
    run = subprocess.run(args, capture_output=True, text=True, timeout=120)
    tally("cli_runs")
    tally(f"exit_{run.returncode}")
    _check(run, target)


def test_hundreds_of_damaged_bags_in_a_worker(tmp_path: Path) -> None:
    run = subprocess.run(
        [sys.executable, "-m", "tests.reliability.replay_worker", str(tmp_path), "8",
         str(WORKER_CASES)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    current = (tmp_path / "current.txt").read_text() if (tmp_path / "current.txt").exists() else "?"
    assert run.returncode == 0, f"worker died ({run.returncode}) on {current}: {run.stderr[-2000:]}"
    summary = json.loads(run.stdout.strip().splitlines()[-1])
    assert summary["broken"] == [], summary
    tally("cases", summary["cases"])
    for outcome, n in summary["outcomes"].items():
        tally(outcome, n)
