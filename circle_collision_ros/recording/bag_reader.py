"""Read recorded circle-collision messages back from a rosbag2 MCAP bag.

:func:`open_bag` takes a bag directory (``metadata.yaml`` + one ``.mcap``) or a
bare ``.mcap`` file, validates the whole file once (record framing, chunk and
data-section CRCs, summary CRC, channel/schema references) and returns a
:class:`BagContents` whose :meth:`~BagContents.records` yields
:class:`BagRecord` tuples in log-time order, re-reading one chunk at a time.

The parser is a small, self-contained MCAP reader rather than ``mcap.reader``:
every declared length is checked against the bytes that are really there, so
garbage (random bytes, bit flips, absurd lengths) ends in :class:`BagError`
quickly and without large allocations, and a file cut short by a hard kill
can be read up to its last complete chunk (``tolerant=True``).
"""
from __future__ import annotations

import heapq
import json
import os
import struct
import zlib
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO, NamedTuple

import yaml

from .bag_recorder import BagFormat

__all__ = [
    "BagContents",
    "BagError",
    "BagRecord",
    "Limits",
    "McapOpcode",
    "RECORDED_TYPES",
    "TopicInfo",
    "open_bag",
]

RECORDED_TYPES = frozenset({
    "circle_collision_msgs/msg/CircleStateArray",
    "circle_collision_msgs/msg/CollisionPredictionArray",
    "circle_collision_msgs/msg/CircleState",
    "nav_msgs/msg/Odometry",
})
"""Message types :func:`open_bag` yields by default; other channels are ignored."""


class McapOpcode:
    """MCAP record opcodes (https://mcap.dev/spec)."""

    HEADER = 0x01
    FOOTER = 0x02
    SCHEMA = 0x03
    CHANNEL = 0x04
    MESSAGE = 0x05
    CHUNK = 0x06
    DATA_END = 0x0F
    METADATA = 0x0C


class Limits:
    """Sanity bounds that keep garbage input from allocating or looping much."""

    MAGIC = b"\x89MCAP0\r\n"
    RECORD_PREFIX = 9          # opcode (1) + length (8)
    FOOTER_LENGTH = 20
    MAX_CHUNK_UNCOMPRESSED = 512 * 1024 * 1024


class BagError(Exception):
    """A bag cannot be read; the one-line message names the file and the problem."""


class BagRecord(NamedTuple):
    """One recorded message."""

    topic: str
    type_name: str
    data: bytes
    log_time_ns: int
    publish_time_ns: int


@dataclass(frozen=True)
class TopicInfo:
    """A recorded topic of one of the requested types."""

    topic: str
    type_name: str
    definition: str
    offered_qos: str
    type_hash: str
    message_count: int


class _Corrupt(Exception):
    """Internal: structural problem at a file offset."""


@dataclass
class _Segment:
    """Messages of one chunk (re-read lazily) or of consecutive unchunked records."""

    start_ns: int
    order: int
    chunk_offset: int = -1     # offset of the chunk record content, -1 for in-memory
    chunk_length: int = 0
    messages: list[tuple[int, int, int, bytes]] = field(default_factory=list)


class _Cursor:
    """Bounds-checked little-endian reads from a bytes object."""

    __slots__ = ("data", "pos", "end")

    def __init__(self, data: bytes, pos: int = 0, end: int | None = None) -> None:
        self.data = data
        self.pos = pos
        self.end = len(data) if end is None else end

    def take(self, size: int) -> bytes:
        if size < 0 or size > self.end - self.pos:
            raise _Corrupt(f"field of {size} bytes overruns its record")
        chunk = self.data[self.pos:self.pos + size]
        self.pos += size
        return chunk

    def u16(self) -> int:
        return struct.unpack("<H", self.take(2))[0]

    def u32(self) -> int:
        return struct.unpack("<I", self.take(4))[0]

    def u64(self) -> int:
        return struct.unpack("<Q", self.take(8))[0]

    def record(self) -> tuple[int, _Cursor]:
        """Read an (opcode, length, content) record nested in this buffer."""
        opcode = self.take(1)[0]
        length = self.u64()
        if length > self.end - self.pos:
            raise _Corrupt("record inside chunk overruns the chunk")
        body = _Cursor(self.data, self.pos, self.pos + length)
        self.pos = body.end
        return opcode, body

    def string(self) -> str:
        raw = self.take(self.u32())
        try:
            return raw.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise _Corrupt("string is not UTF-8") from exc

    def string_map(self) -> dict[str, str]:
        size = self.u32()
        if size > self.end - self.pos:
            raise _Corrupt("map overruns its record")
        inner = _Cursor(self.data, self.pos, self.pos + size)
        self.pos = inner.end
        result: dict[str, str] = {}
        while inner.pos < inner.end:
            key = inner.string()
            result[key] = inner.string()
        return result


