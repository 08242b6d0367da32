"""Recording faults of a real collision_node process: SIGKILL, and the bag directory removed.

Guarantees proved here:
- SIGKILL while recording: the bag stays readable up to its last complete
  chunk (open_bag(..., tolerant=True), `replay --tolerant`): the idle chunk
  reaches the disk by itself (ChunkLimits.MAX_AGE_S), and whatever was on disk
  before the kill is all still read after it; strict reading refuses it with a one-line
  error; the replayed predictions are bit-identical to the recorded ones;
- the recording directory removed mid-run: the node says so in its log and on
  /diagnostics (level WARN, key `recording`), and keeps predicting.
"""
from __future__ import annotations

import shutil
import struct
import subprocess
import sys
import time
from pathlib import Path

import pytest

from circle_collision_ros.recording.bag_reader import BagError, open_bag
from tests.reliability.conftest import fact, tally
from tests.reliability.node_process import Client, NodeProcess, stamp_of
from tests.reliability.test_faults_node import _pair, _ttcs
from tests.reliability.wire import encode_array

REPLAY = [sys.executable, "-m", "circle_collision_ros.recording.replay"]


HANG_GUARD_S = 60.0  # bounds a wait for a condition; never a measured duration


def _stream(client: Client, prefix: str, until) -> int:
    """Send states (one message per ~50 ms) until `until()` holds; returns the count sent.
    The deadline only guards against a hang: the test waits on the condition, not a time."""
    sent = 0
    deadline = time.monotonic() + HANG_GUARD_S
    while not until():
        assert time.monotonic() < deadline, f"condition not reached after {sent} messages"
        now = client.now_ns()
        client.pub.publish(encode_array(_pair(prefix, now, x0=0.01 * (sent % 50)), now))
        sent += 1
        client.spin(0.05)
    return sent


def _on_disk(bag: Path):
    """What a tolerant reader sees of a bag being recorded (None before the first chunk)."""
    try:
        return open_bag(bag, tolerant=True)
    except BagError:
        return None


def _prediction_stamps(contents) -> set[int]:
    stamps = set()
    for r in contents.records(["/collision_predictions"]):
        sec, nanosec = struct.unpack_from("<iI", r.data, 4)  # header.stamp after the encapsulation
        stamps.add(sec * 10**9 + nanosec)
    return stamps


def test_sigkill_while_recording(tmp_path: Path) -> None:
    """Count, don't time: stream until 20 predictions are answered, wait until the recorder's
    idle flush has put the answer to the last input on disk, then SIGKILL. What was on disk
    must all be readable afterwards (tolerant), and nothing answered is lost."""
    bag = tmp_path / "killed"
    node = NodeProcess(tmp_path / "node.log", frame_id="map", record_path=str(bag), marker_rate=0.0)
    client = Client("kill_client")
    try:
        client.wait_matched()
        now = client.now_ns()
        client.send_until_answered(encode_array(_pair("k_", now), now), now)
        start = len(client.predictions)
        sent = _stream(client, "k_", lambda: len(client.predictions) - start >= 20)
        last = stamp_of(client.predictions[-1][1])
        on_disk = None
        deadline = time.monotonic() + HANG_GUARD_S
        while on_disk is None or last not in _prediction_stamps(on_disk):
            assert time.monotonic() < deadline, "the last answer never reached the disk"
            client.spin(0.1)
            on_disk = _on_disk(bag)
        before = {t: i.message_count for t, i in on_disk.topics.items()}
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
    assert counts["/circle_states"] >= before["/circle_states"] >= 20
    assert counts["/collision_predictions"] >= before["/collision_predictions"] >= 20
    assert last in _prediction_stamps(contents)  # everything answered before the kill survived
    lost_s = (killed_ns - contents.end_time_ns) * 1e-9
    run = subprocess.run(
        REPLAY + [str(bag), "--tolerant"], capture_output=True, text=True, timeout=120
    )
    assert run.returncode == 0, run.stdout + run.stderr
    assert "truncated" in run.stderr and "Traceback" not in run.stderr
    assert "all predictions identical" in run.stdout
    strict_run = subprocess.run(REPLAY + [str(bag)], capture_output=True, text=True, timeout=120)
    assert strict_run.returncode == 2 and len(strict_run.stderr.strip().splitlines()) == 1
    tally("messages_sent", sent)
    fact("recorded_states", counts["/circle_states"])
    fact("recorded_predictions", counts["/collision_predictions"])
    fact("lost_at_kill_s", round(lost_s, 2))  # reported, not asserted (machine-dependent)


def test_recording_directory_removed(tmp_path: Path) -> None:
    bag = tmp_path / "removed"
    node = NodeProcess(tmp_path / "node.log", frame_id="map", record_path=str(bag), marker_rate=0.0)
    client = Client("rm_client")
    try:
        client.wait_matched()
        now = client.now_ns()
        client.send_until_answered(encode_array(_pair("r_", now), now), now)
        # recording, with a chunk on disk
        _stream(client, "r_", lambda: getattr(_on_disk(bag), "message_count", 0) > 0)
        shutil.rmtree(bag)

        def failed() -> bool:
            return any(d.get("recording", "").startswith("failed") for d in client.diagnostics)

        # The node notices (on /diagnostics), then keeps predicting: 10 more answers after that.
        _stream(client, "r_", failed)
        noticed = len(client.predictions)

        def answered_since() -> list:
            return [m for _, m in client.predictions[noticed:] if _ttcs(m, "r_")]

        _stream(client, "r_", lambda: len(answered_since()) >= 10)
        after = answered_since()
        assert len(after) >= 10, "predictions stopped after the bag directory was removed"
        assert node.alive()
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
