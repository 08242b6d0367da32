"""When the prediction path is busy, so that the node's side threads step aside.

The node wraps its prediction work (ingest, predict, publish) in ``busy()``; the marker
drawing and the completion of probabilities (node/markers.py, node/probabilities.py) cut
their work into short steps and call ``pause()`` between them, which returns at once while
the node is idle and otherwise waits until it is, for at most MAX_PAUSE_S (so that a node that
is never idle still gets markers and completions, late). Python threads share one interpreter
lock and this machine's cores are few: a side step running beside a prediction would delay it.

Markers also step aside for the completion of probabilities, which are predictions too: the
completion thread marks its evaluation with ``completing()`` and the marker thread pauses with
``pause(completions=True)``, which waits for both (at most MAX_PAUSE_S in all). Markers are the
only work for eyes alone, so they come last: drawn in the gaps, never beside a completion.

One side thread may go on beside a narrow prediction: ``pause(beside=True)`` returns at once
while the busy period is narrow, one whose prediction kernels run on one core. A wide one, whose
kernels want numba's threads on every core (core/parallel_policy.py), holds it as any other.
A period cannot know that before its kernels ask, so it takes the previous period's answer:
``threads_wanted`` moved during it. (A reading of whether threads were granted would not do: a
side thread beside the kernels takes the free core they look for, they run serial, and every
later period would read narrow.)
"""
from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager

from circle_collision_ros.core.parallel_policy import threads_wanted

__all__ = ["NodeActivity"]


class NodeActivity:
    """A busy flag the prediction path raises and side threads wait on."""

    MAX_PAUSE_S = 0.25

    def __init__(self) -> None:
        self._idle = threading.Event()
        self._idle.set()
        self._narrow = threading.Event()  # set while busy with a narrow period
        self._wide_next = True  # until a period has shown otherwise: every core wanted
        self._completions_idle = threading.Event()
        self._completions_idle.set()
        self._completions = 0  # completions under way (completing() may nest across threads)
        self._lock = threading.Lock()

    @property
    def wide(self) -> bool:
        """Whether the next busy period is taken to want every core (the last one did)."""
        return self._wide_next

    @contextmanager
    def busy(self) -> Iterator[None]:
        """Around the node's prediction work: side steps wait meanwhile."""
        if not self._wide_next:
            self._narrow.set()
        self._idle.clear()
        before = threads_wanted()
        try:
            yield
        finally:
            self._wide_next = threads_wanted() != before
            self._narrow.clear()
            self._idle.set()

    @property
    def completions_running(self) -> bool:
        """Whether a completion is being evaluated (``completing()``)."""
        return not self._completions_idle.is_set()

    @contextmanager
    def completing(self) -> Iterator[None]:
        """Around the evaluation of a completion (node/probabilities.py): markers wait meanwhile."""
        with self._lock:
            self._completions += 1
            self._completions_idle.clear()
        try:
            yield
        finally:
            with self._lock:
                self._completions -= 1
                if self._completions == 0:
                    self._completions_idle.set()

    def pause(self, beside: bool = False, completions: bool = False) -> None:
        """Between two side steps: wait while the node is busy (at most MAX_PAUSE_S); with
        `beside`, not while the busy period is narrow (one side thread, on the other core);
        with `completions` (markers), also while a completion is evaluated (MAX_PAUSE_S in
        all)."""
        if beside and self._narrow.is_set():
            return
        if not completions:
            self._idle.wait(self.MAX_PAUSE_S)
            return
        end = time.monotonic() + self.MAX_PAUSE_S
        # until both are clear at once: one may be raised again while the other is awaited
        while True:
            held = next((e for e in (self._idle, self._completions_idle) if not e.is_set()), None)
            left = end - time.monotonic()
            if held is None or left <= 0.0:
                return
            held.wait(left)
