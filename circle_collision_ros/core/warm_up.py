"""Compile the core's numba kernels ahead of use, in parallel processes, once per source version.

numba compiles a kernel at its first call and keeps the machine code in its
on-disk cache (``__pycache__`` beside the sources), so only the first start
after an install or a code change pays the compile; later starts load the
cache.  A caller compiled after its callees loads them from that cache instead
of compiling them again, so the work is split into jobs that build on each
other and run side by side:

* ``narrow``: the scalar first-contact solver every scene evaluation calls;
* ``parts``: the scene's kernels that never call it (broad phase, ordering), beside it;
* ``rows``: the scene's kernels that evaluate pairs and store records, once ``narrow`` is;
* ``batch``: the vectorised batch solver of large frames (independent of ``narrow``);
* ``exact``: the scene's serial kernels (frames, one-body updates);
* ``large``: frames of ``Scene.COMPILED_ROWS`` pairs or more (the vectorised path);
* ``threads``: the threaded twins the parallel policy picks for large frames;
* ``uncertain``: the probability of contact (screen, per-pair kernels and fallbacks).

``pipeline.kernels`` adds the message jobs.  A job runs in its own process
(``python -m <module> --job NAME --dimensions D``) once the jobs it builds on
are done; a stamp per (job, dimensions, source hash) records that it was
compiled, and a lock file per stamp lets concurrent preparers (a set-up step,
two nodes, test workers) wait for one compile rather than repeat it.
"""
from __future__ import annotations

import argparse
import fcntl
import hashlib
import os
import re
import subprocess
import sys
import time
from collections.abc import Callable, Iterable, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator, NamedTuple

import numpy as np

from circle_collision_ros.core.broad.relative import PARALLEL_MIN_PAIRS
from circle_collision_ros.core.broad.sweep import PARALLEL_MIN_BODIES
from circle_collision_ros.core.narrow.batch import (PARALLEL_MIN_ROWS, time_to_collision,
                                                    ttc_scalar, ttc_scalar2)
from circle_collision_ros.core.narrow.contact import PARALLEL_MIN_CONTACTS
from circle_collision_ros.core.parallel_policy import threads_forced
from circle_collision_ros.core.scene import Scene
from circle_collision_ros.core.uncertainty import load_fallback_kernels

__all__ = ["Job", "CORE_JOBS", "large_frames_reachable", "threads_reachable", "warm_scene_parts",
           "warm_scene_rows", "warm_scenes", "warm_large_frames", "warm_uncertain",
           "source_hash", "is_compiled", "with_dependencies", "compile_jobs", "main"]

_PACKAGE = Path(__file__).resolve().parents[1]


class Job(NamedTuple):
    """A compile job: ``run(dimensions, horizon)`` in a process of ``module``'s ``--job``."""

    run: Callable[[int, float], None]
    after: tuple[str, ...]  # the jobs whose kernels it calls (compiled first, then loaded)
    module: str


def large_frames_reachable(max_bodies: int) -> bool:
    """Whether a scene of at most ``max_bodies`` bodies can have ``Scene.COMPILED_ROWS`` pairs
    or more to evaluate at once (the vectorised path)."""
    return max_bodies * (max_bodies - 1) // 2 >= Scene.COMPILED_ROWS


def threads_reachable(max_bodies: int) -> bool:
    """Whether a scene of at most ``max_bodies`` bodies can reach a threaded kernel: the
    parallel policy's smallest work threshold against the bodies and their pairs."""
    pairs = max_bodies * (max_bodies - 1) // 2
    return max_bodies >= PARALLEL_MIN_BODIES or pairs >= min(
        PARALLEL_MIN_ROWS, PARALLEL_MIN_PAIRS, PARALLEL_MIN_CONTACTS)


def _narrow(dimensions: int, horizon: float) -> None:
    if dimensions == 2:  # the scene's chain per dimension (scene.kernels._pair_ttc)
        ttc_scalar2(0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 5.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, horizon)
    else:
        ttc_scalar(0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0,
                   5.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, horizon)


def _batch(dimensions: int, horizon: float) -> None:
    z = np.zeros((2, dimensions))
    with threads_forced(False):  # the serial kernel; the threaded one is the threads job's
        time_to_collision(z + 2.0, z, z, np.ones(2), z, z, z, np.ones(2), float(horizon))


