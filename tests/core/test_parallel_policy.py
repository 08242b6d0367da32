"""parallel_policy: threads only with enough work and a free core.

Guarantee proved here: while as many busy processes run as this process has
cores, ``cores_free()`` is 0 and ``threads_pay`` says serial, whatever the
work, also right after a threaded kernel; below the work threshold it says serial on any machine.
``threads_wanted`` counts the calls with the work for threads, granted or not (node/activity.py
reads it: a count of the granted ones would read "narrow" whenever a side thread held a core).
(Every threaded
kernel is compared bit for bit with its serial twin in the kernels' own tests,
so the choice can only change timing.)
"""
from __future__ import annotations

import os
import subprocess
import sys
import time

import pytest

from circle_collision_ros.core import parallel_policy as pp


def test_below_the_threshold_is_serial():
    before = pp.threads_wanted()
    assert not pp.threads_pay(4095, 4096)
    assert not pp.threads_pay(0, 1)
    assert pp.threads_wanted() == before  # not work for threads


def test_cores_free_is_within_the_affinity_set():
    assert 0 <= pp.cores_free() <= len(os.sched_getaffinity(0))


@pytest.mark.skipif(not os.path.exists("/proc/loadavg"), reason="Linux /proc only")
def test_busy_cores_make_kernels_serial():
    """One spinning process per core: no core is free, so no kernel goes threaded."""
    n = len(os.sched_getaffinity(0))
    # each spinner says on its pipe that it is about to spin (no sleep and hope)
    spin = ("import sys, time\nt = time.time() + 20\nsys.stdout.write('r')\nsys.stdout.flush()\n"
            "while time.time() < t: pass\n")
    procs = [
        subprocess.Popen([sys.executable, "-S", "-c", spin], stdout=subprocess.PIPE)
        for _ in range(n)
    ]
    try:
        for p in procs:
            assert p.stdout.read(1) == b"r"  # this spinner is running
        seen = [pp.cores_free() for _ in range(20)]
        assert max(seen) == 0, seen
        before = pp.threads_wanted()
        assert not pp.threads_pay(10**9, 1)
        # serial, but work for threads all the same (on one core nothing is)
        assert pp.threads_wanted() == before + (n > 1)
        # right after a threaded kernel our pool's workers are not counted as others'
        # work, but the spinners still are: serial
        pp._last_yes = time.monotonic()
        assert not pp.threads_pay(10**9, 1)
    finally:
        for p in procs:
            p.kill()
            p.wait()
            p.stdout.close()


def test_threads_forced_overrides_and_restores() -> None:
    """Warm-ups force each choice so both twins get compiled; the policy decides again after."""
    from circle_collision_ros.core.parallel_policy import threads_forced, threads_pay

    before = pp.threads_wanted()
    with threads_forced(True):
        assert threads_pay(1, 10**9)  # below any threshold: threaded all the same
        with threads_forced(False):
            assert not threads_pay(10**9, 1)
        assert threads_pay(1, 10**9)
    assert pp.threads_wanted() == before + 2  # the forced threaded answers
    assert not threads_pay(1, 10**9)  # deciding again: too little work
