"""Tests of open_bag: ordering, metadata, and robustness against bad files."""
from __future__ import annotations

import random
import signal
import struct
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from mcap.writer import CompressionType, Writer
from rclpy.serialization import deserialize_message, serialize_message

from circle_collision_msgs.msg import CircleStateArray
from circle_collision_ros.recording.bag_reader import BagError, BagRecord, Limits, open_bag
from circle_collision_ros.recording.bag_recorder import BagFormat, BagRecorder
from circle_collision_ros.recording.ros_type_definitions import full_msg_definition

from tests.stress import examples

from .test_bag_recorder import (CONFIG, PREDICTIONS_TYPE, STATES_TYPE, T0, make_states,
                                record_sample_bag)


@pytest.fixture(scope="module")
def sample_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return record_sample_bag(tmp_path_factory.mktemp("sample") / "bag", count=30,
                             max_chunk_bytes=4096)


@pytest.fixture(scope="module")
def sample_bytes(sample_bag: Path) -> bytes:
    return (sample_bag / f"bag{BagFormat.FILE_SUFFIX}").read_bytes()


class _Hang(Exception):
    pass


#: Only a guard against a hang (an endless loop on a lying length): never a measured duration.
#: What a bad length must not cost is bounded directly: allocations (small_allocations).
HANG_GUARD_S = 30.0


@contextmanager
def small_allocations(limit_bytes: int = 16 * 1024 * 1024) -> Iterator[None]:
    """Fail if the body's peak traced allocation exceeds `limit_bytes` (default 16 MiB, for
    files of a few kB): a reader that believed a declared length of 2**62 would try to
    allocate or read that much, and a MemoryError would count as an allocation too."""
    import tracemalloc

    was_tracing = tracemalloc.is_tracing()
    if not was_tracing:
        tracemalloc.start()
    tracemalloc.reset_peak()
    base = tracemalloc.get_traced_memory()[0]
    try:
        yield
    finally:
        peak = tracemalloc.get_traced_memory()[1]
        if not was_tracing:
            tracemalloc.stop()
    assert peak - base < limit_bytes, f"peak allocation {peak - base} bytes"


@contextmanager
def time_limit(seconds: float) -> Iterator[None]:
    """Fail (rather than hang the suite) if the body takes longer than `seconds`."""
    def on_alarm(signum: int, frame: object) -> None:
        raise _Hang(f"took longer than {seconds} s")

    # pytest-timeout may own SIGALRM too: put its handler and remaining time back.
    previous = signal.signal(signal.SIGALRM, on_alarm)
    outer_delay, outer_interval = signal.setitimer(signal.ITIMER_REAL, seconds)
    started = time.monotonic()
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)
        if outer_delay > 0:
            remaining = max(outer_delay - (time.monotonic() - started), 0.001)
            signal.setitimer(signal.ITIMER_REAL, remaining, outer_interval)


def read_all(path: Path, tolerant: bool = False) -> list[BagRecord]:
    return list(open_bag(path, tolerant=tolerant))


def write_foreign_mcap(path: Path, profile: str, schema_name: str, schema_encoding: str,
                       message_encoding: str, data: bytes = b"{}") -> Path:
    with open(path, "wb") as stream:
        writer = Writer(stream, compression=CompressionType.ZSTD)
        writer.start(profile=profile)
        schema_id = writer.register_schema(schema_name, schema_encoding, b"string data")
        channel_id = writer.register_channel("/foreign", message_encoding, schema_id)
        for i in range(5):
            writer.add_message(channel_id, log_time=i, data=data, publish_time=i)
        writer.finish()
    return path


# -- normal reading --------------------------------------------------------------------------

def test_reads_directory_and_bare_file_alike(sample_bag: Path) -> None:
    from_dir = open_bag(sample_bag)
    from_file = open_bag(sample_bag / f"bag{BagFormat.FILE_SUFFIX}")
    assert list(from_dir) == list(from_file)
    assert not from_dir.truncated and from_dir.problem is None
    assert from_dir.config == CONFIG
    assert from_dir.message_count == 60
    assert {t: i.type_name for t, i in from_dir.topics.items()} == {
        "/circles/a": STATES_TYPE, "/collision_predictions": PREDICTIONS_TYPE}
    assert from_dir.topics["/circles/a"].definition == full_msg_definition(STATES_TYPE)
    assert (from_dir.start_time_ns, from_dir.end_time_ns) == (T0, T0 + 59 * 10**6)


def test_records_are_in_log_time_order_and_filterable(sample_bag: Path) -> None:
    records = list(open_bag(sample_bag))
    assert [r.log_time_ns for r in records] == [T0 + k * 10**6 for k in range(60)]
    assert [r.topic for r in records[:2]] == ["/circles/a", "/collision_predictions"]
    states = list(open_bag(sample_bag).records(["/circles/a"]))
    assert [deserialize_message(r.data, CircleStateArray) for r in states] == [
        make_states(i) for i in range(30)]
    assert states[0].publish_time_ns == states[0].log_time_ns


