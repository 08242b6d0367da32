"""collision_probabilities: each prediction completed off the prediction path.

The prediction path publishes `collision_predictions` at once. Of its uncertain pairs, at
most `uncertain_pair_budget` get the full probability evaluation there; the rest carry a
cheap certified interval (deferred rows). This thread takes the newest such prediction,
evaluates every deferred row in full (``ScenePrediction.completed``) and publishes the result,
stamped as the prediction it completes, on `collision_probabilities`: the message the same
scene publishes with ``uncertain_pair_budget`` 0, bit for bit.

- The exact times never wait: the prediction path only hands over a reference.
- The heavy kernels release the interpreter lock (numba ``nogil``): the rows go to ``PARTS``
  threads at a lower scheduling priority (``NICE``), in steps of a few rows, each taken by
  the next free thread. Before each step a thread waits while the prediction path is busy
  (node/activity.py), so that the exact path is not slowed by the cores or the lock they
  hold; but the first of them goes on while the busy period is narrow, one whose kernels run
  on one core: the other core is free then, and the completion does not fall a frame behind
  each time the next input arrives; it runs at ``BESIDE_NICE``. Beside a wide period, whose
  kernels use numba's threads on both cores (large scenes), it waits too: there it slowed
  the predictions.
- Latest wins: a prediction superseded before the thread takes it is never completed
  (counted in ``superseded``). A prediction with nothing deferred is republished as it is.
- Lag: a completion published when a newer prediction had been offered is counted in ``late``
  (the exact answer of the next input went out before it: at a tracker's frame rate, a
  completion later than one frame); ``lag_problem`` says when a period shows the completions
  falling behind.
- Recording: each message is recorded with the log time of the prediction it completes, so
  replay knows which prediction it belongs to and recomputes it (recording/replay_engine.py).
"""
from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import NamedTuple

from circle_collision_ros.node.activity import NodeActivity
from circle_collision_ros.pipeline.prediction_messages import ScenePrediction

__all__ = ["ProbabilityPublisher", "lag_problem"]


class _Job(NamedTuple):
    prediction: ScenePrediction
    data: bytes  # the prediction's published bytes (republished when nothing was deferred)
    log_time_ns: int
    offered: float  # time.monotonic() at the offer
    seq: int  # offers made up to and including this one


def lag_problem(published: int, late: int, superseded: int) -> str | None:
    """What a period's counts of completions (published, late, superseded) say about
    `collision_probabilities`, or None when it keeps up: a problem when no completion was
    published while predictions were superseded (one completion outlasted the whole period,
    and the predictions offered meanwhile got none).  Late completions alone are not: in a
    fast per-body stream the next prediction comes within milliseconds, so nearly every
    completion is published after it, and is still only milliseconds old."""
    if not (published == 0 and superseded > 0):
        return None
    return (f"collision_probabilities falls behind the inputs: {late} of {published} "
            f"completions came after the next prediction, {superseded} predictions got none")


def _lower_priority(nice: int) -> None:
    """This thread at niceness `nice` (Linux: per thread; elsewhere or if refused, unchanged:
    only the scheduling order is at stake, never a result)."""
    try:
        os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), nice)
    except (AttributeError, OSError):
        pass


