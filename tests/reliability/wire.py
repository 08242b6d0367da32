"""Serialized CircleState(Array) bytes built directly (both byte orders), for fuzzing and load.

Independent of cdr_codec (the code under test) and much faster than building
rclpy message objects (~30 us per CircleState), so a 1,000-body scene at 30 Hz
costs a few ms per message. Layout: OMG XCDR1 with a 4-byte encapsulation header
(00 01 = little endian, 00 00 = big endian); alignment is counted from the end
of that header.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass, field


@dataclass
class Body:
    """One CircleState's fields (stamp in ns; vectors as 3-tuples)."""

    id: str
    radius: float = 0.5
    p: tuple = (0.0, 0.0, 0.0)
    v: tuple = (0.0, 0.0, 0.0)
    a: tuple = (0.0, 0.0, 0.0)
    stamp_ns: int = 0
    frame: str = "map"
    remove: bool = False
    id_bytes: bytes | None = field(default=None, repr=False)  # raw id (e.g. invalid UTF-8)
    stamp: tuple | None = None  # raw (sec, nanosec), e.g. nanosec >= 1e9; overrides stamp_ns
    covariance: tuple = ()  # any length (the bounded sequence float64[<=36])


class _Writer:
    def __init__(self, big_endian: bool) -> None:
        self.e = ">" if big_endian else "<"
        self.buf = bytearray(b"\x00\x00\x00\x00" if big_endian else b"\x00\x01\x00\x00")

    def pad(self, n: int) -> None:
        self.buf += b"\x00" * ((-(len(self.buf) - 4)) % n)

    def u32(self, v: int) -> None:
        self.pad(4)
        self.buf += struct.pack(self.e + "I", v)

    def stamp(self, ns: int) -> None:
        sec, nanosec = divmod(ns, 1_000_000_000)
        sec = max(min(sec, 2**31 - 1), -(2**31))
        self.pad(4)
        self.buf += struct.pack(self.e + "iI", sec, nanosec)

    def string(self, raw: bytes) -> None:
        self.u32(len(raw) + 1)
        self.buf += raw + b"\x00"

    def f64s(self, values) -> None:
        self.pad(8)
        self.buf += struct.pack(self.e + f"{len(values)}d", *values)


def _state(w: _Writer, b: Body, with_covariance: bool = True) -> None:
    if b.stamp is not None:
        w.pad(4)
        w.buf += struct.pack(w.e + "iI", *b.stamp)
    else:
        w.stamp(b.stamp_ns)
    w.string(b.frame.encode())
    w.string(b.id_bytes if b.id_bytes is not None else b.id.encode("utf-8", "surrogatepass"))
    w.f64s((b.radius, *b.p, *b.v, *b.a))
    w.buf.append(1 if b.remove else 0)
    if not with_covariance:
        return
    w.u32(len(b.covariance))
    if b.covariance:
        w.f64s(b.covariance)


def encode_array(bodies, stamp_ns: int, frame: str = "map", big_endian: bool = False,
                 with_covariance: bool = True) -> bytes:
    """Serialized CircleStateArray (with_covariance False: the layout before CircleState had
    its covariance sequence, as old recordings)."""
    w = _Writer(big_endian)
    w.stamp(stamp_ns)
    w.string(frame.encode())
    w.u32(len(bodies))
    for b in bodies:
        _state(w, b, with_covariance)
    return bytes(w.buf)


def encode_state(body: Body, big_endian: bool = False, with_covariance: bool = True) -> bytes:
    """Serialized CircleState (with_covariance as encode_array's)."""
    w = _Writer(big_endian)
    _state(w, body, with_covariance)
    return bytes(w.buf)


def encode_scene(ids: list[bytes], radii, p, v, a, stamp_ns: int, frame: str = "map") -> bytes:
    """Serialized CircleStateArray of N bodies sharing one stamp/frame (fast path for load).

    ids are pre-encoded; p, v, a are (N, 3) arrays. ~2 us per body.
    """
    w = _Writer(False)
    w.stamp(stamp_ns)
    fr = frame.encode()
    w.string(fr)
    n = len(ids)
    w.u32(n)
    sec, nanosec = divmod(stamp_ns, 1_000_000_000)
    head = struct.pack("<iI", sec, nanosec) + struct.pack("<I", len(fr) + 1) + fr + b"\x00"
    rows = [radii.tolist(), p.tolist(), v.tolist(), a.tolist()]
    buf = w.buf
    for k in range(n):
        buf += b"\x00" * ((-(len(buf) - 4)) % 4)
        buf += head
        buf += b"\x00" * ((-(len(buf) - 4)) % 4)
        buf += struct.pack("<I", len(ids[k]) + 1) + ids[k] + b"\x00"
        buf += b"\x00" * ((-(len(buf) - 4)) % 8)
        buf += struct.pack("<10d", rows[0][k], *rows[1][k], *rows[2][k], *rows[3][k])
        buf.append(0)
        buf += b"\x00" * ((-(len(buf) - 4)) % 4) + b"\x00\x00\x00\x00"  # empty covariance
    return bytes(buf)
