"""CircleState / CircleStateArray codec: bytes <-> StateBatch (the node's hot path).

The node decodes the raw bytes of its subscriptions here instead of through
rclpy's message objects; load generators, replay and the service encode states
here. Wire format, the two layouts (`uncertainty`) and why this is safe on
untrusted bytes: pipeline/cdr.py.

decode_state_row is the pure-Python reader of one little-endian CircleState
(per-body streams, pipeline/state_groups): it reads exactly what decode_states
reads, or returns None and leaves the message to decode_states.

StateDecoder is decode_states for one stream: a message laid out as the previous one (a
tracker's next frame) is read at that message's positions and shares its id tuple, so the
steps after decoding skip their per-id work for it.
"""
from __future__ import annotations

import struct

import numpy as np
from numba import njit

from circle_collision_msgs.msg import CircleState, CircleStateArray
from circle_collision_ros.pipeline.cdr import (CDR_BE, CDR_LE, ORIGIN, CdrError, CdrWriter, align,
                                               read_string, read_u32)
from circle_collision_ros.pipeline.state_batch import StateBatch

COVARIANCE_SIZE = 36  # values of a CircleState covariance (6x6 row-major); 0 = none given


@njit(cache=True)
def _decode_states(buf, f64, pos, count, stamps, strings, radius, pva, remove, be, with_cov,
                   cov_size, cov_at, where):
    """Decode `count` CircleStates starting at `pos`; returns the end position or -1.

    stamps[k]: the header stamp in ns (int32 seconds: no int64 overflow).
    f64 is the buffer viewed as float64 from ORIGIN on (in the message's byte
    order, converted to native): a float64 field sits at a position 8-aligned
    relative to ORIGIN, i.e. exactly at f64[(pos - ORIGIN) // 8]. be: big endian.
    radius[k], pva[0, k] position, pva[1, k] velocity, pva[2, k] acceleration: three
    C-ordered (count, 3) arrays, which the scene's store takes without a copy.
    with_cov: the layout has the covariance sequence; its length goes to
    cov_size[k] (any length is skipped bounds-checked: validation rejects it) and the
    f64 index of its first value to cov_at[k] (_covariances reads the values: most
    messages give none, and a (count, 36) block written for every message would cost
    more than the rest of the decode). where[k]: the byte position of the state's stamp
    and the f64 index of its radius (StateDecoder reads the next message there).
    """
    n = buf.shape[0]
    for k in range(count):
        pos = align(pos, 4)
        if pos + 8 > n:
            return -1
        where[k, 0] = pos
        stamps[k] = _stamp(buf, pos, be)
        off, ln, pos = read_string(buf, pos + 8, be)
        if off < 0:
            return -1
        strings[k, 0], strings[k, 1] = off, ln
        off, ln, pos = read_string(buf, pos, be)
        if off < 0:
            return -1
        strings[k, 2], strings[k, 3] = off, ln
        pos = align(pos, 8)
        if pos + 80 + 1 > n:
            return -1
        first = (pos - ORIGIN) // 8
        where[k, 1] = first
        _numbers(buf, f64, k, first, radius, pva, remove)
        pos += 81
        if with_cov:
            pos = align(pos, 4)
            if pos + 4 > n:
                return -1
            size = read_u32(buf, pos, be)
            pos += 4
            cov_size[k] = size
            if size > 0:
                pos = align(pos, 8)
                if pos + 8 * size > n:
                    return -1
            cov_at[k] = (pos - ORIGIN) // 8
            pos += 8 * size
    return pos


@njit(cache=True, inline="always")
def _stamp(buf, pos, be):
    """The header stamp at pos in ns (int32 seconds: no int64 overflow)."""
    sec = np.int64(read_u32(buf, pos, be))
    if sec >= 2**31:  # int32
        sec -= 2**32
    return sec * 1_000_000_000 + np.int64(read_u32(buf, pos + 4, be))


@njit(cache=True, inline="always")
def _numbers(buf, f64, k, first, radius, pva, remove):
    """State k's radius, position, velocity, acceleration from f64[first:first + 10] and
    its remove flag from the byte after them."""
    radius[k] = f64[first]
    for j in range(3):  # position, velocity, acceleration
        for d in range(3):
            pva[j, k, d] = f64[first + 1 + 3 * j + d]
    remove[k] = buf[ORIGIN + 8 * first + 80] != 0


