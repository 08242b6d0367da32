"""When the prediction path is busy, so that the node's side threads step aside.

The node wraps its prediction work (ingest, predict, publish) in ``busy()``; the marker
drawing and the completion of probabilities (node/markers.py, node/probabilities.py) cut
their work into short steps and call ``pause()`` between them, which returns at once while
the node is idle and otherwise waits until it is, for at most MAX_PAUSE_S (so that a node that
is never idle still gets markers and completions, late). Python threads share one interpreter
lock and this machine's cores are few: a side step running beside a prediction would delay it.
"""
from __future__ import annotations

import threading
from collections.abc import Iterator
from contextlib import contextmanager

__all__ = ["NodeActivity"]


class NodeActivity:
    """A busy flag the prediction path raises and side threads wait on."""

    MAX_PAUSE_S = 0.25

    def __init__(self) -> None:
        self._idle = threading.Event()
        self._idle.set()

    @contextmanager
    def busy(self) -> Iterator[None]:
        """Around the node's prediction work: side steps wait meanwhile."""
        self._idle.clear()
        try:
            yield
        finally:
            self._idle.set()

    def pause(self) -> None:
        """Between two side steps: wait while the node is busy (at most MAX_PAUSE_S)."""
        self._idle.wait(self.MAX_PAUSE_S)
