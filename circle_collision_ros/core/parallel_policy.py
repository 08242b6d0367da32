"""When a kernel runs on numba's threads: enough work, and a core free right now.

Every threaded kernel in ``core`` computes each row exactly as its serial twin
(tests compare them bit for bit), so this choice changes only the time taken,
never a result.

Why "a core free right now": a parallel region hands half the rows to a
worker thread and then waits for it.  When another process holds the other
core, the worker waits for a time slice first, and the threaded kernel can
take many times the serial time; on an idle machine it takes well under it
(bench/accuracy_vs_time.py and bench/scale.py time both).  A robot shares
its cores with its other nodes, so the kernels ask before each large call.

How: /proc/loadavg's fourth field counts the tasks that are runnable at this
instant, this thread included; a core is free if that count is below the
cores this process may use.  Our own pool's workers spin for a while after a
parallel region (libgomp's default wait policy) and are counted there too:
without a correction a second threaded kernel right after a first (broad
phase, then narrow phase) saw no free core and ran serial, even on an idle
machine.  So for
_GRACE_S after a yes the pool's workers are not counted as other work: the
decision holds for a burst of kernels.  Reading it is one pread on a
descriptor kept open, negligible against the work at the thresholds
where it is asked.  Where the file is missing (not Linux), threads are used
above the thresholds as if every core were free.
"""
from __future__ import annotations

import math
import os
import time
from collections.abc import Iterator
from contextlib import contextmanager

import numba

__all__ = ["cores_free", "threads_pay", "threads_forced", "threads_wanted"]

#: s after a yes during which our own pool's (possibly spinning) workers are not
#: counted as other work.
_GRACE_S = 0.05
_last_yes = -math.inf
_forced: bool | None = None  # threads_forced's answer, None: decide
_wanted = 0  # threads_pay calls with enough work for threads (threads_wanted)

try:
    _CORES = len(os.sched_getaffinity(0))
except AttributeError:  # not Linux
    _CORES = os.cpu_count() or 1

try:
    _LOADAVG = os.open("/proc/loadavg", os.O_RDONLY)
except OSError:
    _LOADAVG = -1


def cores_free(own_workers: int = 0) -> int:
    """Cores of this process's affinity set not running another task at this instant;
    `own_workers` runnable tasks are ours (the thread pool's), not another's."""
    if _LOADAVG < 0:
        return _CORES
    try:
        running = int(os.pread(_LOADAVG, 128, 0).split()[3].split(b"/")[0])
    except (OSError, ValueError, IndexError):
        return _CORES
    return max(0, _CORES - max(1, running - own_workers))  # `running` counts this thread too


def threads_pay(work: int, min_work: int) -> bool:
    """True if a kernel with `work` items should run threaded: at least `min_work`
    items (below it a parallel launch costs more than it saves even on idle
    cores) and a core free for the worker thread now."""
    global _last_yes, _wanted
    if _forced is not None:
        _wanted += _forced
        return _forced
    if work < min_work or _CORES <= 1:
        return False
    _wanted += 1
    now = time.monotonic()
    own = numba.get_num_threads() - 1 if now - _last_yes < _GRACE_S else 0
    if cores_free(own) >= 1:
        _last_yes = now
        return True
    return False


def threads_wanted() -> int:
    """How many threads_pay calls so far had the work for threads, whether or not a core was
    free: a caller compares two readings to learn whether the work between them wants both
    cores (node/activity.py), which the answers themselves cannot tell while another thread
    holds a core."""
    return _wanted


@contextmanager
def threads_forced(threaded: bool) -> Iterator[None]:
    """Within the block threads_pay answers `threaded` whatever the work and the load.

    For warm-ups only (not thread-safe: call it before other threads run kernels): a
    threaded twin that the warm-up's small inputs and the load of the moment would not
    choose is then compiled (or loaded) too, and not in the first large frame of a node.
    """
    global _forced
    saved, _forced = _forced, bool(threaded)
    try:
        yield
    finally:
        _forced = saved
