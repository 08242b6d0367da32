"""CDR primitives shared by the message codecs (state_codec, prediction_codec, odometry).

rclpy turns every nested field into a Python object (about 30 us per
CircleState), so the node reads the raw bytes of its subscriptions with
compiled kernels instead, and writes its output bytes the same way. Both follow
the ROS 2 wire format (OMG XCDR1, little endian, as Fast DDS writes it):

- a 4-byte encapsulation header (00 01 00 00 = CDR little endian); every
  alignment is counted from the end of that header (ORIGIN);
- primitives are aligned to their own size (float64 to 8);
- a string is a uint32 length that counts the trailing NUL, then the bytes;
- a sequence is a uint32 count, then the elements (aligned to their own size
  only when there is at least one: an empty sequence is the count alone).

Two layouts of our interfaces exist on the wire and in recordings: the current
one (CircleState ends with `float64[<=36] covariance`; CollisionPrediction ends
with collision_probability, collision_probability_bound,
plausible_time_to_collision) and the one before the probability fields (neither). The node
speaks the current one; replay reads and writes the one a recording's schema
names (`uncertainty=False`), so old bags replay bit-identically.

Big-endian CDR (00 00) is decoded by the same kernels with the byte order
swapped; any other encapsulation is refused (CdrError). Untrusted bytes are
never handed to rclpy's deserializer: on malformed input it can crash the
process (SIGSEGV, e.g. CircleState b"\\x00\\x00\\x90\\xfa";
tests/reliability/test_fuzz_cdr.py). Tests check both directions against
rclpy.serialization on valid bytes.

Why this is safe on garbage: every read is bounds-checked against the buffer
and a string must end in NUL inside it; a violation returns an error code (the
compiled readers) or raises CdrError (CdrReader), and the message is rejected
as a whole, never partially used.
"""
from __future__ import annotations

import struct

import numpy as np
from numba import njit

CDR_LE = b"\x00\x01"
CDR_BE = b"\x00\x00"
ORIGIN = 4  # alignment is relative to the end of the encapsulation header
_U32 = struct.Struct("<I")


class CdrError(ValueError):
    """Bytes that are not a well-formed message of the expected type."""


@njit(cache=True)
def align(pos, n):
    """pos rounded up to a multiple of n counted from ORIGIN."""
    return ORIGIN + ((pos - ORIGIN + n - 1) // n) * n


@njit(cache=True)
def read_u32(buf, pos, be):
    """The uint32 at buf[pos:pos + 4] (be: big endian) as int64; the caller checks the bounds."""
    if be:
        return (np.int64(buf[pos]) << 24) | (np.int64(buf[pos + 1]) << 16) \
            | (np.int64(buf[pos + 2]) << 8) | np.int64(buf[pos + 3])
    return np.int64(buf[pos]) | (np.int64(buf[pos + 1]) << 8) | (np.int64(buf[pos + 2]) << 16) \
        | (np.int64(buf[pos + 3]) << 24)


@njit(cache=True)
def read_string(buf, pos, be):
    """(offset, length without NUL, next position) or (-1, 0, 0) when malformed."""
    pos = align(pos, 4)
    if pos + 4 > buf.shape[0]:
        return -1, 0, 0
    size = read_u32(buf, pos, be)
    start = pos + 4
    if size == 0:  # some writers send a bare zero length for ""
        return start, 0, start
    if start + size > buf.shape[0] or buf[start + size - 1] != 0:
        return -1, 0, 0
    return start, size - 1, start + size


class CdrWriter:
    """Little-endian XCDR1 writer with alignment counted from the encapsulation header."""

    def __init__(self) -> None:
        self.buf = bytearray(CDR_LE + b"\x00\x00")

    def _pad(self, n: int) -> None:
        self.buf += b"\x00" * ((-(len(self.buf) - ORIGIN)) % n)

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

    def f32s(self, *values: float) -> None:
        self._pad(4)
        self.buf += struct.pack(f"<{len(values)}f", *values)

    def f64_array(self, values: np.ndarray) -> None:
        """Every value of ``values`` as float64, in C order (a sequence's elements; one
        alignment for all: float64 fields only)."""
        self._pad(8)
        self.buf += np.ascontiguousarray(values, dtype="<f8").tobytes()


class CdrReader:
    """Little-endian XCDR1 reader on plain ``struct`` reads, each checked against the buffer
    (any violation a CdrError): for bytes read once per message, where a compiled pass
    would not pay (recorded predictions, strings)."""

    __slots__ = ("data", "pos")

    def __init__(self, data: bytes) -> None:
        if len(data) < ORIGIN or data[:2] != CDR_LE:
            raise CdrError(
                f"not little-endian CDR (encapsulation {bytes(data[:2]).hex() or 'missing'})"
            )
        self.data, self.pos = data, ORIGIN

    def unpack(self, fmt: struct.Struct, align: int) -> tuple:
        pos = ORIGIN + (self.pos - ORIGIN + align - 1) // align * align
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
            text = self.data[self.pos : end - 1].decode()
        except UnicodeDecodeError as exc:
            raise CdrError(f"string at byte {self.pos} is not UTF-8 ({exc.reason})") from exc
        self.pos = end
        return text

    def u8(self) -> int:
        if self.pos >= len(self.data):
            raise CdrError(f"message ends at byte {self.pos}")
        self.pos += 1
        return self.data[self.pos - 1]


def decode_string(data: bytes) -> str:
    """std_msgs/String bytes -> its text; CdrError if malformed."""
    return CdrReader(data).string()
