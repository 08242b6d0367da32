"""Record a replay corpus from the demo scene: N real runs, varied seeds and sizes (0.5-5 MB each).

    .venv/bin/python scripts/make_corpus.py bench/.cache/corpus [--count 40] [--parallel 2]

Each recording is a real run like scripts/make_test_bags.py makes (collision_node
and demo_scene as separate processes over DDS on localhost, recorded by the
node); body count, duration, dimensions and bad-input share vary with the run
index, so the corpus mixes small and large bags. Runs going on at once each
get their own ROS domain (claimed like the test suite does), so they never
hear each other. Existing bags in OUT_DIR are kept (delete the folder to redo).
For the corpus benchmark (bench/bench_replay_corpus.py); not committed.
"""
from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import NamedTuple

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tests.conftest import _claim_domain_id  # noqa: E402  (the test suite's domain locks)

SIZE_RANGE_MB = (0.5, 5.0)


class RunSpec(NamedTuple):
    """One demo run to record."""

    name: str
    seed: int
    count: int       # bodies
    duration: float  # s of recording after the first prediction
    dimensions: int
    bad_fraction: float

    def args(self) -> list[str]:
        area = 40.0 * (self.count / 25) ** (1 / self.dimensions)  # similar density at every size
        return ["--count", str(self.count), "--seed", str(self.seed), "--duration",
                str(self.duration), "--dimensions", str(self.dimensions), "--area", f"{area:.1f}",
                "--bad-fraction", str(self.bad_fraction)]


def plan(count: int) -> list[RunSpec]:
    """Sizes spread over the range: bodies 25-70 and 4-10 s (3-D, every 4th run, 2 s longer: fewer
    contacts), every 5th run with bad inputs."""
    specs = []
    for k in range(count):
        specs.append(
            RunSpec(name=f"run_{k:03d}", seed=100 + k, count=25 + (k * 7) % 46,
                    duration=4.0 + (k * 5) % 7 + (2 if k % 4 == 3 else 0),
                    dimensions=3 if k % 4 == 3 else 2, bad_fraction=0.03 if k % 5 == 4 else 0.0)
        )
    return specs


def record(spec: RunSpec, out: Path, domain: int) -> str:
    bag = out / spec.name
    if (bag / "metadata.yaml").is_file():
        return f"{bag}: kept"
    shutil.rmtree(bag, ignore_errors=True)
    env = {**os.environ, "ROS_DOMAIN_ID": str(domain), "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}
    runs = out / f"_runs_{spec.name}"
    run = subprocess.run(
        [sys.executable, "-m", "circle_collision_ros.demo.run", "--runs-dir", str(runs), "--bag",
         str(bag), *spec.args()],
        capture_output=True,
        text=True,
        env=env,
    )
    shutil.rmtree(runs, ignore_errors=True)
    if run.returncode != 0:
        shutil.rmtree(bag, ignore_errors=True)
        return f"{bag}: FAILED ({run.returncode}): {run.stderr.strip().splitlines()[-1:]}"
    size = sum(f.stat().st_size for f in bag.iterdir()) / 1e6
    note = "" if SIZE_RANGE_MB[0] <= size <= SIZE_RANGE_MB[1] else "  (outside 0.5-5 MB)"
    return (f"{bag}: {size:.2f} MB, {spec.count} bodies, {spec.duration:.0f} s, "
            f"{spec.dimensions}-D{note}")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path, help="folder for the bags")
    parser.add_argument("--count", type=int, default=40, help="recordings (default 40)")
    parser.add_argument("--parallel", type=int, default=2, help="runs at once (default 2)")
    opts = parser.parse_args()
    opts.out.mkdir(parents=True, exist_ok=True)
    domains = [int(os.environ["ROS_DOMAIN_ID"])] + [
        _claim_domain_id() for _ in range(opts.parallel - 1)
    ]
    specs = plan(opts.count)
    failed = 0
    with ThreadPoolExecutor(opts.parallel) as pool:
        lanes = [specs[i :: opts.parallel] for i in range(opts.parallel)]

        def lane(index: int) -> None:
            nonlocal failed
            for spec in lanes[index]:
                line = record(spec, opts.out, domains[index])
                failed += "FAILED" in line
                print(line, flush=True)

        list(pool.map(lane, range(opts.parallel)))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
