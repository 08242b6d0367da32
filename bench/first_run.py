#!/usr/bin/env python3
"""First run from a fresh clone: scripts/demo.sh to its first prediction, then scripts/test.sh.

    .venv/bin/python bench/first_run.py [--skip-tests] [--keep] [--pip-cache {warm,cold}] [--out
    DIR]

In a temporary directory, ``git clone`` this repository (its committed HEAD:
uncommitted changes are not in the clone), then

1. time ``bash scripts/demo.sh --duration 3`` from its start to the demo's
   first prediction (the line ``first prediction after X s`` the demo prints;
   a clone without that line: its first live-table line, printed at the same
   moment). Every line either stream prints is time-stamped, so the bootstrap's
   steps (``[bootstrap] ...``) are on the same clock: the figure "after the
   dependency installs" counts from the start of the first bootstrap step that
   follows ``installing pinned dependencies``;
2. then, on that set-up, time ``bash scripts/test.sh -q -p no:cacheprovider``
   (the default suite) to its end, with its exit code (--skip-tests: not run).

Targets: first prediction <= 120 s from the start and <= 45 s after the
dependency installs; the test command <= 6 min after the set-up. Prints the
figures and writes them to <out>/first_run.md (default bench/results/) with
the machine's cores and its load average at the start and the end.

--pip-cache warm (default) uses pip's usual cache; cold gives pip a fresh,
empty cache directory (PIP_CACHE_DIR), as on a machine that never installed
the wheels. Everything runs with ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST and a
ROS_DOMAIN_ID of its own (claimed with the test suite's lock files), without
environment variables that point into this checkout (an activated venv).
--keep keeps the clone and prints where it is. Takes minutes: it creates a
venv, installs the ROS 2 wheels, builds the interfaces and compiles the
numba kernels from nothing.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import fcntl
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

TARGET_FIRST_PREDICTION_S = 120.0
TARGET_AFTER_DEPS_S = 45.0
TARGET_TESTS_S = 360.0
DEMO_CMD = ["bash", "scripts/demo.sh", "--duration", "3"]
TEST_CMD = ["bash", "scripts/test.sh", "-q", "-p", "no:cacheprovider"]
DEMO_TIMEOUT_S = 1800.0
TEST_TIMEOUT_S = 3600.0

FIRST_PREDICTION = re.compile(r"first prediction after ([0-9.]+) s")
TABLE_LINE = re.compile(r"^circle_collision_ros demo .*predictions received")
DEPS_LINE = "[bootstrap] installing pinned dependencies"


def _claim_domain() -> tuple[int, int]:
    """A free ROS domain id, locked like the tests do (from 100 down, away from their low ids)."""
    for domain in range(100, 0, -1):
        path = os.path.join(tempfile.gettempdir(), f"circle_collision_ros_domain_{domain}.lock")
        fd = os.open(path, os.O_CREAT | os.O_RDWR, 0o666)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            os.close(fd)
            continue
        return domain, fd
    raise SystemExit("no free ROS domain id in 1..100")


def clean_env(domain: int, pip_cache: str | None) -> dict:
    """This process's environment without anything pointing into this checkout (or its venv)."""
    root = str(ROOT)
    env = {k: v for k, v in os.environ.items() if root not in v or k == "PATH"}
    env["PATH"] = os.pathsep.join(
        p for p in env.get("PATH", "").split(os.pathsep) if p and root not in p
    )
    for k in (
        "VIRTUAL_ENV",
        "PYTHONPATH",
        "PYTHONHOME",
        "NUMBA_CACHE_DIR",
        "ROS_STATIC_PEERS",
        "CIRCLE_COLLISION_TEST_DOMAIN_ID",
        # set by the ROS wheels' bootstrapper once it has re-executed this venv's Python with
        # its library path: inherited, it would keep the clone's Python from doing the same
        "_ROS_WHEELS_BOOTSTRAP_COMPLETE",
        "LD_LIBRARY_PATH",
    ):
        env.pop(k, None)
    for k in [k for k in env if k.startswith("_CCR_")]:
        env.pop(k)
    env.update(ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", ROS_DOMAIN_ID=str(domain),
               PYTHONUNBUFFERED="1", MPLBACKEND="Agg")
    if pip_cache:
        env["PIP_CACHE_DIR"] = pip_cache
    return env


