"""The firmware's command handling as a pure state machine (Python mirror).

The logic of ``firmware/cartpole_bridge/joint_protocol.cpp`` (``JpDevice``),
which the emulator runs, so it answers exactly as the sketch does. Time is an
argument (device ``micros()``, uint32, wrapping), so every behaviour is a pure
function of the inputs: ``E`` enables (zero setpoint) or disables, ``U`` sets
the clamped setpoint and feeds the 50 ms watchdog (checked at each 5 ms tick,
tripping at the tick that crosses the deadline), ``R`` zeroes the counters
(refused while enabled), ``P`` answers ``V``, ``L`` streams; a tagged ``U``
starts the latency report of protocol version 2; current towards a closed
limit switch is inhibited; a refused line is answered ``!,<code>,<reason>``.
The same rules are pinned for both by ``firmware/test_vectors/protocol_vectors.txt``;
in prose in docs/rig.md ("The Joint protocol", "The latency report").
"""
from __future__ import annotations

from dataclasses import dataclass

from . import protocol as jp

WATCHDOG_US = 50_000
"""Device watchdog: longest time without ``U`` while enabled [us]."""
SAMPLE_PERIOD_US = 5_000
"""The firmware's sample period Ts [us]: the watchdog runs once a period."""


def elapsed_us(now_us: int, then_us: int) -> int:
    """``now - then`` on the wrapping uint32 ``micros()`` clock."""
    return (now_us - then_us) % jp.UINT32


