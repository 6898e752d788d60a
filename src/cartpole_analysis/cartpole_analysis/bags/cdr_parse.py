"""Direct readers of the two message layouts a run's bag is made of (no ROS, no typestore).

ROS 2 CDR (XCDR1): a 4-byte encapsulation header whose second byte gives the
byte order, then the fields, each aligned to its size relative to the start
of the payload. Reading the few fields the analysis needs this way is about
ten times faster than a generic deserialiser on long bags; tests compare both.
"""
from __future__ import annotations

import struct

import numpy as np


class _Cdr:
    """A cursor over one CDR payload."""

    __slots__ = ('buf', 'order', 'pos')

    def __init__(self, data: bytes | memoryview) -> None:
        self.buf = memoryview(data)
        self.order = '<' if self.buf[1] & 1 else '>'
        self.pos = 0  # relative to the payload (after the 4-byte header)

    def align(self, n: int) -> None:
        self.pos += (-self.pos) % n

    def u32(self) -> int:
        self.align(4)
        (v,) = struct.unpack_from(self.order + 'I', self.buf, 4 + self.pos)
        self.pos += 4
        return v

    def stamp_ns(self) -> int:
        sec, nanosec = struct.unpack_from(self.order + 'iI', self.buf, 4 + self.pos)
        self.pos += 8
        return sec * 1_000_000_000 + nanosec

    def octet(self) -> int:
        value = self.buf[4 + self.pos]
        self.pos += 1
        return value

    def string(self) -> str:
        n = self.u32()
        start = 4 + self.pos
        self.pos += n
        return bytes(self.buf[start:start + max(n - 1, 0)]).decode('utf-8')

    def doubles(self) -> np.ndarray:
        n = self.u32()
        if n:
            self.align(8)
        arr = np.frombuffer(self.buf, dtype=self.order + 'f8', count=n, offset=4 + self.pos)
        self.pos += 8 * n
        return arr


def parse_joint_state(data: bytes | memoryview) -> tuple[int, list[str], np.ndarray, np.ndarray,
                                                         np.ndarray]:
    """(stamp [ns], name, position, velocity, effort) of a CDR sensor_msgs/JointState."""
    c = _Cdr(data)
    stamp = c.stamp_ns()
    c.string()  # frame_id
    names = [c.string() for _ in range(c.u32())]
    position, velocity, effort = c.doubles(), c.doubles(), c.doubles()
    return stamp, names, position, velocity, effort


def parse_diagnostic_array(data: bytes | memoryview) -> tuple[int, list[tuple[str, dict[str, str]]]]:
    """(stamp [ns], [(status name, {key: value})]) of a CDR diagnostic_msgs/DiagnosticArray."""
    c = _Cdr(data)
    stamp = c.stamp_ns()
    c.string()  # frame_id
    statuses = []
    for _ in range(c.u32()):
        c.octet()  # level
        name = c.string()
        c.string()  # message
        c.string()  # hardware_id
        values = {}
        for _ in range(c.u32()):
            key = c.string()
            values[key] = c.string()
        statuses.append((name, values))
    return stamp, statuses
