"""A direct reader of serialized ``diagnostic_msgs/DiagnosticArray`` messages (no ROS).

The viewer takes the controller status 200 times a second; reading the
strings it needs straight from the CDR bytes (as
:func:`cartpole_analysis.analysis.analyze.parse_joint_state` does for JointState)
costs a fraction of rclpy's deserialisation into message objects.

Layout (XCDR1, as rclpy hands it to a ``raw=True`` subscription): a 4-byte
encapsulation header whose second byte gives the byte order, then
``header`` (int32 sec, uint32 nanosec, string frame_id) and the sequence of
``DiagnosticStatus`` (octet level, strings name, message, hardware_id, and
the sequence of ``KeyValue`` (strings key, value)); strings are a uint32
length including the terminating NUL, then the bytes; uint32s are aligned
to 4 bytes from the start of the payload.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass


@dataclass(frozen=True)
class Status:
    """One ``DiagnosticStatus``: level, name, message, hardware id, key/values."""

    level: int
    name: str
    message: str
    hardware_id: str
    values: dict[str, str]


def parse_diagnostic_array(data: bytes | memoryview) -> tuple[int, list[Status]]:
    """(header stamp [ns], statuses) of a CDR ``diagnostic_msgs/DiagnosticArray``.

    Raises ValueError on a truncated or malformed message.
    """
    buf = bytes(data)
    if len(buf) < 12:
        raise ValueError('DiagnosticArray message too short')
    order = '<' if buf[1] & 1 else '>'
    u32 = struct.Struct(order + 'I')
    base = 4
    pos = 8  # after the stamp (relative to the payload start)

    def uint32() -> int:
        nonlocal pos
        pos += (-pos) % 4
        if base + pos + 4 > len(buf):
            raise ValueError('DiagnosticArray message truncated')
        (value,) = u32.unpack_from(buf, base + pos)
        pos += 4
        return value

    def string() -> str:
        nonlocal pos
        n = uint32()
        if base + pos + n > len(buf):
            raise ValueError('DiagnosticArray string runs past the message')
        text = buf[base + pos:base + pos + max(n - 1, 0)].decode('utf-8', errors='replace')
        pos += n
        return text

    sec, nanosec = struct.unpack_from(order + 'iI', buf, base)
    string()  # frame_id
    statuses = []
    for _ in range(uint32()):
        if base + pos >= len(buf):
            raise ValueError('DiagnosticArray message truncated')
        level = buf[base + pos]
        pos += 1
        name, message, hardware_id = string(), string(), string()
        values = {}
        for _ in range(uint32()):
            key = string()
            values[key] = string()
        statuses.append(Status(level, name, message, hardware_id, values))
    return sec * 1_000_000_000 + nanosec, statuses