@dataclass
class DeviceLogic:
    """Command handling, watchdog and flags of the I/O bridge firmware."""

    name: str = 'cartpole_bridge'
    dac_zero: int = 1953
    dac_max: int = 4095
    watchdog_us: int = WATCHDOG_US
    sample_period_us: int = SAMPLE_PERIOD_US
    positive_setpoint_drives_right: bool = True

    enabled: bool = False
    streaming: bool = False
    watchdog_tripped: bool = False
    setpoint: int = 0
    last_u_us: int = 0
    seq: int = 0
    pending_tag: int | None = None
    """Tag of the last tagged ``U``, until its output is written (or reported acting)."""
    applied_tag: int | None = None
    """Tag of the command in force (None: no tagged command in force, no report)."""
    applied_us: int = 0
    """Device time [us] at which the command :attr:`applied_tag` took effect."""
    _first_tag: int | None = None
    """First tag since the report last ended: reports of older tags are late (a delayed
    command of before a disarm) and not taken."""
    _limit_left: bool = False
    _limit_right: bool = False

    # -- commands -----------------------------------------------------------------
    def handle_line(self, line: bytes, now_us: int) -> tuple[list[bytes], bool]:
        """Act on one received line; returns (reply lines, reset the counters)."""
        message = jp.decode_line(line, direction='host')
        if isinstance(message, jp.DecodeError):
            return [self.error(jp.ERROR_CODES[message.reason], message.reason)], False
        if isinstance(message, jp.Ping):
            return [jp.encode(jp.Version(jp.PROTOCOL_VERSION, self.name))], False
        if isinstance(message, jp.Enable):
            self.enabled = message.on
            self.setpoint = 0
            self.watchdog_tripped = False
            self.last_u_us = now_us
            self.end_report()
            return [], False
        if isinstance(message, jp.Stream):
            self.streaming = message.on
            return [], False
        if isinstance(message, jp.ResetCounters):
            if self.enabled:
                return [self.error(jp.ERROR_CODES['refused'], 'reset refused while enabled')], False
            return [], True
        # Setpoint
        self.setpoint = min(max(message.value, -self.dac_zero), self.dac_max - self.dac_zero)
        self.last_u_us = now_us
        self.watchdog_tripped = False
        if message.tag is None or not self.enabled:
            self.end_report()
        else:
            self.pending_tag = message.tag
            if self._first_tag is None:
                self._first_tag = message.tag
        return [], False

    # -- the latency report (version 2) ------------------------------------------------------
    def end_report(self) -> None:
        """No tagged command is in force any more: ``S`` lines without the report."""
        self.pending_tag = self.applied_tag = self._first_tag = None

    def output_written(self, now_us: int) -> None:
        """The output was written at ``now_us`` (the sketch's DAC write): a pending tagged
        command took effect then."""
        if self.pending_tag is not None:
            self.command_applied(self.pending_tag, now_us)

    def take_pending(self) -> int | None:
        """The pending tag, handed over to whoever reports it acting (the emulator's plant)."""
        tag, self.pending_tag = self.pending_tag, None
        return tag

    def command_applied(self, tag: int, now_us: int) -> None:
        """The command tagged ``tag`` took effect at device time ``now_us`` [us]. Ignored
        for a tag from before the report last ended."""
        first = self._first_tag
        if first is None or (tag - first) % jp.UINT32 >= jp.UINT32 // 2:
            return
        if self.pending_tag == tag:
            self.pending_tag = None
        self.applied_tag, self.applied_us = tag, now_us % jp.UINT32

    @staticmethod
    def error(code: int, text: str) -> bytes:
        return jp.encode(jp.DeviceError(code, text))

    # -- periodic ------------------------------------------------------------------------
    def tick(self, now_us: int, limit_left: bool, limit_right: bool) -> list[bytes]:
        """Run the watchdog and the limit switches at ``now_us``; returns lines to send.

        Called once a sample period; the watchdog trips at this tick when the
        next one (``sample_period_us`` later) would be past the deadline.
        """
        out: list[bytes] = []
        if self.enabled and not self.watchdog_tripped and \
                elapsed_us(now_us, self.last_u_us) > self.watchdog_us - self.sample_period_us:
            self.watchdog_tripped = True
            self.end_report()
            out.append(self.error(jp.ERROR_CODES['watchdog'], 'watchdog'))
        if self.enabled and limit_left and not self._limit_left:
            out.append(self.error(jp.ERROR_CODES['limit'], 'limit left'))
        if self.enabled and limit_right and not self._limit_right:
            out.append(self.error(jp.ERROR_CODES['limit'], 'limit right'))
        self._limit_left, self._limit_right = limit_left, limit_right
        return out

    def output_setpoint(self) -> int:
        """The setpoint the DAC outputs now: 0 unless enabled, watchdog quiet and
        not pushing towards a closed limit switch."""
        if not self.enabled or self.watchdog_tripped:
            return 0
        s = self.setpoint
        rightwards = s > 0 if self.positive_setpoint_drives_right else s < 0
        leftwards = s < 0 if self.positive_setpoint_drives_right else s > 0
        if (rightwards and self._limit_right) or (leftwards and self._limit_left):
            return 0
        return s

    def dac_value(self) -> int:
        """12-bit DAC value written: dac_zero + output setpoint (Appendix A)."""
        return min(max(self.dac_zero + self.output_setpoint(), 0), self.dac_max)

    def flags(self) -> int:
        return ((jp.FLAG_ENABLED if self.enabled else 0)
                | (jp.FLAG_WATCHDOG if self.watchdog_tripped else 0)
                | (jp.FLAG_LIMIT_LEFT if self._limit_left else 0)
                | (jp.FLAG_LIMIT_RIGHT if self._limit_right else 0))

    def sample_line(self, now_us: int, cart_ticks: int, pend_ticks: int) -> bytes | None:
        """The ``S`` line of this sample if streaming (seq counts every sample period), with
        the latency report while a tagged command is in force."""
        seq = self.seq
        self.seq = (self.seq + 1) % jp.UINT32
        if not self.streaming:
            return None
        now_us %= jp.UINT32
        back = age = None
        if self.applied_tag is not None:
            back = (seq - self.applied_tag) % jp.UINT32
            age = (now_us - self.applied_us) % jp.UINT32
        return jp.encode(jp.Sample(seq, now_us, cart_ticks, pend_ticks, self.flags(), back, age))
