"""Fuzzing cdr_codec.decode_states, the node's first contact with untrusted bytes.

Guarantees proved here:
- random, mutated (byte flips, insertions, deletions) and truncated byte strings
  give a StateBatch or CdrError, never another exception, a crash or a hang;
- valid bytes (serialize_message of random messages, and our own big-endian
  encoding) decode to exactly what rclpy's deserialize_message gives;
- the byte strings that made the old code crash (SIGSEGV inside rclpy's
  deserializer, ValueError for 2-3 byte CircleStates) are now CdrError; the
  SIGSEGV itself is shown in a subprocess so that this session survives it.
Example counts: a quick sample by default, the full counts under --stress (tests/stress.py).
"""
from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from rclpy.serialization import deserialize_message, serialize_message
from std_msgs.msg import Header

from circle_collision_msgs.msg import CircleState, CircleStateArray
from circle_collision_ros.pipeline.cdr import CdrError
from circle_collision_ros.pipeline.state_codec import decode_states
from circle_collision_ros.pipeline.state_batch import StateBatch
from tests.reliability.conftest import tally
from tests.stress import examples
from tests.reliability.wire import Body, encode_array, encode_state
from tests.node_helpers import random_states, state_array

TYPES = (CircleState, CircleStateArray)
# Found by fuzzing (see module doc): rclpy.serialization.deserialize_message
# dies with SIGSEGV on these, and the old decode_states handed them to it.
RCLPY_CRASHERS = [(b"\x00\x00\x90\xfa", "CircleState"), (b"\x00\x00\x90\xfa", "CircleStateArray"),
                  (b"\x00\x01\x90\xfa", "CircleStateArray")]
SHORT = [b"", b"\x00", b"\x00\x01", b"\x00\x01\x00", b"\x00\x00\x00"]

FUZZ = settings(max_examples=examples(150, 1500), deadline=None,
                suppress_health_check=[HealthCheck.too_slow])

_VALID = [serialize_message(state_array(random_states(n, seed=n))) for n in (0, 1, 3, 7)]
_WITH_COVARIANCE = state_array(random_states(4, seed=5))
for _k, _s in enumerate(_WITH_COVARIANCE.circles):
    _s.covariance = [float(_k + 1)] * (36 if _k % 2 else _k)
_VALID.append(serialize_message(_WITH_COVARIANCE))
_VALID += [serialize_message(s) for s in random_states(3, seed=99)]


def _decode_safely(data: bytes) -> None:
    for msg_type in TYPES:
        tally("decodes")
        try:
            batch = decode_states(data, msg_type)
        except CdrError:
            tally("cdr_errors")
            continue
        tally("decoded_ok")
        assert isinstance(batch, StateBatch)
        n = len(batch)
        assert batch.radius.shape == (n,) and batch.position.shape == (n, 3)
        assert batch.stamp_ns.shape == (n,) and len(batch.frames) == n


def _same(batch: StateBatch, msg, msg_type) -> None:
    if msg_type is CircleStateArray:
        want = StateBatch.from_messages(msg.circles, msg.header.frame_id)
    else:
        want = StateBatch.from_messages([msg])
    assert batch.ids == want.ids and batch.frames == want.frames
    assert np.array_equal(batch.stamp_ns, want.stamp_ns)
    assert np.array_equal(batch.remove, want.remove)
    for name in ("radius", "position", "velocity", "acceleration", "covariance", "covariance_size"):
        got, expected = getattr(batch, name), getattr(want, name)
        assert (got is None) == (expected is None), name
        if got is not None:
            assert np.array_equal(got, expected, equal_nan=True), name


@FUZZ
@given(st.binary(max_size=400))
def test_random_bytes_decode_or_cdr_error(data: bytes) -> None:
    tally("examples")
    _decode_safely(data)
    _decode_safely(b"\x00\x01\x00\x00" + data)  # past the encapsulation check
    _decode_safely(b"\x00\x00\x00\x00" + data)  # big-endian path


