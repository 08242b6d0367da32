"""NodeActivity (node/activity.py): when the node's side threads step aside.

Guarantees proved here:
- ``pause()`` waits while the prediction path is busy and returns once it is idle;
- ``pause(beside=True)`` returns at once while the busy period is narrow (the previous period's
  kernels did not want numba's threads) and waits like ``pause()`` while it is wide: in the
  first period, and after a period whose kernels had the work for threads, granted or not.
"""
from __future__ import annotations

import os
import threading
import time

import pytest

from circle_collision_ros.core import parallel_policy as pp
from circle_collision_ros.node.activity import NodeActivity


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
