"""Corpus replay benchmark: local workers 2 vs 1, Dask LocalCluster 2 vs 1, engine overhead,
one-bag throughput.

    .venv/bin/python bench/bench_replay_corpus.py [--corpus bench/.cache/corpus] [--bags 40]

Prints, in one run on this machine:
- `replay CORPUS --jobs 1` vs `--jobs 2` wall time (target: 2 workers >= 1.7x faster);
- the same command with `--cluster` on a Dask LocalCluster of 1 vs 2 worker
  processes (target >= 1.5x); the workers are warmed (engine imported) first,
  as on a long-lived cluster;
- the engine's overhead per bag in ms: wall time minus the replay time the
  workers report (JUnit testcase times), over the bag count, on 1 worker; and
  the same for tiny tasks (non-MCAP files that fail at once);
- single-bag throughput (inputs/s, pairs/s) of the largest bag and of the
  test bags, and a cProfile of one replay grouped by where the time goes.
Wall times come from `replay`'s own summary line (worker start-up included,
interpreter start-up not). The corpus is recorded by scripts/make_corpus.py
when missing (minutes). The machine has 2 cores shared with other work: ratios
from the same run are what counts; the load average is printed.
"""

from __future__ import annotations

import argparse
import cProfile
import os
import pstats
import re
import resource
import subprocess
import sys
import tempfile
import time
import xml.etree.ElementTree as ET
from pathlib import Path

from _common import ROOT

REPLAY = [sys.executable, "-m", "circle_collision_ros.recording.replay"]
DEFAULT_CORPUS = ROOT / "bench" / ".cache" / "corpus"


def _cpu_seconds() -> tuple[float, float]:
    """(CPU s used by our finished children, CPU s used by the whole machine) so far."""
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    with open("/proc/stat") as f:
        fields = [int(x) for x in f.readline().split()[1:]]
    busy = sum(fields) - fields[3] - fields[4]  # all but idle and iowait
    return children.ru_utime + children.ru_stime, busy / os.sysconf("SC_CLK_TCK")


def replay_wall(args: list[str]) -> tuple[float, float, int, float | None]:
    """(wall s from replay's summary, sum of per-bag worker seconds, bags, CPU cores used) of one
    run.

    Also prints the CPU time the run used and what the rest of the machine used
    meanwhile (local runs: the workers are the command's children).
    """
    with tempfile.TemporaryDirectory() as tmp:
        junit = Path(tmp) / "r.xml"
        ours0, machine0 = _cpu_seconds()
        t0 = time.monotonic()
        run = subprocess.run(
            REPLAY + args + ["--junit-xml", str(junit)], capture_output=True, text=True
        )
        ours1, machine1 = _cpu_seconds()
        elapsed = time.monotonic() - t0
        if "--cluster" not in args:  # Dask workers are not the command's children
            print(
                f"  replay {' '.join(a for a in args if not a.startswith('/'))}: {elapsed:.1f} s, "
                f"CPU used by it {ours1 - ours0:.1f} s, by other processes "
                f"{machine1 - machine0 - (ours1 - ours0):.1f} s, of {os.cpu_count() * elapsed:.1f} "
                "s",
                flush=True,
            )
        if run.returncode not in (0, 2) or "wall time" not in run.stdout:
            raise SystemExit(
                f"replay failed ({run.returncode}): {run.stdout[-2000:]}{run.stderr[-2000:]}"
            )
        wall = float(re.search(r"^wall time: ([\d.]+) s", run.stdout, re.M).group(1))
        cases = list(ET.parse(junit).getroot().iter("testcase"))
        cores = None if "--cluster" in args else (ours1 - ours0) / elapsed
        return wall, sum(float(c.get("time")) for c in cases), len(cases), cores


def best(args: list[str], repeat: int) -> tuple[float, float, int, float | None]:
    return min((replay_wall(args) for _ in range(repeat)), key=lambda r: r[0])


def load() -> str:
    return "load average " + " ".join(f"{x:.2f}" for x in os.getloadavg())


def compare(label: str, target: float, runs: dict[int, list[tuple[float, float, int]]]) -> None:
    """Best wall time per worker count; worker-seconds show how much CPU each bag got."""
    one, two = (min(runs[k], key=lambda r: r[0]) for k in (1, 2))
    print(
        f"{label}, {one[2]} bags: 1 worker {one[0]:.2f} s, 2 workers {two[0]:.2f} s -> speedup "
        f"{one[0] / two[0]:.2f}x (target >= {target}x); replay time summed over bags "
        f"{one[1]:.1f} s vs {two[1]:.1f} s   [{load()}]",
        flush=True,
    )
    if one[3] is not None:
        autogroup = Path("/proc/sys/kernel/sched_autogroup_enabled")
        print(
            f"  CPU the run got: {one[3]:.2f} cores with 1 worker, {two[3]:.2f} cores with 2 "
            "workers"
            + (
                "; the kernel shares CPU fairly between sessions (sched_autogroup_enabled=1), so "
                "on a "
                "machine busy with other sessions more workers in one session get no more CPU"
                if autogroup.exists() and autogroup.read_text().strip() == "1"
                else ""
            ),
            flush=True,
        )


def local_speedup(corpus: Path, repeat: int) -> None:
    runs: dict[int, list] = {1: [], 2: []}
    for _ in range(repeat):  # interleaved, so a change in the machine's load hits both
        for jobs in (1, 2):
            runs[jobs].append(replay_wall([str(corpus), "--jobs", str(jobs)]))
    compare("local pool", 1.7, runs)


