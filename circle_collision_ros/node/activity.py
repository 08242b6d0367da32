"""When the prediction path is busy, so that the node's side threads step aside.

The node wraps its prediction work (ingest, predict, publish) in ``busy()``; the marker
drawing and the completion of probabilities (node/markers.py, node/probabilities.py) cut
their work into short steps and call ``pause()`` between them, which returns at once while
the node is idle and otherwise waits until it is, for at most MAX_PAUSE_S (so that a node that
is never idle still gets markers and completions, late). Python threads share one interpreter
lock and this machine's cores are few: a side step running beside a prediction would delay it.

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

    def pause(self, beside: bool = False) -> None:
        """Between two side steps: wait while the node is busy (at most MAX_PAUSE_S); with
        `beside`, not while the busy period is narrow (one side thread, on the other core)."""
        if beside and self._narrow.is_set():
            return
        self._idle.wait(self.MAX_PAUSE_S)