@FUZZ
@given(st.sampled_from(range(len(_VALID))), st.lists(
    st.tuples(st.sampled_from(["flip", "set", "insert", "delete", "truncate"]),
              st.integers(0, 10**6), st.integers(0, 255)), min_size=1, max_size=6))
def test_mutated_valid_bytes_decode_or_cdr_error(which: int, edits) -> None:
    tally("examples")
    data = bytearray(_VALID[which])
    for op, where, value in edits:
        k = where % (len(data) + 1)
        if op == "insert":
            data[k:k] = bytes([value])
        elif op == "truncate":
            del data[k:]
        elif data and k < len(data):
            if op == "flip":
                data[k] ^= 1 << (value % 8)
            elif op == "set":
                data[k] = value
            else:
                del data[k]
    _decode_safely(bytes(data))


@pytest.mark.parametrize("data", SHORT, ids=lambda d: d.hex() or "empty")
def test_short_buffers_are_cdr_errors(data: bytes) -> None:
    """2-3 byte CircleStates used to raise ValueError (numpy frombuffer), which the node
    does not catch: its spin loop ended and the process exited."""
    for msg_type in TYPES:
        with pytest.raises(CdrError):
            decode_states(data, msg_type)


@pytest.mark.parametrize(
    "data, type_name", RCLPY_CRASHERS, ids=lambda x: x.hex() if isinstance(x, bytes) else x
)
def test_rclpy_crashers_are_cdr_errors_and_crash_rclpy(data: bytes, type_name: str) -> None:
    msg_type = {"CircleState": CircleState, "CircleStateArray": CircleStateArray}[type_name]
    with pytest.raises(CdrError):
        decode_states(data, msg_type)
    if (data, type_name) != RCLPY_CRASHERS[0]:
        return  # the others crash less reliably or only after seconds of allocation
    # Why decode_states must never fall back to rclpy for untrusted bytes.
    probe = (
        "from rclpy.serialization import deserialize_message\n"
        "from circle_collision_msgs.msg import CircleState, CircleStateArray\n"
        "try:\n    deserialize_message(%r, %s)\nexcept Exception:\n    pass\n" % (data, type_name)
    )
    run = subprocess.run([sys.executable, "-c", probe], capture_output=True, timeout=60)
    assert run.returncode in (0, -11), run  # -11 (SIGSEGV) with rclpy 9.1.2 / Fast CDR 2
    if run.returncode == -11:
        print(f"rclpy deserialize_message({data!r}, {type_name}) -> SIGSEGV")


def _finite_or_special():
    return st.one_of(
        st.floats(allow_nan=True, allow_infinity=True),
        st.sampled_from([0.0, -0.0, 5e-324, -1e308, 1e308]),
    )


_text = st.text(
    st.characters(blacklist_categories=("Cs",), blacklist_characters="\x00"), max_size=40
)


@st.composite
def _messages(draw):
    n = draw(st.integers(0, 6))
    circles = []
    for _ in range(n):
        s = CircleState()
        s.header = Header(
            stamp=Time(
                sec=draw(st.integers(-(2**31), 2**31 - 1)), nanosec=draw(st.integers(0, 2**32 - 1))
            ),
            frame_id=draw(_text),
        )
        s.id = draw(_text)
        s.radius = draw(_finite_or_special())
        for vec in (s.position, s.velocity, s.acceleration):
            vec.x, vec.y, vec.z = (draw(_finite_or_special()) for _ in range(3))
        s.remove = draw(st.booleans())
        # empty, the full 6x6, or a wrong length (decoded, then rejected by validation)
        s.covariance = draw(
            st.one_of(st.just([]), st.lists(_finite_or_special(), min_size=36, max_size=36),
                      st.lists(_finite_or_special(), min_size=1, max_size=35))
        )
        circles.append(s)
    return CircleStateArray(
        header=Header(stamp=Time(sec=draw(st.integers(0, 2**31 - 1))), frame_id=draw(_text)),
        circles=circles,
    )