def _two_bodies(d: int, horizon: float) -> Scene:
    """A predicted scene of two touching bodies at rest."""
    scene = Scene(horizon, d)
    scene.upsert_many(["a", "b"], np.eye(2, d), np.zeros((2, d)), np.zeros((2, d)), np.ones(2), 1)
    scene.predictions()
    return scene


def warm_scene_parts(dimensions: int, horizon: float) -> None:
    """Run the scene's kernels that never call the solver: a rebuild and a stream of one-body
    updates whose bodies are never a candidate pair (the broad phase, the relative filter, the
    grid), and the ordering of records.  They compile beside ``narrow``."""
    d = dimensions
    # two bodies 3 apart with the same velocity: their swept boxes overlap, the relative
    # filter drops them (their distance never changes), so no pair reaches the solver
    p = np.zeros((2, d))
    p[1, 0] = 3.0
    v = np.zeros((2, d))
    v[:, :2] = 1.0
    apart = Scene(horizon, d)
    apart.upsert_many(["a", "b"], p, v, np.zeros((2, d)), np.ones(2), 1)
    apart.predictions()
    apart.compile_ordering()
    _stream(d, horizon, spacing=1e3)


def warm_scene_rows(dimensions: int, horizon: float) -> None:
    """Run the scene's kernels that evaluate pairs and store records (``Scene.
    compile_evaluation``): they call the solver and nothing of ``parts``, so they compile as
    soon as ``narrow`` is, beside the rest of ``parts``."""
    scene = Scene(horizon, dimensions)
    scene.upsert_many(["a", "b"], np.eye(2, dimensions), np.zeros((2, dimensions)),
                      np.zeros((2, dimensions)), np.ones(2), 1)
    scene.compile_evaluation()


def _stream(d: int, horizon: float, spacing: float) -> None:
    """A stream of single states, bodies arriving one by one ``spacing`` apart: the compiled
    query passes, including the specialisations for the read-only arrays a published
    prediction leaves."""
    stream = Scene(horizon, d)
    for k in range(12):
        p = np.zeros((1, d))
        p[0, 0] = spacing * (k % 6)
        stream.merge([f"s{k % 6}"], [10 + k], p, np.eye(1, d), np.zeros((1, d)), [1.0], [False],
                     0)
        stream.predictions()


def warm_scenes(dimensions: int, horizon: float, threaded: bool = False,
                large: bool = True) -> None:
    """Run the scene's kernels once on tiny scenes: a two-body frame, a stream of one-body
    updates and (``large``) a 100-body frame, the vectorised path of frames of
    ``Scene.COMPILED_ROWS`` pairs or more; ``threaded``: with the threaded twins forced."""
    with threads_forced(threaded):
        _two_bodies(dimensions, horizon)
        _stream(dimensions, horizon, spacing=0.5)
        if large:
            warm_large_frames(dimensions, horizon)


def warm_large_frames(dimensions: int, horizon: float) -> None:
    """A rebuild (a tracker array, an epoch crossing) of ``Scene.COMPILED_ROWS`` pairs or more,
    which runs the vectorised kernels: 100 overlapping bodies."""
    d, k = dimensions, 100
    rows = np.random.default_rng(0).uniform(0.0, 1.0, (k, d))
    crowd = Scene(horizon, d)
    crowd.upsert_many([f"w{i:03d}" for i in range(k)], rows, np.zeros((k, d)), np.zeros((k, d)),
                      np.ones(k), 1)
    crowd.predictions()


def warm_uncertain(dimensions: int, horizon: float, threshold: float = 0.01,
                   threaded: bool = False) -> None:
    """Run the probability-of-contact kernels once (and the fallbacks a tiny scene may not
    reach); ``threaded``: with the threaded twins forced."""
    d = dimensions
    with threads_forced(threaded):
        # without a budget, then with a budget of 0, which defers every pair to the cheap
        # intervals (core.uncertainty.interval): a fresh scene, as answers are kept
        for budget in (None, 0):
            scene = _two_bodies(d, horizon)
            scene.merge(["a"], [2], np.eye(1, d), np.zeros((1, d)), np.zeros((1, d)), [1.0],
                        [False], 0, covariances=np.eye(2 * d)[None] * 0.01)
            scene.uncertain_pairs(threshold, scene.predictions(), max_evaluated=budget)
        load_fallback_kernels(d)


