"""pipeline.kernels: which warm-up paths a node prepares, and that they suffice.

Guarantees proved here:
- a node prepares the exact and message paths always, the vectorised path of large frames
  only when max_bodies allows Scene.COMPILED_ROWS pairs, the threaded twins only when
  max_bodies lets a frame reach the parallel policy's thresholds, and the probability path
  only when use_covariance is on;
- every warm-up path has a compile job, and a node's paths with their dependencies compile
  nothing the jobs left out: after prepare, a predictor of that configuration runs frames
  of every kind it accepts without compiling a kernel (numba's dispatchers gain no
  signature);
- the ``codec`` job reaches the decoders and encoders and no kernel that evaluates a pair,
  so it compiles beside ``exact``.
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from numba.core.registry import CPUDispatcher

from circle_collision_ros.core.scene import Scene
from circle_collision_ros.pipeline import kernels
from circle_collision_ros.pipeline.predictor import (WARM_UP_PATHS, CollisionPredictor,
                                                     PredictorConfig)
from circle_collision_ros.pipeline.state_batch import StateBatch


def test_paths_follow_the_configuration() -> None:
    assert kernels.paths_for(PredictorConfig()) == (
        "exact", "messages", "large", "threads", "uncertain", "uncertain_threads")
    assert kernels.paths_for(PredictorConfig(max_bodies=40)) == ("exact", "messages", "uncertain")
    assert kernels.paths_for(PredictorConfig(max_bodies=40, use_covariance=False)) == (
        "exact", "messages")
    assert kernels.paths_for(PredictorConfig(use_covariance=False)) == (
        "exact", "messages", "large", "threads")
    n = next(k for k in range(2, 1000) if k * (k - 1) // 2 >= Scene.COMPILED_ROWS)
    assert "large" not in kernels.paths_for(PredictorConfig(max_bodies=n - 1))
    assert "large" in kernels.paths_for(PredictorConfig(max_bodies=n))
    assert set(WARM_UP_PATHS) <= set(kernels.JOBS)


def _signatures() -> int:
    import gc

    # type(), not isinstance(): gc also lists dead weak proxies, whose __class__ raises
    return sum(len(o.signatures) for o in gc.get_objects() if type(o) is CPUDispatcher)


def _batch(n: int, t: int, covariance: bool) -> StateBatch:
    rng = np.random.default_rng(n)
    p = np.zeros((n, 3))
    p[:, :2] = rng.uniform(0.0, 8.0, (n, 2))
    v = np.zeros((n, 3))
    v[:, :2] = rng.normal(0.0, 1.0, (n, 2))
    cov = np.zeros((n, 36))
    cov[:, ::7] = 0.04
    return StateBatch(ids=[f"b{k}" for k in range(n)], frames=["map"] * n,
                      stamp_ns=np.full(n, t, np.int64), radius=np.full(n, 0.4), position=p,
                      velocity=v, acceleration=np.zeros((n, 3)), remove=np.zeros(n, bool),
                      covariance=cov if covariance else None,
                      covariance_size=np.full(n, 36, np.int64) if covariance else None)


def test_a_prepared_demo_node_compiles_nothing_on_its_frames() -> None:
    """The demo's configuration (40 bodies, no covariance): after prepare, frames of every
    size it accepts, one-body updates and states that carry covariance (dropped) compile no
    new kernel specialisation."""
    config = PredictorConfig(frame_id="map", max_bodies=40, use_covariance=False)
    predictor = CollisionPredictor(config)
    assert kernels.prepare(predictor) == ("exact", "messages")
    before = _signatures()
    t = 1_000_000_000
    for n, covariance in ((2, False), (40, False), (40, True), (1, False)):
        t += 10_000_000
        report = predictor.receive_batch(_batch(n, t, covariance), t)
        assert report.covariance_ignored == (n if covariance else 0)
        predictor.predict().to_cdr()
    assert _signatures() == before


_CODEC_PROBE = """
import gc
from numba.core.registry import CPUDispatcher
from circle_collision_ros.pipeline.predictor import CollisionPredictor, PredictorConfig
CollisionPredictor(PredictorConfig(dimensions={d})).warm_up_codec()
print(sorted(o.py_func.__name__ for o in gc.get_objects()
             if type(o) is CPUDispatcher and o.signatures))
"""


@pytest.mark.parametrize("d", [2, 3])
def test_codec_job_evaluates_no_pair(d: int) -> None:
    """In a fresh interpreter, warm_up_codec loads (or compiles) the state decoders and the
    prediction encoders, and no solver or kernel that calls it."""
    out = subprocess.run([sys.executable, "-c", _CODEC_PROBE.format(d=d)], capture_output=True,
                         text=True, check=True, cwd=Path(kernels.__file__).parents[2]).stdout
    loaded = set(eval(out.strip().splitlines()[-1]))
    assert {"_decode_states", "_encode_contacts", "_encode_predictions"} <= loaded
    assert not loaded & {"ttc_scalar", "ttc_scalar2", "certified_pair2", "certified_pair3",
                         "evaluate_rows", "evaluate_and_store", "ordered_query"}


def test_a_prepared_covariance_node_compiles_nothing_when_its_budget_defers() -> None:
    """With covariance and a budget of one full evaluation, frames whose other uncertain pairs
    are deferred to the cheap intervals compile no new kernel after prepare."""
    config = PredictorConfig(frame_id="map", max_bodies=40, uncertain_pair_budget=1)
    predictor = CollisionPredictor(config)
    assert kernels.prepare(predictor) == ("exact", "messages", "uncertain")
    before = _signatures()
    t = 1_000_000_000
    for n in (40, 2, 40):
        t += 10_000_000
        predictor.receive_batch(_batch(n, t, True), t)
        prediction = predictor.predict()
        prediction.to_cdr()
    assert prediction.uncertainty.deferred > 0
    assert _signatures() == before