def _decompress(compression: str, data: bytes, size: int) -> bytes:
    if size > Limits.MAX_CHUNK_UNCOMPRESSED:
        raise _Corrupt(f"chunk declares {size} uncompressed bytes")
    try:
        if compression == "":
            raw = data
        elif compression == "zstd":
            import zstandard
            raw = zstandard.ZstdDecompressor().decompress(data, max_output_size=size)
        elif compression == "lz4":
            import lz4.frame
            raw = lz4.frame.decompress(data)
        else:
            raise _Corrupt(f"unsupported chunk compression {compression!r}")
    except _Corrupt:
        raise
    except ImportError as exc:
        raise _Corrupt(f"chunk compression {compression!r} needs {exc.name}") from exc
    except Exception as exc:  # noqa: BLE001 -- decompressors raise assorted types on garbage
        raise _Corrupt(f"chunk does not decompress ({compression}): {exc}") from exc
    if len(raw) != size:
        raise _Corrupt(f"chunk decompresses to {len(raw)} bytes, header says {size}")
    return raw


def _parse_chunk(content: bytes) -> tuple[int, bytes]:
    """Return (message_start_time, records) of a chunk record's content, CRC-checked."""
    cursor = _Cursor(content)
    start = cursor.u64()
    cursor.u64()  # message_end_time
    size = cursor.u64()
    crc = cursor.u32()
    compression = cursor.string()
    records = cursor.take(cursor.u64())
    raw = _decompress(compression, records, size)
    if crc and zlib.crc32(raw) != crc:
        raise _Corrupt("chunk CRC mismatch")
    return start, raw


@dataclass
class _ScanState:
    schemas: dict[int, tuple[str, str, bytes]] = field(default_factory=dict)
    channels: dict[int, tuple[str, str, int, dict[str, str]]] = field(default_factory=dict)
    # channel id -> [message count, first log time, last log time]
    counts: dict[int, list[int]] = field(default_factory=dict)
    segments: list[_Segment] = field(default_factory=list)
    config: dict[str, Any] | None = None
    header_seen: bool = False


