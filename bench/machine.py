"""The machine a benchmark ran on: CPU, cores, load, Python and library versions, date, commit."""

from __future__ import annotations

import datetime as _dt
import os
import platform
import subprocess
import sys
from pathlib import Path

import _common
from _common import md_table


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.lower().startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _git(*args: str) -> str:
    try:
        return subprocess.run(
            ["git", *args], cwd=str(_common.ROOT), capture_output=True, text=True, timeout=10
        ).stdout.strip()
    except (OSError, subprocess.TimeoutExpired):
        return ""


def _version(mod: str) -> str:
    try:
        m = __import__(mod)
        return getattr(m, "__version__", "?")
    except Exception:  # pragma: no cover - reporting only
        return "not installed"


def _mem_gib() -> float:
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemTotal:"):
                return int(line.split()[1]) / 2**20
    except OSError:
        pass
    return float("nan")


def collect(argv: list[str] | None = None) -> dict:
    """Facts recorded before the run (``finish`` adds the end-of-run ones)."""
    try:
        affinity = len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover
        affinity = os.cpu_count()
    commit = _git("rev-parse", "--short=12", "HEAD")
    dirty = _git(
        "status", "--porcelain", "--untracked-files=no", "--", "circle_collision_ros", "bench"
    )
    return dict(
        date_utc=_dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M:%S UTC"),
        cpu_model=_cpu_model(),
        logical_cpus=os.cpu_count(),
        usable_cpus=affinity,
        memory_gib=round(_mem_gib(), 1),
        os=f"{platform.system()} {platform.release()} ({platform.machine()})",
        python=sys.version.split()[0],
        numpy=_version("numpy"),
        numba=_version("numba"),
        mpmath=_version("mpmath"),
        matplotlib=_version("matplotlib"),
        ros_distro=os.environ.get("ROS_DISTRO", "") or "Kilted wheels (venv)",
        ros_domain_id=os.environ.get("ROS_DOMAIN_ID", "0"),
        ros_discovery_range=os.environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE", ""),
        git_commit=commit
        + (" + uncommitted changes in circle_collision_ros/ or bench/" if dirty else ""),
        loadavg_start=" ".join(f"{x:.2f}" for x in os.getloadavg()),
        command=" ".join(argv if argv is not None else sys.argv),
    )


def finish(info: dict, wall_s: float, sections: dict) -> dict:
    import numba

    info["loadavg_end"] = " ".join(f"{x:.2f}" for x in os.getloadavg())
    info["numba_threads"] = numba.get_num_threads()
    try:
        info["numba_threading_layer"] = numba.threading_layer()
    except ValueError:  # no parallel kernel ran
        info["numba_threading_layer"] = "(not initialised)"
    info["wall_s"] = round(wall_s, 1)
    info["section_wall_s"] = {k: round(v, 1) for k, v in sections.items()}
    return info


LABELS = [("date_utc", "date"), ("cpu_model", "CPU model"), ("logical_cpus", "logical CPUs"),
          ("usable_cpus", "CPUs usable by this process"), ("memory_gib", "memory (GiB)"),
          ("os", "OS"), ("python", "Python"), ("numpy", "numpy"), ("numba", "numba"),
          ("numba_threads", "numba threads"), ("numba_threading_layer", "numba threading layer"),
          ("mpmath", "mpmath"), ("matplotlib", "matplotlib"), ("ros_distro", "ROS 2"),
          ("ros_discovery_range", "ROS_AUTOMATIC_DISCOVERY_RANGE"),
          ("ros_domain_id", "ROS_DOMAIN_ID"), ("git_commit", "git commit"),
          ("loadavg_start", "load average at start (1/5/15 min)"),
          ("loadavg_end", "load average at end"), ("wall_s", "benchmark wall time (s)"),
          ("command", "command")]


def table(info: dict) -> str:
    rows = [[lab, f"`{info[k]}`" if k == "command" else info[k]] for k, lab in LABELS if k in info]
    if "section_wall_s" in info:
        rows.append(
            [
                "section wall times (s)",
                ", ".join(f"{k} {v}" for k, v in info["section_wall_s"].items()),
            ]
        )
    return md_table(["item", "value"], rows, "ll")


def one_line(info: dict) -> str:
    return (
        f"{info['date_utc']}, {info['cpu_model']}, {info['usable_cpus']} CPUs, Python "
        f"{info['python']}, "
        f"numpy {info['numpy']}, numba {info['numba']} ({info.get('numba_threads', '?')} threads), "
        f"load average {info['loadavg_start']} at start"
    )


def write_markdown(info: dict, out: Path) -> Path:
    p = out / "machine.md"
    p.write_text(
        "# Machine\n\nRecorded by bench/run_all.py beside the numbers of the same run. The machine "
        "may be shared: compare methods within one run (ratios), not absolute figures across "
        "runs.\n\n"
        + table(info)
    )
    return p


if __name__ == "__main__":
    print(table(collect()))
