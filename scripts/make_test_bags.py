"""Regenerate the recorded bags in tests/data/ from the demo scene.

    .venv/bin/python scripts/make_test_bags.py

Each bag is a real run: collision_node and demo_scene as separate processes over
DDS on localhost, recorded by the node. The replay tests then require that
replaying each bag reproduces every recorded prediction bit for bit, so any
change that alters a prediction shows up as a failing test; regenerate the bags
(and say why in the commit) when such a change is intended.
"""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

DATA = Path(__file__).resolve().parents[1] / "tests" / "data"
BAGS = {"plain_2d": ["--count", "25", "--seed", "3"],
        "bad_inputs_2d": ["--count", "25", "--seed", "4", "--bad-fraction", "0.05"],
        "spheres_3d": ["--count", "25", "--seed", "5", "--dimensions", "3", "--area", "15"]}


def main() -> int:
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    for name, args in BAGS.items():
        bag = DATA / name
        shutil.rmtree(bag, ignore_errors=True)
        run = subprocess.run(
            [sys.executable, "-m", "circle_collision_ros.demo.run", "--duration", "3", "--runs-dir",
             str(DATA / "_runs"), "--bag", str(bag), *args],
            capture_output=True,
            text=True,
        )
        if run.returncode != 0:
            print(run.stdout, run.stderr, file=sys.stderr)
            return run.returncode
        size = sum(f.stat().st_size for f in bag.iterdir())
        print(f"{bag}: {size / 1024:.0f} KiB")
    shutil.rmtree(DATA / "_runs", ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
