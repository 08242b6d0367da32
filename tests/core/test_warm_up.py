"""core.warm_up's compile orchestration, with real processes (tests/core/warm_up_jobs.py).

Guarantees proved here:
- a job runs after every job it builds on has ended, and independent jobs run side by side;
- a job already stamped for the current sources is not run again;
- two preparers started together (a set-up step and a node, two test workers) run each job
  once: the second waits on the job's lock and finds the stamp;
- a failing job raises RuntimeError naming the job and carrying its output;
- threads_reachable follows the parallel policy's smallest threshold;
- the ``parts`` job never reaches the solver or a kernel that calls it, so it can compile
  beside ``narrow``; the ``rows`` job reaches nothing of ``parts``, so it can compile beside
  it once ``narrow`` is done; their direct calls compile the types the scene calls.
"""
from __future__ import annotations

import os
import subprocess
import sys
import threading

import numba
import pytest

from circle_collision_ros.core import warm_up
from circle_collision_ros.core.warm_up import (compile_jobs, is_compiled, threads_reachable,
                                               with_dependencies)
from tests.core.warm_up_jobs import JOBS


@pytest.fixture
def job_log(tmp_path, monkeypatch):
    """A private stamp folder (numba's cache dir is read for it) and the jobs' log file."""
    monkeypatch.setattr(numba.config, "CACHE_DIR", str(tmp_path / "cache"))
    log = tmp_path / "jobs.log"
    monkeypatch.setenv("WARM_UP_TEST_LOG", str(log))
    return log


def _events(log):
    rows = [line.split() for line in log.read_text().splitlines()]
    return [(name, int(d), what, float(t)) for name, d, what, t in rows]


def test_dependencies_first_each_once() -> None:
    assert with_dependencies(["top"], JOBS) == ["base", "left", "right", "top"]
    assert with_dependencies(["right", "left"], JOBS) == ["base", "right", "left"]


def test_jobs_run_after_what_they_build_on_and_side_by_side(job_log) -> None:
    compile_jobs(["top"], [2], JOBS, processes=2)
    ev = _events(job_log)
    at = {(n, w): t for n, _, w, t in ev}
    assert sorted({n for n, *_ in ev}) == ["base", "left", "right", "top"]
    assert at["base", "end"] <= min(at["left", "start"], at["right", "start"])
    assert max(at["left", "end"], at["right", "end"]) <= at["top", "start"]
    # left and right ran side by side: each waited for the other to start (warm_up_jobs.py)
    assert all(is_compiled(n, 2) for n in ("base", "left", "right", "top"))
    job_log.write_text("")
    assert compile_jobs(["top"], [2], JOBS) == 0.0  # stamped: nothing runs
    assert job_log.read_text() == ""
    compile_jobs(["top"], [2, 3], JOBS, processes=2)  # only the 3-D jobs run
    assert {(n, d) for n, d, *_ in _events(job_log)} == {(n, 3) for n in JOBS if n != "broken"}


