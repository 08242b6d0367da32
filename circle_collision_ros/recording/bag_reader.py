"""Read recorded messages back from a rosbag2 MCAP bag: a thin layer over ``mcap``.

``mcap.stream_reader.StreamReader(validate_crcs=True, record_size_limit=<file
size>)`` checks chunk and data-section CRCs and bounds every declared length.
This layer adds what the library leaves to its caller: a short read is an
error (the library would pass on a short last record), a chunk's declared size
is bounded before decompression, the footer's summary CRC and the end magic are
checked, and every failure is one BagError line naming the file. ``tolerant``
(a hard-killed recorder) is the same read stopped at the first bad or missing
record, keeping the complete chunks before it. Memory: the selected messages.
"""
from __future__ import annotations

import json
import os
import zlib
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO, NamedTuple

import yaml
from mcap.records import Channel, Chunk, Footer, Header, Message, Metadata, Schema
from mcap.stream_reader import StreamReader, breakup_chunk

from .bag_recorder import BagFormat

RECORDED_TYPES = frozenset({"circle_collision_msgs/msg/CircleStateArray", "nav_msgs/msg/Odometry",
                            "circle_collision_msgs/msg/CircleState",
                            "circle_collision_msgs/msg/CollisionPredictionArray"})
"""Message types open_bag yields by default; other channels are ignored."""


class Limits:
    MAGIC = b"\x89MCAP0\r\n"
    FOOTER_RECORD = 29  # opcode, length, summary_start, summary_offset_start, summary_crc
    MAX_CHUNK_UNCOMPRESSED = 512 * 1024 * 1024


class BagError(Exception):
    """A bag cannot be read; the one-line message names the file and the problem."""


class BagRecord(NamedTuple):
    """One recorded message; schema: the ros2msg definition text its channel was recorded with
    (the layout its bytes follow; replay decodes and re-encodes by it)."""

    topic: str
    type_name: str
    data: bytes
    log_time_ns: int
    publish_time_ns: int
    schema: str = ""



TopicInfo = NamedTuple(
    "TopicInfo",
    [("topic", str), ("type_name", str), ("definition", str), ("offered_qos", str),
     ("type_hash", str), ("message_count", int)],
)


class _ExactReader:
    """A file whose reads return exactly the bytes asked, else raise ValueError('truncated: ...').

    A size beyond the end fails before reading: nothing is allocated for lengths read from garbage.
    """

    def __init__(self, stream: BinaryIO, size: int) -> None:
        self.stream, self.size = stream, size

    def read(self, size: int = -1) -> bytes:
        position = self.stream.tell()
        if size > self.size - position:
            raise ValueError(
                f"truncated: a record at byte {position} needs {size} bytes, "
                f"{self.size - position} remain"
            )
        return self.stream.read(size)


@dataclass
class BagContents:
    """Topics of the requested types, other topics, the recorded config, records by log time.

    truncated/problem (tolerant mode): what ended reading early.
    """

    path: Path
    topics: dict[str, TopicInfo]
    ignored_topics: dict[str, str]
    config: dict[str, Any] | None
    truncated: bool
    problem: str | None
    all_records: list[BagRecord]  # log-time order, ties in file order

    def __post_init__(self) -> None:
        self.message_count = len(self.all_records)
        times = [r.log_time_ns for r in self.all_records] or [0]
        self.start_time_ns, self.end_time_ns = times[0], times[-1]

    def __iter__(self) -> Iterator[BagRecord]:
        return self.records()

    def records(self, topics: Iterable[str] | None = None) -> Iterator[BagRecord]:
        wanted = None if topics is None else set(topics)
        return (r for r in self.all_records if wanted is None or r.topic in wanted)