def dask_runs(corpus: Path, tiny: Path, repeat: int) -> None:
    import dask
    from distributed import Client, LocalCluster

    walls = {}
    with dask.config.set({"distributed.scheduler.allowed-failures": 0}):
        for workers in (1, 2):
            with (
                LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                             dashboard_address=":0", host="127.0.0.1") as cluster,
                Client(cluster.scheduler_address) as client,
            ):
                client.run(
                    lambda: __import__("circle_collision_ros.recording.replay")
                )  # warm workers
                address = cluster.scheduler_address
                walls[workers] = best([str(corpus), "--cluster", address], repeat)
                if workers == 1:
                    wall, worked, bags, _ = walls[1]
                    print(
                        f"Dask engine overhead per bag (1 worker, recorded bags): "
                        f"{(wall - worked) / bags * 1e3:.1f} ms",
                        flush=True,
                    )
                    wall, worked, bags, _ = best([str(tiny), "--cluster", address], repeat)
                    print(
                        f"Dask engine overhead per bag (1 worker, {bags} tiny tasks): "
                        f"{(wall - worked) / bags * 1e3:.1f} ms; per tiny task end to end "
                        f"{wall / bags * 1e3:.1f} ms",
                        flush=True,
                    )
    compare("Dask LocalCluster", 1.5, {k: [v] for k, v in walls.items()})


def throughput(bags: list[Path], profile_bag: Path) -> None:
    from circle_collision_ros.recording.replay_engine import load_bag, replay_offline

    for bag in bags:
        _, records = load_bag(bag)
        replay_offline(records)  # warm (numba kernels load from their cache)
        times = []
        for _ in range(3):
            t0 = time.perf_counter()
            report = replay_offline(records)
            times.append(time.perf_counter() - t0)
        t = min(times)
        print(
            f"one-bag replay {bag.name}: {report.inputs} inputs, {report.pairs_compared} pairs in "
            f"{t:.3f} s"
            f" -> {report.inputs / t:.0f} inputs/s, {report.pairs_compared / t:.0f} pairs/s",
            flush=True,
        )
    _, records = load_bag(profile_bag)
    profiler = cProfile.Profile()
    profiler.enable()
    replay_offline(records)
    profiler.disable()
    stats = pstats.Stats(profiler)
    total = sum(v[2] for v in stats.stats.values())
    groups: dict[str, float] = {}
    for (filename, _, name), (_, _, tottime, _, _) in stats.stats.items():
        groups[_group(filename, name)] = groups.get(_group(filename, name), 0.0) + tottime
    print(
        f"profile of one replay of {profile_bag.name} ({total:.3f} s under cProfile), own time by "
        "part:"
    )
    for group, seconds in sorted(groups.items(), key=lambda kv: -kv[1]):
        print(f"  {seconds / total:6.1%}  {group}")
    print("  top functions (own time):")
    rows = sorted(stats.stats.items(), key=lambda kv: -kv[1][2])[:10]
    for (filename, line, name), (_, calls, tottime, _, _) in rows:
        print(f"  {tottime / total:6.1%}  {calls:7d} calls  {Path(filename).name}:{line} {name}")


def _group(filename: str, name: str) -> str:
    if "circle_collision_ros/core" in filename:
        return "solver core (circle_collision_ros/core)"
    if "circle_collision_ros/pipeline" in filename:
        return "predictor pipeline (registry, validation, CDR codec, message rows)"
    if "rclpy" in name or "rclpy" in filename:
        return "rclpy (de)serialization"
    if "/msg/_" in filename:
        return "ROS message classes (construction, comparison)"
    if "circle_collision_ros/recording" in filename:
        return "replay loop and comparison"
    if "numpy" in filename or "ufunc" in name or "numpy" in name:
        return "numpy"
    return "other Python"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--corpus", type=Path, default=DEFAULT_CORPUS)
    parser.add_argument("--bags", type=int, default=40)
    parser.add_argument("--repeat", type=int, default=2, help="runs per configuration, best taken")
    opts = parser.parse_args()
    if len(list(opts.corpus.glob("*/metadata.yaml"))) < opts.bags:
        print(f"recording the corpus into {opts.corpus} (scripts/make_corpus.py) ...", flush=True)
        subprocess.run(
            [sys.executable, str(ROOT / "scripts" / "make_corpus.py"), str(opts.corpus), "--count",
             str(opts.bags)],
            check=True,
        )
    bags = sorted(opts.corpus.glob("*/metadata.yaml"))[: opts.bags]
    sizes = [sum(f.stat().st_size for f in b.parent.iterdir()) / 1e6 for b in bags]
    print(
        f"corpus: {len(bags)} bags, {min(sizes):.2f}-{max(sizes):.2f} MB each, {sum(sizes):.0f} "
        "MB; "
        f"{os.cpu_count()} CPUs   [{load()}]",
        flush=True,
    )
    with tempfile.TemporaryDirectory() as tmp:
        corpus = Path(tmp) / "corpus"
        corpus.mkdir()
        for b in bags:
            (corpus / b.parent.name).symlink_to(b.parent.resolve())
        tiny = Path(tmp) / "tiny"
        tiny.mkdir()
        for k in range(200):
            (tiny / f"t{k:03d}.mcap").write_text("not a recording\n")
        local_speedup(corpus, opts.repeat)
        dask_runs(corpus, tiny, opts.repeat)
    largest = bags[max(range(len(bags)), key=sizes.__getitem__)].parent
    data = ROOT / "tests" / "data"
    throughput([largest, data / "plain_2d", data / "spheres_3d"], largest)
    return 0


if __name__ == "__main__":
    sys.exit(main())
