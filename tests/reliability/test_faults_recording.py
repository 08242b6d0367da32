"""Recording faults of a real collision_node process: SIGKILL, and the bag directory removed.

Guarantees proved here:
- SIGKILL while recording: the bag stays readable up to its last complete
  chunk (open_bag(..., tolerant=True), `replay --tolerant`), losing at most
  ~ChunkLimits.MAX_AGE_S of messages; strict reading refuses it with a one-line
  error; the replayed predictions are bit-identical to the recorded ones;
- the recording directory removed mid-run: the node says so in its log and on
  /diagnostics (level WARN, key `recording`), and keeps predicting.
"""
from __future__ import annotations

import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from circle_collision_ros.recording.bag_reader import BagError, open_bag
from circle_collision_ros.recording.bag_recorder import ChunkLimits
from tests.reliability.conftest import fact, tally
from tests.reliability.node_process import Client, NodeProcess
from tests.reliability.test_faults_node import _pair
from tests.reliability.wire import encode_array

REPLAY = [sys.executable, "-m", "circle_collision_ros.recording.replay"]


def _stream(client: Client, seconds: float, prefix: str) -> int:
    sent = 0
    end = time.monotonic() + seconds
    k = 0
    while time.monotonic() < end:
        now = client.now_ns()
        client.pub.publish(encode_array(_pair(prefix, now, x0=0.01 * (k % 50)), now))
        sent += 1
        k += 1
        client.spin(0.05)
    return sent


def test_sigkill_while_recording(tmp_path: Path) -> None:
    bag = tmp_path / "killed"
    node = NodeProcess(tmp_path / "node.log", frame_id="map", record_path=str(bag), marker_rate=0.0)
    client = Client("kill_client")
    try:
        client.wait_matched()
        now = client.now_ns()
        client.send_until_answered(encode_array(_pair("k_", now), now), now)
        sent = _stream(client, 3.5, "k_")
        killed_ns = time.time_ns()
        node.kill()  # SIGKILL: no close, no summary, no footer
    finally:
        client.close()
        node.stop()
    with pytest.raises(BagError) as strict:
        open_bag(bag)
    assert "truncated" in str(strict.value) and "\n" not in str(strict.value)
    contents = open_bag(bag, tolerant=True)
    assert contents.truncated
    counts = {t: i.message_count for t, i in contents.topics.items()}
    assert counts["/circle_states"] >= 10 and counts["/collision_predictions"] >= 10
    lost_s = (killed_ns - contents.end_time_ns) * 1e-9
    assert lost_s < ChunkLimits.MAX_AGE_S + 1.5  # at most the open chunk (+ a slow machine)
    run = subprocess.run(REPLAY + [str(bag), "--tolerant"], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stdout + run.stderr
    assert "truncated" in run.stderr and "Traceback" not in run.stderr
    assert "all predictions identical" in run.stdout
    strict_run = subprocess.run(REPLAY + [str(bag)], capture_output=True, text=True, timeout=120)
    assert strict_run.returncode == 2 and len(strict_run.stderr.strip().splitlines()) == 1
    tally("messages_sent", sent)
    fact("recorded_states", counts["/circle_states"])
    fact("recorded_predictions", counts["/collision_predictions"])
    fact("lost_at_kill_s", round(lost_s, 2))


def test_recording_directory_removed(tmp_path: Path) -> None:
    bag = tmp_path / "removed"
    node = NodeProcess(tmp_path / "node.log", frame_id="map", record_path=str(bag), marker_rate=0.0)
    client = Client("rm_client")
    try:
        client.wait_matched()
        now = client.now_ns()
        client.send_until_answered(encode_array(_pair("r_", now), now), now)
        _stream(client, 1.0, "r_")
        shutil.rmtree(bag)
        removed = time.time()
        _stream(client, 3.0, "r_")
        after = [m for t, m in client.predictions if t > removed + 2.0]
        assert len(after) >= 10, "predictions stopped after the bag directory was removed"
        assert node.alive()
        assert client.spin(5.0, lambda: any("recording" in d and d["recording"].startswith("failed")
                                            for d in client.diagnostics))
        diag = [d for d in client.diagnostics if d.get("recording", "").startswith("failed")][-1]
        assert diag["_level"] == 1 and "recording" in diag["_message"], diag
        log = node.log()
        assert "recording stopped, predictions continue" in log and "removed" in log, log[-2000:]
        fact("predictions_after_removal", len(after))
        fact("diagnostics_recording", diag["recording"][:80])
    finally:
        client.close()
        code = node.stop()
    assert code == 0 and "Traceback" not in node.log(), node.log()[-3000:]