class _Scanner:
    """One validating pass over an MCAP file."""

    def __init__(self, path: Path, stream: BinaryIO, size: int) -> None:
        self.path = path
        self.stream = stream
        self.size = size
        self.state = _ScanState()
        self.crc = 0

    def read_record(self, pos: int, limit: int) -> tuple[int, bytes, int]:
        """Read the record at ``pos``: (opcode, content, next position).

        Also folds the record's bytes into the running data-section CRC.
        """
        if limit - pos < Limits.RECORD_PREFIX:
            raise _Corrupt(f"truncated: record header at byte {pos} is cut off")
        self.stream.seek(pos)
        prefix = self.stream.read(Limits.RECORD_PREFIX)
        opcode, length = struct.unpack("<BQ", prefix)
        body_start = pos + Limits.RECORD_PREFIX
        if length > limit - body_start:
            raise _Corrupt(f"truncated: record at byte {pos} declares {length} bytes, "
                           f"only {limit - body_start} remain")
        content = self.stream.read(length)
        if len(content) != length:
            raise _Corrupt(f"truncated: short read at byte {body_start}")
        self.crc = zlib.crc32(content, zlib.crc32(prefix, self.crc))
        return opcode, content, body_start + length

    def inner_records(self, raw: bytes, chunk_start: int, order: int) -> _Segment:
        segment = _Segment(start_ns=chunk_start, order=order)
        cursor = _Cursor(raw)
        while cursor.pos < cursor.end:
            opcode, body = cursor.record()
            message = self.handle(opcode, body)
            if message is not None:
                segment.messages.append(message)
        return segment

    def handle(self, opcode: int, body: _Cursor) -> tuple[int, int, int, bytes] | None:
        """Apply a schema/channel/metadata record; return a message as a tuple."""
        state = self.state
        if opcode == McapOpcode.SCHEMA:
            schema_id = body.u16()
            state.schemas[schema_id] = (body.string(), body.string(), body.take(body.u32()))
        elif opcode == McapOpcode.CHANNEL:
            channel_id = body.u16()
            schema_id = body.u16()
            topic = body.string()
            encoding = body.string()
            metadata = body.string_map()
            if schema_id and schema_id not in state.schemas:
                raise _Corrupt(f"channel {topic} refers to unknown schema {schema_id}")
            state.channels[channel_id] = (topic, encoding, schema_id, metadata)
        elif opcode == McapOpcode.MESSAGE:
            channel_id = body.u16()
            body.u32()  # sequence
            log_time = body.u64()
            publish_time = body.u64()
            data = body.take(body.end - body.pos)
            if channel_id not in state.channels:
                raise _Corrupt(f"message on unknown channel {channel_id}")
            return channel_id, log_time, publish_time, data
        elif opcode == McapOpcode.METADATA:
            name = body.string()
            values = body.string_map()
            if name == BagFormat.CONFIG_METADATA_NAME:
                state.config = {key: _decode_config_value(value) for key, value in values.items()}
        return None

    def count(self, messages: Iterable[tuple[int, int, int, bytes]]) -> None:
        counts = self.state.counts
        for channel_id, log_time, _, _ in messages:
            entry = counts.get(channel_id)
            if entry is None:
                counts[channel_id] = [1, log_time, log_time]
            else:
                entry[0] += 1
                entry[1] = min(entry[1], log_time)
                entry[2] = max(entry[2], log_time)

    def scan(self) -> tuple[bool, str | None]:
        """Walk the file; return (complete, problem). Raises _Corrupt on the first problem."""
        self.stream.seek(0)
        magic = self.stream.read(len(Limits.MAGIC))
        if self.size == 0:
            raise _Corrupt("empty file")
        if magic != Limits.MAGIC:
            raise _Corrupt("not an MCAP file (bad magic)")
        self.crc = zlib.crc32(magic)
        opcode, content, pos = self.read_record(len(magic), self.size)
        if opcode != McapOpcode.HEADER:
            raise _Corrupt("first record is not an MCAP header")
        _Cursor(content).string()  # profile: any; foreign ros2 writers vary
        self.state.header_seen = True
        loose: _Segment | None = None
        order = 0
        while True:
            crc_before = self.crc  # DataEnd's CRC covers everything before it
            opcode, content, after = self.read_record(pos, self.size)
            if opcode == McapOpcode.DATA_END:
                expected = _Cursor(content).u32()
                if expected and expected != crc_before:
                    raise _Corrupt("data section CRC mismatch")
                self.check_summary(after)
                return True, None
            if opcode == McapOpcode.CHUNK:
                chunk_start, raw = _parse_chunk(content)
                segment = self.inner_records(raw, chunk_start, order)
                segment.chunk_offset = pos
                segment.chunk_length = after - pos
                if segment.messages:
                    self.count(segment.messages)
                    segment.start_ns = min(m[1] for m in segment.messages)
                    segment.messages = []  # re-read lazily by records()
                    self.state.segments.append(segment)
                    order += 1
                loose = None
            else:
                message = self.handle(opcode, _Cursor(content))
                if message is not None:
                    self.count([message])
                    if loose is None:
                        loose = _Segment(start_ns=message[1], order=order)
                        self.state.segments.append(loose)
                        order += 1
                    loose.messages.append(message)
                    loose.start_ns = min(loose.start_ns, message[1])
            pos = after

    def stream_bytes(self, pos: int, size: int) -> bytes:
        self.stream.seek(pos)
        return self.stream.read(size)

    def check_summary(self, pos: int) -> None:
        """Validate the summary section framing, the footer, its CRC and the end magic."""
        footer_pos = self.size - len(Limits.MAGIC) - Limits.RECORD_PREFIX - Limits.FOOTER_LENGTH
        if footer_pos < pos:
            raise _Corrupt("truncated: footer missing after the data section")
        while pos < footer_pos:
            opcode, content, pos = self.read_record(pos, footer_pos)
            # Topics that never got a message are declared only here (writers emit
            # schema/channel records with the first chunk that uses them).
            if opcode in (McapOpcode.SCHEMA, McapOpcode.CHANNEL):
                self.handle(opcode, _Cursor(content))
        if pos != footer_pos:
            raise _Corrupt("summary section does not end at the footer")
        opcode, content, after = self.read_record(footer_pos, self.size)
        if opcode != McapOpcode.FOOTER or len(content) != Limits.FOOTER_LENGTH:
            raise _Corrupt("footer record missing or malformed")
        if self.stream_bytes(after, len(Limits.MAGIC)) != Limits.MAGIC:
            raise _Corrupt("truncated: end magic missing")
        summary_start, _, summary_crc = struct.unpack("<QQI", content)
        if summary_crc:
            start = summary_start or footer_pos
            if not 0 < start <= footer_pos:
                raise _Corrupt("footer points outside the file")
            crc = zlib.crc32(self.stream_bytes(start, footer_pos - start))
            crc = zlib.crc32(self.stream_bytes(footer_pos, Limits.RECORD_PREFIX + 16), crc)
            if crc != summary_crc:
                raise _Corrupt("summary CRC mismatch")