def test_out_of_order_log_times_across_chunks_are_sorted(tmp_path: Path) -> None:
    rng = random.Random(4)
    times = [T0 + i * 1000 + rng.randint(-5000, 5000) for i in range(400)]
    with BagRecorder(tmp_path / "bag", max_chunk_bytes=2048) as bag:
        bag.add_topic("/circles/a", STATES_TYPE)
        for i, t in enumerate(times):
            bag.write("/circles/a", serialize_message(make_states(i)), t)
    records = read_all(tmp_path / "bag")
    assert [r.log_time_ns for r in records] == sorted(times)


def test_directory_without_metadata_yaml_still_reads(tmp_path: Path) -> None:
    bag = record_sample_bag(tmp_path / "bag", count=3)
    (bag / "metadata.yaml").unlink()
    assert len(read_all(bag)) == 6


def test_bag_with_unrelated_topics_ignores_them(tmp_path: Path) -> None:
    with BagRecorder(tmp_path / "bag") as bag:
        bag.add_topic("/circles/a", STATES_TYPE)
        bag.add_topic("/chatter", "std_msgs/msg/String")
        bag.write("/chatter", b"\x00\x01\x00\x00\x03\x00\x00\x00hi\x00\x00", T0)
        bag.write("/circles/a", serialize_message(make_states(0)), T0 + 1)
    contents = open_bag(tmp_path / "bag")
    assert contents.ignored_topics == {"/chatter": "std_msgs/msg/String"}
    assert [r.topic for r in contents] == ["/circles/a"]


# -- bad input -------------------------------------------------------------------------------

def test_missing_path(tmp_path: Path) -> None:
    with pytest.raises(BagError, match=r"nothing_here: no such file"):
        open_bag(tmp_path / "nothing_here")


def test_empty_and_random_files(tmp_path: Path) -> None:
    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    with pytest.raises(BagError, match=r"empty.mcap: empty file"):
        open_bag(empty, tolerant=True)
    noise = tmp_path / "noise.mcap"
    noise.write_bytes(random.Random(1).randbytes(5000))
    with pytest.raises(BagError, match=r"noise.mcap: not an MCAP file"):
        open_bag(noise)
    (tmp_path / "dir").mkdir()
    with pytest.raises(BagError, match=r"dir: bag directory has no .mcap file"):
        open_bag(tmp_path / "dir")


def test_huge_declared_length_fails_fast(tmp_path: Path) -> None:
    path = tmp_path / "huge.mcap"
    path.write_bytes(Limits.MAGIC + struct.pack("<BQ", 0x01, 2**63) + b"\0" * 16)
    with time_limit(HANG_GUARD_S), small_allocations(), \
            pytest.raises(BagError, match=r"huge.mcap: truncated: .*declares"):
        open_bag(path)


@pytest.mark.parametrize("fraction", [0.02, 0.3, 0.6, 0.97, 0.9999])
def test_truncated_file_strict_vs_tolerant(tmp_path: Path, sample_bytes: bytes,
                                           fraction: float) -> None:
    path = tmp_path / "cut.mcap"
    path.write_bytes(sample_bytes[:int(len(sample_bytes) * fraction)])
    with pytest.raises(BagError, match=r"cut.mcap: truncated.*tolerant=True"):
        open_bag(path)
    try:
        contents = open_bag(path, tolerant=True)
    except BagError as error:  # cut before the first chunk: nothing to recover
        assert fraction < 0.1 and "cut.mcap: no channels" in str(error)
        assert "reading stopped early: truncated" in str(error)
        return
    assert contents.truncated and contents.problem.startswith("truncated")
    records = list(contents)
    assert records and [r.log_time_ns for r in records] == [
        T0 + k * 10**6 for k in range(len(records))]
    expected = {2 * i: make_states(i) for i in range(30)}
    for k, record in enumerate(records):
        if record.topic == "/circles/a":
            assert deserialize_message(record.data, CircleStateArray) == expected[k]


