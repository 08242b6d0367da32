"""Direct CDR decoding of circle states and encoding of predictions (the node's hot path).

rclpy turns every nested field into a Python object (about 30 us per
CircleState), so the node reads the raw bytes of its subscriptions with the
kernels below instead, and writes its output bytes the same way. Both follow
the ROS 2 wire format (OMG XCDR1, little endian, as Fast DDS writes it):

- a 4-byte encapsulation header (00 01 00 00 = CDR little endian); every
  alignment is counted from the end of that header;
- primitives are aligned to their own size (float64 to 8);
- a string is a uint32 length that counts the trailing NUL, then the bytes;
- a sequence is a uint32 count, then the elements (aligned to their own size
  only when there is at least one: an empty sequence is the count alone).

Two layouts of our interfaces exist on the wire and in recordings: the current
one (CircleState ends with `float64[<=36] covariance`; CollisionPrediction ends
with collision_probability, collision_probability_bound,
plausible_time_to_collision) and the one before issue 18 (neither). The node
speaks the current one; replay reads and writes the one a recording's schema
names (`uncertainty=False`), so old bags replay bit-identically.

Big-endian CDR (00 00) is decoded by the same kernels with the byte order
swapped; any other encapsulation is refused (CdrError). Untrusted bytes are
never handed to rclpy's deserializer: on malformed input it can crash the
process (SIGSEGV, e.g. CircleState b"\\x00\\x00\\x90\\xfa";
tests/reliability/test_fuzz_cdr.py). Tests check both directions against
rclpy.serialization on valid bytes.

Why this is safe on garbage: every read is bounds-checked against the buffer
and a string must end in NUL inside it; a violation returns an error code and
the message is rejected as a whole, never partially used.
"""
from __future__ import annotations

import struct
import sys

import numpy as np
from numba import njit

from circle_collision_msgs.msg import CircleState, CircleStateArray
from circle_collision_ros.pipeline.state_batch import StateBatch

CDR_LE = b"\x00\x01"
CDR_BE = b"\x00\x00"
_ORIGIN = 4  # alignment is relative to the end of the encapsulation header


class CdrError(ValueError):
    """Bytes that are not a well-formed message of the expected type."""


