"""Bounds-checked decoding of recorded CollisionPredictionArray and String bytes (replay's input).

A bag is untrusted input, and rclpy's deserializer can crash the process on
malformed bytes (see pipeline/cdr_codec.py), so replay decodes what it reads
from a recording here: plain ``struct`` reads, each checked against the
buffer, any violation a :class:`~circle_collision_ros.pipeline.cdr_codec.CdrError`.
Layout: XCDR1 little endian as pipeline/cdr_codec.py's encoder writes it
(alignment counted from the end of the 4-byte encapsulation header).

The rows are plain NamedTuples, compared field by field with ``==`` exactly
as the generated message classes compare (floats by value: -0.0 == 0.0,
NaN != NaN). tests/recording/test_prediction_cdr.py checks them against
rclpy on valid bytes and on damaged ones.
"""
from __future__ import annotations

import struct
from typing import NamedTuple

from circle_collision_ros.pipeline.cdr_codec import CDR_LE, CdrError

_ORIGIN = 4
_TIME = struct.Struct("<iI")
_F64 = struct.Struct("<d")
_U32 = struct.Struct("<I")
_VECTORS = struct.Struct("<7d")  # contact_point xyz, normal xyz, closing_speed
_UNCERTAINTY = struct.Struct("<3d")  # collision_probability, its bound, plausible_time_to_collision


class PairPrediction(NamedTuple):
    """One pair's entry of a CollisionPredictionArray (units: s, m, m/s)."""

    id_a: str
    id_b: str
    status: int                               # CollisionPrediction.NO_CONTACT / CONTACT / OVERLAPPING
    time_to_collision: float                  # s after the array's stamp; +inf when no contact
    contact_time: tuple[int, int]             # (sec, nanosec)
    contact_point: tuple[float, float, float]
    normal: tuple[float, float, float]
    closing_speed: float
    # None in recordings made before the interface had them (see cdr_codec, "Two layouts").
    collision_probability: float | None = None
    collision_probability_bound: float | None = None
    plausible_time_to_collision: float | None = None  # s after the array's stamp; +inf if never


class PredictionArray(NamedTuple):
    """A decoded CollisionPredictionArray."""

    header: tuple[int, int, str]              # (stamp sec, stamp nanosec, frame_id)
    horizon: float
    predictions: tuple[PairPrediction, ...]


class _Reader:
    __slots__ = ("data", "pos")

    def __init__(self, data: bytes) -> None:
        if len(data) < _ORIGIN or data[:2] != CDR_LE:
            raise CdrError(f"not little-endian CDR (encapsulation {bytes(data[:2]).hex() or 'missing'})")
        self.data, self.pos = data, _ORIGIN

    def unpack(self, fmt: struct.Struct, align: int) -> tuple:
        pos = _ORIGIN + (self.pos - _ORIGIN + align - 1) // align * align
        if pos + fmt.size > len(self.data):
            raise CdrError(f"message ends inside a field at byte {pos}")
        self.pos = pos + fmt.size
        return fmt.unpack_from(self.data, pos)

    def string(self) -> str:
        (length,) = self.unpack(_U32, 4)
        end = self.pos + length
        if length < 1 or end > len(self.data) or self.data[end - 1] != 0:
            raise CdrError(f"string of {length} bytes at byte {self.pos} is malformed")
        try:
            text = self.data[self.pos:end - 1].decode()
        except UnicodeDecodeError as exc:
            raise CdrError(f"string at byte {self.pos} is not UTF-8 ({exc.reason})") from exc
        self.pos = end
        return text

    def u8(self) -> int:
        if self.pos >= len(self.data):
            raise CdrError(f"message ends at byte {self.pos}")
        self.pos += 1
        return self.data[self.pos - 1]


def decode_prediction_array(data: bytes, *, uncertainty: bool = True) -> PredictionArray:
    """CollisionPredictionArray bytes -> PredictionArray; CdrError if malformed.

    uncertainty=False: the layout before the probability fields (older recordings).
    """
    r = _Reader(data)
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
        predictions.append(PairPrediction(id_a, id_b, status, ttc, contact_time, v[0:3], v[3:6], v[6], *u))
    return PredictionArray(header, horizon, tuple(predictions))


def peek_prediction_array(data: bytes) -> tuple[float, int]:
    """(horizon, number of entries) of CollisionPredictionArray bytes, without decoding the entries."""
    r = _Reader(data)
    r.unpack(_TIME, 4)
    r.string()
    (horizon,) = r.unpack(_F64, 8)
    (count,) = r.unpack(_U32, 4)
    return horizon, count


def decode_string(data: bytes) -> str:
    """std_msgs/String bytes -> its text; CdrError if malformed."""
    return _Reader(data).string()
