"""Corrupted and garbage messages at a real collision_node process over DDS.

Guarantees proved here:
- randomly corrupted CircleStateArrays (tests/reliability/corrupt.py): the node
  survives, rejects exactly the bad states (its /diagnostics count equals the
  oracle's), and its predictions for the good states are field-for-field those
  of CollisionPredictor fed the good subset alone;
- undecodable payloads (random bytes, truncations, 2-3 byte buffers, the bytes
  that crash rclpy's deserializer) on array and single-state topics cost the
  node nothing: still alive, still answering. Before the cdr_codec fix the
  4-byte CircleState b"\\x00\\x00\\x90\\xfa" killed it with SIGSEGV.
Example counts: a quick sample by default, the full counts under --stress (tests/stress.py).
"""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from circle_collision_msgs.msg import CircleStateArray
from circle_collision_ros.pipeline.state_codec import decode_states
from circle_collision_ros.pipeline.predictor import CollisionPredictor, PredictorConfig
from tests.reliability.conftest import tally
from tests.stress import examples
from tests.reliability.corrupt import corrupted_message
from tests.reliability.node_process import Client, NodeProcess, stamp_of
from tests.reliability.wire import Body, encode_array, encode_state

SINGLE = "robot/circle_state"


@pytest.fixture(scope="module")
def live(tmp_path_factory):
    node = NodeProcess(tmp_path_factory.mktemp("fuzz_node") / "node.log", frame_id="map",
                       horizon=5.0, single_state_topics=f"['{SINGLE}']", marker_rate=50.0)
    client = Client("fuzz_client", single_topic=SINGLE)
    try:
        client.wait_matched()
        yield node, client
    finally:
        client.close()
        code = node.stop()
        log = node.log()
        assert "Traceback" not in log, log[-3000:]
        assert code == 0, log[-3000:]


def test_corrupted_arrays_over_dds(live) -> None:
    """The fuzz examples, then the node's own count of rejected states against the
    oracle's: one test, so the count is checked on the node the examples ran against
    (under pytest-xdist a separate test could land on another worker, with its own node)."""
    node, client = live
    before = client.last_diagnostics(timeout=5.0)
    sent = {"n": 0, "bad": 0}

    @settings(max_examples=examples(10, 25), deadline=None,
              suppress_health_check=list(HealthCheck))
    @given(st.data())
    def example(data) -> None:
        n = sent["n"] = sent["n"] + 1
        now = client.now_ns()
        prefix = f"e{n}_"
        bodies, bad = data.draw(corrupted_message(prefix, now, offset=1e5 * n, max_good=10,
                                                  max_bad=8))
        good = [b for k, b in enumerate(bodies) if k not in bad]
        tally("messages")
        tally("states", len(bodies))
        tally("bad_states", len(bad))
        out = client.send_until_answered(encode_array(bodies, now), now)
        sent["bad"] += len(bad) * client.sends
        assert node.alive()
        twin = CollisionPredictor(PredictorConfig(horizon=5.0, frame_id="map"))
        twin.receive_batch(decode_states(encode_array(good, now), CircleStateArray), now)
        want = twin.predict().to_message().predictions
        got = [p for p in out.predictions
               if p.id_a.startswith(prefix) and p.id_b.startswith(prefix)]
        assert got == list(want)
        tally("contacts_compared", len(got))

    example()
    assert sent["n"] > 0
    # the node's count over the examples equals the oracle's total (its diagnostics are
    # cumulative: the difference from before them)
    diag = client.last_diagnostics(timeout=5.0)
    rejected = int(diag["states_rejected"]) - int(before["states_rejected"])
    assert rejected == sent["bad"], (diag, before)
    assert int(diag["errors"]) == int(before["errors"])


GARBAGE = [b"", b"\x00", b"\x00\x01", b"\x00\x01\x00", b"\x00\x00\x90\xfa", b"\x00\x01\x90\xfa",
           b"\x00\x03\x00\x00" + b"\x01" * 40, b"\xff" * 64]


def test_garbage_bytes_cost_nothing(live) -> None:
    node, client = live
    rng = np.random.default_rng(8)
    valid = encode_array([Body(f"g{k}", 0.5, (k * 3.0, 0.0, 0.0), stamp_ns=client.now_ns())
                          for k in range(5)], client.now_ns())
    payloads = list(GARBAGE)
    for _ in range(examples(50, 150)):
        cut = bytearray(valid[: int(rng.integers(0, len(valid)))])
        for _ in range(int(rng.integers(0, 4))):
            if cut:
                cut[int(rng.integers(0, len(cut)))] = int(rng.integers(0, 256))
        payloads.append(bytes(cut))
        payloads.append(bytes(rng.integers(0, 256, int(rng.integers(0, 200)), dtype=np.uint8)))
    assert client.spin(30.0, lambda: client.single_pub.get_subscription_count() > 0)
    for data in payloads:
        client.pub.publish(data)
        client.single_pub.publish(data)
        client.spin(0.002)
    tally("garbage_messages", 2 * len(payloads))
    assert node.alive(), node.log()[-3000:]
    # No fixed wait: the probes below go out on the same two writers after the garbage, so
    # their answers come only once the node has taken (and survived) every payload before them.
    now = client.now_ns()
    probe = [Body("probe_a", 0.5, (1e7, 0.0, 0.0), (1.0, 0.0, 0.0), stamp_ns=now),
             Body("probe_b", 0.5, (1e7 + 3.0, 0.0, 0.0), stamp_ns=now)]
    out = client.send_until_answered(encode_array(probe, now), now)
    assert [(p.id_a, p.id_b, p.time_to_collision) for p in out.predictions
            if p.id_a.startswith("probe")] == [("probe_a", "probe_b", 2.0)]
    # and the single-state topic still works
    later = client.now_ns()
    client.single_pub.publish(
        encode_state(Body("probe_c", 0.5, (1e7 + 6.0, 0.0, 0.0), stamp_ns=later))
    )
    assert client.spin(10.0, lambda: any(stamp_of(m) == later for _, m in client.predictions))
    assert node.alive()