_MODULE = "circle_collision_ros.core.warm_up"
CORE_JOBS: dict[str, Job] = {
    "narrow": Job(_narrow, (), _MODULE),
    "parts": Job(warm_scene_parts, (), _MODULE),
    "batch": Job(_batch, (), _MODULE),
    "rows": Job(warm_scene_rows, ("narrow",), _MODULE),
    "exact": Job(lambda d, h: warm_scenes(d, h, large=False), ("narrow", "parts", "rows"),
                 _MODULE),
    "large": Job(warm_large_frames, ("exact", "batch"), _MODULE),
    "threads": Job(lambda d, h: warm_scenes(d, h, threaded=True), ("large",), _MODULE),
    "uncertain": Job(warm_uncertain, ("exact",), _MODULE),
}


# What marks a module numba compiles from: one that defines a kernel or an overload.  The
# orchestration (this module, pipeline/kernels.py, the predictor) calls kernels but is not
# compiled, so editing it keeps the cache.
_COMPILED_SOURCE = re.compile(rb"njit|register_jitable|@overload|@intrinsic|objmode|@jit\b")


def source_hash() -> str:
    """Hash of the modules numba compiles from (core and pipeline) and of numba's version."""
    import numba

    h = hashlib.sha256(f"{numba.__version__} {sys.version} {_PACKAGE}".encode())
    for path in sorted([*(_PACKAGE / "core").rglob("*.py"), *(_PACKAGE / "pipeline").glob("*.py")]):
        data = path.read_bytes()
        if _COMPILED_SOURCE.search(data) and path != Path(__file__).resolve():
            h.update(path.relative_to(_PACKAGE).as_posix().encode())
            h.update(data)
    return h.hexdigest()[:16]


def _stamps() -> Path:
    import numba

    root = Path(numba.config.CACHE_DIR) if numba.config.CACHE_DIR else _PACKAGE / "__pycache__"
    return root / "kernel_stamps"


def _stamp(job: str, dimensions: int, digest: str) -> Path:
    return _stamps() / f"{job}-{dimensions}d-{digest}"


def is_compiled(job: str, dimensions: int, digest: str | None = None) -> bool:
    """Whether ``job`` was compiled for ``dimensions`` from the current sources."""
    return _stamp(job, dimensions, digest or source_hash()).exists()


