"""The Joint serial protocol's codec: messages, checksums, encoding and decoding.

ASCII lines between the host and the Arduino Due I/O bridge, ``\\n``
terminated (a ``\\r`` before it is tolerated), 115200 baud 8N1, each ending in
``*HH``, the XOR of every byte before the ``*`` (as in NMEA 0183). Host to
device: :class:`Ping` ``P``, :class:`Enable` ``E``, :class:`ResetCounters`
``R``, :class:`Stream` ``L``, :class:`Setpoint` ``U``; device to host:
:class:`Version` ``V``, :class:`Sample` ``S``, :class:`DeviceError` ``!``.
Version 2 (:data:`PROTOCOL_VERSION`) adds the loop's latency report (a tagged
``U`` and two more ``S`` fields). The lines, the field rules and the latency
report are in docs/rig.md ("The Joint protocol"); the firmware's
``joint_protocol.cpp`` implements the same, pinned by the shared vectors in
``firmware/test_vectors/protocol_vectors.txt``.

Decoding never raises: :func:`decode_line` returns a message or a
:class:`DecodeError` whose ``reason`` is one of :data:`DECODE_REASONS`, so the
caller counts and drops. The line splitter, the counters and the calibration
are modules of their own. No ROS import.
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Union

PROTOCOL_VERSION = 2
"""Version the device announces in ``V`` (2: tagged setpoints and the latency report)."""
LATENCY_REPORT_VERSION = 2
"""The first version with tagged ``U`` and the ``S`` latency fields; a device of an older
version gets untagged setpoints only (it would refuse a tag as ``bad_field_count``)."""

MAX_LINE = 96
"""Longest accepted line in bytes, checksum included, terminator excluded."""

UINT32 = 1 << 32
INT16_MIN, INT16_MAX = -32768, 32767

FLAG_ENABLED = 1 << 0
FLAG_WATCHDOG = 1 << 1
FLAG_LIMIT_LEFT = 1 << 2
FLAG_LIMIT_RIGHT = 1 << 3

DECODE_REASONS = ('bad_checksum', 'missing_checksum', 'oversized', 'unknown_type',
                  'bad_field_count', 'bad_number', 'out_of_range', 'non_ascii')
"""Every reason a line is refused; also the device's ``!`` codes 1..8 in this order."""

ERROR_CODES = {reason: i + 1 for i, reason in enumerate(DECODE_REASONS)}
ERROR_CODES.update({
    'refused': 9,        # a valid command the device will not do now (R while enabled)
    'watchdog': 16,      # no U for 50 ms while enabled: current zeroed
    'limit': 17,         # a limit switch closed while enabled
    'rx_overflow': 18,   # the device's input buffer overflowed, bytes were lost
})
"""``!`` codes. Codes >= :data:`FAULT_CODE_MIN` are faults: the host disarms."""
FAULT_CODE_MIN = 16

HOST_TYPES = frozenset('PERLU')
DEVICE_TYPES = frozenset('VS!')

_NUMBER = re.compile(rb'-?[0-9]{1,10}\Z')
_HEX = b'0123456789abcdefABCDEF'


# -- messages ----------------------------------------------------------------------
@dataclass(frozen=True)
class Ping:
    """``P``: the device answers :class:`Version`."""

    def body(self) -> str:
        return 'P'


@dataclass(frozen=True)
class Enable:
    """``E,1`` / ``E,0``: enable / disable the amplifier (disabled = zero current)."""

    on: bool

    def body(self) -> str:
        return f'E,{int(bool(self.on))}'


@dataclass(frozen=True)
class ResetCounters:
    """``R``: zero both encoder counters (HCTL-2021 RST)."""

    def body(self) -> str:
        return 'R'


@dataclass(frozen=True)
class Stream:
    """``L,1`` / ``L,0``: start / stop streaming samples."""

    on: bool

    def body(self) -> str:
        return f'L,{int(bool(self.on))}'


@dataclass(frozen=True)
class Setpoint:
    """``U,<setpoint>[,<tag>]``: signed current setpoint, F = 0.017623 N x setpoint (A.3);
    ``tag`` (version 2): the ``seq`` of the sample the command was computed from."""

    value: int
    tag: int | None = None

    def body(self) -> str:
        _check_range('setpoint', self.value, INT16_MIN, INT16_MAX)
        if self.tag is None:
            return f'U,{int(self.value)}'
        _check_range('tag', self.tag, 0, UINT32 - 1)
        return f'U,{int(self.value)},{int(self.tag)}'


