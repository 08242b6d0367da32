"""The completion thread of collision_node (node/probabilities.py), without DDS.

Guarantees proved here:
- a prediction with deferred rows is published completed: the bytes a budget-0 predictor
  publishes for the same input; one with nothing deferred is republished as it is; each is
  recorded with the log time it was offered with;
- latest wins: a prediction replaced before the thread takes it is never published, and is
  counted; the exact path's offer never waits for a completion in progress;
- a completion published when a newer prediction had been offered is counted late, one
  published before is not; ``lag_problem`` reports a period in which none was published while
  predictions were superseded, and nothing else (the node's /diagnostics WARN);
- close() publishes what was offered before it; a failing publish is reported and the next
  prediction is still completed;
- while the node is busy the completion waits, but for one thread beside a narrow prediction
  path (node/activity.py): a completion offered then is published before the path is idle;
  that thread runs at BESIDE_NICE, the others at NICE (Linux);
- every step of the evaluation runs inside ``NodeActivity.completing()``, so the marker thread
  steps aside for it (tests/node/test_activity.py), and nothing is held after it.
"""
from __future__ import annotations

import contextlib
import os
import threading
import time

import pytest

from circle_collision_ros.node.probabilities import ProbabilityPublisher, lag_problem
from circle_collision_ros.pipeline.predictor import CollisionPredictor, PredictorConfig
from tests.core.scene.test_scene_uncertain import BASE, _batch


def _prediction(budget: int, seed: int = 9):
    predictor = CollisionPredictor(PredictorConfig(stale_timeout=3600.0,
                                                   uncertain_pair_budget=budget))
    predictor.receive_batch(_batch(16, seed=seed, sigma=0.4, spread=7.0), BASE)
    return predictor.predict()


@pytest.mark.parametrize("overtaken", [False, True], ids=["in_turn", "overtaken"])
def test_completed_bytes_log_times_and_lateness(overtaken, monkeypatch) -> None:
    """In turn, each prediction is published before the next is offered: none late.
    Overtaken, the first prediction's evaluation is held (the node is busy, a wide period)
    until the next has been offered: the first is published late, the second is not."""
    from circle_collision_ros.node.activity import NodeActivity

    taken = threading.Event()

    class Recording(NodeActivity):
        def pause(self, beside: bool = False, completions: bool = False) -> None:
            taken.set()  # the thread holds the first prediction: it cannot be superseded now
            super().pause(beside, completions)

    monkeypatch.setattr(NodeActivity, "MAX_PAUSE_S", 60.0)  # beyond the waits below
    activity = Recording()
    published, recorded = [], []
    worker = ProbabilityPublisher(published.append, lambda d, t: recorded.append((d, t)),
                                  activity=activity)
    try:
        part, full = _prediction(2), _prediction(0)
        assert part.deferred and not full.deferred
        with activity.busy() if overtaken else contextlib.nullcontext():
            worker.offer(part, part.to_cdr(), 11)
            assert taken.wait(30.0) if overtaken else worker.wait_idle(30.0)
            worker.offer(full, b"as published", 12)
        assert worker.wait_idle(30.0)
    finally:
        worker.close()
    assert published == [full.to_cdr(), b"as published"]
    assert recorded == [(full.to_cdr(), 11), (b"as published", 12)]
    assert worker.completed == 1 and worker.published == 2
    assert worker.late == int(overtaken) and worker.superseded == 0


def test_lag_problem_only_when_a_period_published_nothing_it_was_given() -> None:
    assert lag_problem(0, 0, 0) is None and lag_problem(30, 0, 0) is None
    # a fast per-body stream: most completions late and many superseded, yet published in time
    assert lag_problem(300, 200, 100) is None
    # one completion outlasted the period while three predictions were offered
    assert lag_problem(0, 0, 3) == ("collision_probabilities falls behind the inputs: 0 of 0 "
                                    "completions came after the next prediction, 3 predictions "
                                    "got none")


def test_latest_wins_and_the_offer_never_waits() -> None:
    gate = threading.Event()
    published = []

    def slow_publish(data: bytes) -> None:
        gate.wait(10.0)
        published.append(data)

    worker = ProbabilityPublisher(slow_publish)
    try:
        p = _prediction(0)
        worker.offer(p, b"first", 1)
        time.sleep(0.1)  # the thread holds "first" in publish
        started = time.monotonic()
        for k in range(5):
            worker.offer(p, f"later {k}".encode(), 2 + k)
        assert time.monotonic() - started < 0.05
        gate.set()
        assert worker.wait_idle(10.0)
    finally:
        worker.close()
    assert published == [b"first", b"later 4"]
    assert worker.superseded == 4


