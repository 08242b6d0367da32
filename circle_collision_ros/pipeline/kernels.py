"""Compile the numba kernels a command needs, before it needs them, in parallel processes.

numba compiles a kernel at its first call and keeps the machine code in its
on-disk cache (``__pycache__`` beside the sources), so only the first start
after an install or a code change pays the compile; later starts load the
cache.  The node must never meet a cold compile in the middle of a stream, so
it prepares every path a message can reach before it subscribes:

* ``exact``: the scene (small, large and one-body updates), serial kernels;
* ``threads``: the threaded twins the parallel policy picks for large frames;
* ``uncertain``: the probability of contact (screen, per-pair kernels, the
  fallbacks a warm-up scene may not reach);
* ``messages``: decoding the input types and encoding the outputs.

A cold start compiles the paths in separate processes (``--jobs``, one per
core by default), each writing numba's cache, then loads them in the calling
process.  A stamp per (path, dimensions, source hash) records that a path was
compiled, so a warm start loads the cache without spawning anything.
``scripts/test.sh`` runs ``python -m circle_collision_ros.pipeline.kernels``
first, so a test run compiles each kernel once rather than once per worker or
per node it starts.
"""
from __future__ import annotations

import argparse
import hashlib
import os
import subprocess
import sys
import time
from collections.abc import Callable, Iterable
from pathlib import Path

from circle_collision_ros.pipeline.predictor import WARM_UP_PATHS as PATHS
from circle_collision_ros.pipeline.predictor import CollisionPredictor, PredictorConfig

__all__ = ["PATHS", "source_hash", "is_compiled", "compile_in_processes", "prepare", "main"]

# Order of the compile jobs: the costliest first, so the last process to finish is a short one.
_COSTLIEST_FIRST = ("uncertain", "exact", "messages", "threads")
# The paths whose kernels a path's warm-up also runs (a message with covariance is predicted
# on the uncertain path; the threaded pass runs the scenes and the uncertain path with threads
# forced): it starts after them and loads theirs from the cache.  The threaded pass does not
# wait for the message path, whose codec kernels are small.
_REACHES = {"messages": ("uncertain",), "threads": ("exact", "uncertain")}

_PACKAGE = Path(__file__).resolve().parents[1]


def source_hash() -> str:
    """Hash of the modules numba compiles from (core and pipeline) and of numba's version."""
    import numba

    h = hashlib.sha256(f"{numba.__version__} {sys.version} {_PACKAGE}".encode())
    for path in sorted([*(_PACKAGE / "core").rglob("*.py"), *(_PACKAGE / "pipeline").glob("*.py")]):
        data = path.read_bytes()
        if b"numba" in data:  # only the modules numba compiles from decide its cache
            h.update(path.relative_to(_PACKAGE).as_posix().encode())
            h.update(data)
    return h.hexdigest()[:16]


def _stamp(path: str, dimensions: int, digest: str) -> Path:
    import numba

    root = Path(numba.config.CACHE_DIR) if numba.config.CACHE_DIR else _PACKAGE / "__pycache__"
    return root / "kernel_stamps" / f"{path}-{dimensions}d-{digest}"


def is_compiled(path: str, dimensions: int, digest: str | None = None) -> bool:
    """Whether ``path`` was compiled for ``dimensions`` from the current sources."""
    return _stamp(path, dimensions, digest or source_hash()).exists()


def _drop_stale_caches(digest: str) -> None:
    """After a source change, delete numba's cache files of the package (and the old stamps).

    numba checks only the source file of the function it loads, so a kernel cached before a
    change in a module it calls would be reused: every kernel is compiled afresh instead."""
    stamps = _stamp("exact", 2, digest).parent
    stale = [f for f in stamps.glob("*") if not f.name.endswith(digest)] if stamps.is_dir() else []
    if not stale:
        return
    import numba

    roots = [_PACKAGE, *([Path(numba.config.CACHE_DIR)] if numba.config.CACHE_DIR else [])]
    for f in [*(c for r in roots for c in r.rglob("*.nb[ic]")), *stale]:
        try:
            f.unlink()
        except OSError:
            pass


def _mark(path: str, dimensions: int, digest: str) -> None:
    stamp = _stamp(path, dimensions, digest)
    try:
        stamp.parent.mkdir(parents=True, exist_ok=True)
        stamp.touch()
    except OSError:  # a read-only install: numba caches elsewhere or not at all; nothing to record
        pass


def _run_path(path: str, dimensions: int) -> None:
    """Run ``path``'s kernels once, in this process (compiling or loading them)."""
    CollisionPredictor(PredictorConfig(dimensions=dimensions)).warm_up(paths=(path,))


