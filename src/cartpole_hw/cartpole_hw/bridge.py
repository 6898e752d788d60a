"""The host side of the Joint protocol as a pure state machine (no ROS, no serial).

:class:`BridgeCore` turns received lines, force commands and the passage of
time into lines to send and samples to publish. The serial link
(:mod:`cartpole_hw.serial_link`) and the ROS node (:mod:`cartpole_hw.hw_node`)
only move bytes and messages; every safety rule lives here and is tested
without a port: disarmed by default (``E,0``, only ``U,0``), arming only with
a live link, homed encoders and (for the lifecycle's activate) a warm control
loop, the host watchdog, the refusal of implausible sequence jumps, zero force
and disarm on every fault, the limit switches' directional inhibit, homing
only on request. Each sample is stamped with the device's time of sampling
(:class:`~cartpole_hw.device_clock.DeviceClock`), and with protocol version 2
the device's report of the command in force becomes an :class:`AppliedCommand`.
The rules one by one, and why: docs/rig.md ("Conversions, device-time stamps
and the safety rules", "The latency report"). Time ``now`` is
``time.monotonic()`` seconds.
"""
from __future__ import annotations

import math
from collections import deque

from cartpole_core.realtime import CycleGapMeter

from . import protocol as jp
from .bridge_records import AppliedCommand, BridgeConfig, BridgeCounts, JointSample, Output
from .counters import CounterUnwrapper, SequenceTracker
from .device_clock import DeviceClock

__all__ = ['AppliedCommand', 'BridgeConfig', 'BridgeCore', 'BridgeCounts', 'JointSample',
           'Output', 'U_ZERO', 'E_ON', 'E_OFF', 'PING', 'RESET', 'STREAM_ON', 'STREAM_OFF']


U_ZERO = jp.encode(jp.Setpoint(0))
E_ON = jp.encode(jp.Enable(True))
E_OFF = jp.encode(jp.Enable(False))
PING = jp.encode(jp.Ping())
RESET = jp.encode(jp.ResetCounters())
STREAM_ON = jp.encode(jp.Stream(True))
STREAM_OFF = jp.encode(jp.Stream(False))


