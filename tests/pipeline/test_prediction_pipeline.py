"""CollisionPredictor: the node's path from messages to predictions, without a ROS graph.

Guarantees proved here:
- predictions equal the core narrow phase on every pair of the scene propagated
  to the newest stamp (bitwise-equal times);
- every bad-input class is rejected with a reason naming the field, and the
  good states of the same message are still used;
- latest state wins by stamp (late and duplicated states are ignored);
  removal, expiry and max_bodies behave as documented;
- the same inputs in the same order give bit-identical outputs.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from circle_collision_msgs.msg import CollisionPrediction
from circle_collision_ros.pipeline.predictor import (CollisionPredictor, IntakeReport,
                                                     PredictorConfig, predict_once)
from circle_collision_ros.pipeline.state_batch import StateBatch
from tests.node_helpers import (BASE_NS, assert_no_nan, contacts_of, expected_contacts,
                                random_states, state)

NOW = BASE_NS + 10_000_000


def receive(
    predictor: CollisionPredictor, states, now_ns: int, array_frame: str = ""
) -> IntakeReport:
    """One received message of CircleState objects (the node's receive_batch path)."""
    return predictor.receive_batch(StateBatch.from_messages(states, array_frame), now_ns)


def test_matches_core_on_every_pair() -> None:
    states = random_states(60, seed=3)
    predictor = CollisionPredictor(PredictorConfig(horizon=5.0))
    report = receive(predictor, states, NOW)
    assert report.accepted == 60 and not report.rejected
    out = predictor.predict().to_message()
    want = expected_contacts(states, 5.0)
    assert want, "scene should have contacts"
    assert contacts_of(out) == want
    times = [p.time_to_collision for p in out.predictions]
    assert times == sorted(times)
    assert out.header.stamp.sec * 10**9 + out.header.stamp.nanosec == max(
        s.header.stamp.sec * 10**9 + s.header.stamp.nanosec for s in states
    )
    assert_no_nan(out)


def test_three_d_scene_matches_core() -> None:
    states = random_states(40, seed=5, dimensions=3, spread=10.0)
    predictor = CollisionPredictor(PredictorConfig(horizon=4.0, dimensions=3))
    receive(predictor, states, NOW)
    assert contacts_of(predictor.predict().to_message()) == expected_contacts(
        states, 4.0, dimensions=3
    )


def test_two_d_mode_ignores_z() -> None:
    a = state("a", (0, 0, 100.0), (1, 0, 0))
    b = state("b", (5, 0, -100.0))
    predictor = CollisionPredictor(PredictorConfig(horizon=10.0))
    receive(predictor, [a, b], NOW)
    (p,) = predictor.predict().to_message().predictions
    assert p.time_to_collision == 4.0 and p.contact_point.z == 0.0


def test_overlapping_status_and_details() -> None:
    predictor = CollisionPredictor(PredictorConfig(horizon=10.0))
    receive(
        predictor,
        [state("a", (0, 0), r=1.0), state("b", (1.5, 0), r=1.0),
         state("c", (10, 0), (-1, 0, 0), r=1.0)],
        NOW,
    )
    out = {(p.id_a, p.id_b): p for p in predictor.predict().to_message().predictions}
    assert out[("a", "b")].status == CollisionPrediction.OVERLAPPING
    assert out[("a", "b")].time_to_collision == 0.0
    bc = out[("b", "c")]
    assert bc.status == CollisionPrediction.CONTACT and bc.time_to_collision == pytest.approx(6.5)
    assert (bc.normal.x, bc.normal.y) == pytest.approx((1.0, 0.0))
    assert bc.closing_speed == pytest.approx(1.0)
    assert bc.contact_point.x == pytest.approx(2.5)
    stamp_ns = bc.contact_time.sec * 10**9 + bc.contact_time.nanosec
    assert stamp_ns == BASE_NS + 6_500_000_000


@pytest.mark.parametrize(
    "mutate, reason",
    [
        (lambda s: setattr(s.position, "x", math.nan), "position.x is nan"),
        (lambda s: setattr(s.velocity, "y", math.inf), "velocity.y is inf"),
        (lambda s: setattr(s.acceleration, "z", -math.inf), "acceleration.z is -inf"),
        (lambda s: setattr(s, "radius", math.nan), "radius is nan"),
        (lambda s: setattr(s, "radius", -0.5), "radius is negative"),
        (lambda s: setattr(s, "id", ""), "empty id"),
        (
            lambda s: setattr(s.header, "frame_id", "odom"),
            "frame 'odom' is not the scene frame 'map'",
        ),
        (
            lambda s: (setattr(s.header.stamp, "sec", 0), setattr(s.header.stamp, "nanosec", 0)),
            "header.stamp is zero",
        ),
        (lambda s: setattr(s.header.stamp, "sec", s.header.stamp.sec + 3600), "in the future"),
    ],
    ids=["nan", "inf", "neg-inf", "nan-radius", "negative-radius", "empty-id", "wrong-frame",
         "zero-stamp", "future-stamp"],
)
def test_bad_state_rejected_rest_predicted(mutate, reason) -> None:
    states = [state("a", (0, 0), (1, 0, 0)), state("b", (5, 0)), state("bad", (2.5, 3), (0, -1, 0))]
    mutate(states[2])
    predictor = CollisionPredictor(PredictorConfig(frame_id="map", horizon=10.0))
    report = receive(predictor, states, NOW)
    assert report.accepted == 2 and len(report.rejected) == 1
    assert reason in report.rejected[0].reason and report.rejected[0].index == 2
    out = predictor.predict().to_message()
    assert contacts_of(out) == {("a", "b"): 4.0}
    assert_no_nan(out)


def test_duplicate_ids_in_one_message_are_all_rejected() -> None:
    predictor = CollisionPredictor(PredictorConfig())
    report = receive(predictor, [state("a", (0, 0)), state("a", (9, 9)), state("b", (3, 0))], NOW)
    assert report.accepted == 1 and [r.body_id for r in report.rejected] == ["a", "a"]
    assert "more than once" in report.rejected[0].reason


def test_empty_message_changes_nothing() -> None:
    predictor = CollisionPredictor(PredictorConfig())
    report = receive(predictor, [], NOW)
    assert not report.changed
    assert predictor.predict().to_message().predictions == []


def test_first_frame_is_adopted_then_enforced() -> None:
    predictor = CollisionPredictor(PredictorConfig(frame_id=""))
    receive(predictor, [state("a", (0, 0), frame="odom")], NOW)
    report = receive(predictor, [state("b", (0, 0), frame="map")], NOW)
    assert (
        predictor.frame_id == "odom" and "not the scene frame 'odom'" in report.rejected[0].reason
    )


def test_latest_stamp_wins_and_late_states_are_ignored() -> None:
    predictor = CollisionPredictor(PredictorConfig(horizon=100.0))
    receive(predictor, [state("a", (0, 0), (1, 0, 0), stamp_ns=BASE_NS), state("b", (10, 0))], NOW)
    late = receive(predictor, [state("a", (0, 0), (-1, 0, 0), stamp_ns=BASE_NS - 1)], NOW)
    dup = receive(predictor, [state("a", (0, 0), (1, 0, 0), stamp_ns=BASE_NS)], NOW)
    assert late.ignored == 1 and dup.ignored == 1 and not late.changed and not dup.changed
    assert contacts_of(predictor.predict().to_message()) == {("a", "b"): 9.0}


def test_states_are_propagated_to_the_newest_stamp() -> None:
    # a was seen 2 s before b: at b's stamp a has moved 2 m, so contact is 2 s sooner.
    predictor = CollisionPredictor(PredictorConfig(horizon=100.0))
    receive(
        predictor,
        [
            state("a", (0, 0), (1, 0, 0), stamp_ns=BASE_NS - 2_000_000_000),
            state("b", (10, 0), stamp_ns=BASE_NS),
        ],
        NOW,
    )
    assert contacts_of(predictor.predict().to_message()) == {("a", "b"): 7.0}


def test_removal_and_expiry() -> None:
    predictor = CollisionPredictor(PredictorConfig(stale_timeout=1.0))
    receive(predictor, [state("a", (0, 0)), state("b", (1, 0))], NOW)
    report = receive(predictor, [state("a", (0, 0), stamp_ns=BASE_NS + 1, remove=True)], NOW)
    assert report.removed == 1 and "a" not in predictor
    report = receive(predictor, [], NOW + 1_500_000_000)
    assert report.expired == ["b"] and len(predictor) == 0
    assert not receive(
        predictor, [state("zz", (0, 0), stamp_ns=BASE_NS + 2, remove=True)], NOW
    ).changed


def test_max_bodies_bounds_the_scene() -> None:
    predictor = CollisionPredictor(PredictorConfig(max_bodies=10))
    report = receive(predictor, random_states(25, seed=1), NOW)
    assert report.accepted == 10 and len(report.rejected) == 15
    assert "scene is full" in report.rejected[0].reason


def test_report_all_pairs_lists_no_contact_pairs_without_nan() -> None:
    predictor = CollisionPredictor(PredictorConfig(report_all_pairs=True, horizon=1.0))
    receive(predictor, random_states(12, seed=9, spread=30.0), NOW)
    out = predictor.predict().to_message()
    assert len(out.predictions) == 12 * 11 // 2
    none = [p for p in out.predictions if p.status == CollisionPrediction.NO_CONTACT]
    assert none and all(p.time_to_collision == math.inf for p in none)
    assert_no_nan(out)


def test_same_inputs_give_bit_identical_outputs() -> None:
    runs = []
    for _ in range(2):
        predictor = CollisionPredictor(PredictorConfig())
        outs = []
        for k in range(5):
            receive(
                predictor, random_states(30, seed=k, stamp_ns=BASE_NS + k * 33_000_000), NOW + k
            )
            outs.append(predictor.predict().to_message())
        runs.append(outs)
    assert runs[0] == runs[1]  # message equality compares float fields exactly


def test_predict_once_names_the_bad_circle() -> None:
    states = [state("a", (0, 0)), state("b", (5, 0), r=-1.0)]
    ok, message, out = predict_once(states, PredictorConfig())
    assert not ok and out is None
    assert message.startswith("circles[1] (id 'b'): radius is negative")
    ok, message, out = predict_once(
        [state("a", (0, 0), (1, 0, 0)), state("b", (5, 0))], PredictorConfig(), horizon=10.0
    )
    assert ok and contacts_of(out.to_message()) == {("a", "b"): 4.0}


def test_late_state_after_removal_is_ignored() -> None:
    """A state older than the body's removal must not bring it back."""
    predictor = CollisionPredictor(PredictorConfig(horizon=5.0))
    receive(predictor, [state("a", (0, 0), r=1.0), state("g", (3, 0), (-1, 0, 0), r=1.0)], NOW)
    assert contacts_of(predictor.predict().to_message()) == {("a", "g"): 1.0}
    removal = receive(
        predictor, [state("g", (0, 0), stamp_ns=BASE_NS + 200_000_000, remove=True)], NOW
    )
    assert removal.removed == 1 and predictor.predict().to_message().predictions == []
    late = receive(
        predictor, [state("g", (2.9, 0), (-1, 0, 0), r=1.0, stamp_ns=BASE_NS + 100_000_000)], NOW
    )
    assert late.accepted == 0 and late.ignored == 1 and not late.changed
    assert predictor.predict().to_message().predictions == [] and "g" not in predictor
    newer = receive(
        predictor, [state("g", (2.7, 0), (-1, 0, 0), r=1.0, stamp_ns=BASE_NS + 300_000_000)], NOW
    )
    assert newer.accepted == 1 and "g" in predictor  # a newer state is a new track


def test_removal_memory_is_kept_for_stale_timeout() -> None:
    predictor = CollisionPredictor(PredictorConfig(stale_timeout=1.0))
    receive(
        predictor, [state(f"r{k}", (0, 0), stamp_ns=BASE_NS, remove=True) for k in range(100)], NOW
    )
    late = receive(predictor, [state("r1", (0, 0), stamp_ns=BASE_NS - 1)], NOW + 500_000_000)
    assert late.ignored == 1 and late.accepted == 0
    # One stale_timeout (receive clock) after the removals they are forgotten: memory stays bounded.
    predictor.expire(NOW + 1_000_000_001)
    assert predictor._scene.remembered_removals == 0
    report = receive(predictor, [state("r1", (0, 0), stamp_ns=BASE_NS - 1)], NOW + 1_000_000_001)
    assert report.accepted == 1


def test_max_bodies_counts_after_removals_in_the_same_message() -> None:
    """Full scene (3 of 3), one message [remove g, add h] must accept h."""
    predictor = CollisionPredictor(PredictorConfig(max_bodies=3))
    receive(predictor, [state("a", (0, 0)), state("b", (5, 0)), state("g", (10, 0))], NOW)
    report = receive(
        predictor,
        [
            state("g", (0, 0), stamp_ns=BASE_NS + 1, remove=True),
            state("h", (20, 0), stamp_ns=BASE_NS + 1),
        ],
        NOW,
    )
    assert not report.rejected, report.rejected
    assert (report.removed, report.accepted) == (1, 1) and "h" in predictor and len(predictor) == 3
    full = receive(predictor, [state("i", (30, 0), stamp_ns=BASE_NS + 2)], NOW)
    assert "scene is full" in full.rejected[0].reason


def test_one_body_updates_equal_full_recomputation_and_fresh_predictor() -> None:
    """Per-body streams (each state its own message, newer interleaved stamps): every output
    equals a full recomputation, and the last one equals, byte for byte, a fresh predictor
    given the final states in one message; it also matches the brute-force rule."""
    states = random_states(80, seed=11, spread=15.0)
    live = CollisionPredictor(PredictorConfig(horizon=4.0))
    receive(live, states, NOW)
    live.predict()
    current = {s.id: s for s in states}
    for k, s in enumerate(random_states(80, seed=12, spread=15.0)[:40]):
        s.header.stamp.nanosec += 1_000_000 * (k % 7) + 50_000_000
        current[s.id] = s
        receive(live, [s], NOW + k)
        out, full = live.predict().contacts, live._scene.full_recomputation()
        assert out.id_a.tolist() == full.id_a.tolist() and out.id_b.tolist() == full.id_b.tolist()
        assert np.array_equal(out.ttc, full.ttc) and np.array_equal(out.contact_ns, full.contact_ns)
    fresh = CollisionPredictor(PredictorConfig(horizon=4.0))
    receive(fresh, list(current.values()), NOW + 100)
    final = live.predict()
    assert final.to_cdr() == fresh.predict().to_cdr()
    assert contacts_of(final.to_message()) == expected_contacts(list(current.values()), 4.0)
    assert len(final.contacts) > 10


def test_one_state_validation_on_scalars_equals_the_vectorised_checks() -> None:
    """A one-state message is checked on Python scalars (state_validation.clean_single_state) and
    falls back to the vectorised checks whenever anything might be wrong: over random clean and
    bad single states (each bad-input class, removals, frames, stamps) check_batch gives the same
    verdict, reasons and adopted frame as for the same state checked in a two-state batch."""
    from circle_collision_ros.pipeline.state_validation import check_batch, clean_single_state

    rng = np.random.default_rng(3)
    bad_values = [math.nan, math.inf, -math.inf, 2e12, -2e12, -1.0]
    fast_taken = 0
    for k in range(400):
        s = state(rng.choice(["a", "", "körper"]), rng.uniform(-5, 5, 3), rng.uniform(-2, 2, 3),
                  rng.uniform(-1, 1, 3), r=float(rng.uniform(0, 2)),
                  stamp_ns=int(rng.choice([NOW, NOW + 2_000_000_000, 0, -5, NOW - 10**9])),
                  frame=str(rng.choice(["map", "odom", ""])), remove=bool(rng.random() < 0.2))
        if rng.random() < 0.5:
            field = rng.choice(["radius", "position", "velocity", "acceleration"])
            value = float(rng.choice(bad_values))
            if field == "radius":
                s.radius = value
            else:
                setattr(getattr(s, field), str(rng.choice(["x", "y", "z"])), value)
        # a removal beside it: never adopts a frame, so row 0 is judged as when alone
        other = state("zz_other", (0.0, 0.0, 0.0), stamp_ns=NOW, frame="", remove=True)
        frame = str(rng.choice(["", "map"]))
        now = None if rng.random() < 0.2 else NOW
        one = StateBatch.from_messages([s])
        fast_taken += clean_single_state(one, frame, now) is not None
        got = check_batch(one, frame_id=frame, now_ns=now)
        want = check_batch(StateBatch.from_messages([s, other]), frame_id=frame, now_ns=now)
        assert bool(got.good[0]) == bool(want.good[0]), (k, s)
        assert [(r.index, r.body_id, r.reason) for r in got.rejections] == [
            (r.index, r.body_id, r.reason) for r in want.rejections if r.index == 0
        ], (k, s)
        if got.good[0] and not s.remove:
            assert got.frame_id == (frame or s.header.frame_id)
        assert not got.uncertain[0]
    assert 40 < fast_taken < 360  # both paths exercised


#: A fresh process that warms up, then lists each kernel compiled or loaded afterwards.
_AFTER_WARM_UP = """
import numpy as np
import numba.core.dispatcher as dispatcher
from circle_collision_ros.pipeline.predictor import CollisionPredictor, PredictorConfig
CollisionPredictor(PredictorConfig(dimensions={d})).warm_up()
loaded = []
original = dispatcher.Dispatcher._compile_for_args
def spy(self, *args, **kwargs):
    loaded.append(self.py_func.__name__)
    return original(self, *args, **kwargs)
dispatcher.Dispatcher._compile_for_args = spy
"""

_FIRST_REBUILD = (
    _AFTER_WARM_UP
    + """
from circle_collision_ros.core.scene import Scene
k = 120  # a rebuild of k (k - 1) / 2 = 7,140 overlapping pairs: the vectorised, threaded path
scene = Scene(5.0, {d})
scene.upsert_many([f"b{{i}}" for i in range(k)], np.random.default_rng(1).uniform(0, 1, (k, {d})),
                  np.zeros((k, {d})), np.zeros((k, {d})), np.ones(k), 10**18)
assert len(scene.predictions()) == k * (k - 1) // 2
print("loaded:", loaded)
"""
)


@pytest.mark.parametrize("dimensions", [2, 3])
def test_warm_up_loads_the_large_scene_kernels(dimensions) -> None:
    """CollisionPredictor.warm_up (the node calls it at start) also loads the kernels of a large
    rebuild (vectorised, threaded: a tracker array, an epoch crossing), so the first such cycle
    pays no numba cache load (~0.15 s; seconds where the cache is stale). Fresh process: earlier
    tests must not have loaded them."""
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-c", _FIRST_REBUILD.format(d=dimensions)],
                         capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    assert "loaded: []" in out.stdout, out.stdout


_FIRST_MESSAGES = (
    _AFTER_WARM_UP
    + """
from dataclasses import replace
from itertools import product
from circle_collision_msgs.msg import CircleState, CircleStateArray
from circle_collision_ros.core.parallel_policy import threads_forced
from circle_collision_ros.pipeline.state_codec import (
    decode_states, encode_state, encode_state_array)
from circle_collision_ros.pipeline.state_batch import StateBatch
rng = np.random.default_rng(3)
n, t = 40, 1_700_000_000 * 10**9
cov = np.zeros((n, 36))
cov[:, ::7] = rng.uniform(0.0, 0.05, (n, 6))
for threaded, uncertain, report_all in product((False, True), repeat=3):
    with threads_forced(threaded):  # large frames take the threaded twins
        batch = StateBatch(ids=[f"robot_{{k}}" for k in range(n)], frames=["odom"] * n,
                           stamp_ns=np.full(n, t, np.int64), radius=rng.uniform(0.2, 1.0, n),
                           position=rng.uniform(-10, 10, (n, 3)), velocity=rng.normal(0, 1, (n, 3)),
                           acceleration=rng.normal(0, 0.2, (n, 3)), remove=np.zeros(n, dtype=bool),
                           covariance=cov if uncertain else None,
                           covariance_size=np.full(n, 36, np.int64) if uncertain else None)
        node = CollisionPredictor(PredictorConfig(dimensions={d}, frame_id="odom",
                                                  report_all_pairs=report_all))
        node.receive_batch(decode_states(encode_state_array(batch, t, "odom"), CircleStateArray), t)
        node.predict().to_cdr()
        for k in range(5):
            one = replace(batch.select(np.array([k])), stamp_ns=np.array([t + k + 1], np.int64))
            node.receive_batch(decode_states(encode_state(one), CircleState), t + k + 1)
            node.predict().to_cdr()
# a first prediction with no contact (bodies far apart), as a node's often is
lonely = CollisionPredictor(PredictorConfig(dimensions={d}, frame_id="odom"))
lonely.receive_batch(
    decode_states(encode_state_array(batch.select(np.array([0])), t, "odom"), CircleStateArray),
    t,
)
assert len(lonely.predict().contacts) == 0
lonely.predict().to_cdr()
print("loaded:", loaded)
"""
)


@pytest.mark.parametrize("dimensions", [2, 3])
def test_warm_up_loads_the_message_path_kernels(dimensions) -> None:
    """After CollisionPredictor.warm_up the node's message path (decode of CircleStateArray and
    CircleState, exact and with covariance; prediction; both output encoders) compiles and loads
    nothing: left to the first messages, a fresh install's node answered 2 of 180 inputs of
    bench/bench_node.py's first scenario. Fresh process: earlier tests must not have loaded them."""
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-c", _FIRST_MESSAGES.format(d=dimensions)],
                         capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    assert "loaded: []" in out.stdout, out.stdout
