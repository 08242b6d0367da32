"""Static rows of a prediction: incremental equals recomputed, bit for bit.

Guarantees proved here (pipeline/static_scene.py, StaticCache):
- on a stream of per-body updates with older stamps, removals and epoch changes, the rows
  of an incremental predictor equal a recomputation from the same stored states (a cache
  that has seen nothing), bit for bit, and equal the rule applied by hand (evaluate at
  t_b = max(E, T) over H + S, shift by R - t_b, re-evaluate at R a contact that began
  before it);
- a one-body update evaluates that body alone; a tracker frame evaluates every body.
"""
from __future__ import annotations

import math

import numpy as np

from circle_collision_ros.core.scene.store import propagate_ns
from circle_collision_ros.core.static import Polygon, Segments, StaticIndex, StaticWorld
from circle_collision_ros.core.static import time_to_static
from circle_collision_ros.pipeline.predictor import CollisionPredictor, PredictorConfig
from circle_collision_ros.pipeline.static_scene import StaticCache, StaticRows
from circle_collision_ros.pipeline.state_batch import StateBatch

T0 = 1_700_000_000 * 1_000_000_000
WORLD = StaticWorld.build([
    Segments("wall", np.array([[-20.0, -20.0], [20.0, -20.0]]),
             np.array([[20.0, -20.0], [20.0, 20.0]])),
    Polygon("crate", np.array([[2.0, 2.0], [5.0, 2.0], [5.0, 4.0], [2.0, 4.0]])),
])
INDEX = StaticIndex.build(WORLD)


def _batch(ids, stamps, P, V, A, R, remove=None) -> StateBatch:
    n = len(ids)
    z = np.zeros((n, 1))
    return StateBatch(ids=list(ids), frames=["map"] * n, stamp_ns=np.asarray(stamps, np.int64),
                      radius=np.asarray(R, float), position=np.hstack([P, z]),
                      velocity=np.hstack([V, z]), acceleration=np.hstack([A, z]),
                      remove=np.zeros(n, bool) if remove is None else np.asarray(remove))


def _rows(st):
    return None if st is None else (st.id_a, st.id_b, st.ttc.tobytes(),
                                    st.contact_ns.tobytes(), st.point.tobytes(),
                                    st.normal.tobytes(), st.closing_speed.tobytes())


def _fresh(predictor: CollisionPredictor) -> StaticRows:
    """The same scene's rows from a cache that has seen nothing (a full recomputation)."""
    scene = predictor._scene  # noqa: SLF001 - test oracle
    return StaticCache().rows(scene.stored_states(), scene.reference_ns, scene.epoch_ns,
                              scene.slack, predictor.config.horizon, INDEX)


def _by_hand(predictor: CollisionPredictor) -> dict:
    """The rule of StaticCache written out per body."""
    scene = predictor._scene  # noqa: SLF001 - test oracle
    ids, P, V, A, R, T = scene.stored_states()
    ref, E, S, H = scene.reference_ns, scene.epoch_ns, scene.slack, predictor.config.horizon
    out = {}
    for k, body in enumerate(ids):
        tb = max(E, int(T[k]))
        p, v = propagate_ns(P[k:k + 1, :2], V[k:k + 1, :2], A[k:k + 1, :2],
                            np.array([tb - T[k]]))
        tau = time_to_static(p, v, A[k:k + 1, :2], R[k:k + 1], INDEX, H + S).time[0]
        d = (ref - tb) * 1e-9
        if tb == ref:
            ttc = tau
        elif tau > d:
            ttc = tau - d
        else:
            p, v = propagate_ns(P[k:k + 1, :2], V[k:k + 1, :2], A[k:k + 1, :2],
                                np.array([ref - T[k]]))
            ttc = time_to_static(p, v, A[k:k + 1, :2], R[k:k + 1], INDEX, H).time[0]
        if ttc <= H:
            out[body] = ttc
    return out