@dataclass(frozen=True)
class Version:
    """``V,<version>,<name>``: the answer to :class:`Ping`."""

    version: int
    name: str

    def body(self) -> str:
        _check_range('version', self.version, 0, 65535)
        _check_text('name', self.name, allow_comma=False, allow_empty=False)
        return f'V,{int(self.version)},{self.name}'


@dataclass(frozen=True)
class Sample:
    """``S,<seq>,<t_us>,<cart_ticks>,<pend_ticks>,<flags>[,<back>,<age_us>]``: one 5 ms
    sample; ``back`` and ``age_us`` (version 2, both or neither): the command in force
    answers sample ``seq - back`` and took effect ``age_us`` before this sample."""

    seq: int
    t_us: int
    cart_ticks: int
    pend_ticks: int
    flags: int
    back: int | None = None
    age_us: int | None = None

    def body(self) -> str:
        _check_range('seq', self.seq, 0, UINT32 - 1)
        _check_range('t_us', self.t_us, 0, UINT32 - 1)
        _check_range('cart_ticks', self.cart_ticks, INT16_MIN, INT16_MAX)
        _check_range('pend_ticks', self.pend_ticks, INT16_MIN, INT16_MAX)
        _check_range('flags', self.flags, 0, 15)
        body = (f'S,{int(self.seq)},{int(self.t_us)},{int(self.cart_ticks)},'
                f'{int(self.pend_ticks)},{int(self.flags)}')
        if self.back is None and self.age_us is None:
            return body
        _check_range('back', self.back, 0, UINT32 - 1)
        _check_range('age_us', self.age_us, 0, UINT32 - 1)
        return f'{body},{int(self.back)},{int(self.age_us)}'

    @property
    def applied_seq(self) -> int | None:
        """``seq`` of the sample the command in force answers (None: no report)."""
        return None if self.back is None else (self.seq - self.back) % UINT32

    @property
    def applied_t_us(self) -> int | None:
        """Device time [us] at which the command in force took effect (None: no report)."""
        return None if self.age_us is None else (self.t_us - self.age_us) % UINT32

    @property
    def enabled(self) -> bool:
        return bool(self.flags & FLAG_ENABLED)

    @property
    def watchdog_tripped(self) -> bool:
        return bool(self.flags & FLAG_WATCHDOG)

    @property
    def limit_left(self) -> bool:
        return bool(self.flags & FLAG_LIMIT_LEFT)

    @property
    def limit_right(self) -> bool:
        return bool(self.flags & FLAG_LIMIT_RIGHT)


@dataclass(frozen=True)
class DeviceError:
    """``!,<code>,<text>``: an error the device noticed (codes in :data:`ERROR_CODES`)."""

    code: int
    text: str

    def body(self) -> str:
        _check_range('code', self.code, 0, 255)
        _check_text('text', self.text, allow_comma=True, allow_empty=True)
        return f'!,{int(self.code)},{self.text}'

    @property
    def is_fault(self) -> bool:
        return self.code >= FAULT_CODE_MIN


Message = Union[Ping, Enable, ResetCounters, Stream, Setpoint, Version, Sample, DeviceError]


@dataclass(frozen=True)
class DecodeError:
    """A refused line: ``reason`` is one of :data:`DECODE_REASONS`."""

    reason: str
    line: bytes = b''
    detail: str = ''

    def __bool__(self) -> bool:   # so ``if result:`` reads "decoded"
        return False


def _check_range(name: str, value: int, lo: int, hi: int) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
        raise ValueError(f'{name} must be an integer in [{lo}, {hi}], got {value!r}')


def _check_text(name: str, text: str, allow_comma: bool, allow_empty: bool) -> None:
    if not isinstance(text, str) or (not text and not allow_empty):
        raise ValueError(f'{name} must be a non-empty string, got {text!r}')
    bad = [c for c in text if not 0x20 <= ord(c) <= 0x7E or c == '*' or (c == ',' and not allow_comma)]
    if bad:
        raise ValueError(f'{name} {text!r} has characters the protocol cannot carry: {bad!r}')


# -- checksum and encoding ------------------------------------------------------------
def checksum(body: bytes | str) -> int:
    """XOR of every byte of ``body`` (the part of a line before ``*``)."""
    if isinstance(body, str):
        body = body.encode('ascii')
    value = 0
    for byte in body:
        value ^= byte
    return value


def frame(body: str) -> bytes:
    """``body*HH\\n`` with the checksum in upper-case hex."""
    raw = body.encode('ascii')
    line = raw + b'*%02X\n' % checksum(raw)
    if len(line) - 1 > MAX_LINE:
        raise ValueError(f'line {body!r} is longer than {MAX_LINE} bytes')
    return line


