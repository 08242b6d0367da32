"""RViz / Foxglove markers for the scene and its predicted contacts, off the prediction path.

Namespaces: `bodies` (one cylinder or sphere per body, coloured by its most
urgent contact) and `contacts` (a small sphere at each predicted contact
point). Probability is opacity: a body's colour band comes from its
earliest plausible contact (= the contact time for exact states) and its alpha
is scaled by Urgency.opacity of its most probable listed pair; a contact
sphere's alpha by its pair's probability. Exact contacts (probability 1) are
fully opaque. A body or pair keeps its marker id while it is in the scene; when it
leaves, its id returns to a free list (smallest first), so the id tables hold
exactly the live scene and ids stay below the largest scene seen. Each array
starts with a DELETEALL and lists the whole scene, so it is complete on its
own (a display that missed an array or joined late shows no ghosts).

MarkerPublisher draws on its own thread: the prediction path only hands over
the newest prediction (a reference, under a lock). The thread draws at most
`marker_rate` times a second and within MARKER_BUDGET of wall time, always the
newest prediction, and always the last one offered (so a removal just after a
drawing is still drawn, never left on screen).

Arrays are serialized straight to CDR with numpy (MarkerArrayEncoder): building
Marker objects in Python cost ~0.13 s per 1,000 bodies, which on the GIL would
have slowed the prediction thread; encoding costs ~1 ms.
"""
from __future__ import annotations

import heapq
import threading
import time
from collections.abc import Callable, Hashable, Sequence
from typing import NamedTuple

import numpy as np

from circle_collision_msgs.msg import CollisionPrediction
from circle_collision_ros.node.activity import NodeActivity
from circle_collision_ros.pipeline.prediction_messages import ScenePrediction

# visualization_msgs/Marker constants (kept here so encoding needs no message objects).
SPHERE, CYLINDER = 2, 3
ADD, DELETE, DELETEALL = 0, 2, 3


class Urgency:
    """Colour bands (RGBA) by time to collision (s)."""

    CRITICAL_S = 1.0
    WARNING_S = 3.0
    CRITICAL = (0.9, 0.1, 0.1, 0.9)
    WARNING = (1.0, 0.55, 0.0, 0.8)
    NOTICE = (0.95, 0.85, 0.1, 0.7)
    CLEAR = (0.3, 0.6, 0.9, 0.5)

    MIN_OPACITY = 0.25  # fraction of the band's alpha at probability 0 (still visible)

    @classmethod
    def colours(cls, ttc: np.ndarray, probability: np.ndarray | None = None) -> np.ndarray:
        """(N, 4) float32 colours for times to collision (inf = no contact); with
        `probability`, each alpha is scaled by opacity(probability) where ttc is finite."""
        bands = np.array([cls.CRITICAL, cls.WARNING, cls.NOTICE, cls.CLEAR], dtype=np.float32)
        band = np.where(ttc < cls.CRITICAL_S, 0, np.where(ttc < cls.WARNING_S, 1,
                                                           np.where(np.isfinite(ttc), 2, 3)))
        out = bands[band]
        if probability is not None:
            scale = np.where(np.isfinite(ttc), cls.opacity(probability), 1.0)
            out[:, 3] *= scale.astype(np.float32)
        return out

    @classmethod
    def opacity(cls, probability: np.ndarray) -> np.ndarray:
        """Alpha factor for a probability of contact: MIN_OPACITY at 0 up to 1 at 1."""
        return cls.MIN_OPACITY + (1.0 - cls.MIN_OPACITY) * np.clip(probability, 0.0, 1.0)


class MarkerIds:
    """A small integer per key while the key is live; freed ids are reused smallest first."""

    def __init__(self) -> None:
        self._ids: dict[Hashable, int] = {}
        self._free: list[int] = []

    def __len__(self) -> int:
        return len(self._ids)

    def __contains__(self, key: Hashable) -> bool:
        return key in self._ids

    def keys(self):
        return self._ids.keys()

    def assign(self, key: Hashable) -> int:
        marker_id = self._ids.get(key)
        if marker_id is None:
            marker_id = heapq.heappop(self._free) if self._free else len(self._ids)
            self._ids[key] = marker_id
        return marker_id

    def release(self, key: Hashable) -> int:
        marker_id = self._ids.pop(key)
        heapq.heappush(self._free, marker_id)
        return marker_id

    def clear(self) -> None:
        self._ids.clear()
        self._free.clear()

    @property
    def largest(self) -> int:
        """Largest id handed out and still tracked (live or free); -1 when none."""
        return max(max(self._ids.values(), default=-1), max(self._free, default=-1))


