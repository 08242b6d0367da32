"""CollisionPredictionArray codec: the node's compiled encoder and replay's bounds-checked decoder.

Encoding (encode_prediction_array, encode_contact_rows) writes the node's
output bytes in one compiled pass, little-endian XCDR1 (pipeline/cdr.py), the
current layout or (`uncertainty=False`) the one before the probability fields.

Decoding (decode_prediction_array, peek_prediction_array) reads what replay
takes from a recording. A bag is untrusted input, and rclpy's deserializer can
crash the process on malformed bytes (see pipeline/cdr.py), so these are plain
``struct`` reads, each checked against the buffer, any violation a
:class:`~circle_collision_ros.pipeline.cdr.CdrError`. The rows are plain
NamedTuples, compared field by field with ``==`` exactly as the generated
message classes compare (floats by value: -0.0 == 0.0, NaN != NaN).

tests/pipeline/test_prediction_codec.py checks the encoder against a
field-by-field reference writer and rclpy, and the decoder against rclpy and
the recorded schema on valid bytes and on damaged ones.
"""
from __future__ import annotations

import struct
import sys
from typing import NamedTuple

import numpy as np
from numba import njit

from circle_collision_ros.pipeline.cdr import CDR_LE, ORIGIN, CdrReader, align

_TIME = struct.Struct("<iI")
_F64 = struct.Struct("<d")
_U32 = struct.Struct("<I")
_VECTORS = struct.Struct("<7d")  # contact_point xyz, normal xyz, closing_speed
_UNCERTAINTY = struct.Struct("<3d")  # collision_probability, its bound, plausible_time_to_collision


class PairPrediction(NamedTuple):
    """One pair's entry of a CollisionPredictionArray (units: s, m, m/s)."""

    id_a: str
    id_b: str
    # CollisionPrediction.NO_CONTACT / CONTACT / OVERLAPPING
    status: int
    time_to_collision: float                  # s after the array's stamp; +inf when no contact
    contact_time: tuple[int, int]             # (sec, nanosec)
    contact_point: tuple[float, float, float]
    normal: tuple[float, float, float]
    closing_speed: float
    # None in recordings made before the interface had them (see pipeline/cdr.py, "Two layouts").
    collision_probability: float | None = None
    collision_probability_bound: float | None = None
    plausible_time_to_collision: float | None = None  # s after the array's stamp; +inf if never


class PredictionArray(NamedTuple):
    """A decoded CollisionPredictionArray."""

    header: tuple[int, int, str]              # (stamp sec, stamp nanosec, frame_id)
    horizon: float
    predictions: tuple[PairPrediction, ...]


def decode_prediction_array(data: bytes, *, uncertainty: bool = True) -> PredictionArray:
    """CollisionPredictionArray bytes -> PredictionArray; CdrError if malformed.

    uncertainty=False: the layout before the probability fields (older recordings).
    """
    r = CdrReader(data)
    sec, nanosec = r.unpack(_TIME, 4)
    header = (sec, nanosec, r.string())
    (horizon,) = r.unpack(_F64, 8)
    (count,) = r.unpack(_U32, 4)
    predictions = []
    for _ in range(count):
        id_a, id_b, status = r.string(), r.string(), r.u8()
        (ttc,) = r.unpack(_F64, 8)
        contact_time = r.unpack(_TIME, 4)
        v = r.unpack(_VECTORS, 8)
        u = r.unpack(_UNCERTAINTY, 8) if uncertainty else (None, None, None)
        predictions.append(
            PairPrediction(id_a, id_b, status, ttc, contact_time, v[0:3], v[3:6], v[6], *u)
        )
    return PredictionArray(header, horizon, tuple(predictions))


def peek_prediction_array(data: bytes) -> tuple[float, int]:
    """(horizon, entry count) of CollisionPredictionArray bytes, without decoding the entries."""
    r = CdrReader(data)
    r.unpack(_TIME, 4)
    r.string()
    (horizon,) = r.unpack(_F64, 8)
    (count,) = r.unpack(_U32, 4)
    return horizon, count