def compile_in_processes(jobs: Iterable[tuple[str, int]], processes: int | None = None) -> float:
    """Compile each (path, dimensions) in its own process, ``processes`` at a time (default:
    the cores this process may use); returns the wall time, s.  A job starts once the jobs
    whose kernels it reaches (``_REACHES``) are done, so it loads them instead of compiling
    them again.  Raises RuntimeError naming the job whose process failed, with its output."""
    from concurrent.futures import FIRST_COMPLETED, ThreadPoolExecutor, wait

    def run(job: tuple[str, int]) -> subprocess.CompletedProcess:
        cmd = [sys.executable, "-m", "circle_collision_ros.pipeline.kernels", "--in-process",
               "--paths", job[0], "--dimensions", str(job[1])]
        return subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)

    pending = sorted(jobs, key=lambda job: (_COSTLIEST_FIRST.index(job[0]), -job[1]))
    limit = processes or len(os.sched_getaffinity(0))
    started = time.monotonic()
    running: dict = {}
    with ThreadPoolExecutor(max_workers=limit) as pool:
        while pending or running:
            waiting_on = {(p, d) for p, d in [*pending, *running.values()]}
            for job in list(pending):
                if len(running) >= limit:
                    break
                # 3-D after 2-D: most kernels take the same types in both and load from the cache
                deps = [(dep, job[1]) for dep in _REACHES.get(job[0], ())]
                deps += [(job[0], 2)] if job[1] == 3 else []
                if not any(dep in waiting_on for dep in deps):
                    pending.remove(job)
                    running[pool.submit(run, job)] = job
            done, _ = wait(running, return_when=FIRST_COMPLETED)
            for future in done:
                job = running.pop(future)
                result = future.result()
                if result.returncode != 0:
                    raise RuntimeError(f"compiling the {job[0]} kernels ({job[1]}-D) failed "
                                       f"(exit {result.returncode}):\n{result.stdout[-4000:]}")
    return time.monotonic() - started


def prepare(predictor: CollisionPredictor, paths: Iterable[str] = PATHS,
            log: Callable[[str], None] | None = None, processes: int | None = None) -> None:
    """Make ``paths`` ready for ``predictor``'s dimensions in this process: compile the ones
    not yet in numba's cache in parallel processes (saying so through ``log``), then run
    ``predictor.warm_up`` here, which loads them."""
    paths = tuple(paths)
    dimensions = predictor.config.dimensions
    digest = source_hash()
    cold = [(p, dimensions) for p in paths if not is_compiled(p, dimensions, digest)]
    if cold:
        _drop_stale_caches(digest)
        if log:
            log(f"compiling the numba kernels for {', '.join(p for p, _ in cold)} ({dimensions}-D) "
                "before subscribing: the first start after an install or a code change; later "
                "starts load them from the cache")
        seconds = compile_in_processes(cold, processes)
        for p, d in cold:
            _mark(p, d, digest)
        if log:
            log(f"kernels compiled in {seconds:.0f} s")
    predictor.warm_up(paths)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m circle_collision_ros.pipeline.kernels",
        description="Compile the numba kernels into their on-disk cache (what a node start, the "
                    "demo or the tests would otherwise compile at their first call).")
    parser.add_argument("--paths", nargs="+", choices=PATHS, default=list(PATHS))
    parser.add_argument("--dimensions", nargs="+", type=int, choices=(2, 3), default=[2, 3])
    parser.add_argument(
        "--jobs", type=int, default=None, help="processes at a time (default: cores)"
    )
    parser.add_argument("--in-process", action="store_true", help=argparse.SUPPRESS)
    opts = parser.parse_args(argv)
    if opts.in_process:
        for d in opts.dimensions:
            for p in opts.paths:
                _run_path(p, d)
        return 0
    digest = source_hash()
    cold = [(p, d) for d in opts.dimensions for p in opts.paths if not is_compiled(p, d, digest)]
    if not cold:
        print("kernels: every requested path is compiled (numba's cache is current)", flush=True)
        return 0
    _drop_stale_caches(digest)
    print(
        f"kernels: compiling {len(cold)} paths in up to "
        f"{opts.jobs or len(os.sched_getaffinity(0))} "
        "processes ...",
        flush=True,
    )
    try:
        seconds = compile_in_processes(cold, opts.jobs)
    except RuntimeError as exc:
        print(f"kernels: {exc}", file=sys.stderr)
        return 1
    for p, d in cold:
        _mark(p, d, digest)
    print(f"kernels: compiled in {seconds:.0f} s", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
