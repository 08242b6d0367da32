"""Inputs that were published but never reached the node, counted exactly per publisher.

The node cannot see a frame that never arrived, but every sample carries its
writer's sequence number (rmw MessageInfo `publication_sequence_number`, with
`publisher_gid`). DDS numbers a writer's samples 1, 2, 3, ... so a jump from
n to n + k + 1 means k samples of that publisher did not reach this reader:
lost by the transport (best-effort, large frames over a small shared-memory
segment) or overwritten in the node's own KEEP_LAST queue. That count is exact,
with no rate model and so no false alarms on steady small scenes: a gap of 0 is
never reported. What is lost is told apart by size: frames above
LARGE_MESSAGE_BYTES are the ones Fast DDS's default 512 KB shared-memory
segment cannot carry (README, "Large scenes").

The first sample seen from a publisher only starts its count (it may have
published before the node subscribed); an RMW that gives no sequence numbers
leaves every count at 0.
"""
from __future__ import annotations

from dataclasses import dataclass, field


class LossThresholds:
    """When a loss is worth a warning, and what counts as a large frame."""

    # Fast DDS's default shared-memory segment is 512 KiB; frames over about half of it
    # were the ones lost in the measurements (bench/transport_delivery.py).
    LARGE_MESSAGE_BYTES = 256 * 1024
    # Publishers not heard from for this long are forgotten (bounds memory when
    # publishers come and go).
    FORGET_AFTER_NS = 60_000_000_000


@dataclass
class PublisherLoss:
    """One publisher on one topic: samples received and samples that never arrived."""

    last_sequence: int
    last_heard_ns: int
    received: int = 1
    missing: int = 0


@dataclass
class TopicLoss:
    """One input topic: totals over its publishers, and the largest frame seen."""

    received: int = 0
    missing: int = 0
    largest_bytes: int = 0
    missing_large: int = 0  # missing samples from publishers that send large frames
    publishers: dict[bytes, PublisherLoss] = field(default_factory=dict)


class InputLossMonitor:
    """Counts inputs that never arrived, per topic, from writers' sequence numbers."""

    def __init__(self) -> None:
        self.topics: dict[str, TopicLoss] = {}
        self._reported_missing: dict[str, int] = {}

    def observe(self, topic: str, size_bytes: int, info: dict | None, received_ns: int) -> int:
        """Account one received sample; return how many of its publisher's samples it shows missing.

        info : the rmw MessageInfo of the sample (None or without sequence numbers: size only).
        """
        stats = self.topics.get(topic)
        if stats is None:
            stats = self.topics[topic] = TopicLoss()
        stats.received += 1
        large = size_bytes > LossThresholds.LARGE_MESSAGE_BYTES
        stats.largest_bytes = max(stats.largest_bytes, size_bytes)
        sequence = info.get("publication_sequence_number") if info else None
        gid = info.get("publisher_gid") if info else None
        if not sequence or not gid:
            return 0
        key = bytes(gid.get("data", b"")) if isinstance(gid, dict) else bytes(gid)
        publisher = stats.publishers.get(key)
        if publisher is None:
            stats.publishers[key] = PublisherLoss(last_sequence=sequence, last_heard_ns=received_ns)
            return 0
        publisher.received += 1
        publisher.last_heard_ns = received_ns
        # Out-of-order or repeated samples (possible with several transports) show no loss.
        gap = max(0, sequence - publisher.last_sequence - 1)
        publisher.last_sequence = max(publisher.last_sequence, sequence)
        if gap:
            publisher.missing += gap
            stats.missing += gap
            if large:
                stats.missing_large += gap
        return gap

    def forget_silent(self, now_ns: int) -> None:
        """Drop publishers not heard from within LossThresholds.FORGET_AFTER_NS."""
        for stats in self.topics.values():
            silent = [
                k
                for k, p in stats.publishers.items()
                if now_ns - p.last_heard_ns > LossThresholds.FORGET_AFTER_NS
            ]
            for key in silent:
                del stats.publishers[key]

    @property
    def missing(self) -> int:
        """Samples that never arrived, all topics."""
        return sum(s.missing for s in self.topics.values())

    def new_losses(self) -> list[str]:
        """One line per topic that lost samples since the last call (for a throttled warning)."""
        lines = []
        for topic, stats in self.topics.items():
            new = stats.missing - self._reported_missing.get(topic, 0)
            if new <= 0:
                continue
            self._reported_missing[topic] = stats.missing
            line = (
                f"{topic}: {new} input message(s) published but never received "
                f"({stats.missing} of {stats.missing + stats.received} in all)"
            )
            if stats.missing_large:
                line += (
                    f"; frames up to {stats.largest_bytes / 1e6:.2f} MB are larger than Fast DDS's"
                    " default shared-memory segment carries: load config/fastdds_large_scenes.xml"
                    " in the publishers too (export FASTDDS_DEFAULT_PROFILES_FILE=...; README,"
                    " 'Large scenes')"
                )
            else:
                line += (
                    "; the node may be falling behind its input queue, or the network drops frames"
                )
            lines.append(line)
        return lines