def run_timed(
    cmd: list[str], cwd: Path, env: dict, timeout: float, label: str
) -> tuple[object, list[tuple[float, str]], float]:
    """Run ``cmd``; (exit code or "timeout", [(seconds since its start, line)], wall s).

    stdout and stderr are read as they come, each line stamped on arrival and
    echoed. On a timeout the command's process group is ended.
    """
    t0 = time.monotonic()
    proc = subprocess.Popen(cmd, cwd=str(cwd), env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, errors="replace", bufsize=1,
                            start_new_session=True)
    lines: list[tuple[float, str]] = []
    lock = threading.Lock()

    def pump(stream):
        for line in stream:
            t = time.monotonic() - t0
            line = line.rstrip("\n")
            with lock:
                lines.append((t, line))
                print(f"[{label} {t:7.1f} s] {line}", flush=True)

    readers = [
        threading.Thread(target=pump, args=(s,), daemon=True) for s in (proc.stdout, proc.stderr)
    ]
    for r in readers:
        r.start()
    try:
        rc: object = proc.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGTERM)  # the command's own process group (start_new_session)
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
        rc = "timeout"
    wall = time.monotonic() - t0
    for r in readers:
        r.join(timeout=10)
    lines.sort(key=lambda x: x[0])
    return rc, lines, wall


def demo_figures(lines: list[tuple[float, str]]) -> dict:
    """First prediction, the bootstrap's steps and the end of the dependency installs."""
    boot = [(t, s) for t, s in lines if s.startswith("[bootstrap]")]
    fig: dict = {"bootstrap": boot, "first_prediction_s": None, "demo_clock_s": None,
                 "marker": None, "deps_done_s": None, "deps_step": None}
    for t, s in lines:
        m = FIRST_PREDICTION.search(s)
        if m:
            fig.update(first_prediction_s=t, demo_clock_s=float(m.group(1)),
                       marker="the demo's line `first prediction after X s`")
            break
    if fig["first_prediction_s"] is None:
        for t, s in lines:
            if TABLE_LINE.search(s):
                fig.update(
                    first_prediction_s=t,
                    marker="the demo's first live-table line (printed on the "
                    "first prediction; the cloned demo prints no `first prediction after` line)",
                )
                break
    for i, (t, s) in enumerate(boot):
        if s.startswith(DEPS_LINE):
            if i + 1 < len(boot):
                fig.update(deps_done_s=boot[i + 1][0], deps_step=boot[i + 1][1])
            break
    return fig


def _s(x) -> str:
    return "n/a" if x is None else f"{x:.1f} s"


def _met(x, target) -> str:
    return "n/a" if x is None else ("yes" if x <= target else "NO")


def _scrub(text: str, clone: Path) -> str:
    text = text.replace(str(clone), "<clone>").replace(str(ROOT), "<repo>")
    return re.sub(re.escape(tempfile.gettempdir().rstrip("/")) + r"/[^\s'\":,)\]]*", "<tmp>", text)