def test_incremental_equals_recomputed_and_the_rule() -> None:
    rng = np.random.default_rng(3)
    n = 60
    predictor = CollisionPredictor(PredictorConfig(horizon=4.0, frame_id="map",
                                                   stale_timeout=1e6))
    predictor.set_static(INDEX)
    ids = [f"b{k:02d}" for k in range(n)]
    P = rng.uniform(-15, 15, (n, 2))
    V = rng.normal(0, 3, (n, 2))
    A = rng.normal(0, 0.5, (n, 2))
    R = rng.uniform(0.1, 0.8, n)
    predictor.ingest(_batch(ids, np.full(n, T0), P, V, A, R), None)
    first = predictor.predict()
    assert predictor._static_cache.evaluated == n  # noqa: SLF001
    assert first.static is not None and len(first.static) > 5
    now = T0
    checked = 0
    for step in range(80):
        now += int(rng.integers(5, 400)) * 1_000_000  # crosses epochs (S = 1 s)
        k = int(rng.integers(0, n))
        if step % 17 == 5:
            predictor.ingest(_batch([ids[k]], [now], P[k:k + 1], V[k:k + 1], A[k:k + 1],
                                    R[k:k + 1], remove=[True]), None)
        else:
            P[k] = rng.uniform(-15, 15, 2)
            predictor.ingest(_batch([ids[k]], [now], P[k:k + 1], V[k:k + 1], A[k:k + 1],
                                    R[k:k + 1]), None)
        prediction = predictor.predict()
        assert predictor._static_cache.evaluated <= len(predictor)  # noqa: SLF001
        assert _rows(prediction.static) == _rows(_fresh(predictor))
        hand = _by_hand(predictor)
        got = dict(zip(prediction.static.id_a, prediction.static.ttc.tolist()))
        assert got.keys() == hand.keys() and all(got[b] == hand[b] for b in hand)
        checked += len(got)
    assert checked > 200


def test_a_one_body_update_evaluates_that_body_alone() -> None:
    n = 200
    rng = np.random.default_rng(4)
    predictor = CollisionPredictor(PredictorConfig(horizon=4.0, frame_id="map"))
    predictor.set_static(INDEX)
    ids = [f"b{k:03d}" for k in range(n)]
    P, V = rng.uniform(-15, 15, (n, 2)), rng.normal(0, 3, (n, 2))
    A, R = np.zeros((n, 2)), np.full(n, 0.3)
    predictor.ingest(_batch(ids, np.full(n, T0), P, V, A, R), None)
    predictor.predict()
    # a newer stamp in the same epoch: one body changed, the others keep their answers
    predictor.ingest(_batch([ids[7]], [T0 + 10_000_000], P[7:8] + 0.5, V[7:8], A[7:8], R[7:8]),
                     None)
    predictor.predict()
    assert predictor._static_cache.evaluated == 1  # noqa: SLF001
    # a tracker frame: every body
    predictor.ingest(_batch(ids, np.full(n, T0 + 20_000_000), P + 0.1, V, A, R), None)
    predictor.predict()
    assert predictor._static_cache.evaluated == n  # noqa: SLF001
    assert math.isfinite(predictor.config.horizon)


def test_a_new_world_is_answered_with_unchanged_bodies() -> None:
    """The cache holds the index it answered: bodies that did not move are answered
    against a new world (also when the old index is freed and its id() reused)."""
    predictor = CollisionPredictor(PredictorConfig(horizon=4.0, frame_id="map"))
    n = 3
    P = np.array([[0.0, 0.0], [0.0, 5.0], [0.0, -5.0]])
    V = np.array([[1.0, 0.0], [1.0, 0.0], [1.0, 0.0]])
    predictor.ingest(_batch(["a", "b", "c"], np.full(n, T0), P, V, np.zeros((n, 2)),
                            np.full(n, 0.5)), None)
    for x in (2.0, 3.0, 2.5, 3.5):  # each world replaces (and frees) the previous index
        wall = StaticWorld.build([Segments("w", np.array([[x, -10.0]]), np.array([[x, 10.0]]))])
        predictor.set_static(StaticIndex.build(wall))
        rows = predictor.predict().static
        assert rows.id_a == ["a", "b", "c"] and (rows.ttc == x - 0.5).all()