def _read(stream: BinaryIO, size: int, bag: dict) -> None:
    """One validating pass: fills bag's schemas, channels, messages and config."""
    reader = StreamReader(
        _ExactReader(stream, size), emit_chunks=True, validate_crcs=True, record_size_limit=size
    )
    for record in reader.records:
        if not bag["header_seen"] and not isinstance(record, Header):
            raise ValueError("first record is not an MCAP header")
        bag["header_seen"], inner, messages = True, [record], []
        if isinstance(record, Chunk):
            if record.uncompressed_size > Limits.MAX_CHUNK_UNCOMPRESSED:
                raise ValueError(f"chunk declares {record.uncompressed_size} uncompressed bytes")
            inner = breakup_chunk(record, validate_crc=True)
        for item in inner:
            if isinstance(item, Schema):
                bag["schemas"][item.id] = item
            elif isinstance(item, Channel):
                bag["channels"][item.id] = item
            elif isinstance(item, Message):  # on an undeclared channel: never selected
                messages.append(item)
            elif isinstance(item, Metadata) and item.name == BagFormat.CONFIG_METADATA_NAME:
                bag["config"] = {k: _json_or_text(v) for k, v in item.metadata.items()}
        # only once the whole chunk parsed: a chunk is kept whole or not
        bag["messages"] += messages
        if isinstance(record, Footer):
            footer, resume = size - len(Limits.MAGIC) - Limits.FOOTER_RECORD, stream.tell()
            stream.seek(footer + Limits.FOOTER_RECORD)
            if resume != footer + Limits.FOOTER_RECORD or stream.read() != Limits.MAGIC:
                raise ValueError("truncated: end magic missing after the footer")
            start = record.summary_start or footer
            if record.summary_crc and not 0 < start <= footer:
                raise ValueError("footer points outside the file")
            stream.seek(start)  # the summary CRC covers the summary and the footer up to the CRC
            if (
                record.summary_crc
                and zlib.crc32(stream.read(footer + 25 - start)) != record.summary_crc
            ):
                raise ValueError("summary CRC mismatch")
            stream.seek(resume)  # the library reads the end magic next


def _json_or_text(value: str) -> Any:
    try:
        return json.loads(value)
    except ValueError:
        return value


def _resolve_mcap(path: Path) -> Path:
    """The MCAP file of a bag directory (via metadata.yaml, else the only .mcap) or file."""
    if not path.exists():
        raise BagError(f"{path}: no such file or directory")
    if not path.is_dir():
        return path
    try:
        info = yaml.safe_load((path / BagFormat.METADATA_FILE).read_text(encoding="utf-8"))[
            "rosbag2_bagfile_information"
        ]
        candidates = [path / Path(str(name)).name for name in info["relative_file_paths"]]
        storage = info.get("storage_identifier")
    except Exception:  # noqa: BLE001 -- a missing/damaged metadata.yaml must not hide the data
        candidates, storage = sorted(path.glob("*.mcap")), None
    if storage not in (None, BagFormat.STORAGE_IDENTIFIER):
        raise BagError(f"{path}: storage {storage!r} is not supported (only mcap)")
    existing = [c for c in candidates if c.is_file()]
    if len(existing) != 1:
        what = (
            "no .mcap file"
            if not existing
            else f"{len(existing)} .mcap files (split bags unsupported)"
        )
        raise BagError(f"{path}: bag directory has {what}")
    return existing[0]


def _describe(exc: BaseException) -> str:
    name, text = type(exc).__name__, str(exc) or type(exc).__name__
    if name == "RecordLengthLimitExceeded":
        return f"truncated: a record declares more bytes than the file holds ({text})"
    if name == "CRCValidationError":
        return f"CRC mismatch ({text})"
    return text if type(exc) is ValueError else f"malformed MCAP ({name}: {text})"