class BridgeCore:
    """Host-side protocol state machine: disconnected, connected, armed, fault (see the
    module docstring); the codec is :mod:`cartpole_hw.protocol`."""

    def __init__(self, config: BridgeConfig | None = None) -> None:
        self.config = config or BridgeConfig()
        self.connected = False
        self.link_ready = False
        self.device_name = ''
        self.armed = False
        self.homed = False
        self.homing = False
        self.commands_live = False
        self.last_command = -math.inf
        self.last_sample = -math.inf
        self.ping_sent = -math.inf
        self.home_sent = -math.inf
        self.armed_at = -math.inf
        self.flags = 0
        self.tracker = SequenceTracker()
        self.device_clock = DeviceClock()
        self._unwrap_cart = CounterUnwrapper(self.config.calibration.counter_bits)
        self._unwrap_pend = CounterUnwrapper(self.config.calibration.counter_bits)
        self._since_resync = 0
        self._last_sequence_receipt: float | None = None
        self._jump_candidate: int | None = None
        self._jump_run = 0
        self.gaps = CycleGapMeter()
        """Longest gap between two valid samples' receipts (a stall figure)."""
        self.warm_run = 0
        """Consecutive fresh commands received while disarmed (see warm_commands)."""
        self._last_warm_command = -math.inf
        self.counts = BridgeCounts()
        self.last_error = ''
        self.latencies: deque[float] = deque(maxlen=self.config.latency_window)
        self.last_setpoint = 0
        self.device_version: int | None = None
        """Protocol version of the device's last ``V`` answer (None before one)."""
        self._applied_seq: int | None = None
        self.actuation_latency = math.nan
        """The latest reported sample-to-command-in-force latency [s] (device time)."""

    @property
    def tags_commands(self) -> bool:
        """The device takes tagged setpoints and reports them (protocol version 2)."""
        return self.device_version is not None and \
            self.device_version >= jp.LATENCY_REPORT_VERSION

    # -- link ----------------------------------------------------------------------------------
    def on_connect(self, now: float) -> list[bytes]:
        """The port is open: make the device safe, ask who it is, start streaming."""
        self.connected = True
        self.counts.connects += 1
        self.link_ready = False
        self.armed = False
        self.commands_live = False
        self.homing = False
        self.ping_sent = now
        self.last_sample = now
        self._applied_seq = None
        return [U_ZERO, E_OFF, PING, STREAM_ON]

    def on_disconnect(self, now: float, reason: str, orderly: bool = False) -> None:
        """The port failed or vanished: disarm (nothing can be sent any more); ``orderly``:
        closed on purpose after :meth:`shutdown` (no fault)."""
        if self.connected and not orderly:
            self._fault(f'link lost: {reason}')
        elif orderly:
            self.disarm()
        self.connected = False
        self.link_ready = False
        self.homing = False

    # -- requests ----------------------------------------------------------------------------
    def arm(self, now: float) -> tuple[bool, str, list[bytes]]:
        """Arm: enable the amplifier (``E,1``) and start forwarding commands."""
        reason = self.arm_refusal()
        if reason:
            return False, reason, []
        if self.armed:
            return True, 'already armed', []
        self.armed = True
        self.commands_live = False
        self.warm_run = 0
        self.armed_at = now
        self._since_resync = 0
        return True, 'armed', [E_ON, U_ZERO]

    def activate(self, now: float) -> tuple[bool, str, list[bytes]]:
        """Arm if the control loop is warm (see the module docstring): the node's
        lifecycle activate; refused with the reason otherwise."""
        if not self.armed and not self.arm_refusal() and not self.loop_warm(now):
            return False, (f'the control loop does not answer the samples in time: '
                           f'{self.warm_run} of {self.config.warm_commands} fresh force '
                           f'commands in a row, the latest '
                           f'{self._warm_age(now)}; start the controller first'), []
        return self.arm(now)

    def _warm_age(self, now: float) -> str:
        age = now - self._last_warm_command
        return 'never' if not math.isfinite(age) else f'{1e3 * age:.0f} ms ago'

    def arm_refusal(self) -> str:
        """Why arming is refused now ('' if it is allowed)."""
        if not self.connected:
            return 'not connected to the device'
        if not self.link_ready:
            return 'the device has not answered the ping (V line) yet'
        if self.homing:
            return 'homing in progress'
        if not self.homed:
            return 'encoders not homed: call ~/home (cart at the left stop, pendulum hanging still)'
        return ''

    def disarm(self) -> list[bytes]:
        """Zero force and disable: ``U,0``, ``E,0`` (also when already disarmed)."""
        self.armed = False
        self.commands_live = False
        self.last_setpoint = 0
        return [U_ZERO, E_OFF] if self.connected else []

    def home(self, now: float) -> tuple[bool, str, list[bytes]]:
        """Reset both counters (``R``), then ``P``; only while disarmed."""
        if self.armed:
            return False, 'refused while armed: disarm first', []
        if not self.connected:
            return False, 'not connected to the device', []
        self.homing = True
        self.home_sent = now
        return True, 'homing: R sent', [RESET, PING]

    def shutdown(self) -> list[bytes]:
        """Last words: zero force, disable, stop streaming."""
        out = self.disarm()
        return out + ([STREAM_OFF] if self.connected else [])

    def _fault(self, reason: str) -> list[bytes]:
        self.counts.faults += 1
        self.last_error = reason
        if self.armed:
            return self.disarm()
        return []

    # -- force commands ------------------------------------------------------------------------
    def on_command(self, force: float, now: float, latency: float | None = None,
                   tag: int | None = None) -> list[bytes]:
        """A force command [N] from the controller; ``latency`` = now - its stamp [s];
        ``tag`` = the ``seq`` of the sample it answers, if it is one of this bridge's (sent
        with the setpoint to a device that reports, :attr:`tags_commands`)."""
        if not self.armed:
            self.counts.ignored_commands += 1
            fresh = math.isfinite(force) and (latency is None
                                              or latency <= 0.5 * self.config.command_timeout)
            self.warm_run = self.warm_run + 1 if fresh else 0
            self._last_warm_command = now
            return []
        if not math.isfinite(force):
            self.counts.bad_commands += 1
            return []
        if latency is not None and latency > self.config.command_timeout:
            self.counts.stale_commands += 1
            return []
        if (force > 0 and self.flags & jp.FLAG_LIMIT_RIGHT) or \
                (force < 0 and self.flags & jp.FLAG_LIMIT_LEFT):
            self.counts.limit_inhibits += 1
            force = 0.0
        setpoint = self.config.calibration.force_to_setpoint(force)
        self.commands_live = True
        self.last_command = now
        self.last_setpoint = setpoint
        if latency is not None and latency >= 0:
            self.latencies.append(latency)
        if tag is not None and self.tags_commands:
            return [jp.encode(jp.Setpoint(setpoint, tag % jp.UINT32))]
        return [jp.encode(jp.Setpoint(setpoint))]

    # -- time ------------------------------------------------------------------------------------
    def on_tick(self, now: float) -> list[bytes]:
        """Watchdogs and retries; call at least every few ms."""
        out: list[bytes] = []
        if not self.connected:
            return out
        cfg = self.config
        if self.armed and self.commands_live and \
                now + cfg.tick_period - self.last_command > cfg.command_timeout:
            self.counts.watchdog_trips += 1
            out += self._fault(f'host watchdog: no fresh force command for '
                               f'{1e3 * (now - self.last_command):.0f} ms')
        if self.armed and now - self.last_sample > self.config.sample_timeout:
            out += self._fault(f'no valid sample for {1e3 * (now - self.last_sample):.0f} ms')
        if (not self.link_ready or self.homing) and now - self.ping_sent > self.config.answer_timeout \
                and now - self.home_sent > self.config.answer_timeout:
            if self.homing:
                self.homing = False
                self.last_error = 'homing failed: no V answer after R'
            self.ping_sent = now
            out += [PING, STREAM_ON]
        return out

    def loop_warm(self, now: float) -> bool:
        """The control loop answers in time: ``warm_commands`` fresh commands in a row,
        the latest within ``command_timeout`` (see the module docstring)."""
        cfg = self.config
        return self.warm_run >= cfg.warm_commands and \
            (cfg.warm_commands == 0 or now - self._last_warm_command <= cfg.command_timeout)

    # -- received lines ------------------------------------------------------------------------------
    def on_line(self, line: bytes | jp.DecodeError, now: float) -> Output:
        """One line from the splitter (or its oversize error)."""
        message = line if isinstance(line, jp.DecodeError) else jp.decode_line(line, direction='device')
        if isinstance(message, jp.DecodeError):
            self.counts.bad_lines[message.reason] += 1
            return Output()
        if isinstance(message, jp.Sample):
            return self._on_sample(message, now)
        if isinstance(message, jp.Version):
            return Output(self._on_version(message, now))
        return Output(self._on_device_error(message))

    def _on_version(self, message: jp.Version, now: float) -> list[bytes]:
        self.device_name = message.name
        if not 1 <= message.version <= jp.PROTOCOL_VERSION:
            self.link_ready = False
            self.device_version = None
            self.last_error = (f'device speaks protocol version {message.version}, '
                               f'this bridge 1 to {jp.PROTOCOL_VERSION}')
            return self._fault(self.last_error)
        self.device_version = message.version
        self.link_ready = True
        if self.homing:
            self.homing = False
            self.homed = True
            self.counts.homes += 1
            self.gaps.last = None      # the samples discarded while homing are no stall
            self._unwrap_cart.reset()
            self._unwrap_pend.reset()
        return []

    def _on_device_error(self, message: jp.DeviceError) -> list[bytes]:
        self.counts.device_errors[message.code] += 1
        if message.code == jp.ERROR_CODES['watchdog']:
            self.counts.device_watchdog_trips += 1
        if message.is_fault and self.armed:
            return self._fault(f'device fault {message.code}: {message.text}')
        return []

    def _implausible_sequence(self, seq: int, now: float) -> bool:
        """Refuse a forward jump the device cannot have made (see the module docstring)."""
        last = self.tracker.last
        if last is None or self._last_sequence_receipt is None:
            return False
        delta = (seq - last) % jp.UINT32
        if delta <= 1 or delta >= jp.UINT32 // 2:
            return False  # next, duplicate or backwards: the tracker's business
        cfg = self.config
        possible = 1 + (now - self._last_sequence_receipt + cfg.sequence_slack) / cfg.sample_time
        if delta <= possible:
            return False
        follows = self._jump_candidate is not None and seq == (self._jump_candidate + 1) % jp.UINT32
        self._jump_run = self._jump_run + 1 if follows else 1
        self._jump_candidate = seq
        if self._jump_run >= 3:  # the device really continues from there
            self._jump_run, self._jump_candidate = 0, None
            self.counts.sequence_resyncs += 1
            self.tracker.resync(seq)
            return False
        self.counts.bad_samples += 1
        return True

    def _on_sample(self, s: jp.Sample, now: float) -> Output:
        out: list[bytes] = []
        if self._implausible_sequence(s.seq, now):
            return Output()
        self._jump_run, self._jump_candidate = 0, None
        self._last_sequence_receipt = now
        jump = self.tracker.update(s.seq)
        if jump < 0:
            # sequence went back: the device restarted, its counters are zero again
            self.homed = False
            self._unwrap_cart.reset()
            self._unwrap_pend.reset()
            self.device_clock.reset()   # its micros() started again too
            out += self._fault('sample sequence jumped back (device restarted?): re-home')
        elif jump > 0:
            self.counts.seq_gaps += 1
        if self.homing:
            return Output(out)  # counts before the reset took effect
        self.counts.samples += 1
        self.last_sample = now
        self.gaps.tick(now)
        previous, self.flags = self.flags, s.flags
        cal = self.config.calibration
        x = cal.cart_position(self._unwrap_cart.update(s.cart_ticks))
        theta = cal.pendulum_angle(self._unwrap_pend.update(s.pend_ticks))
        if self.armed:
            if s.watchdog_tripped:
                out += self._fault('device watchdog tripped (U lines not arriving)')
            rising = s.flags & ~previous
            if rising & jp.FLAG_LIMIT_LEFT:
                out += self._fault('left limit switch closed while armed')
            elif rising & jp.FLAG_LIMIT_RIGHT:
                out += self._fault('right limit switch closed while armed')
        self._since_resync += 1
        if self.armed:
            if not self.commands_live:
                out.append(U_ZERO)
            if not s.enabled and self._since_resync >= 10:
                self._since_resync = 0
                out.append(E_ON)        # E,1 was lost
        elif s.enabled and self.connected and self._since_resync >= 10:
            self._since_resync = 0
            out += [U_ZERO, E_OFF]      # E,0 was lost
        stamp = self.device_clock.stamp(s.t_us, now)
        return Output(out, JointSample(now, stamp, s.seq, s.t_us, x, theta, s.flags,
                                       max(jump, 0), self._applied(s)))

    def _applied(self, s: jp.Sample) -> AppliedCommand | None:
        """The command in force the sample reports, if it is a new one (call after the
        sample was stamped: its applied time is mapped like the sample's)."""
        seq = s.applied_seq
        if seq is None or seq == self._applied_seq:
            self._applied_seq = seq
            return None
        self._applied_seq = seq
        stamp = self.device_clock.stamp_of(s.applied_t_us)
        if stamp is None:
            return None
        latency = (s.back * self.config.sample_time * 1e6 - s.age_us) * 1e-6
        self.counts.actuation_reports += 1
        self.actuation_latency = latency
        return AppliedCommand(seq, stamp, latency)

    # -- health ---------------------------------------------------------------------------------------
    def latency_stats(self) -> tuple[float, float]:
        """(p50, max) of the recent receipt-to-command-send latencies [s] (nan if none)."""
        if not self.latencies:
            return math.nan, math.nan
        ordered = sorted(self.latencies)
        return ordered[len(ordered) // 2], ordered[-1]

    def health(self) -> dict[str, str]:
        """Health figures as strings (the KeyValues of ``/cartpole/hw/health``)."""
        p50, worst = self.latency_stats()
        counts = self.counts
        values = {
            'connected': str(self.connected).lower(),
            'link_ready': str(self.link_ready).lower(),
            'device': self.device_name,
            'armed': str(self.armed).lower(),
            'homed': str(self.homed).lower(),
            'homing': str(self.homing).lower(),
            'warm_commands': str(self.warm_run),
            'samples': str(counts.samples),
            'lost_samples': str(self.tracker.lost),
            'seq_gaps': str(counts.seq_gaps),
            'sample_latency_s': repr(self.device_clock.latency),
            'device_clock_drift_ppm': repr(self.device_clock.drift * 1e6),
            'device_clock_slew_s': repr(self.device_clock.offset_error),
            'device_clock_resets': str(self.device_clock.resets),
            'bad_lines': str(sum(counts.bad_lines.values())),
        }
        for reason in jp.DECODE_REASONS:
            values[f'bad_lines.{reason}'] = str(counts.bad_lines[reason])
        values.update({
            'watchdog_trips': str(counts.watchdog_trips),
            'device_watchdog': str(bool(self.flags & jp.FLAG_WATCHDOG)).lower(),
            'device_watchdog_trips': str(counts.device_watchdog_trips),
            'device_errors': str(sum(counts.device_errors.values())),
            'device_enabled': str(bool(self.flags & jp.FLAG_ENABLED)).lower(),
            'limit_left': str(bool(self.flags & jp.FLAG_LIMIT_LEFT)).lower(),
            'limit_right': str(bool(self.flags & jp.FLAG_LIMIT_RIGHT)).lower(),
            'latency_p50': repr(p50),
            'latency_max': repr(worst),
            'actuation_latency_s': repr(self.actuation_latency),
            'actuation_reports': str(counts.actuation_reports),
            'setpoint': str(self.last_setpoint),
            'ignored_commands': str(counts.ignored_commands),
            'bad_commands': str(counts.bad_commands),
            'bad_samples': str(counts.bad_samples),
            'sequence_resyncs': str(counts.sequence_resyncs),
            'longest_cycle_gap_s': repr(self.gaps.longest),
            'stale_commands': str(counts.stale_commands),
            'limit_inhibits': str(counts.limit_inhibits),
            'faults': str(counts.faults),
            'reconnects': str(counts.reconnects),
            'last_error': self.last_error,
        })
        return values