@njit(cache=True)
def _align(pos, n):
    return _ORIGIN + ((pos - _ORIGIN + n - 1) // n) * n


@njit(cache=True)
def _u32(buf, pos, be):
    if be:
        return (np.int64(buf[pos]) << 24) | (np.int64(buf[pos + 1]) << 16) \
            | (np.int64(buf[pos + 2]) << 8) | np.int64(buf[pos + 3])
    return np.int64(buf[pos]) | (np.int64(buf[pos + 1]) << 8) | (np.int64(buf[pos + 2]) << 16) \
        | (np.int64(buf[pos + 3]) << 24)


@njit(cache=True)
def _string(buf, pos, be):
    """(offset, length without NUL, next position) or (-1, 0, 0) when malformed."""
    pos = _align(pos, 4)
    if pos + 4 > buf.shape[0]:
        return -1, 0, 0
    size = _u32(buf, pos, be)
    start = pos + 4
    if size == 0:  # some writers send a bare zero length for ""
        return start, 0, start
    if start + size > buf.shape[0] or buf[start + size - 1] != 0:
        return -1, 0, 0
    return start, size - 1, start + size


COVARIANCE_SIZE = 36  # values of a CircleState covariance (6x6 row-major); 0 = none given


@njit(cache=True)
def _decode_states(buf, f64, pos, count, stamps, strings, numbers, remove, be, with_cov, cov_size, cov):
    """Decode `count` CircleStates starting at `pos`; returns the end position or -1.

    stamps[k]: the header stamp in ns (int32 seconds: no int64 overflow).
    f64 is the buffer viewed as float64 from _ORIGIN on (in the message's byte
    order, converted to native): a float64 field sits at a position 8-aligned
    relative to _ORIGIN, i.e. exactly at f64[(pos - _ORIGIN) // 8]. be: big endian.
    with_cov: the layout has the covariance sequence; its length goes to
    cov_size[k] (any length is skipped bounds-checked: validation rejects it),
    its values to cov[k] when it has COVARIANCE_SIZE of them, else cov[k] = 0.
    """
    n = buf.shape[0]
    for k in range(count):
        pos = _align(pos, 4)
        if pos + 8 > n:
            return -1
        sec = np.int64(_u32(buf, pos, be))
        if sec >= 2**31:  # int32
            sec -= 2**32
        stamps[k] = sec * 1_000_000_000 + np.int64(_u32(buf, pos + 4, be))
        off, ln, pos = _string(buf, pos + 8, be)
        if off < 0:
            return -1
        strings[k, 0], strings[k, 1] = off, ln
        off, ln, pos = _string(buf, pos, be)
        if off < 0:
            return -1
        strings[k, 2], strings[k, 3] = off, ln
        pos = _align(pos, 8)
        if pos + 80 + 1 > n:
            return -1
        first = (pos - _ORIGIN) // 8
        for j in range(10):  # radius, position, velocity, acceleration
            numbers[k, j] = f64[first + j]
        pos += 80
        remove[k] = buf[pos] != 0
        pos += 1
        if with_cov:
            pos = _align(pos, 4)
            if pos + 4 > n:
                return -1
            size = _u32(buf, pos, be)
            pos += 4
            cov_size[k] = size
            if size > 0:
                pos = _align(pos, 8)
                if pos + 8 * size > n:
                    return -1
            first = (pos - _ORIGIN) // 8
            full = size == COVARIANCE_SIZE
            for j in range(COVARIANCE_SIZE):
                cov[k, j] = f64[first + j] if full else 0.0
            pos += 8 * size
    return pos


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


def _decoded(data: bytes, buf: np.ndarray, strings: np.ndarray, col: int) -> list[str]:
    """The strings of column `col` of `strings` as str (UnicodeDecodeError if one is not UTF-8).

    One decode of all of them joined by NUL and one split, instead of a slice and
    a decode per string (~5x less time at 5,000 states): NUL ends no UTF-8
    sequence and starts none, so the joined bytes are valid exactly when each
    string is, and the split returns them unchanged -- unless a string holds a
    NUL itself, which the count of the parts shows; then each is decoded alone.
    All strings equal (the frames of an array, mostly): one decode, shared."""
    count = strings.shape[0]
    if count == 0:
        return []
    # one string (a per-body stream's message) needs no compiled pass to be "all the same"
    joined, same = (None, True) if count == 1 else _joined(buf, strings, col)
    if same:
        return [data[strings[0, col]:strings[0, col] + strings[0, col + 1]].decode()] * count
    parts = joined.tobytes().decode().split("\0")
    if len(parts) == count + 1:
        del parts[-1]
        return parts
    return [data[o:o + n].decode() for o, n in zip(strings[:, col].tolist(), strings[:, col + 1].tolist())]


def _batch(data: bytes, buf: np.ndarray, count: int, start: int, array_frame: str,
           be: bool, uncertainty: bool) -> StateBatch:
    stamps = np.empty(count, dtype=np.int64)
    strings = np.empty((count, 4), dtype=np.int64)
    numbers = np.empty((count, 10), dtype=np.float64)
    remove = np.empty(count, dtype=np.bool_)
    cov_size = np.zeros(count if uncertainty else 0, dtype=np.int64)
    cov = np.empty((count if uncertainty else 0, COVARIANCE_SIZE), dtype=np.float64)
    f64 = np.frombuffer(data, dtype=">f8" if be else "<f8", offset=_ORIGIN, count=(len(data) - _ORIGIN) // 8)
    if not f64.dtype.isnative:
        f64 = f64.astype(np.float64)
    if _decode_states(buf, f64, start, count, stamps, strings, numbers, remove, be, uncertainty,
                      cov_size, cov) < 0:
        raise CdrError("truncated or malformed CircleState data")
    given = uncertainty and (bool(cov_size[0]) if count == 1 else bool(cov_size.any()))
    try:
        ids = _decoded(data, buf, strings, 2)
        frames = _decoded(data, buf, strings, 0)
    except UnicodeDecodeError as exc:
        raise CdrError(f"a string is not UTF-8 ({exc.reason})") from exc
    if "" in frames:  # a state without a frame has the array's
        frames = [f or array_frame for f in frames]
    # positional: a frozen dataclass takes keywords at twice the cost (~2 us of a one-state message)
    return StateBatch(ids, frames, stamps, numbers[:, 0], numbers[:, 1:4], numbers[:, 4:7], numbers[:, 7:10],
                      remove, cov if given else None, cov_size if given else None)


def decode_states(data: bytes, msg_type: type, *, uncertainty: bool = True) -> StateBatch:
    """StateBatch from serialized CircleStateArray or CircleState bytes.

    uncertainty : False decodes the layout before CircleState had `covariance`
        (recordings made before issue 18; replay reads the recorded schema).

    Raises
    ------
    CdrError
        If the bytes are not a well-formed message of `msg_type`.
    """
    if msg_type is not CircleState and msg_type is not CircleStateArray:
        raise TypeError(f"no CDR decoder for {msg_type.__name__}")
    if len(data) < _ORIGIN or data[:2] not in (CDR_LE, CDR_BE):
        raise CdrError(f"not plain CDR (encapsulation {bytes(data[:2]).hex() or 'missing'})")
    be = data[:2] == CDR_BE
    buf = np.frombuffer(data, dtype=np.uint8)
    if msg_type is CircleState:
        return _batch(data, buf, 1, _ORIGIN, "", be, uncertainty)
    # Array header: stamp (8 bytes), frame_id, then the sequence count.
    off, ln, pos = _string(buf, _ORIGIN + 8, be) if len(buf) >= _ORIGIN + 8 else (-1, 0, 0)
    if off < 0:
        raise CdrError("truncated or malformed CircleStateArray header")
    pos = _align(pos, 4)
    if pos + 4 > len(buf):
        raise CdrError("truncated CircleStateArray (no sequence length)")
    count = int(_u32(buf, pos, be))
    # Each state needs at least 97 bytes (empty strings, no padding; 101 with the
    # covariance length): a larger count is a lie, not something to allocate for.
    if count * (101 if uncertainty else 97) > len(buf) - pos:
        raise CdrError(f"sequence length {count} does not fit in {len(buf)} bytes")
    try:
        array_frame = data[off:off + ln].decode()
    except UnicodeDecodeError as exc:
        raise CdrError(f"frame_id is not UTF-8 ({exc.reason})") from exc
    return _batch(data, buf, count, pos + 4, array_frame, be, uncertainty)


class _Writer:
    """Little-endian XCDR1 writer with alignment counted from the encapsulation header."""

    def __init__(self) -> None:
        self.buf = bytearray(CDR_LE + b"\x00\x00")

    def _pad(self, n: int) -> None:
        self.buf += b"\x00" * ((-(len(self.buf) - _ORIGIN)) % n)

    def u8(self, v: int) -> None:
        self.buf.append(v)

    def u32(self, v: int) -> None:
        self._pad(4)
        self.buf += struct.pack("<I", v)

    def time(self, sec: int, nanosec: int) -> None:
        self._pad(4)
        self.buf += struct.pack("<iI", sec, nanosec)

    def string(self, encoded: bytes) -> None:
        self.u32(len(encoded) + 1)
        self.buf += encoded + b"\x00"

    def f64s(self, *values: float) -> None:
        self._pad(8)
        self.buf += struct.pack(f"<{len(values)}d", *values)


def encode_state_array(batch: StateBatch, stamp_ns: int, frame_id: str) -> bytes:
    """Serialized CircleStateArray of `batch` (header stamp/frame as given).

    Each state's header carries its own stamp and frame; its covariance is
    batch.covariance's row when batch.covariance_size says 36, else empty. Used
    by load generators (benchmarks, soak) that must publish thousands of states
    at 30 Hz without building message objects.
    """
    w = _Writer()
    w.time(*divmod(int(stamp_ns), 1_000_000_000))
    w.string(frame_id.encode())
    w.u32(len(batch))
    _write_states(w, batch)
    return bytes(w.buf)


def encode_state(batch: StateBatch) -> bytes:
    """Serialized CircleState of a one-state batch (as encode_state_array writes each state)."""
    if len(batch) != 1:
        raise ValueError(f"encode_state takes one state, got {len(batch)}")
    w = _Writer()
    _write_states(w, batch)
    return bytes(w.buf)


def _write_states(w: _Writer, batch: StateBatch) -> None:
    numbers = np.column_stack([batch.radius, batch.position, batch.velocity, batch.acceleration]).tolist()
    if batch.covariance is None:
        covariances = [()] * len(batch)
    else:
        covariances = [row if size == COVARIANCE_SIZE else ()
                       for row, size in zip(batch.covariance.tolist(), batch.covariance_size.tolist())]
    for body_id, frame, stamp, values, remove, cov in zip(batch.ids, batch.frames, batch.stamp_ns.tolist(),
                                                          numbers, batch.remove.tolist(), covariances):
        w.time(*divmod(stamp, 1_000_000_000))
        w.string(frame.encode())
        w.string(body_id.encode())
        w.f64s(*values)
        w.u8(1 if remove else 0)
        w.u32(len(cov))
        if cov:
            w.f64s(*cov)


@njit(cache=True)
def _prediction_array_end(frame_len, name_len, count, uncertainty):
    """End position of a CollisionPredictionArray with these string lengths (no NULs)."""
    pos = _align(_ORIGIN + 8, 4) + 4 + frame_len + 1  # stamp, frame_id
    pos = _align(pos, 8) + 8                           # horizon
    pos = _align(pos, 4) + 4                           # sequence count
    for k in range(count):
        pos = _align(pos, 4) + 4 + name_len[2 * k] + 1
        pos = _align(pos, 4) + 4 + name_len[2 * k + 1] + 1
        pos = _align(pos + 1, 8) + 8                   # status, time_to_collision
        pos += 8 + 56                                  # contact_time; point, normal, closing
        if uncertainty:
            pos += 24                                  # probability, its bound, plausible time
    return pos


@njit(cache=True)
def _put_string(buf, u32, pos, src, start, n):
    pos = _align(pos, 4)
    u32[(pos - _ORIGIN) // 4] = n + 1
    pos += 4
    for j in range(n):
        buf[pos + j] = src[start + j]
    buf[pos + n] = 0
    return pos + n + 1


@njit(cache=True)
def _put_array_header(buf, u32, f64, sec, nanosec, frame, horizon, count):
    """CollisionPredictionArray's header stamp, frame_id, horizon and sequence count; the
    position of the first element."""
    u32[0] = np.uint32(sec & 0xFFFFFFFF)
    u32[1] = nanosec
    pos = _put_string(buf, u32, _ORIGIN + 8, frame, 0, frame.shape[0])
    pos = _align(pos, 8)
    f64[(pos - _ORIGIN) // 8] = horizon
    pos = _align(pos + 8, 4)
    u32[(pos - _ORIGIN) // 4] = count
    return pos + 4


@njit(cache=True)
def _encode_predictions(buf, u32, f64, sec, nanosec, frame, horizon, names, name_start, name_len,
                        status, ttc, contact_sec, contact_nanosec, point, normal, closing,
                        uncertainty, probability, bound, plausible):
    """Write a CollisionPredictionArray into zeroed `buf`; u32/f64 view it from _ORIGIN on."""
    count = ttc.shape[0]
    pos = _put_array_header(buf, u32, f64, sec, nanosec, frame, horizon, count)
    for k in range(count):
        pos = _put_string(buf, u32, pos, names, name_start[2 * k], name_len[2 * k])
        pos = _put_string(buf, u32, pos, names, name_start[2 * k + 1], name_len[2 * k + 1])
        buf[pos] = status[k]
        pos = _align(pos + 1, 8)
        f64[(pos - _ORIGIN) // 8] = ttc[k]
        pos += 8
        u32[(pos - _ORIGIN) // 4] = np.uint32(contact_sec[k] & 0xFFFFFFFF)
        u32[(pos - _ORIGIN) // 4 + 1] = np.uint32(contact_nanosec[k])
        pos += 8
        q = (pos - _ORIGIN) // 8
        for j in range(3):
            f64[q + j] = point[k, j]
            f64[q + 3 + j] = normal[k, j]
        f64[q + 6] = closing[k]
        pos += 56
        if uncertainty:
            f64[q + 7] = probability[k]
            f64[q + 8] = bound[k]
            f64[q + 9] = plausible[k]
            pos += 24
    return pos


def _encoded_names(names: list[str]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """UTF-8 bytes of all names back to back, with each name's start and length."""
    joined = "".join(names)
    if joined.isascii():  # byte length = character length
        lengths = np.fromiter(map(len, names), dtype=np.int64, count=len(names))
    else:
        lengths = np.fromiter((len(x.encode()) for x in names), dtype=np.int64, count=len(names))
    starts = np.zeros(len(names), dtype=np.int64)
    np.cumsum(lengths[:-1], out=starts[1:])
    return np.frombuffer(joined.encode(), dtype=np.uint8), starts, lengths


def _readonly(*arrays: np.ndarray) -> list[np.ndarray]:
    """The arrays, each writable one as a read-only view (no copy). numba compiles one
    specialisation per writability of each argument, and the encoders' inputs come writable
    or not depending on their source (the scene's published contacts are read-only, fresh
    columns are not): read-only, every call takes the one specialisation that
    CollisionPredictor.warm_up compiled."""
    out = []
    for a in arrays:
        if a.flags.writeable:
            a = a.view()
            a.flags.writeable = False
        out.append(a)
    return out


def encode_prediction_array(stamp: tuple[int, int], frame_id: str, horizon: float, columns,
                            utf8_ids: tuple | None = None, *, uncertainty: bool = True) -> bytes:
    """Serialized CollisionPredictionArray, written by one compiled loop.

    columns : a prediction_messages.PredictionColumns (id_a, id_b lists; status
        uint8; ttc; contact_ns int64; point, normal (K, 3); closing_speed;
        probability, probability_bound, plausible_ttc), in publication order.
        Padding bytes are zero; int32 seconds wrap as struct's "<i" would
        refuse, so callers keep times inside int32 range.
    utf8_ids : the same ids already encoded, ``(blob, start_a, len_a, start_b,
        len_b)`` (core.scene.SceneContacts.id_utf8): no per-name work here.
    uncertainty : False writes the layout before issue 18 (no probability
        fields), as recordings of that time hold it (replay).
    """
    if sys.byteorder != "little":  # the views below write native floats
        raise NotImplementedError("the compiled CDR encoder needs a little-endian machine")
    count = len(columns.ttc)
    if utf8_ids is not None:
        blob, start_a, len_a, start_b, len_b = utf8_ids
        starts = np.empty(2 * count, dtype=np.int64)
        lengths = np.empty(2 * count, dtype=np.int64)
        starts[0::2], starts[1::2] = start_a, start_b
        lengths[0::2], lengths[1::2] = len_a, len_b
    else:
        names = [None] * (2 * count)
        names[0::2], names[1::2] = columns.id_a, columns.id_b
        blob, starts, lengths = _encoded_names(names)
    frame = np.frombuffer(frame_id.encode(), dtype=np.uint8)
    end = int(_prediction_array_end(frame.shape[0], lengths, count, uncertainty))
    words = -(-(end - _ORIGIN) // 8)  # whole float64 words after the header
    buf = np.zeros(_ORIGIN + 8 * words, dtype=np.uint8)
    buf[:_ORIGIN] = np.frombuffer(CDR_LE + b"\x00\x00", dtype=np.uint8)
    body = buf[_ORIGIN:]
    contact_sec, contact_nanosec = np.divmod(columns.contact_ns, 1_000_000_000)
    (frame, blob, starts, lengths, status, ttc, contact_sec, contact_nanosec, point, normal, closing,
     probability, bound, plausible) = _readonly(
        frame, blob, starts, lengths, columns.status, columns.ttc, contact_sec, contact_nanosec,
        np.ascontiguousarray(columns.point), np.ascontiguousarray(columns.normal), columns.closing_speed,
        columns.probability, columns.probability_bound, columns.plausible_ttc)
    _encode_predictions(buf, body.view(np.uint32), body.view(np.float64), int(stamp[0]), int(stamp[1]),
                        frame, float(horizon), blob, starts, lengths, status, ttc, contact_sec,
                        contact_nanosec, point, normal, closing, uncertainty, probability, bound, plausible)
    return buf[:end].tobytes()


@njit(cache=True, inline="always")
def _put_two_names(u32, body, names, p, start_a, len_a, start_b, len_b):
    """id_a and id_b as CDR strings (length with the NUL, bytes, NUL) from `names` at position
    p (counted from _ORIGIN, so 4-alignment is a mask); the position after them."""
    for start, n in ((start_a, len_a), (start_b, len_b)):
        p = (p + 3) & ~3
        u32[p >> 2] = n + 1
        p += 4
        for j in range(n):
            body[p + j] = names[start + j]
        body[p + n] = 0
        p += n + 1
    return p


@njit(cache=True)
def _encode_contacts(buf, u32, f64, sec, nanosec, frame, horizon, names, start_a, len_a, start_b, len_b,
                     ttc, contact_ns, overlapping, point, normal, closing, contact, overlap_status,
                     found, probability, bound, plausible, extra, x_start_a, x_len_a, x_start_b, x_len_b,
                     no_contact):
    """_encode_predictions of contact rows then uncertain NO_CONTACT rows, with the columns
    derived row by row as prediction_messages.ScenePrediction.columns derives them: a contact
    row's status from `overlapping`, point/normal padded with +0.0 to 3-D, probability,
    bound and plausible time those of its uncertain row found[k] (row of `probability`,
    `bound`, `plausible`), or 1, 0, ttc when found is empty or found[k] < 0; then per
    uncertain row extra[j] (ids at x_start/x_len) a NO_CONTACT row: time +inf, zero contact
    time and details, that row's probability, bound and plausible time.
    Returns the end position, or -1 (buf partly written) at the first non-finite contact row.

    Positions count from _ORIGIN (p), so the CDR alignments are masks and the word indices
    shifts, and one finiteness test per row: 34 instead of 52 us for the 1,164 rows of
    bench/bench_scene_updates.py's 10,000-body scene; the same bytes as the general encoder
    (tests/test_prediction_cdr.py)."""
    count = ttc.shape[0]
    D = point.shape[1]
    p = _put_array_header(buf, u32, f64, sec, nanosec, frame, horizon, count + extra.shape[0]) - _ORIGIN
    body = buf[_ORIGIN:]
    for k in range(count):
        t = ttc[k]
        cs = closing[k]
        # x * 0.0 is +-0.0 for finite x and NaN for inf or NaN: one test for the row
        zero = t * 0.0 + cs * 0.0
        for j in range(D):
            zero += point[k, j] * 0.0 + normal[k, j] * 0.0
        if zero != 0.0:
            return -1
        p = _put_two_names(u32, body, names, p, start_a[k], len_a[k], start_b[k], len_b[k])
        body[p] = overlap_status if overlapping[k] else contact
        q = ((p + 8) & ~7) >> 3  # the float64 word of time_to_collision
        f64[q] = t
        c = contact_ns[k]
        csec = c // 1_000_000_000
        u32[2 * q + 2] = np.uint32(csec & 0xFFFFFFFF)
        u32[2 * q + 3] = np.uint32(c - csec * 1_000_000_000)
        q += 2
        for j in range(3):
            f64[q + j] = point[k, j] if j < D else 0.0
            f64[q + 3 + j] = normal[k, j] if j < D else 0.0
        f64[q + 6] = cs
        j = found[k] if found.shape[0] else -1
        if j < 0:
            f64[q + 7] = 1.0
            f64[q + 8] = 0.0
            f64[q + 9] = t
        else:
            f64[q + 7] = probability[j]
            f64[q + 8] = bound[j]
            f64[q + 9] = plausible[j]
        p = 8 * (q + 10)
    for k in range(extra.shape[0]):
        p = _put_two_names(u32, body, names, p, x_start_a[k], x_len_a[k], x_start_b[k], x_len_b[k])
        body[p] = no_contact
        q = ((p + 8) & ~7) >> 3
        f64[q] = np.inf  # contact time (sec, nanosec) and the details stay the buffer's zeros
        q += 2
        j = extra[k]
        f64[q + 7] = probability[j]
        f64[q + 8] = bound[j]
        f64[q + 9] = plausible[j]
        p = 8 * (q + 10)
    return p + _ORIGIN


@njit(cache=True)
def _contacts_end(frame_len, len_a, len_b):
    pos = _align(_ORIGIN + 8, 4) + 4 + frame_len + 1
    pos = _align(pos, 8) + 8
    pos = _align(pos, 4) + 4
    for k in range(len_a.shape[0]):
        pos = _align(pos, 4) + 4 + len_a[k] + 1
        pos = _align(pos, 4) + 4 + len_b[k] + 1
        pos = _align(pos + 1, 8) + 8 + 8 + 56 + 24
    return pos


_NONE_I = np.empty(0, dtype=np.int64)
_NONE_F = np.empty(0)
_NONE_I.flags.writeable = False
_NONE_F.flags.writeable = False


def encode_contact_rows(stamp: tuple[int, int], frame_id: str, horizon: float, contacts,
                        contact: int, overlapping: int, uncertain=None, no_contact: int = 0) -> bytes | None:
    """The CollisionPredictionArray of the contacts, then (given `uncertain`) uncertain
    NO_CONTACT rows, straight from a core.scene.SceneContacts with UTF-8 ids: the bytes
    encode_prediction_array writes for ScenePrediction.columns of it, without building the
    columns (one compiled pass). contact, overlapping, no_contact: the status values.

    uncertain: None (exact contacts only: probability 1, bound 0, plausible time = ttc) or
    ``(found, probability, bound, plausible, extra, id_utf8)`` of a core.scene.SceneUncertainty
    whose ids lie in the contacts' blob: found (K,) each contact's uncertain row (-1: none),
    the uncertainty's three columns, extra the uncertain rows published after the contacts,
    in order, and the uncertainty's id_utf8.
    None if a contact row is not finite (the caller then takes the general path, which leaves
    such rows out)."""
    if sys.byteorder != "little":
        raise NotImplementedError("the compiled CDR encoder needs a little-endian machine")
    if uncertain is None:
        found, probability, bound, plausible, extra = _NONE_I, _NONE_F, _NONE_F, _NONE_F, _NONE_I
        x_ids = (_NONE_I,) * 4
    else:
        found, probability, bound, plausible, extra, u_utf8 = uncertain
        x_ids = tuple(x[extra] for x in u_utf8[1:])
    (frame, blob, start_a, len_a, start_b, len_b, ttc, contact_ns, over, point, normal, closing, found,
     probability, bound, plausible, extra, x_start_a, x_len_a, x_start_b, x_len_b) = _readonly(
        np.frombuffer(frame_id.encode(), dtype=np.uint8), *contacts.id_utf8, contacts.ttc,
        contacts.contact_ns, contacts.overlapping, contacts.point, contacts.normal, contacts.closing_speed,
        found, probability, bound, plausible, extra, *x_ids)
    # a NO_CONTACT row has a contact row's layout: the end from all rows' id lengths
    lens_a, lens_b = _readonly(np.concatenate((len_a, x_len_a)), np.concatenate((len_b, x_len_b))) \
        if extra.shape[0] else (len_a, len_b)
    end = int(_contacts_end(frame.shape[0], lens_a, lens_b))
    buf = np.zeros(_ORIGIN + 8 * -(-(end - _ORIGIN) // 8), dtype=np.uint8)
    buf[:_ORIGIN] = np.frombuffer(CDR_LE + b"\x00\x00", dtype=np.uint8)
    body = buf[_ORIGIN:]
    if _encode_contacts(buf, body.view(np.uint32), body.view(np.float64), int(stamp[0]), int(stamp[1]),
                        frame, float(horizon), blob, start_a, len_a, start_b, len_b, ttc, contact_ns, over,
                        point, normal, closing, contact, overlapping, found, probability, bound, plausible,
                        extra, x_start_a, x_len_a, x_start_b, x_len_b, no_contact) < 0:
        return None
    return buf[:end].tobytes()
