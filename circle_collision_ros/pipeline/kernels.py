"""Compile the numba kernels a node needs, before it subscribes, in parallel processes.

The node must never meet a cold compile in the middle of a stream, so it prepares
every path its configuration lets a message reach, and only those:

* ``exact`` and ``messages`` always (the scene's serial kernels, decoding and encoding);
* ``large`` when ``max_bodies`` lets a frame have ``Scene.COMPILED_ROWS`` pairs or more;
* ``threads`` when ``max_bodies`` lets a frame reach the parallel policy's thresholds;
* ``uncertain`` (and ``uncertain_threads`` with threads) unless ``use_covariance`` is off.

The core's jobs (``core.warm_up``: ``narrow``, ``parts``, ``rows``, ``batch``,
``exact``, ``large``, ``threads``, ``uncertain``) need no ROS, so a set-up step can compile
them while the interfaces build; this module adds the jobs that touch the
message types.  A cold start
compiles in separate processes (one per core), each writing numba's cache, then
loads everything in the calling process; a warm start only loads.
``scripts/test.sh`` compiles every job first (``python -m
circle_collision_ros.pipeline.kernels``), so the test workers and the nodes they
start compile nothing.
"""
from __future__ import annotations

import sys
from collections.abc import Callable

from circle_collision_ros.core import warm_up as _core
from circle_collision_ros.core.warm_up import (Job, compile_jobs, large_frames_reachable,
                                               threads_reachable)
from circle_collision_ros.pipeline.predictor import CollisionPredictor, PredictorConfig

__all__ = ["JOBS", "paths_for", "prepare", "main"]

_MODULE = "circle_collision_ros.pipeline.kernels"


def _predictor_path(path: str) -> Callable[[int, float], None]:
    def run(dimensions: int, horizon: float) -> None:
        predictor = CollisionPredictor(PredictorConfig(dimensions=dimensions, horizon=horizon))
        predictor.warm_up(paths=(path,))
    return run


def _codec(dimensions: int, horizon: float) -> None:
    predictor = CollisionPredictor(PredictorConfig(dimensions=dimensions, horizon=horizon))
    predictor.warm_up_codec()


#: Every compile job: the core's, with ``threads`` and ``uncertain`` replaced by their
#: message-path versions, plus ``codec`` (decoders and encoders on bodies that are never a
#: candidate pair, beside ``exact``), ``messages`` and ``uncertain_threads``.
JOBS: dict[str, Job] = {
    **_core.CORE_JOBS,
    "codec": Job(_codec, ("parts",), _MODULE),
    "messages": Job(_predictor_path("messages"), ("exact", "codec"), _MODULE),
    "threads": Job(_predictor_path("threads"), ("large", "messages"), _MODULE),
    "uncertain": Job(_predictor_path("uncertain"), ("exact", "messages"), _MODULE),
    "uncertain_threads": Job(_predictor_path("uncertain_threads"), ("uncertain", "threads"),
                             _MODULE),
}


def paths_for(config: PredictorConfig) -> tuple[str, ...]:
    """The warm-up paths a node with ``config`` can reach (see the module docstring)."""
    threads = threads_reachable(config.max_bodies)
    paths = ["exact", "messages"] + (["large"] if large_frames_reachable(config.max_bodies)
                                     else []) + (["threads"] if threads else [])
    if config.use_covariance:
        paths += ["uncertain"] + (["uncertain_threads"] if threads else [])
    return tuple(paths)


def prepare(predictor: CollisionPredictor, log: Callable[[str], None] | None = None,
            processes: int | None = None) -> tuple[str, ...]:
    """Make the paths ``predictor``'s configuration reaches ready in this process: compile
    those not yet in numba's cache in parallel processes (saying so through ``log``), then
    run ``predictor.warm_up`` here, which loads them.  Returns the paths."""
    paths = paths_for(predictor.config)
    compile_jobs(paths, (predictor.config.dimensions,), JOBS, processes, log)
    predictor.warm_up(paths)
    return paths


def main(argv: list[str] | None = None) -> int:
    """``python -m circle_collision_ros.pipeline.kernels``: compile every job (or ``--jobs``)."""
    return _core.main(argv, JOBS, prog=f"python -m {_MODULE}")


if __name__ == "__main__":
    sys.exit(main())
