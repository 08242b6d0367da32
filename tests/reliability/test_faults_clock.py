"""Time faults at a real collision_node process over DDS: stamps and /clock jumping.

Each test runs its own node (other nodes on the domain would answer the same topics).

Guarantees proved here (decided behaviour in docs/reliability.md):
- the tracker's stamps jump backwards (clock reset): the stale bodies expire
  after stale_timeout, then the node predicts at the new stamps (the reference
  time no longer stays in the old future);
- use_sim_time with a /clock that jumps backwards: the scene is cleared at the
  jump (logged, counted in /diagnostics) and prediction resumes with the next
  states; a forward jump expires bodies not refreshed.
"""
from __future__ import annotations

import time

from rosgraph_msgs.msg import Clock

from tests.reliability.conftest import fact
from tests.reliability.node_process import Client, NodeProcess, stamp_of
from tests.reliability.test_faults_node import _pair, _ttcs
from tests.node_helpers import ns_time
from tests.reliability.wire import encode_array


def test_stamps_jump_backwards(tmp_path) -> None:
    """A tracker whose clock is reset 30 s back: its states are 'late' (ignored) until the
    bodies expire (stale_timeout), then they are new bodies again -- and the scene's
    reference time must follow them instead of staying 30 s in the future."""
    node = NodeProcess(tmp_path / "node.log", frame_id="map", stale_timeout=1.0, marker_rate=0.0)
    client = Client("jump_client")
    try:
        client.wait_matched()
        now = client.now_ns()
        client.send_until_answered(encode_array(_pair("j_", now), now), now)
        jump_ns = 30_000_000_000
        t_jump = time.time()
        deadline = time.monotonic() + 6.0
        while time.monotonic() < deadline:
            stamp = client.now_ns() - jump_ns
            client.pub.publish(encode_array(_pair("j_", stamp), stamp))
            client.spin(0.05)
        after = [(t, m) for t, m in client.predictions if t > t_jump]
        assert after, "no prediction after the stamps jumped back"
        t_last, last = after[-1]
        # the output is stamped with the inputs' (jumped) stamps, not the old future ones
        assert abs(stamp_of(last) - (int(t_last * 1e9) - jump_ns)) < 2_000_000_000, \
            (stamp_of(last) - int(t_last * 1e9)) / 1e9
        assert _ttcs(last, "j_") == {("j_a", "j_b"): 2.0}
        recovered = min(t for t, m in after if abs(stamp_of(m) - (int(t * 1e9) - jump_ns)) < 2e9)
        fact("recovery_s", round(recovered - t_jump, 2))
        assert node.alive()
    finally:
        client.close()
        node.stop()


def test_sim_time_clock_jumps(tmp_path) -> None:
    node = NodeProcess(tmp_path / "node.log", frame_id="map", stale_timeout=1.0, marker_rate=0.0,
                       use_sim_time="true")
    client = Client("sim_client")
    clock = client.node.create_publisher(Clock, "/clock", 10)
    sim = {"ns": 1_000 * 10**9}

    def run(seconds: float, ids: tuple[str, ...] = ("s_",), step_ns: int = 50_000_000) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            sim["ns"] += step_ns
            clock.publish(Clock(clock=ns_time(sim["ns"])))
            client.spin(0.01)
            for k, prefix in enumerate(ids):
                client.pub.publish(encode_array(_pair(prefix, sim["ns"], x0=100.0 * k), sim["ns"]))
            client.spin(0.04)

    def sim_stamps_since(t0: float) -> list[int]:
        return [stamp_of(m) for t, m in client.predictions if t >= t0]

    try:
        client.wait_matched()
        assert client.spin(30.0, lambda: clock.get_subscription_count() > 0)
        run(2.0, ("s_", "gone_"))
        assert sim_stamps_since(0), node.log()
        before_jump = sim["ns"]
        # /clock jumps 500 s back (a bag played in a loop restarts); "gone_" is not sent any more
        sim["ns"] -= 500 * 10**9
        t_jump = time.time()
        run(3.0, ("s_",))
        stamps = sim_stamps_since(t_jump)
        assert stamps, f"no predictions after the backward jump\n{node.log()[-2000:]}"
        assert max(stamps) <= sim["ns"] and max(stamps) < before_jump  # new time, not the old future
        last = [m for t, m in client.predictions if t >= t_jump][-1]
        assert _ttcs(last, "s_") == {("s_a", "s_b"): 2.0}
        assert not _ttcs(last, "gone_")  # garbage from before the jump is gone
        # a forward jump: bodies not refreshed expire; refreshed ones go on
        sim["ns"] += 100 * 10**9
        t_fwd = time.time()
        run(1.5, ("s_",))
        assert max(sim_stamps_since(t_fwd)) >= sim["ns"] - 1_000_000_000
        run(1.5, ("s_",))  # /diagnostics runs on a 1 s timer of the (sim) clock
        assert client.diagnostics, "no /diagnostics"
        diag = client.diagnostics[-1]
        fact("clock_jumps_back", diag.get("clock_jumps_back"))
        assert int(diag.get("clock_jumps_back", 0)) >= 1, diag
        assert "clock jumped back" in node.log()
        assert node.alive()
    finally:
        client.close()
        code = node.stop()
        assert "Traceback" not in node.log(), node.log()[-3000:]