def markdown(r: dict, clone: Path) -> str:
    fig = r["demo"]
    after = (
        None
        if fig["first_prediction_s"] is None or fig["deps_done_s"] is None
        else fig["first_prediction_s"] - fig["deps_done_s"]
    )
    rows = [
        ("first prediction, from the start of `scripts/demo.sh`", _s(fig["first_prediction_s"]),
         f"<= {TARGET_FIRST_PREDICTION_S:.0f} s",
         _met(fig["first_prediction_s"], TARGET_FIRST_PREDICTION_S)),
        ("first prediction, after the dependency installs", _s(after),
         f"<= {TARGET_AFTER_DEPS_S:.0f} s", _met(after, TARGET_AFTER_DEPS_S)),
    ]
    if r.get("tests"):
        t = r["tests"]
        rows.append(
            (f"`{' '.join(TEST_CMD)}` after the set-up, exit code {t['exit']}", _s(t["wall_s"]),
             f"<= {TARGET_TESTS_S / 60:.0f} min",
             _met(t["wall_s"], TARGET_TESTS_S) if t["exit"] == 0 else "NO (exit code)")
        )
    else:
        rows.append(
            (f"`{' '.join(TEST_CMD)}` after the set-up", "not run (--skip-tests)",
             f"<= {TARGET_TESTS_S / 60:.0f} min", "n/a")
        )
    out = [
        "# First run from a fresh clone\n",
        f"Measured by `bench/first_run.py{(' ' + ' '.join(r['argv'])) if r['argv'] else ''}` on "
        f"{r['date_utc']}: a `git clone` of commit `{r['commit']}` (committed HEAD"
        + (
            "; the checkout had uncommitted changes, which the clone does not have"
            if r["dirty"]
            else ""
        )
        + f"), pip cache {r['pip_cache']}"
        + (" (an empty PIP_CACHE_DIR)" if r["pip_cache"] == "cold" else " (pip's usual cache)")
        + f". Machine: {r['cpus']} logical CPUs ({r['usable_cpus']} usable by this process); load "
        f"average (1/5/15 min) {r['load_start']} at the start, {r['load_end']} at the end. "
        "ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST and a ROS_DOMAIN_ID of its own.\n",
        "| figure | measured | target | met |",
        "|:---|---:|---:|:---|",
    ]
    out += [f"| {a} | {b} | {c} | {d} |" for a, b, c, d in rows]
    out += [
        "",
        (
            f"First prediction taken from {fig['marker']}; "
            if fig["marker"]
            else "No prediction was seen. "
        )
        + (
            f"the demo's own clock (from the import of its module) read {fig['demo_clock_s']:.1f} "
            "s, so "
            f"its process started {fig['first_prediction_s'] - fig['demo_clock_s']:.1f} s into the "
            "command "
            "(the bootstrap and the interpreter's start-up before that). "
            if fig["demo_clock_s"] is not None
            else ""
        )
        + (
            '"After the dependency installs" counts from the start of the bootstrap step that '
            'follows '
            f"them (`{fig['deps_step']}`)."
            if fig["deps_step"]
            else "No bootstrap step followed `installing pinned dependencies`, so the figure after "
                 "the "
            "dependency installs is not available."
        ),
        "",
        f"## `{' '.join(DEMO_CMD)}`: exit code {r['demo_exit']}, {r['demo_wall_s']:.1f} s in all\n",
        "| s from its start | line |",
        "|---:|:---|",
    ]
    marks = list(fig["bootstrap"])
    if fig["first_prediction_s"] is not None:
        if fig["demo_clock_s"] is not None:
            marks.append(
                (fig["first_prediction_s"] - fig["demo_clock_s"], "(the demo module is imported)")
            )
        marks.append((fig["first_prediction_s"], "(first prediction)"))
    out += [f"| {t:.1f} | `{_scrub(s, clone)}` |" for t, s in sorted(marks)]
    if r.get("tests"):
        t = r["tests"]
        out += [
            "",
            f"## `{' '.join(TEST_CMD)}`: exit code {t['exit']}, {t['wall_s']:.1f} s\n",
            "Its first and last lines:\n",
            "```text",
        ]
        out += [f"{ts:7.1f} s  {_scrub(x, clone)}" for ts, x in t["head"]]
        out += ["..."] if t["lines"] > len(t["head"]) + len(t["tail"]) else []
        out += [f"{ts:7.1f} s  {_scrub(x, clone)}" for ts, x in t["tail"]]
        out += ["```"]
    if r["demo_exit"] != 0:
        out += ["", "The demo's last lines:\n", "```text"]
        out += [f"{t:7.1f} s  {_scrub(s, clone)}" for t, s in r["demo_tail"]] + ["```"]
    return "\n".join(out) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog=__doc__)
    ap.add_argument("--skip-tests", action="store_true", help="only the demo, not the test command")
    ap.add_argument("--keep", action="store_true", help="keep the clone (its path is printed)")
    ap.add_argument(
        "--pip-cache",
        choices=("warm", "cold"),
        default="warm",
        help="warm: pip's usual cache; cold: a fresh, empty PIP_CACHE_DIR (default warm)",
    )
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results",
                    help="folder for first_run.md (default bench/results/)")
    a = ap.parse_args(argv)
    argv_shown = [
        _scrub(x.replace(str(ROOT) + "/", ""), ROOT)
        for x in (sys.argv[1:] if argv is None else argv)
    ]
    a.out.mkdir(parents=True, exist_ok=True)

    def git(*args):
        return subprocess.run(
            ["git", *args], cwd=str(ROOT), capture_output=True, text=True
        ).stdout.strip()

    r: dict = dict(argv=argv_shown, pip_cache=a.pip_cache, cpus=os.cpu_count(),
                   usable_cpus=len(os.sched_getaffinity(0)),
                   commit=git("rev-parse", "--short=12", "HEAD"),
                   dirty=bool(git("status", "--porcelain", "--untracked-files=no")),
                   date_utc=_dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
                   load_start=" ".join(f"{x:.2f}" for x in os.getloadavg()))
    print(f"load average at start: {r['load_start']}; {r['cpus']} CPUs", flush=True)
    domain, lock_fd = _claim_domain()
    tmp = Path(tempfile.mkdtemp(prefix="ccr-first-run-"))
    clone = tmp / "circle_collision_ros"
    try:
        pip_cache = None
        if a.pip_cache == "cold":
            pip_cache = str(tmp / "pip-cache")
            os.makedirs(pip_cache)
        env = clean_env(domain, pip_cache)
        t0 = time.monotonic()
        subprocess.run(["git", "clone", "--quiet", str(ROOT), str(clone)], check=True)
        print(
            f"cloned commit {r['commit']} in {time.monotonic() - t0:.1f} s "
            f"(ROS_DOMAIN_ID {domain})",
            flush=True,
        )

        rc, lines, wall = run_timed(DEMO_CMD, clone, env, DEMO_TIMEOUT_S, "demo")
        fig = demo_figures(lines)
        r.update(demo=fig, demo_exit=rc, demo_wall_s=wall, demo_tail=lines[-20:])
        after = (
            None
            if fig["first_prediction_s"] is None or fig["deps_done_s"] is None
            else fig["first_prediction_s"] - fig["deps_done_s"]
        )
        print(
            f"first prediction after {_s(fig['first_prediction_s'])} from the start of "
            "scripts/demo.sh "
            f"(target <= {TARGET_FIRST_PREDICTION_S:.0f} s), {_s(after)} after the dependency "
            "installs "
            f"(target <= {TARGET_AFTER_DEPS_S:.0f} s); demo exit code {rc}",
            flush=True,
        )

        if not a.skip_tests:
            rc_t, tl, wall_t = run_timed(TEST_CMD, clone, env, TEST_TIMEOUT_S, "test")
            r["tests"] = dict(exit=rc_t, wall_s=wall_t, head=tl[:5],
                              tail=tl[max(5, len(tl) - 15) :], lines=len(tl))
            print(
                f"{' '.join(TEST_CMD)}: {wall_t:.1f} s after the set-up (target <= "
                f"{TARGET_TESTS_S / 60:.0f} min), exit code {rc_t}",
                flush=True,
            )
    finally:
        r["load_end"] = " ".join(f"{x:.2f}" for x in os.getloadavg())
        if a.keep:
            print(f"clone kept: {clone}")
        else:
            shutil.rmtree(tmp, ignore_errors=True)
        os.close(lock_fd)
    print(f"load average at end: {r['load_end']}", flush=True)
    md = a.out / "first_run.md"
    md.write_text(markdown(r, clone))
    try:
        shown = md.resolve().relative_to(ROOT)
    except ValueError:
        shown = md
    print(f"wrote {shown}")
    ok = (
        r["demo_exit"] == 0
        and r["demo"]["first_prediction_s"] is not None
        and (a.skip_tests or r["tests"]["exit"] == 0)
    )
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