@njit(cache=True)
def _covariances(f64, cov_size, cov_at, cov):
    """cov[k] = the COVARIANCE_SIZE values at f64[cov_at[k]:] where cov_size[k] says there are
    that many, else zeros (the positions _decode_states checked against the buffer)."""
    for k in range(cov_size.shape[0]):
        full = cov_size[k] == COVARIANCE_SIZE
        for j in range(COVARIANCE_SIZE):
            cov[k, j] = f64[cov_at[k] + j] if full else 0.0


@njit(cache=True)
def _joined(buf, strings, col):
    """The strings at (strings[k, col], strings[k, col + 1]) of buf, each followed
    by a NUL, in one byte array; and whether all of them are the same bytes."""
    count = strings.shape[0]
    total = 0
    for k in range(count):
        total += strings[k, col + 1] + 1
    out = np.empty(total, dtype=np.uint8)
    o0, n0 = strings[0, col], strings[0, col + 1]
    same = True
    q = 0
    for k in range(count):
        o, n = strings[k, col], strings[k, col + 1]
        if n != n0:
            same = False
        for j in range(n):
            c = buf[o + j]
            out[q + j] = c
            if same and c != buf[o0 + j]:  # same: n == n0, so j < n0
                same = False
        out[q + n] = 0
        q += n + 1
    return out, same


def _decoded(data: bytes, buf: np.ndarray, strings: np.ndarray, col: int) -> tuple:
    """The strings of column `col` of `strings` as a tuple of str (UnicodeDecodeError if one is
    not UTF-8).

    One decode of all of them joined by NUL and one split, instead of a slice and
    a decode per string (~5x less time at 5,000 states): NUL ends no UTF-8
    sequence and starts none, so the joined bytes are valid exactly when each
    string is, and the split returns them unchanged -- unless a string holds a
    NUL itself, which the count of the parts shows; then each is decoded alone.
    All strings equal (the frames of an array, mostly): one decode, shared."""
    count = strings.shape[0]
    if count == 0:
        return ()
    # one string (a per-body stream's message) needs no compiled pass to be "all the same"
    joined, same = (None, True) if count == 1 else _joined(buf, strings, col)
    if same:
        return (data[strings[0, col] : strings[0, col] + strings[0, col + 1]].decode(),) * count
    parts = joined.tobytes().decode().split("\0")
    if len(parts) == count + 1:
        del parts[-1]
        return tuple(parts)
    return tuple(
        data[o : o + n].decode()
        for o, n in zip(strings[:, col].tolist(), strings[:, col + 1].tolist())
    )


def _f64_view(data: bytes, be: bool) -> np.ndarray:
    """The buffer as float64 from ORIGIN on, in native byte order (see _decode_states)."""
    f64 = np.frombuffer(
        data, dtype=">f8" if be else "<f8", offset=ORIGIN, count=(len(data) - ORIGIN) // 8
    )
    return f64 if f64.dtype.isnative else f64.astype(np.float64)


def _batch(data: bytes, buf: np.ndarray, count: int, start: int, array_frame: str, be: bool,
           uncertainty: bool, layout: "_Layout | None" = None) -> StateBatch:
    stamps = np.empty(count, dtype=np.int64)
    strings = np.empty((count, 4), dtype=np.int64)
    radius = np.empty(count, dtype=np.float64)
    pva = np.empty((3, count, 3), dtype=np.float64)
    remove = np.empty(count, dtype=np.bool_)
    cov_size = np.zeros(count if uncertainty else 0, dtype=np.int64)
    cov_at = np.zeros(count if uncertainty else 0, dtype=np.int64)
    where = np.empty((count, 2), dtype=np.int64)
    f64 = _f64_view(data, be)
    if (
        _decode_states(buf, f64, start, count, stamps, strings, radius, pva, remove, be,
                       uncertainty, cov_size, cov_at, where)
        < 0
    ):
        raise CdrError("truncated or malformed CircleState data")
    given = uncertainty and (bool(cov_size[0]) if count == 1 else bool(cov_size.any()))
    cov = None
    if given:
        cov = np.empty((count, COVARIANCE_SIZE), dtype=np.float64)
        _covariances(f64, cov_size, cov_at, cov)
    try:
        ids = _decoded(data, buf, strings, 2)
        frames = _decoded(data, buf, strings, 0)
    except UnicodeDecodeError as exc:
        raise CdrError(f"a string is not UTF-8 ({exc.reason})") from exc
    if count and not strings[:, 1].all():  # a state without a frame has the array's
        frames = tuple(f or array_frame for f in frames)
    if layout is not None:
        layout.keep(data, where, cov_size if given else None, cov_at, ids, frames,
                    start != ORIGIN)
    # positional: a frozen dataclass takes keywords at twice the cost (~2 us of a one-state message)
    return StateBatch(ids, frames, stamps, radius, pva[0], pva[1], pva[2], remove, cov,
                      cov_size if given else None)