class ProbabilityPublisher:
    """A thread that completes and publishes the newest offered prediction.

    publish(data) sends serialized CollisionPredictionArray bytes; record(data, log_time_ns)
    records them; on_error(text) reports a failure (the thread keeps running).
    """

    #: Threads evaluating one completion's rows (each share on its own core, if there is one).
    PARTS = min(2, os.cpu_count() or 1)
    #: Niceness of those threads (the prediction path keeps the process's, 0 by default).
    NICE = 10
    #: Niceness of the one that goes on beside a narrow prediction path: it is running when
    #: the exact prediction is published and its subscribers wake, and at NICE it still
    #: delayed them measurably (live exact latency, bench/bench_probabilities.py).
    BESIDE_NICE = 19

    def __init__(self, publish: Callable[[bytes], None],
                 record: Callable[[bytes, int], None] | None = None,
                 on_error: Callable[[str], None] | None = None,
                 activity: NodeActivity | None = None) -> None:
        self._publish = publish
        self._record = record or (lambda data, log_time_ns: None)
        self._on_error = on_error or (lambda text: None)
        self.activity = activity or NodeActivity()
        self._cond = threading.Condition()
        self._latest: _Job | None = None
        self._stopped = False
        self._busy = False
        self.published = 0  # messages published
        self.completed = 0  # of which had deferred rows evaluated here
        self.superseded = 0  # offered predictions replaced before the thread took them
        self.late = 0  # of the published, those a newer prediction was offered before
        self._offers = 0
        self.last_compute_s = 0.0  # the last completion's evaluation time
        self.last_delay_s = 0.0  # the last message's offer-to-publish time
        self._local = threading.local()  # .beside: this pool thread goes on beside narrow work
        self._started = 0
        self._pool = ThreadPoolExecutor(self.PARTS, "collision_node_probabilities",
                                        initializer=self._start_part)
        self._thread = threading.Thread(target=self._run, name="collision_node_probabilities",
                                        daemon=True)
        self._thread.start()

    def offer(self, prediction: ScenePrediction, data: bytes, log_time_ns: int) -> None:
        """Hand over the newest prediction, its published bytes and its log time."""
        with self._cond:
            if self._latest is not None:
                self.superseded += 1
            self._offers += 1
            self._latest = _Job(prediction, data, log_time_ns, time.monotonic(), self._offers)
            self._cond.notify_all()  # the thread, and wait_idle's callers, wait on it

    def close(self) -> None:
        """Stop the thread once it has published (and recorded) what was offered."""
        with self._cond:
            self._stopped = True
            self._cond.notify_all()
        self._thread.join(timeout=30.0)
        self._pool.shutdown(wait=False)

    def wait_idle(self, timeout: float) -> bool:
        """True once every offered prediction is published or superseded (tests)."""
        with self._cond:
            return self._cond.wait_for(lambda: self._latest is None and not self._busy, timeout)

    def _start_part(self) -> None:
        """A pool thread's start: the first one started goes on beside a narrow prediction
        path, at BESIDE_NICE; the others at NICE."""
        with self._cond:
            self._local.beside = self._started == 0 and self.PARTS > 1
            self._started += 1
        _lower_priority(self.BESIDE_NICE if self._local.beside else self.NICE)

    def _step_aside(self) -> None:
        """complete_uncertainty's pause, before each step of rows."""
        self.activity.pause(beside=getattr(self._local, "beside", False))

    def _run(self) -> None:
        _lower_priority(self.NICE)
        while True:
            with self._cond:
                while not self._stopped and self._latest is None:
                    self._cond.wait()
                if self._latest is None:  # stopped, and everything offered is done
                    return
                job, self._latest = self._latest, None
                self._busy = True
            try:
                data = job.data
                if job.prediction.deferred:
                    started = time.monotonic()
                    with self.activity.completing():  # markers wait meanwhile
                        done = job.prediction.completed(self._pool, self.PARTS, self._step_aside)
                    data = done.to_cdr()
                    self.last_compute_s = time.monotonic() - started
                    self.completed += 1
                with self._cond:  # the next input's exact answer is out already
                    late = self._offers > job.seq
                self._publish(data)
                self.last_delay_s = time.monotonic() - job.offered
                self.published += 1
                if late:
                    self.late += 1
                self._record(data, job.log_time_ns)
            except Exception as exc:  # one failed completion never stops the next ones
                self._on_error(f"probabilities of the prediction at {job.log_time_ns} ns "
                               f"skipped: {exc!r}")
            finally:
                with self._cond:
                    self._busy = False
                    self._cond.notify_all()