def test_concurrent_preparers_run_each_job_once(job_log) -> None:
    errors: list[BaseException] = []

    def prepare() -> None:
        try:
            compile_jobs(["top"], [2], JOBS, processes=2)
        except BaseException as exc:  # pragma: no cover - reported below
            errors.append(exc)

    threads = [threading.Thread(target=prepare) for _ in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(120)
    assert not errors
    starts = [n for n, _, what, _ in _events(job_log) if what == "start"]
    assert sorted(starts) == ["base", "left", "right", "top"]


def test_a_failing_job_is_named_with_its_output(job_log) -> None:
    with pytest.raises(RuntimeError, match=r"compiling the broken kernels \(2-D\) failed "
                                           r"\(exit 3\)"):
        compile_jobs(["broken"], [2], JOBS)
    assert is_compiled("base", 2) and not is_compiled("broken", 2)


def test_threads_reachable_at_the_policy_thresholds() -> None:
    smallest = min(warm_up.PARALLEL_MIN_ROWS, warm_up.PARALLEL_MIN_PAIRS,
                   warm_up.PARALLEL_MIN_CONTACTS)
    n = next(k for k in range(2, 10_000) if k * (k - 1) // 2 >= smallest)
    assert not threads_reachable(n - 1) and threads_reachable(n)
    assert threads_reachable(warm_up.PARALLEL_MIN_BODIES)


def test_source_hash_follows_compiled_modules_only(tmp_path, monkeypatch) -> None:
    """An edit of a module numba compiles from changes the hash (the cache is dropped); an
    edit of the orchestration that only calls kernels does not."""
    import shutil

    package = tmp_path / "circle_collision_ros"
    for part in ("core", "pipeline"):
        shutil.copytree(warm_up._PACKAGE / part, package / part,
                        ignore=shutil.ignore_patterns("__pycache__"))
    monkeypatch.setattr(warm_up, "_PACKAGE", package)
    base = warm_up.source_hash()
    for orchestration in ("pipeline/kernels.py", "pipeline/predictor.py"):
        with open(package / orchestration, "a") as f:
            f.write("\n# an edit\n")
        assert warm_up.source_hash() == base, orchestration
    with open(package / "core/narrow/batch.py", "a") as f:
        f.write("\n# an edit\n")
    assert warm_up.source_hash() != base


_PARTS_PROBE = """
from circle_collision_ros.core.narrow.batch import ttc_scalar, ttc_scalar2
from circle_collision_ros.core.scene import kernels
from circle_collision_ros.core.warm_up import warm_scene_parts
warm_scene_parts({d}, 5.0)
solver = [f.__name__ for f in (ttc_scalar, ttc_scalar2, kernels.evaluate_rows,
          kernels.evaluate_and_store, kernels.ordered_query) if f.signatures]
parts = [f.__name__ for f in (kernels.split_and_order, kernels.assemble, kernels.incremental_pairs)
         if f.signatures]
print(solver, parts)
"""


_ROWS_PROBE = """
from circle_collision_ros.core.scene import kernels
from circle_collision_ros.core.warm_up import warm_scene_rows
warm_scene_rows({d}, 5.0)
print([f.__name__ for f in (kernels.evaluate_rows, kernels.evaluate_and_store) if f.signatures],
      [f.__name__ for f in (kernels.split_and_order, kernels.assemble, kernels.incremental_pairs,
                            kernels.ordered_query) if f.signatures])
"""


@pytest.mark.parametrize("d", [2, 3])
def test_scene_rows_reach_no_part_of_the_parts_job(d: int) -> None:
    """The rows job loads the kernels that evaluate and store pairs, and nothing the parts job
    compiles (so it can run once ``narrow`` is done, beside ``parts``)."""
    out = subprocess.run([sys.executable, "-c", _ROWS_PROBE.format(d=d)], capture_output=True,
                         text=True, check=True, cwd=warm_up._PACKAGE.parent).stdout
    assert out.split("\n")[-2] == "['evaluate_rows', 'evaluate_and_store'] []"


@pytest.mark.parametrize("d", [2, 3])
def test_scene_parts_never_reach_the_solver(d: int) -> None:
    """In a fresh interpreter (no kernel loaded yet), the parts job's scenes load or compile
    the ordering and broad-phase kernels and not one kernel that calls the solver."""
    out = subprocess.run([sys.executable, "-c", _PARTS_PROBE.format(d=d)], capture_output=True,
                         text=True, check=True, cwd=warm_up._PACKAGE.parent).stdout
    assert out.split("\n")[-2] == "[] ['split_and_order', 'assemble', 'incremental_pairs']"


_SAME_TYPES_PROBE = """
import os
from circle_collision_ros.core import warm_up
from circle_collision_ros.core.scene import kernels
warm_up.warm_scene_parts({d}, 5.0)
warm_up.warm_scene_rows({d}, 5.0)
warm_up.warm_scenes({d}, 5.0, large=False)
print(*(len(f.signatures) for f in (kernels.split_and_order, kernels.assemble,
                                    kernels.evaluate_rows, kernels.evaluate_and_store)))
"""


@pytest.mark.stress  # compiles the scene from an empty cache: ~45 s of one core a dimension
@pytest.mark.parametrize("d", [2, 3])
def test_scene_parts_compile_the_types_the_scene_calls(tmp_path, d: int) -> None:
    """With an empty cache (every kernel compiled in this interpreter, so callees record
    their signatures), the direct calls of the parts and rows jobs and the scene's own calls
    give each kernel one specialisation: the exact job finds them compiled."""
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)}
    out = subprocess.run([sys.executable, "-c", _SAME_TYPES_PROBE.format(d=d)],
                         capture_output=True, text=True, check=True, env=env,
                         cwd=warm_up._PACKAGE.parent).stdout
    assert out.split("\n")[-2] == "1 1 1 1"
