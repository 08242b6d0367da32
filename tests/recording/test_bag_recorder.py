"""Tests of BagRecorder: rosbag2/MCAP compatibility, failure modes, crash safety.

No ROS graph: messages are serialized with rclpy.serialization only.
"""
from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import pytest
import yaml
from circle_collision_msgs.msg import (CircleState, CircleStateArray, CollisionPrediction,
                                       CollisionPredictionArray)
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rclpy.serialization import deserialize_message, serialize_message

from circle_collision_ros.recording.bag_reader import BagError, open_bag
from circle_collision_ros.recording.bag_recorder import (BagFormat, BagRecorder, RecordingError,
                                                         qos_profiles_yaml)
from circle_collision_ros.recording.ros_type_definitions import (DefinitionFormat,
                                                                 TypeDefinitionError,
                                                                 full_msg_definition)

STATES_TYPE = "circle_collision_msgs/msg/CircleStateArray"
PREDICTIONS_TYPE = "circle_collision_msgs/msg/CollisionPredictionArray"
T0 = 1_700_000_000_000_000_000
CONFIG = {"horizon": 5.0, "dimensions": 2, "frame_id": "map", "stale_timeout": 0.5,
          "report_all_pairs": False, "publish_rate": 20.0,
          "state_topics": ["/circles/a", "/circles/b"]}


def make_states(i: int) -> CircleStateArray:
    msg = CircleStateArray()
    msg.header.stamp.sec = 100 + i
    msg.header.stamp.nanosec = 7 * i
    msg.header.frame_id = f"seq{i}"
    for k in range(2):
        circle = CircleState()
        circle.header.stamp.sec = 100 + i
        circle.id = f"body{k}"
        circle.radius = 0.5 + k
        circle.position.x = float(i)
        circle.position.y = -float(k)
        circle.velocity.x = 1.25
        circle.acceleration.z = -9.81
        circle.remove = k == 1
        if k == 0:  # the bounded sequence float64[<=36]: empty on body1, 36 values on body0
            circle.covariance = [i + j / 64.0 for j in range(36)]
        msg.circles.append(circle)
    return msg


def make_predictions(i: int) -> CollisionPredictionArray:
    msg = CollisionPredictionArray()
    msg.header.stamp.sec = 100 + i
    msg.header.frame_id = "map"
    msg.horizon = 5.0
    prediction = CollisionPrediction()
    prediction.id_a, prediction.id_b = "body0", "body1"
    prediction.status = CollisionPrediction.CONTACT
    prediction.time_to_collision = 0.25 * i
    prediction.contact_time.sec = 101 + i
    prediction.contact_point.x = 1.5
    prediction.normal.y = 1.0
    prediction.closing_speed = 2.0
    prediction.collision_probability = 0.5 + i / 1024.0
    prediction.collision_probability_bound = 1e-9
    prediction.plausible_time_to_collision = 0.125 * i
    msg.predictions.append(prediction)
    return msg


def record_sample_bag(bag_dir: Path, count: int = 50, **kwargs: object) -> Path:
    """A closed bag with `count` state and `count` prediction messages, plus the config."""
    with BagRecorder(bag_dir, **kwargs) as bag:  # type: ignore[arg-type]
        bag.add_topic("/circles/a", STATES_TYPE)
        bag.add_topic("/collision_predictions", PREDICTIONS_TYPE)
        bag.write_config(CONFIG)
        for i in range(count):
            bag.write("/circles/a", serialize_message(make_states(i)), T0 + 2 * i * 10**6)
            bag.write("/collision_predictions", serialize_message(make_predictions(i)),
                      T0 + (2 * i + 1) * 10**6)
    return bag_dir


# -- type definitions ------------------------------------------------------------------------

