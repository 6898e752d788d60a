"""The Joint serial protocol (docs/rig.md, "The Joint protocol"): codec, stream splitter,
conversions.

ASCII lines between the host and the Arduino Due I/O bridge, ``\\n``
terminated (a ``\\r`` before it is tolerated), 115200 baud 8N1. Every line
ends with ``*HH``: the XOR of every byte before the ``*``, as two hex digits
(emitted upper case, accepted in either case), as in NMEA 0183.

=================  ==========================================  ===========
direction          line                                        class
=================  ==========================================  ===========
host -> device     ``P``                                       :class:`Ping`
host -> device     ``E,1`` / ``E,0``                           :class:`Enable`
host -> device     ``R``                                       :class:`ResetCounters`
host -> device     ``L,1`` / ``L,0``                           :class:`Stream`
host -> device     ``U,<setpoint>``                            :class:`Setpoint`
host -> device     ``U,<setpoint>,<tag>`` (version 2)          :class:`Setpoint`
device -> host     ``V,<version>,<name>``                      :class:`Version`
device -> host     ``S,<seq>,<t_us>,<cart>,<pend>,<flags>``    :class:`Sample`
device -> host     ``S,...,<flags>,<back>,<age_us>`` (v2)      :class:`Sample`
device -> host     ``!,<code>,<text>``                         :class:`DeviceError`
=================  ==========================================  ===========

Version 2 (:data:`PROTOCOL_VERSION`) adds the loop's latency report. The
host tags a setpoint with the ``seq`` of the sample it was computed from
(``U,<setpoint>,<tag>``); the untagged ``U,<setpoint>`` stays valid (the zero
commands of a disarm, which answer no sample). Every sample line after a
tagged setpoint took effect carries two more fields: which command is in
force and when it took effect, both relative to the sample itself, in the
device's own units:

- ``back``: ``seq - tag`` (mod 2**32), how many samples before this one the
  sample the command answers was taken;
- ``age_us``: ``t_us - applied`` (mod 2**32), how long before this sample
  the command took effect (``micros()`` when the firmware wrote it to the
  DAC; in the emulator when it acts on the plant, its scenario delay
  included).

So ``applied_seq = seq - back`` and ``applied_t_us = t_us - age_us``
(:attr:`Sample.applied_seq`, :attr:`Sample.applied_t_us`). Relative, not
absolute: the line stays as short as a version-1 line plus a few bytes
(``,2,3100``), which matters on the programming port's 115200 baud (200
lines a second of 60 bytes would not fit). The two fields are absent (the
version-1 form, 5 fields) until the first tagged setpoint took effect and
again after anything that ends it: an untagged ``U``, ``E``, the watchdog,
a tagged ``U`` while disabled. A version-1 host sends no tags, so it never
sees a 7-field line from a version-2 device. The host accepts both forms,
the device both ``U`` forms.

Field rules (the firmware's ``joint_protocol.cpp`` implements the same; the
shared vectors in ``firmware/test_vectors/protocol_vectors.txt`` pin both):

- numbers are decimal, ``-?[0-9]{1,10}`` (no ``+``, no spaces), else
  ``bad_number``;
- ``seq`` and ``t_us`` are uint32 (0 .. 2**32 - 1) and wrap: ``seq`` counts
  samples since the device booted, ``t_us`` is the device's ``micros()``;
- ``cart``/``pend`` are the raw HCTL-2021 counters, int16 (they wrap);
- ``flags`` is 0..15 (bit 0 enabled, bit 1 watchdog tripped, bit 2 left
  limit switch, bit 3 right limit switch);
- ``U``'s setpoint is int16 on the wire; the device clamps it to the DAC
  range (DAC value = 1953 + setpoint in 0..4095, Appendix A); its tag,
  ``back`` and ``age_us`` are uint32;
- ``E``/``L`` take exactly ``0`` or ``1``; ``V``'s version is 0..65535 and
  its name non-empty; ``!``'s code is 0..255 and its text is everything after
  the second comma (commas allowed, ``*`` not);
- a line is at most :data:`MAX_LINE` bytes without its terminator, every byte
  printable ASCII (0x20..0x7E).

Decoding never raises: :func:`decode_line` returns a message or a
:class:`DecodeError` whose ``reason`` is one of :data:`DECODE_REASONS`, so
the caller counts and drops. This module has no ROS import.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from typing import Iterable, Union

from cartpole_core.model import CartPoleParameters, EncoderResolution, wrap_counter

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


# -- stream splitting -------------------------------------------------------------------------
@dataclass
class LineSplitter:
    """Splits arbitrary byte chunks into lines, with a bounded buffer.

    :meth:`feed` returns complete lines (bytes, terminator and a trailing
    ``\\r`` stripped, empty lines skipped) and, for every run of more than
    :data:`MAX_LINE` bytes without a newline, one ``DecodeError('oversized')``:
    the bytes are dropped up to the next ``\\n``. The buffer never holds more
    than ``max_line + 1`` bytes.
    """

    max_line: int = MAX_LINE
    _buffer: bytearray = field(default_factory=bytearray)
    _discarding: bool = False

    def feed(self, chunk: bytes) -> list[bytes | DecodeError]:
        out: list[bytes | DecodeError] = []
        start = 0
        n = len(chunk)
        while start < n:
            nl = chunk.find(b'\n', start)
            end = n if nl < 0 else nl
            piece = chunk[start:end]
            if self._discarding:
                pass
            elif len(self._buffer) + len(piece) > self.max_line + 1:   # +1: a trailing \r
                out.append(DecodeError('oversized', bytes(self._buffer[:32]) + piece[:32]))
                self._buffer.clear()
                self._discarding = True
            else:
                self._buffer += piece
            if nl < 0:
                break
            # a terminator: emit the line (unless it was discarded)
            if not self._discarding:
                line = bytes(self._buffer)
                if line.endswith(b'\r'):
                    line = line[:-1]
                if len(line) > self.max_line:
                    out.append(DecodeError('oversized', line[:64]))
                elif line:
                    out.append(line)
            self._buffer.clear()
            self._discarding = False
            start = nl + 1
        return out

    @property
    def buffered(self) -> int:
        return len(self._buffer)

    def reset(self) -> None:
        self._buffer.clear()
        self._discarding = False


@dataclass
class SequenceTracker:
    """Counts lost samples from the uint32 sequence numbers of ``S`` lines.

    ``seq`` wraps from 2**32 - 1 to 0 (about 248 days at 200 Hz); a step of
    ``d = (seq - last) mod 2**32`` with ``0 < d < 2**31`` means ``d - 1`` lost
    samples, ``d == 0`` a duplicate, anything else a jump backwards
    (the device restarted, or a stale line): counted in :attr:`restarts` and
    the tracker resynchronises on it.
    """

    received: int = 0
    lost: int = 0
    duplicates: int = 0
    restarts: int = 0
    last: int | None = None

    def update(self, seq: int) -> int:
        """Account for ``seq``; returns the samples lost just before it
        (-1 for a restart/backwards jump, 0 for a duplicate or none lost)."""
        self.received += 1
        if self.last is None:
            self.last = seq
            return 0
        delta = (seq - self.last) % UINT32
        if delta == 0:
            self.duplicates += 1
            return 0
        self.last = seq
        if delta < UINT32 // 2:
            self.lost += delta - 1
            return delta - 1
        self.restarts += 1
        return -1

    def resync(self, seq: int) -> None:
        """Take ``seq`` as the next number (no loss counted): the sequence really moved."""
        self.last = (seq - 1) % UINT32

    def reset(self) -> None:
        self.last = None


@dataclass
class CounterUnwrapper:
    """Rebuilds a continuous count from a wrapping signed counter (the HCTL-2021's int16).

    Correct as long as the counter moves less than half its range between two
    reads (16 revolutions of the pendulum in 5 ms is far beyond the rig).
    """

    bits: int = 16
    _last: int | None = None
    _total: int = 0

    def update(self, raw: int) -> int:
        if self._last is None:
            self._total = raw
        else:
            self._total += wrap_counter(raw - self._last, self.bits)
        self._last = raw
        return self._total

    def reset(self) -> None:
        self._last = None
        self._total = 0


# -- conversions (2.3), (2.4), (A.3) ----------------------------------------------------------
@dataclass(frozen=True)
class Calibration(EncoderResolution):
    """Ticks <-> SI and force <-> setpoint of the rig.

    The encoder figures default to those of :class:`CartPoleParameters` (the
    one place the thesis's 8737 ticks over 0.769 m, 2000 ticks/rev and 16-bit
    counters are written), as floats (the bridge's parameters
    are doubles); the resolutions are :class:`EncoderResolution`'s. Signs are +1 when a positive count means the cart moved right (x grows)
    and the pendulum turned towards positive theta, and when a positive
    setpoint pushes the cart right; flip them if the wiring is reversed.
    """

    cart_sign: int = 1
    pendulum_sign: int = 1
    force_sign: int = 1
    cart_ticks_over_travel: float = float(CartPoleParameters.cart_ticks_over_travel)
    """Cart ticks over the whole travel (2.4)."""
    travel: float = CartPoleParameters.travel
    """Cart travel between the end stops [m] (section 2.3)."""
    pendulum_ticks_per_rev: float = float(CartPoleParameters.pendulum_ticks_per_rev)
    """Pendulum ticks per revolution (2.3)."""
    setpoint_per_newton: float = 56.744
    """1 / 0.017623 N, setpoint per newton (A.3)."""
    dac_zero: int = 1953
    """DAC value of zero current (Appendix A: offset 2000 corrected to 1953)."""
    dac_max: int = 4095
    """Largest value of the 12-bit DAC."""
    counter_bits: int = CartPoleParameters.counter_bits
    """Width of the HCTL-2021 counters; they wrap (section 2.3)."""

    def __post_init__(self) -> None:
        for name in ('cart_sign', 'pendulum_sign', 'force_sign'):
            if getattr(self, name) not in (1, -1):
                raise ValueError(f'{name} must be +1 or -1, got {getattr(self, name)!r}')
        for name in ('cart_ticks_over_travel', 'travel', 'pendulum_ticks_per_rev',
                     'setpoint_per_newton'):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f'{name} must be a finite number > 0, got {value!r}')
        if not (isinstance(self.dac_max, int) and self.dac_max > 0):
            raise ValueError(f'dac_max must be a positive integer, got {self.dac_max!r}')
        if not (isinstance(self.dac_zero, int) and 0 <= self.dac_zero <= self.dac_max):
            raise ValueError(f'dac_zero must be an integer in [0, {self.dac_max}], got {self.dac_zero!r}')

    @classmethod
    def from_parameters(cls, params: CartPoleParameters, **changes) -> 'Calibration':
        """The calibration matching the plant parameters' encoder figures."""
        base = dict(cart_ticks_over_travel=float(params.cart_ticks_over_travel),
                    travel=params.travel,
                    pendulum_ticks_per_rev=float(params.pendulum_ticks_per_rev),
                    counter_bits=params.counter_bits)
        base.update(changes)
        return cls(**base)

    @property
    def setpoint_min(self) -> int:
        """Lowest setpoint the DAC can output: -dac_zero (-1953)."""
        return -self.dac_zero

    @property
    def setpoint_max(self) -> int:
        """Highest setpoint the DAC can output: dac_max - dac_zero (2142)."""
        return self.dac_max - self.dac_zero

    def cart_position(self, ticks: int) -> float:
        """x [m] from an unwrapped cart count (2.4); 0 at the left stop after reset."""
        return self.cart_sign * ticks * self.cart_resolution

    def pendulum_angle(self, ticks: int) -> float:
        """theta [rad] from an unwrapped pendulum count (2.3); pi hanging after reset."""
        return math.pi + self.pendulum_sign * ticks * self.pendulum_resolution

    def force_to_setpoint(self, force: float) -> int:
        """setpoint = 56.744 x F (A.3), rounded half up, clamped to the DAC range
        [-1953, 2142]; a non-finite force gives 0. The amplifier saturates at
        +11 A / -12 A (about +34 N / -37 N, Appendix C) anyway, well inside
        that range (+-37 N is about +-2100)."""
        if not math.isfinite(force):
            return 0
        setpoint = math.floor(self.force_sign * force * self.setpoint_per_newton + 0.5)
        return self.clamp_setpoint(setpoint)

    def setpoint_to_force(self, setpoint: int) -> float:
        """F = setpoint / 56.744 = 0.017623 N x setpoint (A.3)."""
        return self.force_sign * setpoint / self.setpoint_per_newton

    def clamp_setpoint(self, setpoint: int) -> int:
        """The setpoint the DAC can output: dac_value(s) - dac_zero."""
        return min(max(int(setpoint), self.setpoint_min), self.setpoint_max)

    def dac_value(self, setpoint: int) -> int:
        """12-bit DAC value for a setpoint: dac_zero + setpoint clamped to 0..dac_max."""
        return min(max(self.dac_zero + int(setpoint), 0), self.dac_max)


def iter_lines(chunks: Iterable[bytes]) -> Iterable[bytes | DecodeError]:
    """Convenience: split an iterable of chunks into lines with a :class:`LineSplitter`."""
    splitter = LineSplitter()
    for chunk in chunks:
        yield from splitter.feed(chunk)