def encode(message: Message) -> bytes:
    """The wire form of ``message``: ``body*HH\\n``. Raises ValueError on fields the
    protocol cannot carry (a bug of the caller, not of the link)."""
    return frame(message.body())


# -- decoding -----------------------------------------------------------------------------
def _number(field_: bytes, lo: int, hi: int) -> int | str:
    """The integer in ``field_`` or the reason it is refused."""
    if not _NUMBER.match(field_):
        return 'bad_number'
    value = int(field_)
    if not lo <= value <= hi:
        return 'out_of_range'
    return value


_UINT32 = (0, UINT32 - 1)
_S_FIELDS = (_UINT32, _UINT32, (INT16_MIN, INT16_MAX), (INT16_MIN, INT16_MAX), (0, 15))
_ARGS = {  # type -> the accepted forms: per field (lo, hi), or None for text
    'P': ((),),
    'R': ((),),
    'E': (((0, 1),),),
    'L': (((0, 1),),),
    'U': (((INT16_MIN, INT16_MAX),), ((INT16_MIN, INT16_MAX), _UINT32)),
    'V': (((0, 65535), None),),
    'S': (_S_FIELDS, _S_FIELDS + (_UINT32, _UINT32)),
    '!': (((0, 255), None),),
}


def decode_line(line: bytes | bytearray | str, direction: str | None = None) -> Message | DecodeError:
    """Decode one line (with or without its ``\\n`` / ``\\r\\n``).

    ``direction`` restricts the accepted types: ``'device'`` for lines from the
    device (V, S, !), ``'host'`` for lines from the host (P, E, R, L, U),
    None for both. A type of the other direction is ``unknown_type``.
    Never raises; a refused line gives a :class:`DecodeError`.
    """
    if isinstance(line, str):
        try:
            line = line.encode('ascii')
        except UnicodeEncodeError:
            return DecodeError('non_ascii', line.encode('utf-8', 'replace')[:MAX_LINE])
    line = bytes(line)
    if line.endswith(b'\n'):
        line = line[:-1]
    if line.endswith(b'\r'):
        line = line[:-1]
    if len(line) > MAX_LINE:
        return DecodeError('oversized', line[:MAX_LINE], f'{len(line)} bytes')
    if any(b < 0x20 or b > 0x7E for b in line):
        return DecodeError('non_ascii', line)
    star = line.rfind(b'*')
    if star < 0:
        return DecodeError('missing_checksum', line)
    body, tail = line[:star], line[star + 1:]
    if len(tail) != 2 or tail[0] not in _HEX or tail[1] not in _HEX:
        return DecodeError('bad_checksum', line, 'checksum is not two hex digits')
    if int(tail, 16) != checksum(body):
        return DecodeError('bad_checksum', line, f'computed {checksum(body):02X}')
    kind = body[:1].decode('ascii')
    allowed = HOST_TYPES | DEVICE_TYPES
    if direction == 'device':
        allowed = DEVICE_TYPES
    elif direction == 'host':
        allowed = HOST_TYPES
    if kind not in allowed or (len(body) > 1 and body[1:2] != b','):
        return DecodeError('unknown_type', line)
    fields = body.split(b',', 2) if kind == '!' else body.split(b',')
    args = fields[1:]
    forms = _ARGS[kind]
    specs = next((form for form in forms if len(form) == len(args)), None)
    if specs is None:
        counts = ' or '.join(str(len(form)) for form in forms)
        return DecodeError('bad_field_count', line, f'{kind} takes {counts} fields, got {len(args)}')
    values: list[int | str] = []
    for spec, raw in zip(specs, args):
        if spec is None:
            values.append(raw.decode('ascii'))
            continue
        value = _number(raw, *spec)
        if isinstance(value, str):
            return DecodeError(value, line, f'field {raw!r}')
        values.append(value)
    if kind == 'P':
        return Ping()
    if kind == 'R':
        return ResetCounters()
    if kind == 'E':
        return Enable(bool(values[0]))
    if kind == 'L':
        return Stream(bool(values[0]))
    if kind == 'U':
        return Setpoint(*values)
    if kind == 'V':
        if not values[1]:
            return DecodeError('bad_field_count', line, 'empty name')
        return Version(values[0], values[1])
    if kind == 'S':
        return Sample(*values)
    return DeviceError(values[0], values[1])


def canonical(result: Message | DecodeError) -> str:
    """The text form used by the shared test vectors: the body of a decoded
    message (``S,1,5000,-3,12,1``) or ``err:<reason>``."""
    if isinstance(result, DecodeError):
        return f'err:{result.reason}'
    return result.body()