def _decode_config_value(value: str) -> Any:
    try:
        return json.loads(value)
    except ValueError:
        return value


class BagContents:
    """A validated bag: topics, configuration, and a log-time ordered record iterator.

    Attributes
    ----------
    path
        The MCAP file.
    topics
        Topics of the requested types, by name.
    ignored_topics
        Other topics in the file and their type names (not yielded).
    config
        The recorded node configuration (``circle_collision_ros/config``), or ``None``.
    truncated
        True if the file ended early or broke off (tolerant mode only); records
        up to the last complete chunk are still yielded.
    problem
        What ended reading early, or ``None``.
    start_time_ns, end_time_ns, message_count
        Over the yielded topics' messages.
    """

    def __init__(self, path: Path, scan: _ScanState, topics: dict[str, TopicInfo],
                 ignored: dict[str, str], channel_ids: dict[int, tuple[str, str]],
                 truncated: bool, problem: str | None) -> None:
        self.path = path
        self.topics = topics
        self.ignored_topics = ignored
        self.config = scan.config
        self.truncated = truncated
        self.problem = problem
        self._segments = sorted(scan.segments, key=lambda s: (s.start_ns, s.order))
        self._channels = channel_ids
        self.message_count = sum(t.message_count for t in topics.values())
        spans = [scan.counts[cid] for cid in channel_ids if cid in scan.counts]
        self.start_time_ns = min((s[1] for s in spans), default=0)
        self.end_time_ns = max((s[2] for s in spans), default=0)

    def __iter__(self) -> Iterator[BagRecord]:
        return self.records()

    def records(self, topics: Iterable[str] | None = None) -> Iterator[BagRecord]:
        """Yield records in log-time order (ties in file order).

        Parameters
        ----------
        topics
            Restrict to these topic names; default all of :attr:`topics`.

        Raises
        ------
        BagError
            If the file changed since :func:`open_bag` and no longer reads.
        """
        selected = None if topics is None else set(topics)
        wanted = {cid for cid, (topic, _) in self._channels.items()
                  if selected is None or topic in selected}
        heap: list[tuple[int, int, int, BagRecord]] = []
        sequence = 0
        try:
            with open(self.path, "rb") as stream:
                for index, segment in enumerate(self._segments):
                    for channel_id, log_time, publish_time, data in self._load(stream, segment):
                        if channel_id in wanted:
                            topic, type_name = self._channels[channel_id]
                            record = BagRecord(topic, type_name, data, log_time, publish_time)
                            heapq.heappush(heap, (log_time, segment.order, sequence, record))
                            sequence += 1
                    # Segments are sorted by start time, so nothing later can precede this.
                    horizon = (self._segments[index + 1].start_ns
                               if index + 1 < len(self._segments) else None)
                    while heap and (horizon is None or heap[0][0] < horizon):
                        yield heapq.heappop(heap)[3]
        except (OSError, _Corrupt) as exc:
            raise BagError(f"{self.path}: {exc}") from exc

    def _load(self, stream: BinaryIO, segment: _Segment) -> list[tuple[int, int, int, bytes]]:
        if segment.chunk_offset < 0:
            return segment.messages
        stream.seek(segment.chunk_offset + Limits.RECORD_PREFIX)
        content = stream.read(segment.chunk_length - Limits.RECORD_PREFIX)
        _, raw = _parse_chunk(content)
        messages: list[tuple[int, int, int, bytes]] = []
        cursor = _Cursor(raw)
        while cursor.pos < cursor.end:
            opcode, body = cursor.record()
            if opcode == McapOpcode.MESSAGE:
                channel_id = body.u16()
                body.u32()
                log_time = body.u64()
                publish_time = body.u64()
                data = body.take(body.end - body.pos)
                messages.append((channel_id, log_time, publish_time, data))
        return messages


def _resolve_mcap(path: Path) -> Path:
    """The MCAP file of a bag directory (via metadata.yaml, else the only .mcap) or file."""
    if not path.exists():
        raise BagError(f"{path}: no such file or directory")
    if not path.is_dir():
        return path
    candidates: list[Path] = []
    try:
        metadata = yaml.safe_load((path / BagFormat.METADATA_FILE).read_text(encoding="utf-8"))
        info = metadata["rosbag2_bagfile_information"]
        if info.get("storage_identifier") not in (None, BagFormat.STORAGE_IDENTIFIER):
            raise BagError(f"{path}: storage {info['storage_identifier']!r} is not supported "
                           "(only mcap)")
        candidates = [path / Path(str(name)).name for name in info["relative_file_paths"]]
    except BagError:
        raise
    except (OSError, yaml.YAMLError, KeyError, TypeError, AttributeError, ValueError,
            RecursionError):
        # A missing/damaged metadata.yaml (e.g. after a crash) must not hide the data.
        candidates = sorted(path.glob("*.mcap"))
    existing = [c for c in candidates if c.is_file()]
    if len(existing) != 1:
        what = ("no .mcap file" if not existing
                else f"{len(existing)} .mcap files (split bags unsupported)")
        raise BagError(f"{path}: bag directory has {what}")
    return existing[0]


