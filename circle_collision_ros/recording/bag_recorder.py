"""Record serialized ROS 2 messages to a rosbag2-compatible MCAP bag directory.

A bag directory holds ``metadata.yaml`` (rosbag2 format, version 9) and one
``<dir>_0.mcap`` file (MCAP profile ``ros2``, schemas ``ros2msg`` with full
dependency text, messages ``cdr``), so it opens with ``ros2 bag``, rosbags, the
``mcap`` Python reader with ``mcap-ros2-support`` and Foxglove, without our
interface package installed.

Crash safety
------------
Messages are buffered in an MCAP chunk that is closed and handed to the OS
(``flush``; no ``fsync``) when it exceeds :attr:`ChunkLimits.MAX_BYTES` or its
oldest message is :attr:`ChunkLimits.MAX_AGE_S` old (a background thread covers
idle periods). A SIGKILL therefore loses at most the open chunk -- about 1 s
or 1 MiB of messages -- plus the MCAP summary/footer; the rest reads back with
``circle_collision_ros.recording.bag_reader.open_bag(path, tolerant=True)``. An OS crash
or power loss can lose more (page cache); only :meth:`BagRecorder.close` fsyncs.

``metadata.yaml`` is written at start, rewritten (atomically, via rename) at
most once a second after a chunk reaches the OS, and finally at close. After a
hard kill it thus lists every topic with counts that are at most ~1 s behind
the data in the MCAP file, and ``custom_data`` says
``circle_collision_ros/recording_state: recording`` instead of ``closed``.
``ros2 bag reindex`` can rebuild it exactly.
"""
from __future__ import annotations

import atexit
import json
import os
import threading
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, BinaryIO

import yaml
from mcap.writer import LIBRARY_IDENTIFIER, CompressionType, Writer

from .ros_type_definitions import TypeDefinitionError, full_msg_definition, type_description_hash

__all__ = ["BagFormat", "BagRecorder", "ChunkLimits", "RecordingError", "qos_profiles_yaml"]


class BagFormat:
    """Names and versions shared by the recorder and the reader."""

    PROFILE = "ros2"
    SCHEMA_ENCODING = "ros2msg"
    MESSAGE_ENCODING = "cdr"
    STORAGE_IDENTIFIER = "mcap"
    METADATA_FILE = "metadata.yaml"
    METADATA_VERSION = 9  # rosbag2 Jazzy/Kilted
    ROS_DISTRO = "kilted"
    FILE_SUFFIX = "_0.mcap"
    CONFIG_METADATA_NAME = "circle_collision_ros/config"
    ROSBAG2_METADATA_NAME = "rosbag2"  # rosbag2 also embeds metadata.yaml under this name
    CHANNEL_QOS_KEY = "offered_qos_profiles"
    CHANNEL_TYPE_HASH_KEY = "topic_type_hash"
    STATE_KEY = "circle_collision_ros/recording_state"
    STATE_RECORDING = "recording"
    STATE_CLOSED = "closed"
    LIBRARY = f"circle_collision_ros; {LIBRARY_IDENTIFIER}"


class ChunkLimits:
    """Bounds on the data a hard kill can lose (the open chunk)."""

    MAX_BYTES = 1024 * 1024
    MAX_AGE_S = 1.0
    METADATA_REFRESH_S = 1.0


class RecordingError(RuntimeError):
    """The bag cannot be created or written; the message names the path."""


_UINT64_MAX = 2**64 - 1