@settings(max_examples=examples(50, 300), deadline=None)
@given(_messages())
def test_valid_bytes_decode_like_rclpy(msg: CircleStateArray) -> None:
    tally("examples")
    tally("states", len(msg.circles))
    data = serialize_message(msg)
    _same(decode_states(data, CircleStateArray), deserialize_message(data, CircleStateArray),
          CircleStateArray)
    for s in msg.circles[:2]:
        one = serialize_message(s)
        _same(decode_states(one, CircleState), deserialize_message(one, CircleState), CircleState)


@settings(max_examples=examples(40, 200), deadline=None)
@given(_messages())
def test_big_endian_decodes_like_little_endian(msg: CircleStateArray) -> None:
    """Our own big-endian encoding (rclpy writes only little endian) decodes to the same
    batch as rclpy's little-endian bytes; rclpy reads the big-endian bytes the same too."""
    tally("examples")
    stamp = msg.header.stamp.sec * 10**9
    bodies = [
        Body(s.id, s.radius, (s.position.x, s.position.y, s.position.z),
             (s.velocity.x, s.velocity.y, s.velocity.z),
             (s.acceleration.x, s.acceleration.y, s.acceleration.z), 0, s.header.frame_id, s.remove,
             stamp=(s.header.stamp.sec, s.header.stamp.nanosec), covariance=tuple(s.covariance))
        for s in msg.circles
    ]
    be = encode_array(bodies, stamp, msg.header.frame_id, big_endian=True)
    le = serialize_message(msg)
    _same(decode_states(be, CircleStateArray), deserialize_message(le, CircleStateArray),
          CircleStateArray)
    _same(decode_states(be, CircleStateArray), deserialize_message(be, CircleStateArray),
          CircleStateArray)
    if bodies:
        one = encode_state(bodies[0], big_endian=True)
        _same(decode_states(one, CircleState), msg.circles[0], CircleState)


def test_our_encoder_matches_rclpy() -> None:
    """The fuzzers' and the soak's encoder (tests/reliability/wire.py) is itself right."""
    states = random_states(5, seed=4)
    bodies = [
        Body(s.id, s.radius, (s.position.x, s.position.y, s.position.z),
             (s.velocity.x, s.velocity.y, s.velocity.z),
             (s.acceleration.x, s.acceleration.y, s.acceleration.z),
             s.header.stamp.sec * 10**9 + s.header.stamp.nanosec, s.header.frame_id)
        for s in states
    ]
    msg = state_array(states)
    data = encode_array(bodies, msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec)
    got = deserialize_message(data, CircleStateArray)
    assert got == msg
    assert not math.isnan(got.circles[0].radius)


def test_strings_decode_one_by_one_semantics() -> None:
    """The ids and frames of an array are decoded in one pass (joined by NUL, one
    decode, one split): the same strings as decoding each alone -- multi-byte
    UTF-8, empty ids, an empty frame taking the array's, all frames equal or
    not, an id holding a NUL (the one-by-one fallback) -- and an invalid UTF-8 id
    is a CdrError naming UTF-8."""
    cases = [[Body("a"), Body("β-7"), Body(""), Body("日本語", frame="odom"), Body("x", frame="")],
             [Body(f"b{k}") for k in range(50)], [Body("n\x00ul"), Body("plain")],
             [Body("solo", frame="")]]
    for bodies in cases:
        data = encode_array(bodies, 10**9, "arrayframe")
        batch = decode_states(data, CircleStateArray)
        assert batch.ids == tuple(b.id for b in bodies)
        assert batch.frames == tuple(b.frame or "arrayframe" for b in bodies)
    bad = encode_array([Body("ok"), Body("", id_bytes=b"\xff\xfe")], 10**9, "map")
    with pytest.raises(CdrError, match="UTF-8"):
        decode_states(bad, CircleStateArray)
