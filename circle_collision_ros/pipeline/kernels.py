"""Compile the numba kernels a node needs, before it subscribes, in parallel processes.

The node must never meet a cold compile in the middle of a stream, so it prepares
every path its configuration lets a message reach, and only those:

* ``exact`` and ``messages`` always (the scene's serial kernels, decoding and encoding);
* ``large`` when ``max_bodies`` lets a frame have ``Scene.COMPILED_ROWS`` pairs or more;
* ``threads`` when ``max_bodies`` lets a frame reach the parallel policy's thresholds;
* ``uncertain`` (and ``uncertain_threads`` with threads) unless ``use_covariance`` is off;
* ``static`` when the node has static inputs (a map, polygons): the static index, the query
  and its rows in a message, so neither the first map nor the first prediction against it
  meets a compile.

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
from circle_collision_ros.core.parallel_policy import threads_forced
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


def _static(dimensions: int, horizon: float) -> None:
    """Index a tiny world (a map, a polygon, a wall) and predict against it (2-D only)."""
    if dimensions != 2:
        return
    import numpy as np

    from circle_collision_ros.core.static import (GridFrame, OccupancyMap, Polygon, Segments,
                                                  StaticIndex, StaticWorld)

    occupied = np.zeros((8, 8), bool)
    occupied[0, :] = occupied[3:5, 3] = True
    world = StaticWorld.build([
        OccupancyMap("map", occupied, GridFrame(0.5)),
        Polygon("box", np.array([[10.0, 0.0], [11.0, 0.0], [11.0, 1.0]])),
        Segments("wall", np.array([[-3.0, -3.0]]), np.array([[-3.0, 3.0]]))])
    index = StaticIndex.build(world)
    for threaded in (False, True):  # the query's serial and threaded twins
        with threads_forced(threaded):
            _static_frame(index, horizon)


def _static_frame(index, horizon: float) -> None:
    import numpy as np

    from circle_collision_ros.pipeline.state_batch import StateBatch

    predictor = CollisionPredictor(PredictorConfig(dimensions=2, horizon=horizon,
                                                   frame_id="map", use_covariance=False))
    predictor.set_static(index)
    n, t = 4, 1_000_000_000
    position = np.array([[1.0, 2.0, 0.0], [9.0, 0.5, 0.0], [-2.0, 0.0, 0.0], [2.0, 2.0, 0.0]])
    velocity = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    acceleration = np.zeros((n, 3))
    acceleration[0, 0] = 0.1  # the accelerating path of the edge kernel
    predictor.receive_batch(StateBatch(
        ids=["a", "b", "c", "d"], frames=["map"] * n, stamp_ns=np.full(n, t, np.int64),
        radius=np.full(n, 0.25), position=position, velocity=velocity,
        acceleration=acceleration, remove=np.zeros(n, bool)), t)
    predictor.predict().to_cdr()


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
    "static": Job(_static, ("messages",), _MODULE),
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
            processes: int | None = None, static: bool = False) -> tuple[str, ...]:
    """Make the paths ``predictor``'s configuration reaches ready in this process: compile
    those not yet in numba's cache in parallel processes (saying so through ``log``), then
    run ``predictor.warm_up`` here, which loads them (``static``: the static geometry path
    too).  Returns the paths."""
    paths = paths_for(predictor.config)
    extra = ("static",) if static and predictor.config.dimensions == 2 else ()
    compile_jobs(paths + extra, (predictor.config.dimensions,), JOBS, processes, log)
    predictor.warm_up(paths)
    if extra:
        _static(predictor.config.dimensions, predictor.config.horizon)
    return paths + extra


def main(argv: list[str] | None = None) -> int:
    """``python -m circle_collision_ros.pipeline.kernels``: compile every job (or ``--jobs``)."""
    return _core.main(argv, JOBS, prog=f"python -m {_MODULE}")


if __name__ == "__main__":
    sys.exit(main())
