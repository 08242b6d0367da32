"""ego_ids through CollisionPredictor and the service rule.

Guarantees proved here: with ego_ids, the published rows (pairs and static contacts) are
exactly the all-pairs rows that involve an ego body, in the same order and bit for bit; the
stateless service refuses an ego id that is not among its circles.
"""
from __future__ import annotations

import numpy as np

from circle_collision_ros.core.static import Segments, StaticIndex, StaticWorld
from circle_collision_ros.pipeline.predictor import (CollisionPredictor, PredictorConfig,
                                                     predict_once)
from circle_collision_ros.pipeline.state_batch import StateBatch
from tests.node_helpers import random_states

T0 = 1_700_000_000 * 1_000_000_000
INDEX = StaticIndex.build(StaticWorld.build([Segments(
    "wall", np.array([[-25.0, -25.0], [25.0, -25.0]]), np.array([[25.0, -25.0], [25.0, 25.0]]))]))


def _frame(n: int, seed: int) -> StateBatch:
    rng = np.random.default_rng(seed)
    # b003 heads for the wall at x = 25 every frame; the rest move at random
    z = np.zeros((n, 1))
    position = np.hstack([rng.uniform(-20, 20, (n, 2)), z])
    velocity = np.hstack([rng.normal(0, 3, (n, 2)), z])
    position[3], velocity[3] = (20.0, 0.0, 0.0), (3.0, 0.0, 0.0)
    return StateBatch(ids=[f"b{k:03d}" for k in range(n)], frames=["map"] * n,
                      stamp_ns=np.full(n, T0 + seed, np.int64), radius=rng.uniform(0.3, 1.5, n),
                      position=position, velocity=velocity,
                      acceleration=np.hstack([rng.normal(0, 0.3, (n, 2)), z]),
                      remove=np.zeros(n, bool))


def test_ego_rows_are_the_all_pairs_rows_with_an_ego_body() -> None:
    ego = ("b003", "b017", "b999")  # b999 never arrives
    everyone = CollisionPredictor(PredictorConfig(horizon=5.0, frame_id="map"))
    egos = CollisionPredictor(PredictorConfig(horizon=5.0, frame_id="map", ego_ids=ego))
    for p in (everyone, egos):
        p.set_static(INDEX)
    compared = 0
    static_rows = 0
    for seed in range(6):
        frame = _frame(120, seed)
        rows = []
        for p in (everyone, egos):
            p.receive_batch(frame, T0 + seed)
            rows.append(list(p.predict().rows()))
        expected = [r for r in rows[0] if r.id_a in ego or r.id_b in ego]
        assert rows[1] == expected
        static_rows += sum(r.id_b == "wall" for r in rows[1])
        assert any(r.id_b == "wall" and r.id_a not in ego for r in rows[0])
        compared += len(expected)
    assert compared > 10 and static_rows > 0
    assert egos._scene.evaluated_pairs < everyone._scene.evaluated_pairs / 10  # noqa: SLF001


def test_the_service_takes_ego_ids() -> None:
    states = random_states(30, seed=2)
    config = PredictorConfig(horizon=5.0)
    ok, message, everyone = predict_once(states, config, request_time_ns=T0)
    assert ok, message
    ok, message, ego = predict_once(states, config, request_time_ns=T0, ego_ids=["b004"])
    assert ok, message
    assert list(ego.rows()) == [r for r in everyone.rows() if "b004" in (r.id_a, r.id_b)]
    ok, message, _ = predict_once(states, config, request_time_ns=T0, ego_ids=["nobody"])
    assert not ok and "'nobody'" in message