def test_bit_flip_in_chunk_is_detected(tmp_path: Path, sample_bytes: bytes) -> None:
    data = bytearray(sample_bytes)
    data[len(data) // 3] ^= 0x10
    path = tmp_path / "flipped.mcap"
    path.write_bytes(bytes(data))
    with pytest.raises(BagError, match=r"flipped.mcap: .*(CRC|truncated|overrun|unknown)"):
        open_bag(path)
    contents = open_bag(path, tolerant=True)  # the chunks before the damage survive
    assert contents.truncated and 0 < contents.message_count < 60


def test_foreign_mcap_without_our_channels(tmp_path: Path) -> None:
    path = write_foreign_mcap(tmp_path / "foreign.mcap", "", "Foo", "jsonschema", "json")
    with pytest.raises(BagError,
                       match=r"foreign.mcap: no channels of types .*found: /foreign \(Foo\)"):
        open_bag(path)
    ros = write_foreign_mcap(tmp_path / "ros.mcap", "ros2", "std_msgs/msg/String", "ros2msg",
                             "cdr", b"\x00\x01\x00\x00\x01\x00\x00\x00\x00")
    with pytest.raises(BagError, match=r"ros.mcap: no channels"):
        open_bag(ros)


def test_our_type_with_foreign_encoding(tmp_path: Path) -> None:
    path = write_foreign_mcap(tmp_path / "idl.mcap", "ros2", STATES_TYPE, "ros2idl", "cdr")
    with pytest.raises(BagError, match=r"idl.mcap: topic /foreign .*'ros2idl'"):
        open_bag(path)
    path = write_foreign_mcap(tmp_path / "json.mcap", "ros2", STATES_TYPE, "ros2msg", "json")
    with pytest.raises(BagError, match=r"json.mcap: .*message encoding 'json'"):
        open_bag(path)


def test_foreign_zstd_ros2_bag_reads(tmp_path: Path) -> None:
    """Chunks compressed like `ros2 bag record` does by default also read."""
    path = tmp_path / "zstd.mcap"
    data = serialize_message(make_states(3))
    with open(path, "wb") as stream:
        writer = Writer(stream, compression=CompressionType.ZSTD)
        writer.start(profile="ros2")
        schema_id = writer.register_schema(STATES_TYPE, "ros2msg",
                                           full_msg_definition(STATES_TYPE).encode())
        channel_id = writer.register_channel("/circles/a", "cdr", schema_id)
        writer.add_message(channel_id, log_time=5, data=data, publish_time=5)
        writer.finish()
    assert [r.data for r in read_all(path)] == [data]


def test_every_single_bit_flip_is_caught_in_strict_mode(tmp_path: Path,
                                                        sample_bytes: bytes) -> None:
    """CRCs cover chunks, the data section and the summary: no silent corruption."""
    rng = random.Random(7)
    path = tmp_path / "flip.mcap"
    for _ in range(150):
        data = bytearray(sample_bytes)
        position = rng.randrange(len(data))
        data[position] ^= 1 << rng.randrange(8)
        path.write_bytes(bytes(data))
        with time_limit(HANG_GUARD_S), pytest.raises(BagError, match="flip.mcap: "):
            open_bag(path)


@settings(max_examples=examples(50, 150), deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.data())
def test_mutations_raise_only_bag_error(tmp_path: Path, sample_bytes: bytes,
                                        data: st.DataObject) -> None:
    mutated = bytearray(sample_bytes)
    for _ in range(data.draw(st.integers(1, 4))):
        kind = data.draw(st.sampled_from(["set", "truncate", "insert", "delete", "length"]))
        position = data.draw(st.integers(0, max(len(mutated) - 1, 0)))
        if kind == "set" and mutated:
            mutated[position] = data.draw(st.integers(0, 255))
        elif kind == "truncate":
            del mutated[position:]
        elif kind == "insert":
            mutated[position:position] = data.draw(st.binary(min_size=1, max_size=16))
        elif kind == "delete":
            del mutated[position:position + data.draw(st.integers(1, 16))]
        elif kind == "length" and len(mutated) >= position + 8:
            mutated[position:position + 8] = struct.pack("<Q", data.draw(st.sampled_from(
                [0, 1, 2**31, 2**32 + 5, 2**62, 2**64 - 1])))
    path = tmp_path / "mutant.mcap"
    path.write_bytes(bytes(mutated))
    tolerant = data.draw(st.booleans())
    with time_limit(HANG_GUARD_S):
        try:
            contents = open_bag(path, tolerant=tolerant)
            for record in contents:
                assert isinstance(record.data, bytes)
        except BagError as error:
            assert str(error).startswith(str(path)) and "\n" not in str(error)


def test_huge_length_inside_a_record_allocates_nothing(tmp_path: Path, sample_bytes: bytes) -> None:
    """A chunk whose records field claims 2**62 bytes fails at once, strict and tolerant."""
    data = bytearray(sample_bytes)
    pos = len(Limits.MAGIC)
    while data[pos] != 0x06:  # the first chunk record
        pos += 9 + struct.unpack_from("<Q", data, pos + 1)[0]
    compression_length = struct.unpack_from("<I", data, pos + 9 + 28)[0]
    struct.pack_into("<Q", data, pos + 9 + 32 + compression_length, 2**62)
    path = tmp_path / "liar.mcap"
    path.write_bytes(bytes(data))
    with time_limit(HANG_GUARD_S), small_allocations(), \
            pytest.raises(BagError, match=r"liar.mcap: truncated: .* needs 4611686018427387904"):
        open_bag(path)
    with time_limit(HANG_GUARD_S), small_allocations(), \
            pytest.raises(BagError, match=r"liar.mcap: no channels.*stopped early: truncated"):
        open_bag(path, tolerant=True)
