"""The marker thread of collision_node (node/markers.py, MarkerPublisher), without DDS.

Guarantees proved here:
- the drawing steps aside while a completion of probabilities is evaluated
  (``NodeActivity.completing()``), yet keeps its rate: the budget (BUDGET of wall time) counts
  the thread's CPU time, not its waits, so completions that fill most of each frame period do
  not slow the markers below `marker_rate`;
- no array is published while a completion is under way.
"""
from __future__ import annotations

import threading
import time

from circle_collision_ros.node.activity import NodeActivity
from circle_collision_ros.node.markers import MarkerPublisher
from tests.node.test_probabilities import _prediction


def test_markers_keep_their_rate_beside_long_completions() -> None:
    activity = NodeActivity()
    prediction = _prediction(0)
    stop = threading.Event()
    sent_during = []

    def completions() -> None:  # 45 ms of every 50: completions that fill the frame periods
        while not stop.is_set():
            with activity.completing():
                time.sleep(0.045)
            time.sleep(0.005)

    def publish(data: bytes) -> None:
        sent_during.append(activity.completions_running)

    markers = MarkerPublisher(2, 10.0, publish, activity=activity)
    side = threading.Thread(target=completions)
    side.start()
    try:
        started = time.monotonic()
        while time.monotonic() - started < 3.0:
            markers.offer(prediction)
            time.sleep(0.005)
        drawn = markers.drawn
    finally:
        stop.set()
        side.join(5.0)
        markers.close(clear=False)
    # 10 Hz for 3 s: ~30 drawings, each in a gap between completions; budgeting the waits
    # (up to 45 ms a drawing, at 10 % of wall time: one per 0.25 to 0.45 s) allows far fewer
    assert drawn >= 18, drawn
    # a step in progress may finish as a completion starts; whole arrays are not drawn then
    assert sent_during.count(True) <= len(sent_during) // 4