def qos_profiles_yaml(profiles: Sequence[Any]) -> str:
    """Format QoS profiles as rosbag2's ``offered_qos_profiles`` YAML string.

    Parameters
    ----------
    profiles
        ``rclpy.qos.QoSProfile`` objects (duck-typed; rclpy is not imported) or
        mappings already in rosbag2's form.

    Returns
    -------
    str
        A YAML list, e.g. ``- history: keep_last\\n  depth: 10 ...``; ``""`` for none.
    """
    def duration(value: Any) -> dict[str, int]:
        nanoseconds = int(getattr(value, "nanoseconds", 0))
        return {"sec": nanoseconds // 10**9, "nsec": nanoseconds % 10**9}

    def policy(value: Any) -> str:
        return str(getattr(value, "name", value)).lower()

    items: list[Mapping[str, Any]] = []
    for profile in profiles:
        if isinstance(profile, Mapping):
            items.append(dict(profile))
            continue
        items.append({
            "history": policy(profile.history),
            "depth": int(profile.depth),
            "reliability": policy(profile.reliability),
            "durability": policy(profile.durability),
            "deadline": duration(profile.deadline),
            "lifespan": duration(profile.lifespan),
            "liveliness": policy(profile.liveliness),
            "liveliness_lease_duration": duration(profile.liveliness_lease_duration),
            "avoid_ros_namespace_conventions": bool(profile.avoid_ros_namespace_conventions),
        })
    if not items:
        return ""
    return yaml.safe_dump(items, sort_keys=False, default_flow_style=False).strip()


class _TopicStats:
    __slots__ = ("channel_id", "type_name", "offered_qos", "type_hash", "count")

    def __init__(self, channel_id: int, type_name: str, offered_qos: str, type_hash: str):
        self.channel_id = channel_id
        self.type_name = type_name
        self.offered_qos = offered_qos
        self.type_hash = type_hash
        self.count = 0


class BagRecorder:
    """Thread-safe writer of one rosbag2 MCAP bag directory.

    Parameters
    ----------
    bag_dir
        Directory to create; it may exist only if empty.
    max_chunk_bytes, max_chunk_age_s
        Chunk bounds, see :class:`ChunkLimits`.

    Raises
    ------
    RecordingError
        If ``bag_dir`` is a file, a non-empty directory, or cannot be written.

    Examples
    --------
    >>> with BagRecorder("/tmp/run1") as bag:                      # doctest: +SKIP
    ...     bag.add_topic("/states", "circle_collision_msgs/msg/CircleStateArray")
    ...     bag.write("/states", serialize_message(msg), time.time_ns())
    """

    def __init__(self, bag_dir: str | os.PathLike[str], *,
                 max_chunk_bytes: int = ChunkLimits.MAX_BYTES,
                 max_chunk_age_s: float = ChunkLimits.MAX_AGE_S) -> None:
        self._dir = Path(bag_dir)
        self._file_name = f"{self._dir.name or 'bag'}{BagFormat.FILE_SUFFIX}"
        self._path = self._dir / self._file_name
        self._metadata_path = self._dir / BagFormat.METADATA_FILE
        self._max_age_s = float(max_chunk_age_s)
        self._lock = threading.Lock()
        self._topics: dict[str, _TopicStats] = {}
        self._schemas: dict[str, int] = {}
        self._start_ns: int | None = None
        self._end_ns = 0
        # Counts/times already handed to the OS: what metadata.yaml claims while recording.
        self._durable: tuple[dict[str, int], int | None, int] = ({}, None, 0)
        self._pending_count = 0
        self._pending_since = 0.0
        self._last_metadata_write = 0.0
        self._error: str | None = None
        self._closing = False
        self._closed = False

        self._file = self._create_file()
        try:
            self._inode = os.fstat(self._file.fileno()).st_ino
            self._writer = Writer(self._file, chunk_size=int(max_chunk_bytes),
                                  compression=CompressionType.NONE, enable_data_crcs=True)
            self._writer.start(profile=BagFormat.PROFILE, library=BagFormat.LIBRARY)
            self._file.flush()
            self._write_metadata_yaml(final=False)
        except OSError as exc:
            self._file.close()
            raise RecordingError(f"cannot record to {self._path}: {exc.strerror or exc}") from exc

        self._stop = threading.Event()
        self._flusher = threading.Thread(target=self._flush_periodically,
                                         name="bag_recorder_flush", daemon=True)
        self._flusher.start()
        atexit.register(self.close)

    # -- public API ---------------------------------------------------------------------------

    @property
    def path(self) -> Path:
        """The bag directory."""
        return self._dir

    @property
    def mcap_path(self) -> Path:
        """The MCAP file inside the bag directory."""
        return self._path

    @property
    def error(self) -> str | None:
        """Why recording stopped, if it failed; ``None`` while healthy."""
        return self._error

    def message_counts(self) -> dict[str, int]:
        """Messages written per topic so far."""
        with self._lock:
            return {topic: stats.count for topic, stats in self._topics.items()}

    def add_topic(self, topic: str, type_name: str, offered_qos: str = "",
                  definition: str | None = None) -> None:
        """Declare a topic before writing to it.

        Parameters
        ----------
        topic
            Topic name, e.g. ``/circle_states``.
        type_name
            ``pkg/msg/Type``; its ``.msg`` file (and those of its dependencies)
            must be installed.
        offered_qos
            rosbag2 ``offered_qos_profiles`` YAML (see :func:`qos_profiles_yaml`).
        definition
            The ``ros2msg`` schema text to record, when the bytes follow another
            definition than the installed one (copying an older recording); None:
            the installed definition.

        Raises
        ------
        RecordingError
            If the type definition is missing, the topic exists with another
            type, or writing fails.
        """
        with self._lock:
            self._check_usable()
            existing = self._topics.get(topic)
            if existing is not None:
                if existing.type_name != type_name:
                    raise RecordingError(
                        f"{self._path}: topic {topic} already recorded as {existing.type_name}, "
                        f"not {type_name}")
                return
            try:
                key = type_name if definition is None else (type_name, definition)
                schema_id = self._schemas.get(key)
                if schema_id is None:
                    text = full_msg_definition(type_name) if definition is None else definition
                    schema_id = self._writer.register_schema(
                        type_name, BagFormat.SCHEMA_ENCODING, text.encode("utf-8"))
                    self._schemas[key] = schema_id
                type_hash = type_description_hash(type_name)
                channel_id = self._writer.register_channel(
                    topic, BagFormat.MESSAGE_ENCODING, schema_id,
                    {BagFormat.CHANNEL_QOS_KEY: offered_qos,
                     BagFormat.CHANNEL_TYPE_HASH_KEY: type_hash})
            except TypeDefinitionError as exc:
                raise RecordingError(f"{self._path}: cannot record {topic}: {exc}") from exc
            self._topics[topic] = _TopicStats(channel_id, type_name, offered_qos, type_hash)
            self._guard_io(lambda: self._write_metadata_yaml(final=False))

    def set_offered_qos(self, topic: str, offered_qos: str) -> None:
        """Set a declared topic's ``offered_qos_profiles`` in metadata.yaml.

        For topics whose publishers become known only after add_topic (rosbag2
        records the QoS its publishers offer; ``ros2 bag play`` reads it from
        metadata.yaml). The MCAP channel keeps what add_topic was given: channel
        records cannot change once written.

        Raises
        ------
        RecordingError
            If the recorder failed or is closed, or the topic was not added.
        """
        with self._lock:
            self._check_usable()
            stats = self._topics.get(topic)
            if stats is None:
                raise RecordingError(f"{self._path}: topic {topic} was not added")
            if stats.offered_qos != offered_qos:
                stats.offered_qos = offered_qos
                self._guard_io(lambda: self._write_metadata_yaml(final=False))

    def write(self, topic: str, data: bytes | bytearray | memoryview, log_time_ns: int,
              publish_time_ns: int | None = None) -> None:
        """Record one serialized (CDR) message.

        Parameters
        ----------
        topic
            A topic declared with :meth:`add_topic`.
        data
            The message bytes as received/serialized, recorded unchanged.
        log_time_ns
            Receive time (ns since the epoch); the bag's log time.
        publish_time_ns
            Send time if known; defaults to ``log_time_ns``.

        Raises
        ------
        RecordingError
            If the topic is unknown, the recorder is closed or failed, or the
            write fails (disk full, file removed, ...). After a failure every
            further call raises too; already flushed chunks stay readable.
        """
        publish = log_time_ns if publish_time_ns is None else publish_time_ns
        if not (0 <= log_time_ns <= _UINT64_MAX and 0 <= publish <= _UINT64_MAX):
            raise RecordingError(f"{self._path}: time out of range for {topic}: {log_time_ns}")
        payload = bytes(data)
        with self._lock:
            self._check_usable()
            stats = self._topics.get(topic)
            if stats is None:
                raise RecordingError(f"{self._path}: topic {topic} was not added")

            def add() -> None:
                before = self._file.tell()
                self._writer.add_message(stats.channel_id, log_time=int(log_time_ns),
                                         data=payload, publish_time=int(publish))
                if self._pending_count == 0:
                    self._pending_since = time.monotonic()
                self._pending_count += 1
                stats.count += 1
                self._start_ns = log_time_ns if self._start_ns is None else min(
                    self._start_ns, log_time_ns)
                self._end_ns = max(self._end_ns, log_time_ns)
                if self._file.tell() != before:
                    # The Writer just emitted a full chunk into our buffered file.
                    self._commit()
                elif time.monotonic() - self._pending_since >= self._max_age_s:
                    self._writer.flush()
                    self._commit()

            self._guard_io(add)

    def write_config(self, config: Mapping[str, Any]) -> None:
        """Store the node configuration as MCAP metadata ``circle_collision_ros/config``.

        Each value is JSON-encoded (MCAP metadata values are strings); the
        reader decodes them back. Writing again adds a newer record; readers use
        the last one.

        Raises
        ------
        RecordingError
            If a value is not JSON-serializable or writing fails.
        """
        try:
            encoded = {str(key): json.dumps(value) for key, value in config.items()}
        except (TypeError, ValueError) as exc:
            raise RecordingError(
                f"{self._path}: configuration not JSON-serializable: {exc}") from exc
        with self._lock:
            self._check_usable()

            def add() -> None:
                self._writer.add_metadata(BagFormat.CONFIG_METADATA_NAME, encoded)
                self._file.flush()

            self._guard_io(add)

    def close(self) -> None:
        """Finish the MCAP file (summary, footer), fsync, and write final metadata.yaml.

        Idempotent. Raises :class:`RecordingError` if finishing fails; the file
        is closed regardless.
        """
        with self._lock:
            if self._closing:
                return
            self._closing = True
        self._stop.set()
        if self._flusher is not threading.current_thread():
            self._flusher.join()
        atexit.unregister(self.close)
        with self._lock:
            failure: str | None = None
            try:
                if self._error is None:
                    self._writer.add_metadata(BagFormat.ROSBAG2_METADATA_NAME, {
                        "serialized_metadata": self._metadata_yaml(final=True)})
                    self._writer.finish()
                    self._file.flush()
                    os.fsync(self._file.fileno())
            except (OSError, ValueError) as exc:
                failure = self._fail(exc)
            finally:
                self._closed = True
                try:
                    self._file.close()
                except OSError as exc:  # a failed final flush surfaces here
                    failure = failure or self._fail(exc)
            try:
                self._write_metadata_yaml(final=self._error is None)
            except OSError as exc:
                failure = failure or self._fail(exc)
            if failure is not None:
                raise RecordingError(failure)

    def __enter__(self) -> BagRecorder:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    # -- internals ----------------------------------------------------------------------------

    def _create_file(self) -> BinaryIO:
        if self._dir.exists():
            if not self._dir.is_dir():
                raise RecordingError(f"cannot record to {self._dir}: exists and is not a directory")
            try:
                if any(self._dir.iterdir()):
                    raise RecordingError(
                        f"cannot record to {self._dir}: directory exists and is not empty")
            except OSError as exc:
                raise RecordingError(
                    f"cannot record to {self._dir}: {exc.strerror or exc}") from exc
        try:
            self._dir.mkdir(parents=True, exist_ok=True)
            return open(self._path, "xb")  # noqa: SIM115 -- owned until close()
        except OSError as exc:
            raise RecordingError(f"cannot record to {self._dir}: {exc.strerror or exc}") from exc

    def _check_usable(self) -> None:
        if self._closing or self._closed:
            raise RecordingError(f"{self._path}: recorder is closed")
        if self._error is not None:
            raise RecordingError(self._error)

    def _guard_io(self, action: Any) -> None:
        """Run ``action``; turn I/O failures into a sticky :class:`RecordingError`."""
        try:
            action()
        except RecordingError:
            raise
        except (OSError, ValueError) as exc:  # ValueError: I/O on a closed file
            raise RecordingError(self._fail(exc)) from exc

    def _fail(self, exc: BaseException) -> str:
        reason = getattr(exc, "strerror", None) or str(exc) or type(exc).__name__
        if self._error is None:
            self._error = f"recording to {self._path} failed: {reason}"
        return self._error

    def _commit(self) -> None:
        """Hand finished chunks to the OS and note what is now crash-safe."""
        self._file.flush()
        self._pending_count = 0
        self._durable = ({t: s.count for t, s in self._topics.items()}, self._start_ns,
                         self._end_ns)
        now = time.monotonic()
        if now - self._last_metadata_write >= ChunkLimits.METADATA_REFRESH_S:
            self._check_file_still_there()
            self._write_metadata_yaml(final=False)

    def _check_file_still_there(self) -> None:
        # Writes to an unlinked file succeed silently on POSIX; detect it instead.
        try:
            same = os.stat(self._path).st_ino == self._inode
        except OSError:
            same = False
        if not same:
            raise FileNotFoundError(f"{self._path} was removed or replaced during recording")

    def _flush_periodically(self) -> None:
        tick = max(self._max_age_s / 4.0, 0.01)
        while not self._stop.wait(tick):
            with self._lock:
                if self._closing or self._error is not None:
                    return
                if (self._pending_count
                        and time.monotonic() - self._pending_since >= self._max_age_s):
                    try:
                        self._writer.flush()
                        self._commit()
                    except (OSError, ValueError) as exc:
                        self._fail(exc)
                        return

    def _metadata_yaml(self, final: bool) -> str:
        if final:
            counts = {t: s.count for t, s in self._topics.items()}
            start, end = self._start_ns, self._end_ns
        else:
            durable_counts, start, end = self._durable
            counts = {t: durable_counts.get(t, 0) for t in self._topics}
        total = sum(counts.values())
        start_ns = start if (start is not None and total) else 0
        duration = (end - start_ns) if total else 0
        topics = []
        for topic, stats in self._topics.items():
            try:
                qos = yaml.safe_load(stats.offered_qos) if stats.offered_qos else []
            except yaml.YAMLError:
                qos = []
            topics.append({
                "topic_metadata": {"name": topic, "type": stats.type_name,
                                   "serialization_format": BagFormat.MESSAGE_ENCODING,
                                   "offered_qos_profiles": qos if isinstance(qos, list) else [],
                                   "type_description_hash": stats.type_hash},
                "message_count": counts[topic],
            })
        info = {
            "version": BagFormat.METADATA_VERSION,
            "storage_identifier": BagFormat.STORAGE_IDENTIFIER,
            "duration": {"nanoseconds": duration},
            "starting_time": {"nanoseconds_since_epoch": start_ns},
            "message_count": total,
            "topics_with_message_count": topics,
            "compression_format": "",
            "compression_mode": "",
            "relative_file_paths": [self._file_name],
            "files": [{"path": self._file_name,
                       "starting_time": {"nanoseconds_since_epoch": start_ns},
                       "duration": {"nanoseconds": duration}, "message_count": total}],
            "custom_data": {
                BagFormat.STATE_KEY: (BagFormat.STATE_CLOSED if final
                                      else BagFormat.STATE_RECORDING),
            },
            "ros_distro": BagFormat.ROS_DISTRO,
        }
        return yaml.safe_dump({"rosbag2_bagfile_information": info}, sort_keys=False,
                              default_flow_style=False)

    def _write_metadata_yaml(self, final: bool) -> None:
        # Write-then-rename so a kill mid-write never leaves a half file.
        temporary = self._metadata_path.with_name(f".{BagFormat.METADATA_FILE}.tmp")
        temporary.write_text(self._metadata_yaml(final), encoding="utf-8")
        os.replace(temporary, self._metadata_path)
        self._last_metadata_write = time.monotonic()