class MarkerSegment(NamedTuple):
    """Markers of one namespace and action; length-N arrays (pose/scale/colour unused by DELETE)."""

    ns: str
    type: int
    action: int
    ids: np.ndarray  # (N,) int32
    positions: np.ndarray  # (N, 3) float64
    scales: np.ndarray  # (N, 3) float64
    colours: np.ndarray  # (N, 4) float32


class _Layout(NamedTuple):
    length: int
    offsets: dict[str, int]
    template: np.ndarray  # the marker's bytes with every constant field filled in


class MarkerArrayEncoder:
    """visualization_msgs/MarkerArray as CDR bytes (little endian), from MarkerSegments.

    All markers share one header (stamp, frame_id). A marker with given strings
    serializes to the same bytes at every start position of the same 8-byte
    residue, so each (frame, ns, residue) has one template; per-marker fields
    are written through numpy views. Alignment counts from the end of the
    4-byte encapsulation header, as in pipeline/cdr.py.
    """

    ORIGIN = 4

    def __init__(self) -> None:
        self._layouts: dict[tuple[str, str, int, int, int], _Layout] = {}

    CHUNK = 1024  # markers written between two pause points

    def encode(self, stamp: tuple[int, int], frame_id: str, segments: Sequence[MarkerSegment],
               pause: Callable[[], None] = lambda: None) -> bytes:
        total = sum(len(s.ids) for s in segments)
        plans = []
        pos = end = 4  # origin-relative: the sequence count sits at 0..4
        for segment in segments:
            starts, layouts = self._starts(frame_id, segment, pos)
            plans.append((segment, starts, layouts))
            if len(segment.ids):
                last = int(starts[-1])
                end = last + layouts[last % 8].length
                pos = end + (-end) % 4  # a Marker starts with an int32
        size = self.ORIGIN + end
        out = np.zeros(size + (-size) % 8 + 8, dtype=np.uint8)
        out[:4] = (0, 1, 0, 0)  # CDR little endian
        out.view("<u4")[1] = total
        for segment, starts, layouts in plans:
            if not len(segment.ids):
                continue
            for residue, layout in layouts.items():
                every = np.flatnonzero(starts % 8 == residue)
                for first in range(0, len(every), self.CHUNK):
                    pause()
                    rows = every[first : first + self.CHUNK]
                    self._write(out, starts[rows], rows, layout, segment, stamp)
        return out[:size].tobytes()

    def _write(self, out: np.ndarray, at: np.ndarray, rows: np.ndarray, layout: _Layout,
               segment: MarkerSegment, stamp: tuple[int, int]) -> None:
        """Markers `rows` of `segment`, starting at origin-relative offsets `at`, into `out`."""
        i32, u32, f32 = out.view("<i4"), out.view("<u4"), out.view("<f4")
        f64 = out[self.ORIGIN : self.ORIGIN + (len(out) - 8)].view("<f8")
        absolute = at + self.ORIGIN
        out[absolute[:, None] + np.arange(layout.length)] = layout.template
        o = layout.offsets

        def word(field: str) -> np.ndarray:
            return (absolute + o[field]) // 4

        i32[word("sec")] = stamp[0]
        u32[word("nanosec")] = stamp[1]
        i32[word("id")] = segment.ids[rows]
        if segment.action == ADD:
            pose = (at + o["pose"]) // 8
            scale = (at + o["scale"]) // 8
            for axis in range(3):
                f64[pose + axis] = segment.positions[rows, axis]
                f64[scale + axis] = segment.scales[rows, axis]
            colour = word("color")
            for channel in range(4):
                f32[colour + channel] = segment.colours[rows, channel]

    def _starts(
        self, frame_id: str, segment: MarkerSegment, pos: int
    ) -> tuple[np.ndarray, dict[int, _Layout]]:
        """Origin-relative start of each marker, and the layout per start residue."""
        layouts = {r: self._layout(frame_id, segment, r) for r in (0, 4)}
        n = len(segment.ids)
        padded = {r: layout.length + (-layout.length) % 4 for r, layout in layouts.items()}
        residue = [pos % 8]
        for _ in range(2):  # two residues: from the second marker on the pattern repeats
            residue.append((residue[-1] + padded[residue[-1]]) % 8)
        if n <= 3:
            sequence = np.array(residue[:n], dtype=np.int64)
        elif residue[1] == residue[2]:
            sequence = np.full(n, residue[1], dtype=np.int64)
            sequence[0] = residue[0]
        else:  # alternating from the first marker
            sequence = np.array([residue[0], residue[1]] * ((n + 1) // 2), dtype=np.int64)[:n]
        lengths = np.where(sequence == 0, padded[0], padded[4])
        starts = (
            pos + np.concatenate(([0], np.cumsum(lengths[:-1]))) if n else np.zeros(0, np.int64)
        )
        return starts.astype(np.int64), layouts

    def _layout(self, frame_id: str, segment: MarkerSegment, residue: int) -> _Layout:
        key = (frame_id, segment.ns, segment.type, segment.action, residue)
        layout = self._layouts.get(key)
        if layout is None:
            if len(self._layouts) > 64:  # frames come from parameters/inputs: keep the cache small
                self._layouts.clear()
            layout = self._layouts[key] = _marker_layout(
                frame_id.encode(), segment.ns.encode(), segment.type, segment.action, residue
            )
        return layout


def _marker_layout(frame: bytes, ns: bytes, marker_type: int, action: int, residue: int) -> _Layout:
    """Byte layout of one Marker starting at origin-relative offset `residue` (0 or 4)."""
    buf = bytearray()
    offsets: dict[str, int] = {}
    start = residue

    def pos() -> int:
        return start + len(buf)

    def align(n: int) -> None:
        buf.extend(b"\0" * ((-pos()) % n))

    def put(fmt_bytes: bytes, n: int, name: str | None = None) -> None:
        align(n)
        if name:
            offsets[name] = pos() - start
        buf.extend(fmt_bytes)

    def string(value: bytes) -> None:
        put(len(value + b"\0").to_bytes(4, "little"), 4)
        buf.extend(value + b"\0")

    def count0() -> None:
        put(b"\0\0\0\0", 4)

    put(b"\0" * 4, 4, "sec")
    put(b"\0" * 4, 4, "nanosec")
    string(frame)
    string(ns)
    put(b"\0" * 4, 4, "id")
    put(marker_type.to_bytes(4, "little", signed=True), 4, "type")
    put(action.to_bytes(4, "little", signed=True), 4, "action")
    put(np.array([0, 0, 0, 0, 0, 0, 1.0], "<f8").tobytes(), 8, "pose")  # orientation w = 1
    put(b"\0" * 24, 8, "scale")
    put(b"\0" * 16, 4, "color")
    put(b"\0" * 8, 4, "lifetime")  # 0: forever; deletions are explicit
    put(b"\0", 1, "frame_locked")
    count0()  # points
    count0()  # colors
    string(b"")  # texture_resource
    put(b"\0" * 8, 4)  # texture.header.stamp
    string(b"")  # texture.header.frame_id
    string(b"")  # texture.format
    count0()  # texture.data
    count0()  # uv_coordinates
    string(b"")  # text
    string(b"")  # mesh_resource
    string(b"")  # mesh_file.filename
    count0()  # mesh_file.data
    put(b"\0", 1)  # mesh_use_embedded_materials
    return _Layout(len(buf), offsets, np.frombuffer(bytes(buf), dtype=np.uint8))


class MarkerBuilder:
    """Serialized MarkerArrays: a DELETEALL, then the whole scene; ids bounded by the live scene."""

    CONTACT_DIAMETER_M = 0.3
    FLAT_HEIGHT_M = 0.05

    def __init__(self, dimensions: int) -> None:
        self.dimensions = dimensions
        self.body_ids = MarkerIds()
        self.pair_ids = MarkerIds()
        self._encoder = MarkerArrayEncoder()

    CHUNK = 512  # keys handled between two pause points

    def build(self, prediction: ScenePrediction, pause: Callable[[], None] = lambda: None) -> bytes:
        """The MarkerArray bytes for `prediction`.

        Calls `pause` between short steps (see MarkerPublisher).
        """
        snapshot = prediction.snapshot
        ids = list(snapshot.ids)
        n = len(ids)
        rows = list(prediction.rows())
        contacts = [row for row in rows if row.status != CollisionPrediction.NO_CONTACT]
        # listed pairs: mean contacts and (uncertain states) probable ones; not report_all_pairs'
        # rest
        listed = [
            row
            for row in rows
            if row.status != CollisionPrediction.NO_CONTACT or row.collision_probability > 0.0
        ]
        pause()
        index = dict(zip(ids, range(n)))
        body_ttc = np.full(n, np.inf)
        body_probability = np.zeros(n)
        if listed:
            # both ends of a pair are bodies; a contact with static geometry has one (id_b
            # names the obstacle)
            ends = [(index[row[k]], row) for row in listed for k in (0, 1) if row[k] in index]
            at = np.array([j for j, _ in ends], dtype=np.int64)
            np.minimum.at(body_ttc, at, [row.plausible_time_to_collision for _, row in ends])
            np.maximum.at(body_probability, at, [row.collision_probability for _, row in ends])
        positions = np.zeros((n, 3))
        if n:
            d = min(snapshot.positions.shape[1], 3)
            positions[:, :d] = snapshot.positions[:, :d]
        # a point still shows
        diameters = np.maximum(2.0 * np.asarray(snapshot.radii, dtype=np.float64), 1e-3)
        scales = np.stack(
            [diameters, diameters,
             diameters if self.dimensions == 3 else np.full(n, self.FLAT_HEIGHT_M)],
            axis=1,
        )
        shape = SPHERE if self.dimensions == 3 else CYLINDER
        pause()
        gone_bodies = self._departed(self.body_ids, ids)
        pause()
        bodies = MarkerSegment("bodies", shape, ADD, self._assign(self.body_ids, ids, pause),
                               positions, scales, Urgency.colours(body_ttc, body_probability))
        pause()
        pairs = [(row[0], row[1]) for row in contacts]
        m = len(pairs)
        gone_pairs = self._departed(self.pair_ids, pairs)
        contact_points = np.array([row[5] for row in contacts], dtype=np.float64).reshape(m, 3)
        contact_ttc = np.array([row[3] for row in contacts], dtype=np.float64)
        contact_probability = np.array(
            [row.collision_probability for row in contacts], dtype=np.float64
        )
        contacts_segment = MarkerSegment("contacts", SPHERE, ADD,
                                         self._assign(self.pair_ids, pairs, pause), contact_points,
                                         np.full((m, 3), self.CONTACT_DIAMETER_M),
                                         Urgency.colours(contact_ttc, contact_probability))
        pause()
        # Each array starts with a DELETEALL, so it is complete on its own: a display that missed
        # an array (the publisher keeps only the newest) or joined late shows no ghosts. The
        # departed ids are freed (gone_*) for reuse, which keeps ids bounded by the live scene.
        del gone_bodies, gone_pairs
        segments = [self._clear_segment(), bodies, contacts_segment]
        return self._encoder.encode(prediction.stamp, prediction.frame_id, segments, pause)

    def clear_all(self, stamp: tuple[int, int] = (0, 0), frame_id: str = "") -> bytes:
        """One DELETEALL (every namespace), and forget every id."""
        self.body_ids.clear()
        self.pair_ids.clear()
        return self._encoder.encode(stamp, frame_id, [self._clear_segment()])

    @staticmethod
    def _clear_segment() -> MarkerSegment:
        return MarkerSegment("", SPHERE, DELETEALL, np.zeros(1, np.int32), np.zeros((1, 3)),
                             np.zeros((1, 3)), np.zeros((1, 4), np.float32))

    @classmethod
    def _assign(cls, table: MarkerIds, keys: list, pause: Callable[[], None]) -> np.ndarray:
        out = np.empty(len(keys), dtype=np.int32)
        for start in range(0, len(keys), cls.CHUNK):
            if start:
                pause()
            part = keys[start : start + cls.CHUNK]
            out[start : start + len(part)] = [table.assign(k) for k in part]
        return out

    @staticmethod
    def _departed(table: MarkerIds, keys: list) -> np.ndarray:
        """Release the ids of keys no longer present; returns them (to send DELETEs)."""
        live = set(keys)
        gone = [k for k in table.keys() if k not in live]
        return np.array([table.release(k) for k in gone], dtype=np.int32)


class MarkerPublisher:
    """Draws the newest offered prediction on its own thread at most `rate` Hz, within a CPU budget.

    publish : sends serialized MarkerArray bytes (the node's raw publisher).
    offer() is all the prediction path pays: it replaces a reference under a lock.

    The drawing is cut into short steps (MarkerBuilder.CHUNK keys,
    MarkerArrayEncoder.CHUNK markers) and steps aside at each while the node
    is busy or a completion of probabilities is evaluated (`activity`, node/activity.py).
    """

    BUDGET = 0.1  # fraction of wall time markers may take (their thread's CPU time)

    def __init__(self, dimensions: int, rate_hz: float, publish: Callable[[bytes], None],
                 on_error: Callable[[str], None] | None = None,
                 activity: NodeActivity | None = None) -> None:
        self.builder = MarkerBuilder(dimensions)
        self._publish = publish
        self._on_error = on_error or (lambda text: None)
        self._rate = float(rate_hz)
        self._cond = threading.Condition()
        self._latest: ScenePrediction | None = None
        self._clear_pending = False
        self._stopped = False
        self._next_time = 0.0
        self.activity = activity or NodeActivity()
        self.drawn = 0
        self.last_cost_s = 0.0
        self._thread = threading.Thread(
            target=self._run, name="collision_node_markers", daemon=True
        )
        self._thread.start()

    @property
    def rate(self) -> float:
        return self._rate

    def offer(self, prediction: ScenePrediction) -> None:
        """Hand over the newest prediction (it replaces one not yet drawn)."""
        if self._rate <= 0.0:
            return
        with self._cond:
            self._latest = prediction
            self._cond.notify()

    def set_rate(self, rate_hz: float) -> None:
        """Change the rate; 0 stops drawing and clears what is on screen."""
        with self._cond:
            if rate_hz <= 0.0 < self._rate:
                self._latest = None
                self._clear_pending = True
            self._rate = float(rate_hz)
            self._next_time = 0.0
            self._cond.notify()

    def close(self, clear: bool = True) -> None:
        """Stop the thread (after it finishes a drawing); optionally clear the display."""
        with self._cond:
            self._stopped = True
            self._cond.notify()
        self._thread.join(timeout=5.0)
        if clear:
            self._send(self.builder.clear_all())

    def wait_idle(self, timeout: float) -> bool:
        """True once nothing offered is left undrawn (tests)."""
        deadline = time.monotonic() + timeout
        while True:
            with self._cond:
                if self._latest is None and not self._busy:
                    return True
            if time.monotonic() >= deadline:
                return False
            time.sleep(0.01)

    _busy = False

    def _run(self) -> None:
        while True:
            with self._cond:
                while not self._stopped and self._latest is None and not self._clear_pending:
                    self._cond.wait()
                if self._stopped:
                    return
                if self._clear_pending:
                    self._clear_pending = False
                    clear = True
                else:
                    clear = False
                    # Wait for the rate/budget slot; a newer prediction offered meanwhile replaces
                    # this one.
                    delay = self._next_time - time.monotonic()
                    if delay > 0:
                        self._cond.wait(timeout=delay)
                        continue
                    prediction, self._latest = self._latest, None
                self._busy = True
            try:
                started = time.monotonic()
                cpu = time.thread_time()
                if clear:
                    self._send(self.builder.clear_all())
                else:
                    self._send(self.builder.build(prediction, self._step_aside))
                    self.drawn += 1
                # the budget is the CPU the drawing takes: its waits for the prediction path
                # and for completions (at most a frame period each) take nothing from them
                self.last_cost_s = time.thread_time() - cpu
                if self._rate > 0:
                    self._next_time = started + max(
                        1.0 / self._rate, self.last_cost_s / self.BUDGET
                    )
            except Exception as exc:  # markers are for eyes: never let them stop the node
                self._on_error(f"markers skipped: {exc!r}")
            finally:
                self._busy = False

    def _step_aside(self) -> None:
        """MarkerBuilder's pause: markers wait for the prediction path and for completions."""
        self.activity.pause(completions=True)

    def _send(self, data: bytes) -> None:
        try:
            self._publish(data)
        except Exception as exc:  # e.g. the context shut down under us at exit
            self._on_error(f"markers not published: {exc!r}")
