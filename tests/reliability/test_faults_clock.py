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

HANG_GUARD_S = 60.0  # bounds a wait for a condition; never a measured duration


def test_stamps_jump_backwards(tmp_path) -> None:
    """A tracker whose clock is reset 30 s back: its states are 'late' (ignored) until the
    bodies expire (stale_timeout), then they are new bodies again -- and the scene's
    reference time must follow them instead of staying 30 s in the future.

    No fixed run time: the jumped stream goes on until the node answers it (a prediction
    stamped exactly with one of the jumped stamps sent), within a bound that only guards
    against a hang; then until 5 more predictions, the last of which must answer one too."""
    node = NodeProcess(tmp_path / "node.log", frame_id="map", stale_timeout=1.0, marker_rate=0.0)
    client = Client("jump_client")
    try:
        client.wait_matched()
        now = client.now_ns()
        client.send_until_answered(encode_array(_pair("j_", now), now), now)
        jump_ns = 30_000_000_000
        t_jump = time.time()
        sent: set[int] = set()

        def answered() -> list:  # predictions after the jump stamped with a jumped stamp we sent
            return [(t, m) for t, m in client.predictions if t > t_jump and stamp_of(m) in sent]

        def stream_until(done, seconds: float = HANG_GUARD_S) -> bool:
            deadline = time.monotonic() + seconds
            while time.monotonic() < deadline:
                stamp = client.now_ns() - jump_ns
                sent.add(stamp)
                client.pub.publish(encode_array(_pair("j_", stamp), stamp))
                client.spin(0.05)
                if done():
                    return True
            return False

        assert stream_until(lambda: answered()), "no prediction at the jumped-back stamps"
        recovered, first = answered()[0]
        fact("recovery_s", round(recovered - t_jump, 2))
        # the output is stamped with the inputs' (jumped) stamps, not the old future ones
        assert _ttcs(first, "j_") == {("j_a", "j_b"): 2.0}
        # and it stays there: the last of 5 more predictions answers a jumped stamp too
        assert stream_until(lambda: len([t for t, _ in client.predictions if t > recovered]) >= 5)
        last = client.predictions[-1][1]
        assert stamp_of(last) in sent, (stamp_of(last) - max(sent)) / 1e9
        assert _ttcs(last, "j_") == {("j_a", "j_b"): 2.0}
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

    def run(until, ids: tuple[str, ...] = ("s_",), step_ns: int = 50_000_000) -> bool:
        """Advance /clock and send states at ~1x sim speed until `until()` holds (no fixed
        run time); the deadline only guards against a hang."""
        end = time.monotonic() + HANG_GUARD_S
        while time.monotonic() < end:
            sim["ns"] += step_ns
            clock.publish(Clock(clock=ns_time(sim["ns"])))
            client.spin(0.01)
            for k, prefix in enumerate(ids):
                client.pub.publish(encode_array(_pair(prefix, sim["ns"], x0=100.0 * k), sim["ns"]))
            client.spin(0.04)
            if until():
                return True
        return False

    def sim_stamps_since(t0: float) -> list[int]:
        return [stamp_of(m) for t, m in client.predictions if t >= t0]

    try:
        client.wait_matched()
        assert client.spin(30.0, lambda: clock.get_subscription_count() > 0)
        assert run(lambda: any(_ttcs(m, "gone_") for _, m in client.predictions),
                   ("s_", "gone_")), node.log()[-2000:]
        before_jump = sim["ns"]
        # everything sent before the jump answered (no old-time prediction still on its way)
        assert client.spin(HANG_GUARD_S, lambda: before_jump in sim_stamps_since(0)), \
            node.log()[-2000:]
        # /clock jumps 500 s back (a bag played in a loop restarts); "gone_" is not sent any more
        sim["ns"] -= 500 * 10**9
        t_jump = time.time()
        assert run(lambda: len(sim_stamps_since(t_jump)) >= 10), \
            f"no predictions after the backward jump\n{node.log()[-2000:]}"
        stamps = sim_stamps_since(t_jump)
        # new time, not the old future
        assert max(stamps) <= sim["ns"] and max(stamps) < before_jump
        last = [m for t, m in client.predictions if t >= t_jump][-1]
        assert _ttcs(last, "s_") == {("s_a", "s_b"): 2.0}
        assert not _ttcs(last, "gone_")  # garbage from before the jump is gone
        # a forward jump: bodies not refreshed expire; refreshed ones go on
        sim["ns"] += 100 * 10**9
        jumped_to = sim["ns"]
        t_fwd = time.time()
        assert run(lambda: any(s > jumped_to for s in sim_stamps_since(t_fwd))), node.log()[-2000:]
        first_after = next(m for t, m in client.predictions
                           if t >= t_fwd and stamp_of(m) > jumped_to)
        assert _ttcs(first_after, "s_") == {("s_a", "s_b"): 2.0}  # predicted at the new time
        # /diagnostics runs on a 1 s timer of the (sim) clock
        def jump_reported() -> bool:
            return bool(client.diagnostics) and "clock jumped back" in node.log() \
                and int(client.diagnostics[-1].get("clock_jumps_back", 0)) >= 1

        assert run(jump_reported), (client.diagnostics[-1:], node.log()[-2000:])
        diag = client.diagnostics[-1]
        fact("clock_jumps_back", diag.get("clock_jumps_back"))
        assert int(diag.get("clock_jumps_back", 0)) >= 1, diag
        assert "clock jumped back" in node.log()
        assert node.alive()
    finally:
        client.close()
        node.stop()
        assert "Traceback" not in node.log(), node.log()[-3000:]
