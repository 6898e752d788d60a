"""Test helpers for the live viewer: the address it prints, and the protobuf it sends.

:func:`read_view_url` finds the ``live view on ws://...`` line of
``cartpole run --view`` / ``cartpole offline --view``.

:class:`Schema` is a protobuf wire-format reader driven by the schema a
Foxglove server advertises: the Foxglove WebSocket protocol advertises a
protobuf channel with its schema as a base64 ``FileDescriptorSet``; this
reads that set (itself protobuf, with the field numbers of
google/protobuf/descriptor.proto) and then decodes messages into dicts by
field name, so a test checks what a client would draw without the protobuf
package.
"""
from __future__ import annotations

import base64
import struct

MARKER = 'live view on '


def read_view_url(stream) -> str | None:
    """The viewer's address from a command's stderr lines (None if it ends without one)."""
    for line in stream:
        if MARKER in line:
            return line.split(MARKER)[1].split()[0]
    return None


_DOUBLE, _FLOAT, _MESSAGE, _STRING, _BYTES, _ENUM, _BOOL = 1, 2, 11, 9, 12, 14, 8
_FIXED64 = {1, 6, 16}
_FIXED32 = {2, 7, 15}
_REPEATED = 3


def _varint(buf: bytes, pos: int) -> tuple[int, int]:
    value = shift = 0
    while True:
        byte = buf[pos]
        pos += 1
        value |= (byte & 0x7F) << shift
        if not byte & 0x80:
            return value, pos
        shift += 7


def fields(buf: bytes):
    """(field number, wire type, raw value) of every field of a message."""
    pos = 0
    while pos < len(buf):
        key, pos = _varint(buf, pos)
        number, wire = key >> 3, key & 7
        if wire == 0:
            value, pos = _varint(buf, pos)
        elif wire == 1:
            value, pos = buf[pos:pos + 8], pos + 8
        elif wire == 2:
            n, pos = _varint(buf, pos)
            value, pos = buf[pos:pos + n], pos + n
        elif wire == 5:
            value, pos = buf[pos:pos + 4], pos + 4
        else:
            raise ValueError(f'unsupported wire type {wire}')
        yield number, wire, value


class Schema:
    """The message types of a FileDescriptorSet: full name -> {number: (name, type, label, type_name)}."""

    def __init__(self, descriptor_set: bytes) -> None:
        self.types: dict[str, dict[int, tuple[str, int, int, str]]] = {}
        for number, _, file_bytes in fields(descriptor_set):
            if number != 1:
                continue
            package = ''
            messages = []
            for fnum, _, value in fields(file_bytes):
                if fnum == 2:
                    package = value.decode()
                elif fnum == 4:
                    messages.append(value)
            for message in messages:
                self._add(package, message)

    def _add(self, scope: str, message: bytes) -> None:
        name, members, nested = '', {}, []
        for fnum, _, value in fields(message):
            if fnum == 1:
                name = value.decode()
            elif fnum == 2:
                field = {n: v for n, _, v in fields(value)}
                members[field[3]] = (field[1].decode(), field.get(5, 0), field.get(4, 1),
                                     field.get(6, b'').decode().lstrip('.'))
            elif fnum == 3:
                nested.append(value)
        full = f'{scope}.{name}' if scope else name
        self.types[full] = members
        for child in nested:
            self._add(full, child)

    @classmethod
    def from_advertised(cls, channel: dict) -> 'Schema':
        """From an ``advertise`` entry (``schema`` base64 for protobuf channels)."""
        return cls(base64.b64decode(channel['schema']))

    def decode(self, type_name: str, buf: bytes) -> dict:
        members = self.types[type_name]
        out: dict = {name: [] for name, _, label, _ in members.values() if label == _REPEATED}
        for number, wire, raw in fields(buf):
            if number not in members:
                continue
            name, ftype, label, sub = members[number]
            if wire == 2 and ftype not in (_MESSAGE, _STRING, _BYTES):
                values = list(self._packed(ftype, raw))
            else:
                values = [self._scalar(ftype, wire, raw, sub)]
            if label == _REPEATED:
                out[name].extend(values)
            else:
                out[name] = values[-1]
        for name, ftype, label, _ in members.values():  # proto3 leaves out default values
            if name not in out and ftype != _MESSAGE:
                out[name] = '' if ftype == _STRING else b'' if ftype == _BYTES else \
                    False if ftype == _BOOL else 0
        return out

    def _scalar(self, ftype: int, wire: int, raw, sub: str):
        if ftype == _MESSAGE:
            return self.decode(sub, raw)
        if ftype == _STRING:
            return raw.decode()
        if ftype == _BYTES:
            return bytes(raw)
        if ftype == _DOUBLE:
            return struct.unpack('<d', raw)[0]
        if ftype == _FLOAT:
            return struct.unpack('<f', raw)[0]
        if ftype == _BOOL:
            return bool(raw)
        if wire == 1:
            return struct.unpack('<q', raw)[0]
        if wire == 5:
            return struct.unpack('<i', raw)[0]
        return raw

    def _packed(self, ftype: int, raw: bytes):
        pos = 0
        while pos < len(raw):
            if ftype in _FIXED64:
                yield self._scalar(ftype, 1, raw[pos:pos + 8], '')
                pos += 8
            elif ftype in _FIXED32:
                yield self._scalar(ftype, 5, raw[pos:pos + 4], '')
                pos += 4
            else:
                value, pos = _varint(raw, pos)
                yield value