def test_close_publishes_what_was_offered_and_errors_are_reported() -> None:
    errors, published = [], []
    calls = iter([RuntimeError("link down")])

    def flaky(data: bytes) -> None:
        failure = next(calls, None)
        if failure is not None:
            raise failure
        published.append(data)

    worker = ProbabilityPublisher(flaky, on_error=errors.append)
    p = _prediction(0)
    worker.offer(p, b"lost", 1)
    assert worker.wait_idle(10.0)
    worker.offer(p, b"kept", 2)
    worker.close()
    assert published == [b"kept"]
    assert len(errors) == 1 and "link down" in errors[0] and "at 1 ns" in errors[0]


@pytest.mark.parametrize("budget", [1, 3])
def test_completion_is_the_unbudgeted_prediction(budget) -> None:
    assert _prediction(budget, seed=4).completed().to_cdr() == _prediction(0, seed=4).to_cdr()


@pytest.mark.parametrize("narrow", [False, True], ids=["wide", "narrow"])
def test_completion_steps_aside_while_the_node_is_busy(narrow, monkeypatch) -> None:
    """A wide busy period (the first: nothing known yet) holds every step; in a narrow one (the
    previous period's kernels wanted no threads) one thread goes on, and the completion is
    published while the path is still busy."""
    from circle_collision_ros.node.activity import NodeActivity

    if narrow and ProbabilityPublisher.PARTS < 2:
        pytest.skip("one core: nothing goes on beside the prediction path")
    monkeypatch.setattr(NodeActivity, "MAX_PAUSE_S", 60.0)  # beyond the waits below
    activity = NodeActivity()
    if narrow:
        with activity.busy():
            pass
    published = []
    worker = ProbabilityPublisher(published.append, activity=activity)
    try:
        part = _prediction(2)
        full = _prediction(0).to_cdr()
        with activity.busy():
            worker.offer(part, part.to_cdr(), 1)
            assert worker.wait_idle(30.0 if narrow else 0.3) == narrow
            assert published == ([full] if narrow else [])
        assert worker.wait_idle(30.0)
    finally:
        worker.close()
    assert published == [full]


@pytest.mark.skipif(not hasattr(os, "getpriority"), reason="per-thread niceness: Linux")
def test_the_thread_beside_runs_at_the_lowest_priority() -> None:
    from circle_collision_ros.core.scene.uncertain import COMPLETION_STEP
    from circle_collision_ros.node.activity import NodeActivity

    if ProbabilityPublisher.PARTS < 2:
        pytest.skip("one core: nothing goes on beside the prediction path")
    seen = set()

    class Recording(NodeActivity):
        def pause(self, beside: bool = False) -> None:
            seen.add((beside, os.getpriority(os.PRIO_PROCESS, threading.get_native_id())))
            super().pause(beside)

    predictor = CollisionPredictor(PredictorConfig(stale_timeout=3600.0, uncertain_pair_budget=1))
    predictor.receive_batch(_batch(40, seed=13, sigma=0.5, spread=6.0), BASE)
    part = predictor.predict()
    # steps enough that the second thread starts before the first has taken them all
    assert part.uncertainty.pending.rows.size > 4 * COMPLETION_STEP
    worker = ProbabilityPublisher(lambda data: None, activity=Recording())
    try:
        worker.offer(part, part.to_cdr(), 1)
        assert worker.wait_idle(60.0)
    finally:
        worker.close()
    assert seen == {(True, ProbabilityPublisher.BESIDE_NICE), (False, ProbabilityPublisher.NICE)}


def test_markers_step_aside_for_the_evaluation() -> None:
    from circle_collision_ros.node.activity import NodeActivity

    states = []

    class Recording(NodeActivity):
        def pause(self, beside: bool = False, completions: bool = False) -> None:
            states.append(self.completions_running)
            super().pause(beside, completions)

    activity = Recording()
    worker = ProbabilityPublisher(lambda data: None, activity=activity)
    try:
        part = _prediction(2)
        worker.offer(part, part.to_cdr(), 1)
        assert worker.wait_idle(30.0)
    finally:
        worker.close()
    assert states and all(states)  # each step of rows, from each thread
    assert not activity.completions_running