def open_bag(path: str | os.PathLike[str], *, tolerant: bool = False,
             message_types: Iterable[str] = RECORDED_TYPES) -> BagContents:
    """Open and validate a recording.

    Parameters
    ----------
    path
        Bag directory or ``.mcap`` file.
    tolerant
        Accept a file that ends early or breaks off (hard-killed recorder, copy
        in progress, corrupt tail): read everything up to the last complete
        chunk and report it via :attr:`BagContents.truncated` and ``problem``.
    message_types
        Channel schema names to yield (``pkg/msg/Type``).

    Returns
    -------
    BagContents

    Raises
    ------
    BagError
        One line naming the file: missing path, empty/non-MCAP/corrupt or (in
        strict mode) truncated file, no channels of ``message_types``, or such a
        channel with a schema encoding other than ``ros2msg`` or a message
        encoding other than ``cdr``.
    """
    mcap_path = _resolve_mcap(Path(path))
    truncated, problem = False, None
    try:
        with open(mcap_path, "rb") as stream:
            size = os.fstat(stream.fileno()).st_size
            scanner = _Scanner(mcap_path, stream, size)
            try:
                scanner.scan()
            except _Corrupt as exc:
                # Without magic and header nothing is usable, tolerant or not.
                if not tolerant or not scanner.state.header_seen:
                    raise
                truncated, problem = True, str(exc)
    except _Corrupt as exc:
        hint = ("; open_bag(..., tolerant=True) reads up to the last complete chunk"
                if str(exc).startswith("truncated") and not tolerant else "")
        raise BagError(f"{mcap_path}: {exc}{hint}") from exc
    except OSError as exc:
        raise BagError(f"{mcap_path}: cannot read: {exc.strerror or exc}") from exc
    except (struct.error, IndexError) as exc:  # defensive: a parse slip is still a bad file
        raise BagError(f"{mcap_path}: malformed MCAP: {exc}") from exc
    return _build_contents(mcap_path, scanner.state, set(message_types), truncated, problem)


def _build_contents(path: Path, state: _ScanState, types: set[str], truncated: bool,
                    problem: str | None) -> BagContents:
    topics: dict[str, TopicInfo] = {}
    ignored: dict[str, str] = {}
    channel_ids: dict[int, tuple[str, str]] = {}
    for channel_id, (topic, encoding, schema_id, metadata) in state.channels.items():
        name, schema_encoding, data = state.schemas.get(schema_id, ("", "", b""))
        if name not in types:
            ignored[topic] = name
            continue
        if schema_encoding != BagFormat.SCHEMA_ENCODING or encoding != BagFormat.MESSAGE_ENCODING:
            raise BagError(f"{path}: topic {topic} ({name}) uses schema encoding "
                           f"{schema_encoding!r} / message encoding {encoding!r}; expected "
                           f"{BagFormat.SCHEMA_ENCODING!r} / {BagFormat.MESSAGE_ENCODING!r}")
        if topic in topics and topics[topic].type_name != name:
            raise BagError(f"{path}: topic {topic} recorded with two types")
        previous = topics.get(topic)
        topics[topic] = TopicInfo(
            topic=topic, type_name=name,
            definition=data.decode("utf-8", errors="replace"),
            offered_qos=metadata.get(BagFormat.CHANNEL_QOS_KEY, ""),
            type_hash=metadata.get(BagFormat.CHANNEL_TYPE_HASH_KEY, ""),
            message_count=state.counts.get(channel_id, [0])[0]
            + (previous.message_count if previous else 0))
        channel_ids[channel_id] = (topic, name)
    if not topics:
        found = ", ".join(f"{t} ({n or 'no schema'})" for t, n in sorted(ignored.items())) or "none"
        note = f"; reading stopped early: {problem}" if truncated else ""
        raise BagError(f"{path}: no channels of types {', '.join(sorted(types))} "
                       f"(found: {found}){note}")
    return BagContents(path, state, topics, ignored, channel_ids, truncated, problem)
