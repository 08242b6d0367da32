"""Completing a prediction's deferred uncertain pairs later (core.scene.complete_uncertainty).

Guarantees proved here:
- the completion of a budgeted call equals, bit for bit, the same scene's call without a
  budget: tracker frames (every body restamped) and per-body streams (pairs evaluated at their
  own pair time t_p < R), 2-D and 3-D; no row is left deferred;
- it is a pure function of the call's result: computed after the scene has moved on (new
  states, new predictions), it gives the same bits as right away;
- nothing deferred: the result is returned as it is;
- with a pause and threads, each free thread takes the next step: a thread held in its pause
  delays no step, and the answer does not wait for it to return.
"""
from __future__ import annotations

import threading

import numpy as np
import pytest

from circle_collision_ros.core.scene import Scene, complete_uncertainty
from tests.core.scene.test_scene_uncertain import _batch, _merge_batch, _same

BUDGET = 2


def _scenes(dimensions: int):
    return Scene(5.0, dimensions, method="grid"), Scene(5.0, dimensions, method="grid")


def _frames(seed: int, frames: int = 3):
    batch = _batch(18, seed=seed, sigma=0.4, spread=7.0)
    for k in range(frames):
        yield batch.__class__(**{**batch.__dict__, "stamp_ns": batch.stamp_ns + k * 33_000_000,
                                 "position": batch.position + k * 0.033 * batch.velocity})


@pytest.mark.parametrize("dimensions", [2, 3])
def test_completion_of_tracker_frames_equals_the_unbudgeted_scene(dimensions) -> None:
    budgeted, everything = _scenes(dimensions)
    deferred = 0
    for batch in _frames(seed=21):
        for scene in (budgeted, everything):
            _merge_batch(scene, batch)
        u = budgeted.uncertain_pairs(0.01, budgeted.predictions(), BUDGET)
        full = everything.uncertain_pairs(0.01, everything.predictions())
        deferred += u.deferred
        done = complete_uncertainty(u)
        assert done.deferred_rows is None and done.pending is None
        _same(done, full)
        assert done.id_utf8 is u.id_utf8 and done.contact_rows is u.contact_rows
    assert deferred > 3 * BUDGET


@pytest.mark.parametrize("dimensions", [2, 3])
def test_completion_of_a_stream_equals_the_unbudgeted_scene(dimensions) -> None:
    """One body at a time, each 7 ms after the last: most pairs' time t_p lies before R, and
    the deferred ones wait in the budget's FIFO across calls."""
    batch = _batch(18, seed=5, sigma=0.4, spread=7.0)
    budgeted, everything = _scenes(dimensions)
    for scene in (budgeted, everything):
        _merge_batch(scene, batch)
    lagged = 0
    for step in range(1, 13):
        k = (5 * step) % len(batch)
        moved = batch.__class__(**{**batch.__dict__, "stamp_ns": batch.stamp_ns + step * 7_000_000,
                                   "position": batch.position + 0.007 * step * batch.velocity})
        for scene in (budgeted, everything):
            _merge_batch(scene, moved, [k])
        u = budgeted.uncertain_pairs(0.01, budgeted.predictions(), BUDGET)
        full = everything.uncertain_pairs(0.01, everything.predictions())
        if u.pending is not None:
            lagged += int(np.count_nonzero(u.pending.lag > 0))
        _same(complete_uncertainty(u), full)
    assert lagged > 0


def test_completion_is_a_pure_function_of_the_result() -> None:
    frames = list(_frames(seed=8, frames=4))
    scene = Scene(5.0, 2, method="grid")
    _merge_batch(scene, frames[0])
    u = scene.uncertain_pairs(0.01, scene.predictions(), BUDGET)
    assert u.deferred > 0
    now = complete_uncertainty(u)
    for batch in frames[1:]:  # the scene moves on: new states, new evaluations
        _merge_batch(scene, batch)
        scene.uncertain_pairs(0.01, scene.predictions(), BUDGET)
    _same(complete_uncertainty(u), now)
    assert complete_uncertainty(now) is now


def test_nothing_deferred_is_returned_as_it_is() -> None:
    scene = Scene(5.0, 2, method="grid")
    _merge_batch(scene, next(_frames(seed=3, frames=1)))
    u = scene.uncertain_pairs(0.01, scene.predictions())
    assert u.pending is None and complete_uncertainty(u) is u


def test_steps_with_a_pause_give_the_same_bits() -> None:
    """With a pause (the node's way to step aside), rows go in steps of COMPLETION_STEP, the
    pause is called before each, and the answer is the same, also split over threads."""
    from concurrent.futures import ThreadPoolExecutor

    from circle_collision_ros.core.scene.uncertain import COMPLETION_STEP

    scene = Scene(5.0, 2, method="grid")
    batch = _batch(40, seed=13, sigma=0.5, spread=6.0)
    _merge_batch(scene, batch)
    u = scene.uncertain_pairs(0.01, scene.predictions(), 1)
    assert u.pending.rows.size > 2 * COMPLETION_STEP
    calls = []
    plain = complete_uncertainty(u)
    with ThreadPoolExecutor(2) as pool:
        for executor, parts in ((None, 1), (pool, 2)):
            calls.clear()
            stepped = complete_uncertainty(u, executor, parts, lambda: calls.append(1))
            _same(stepped, plain)
            assert len(calls) >= -(-u.pending.rows.size // COMPLETION_STEP)


def test_a_thread_held_in_its_pause_delays_no_step() -> None:
    """The node lets one thread go on beside its busy prediction path and holds the other:
    the free thread takes every step, and the answer does not wait for the held one."""
    from concurrent.futures import ThreadPoolExecutor

    from circle_collision_ros.core.scene.uncertain import COMPLETION_STEP

    scene = Scene(5.0, 2, method="grid")
    _merge_batch(scene, _batch(40, seed=13, sigma=0.5, spread=6.0))
    u = scene.uncertain_pairs(0.01, scene.predictions(), 1)
    assert u.pending.rows.size > 2 * COMPLETION_STEP
    release = threading.Event()
    held = []
    lock = threading.Lock()

    def pause() -> None:  # the first thread to ask is held until the answer is in
        with lock:
            hold = not held
            if hold:
                held.append(threading.get_ident())
        if hold:
            assert release.wait(60.0)

    with ThreadPoolExecutor(2) as pool:
        try:
            done = complete_uncertainty(u, pool, 2, pause)
        finally:
            release.set()
    _same(done, complete_uncertainty(u))
    assert held  # one thread was held throughout
