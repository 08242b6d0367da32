"""NodeActivity (node/activity.py): when the node's side threads step aside.

Guarantees proved here:
- ``pause()`` waits while the prediction path is busy and returns once it is idle;
- ``pause(beside=True)`` returns at once while the busy period is narrow (the previous period's
  kernels did not want numba's threads) and waits like ``pause()`` while it is wide: in the
  first period, and after a period whose kernels had the work for threads, granted or not;
- ``pause(completions=True)`` (markers) also waits while a completion is evaluated
  (``completing()``, from any number of threads) and returns once none is; a completion's own
  steps (``pause()``) do not wait for it.
"""
from __future__ import annotations

import os
import threading
import time

import pytest

from circle_collision_ros.core import parallel_policy as pp
from circle_collision_ros.node.activity import NodeActivity


def _returns_within(call, seconds: float = 0.3) -> tuple[bool, threading.Thread]:
    """Whether call() on a thread returns within `seconds` (and that thread, to join)."""
    returned = threading.Event()
    side = threading.Thread(target=lambda: (call(), returned.set()))
    side.start()
    return returned.wait(seconds), side


def _pause_returns_during_busy(activity: NodeActivity, beside: bool) -> bool:
    """Whether a side thread's pause returns while the prediction path stays busy."""
    returned = threading.Event()
    with activity.busy():
        side = threading.Thread(target=lambda: (activity.pause(beside), returned.set()))
        side.start()
        during = returned.wait(0.3)
    side.join(5.0)
    assert returned.is_set()  # it returns once the path is idle, whatever else
    return during


@pytest.fixture
def activity(monkeypatch) -> NodeActivity:
    monkeypatch.setattr(NodeActivity, "MAX_PAUSE_S", 10.0)  # a wait is a wait, not a timeout
    return NodeActivity()


def test_pause_waits_while_busy(activity) -> None:
    assert not _pause_returns_during_busy(activity, beside=False)
    with activity.busy():
        pass  # a narrow period
    assert not _pause_returns_during_busy(activity, beside=False)
    started = time.monotonic()
    activity.pause()  # idle: at once
    assert time.monotonic() - started < 0.1


def test_beside_goes_on_only_beside_narrow_periods(activity) -> None:
    assert activity.wide  # nothing known yet: every core wanted
    assert not _pause_returns_during_busy(activity, beside=True)
    with activity.busy():
        pass  # no kernel wanted threads
    assert not activity.wide
    assert _pause_returns_during_busy(activity, beside=True)
    if len(os.sched_getaffinity(0)) < 2:
        pytest.skip("one core: no work is for threads")
    with activity.busy():
        # work for threads, granted or not (tests/core/test_parallel_policy.py: counted when
        # no core is free, as when a side thread holds it; else a side thread would keep the
        # kernels serial for good)
        pp.threads_pay(10**9, 1)
    assert activity.wide
    assert not _pause_returns_during_busy(activity, beside=True)


def test_markers_wait_for_completions(activity) -> None:
    assert not activity.completions_running
    with activity.completing():
        assert activity.completions_running
        during, side = _returns_within(lambda: activity.pause(completions=True))
        assert not during
        own, _ = _returns_within(activity.pause)  # a completion's own step: not held by it
        assert own
    side.join(5.0)
    assert not side.is_alive() and not activity.completions_running
    # two completions under way (overlapping, as from two threads): held until both end
    first, second = activity.completing(), activity.completing()
    first.__enter__()
    second.__enter__()
    first.__exit__(None, None, None)
    during, side = _returns_within(lambda: activity.pause(completions=True))
    assert not during
    second.__exit__(None, None, None)
    side.join(5.0)
    assert not side.is_alive()


def test_markers_wait_for_both_at_once(activity) -> None:
    """Held by a completion, then by the prediction path that starts as it ends: the marker
    step waits for the path too, not only for the flag it waited on first."""
    done = threading.Event()
    with activity.completing():
        during, side = _returns_within(lambda: (activity.pause(completions=True), done.set()))
        assert not during
        busy = activity.busy()
        busy.__enter__()
    assert not done.wait(0.3)
    busy.__exit__(None, None, None)
    side.join(5.0)
    assert done.is_set()


def test_markers_pause_is_bounded(monkeypatch) -> None:
    monkeypatch.setattr(NodeActivity, "MAX_PAUSE_S", 0.2)
    activity = NodeActivity()
    with activity.completing(), activity.busy():
        started = time.monotonic()
        activity.pause(completions=True)
        assert 0.15 < time.monotonic() - started < 2.0
