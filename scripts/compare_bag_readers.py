"""The mcap-library bag reader against the hand-written parser it replaced, on damaged bags.

Loads the old recording/bag_reader.py from git history (commit OLD) and reads
30 random truncations and 200 copies with 3 flipped bits of
tests/data/plain_2d with both, strict and tolerant: prints how many gave the
same outcome (error, or the same records) and lists any that differ.

    .venv/bin/python scripts/compare_bag_readers.py
"""
from __future__ import annotations

import importlib.util
import random
import subprocess
import sys
import tempfile
from pathlib import Path

from circle_collision_ros.recording import bag_reader as new

OLD = "72f4e0b"  # last commit with the hand-written parser
ROOT = Path(__file__).resolve().parents[1]


def load_old():
    source = subprocess.run(
        ["git", "-C", str(ROOT), "show", f"{OLD}:circle_collision_ros/recording/bag_reader.py"],
        check=True,
        capture_output=True,
        text=True,
    ).stdout
    path = Path(tempfile.mkdtemp()) / "old_bag_reader.py"
    path.write_text(
        source.replace("from .bag_recorder", "from circle_collision_ros.recording.bag_recorder")
    )
    spec = importlib.util.spec_from_file_location("old_bag_reader", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules["old_bag_reader"] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def outcome(module, path: Path, tolerant: bool):
    try:
        return [tuple(r) for r in module.open_bag(path, tolerant=tolerant).records()]
    except module.BagError:
        return "BagError"


def main() -> int:
    old = load_old()
    source = next((ROOT / "tests/data/plain_2d").glob("*.mcap")).read_bytes()
    rng = random.Random(15)
    cases = [source[: rng.randrange(len(source))] for _ in range(30)]
    for _ in range(200):
        data = bytearray(source)
        for _ in range(3):
            data[rng.randrange(len(data))] ^= 1 << rng.randrange(8)
        cases.append(bytes(data))
    directory = Path(tempfile.mkdtemp())
    differ = 0
    for k, data in enumerate(cases):
        path = directory / f"case{k}.mcap"
        path.write_bytes(data)
        for tolerant in (False, True):
            if outcome(old, path, tolerant) != outcome(new, path, tolerant):
                differ += 1
                kind = "cut" if k < 30 else "3 bits flipped"
                print(f"case {k} ({kind}, tolerant={tolerant}) differs")
    print(
        f"{len(cases)} damaged copies of plain_2d (30 cuts, 200 x 3 flipped bits), strict and "
        f"tolerant: {2 * len(cases) - differ} of {2 * len(cases)} reads identical (same records "
        "or both BagError)"
    )
    return 1 if differ else 0


if __name__ == "__main__":
    sys.exit(main())