def test_full_definition_matches_rosbag2_layout() -> None:
    text = full_msg_definition(STATES_TYPE)
    sections = text.split(f"\n{DefinitionFormat.SEPARATOR}\n")
    names = [s.splitlines()[0] for s in sections[1:]]
    # Depth-first, sorted per level, each type once -- as rosbag2 writes it.
    assert names == ["MSG: circle_collision_msgs/CircleState", "MSG: geometry_msgs/Point",
                     "MSG: geometry_msgs/Vector3", "MSG: std_msgs/Header",
                     "MSG: builtin_interfaces/Time"]
    assert sections[0].startswith("# A set of circle states")
    assert full_msg_definition("circle_collision_msgs/CircleStateArray") == text


def test_unknown_type_definition_raises() -> None:
    with pytest.raises(TypeDefinitionError, match="no_such_pkg"):
        full_msg_definition("no_such_pkg/msg/Nothing")
    with pytest.raises(TypeDefinitionError, match="invalid"):
        full_msg_definition("not a type")


# -- compatibility with other readers --------------------------------------------------------

def test_mcap_ros2_decoder_reads_fields(tmp_path: Path) -> None:
    bag = record_sample_bag(tmp_path / "bag")
    mcap_file = bag / f"bag{BagFormat.FILE_SUFFIX}"
    with open(mcap_file, "rb") as stream:
        reader = make_reader(stream, validate_crcs=True, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == "ros2"
        states, predictions = [], []
        for schema, channel, message, decoded in reader.iter_decoded_messages():
            assert schema is not None and schema.encoding == "ros2msg"
            assert channel.message_encoding == "cdr"
            assert set(channel.metadata) == {"offered_qos_profiles", "topic_type_hash"}
            assert channel.metadata["topic_type_hash"].startswith("RIHS01_")
            (states if channel.topic == "/circles/a" else predictions).append((message, decoded))
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
    assert len(states) == len(predictions) == 50
    message, decoded = states[7]
    assert message.log_time == T0 + 14 * 10**6
    assert (decoded.header.stamp.sec, decoded.header.stamp.nanosec) == (107, 49)
    assert decoded.header.frame_id == "seq7"
    assert [c.id for c in decoded.circles] == ["body0", "body1"]
    assert decoded.circles[1].radius == 1.5 and decoded.circles[1].remove is True
    assert decoded.circles[0].position.x == 7.0 and decoded.circles[0].acceleration.z == -9.81
    assert list(decoded.circles[0].covariance) == [7 + j / 64.0 for j in range(36)]
    assert list(decoded.circles[1].covariance) == []
    _, prediction = predictions[3]
    assert prediction.horizon == 5.0
    assert prediction.predictions[0].status == 1
    assert prediction.predictions[0].time_to_collision == 0.75
    assert prediction.predictions[0].contact_time.sec == 104
    assert (
        prediction.predictions[0].collision_probability,
        prediction.predictions[0].collision_probability_bound,
        prediction.predictions[0].plausible_time_to_collision,
    ) == (0.5 + 3 / 1024.0, 1e-9, 0.375)
    config = metadata[BagFormat.CONFIG_METADATA_NAME]
    assert {k: yaml.safe_load(v) for k, v in config.items()} == CONFIG
    assert "serialized_metadata" in metadata[BagFormat.ROSBAG2_METADATA_NAME]


@pytest.mark.parametrize("target", ["directory", "mcap_file"])
def test_rosbags_reads_with_embedded_definitions_only(tmp_path: Path, target: str) -> None:
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    bag = record_sample_bag(tmp_path / "bag", count=20)
    path = bag if target == "directory" else bag / f"bag{BagFormat.FILE_SUFFIX}"
    typestore = get_typestore(Stores.EMPTY)  # no std_msgs etc.: all from the bag
    with Reader(path) as reader:
        assert reader.message_count == 40
        for connection in reader.connections:
            typestore.register(get_types_from_msg(connection.msgdef.data, connection.msgtype))
        decoded = [
            (c.topic, t, typestore.deserialize_cdr(raw, c.msgtype))
            for c, t, raw in reader.messages()
        ]
    assert [t for _, t, _ in decoded] == sorted(t for _, t, _ in decoded)
    states = [m for topic, _, m in decoded if topic == "/circles/a"]
    assert states[5].header.frame_id == "seq5"
    assert states[5].circles[0].velocity.x == 1.25
    assert list(states[5].circles[0].covariance) == [5 + j / 64.0 for j in range(36)]
    assert len(states[5].circles[1].covariance) == 0
    predictions = [m for topic, _, m in decoded if topic == "/collision_predictions"]
    assert predictions[2].predictions[0].id_b == "body1"
    assert predictions[2].predictions[0].collision_probability == 0.5 + 2 / 1024.0
    assert predictions[2].predictions[0].plausible_time_to_collision == 0.25


def test_bytes_are_recorded_unchanged(tmp_path: Path) -> None:
    bag = record_sample_bag(tmp_path / "bag", count=5)
    records = list(open_bag(bag))
    assert [
        deserialize_message(r.data, CircleStateArray) for r in records if r.topic == "/circles/a"
    ] == [make_states(i) for i in range(5)]
    # Fast CDR leaves alignment padding uninitialised, so compare with the very bytes written.
    written = [serialize_message(make_states(i)) for i in range(3)]
    with BagRecorder(tmp_path / "exact") as exact:
        exact.add_topic("/circles/a", STATES_TYPE)
        for i, data in enumerate(written):
            exact.write("/circles/a", data, T0 + i)
    assert [r.data for r in open_bag(tmp_path / "exact").records()] == written


def test_metadata_yaml_matches_rosbag2(tmp_path: Path) -> None:
    bag = record_sample_bag(tmp_path / "bag", count=10)
    info = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert info["version"] == 9 and info["storage_identifier"] == "mcap"
    assert info["ros_distro"] == "kilted"
    assert info["relative_file_paths"] == ["bag_0.mcap"]
    assert info["message_count"] == 20
    assert info["starting_time"]["nanoseconds_since_epoch"] == T0
    assert info["duration"]["nanoseconds"] == 19 * 10**6
    assert info["files"][0]["message_count"] == 20
    topics = {t["topic_metadata"]["name"]: t for t in info["topics_with_message_count"]}
    assert topics["/circles/a"]["message_count"] == 10
    assert topics["/circles/a"]["topic_metadata"]["type"] == STATES_TYPE
    assert topics["/circles/a"]["topic_metadata"]["serialization_format"] == "cdr"
    assert topics["/circles/a"]["topic_metadata"]["type_description_hash"].startswith("RIHS01_")
    assert info["custom_data"][BagFormat.STATE_KEY] == BagFormat.STATE_CLOSED


def test_qos_yaml_is_stored_and_parsed(tmp_path: Path) -> None:
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from rosbags.rosbag2 import Reader

    qos = qos_profiles_yaml([QoSProfile(depth=7, reliability=ReliabilityPolicy.BEST_EFFORT)])
    with BagRecorder(tmp_path / "bag") as bag:
        bag.add_topic("/circles/a", STATES_TYPE, qos)
        bag.write("/circles/a", serialize_message(make_states(0)), T0)
    with Reader(tmp_path / "bag") as reader:
        profile = reader.connections[0].ext.offered_qos_profiles[0]
    assert profile.depth == 7 and profile.reliability.name == "BEST_EFFORT"
    assert open_bag(tmp_path / "bag").topics["/circles/a"].offered_qos == qos


# -- API contract and failures ---------------------------------------------------------------


def test_refuses_non_empty_directory(tmp_path: Path) -> None:
    (tmp_path / "bag").mkdir()
    (tmp_path / "bag" / "old.txt").write_text("x")
    with pytest.raises(RecordingError, match=r"bag: directory exists and is not empty"):
        BagRecorder(tmp_path / "bag")


def test_accepts_existing_empty_directory(tmp_path: Path) -> None:
    (tmp_path / "bag").mkdir()
    BagRecorder(tmp_path / "bag").close()
    assert (tmp_path / "bag" / "metadata.yaml").is_file()


def test_refuses_unwritable_paths(tmp_path: Path) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(RecordingError, match="file: exists and is not a directory"):
        BagRecorder(blocker)
    with pytest.raises(RecordingError, match=r"cannot record to .*file/sub"):
        BagRecorder(blocker / "sub")


def test_topic_errors(tmp_path: Path) -> None:
    with BagRecorder(tmp_path / "bag") as bag:
        with pytest.raises(RecordingError, match="no_such_pkg"):
            bag.add_topic("/x", "no_such_pkg/msg/Nothing")
        bag.add_topic("/circles/a", STATES_TYPE)
        bag.add_topic("/circles/a", STATES_TYPE)  # same type again: fine
        with pytest.raises(RecordingError, match="already recorded"):
            bag.add_topic("/circles/a", PREDICTIONS_TYPE)
        with pytest.raises(RecordingError, match="was not added"):
            bag.write("/nope", b"\0\1\0\0", T0)
        with pytest.raises(RecordingError, match="out of range"):
            bag.write("/circles/a", b"\0\1\0\0", -1)
        with pytest.raises(RecordingError, match="JSON"):
            bag.write_config({"bad": object()})


def test_close_is_idempotent_and_final(tmp_path: Path) -> None:
    bag = BagRecorder(tmp_path / "bag")
    bag.add_topic("/circles/a", STATES_TYPE)
    bag.close()
    bag.close()
    with pytest.raises(RecordingError, match="closed"):
        bag.write("/circles/a", serialize_message(make_states(0)), T0)
    assert open_bag(tmp_path / "bag").message_count == 0


def test_removed_bag_directory_raises_recording_error(tmp_path: Path) -> None:
    bag = BagRecorder(tmp_path / "bag", max_chunk_age_s=0.05)
    bag.add_topic("/circles/a", STATES_TYPE)
    data = serialize_message(make_states(0))
    bag.write("/circles/a", data, T0)
    shutil.rmtree(tmp_path / "bag")
    deadline = time.monotonic() + 5.0
    with pytest.raises(RecordingError, match=r"recording to .*bag_0.mcap failed"):
        i = 1
        while time.monotonic() < deadline:
            bag.write("/circles/a", data, T0 + i)
            i += 1
            time.sleep(0.005)
    with pytest.raises(RecordingError):  # sticky
        bag.write("/circles/a", data, T0 + 10**9)
    assert bag.error is not None
    with pytest.raises(RecordingError):
        bag.close()


def test_concurrent_writers(tmp_path: Path) -> None:
    topics = [f"/circles/{k}" for k in range(4)]
    data = serialize_message(make_states(1))
    with BagRecorder(tmp_path / "bag", max_chunk_bytes=16 * 1024) as bag:
        for topic in topics:
            bag.add_topic(topic, STATES_TYPE)

        def writer(topic: str) -> None:
            for i in range(300):
                bag.write(topic, data, time.time_ns())

        threads = [threading.Thread(target=writer, args=(t,)) for t in topics]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join()
        assert bag.message_counts() == dict.fromkeys(topics, 300)
    contents = open_bag(tmp_path / "bag")
    assert {t: i.message_count for t, i in contents.topics.items()} == dict.fromkeys(topics, 300)
    times = [r.log_time_ns for r in contents]
    assert len(times) == 1200 and times == sorted(times)


def test_idle_chunk_reaches_disk_within_max_age(tmp_path: Path) -> None:
    bag = BagRecorder(tmp_path / "bag", max_chunk_age_s=0.2)
    try:
        bag.add_topic("/circles/a", STATES_TYPE)
        for i in range(3):
            bag.write("/circles/a", serialize_message(make_states(i)), T0 + i)
        # No more writes: only the background flush can commit them. Wait for it (polling,
        # not a fixed sleep); the deadline only guards against a flush that never comes.
        deadline = time.monotonic() + 30.0
        while True:
            try:
                contents = open_bag(tmp_path / "bag", tolerant=True)
                if contents.message_count == 3:
                    break
            except BagError:  # no chunk on disk yet
                pass
            assert time.monotonic() < deadline, "the idle chunk never reached the disk"
            time.sleep(0.05)
        assert contents.truncated and contents.message_count == 3
        info = yaml.safe_load((tmp_path / "bag" / "metadata.yaml").read_text())
        info = info["rosbag2_bagfile_information"]
        assert info["custom_data"][BagFormat.STATE_KEY] == BagFormat.STATE_RECORDING
        assert info["topics_with_message_count"][0]["topic_metadata"]["name"] == "/circles/a"
    finally:
        bag.close()


_KILL_CHILD = textwrap.dedent("""
    import sys, time
    from rclpy.serialization import serialize_message
    from circle_collision_ros.recording.bag_recorder import BagRecorder
    from tests.recording.test_bag_recorder import make_states, make_predictions, CONFIG

    bag = BagRecorder(sys.argv[1])
    bag.add_topic("/circles/a", "circle_collision_msgs/msg/CircleStateArray")
    bag.add_topic("/collision_predictions", "circle_collision_msgs/msg/CollisionPredictionArray")
    bag.write_config(CONFIG)
    i = 0
    while True:
        now = time.time_ns()
        bag.write("/circles/a", serialize_message(make_states(i)), now)
        bag.write("/collision_predictions", serialize_message(make_predictions(i)), now + 1)
        i += 1
        if i % 50 == 0:
            print(i, time.monotonic(), flush=True)
        time.sleep(0.001)
""")


@pytest.mark.stress
def test_hard_kill_keeps_everything_but_the_open_chunk(tmp_path: Path) -> None:
    """Count, don't time: once the child has written 200 pairs and a tolerant reader sees
    them on disk (a chunk closed by age or size), SIGKILL it mid-write. Everything seen on
    disk before the kill is still there after it, in order and intact."""
    script = tmp_path / "child.py"
    script.write_text(_KILL_CHILD)
    bag_dir = tmp_path / "bag"
    repo = Path(__file__).resolve().parents[2]
    child = subprocess.Popen([sys.executable, str(script), str(bag_dir)], cwd=repo,
                             stdout=subprocess.PIPE, text=True,
                             env={**os.environ, "PYTHONPATH": str(repo)})
    safe = 0
    try:
        deadline = time.monotonic() + 60.0  # only a guard against a hang
        for line in child.stdout:  # type: ignore[union-attr]
            if int(line.split()[0]) >= 200:
                break
            assert time.monotonic() < deadline
        else:
            raise AssertionError("recorder child did not write 200 messages")
        while safe < 200:  # the written messages reach the disk (the child keeps writing)
            assert time.monotonic() < deadline, f"only {safe} states on disk"
            try:
                safe = open_bag(bag_dir, tolerant=True).topics["/circles/a"].message_count
            except (BagError, KeyError):  # no complete chunk yet
                pass
            time.sleep(0.05)
    finally:
        child.send_signal(signal.SIGKILL)
        child.communicate(timeout=10)
    assert safe >= 200

    contents = open_bag(bag_dir, tolerant=True)
    assert contents.truncated and contents.problem
    assert contents.config == CONFIG
    states = [
        deserialize_message(r.data, CircleStateArray) for r in contents.records(["/circles/a"])
    ]
    assert len(states) >= safe
    assert [s.header.frame_id for s in states] == [f"seq{i}" for i in range(len(states))]
    assert states[-1] == make_states(len(states) - 1)
    predictions = [
        deserialize_message(r.data, CollisionPredictionArray)
        for r in contents.records(["/collision_predictions"])
    ]
    assert predictions[len(predictions) // 2] == make_predictions(len(predictions) // 2)
    info = yaml.safe_load((bag_dir / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert info["custom_data"][BagFormat.STATE_KEY] == BagFormat.STATE_RECORDING
    assert 0 < info["message_count"] <= contents.message_count