def open_bag(path: str | os.PathLike[str], *, tolerant: bool = False,
             message_types: Iterable[str] = RECORDED_TYPES) -> BagContents:
    """Read and validate a recording (bag directory or .mcap file).

    tolerant: accept a file that ends early or breaks off and keep every complete
    chunk before that point. Raises BagError (one line naming the file): missing
    path, empty/non-MCAP/corrupt or (strict) truncated file, no channels of
    `message_types`, or such a channel not in ros2msg/cdr.
    """
    mcap_path = _resolve_mcap(Path(path))
    bag: dict[str, Any] = {"schemas": {}, "channels": {}, "messages": [], "config": None,
                           "header_seen": False}
    problem = None
    try:
        with open(mcap_path, "rb") as stream:
            size = os.fstat(stream.fileno()).st_size
            if size == 0 or stream.read(len(Limits.MAGIC)) != Limits.MAGIC:
                raise ValueError("empty file" if size == 0 else "not an MCAP file (bad magic)")
            stream.seek(0)
            try:
                _read(stream, size, bag)
            except Exception as exc:  # noqa: BLE001 -- any parse failure means a bad file
                problem = _describe(exc)
                if not tolerant or not bag["header_seen"]:
                    hint = (
                        "; open_bag(..., tolerant=True) reads up to the last complete chunk"
                        if problem.startswith("truncated") and not tolerant
                        else ""
                    )
                    raise ValueError(problem + hint) from exc
    except ValueError as exc:
        raise BagError(f"{mcap_path}: {exc}") from exc
    except OSError as exc:
        raise BagError(f"{mcap_path}: cannot read: {exc.strerror or exc}") from exc
    return _contents(mcap_path, bag, set(message_types), problem)


def _contents(path: Path, bag: dict, types: set[str], problem: str | None) -> BagContents:
    topics: dict[str, TopicInfo] = {}
    ignored: dict[str, str] = {}
    selected: dict[int, tuple[str, str, str]] = {}
    counts: dict[int, int] = {}
    for message in bag["messages"]:
        counts[message.channel_id] = counts.get(message.channel_id, 0) + 1
    for channel in bag["channels"].values():
        schema = bag["schemas"].get(channel.schema_id)
        name = schema.name if schema else ""
        if name not in types:
            ignored[channel.topic] = name
            continue
        if (schema.encoding, channel.message_encoding) != (
            BagFormat.SCHEMA_ENCODING,
            BagFormat.MESSAGE_ENCODING,
        ):
            raise BagError(
                f"{path}: topic {channel.topic} ({name}) uses "
                f"schema encoding {schema.encoding!r} / "
                f"message encoding {channel.message_encoding!r}; expected "
                f"{BagFormat.SCHEMA_ENCODING!r} / {BagFormat.MESSAGE_ENCODING!r}"
            )
        previous = topics.get(channel.topic)
        if previous is not None and previous.type_name != name:
            raise BagError(f"{path}: topic {channel.topic} recorded with two types")
        topics[channel.topic] = TopicInfo(
            channel.topic,
            name,
            schema.data.decode("utf-8", errors="replace"),
            channel.metadata.get(BagFormat.CHANNEL_QOS_KEY, ""),
            channel.metadata.get(BagFormat.CHANNEL_TYPE_HASH_KEY, ""),
            counts.get(channel.id, 0) + (previous.message_count if previous else 0),
        )
        selected[channel.id] = (channel.topic, name, schema.data.decode("utf-8", errors="replace"))
    if not topics:
        found = ", ".join(f"{t} ({n or 'no schema'})" for t, n in sorted(ignored.items())) or "none"
        note = f"; reading stopped early: {problem}" if problem else ""
        raise BagError(
            f"{path}: no channels of types {', '.join(sorted(types))} (found: {found}){note}"
        )
    records = sorted(
        (
            BagRecord(*selected[m.channel_id][:2], m.data, m.log_time, m.publish_time,
                      selected[m.channel_id][2])
            for m in bag["messages"]
            if m.channel_id in selected
        ),
        key=lambda r: r.log_time_ns,
    )
    return BagContents(path, topics, ignored, bag["config"], problem is not None, problem, records)