@contextmanager
def _locked(path: Path) -> Iterator[None]:
    """Hold an exclusive lock on ``path``, waiting for it; unlocked where no lock file can be
    made (a read-only install: then numba caches elsewhere or not at all)."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(path, os.O_CREAT | os.O_RDWR, 0o666)
    except OSError:
        yield
        return
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)  # releases the lock


def _drop_stale_caches(digest: str) -> None:
    """After a source change, delete numba's cache files of the package (and the old stamps).

    numba checks only the source file of the function it loads, so a kernel cached before a
    change in a module it calls would be reused: every kernel is compiled afresh instead."""
    with _locked(_stamps() / "drop.lock"):
        stale = [f for f in _stamps().glob("*-*d-*")
                 if not f.name.endswith((digest, digest + ".lock"))]
        if not stale:
            return
        import numba

        roots = [_PACKAGE, *([Path(numba.config.CACHE_DIR)] if numba.config.CACHE_DIR else [])]
        for f in [*(c for r in roots for c in r.rglob("*.nb[ic]")), *stale]:
            try:
                f.unlink()
            except OSError:
                pass


def with_dependencies(names: Iterable[str], jobs: Mapping[str, Job]) -> list[str]:
    """``names`` and every job they build on, each once, dependencies first."""
    out: list[str] = []

    def visit(name: str) -> None:
        if name not in out:
            for dep in jobs[name].after:
                visit(dep)
            out.append(name)

    for name in names:
        visit(name)
    return out


def compile_jobs(names: Iterable[str], dimensions: Iterable[int], jobs: Mapping[str, Job],
                 processes: int | None = None, log: Callable[[str], None] | None = None) -> float:
    """Compile ``names`` (and the jobs they build on) for each of ``dimensions`` into numba's
    cache, each in its own process, up to ``processes`` at a time (default: the cores this
    process may use), a job once those it builds on are done (3-D after 2-D: most kernels
    take the same types).  Jobs already stamped are skipped; a job another process is
    compiling is waited for.  Returns the wall time, s; raises RuntimeError naming the job
    whose process failed, with its output."""
    from concurrent.futures import FIRST_COMPLETED, ThreadPoolExecutor, wait

    started = time.monotonic()
    digest = source_hash()
    dims = sorted(set(dimensions))
    todo = [(n, d) for d in dims for n in with_dependencies(names, jobs)]
    pending = [j for j in todo if not is_compiled(*j, digest)]
    if not pending:
        return 0.0
    _drop_stale_caches(digest)
    if log:
        log(f"compiling the numba kernels ({', '.join(f'{n} {d}-D' for n, d in pending)}) in "
            "parallel processes: the first start after an install or a code change; later "
            "starts load them from the cache")

    def run(job: tuple[str, int]) -> subprocess.CompletedProcess | None:
        name, d = job
        stamp = _stamp(name, d, digest)
        with _locked(stamp.with_name(stamp.name + ".lock")):
            if stamp.exists():  # another process compiled it while this one waited
                return None
            cmd = [sys.executable, "-m", jobs[name].module, "--job", name, "--dimensions", str(d)]
            result = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                    text=True)
            if result.returncode == 0:
                try:
                    stamp.touch()
                except OSError:
                    pass
            return result

    limit = processes or len(os.sched_getaffinity(0))
    running: dict = {}
    with ThreadPoolExecutor(max_workers=limit) as pool:
        while pending or running:
            waiting_on = {*pending, *running.values()}
            for job in list(pending):
                if len(running) >= limit:
                    break
                deps = [(dep, job[1]) for dep in jobs[job[0]].after]
                deps += [(job[0], 2)] if job[1] == 3 else []
                if not any(dep in waiting_on for dep in deps):
                    pending.remove(job)
                    running[pool.submit(run, job)] = job
            done, _ = wait(running, return_when=FIRST_COMPLETED)
            for future in done:
                job = running.pop(future)
                result = future.result()
                if result is not None and result.returncode != 0:
                    for other in running:
                        other.cancel()
                    raise RuntimeError(f"compiling the {job[0]} kernels ({job[1]}-D) failed "
                                       f"(exit {result.returncode}):\n{result.stdout[-4000:]}")
    seconds = time.monotonic() - started
    if log:
        log(f"kernels compiled in {seconds:.0f} s")
    return seconds


def main(argv: list[str] | None = None, jobs: Mapping[str, Job] = CORE_JOBS,
         prog: str = f"python -m {_MODULE}") -> int:
    """Command line: compile jobs (default: all of ``jobs``, both dimensions)."""
    parser = argparse.ArgumentParser(
        prog=prog, description="Compile numba kernels into their on-disk cache (what a node "
                               "start, the demo or the tests would otherwise compile at their "
                               "first call).")
    parser.add_argument("--jobs", nargs="+", choices=list(jobs), default=list(jobs),
                        help="what to compile (and what it builds on); default: everything")
    parser.add_argument("--dimensions", nargs="+", type=int, choices=(2, 3), default=[2, 3])
    parser.add_argument("--processes", type=int, default=None,
                        help="processes at a time (default: cores)")
    parser.add_argument("--job", choices=list(jobs), help=argparse.SUPPRESS)  # one, in-process
    opts = parser.parse_args(argv)
    if opts.job:  # a compile process: run the job's kernels once (compiling or loading them)
        for d in opts.dimensions:
            jobs[opts.job].run(d, 5.0)
        return 0
    try:
        seconds = compile_jobs(opts.jobs, opts.dimensions, jobs, opts.processes,
                               log=lambda s: print(f"kernels: {s}", flush=True))
    except RuntimeError as exc:
        print(f"kernels: {exc}", file=sys.stderr)
        return 1
    if not seconds:
        print("kernels: every requested job is compiled (numba's cache is current)", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