@njit(cache=True)
def _values_mask(size, array_stamp, where, cov_size, cov_at):
    """(size,) uint8, padded with 0 to whole uint64 words: 0 on the bytes that hold values
    (the stamps, each state's 10 numbers and remove flag, covariance values), 0xFF on the
    rest (the encapsulation, string lengths and bytes, sequence lengths, padding): the bytes
    that fix where every value is and what the ids and frames are."""
    mask = np.full(8 * ((size + 7) // 8), 0xFF, dtype=np.uint8)
    mask[size:] = 0
    if array_stamp >= 0:  # the array header's stamp
        mask[array_stamp : array_stamp + 8] = 0
    for k in range(where.shape[0]):
        mask[where[k, 0] : where[k, 0] + 8] = 0
        b = ORIGIN + 8 * where[k, 1]
        mask[b : b + 81] = 0
        if cov_size.shape[0]:
            c = ORIGIN + 8 * cov_at[k]
            mask[c : c + 8 * cov_size[k]] = 0
    return mask


@njit(cache=True)
def _same_layout(words, tail, prev_words, prev_tail, mask):
    """Whether a message's bytes (``words``: its whole uint64 words, ``tail``: its last
    size % 8 bytes) equal the previous message's wherever ``mask`` (_values_mask, viewed as
    words in the same byte order) is 0xFF.  Branch-free over the words: memory speed."""
    acc = np.uint64(0)
    for j in range(words.shape[0]):
        acc |= (words[j] ^ prev_words[j]) & mask[j]
    tail_mask = mask[words.shape[0]:].view(np.uint8)
    for j in range(tail.shape[0]):
        acc |= np.uint64((tail[j] ^ prev_tail[j]) & tail_mask[j])
    return acc == 0


@njit(cache=True)
def _read_values(buf, f64, be, where, stamps, radius, pva, remove):
    """Each state's stamp and numbers at the positions ``where`` (_decode_states) of a
    message of the same layout."""
    for k in range(where.shape[0]):
        stamps[k] = _stamp(buf, where[k, 0], be)
        _numbers(buf, f64, k, where[k, 1], radius, pva, remove)


class _Layout:
    """What StateDecoder keeps of the last message it parsed (see there)."""

    __slots__ = ("data", "words", "tail", "mask", "where", "cov_size", "cov_at", "ids", "frames",
                 "misses", "rest")
    #: After this many messages in a row that did not have the kept layout (two publishers on
    #: one topic, a tracker that reorders its ids), the decoder rests for REST messages: it
    #: parses them without comparing or keeping, so a miss's extra pass and mask are not
    #: paid on every message.
    MISSES = 3
    REST = 8

    def __init__(self) -> None:
        self.data = b""
        self.misses = 0
        self.rest = 0

    def keep(self, data: bytes, where: np.ndarray, cov_size: np.ndarray | None,
             cov_at: np.ndarray, ids: tuple, frames: tuple, array: bool) -> None:
        """Remember the message just parsed (``array``: a CircleStateArray, with a stamp in
        its header).  Only ``bytes`` are kept: they cannot change, where a buffer the caller
        reuses would later compare equal to itself."""
        if type(data) is not bytes or self.rest:
            return
        none = np.zeros(0, dtype=np.int64)
        mask = _values_mask(len(data), ORIGIN if array else -1, where,
                            none if cov_size is None else cov_size, cov_at)
        words, tail = _words(data)
        # every part built before any is replaced: the kept parts always belong together
        self.data, self.words, self.tail, self.mask = data, words, tail, mask.view(np.uint64)
        self.where, self.ids, self.frames, self.cov_at = where, ids, frames, cov_at
        # a copy: the batch's own array may be changed by its holder
        self.cov_size = None if cov_size is None else cov_size.copy()

    def batch(self, data: bytes, buf: np.ndarray, be: bool) -> StateBatch | None:
        """The batch of ``data`` when its layout is the kept message's, else None."""
        if type(data) is not bytes:
            return None
        if self.rest:
            self.rest -= 1
            return None
        if not self.data:
            return None
        words, tail = _words(data)
        if len(data) != len(self.data) or not _same_layout(words, tail, self.words, self.tail,
                                                           self.mask):
            self.misses += 1
            if self.misses >= self.MISSES:
                self.data, self.misses, self.rest = b"", 0, self.REST
            return None
        self.misses = 0
        count = self.where.shape[0]
        stamps = np.empty(count, dtype=np.int64)
        radius = np.empty(count, dtype=np.float64)
        pva = np.empty((3, count, 3), dtype=np.float64)
        remove = np.empty(count, dtype=np.bool_)
        f64 = _f64_view(data, be)
        _read_values(buf, f64, be, self.where, stamps, radius, pva, remove)
        cov = None
        if self.cov_size is not None:
            cov = np.empty((count, COVARIANCE_SIZE), dtype=np.float64)
            _covariances(f64, self.cov_size, self.cov_at, cov)
        self.data, self.words, self.tail = data, words, tail
        return StateBatch(self.ids, self.frames, stamps, radius, pva[0], pva[1], pva[2], remove,
                          cov, None if cov is None else self.cov_size.copy())


def _words(data: bytes) -> tuple[np.ndarray, np.ndarray]:
    """``data`` as whole uint64 words (native order, as _values_mask's view) and its last
    len % 8 bytes."""
    whole = len(data) // 8
    raw = np.frombuffer(data, dtype=np.uint8)
    return raw[: 8 * whole].view(np.uint64), raw[8 * whole :]


def decode_states(data: bytes, msg_type: type, *, uncertainty: bool = True) -> StateBatch:
    """StateBatch from serialized CircleStateArray or CircleState bytes.

    uncertainty : False decodes the layout before CircleState had `covariance`
        (older recordings; replay reads the recorded schema).

    Raises
    ------
    CdrError
        If the bytes are not a well-formed message of `msg_type`.
    """
    return _decode(data, msg_type, uncertainty, None)


class StateDecoder:
    """``decode_states`` for one stream of messages (a topic), remembering the last message.

    A message whose bytes differ from the last parsed one's only in values (stamps, the
    states' numbers and remove flags, covariance values) has the same layout: the same
    strings, lengths and padding, so every value is where it was.  It is read there, in one
    pass comparing the other bytes and one gathering the values, without a parse, and its
    batch shares the last one's id and frame tuples (the same objects; validation,
    state_validation.check_batch, and the scene's merge skip their per-id work for them).
    A tracker sends the same ids in the same order frame after frame: every frame after
    the first takes this path.  The batches are decode_states' bit for bit, and bytes it
    refuses are refused.  Only ``bytes`` messages are kept and compared (other buffers are
    parsed), and after a few misses in a row the decoder parses a while without comparing
    (_Layout.MISSES, REST).  Not thread-safe: one decoder per stream.
    """

    def __init__(self, msg_type: type, *, uncertainty: bool = True) -> None:
        if msg_type is not CircleState and msg_type is not CircleStateArray:
            raise TypeError(f"no CDR decoder for {msg_type.__name__}")
        self.msg_type = msg_type
        self.uncertainty = uncertainty
        self._layout = _Layout()

    def __call__(self, data: bytes) -> StateBatch:
        """The StateBatch of ``data`` (CdrError as decode_states)."""
        return _decode(data, self.msg_type, self.uncertainty, self._layout)


def _decode(data: bytes, msg_type: type, uncertainty: bool, layout: _Layout | None) -> StateBatch:
    if msg_type is not CircleState and msg_type is not CircleStateArray:
        raise TypeError(f"no CDR decoder for {msg_type.__name__}")
    if len(data) < ORIGIN or data[:2] not in (CDR_LE, CDR_BE):
        raise CdrError(f"not plain CDR (encapsulation {bytes(data[:2]).hex() or 'missing'})")
    be = data[:2] == CDR_BE
    buf = np.frombuffer(data, dtype=np.uint8)
    if layout is not None:
        # the encapsulation is compared too: a layout is one byte order's
        same = layout.batch(data, buf, be)
        if same is not None:
            return same
    if msg_type is CircleState:
        return _batch(data, buf, 1, ORIGIN, "", be, uncertainty, layout)
    # Array header: stamp (8 bytes), frame_id, then the sequence count.
    off, ln, pos = read_string(buf, ORIGIN + 8, be) if len(buf) >= ORIGIN + 8 else (-1, 0, 0)
    if off < 0:
        raise CdrError("truncated or malformed CircleStateArray header")
    pos = align(pos, 4)
    if pos + 4 > len(buf):
        raise CdrError("truncated CircleStateArray (no sequence length)")
    count = int(read_u32(buf, pos, be))
    # Each state needs at least 97 bytes (empty strings, no padding; 101 with the
    # covariance length): a larger count is a lie, not something to allocate for.
    if count * (101 if uncertainty else 97) > len(buf) - pos:
        raise CdrError(f"sequence length {count} does not fit in {len(buf)} bytes")
    try:
        array_frame = data[off : off + ln].decode()
    except UnicodeDecodeError as exc:
        raise CdrError(f"frame_id is not UTF-8 ({exc.reason})") from exc
    return _batch(data, buf, count, pos + 4, array_frame, be, uncertainty, layout)


def encode_state_array(batch: StateBatch, stamp_ns: int, frame_id: str) -> bytes:
    """Serialized CircleStateArray of `batch` (header stamp/frame as given).

    Each state's header carries its own stamp and frame; its covariance is
    batch.covariance's row when batch.covariance_size says 36, else empty. Used
    by load generators (benchmarks, soak) that must publish thousands of states
    at 30 Hz without building message objects.
    """
    w = CdrWriter()
    w.time(*divmod(int(stamp_ns), 1_000_000_000))
    w.string(frame_id.encode())
    w.u32(len(batch))
    _write_states(w, batch)
    return bytes(w.buf)


def encode_state(batch: StateBatch) -> bytes:
    """Serialized CircleState of a one-state batch (as encode_state_array writes each state)."""
    if len(batch) != 1:
        raise ValueError(f"encode_state takes one state, got {len(batch)}")
    w = CdrWriter()
    _write_states(w, batch)
    return bytes(w.buf)


def _write_states(w: CdrWriter, batch: StateBatch) -> None:
    numbers = np.column_stack(
        [batch.radius, batch.position, batch.velocity, batch.acceleration]
    ).tolist()
    if batch.covariance is None:
        covariances = [()] * len(batch)
    else:
        covariances = [
            row if size == COVARIANCE_SIZE else ()
            for row, size in zip(batch.covariance.tolist(), batch.covariance_size.tolist())
        ]
    for body_id, frame, stamp, values, remove, cov in zip(batch.ids, batch.frames,
                                                          batch.stamp_ns.tolist(), numbers,
                                                          batch.remove.tolist(), covariances):
        w.time(*divmod(stamp, 1_000_000_000))
        w.string(frame.encode())
        w.string(body_id.encode())
        w.f64s(*values)
        w.u8(1 if remove else 0)
        w.u32(len(cov))
        if cov:
            w.f64s(*cov)


_U32 = struct.Struct("<I")
_TIME = struct.Struct("<iI")
_NUMBERS = struct.Struct("<10d")


def _text(data: bytes, pos: int) -> tuple[str, int] | None:
    """(the string at pos, the position after it), or None when malformed (read_string's rule)."""
    pos += (-(pos - 4)) % 4
    if pos + 4 > len(data):
        return None
    (size,) = _U32.unpack_from(data, pos)
    start = pos + 4
    if size == 0:  # some writers send a bare zero length for ""
        return "", start
    if start + size > len(data) or data[start + size - 1] != 0:
        return None
    return data[start : start + size - 1].decode(), start + size


def decode_state_row(data: bytes, uncertainty: bool) -> tuple | None:
    """(stamp ns, frame, id, 10 numbers, remove, covariance values) of well-formed LE CircleState
    bytes, else None. uncertainty: the layout has the covariance sequence (decode_states)."""
    if len(data) < 4 or data[:2] != CDR_LE:
        return None
    try:
        if len(data) < 12:
            return None
        sec, nanosec = _TIME.unpack_from(data, 4)
        stamp_ns = sec * 1_000_000_000 + nanosec
        frame = _text(data, 12)
        if frame is None:
            return None
        body = _text(data, frame[1])
        if body is None:
            return None
        pos = body[1]
        pos += (-(pos - 4)) % 8
        if pos + 81 > len(data):
            return None
        cov: tuple = ()
        if uncertainty:
            end = pos + 81
            end += (-(end - 4)) % 4
            if end + 4 > len(data):
                return None
            (size,) = _U32.unpack_from(data, end)
            end += 4
            if size:
                end += (-(end - 4)) % 8
                if end + 8 * size > len(data):
                    return None
                cov = (
                    struct.unpack_from(f"<{size}d", data, end)
                    if size <= COVARIANCE_SIZE
                    else (0.0,) * size
                )  # any wrong length is rejected by validation, values unused
        return (stamp_ns, frame[0], body[0], _NUMBERS.unpack_from(data, pos), data[pos + 80] != 0,
                cov)
    except UnicodeDecodeError:
        return None  # decode_states names the error
