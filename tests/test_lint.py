"""The code style check, as ROS 2 packages run ament_flake8 (ros2/examples' test_flake8.py).

ruff (pinned in requirements-test.txt) with the repository's ruff.toml: pycodestyle and
pyflakes rules, lines of at most 100 characters, over the package, tests, benchmarks and scripts.
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_ruff_check_passes() -> None:
    run = subprocess.run(
        [sys.executable, "-m", "ruff", "check", "--no-cache", "--output-format", "concise",
         "circle_collision_ros", "tests", "bench", "scripts", "setup.py", "launch"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert run.returncode == 0, f"ruff found problems:\n{run.stdout}{run.stderr}"
