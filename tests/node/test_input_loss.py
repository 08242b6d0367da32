"""InputLossMonitor's accounting rules (DDS measurements: tests/node/test_transport_profile.py)."""

from __future__ import annotations

from circle_collision_ros.node.input_loss import InputLossMonitor, LossThresholds


def info(seq: int, writer: bytes = b"w1") -> dict:
    return {"publication_sequence_number": seq, "publisher_gid": {"data": writer}}


def test_gaps_are_counted_per_publisher_and_the_first_sample_only_starts_the_count() -> None:
    m = InputLossMonitor()
    assert m.observe("/s", 100, info(7), 0) == 0  # joined late: 1..6 are not ours to count
    assert m.observe("/s", 100, info(8), 1) == 0
    assert m.observe("/s", 100, info(11), 2) == 2  # 9 and 10 never arrived
    assert m.observe("/s", 100, info(1, b"w2"), 3) == 0  # another publisher has its own numbers
    assert m.observe("/s", 100, info(2, b"w2"), 4) == 0
    # late or repeated: no loss, no double count
    assert m.observe("/s", 100, info(10), 5) == 0
    assert m.observe("/s", 100, info(12), 6) == 0
    assert m.missing == 2 and m.topics["/s"].received == 7


def test_no_sequence_numbers_means_no_claims() -> None:
    m = InputLossMonitor()
    for k in range(5):
        assert m.observe("/s", 100, None, k) == 0
        assert (
            m.observe("/s", 100, {"publication_sequence_number": None, "publisher_gid": None}, k)
            == 0
        )
    assert m.missing == 0 and m.new_losses() == []


def test_losses_of_large_frames_point_to_the_transport_profile_once() -> None:
    m = InputLossMonitor()
    big = LossThresholds.LARGE_MESSAGE_BYTES + 1
    m.observe("/big", big, info(1), 0)
    m.observe("/big", big, info(5), 1)
    m.observe("/small", 100, info(1, b"w9"), 0)
    m.observe("/small", 100, info(3, b"w9"), 1)
    lines = m.new_losses()
    assert len(lines) == 2
    big_line = next(line for line in lines if line.startswith("/big"))
    assert "3 input message(s)" in big_line and "fastdds_large_scenes.xml" in big_line
    small_line = next(line for line in lines if line.startswith("/small"))
    assert "fastdds_large_scenes.xml" not in small_line and "falling behind" in small_line
    assert m.new_losses() == []  # reported once; the next loss is reported again
    m.observe("/big", big, info(7), 2)
    assert len(m.new_losses()) == 1


def test_silent_publishers_are_forgotten() -> None:
    m = InputLossMonitor()
    m.observe("/s", 100, info(1, b"a"), 0)
    m.observe("/s", 100, info(1, b"b"), LossThresholds.FORGET_AFTER_NS)
    m.forget_silent(LossThresholds.FORGET_AFTER_NS + 1)
    assert list(m.topics["/s"].publishers) == [b"b"]