@njit(cache=True)
def _prediction_array_end(frame_len, name_len, count, uncertainty):
    """End position of a CollisionPredictionArray with these string lengths (no NULs)."""
    pos = align(ORIGIN + 8, 4) + 4 + frame_len + 1  # stamp, frame_id
    pos = align(pos, 8) + 8  # horizon
    pos = align(pos, 4) + 4  # sequence count
    for k in range(count):
        pos = align(pos, 4) + 4 + name_len[2 * k] + 1
        pos = align(pos, 4) + 4 + name_len[2 * k + 1] + 1
        pos = align(pos + 1, 8) + 8  # status, time_to_collision
        pos += 8 + 56  # contact_time; point, normal, closing
        if uncertainty:
            pos += 24  # probability, its bound, plausible time
    return pos


@njit(cache=True)
def _put_string(buf, u32, pos, src, start, n):
    pos = align(pos, 4)
    u32[(pos - ORIGIN) // 4] = n + 1
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
    pos = _put_string(buf, u32, ORIGIN + 8, frame, 0, frame.shape[0])
    pos = align(pos, 8)
    f64[(pos - ORIGIN) // 8] = horizon
    pos = align(pos + 8, 4)
    u32[(pos - ORIGIN) // 4] = count
    return pos + 4


@njit(cache=True)
def _encode_predictions(buf, u32, f64, sec, nanosec, frame, horizon, names, name_start, name_len,
                        status, ttc, contact_sec, contact_nanosec, point, normal, closing,
                        uncertainty, probability, bound, plausible):
    """Write a CollisionPredictionArray into zeroed `buf`; u32/f64 view it from ORIGIN on."""
    count = ttc.shape[0]
    pos = _put_array_header(buf, u32, f64, sec, nanosec, frame, horizon, count)
    for k in range(count):
        pos = _put_string(buf, u32, pos, names, name_start[2 * k], name_len[2 * k])
        pos = _put_string(buf, u32, pos, names, name_start[2 * k + 1], name_len[2 * k + 1])
        buf[pos] = status[k]
        pos = align(pos + 1, 8)
        f64[(pos - ORIGIN) // 8] = ttc[k]
        pos += 8
        u32[(pos - ORIGIN) // 4] = np.uint32(contact_sec[k] & 0xFFFFFFFF)
        u32[(pos - ORIGIN) // 4 + 1] = np.uint32(contact_nanosec[k])
        pos += 8
        q = (pos - ORIGIN) // 8
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
    uncertainty : False writes the layout before the probability fields (none
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
    words = -(-(end - ORIGIN) // 8)  # whole float64 words after the header
    buf = np.zeros(ORIGIN + 8 * words, dtype=np.uint8)
    buf[:ORIGIN] = np.frombuffer(CDR_LE + b"\x00\x00", dtype=np.uint8)
    body = buf[ORIGIN:]
    contact_sec, contact_nanosec = np.divmod(columns.contact_ns, 1_000_000_000)
    (frame, blob, starts, lengths, status, ttc, contact_sec, contact_nanosec, point, normal,
     closing, probability, bound, plausible) = _readonly(
        frame,
        blob,
        starts,
        lengths,
        columns.status,
        columns.ttc,
        contact_sec,
        contact_nanosec,
        np.ascontiguousarray(columns.point),
        np.ascontiguousarray(columns.normal),
        columns.closing_speed,
        columns.probability,
        columns.probability_bound,
        columns.plausible_ttc,
    )
    _encode_predictions(buf, body.view(np.uint32), body.view(np.float64), int(stamp[0]),
                        int(stamp[1]), frame, float(horizon), blob, starts, lengths, status, ttc,
                        contact_sec, contact_nanosec, point, normal, closing, uncertainty,
                        probability, bound, plausible)
    return buf[:end].tobytes()


@njit(cache=True, inline="always")
def _put_two_names(u32, body, names, p, start_a, len_a, start_b, len_b):
    """id_a and id_b as CDR strings (length with the NUL, bytes, NUL) from `names` at position
    p (counted from ORIGIN, so 4-alignment is a mask); the position after them."""
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
def _encode_contacts(buf, u32, f64, sec, nanosec, frame, horizon, names, start_a, len_a, start_b,
                     len_b, ttc, contact_ns, overlapping, point, normal, closing, contact,
                     overlap_status, found, probability, bound, plausible, extra, x_start_a,
                     x_len_a, x_start_b, x_len_b, no_contact):
    """_encode_predictions of contact rows then uncertain NO_CONTACT rows, with the columns
    derived row by row as prediction_messages.ScenePrediction.columns derives them: a contact
    row's status from `overlapping`, point/normal padded with +0.0 to 3-D, probability,
    bound and plausible time those of its uncertain row found[k] (row of `probability`,
    `bound`, `plausible`), or 1, 0, ttc when found is empty or found[k] < 0; then per
    uncertain row extra[j] (ids at x_start/x_len) a NO_CONTACT row: time +inf, zero contact
    time and details, that row's probability, bound and plausible time.
    Returns the end position, or -1 (buf partly written) at the first non-finite contact row.

    Positions count from ORIGIN (p), so the CDR alignments are masks and the word indices
    shifts, and one finiteness test per row (measured faster than the general encoder:
    bench/bench_scene_updates.py); the same bytes as the general encoder
    (tests/pipeline/test_prediction_codec.py)."""
    count = ttc.shape[0]
    D = point.shape[1]
    p = (
        _put_array_header(buf, u32, f64, sec, nanosec, frame, horizon, count + extra.shape[0])
        - ORIGIN
    )
    body = buf[ORIGIN:]
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
    return p + ORIGIN


@njit(cache=True)
def _contacts_end(frame_len, len_a, len_b):
    pos = align(ORIGIN + 8, 4) + 4 + frame_len + 1
    pos = align(pos, 8) + 8
    pos = align(pos, 4) + 4
    for k in range(len_a.shape[0]):
        pos = align(pos, 4) + 4 + len_a[k] + 1
        pos = align(pos, 4) + 4 + len_b[k] + 1
        pos = align(pos + 1, 8) + 8 + 8 + 56 + 24
    return pos


_NONE_I = np.empty(0, dtype=np.int64)
_NONE_F = np.empty(0)
_NONE_I.flags.writeable = False
_NONE_F.flags.writeable = False


def encode_contact_rows(stamp: tuple[int, int], frame_id: str, horizon: float, contacts,
                        contact: int, overlapping: int, uncertain=None,
                        no_contact: int = 0) -> bytes | None:
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
    (frame, blob, start_a, len_a, start_b, len_b, ttc, contact_ns, over, point, normal, closing,
     found, probability, bound, plausible, extra, x_start_a, x_len_a, x_start_b,
     x_len_b) = _readonly(
        np.frombuffer(frame_id.encode(), dtype=np.uint8),
        *contacts.id_utf8,
        contacts.ttc,
        contacts.contact_ns,
        contacts.overlapping,
        contacts.point,
        contacts.normal,
        contacts.closing_speed,
        found,
        probability,
        bound,
        plausible,
        extra,
        *x_ids,
    )
    # a NO_CONTACT row has a contact row's layout: the end from all rows' id lengths
    lens_a, lens_b = (
        _readonly(np.concatenate((len_a, x_len_a)), np.concatenate((len_b, x_len_b)))
        if extra.shape[0]
        else (len_a, len_b)
    )
    end = int(_contacts_end(frame.shape[0], lens_a, lens_b))
    buf = np.zeros(ORIGIN + 8 * -(-(end - ORIGIN) // 8), dtype=np.uint8)
    buf[:ORIGIN] = np.frombuffer(CDR_LE + b"\x00\x00", dtype=np.uint8)
    body = buf[ORIGIN:]
    if (
        _encode_contacts(buf, body.view(np.uint32), body.view(np.float64), int(stamp[0]),
                         int(stamp[1]), frame, float(horizon), blob, start_a, len_a, start_b, len_b,
                         ttc, contact_ns, over, point, normal, closing, contact, overlapping, found,
                         probability, bound, plausible, extra, x_start_a, x_len_a, x_start_b,
                         x_len_b, no_contact)
        < 0
    ):
        return None
    return buf[:end].tobytes()
