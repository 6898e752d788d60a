"""The host side of the Joint protocol as a pure state machine (no ROS, no serial).

:class:`BridgeCore` turns received lines, force commands and the passage of
time into lines to send and samples to publish. The serial link
(:mod:`cartpole_hw.serial_link`) and the ROS node (:mod:`cartpole_hw.hw_node`)
only move bytes and messages; every safety rule lives here and is tested
without a port. Time ``now`` is ``time.monotonic()`` seconds.

Safety rules (docs/rig.md, "The lifecycle"; any fault commands zero force):

- Disarmed (the default): the device is kept disabled (``E,0``, re-sent if a
  sample shows it enabled) and no ``U`` other than ``U,0`` is ever sent.
- Arming needs a live link (``V`` with protocol version 1 or 2 seen) and homed
  encoders (``R`` done by this bridge, see :meth:`BridgeCore.home`); it sends
  ``E,1`` and ``U,0``. Until the first force command arrives the bridge feeds
  the device ``U,0`` every sample (zero force, device watchdog quiet).
- The node's arming (:meth:`BridgeCore.activate`, the lifecycle's activate)
  needs, besides, a warm loop: ``warm_commands`` consecutive commands
  received while disarmed, each fresh within half the ``command_timeout``, the
  latest within ``command_timeout``. A loop still starting up (a backlog of
  samples being worked off, commands older than the watchdog), or no
  controller at all, would otherwise be armed and at once disarmed by the
  watchdogs. :meth:`BridgeCore.arm` itself arms at once (tests, tools).
- Host watchdog: once commands flow, no fresh command for ``command_timeout``
  -> ``U,0``, ``E,0``, disarmed (a *trip*). Non-finite or stale commands
  (stamp older than ``command_timeout``) are not fresh. The watchdogs run at
  every :meth:`BridgeCore.on_tick` (at least every ``tick_period``, the
  link's read timeout), and the host watchdog trips at the tick that would
  otherwise be the last one before the deadline: ``U,0`` goes out at most
  ``command_timeout`` after the last command arrived, not up to a
  tick later.
- A checksummed sample whose sequence number jumps further ahead than the
  device can have counted since the last accepted sample (one per
  ``sample_time``, plus ``sequence_slack``) is refused as a bad sample
  (``bad_samples``): a corrupted line that kept a valid checksum, not a
  million lost samples. Should the device really have jumped, three
  consecutive samples that follow the new number are taken as the new
  sequence (``sequence_resyncs``).
- Faults that disarm (``U,0`` + ``E,0``): no valid sample for
  ``sample_timeout``, the device's watchdog flag, a limit switch closing
  while armed, a device ``!`` line with a fault code (>= 16), a serial
  error/disconnect, a device restart (sequence jumping back), shutdown.
  Re-arming is always an explicit request (nothing arms by itself).
- Limit switches: force towards a closed switch is never sent (directional
  inhibit), so the cart homed at the left stop (left switch closed) can be
  driven right; a switch *closing* while armed is a crash: fault.
- Homing: ``R`` then ``P``; samples are discarded until the ``V`` answer
  (the device handles lines in order, so every sample after ``V`` counts
  from the new zero), then the counter unwrapping restarts. Allowed only
  while disarmed. Never done automatically on a reconnect: a device that
  kept power kept its counts (the position reference survives, the bridge
  keeps unwrapping), while an automatic reset would silently move x = 0 to
  wherever the cart happens to be. A device that restarted (sequence jumps
  back) has lost its reference: ``homed`` drops and arming is refused until
  an explicit home.

Latency report (protocol version 2): a force command that answers one of
the bridge's samples goes out tagged with that sample's ``seq``
(``U,<setpoint>,<seq>``), and the device says in its sample lines which
command is in force and when, in device time, it took effect. When that
command changes, the sample passed on carries :class:`AppliedCommand`: the
``seq`` it answers and the host time it took effect, its device time mapped
by the same :class:`~cartpole_hw.device_clock.DeviceClock` mapping as the
sample's own stamp (so ``applied - stamp of that sample`` is the loop's
latency as the device's clock measured it, not the host's receipt times).
A version-1 device gets untagged setpoints (it would refuse a tag) and
reports nothing; it works as before. A version above 2 is refused.

Stamps: each sample carries the host time at which the device took it,
from its ``t_us`` through :class:`~cartpole_hw.device_clock.DeviceClock`
(offset and drift from the least-delayed samples; USB latency spikes do not
move it), not the time the line happened to arrive. A ``seq`` gap (samples
lost on the way) is counted (``seq_gaps``, ``lost_samples``); the next
sample's stamp is as many periods later, which is how the EKF sees it.
"""
from __future__ import annotations

import math
from collections import Counter, deque
from dataclasses import dataclass, field

from cartpole_core.realtime import CycleGapMeter

from . import protocol as jp
from .device_clock import DeviceClock


@dataclass(frozen=True)
class BridgeConfig:
    """Tunables of the host side."""

    calibration: jp.Calibration = field(default_factory=jp.Calibration)
    command_timeout: float = 0.05
    """Host watchdog: longest gap between fresh force commands while armed [s]."""
    sample_timeout: float = 0.05
    """Longest gap between valid samples while armed [s] (10 samples)."""
    answer_timeout: float = 0.5
    """Time to wait for the ``V`` answer to a ``P`` before asking again [s]."""
    latency_window: int = 400
    """Number of latest command latencies kept for p50/max (2 s at 200 Hz)."""
    tick_period: float = 0.002
    """Longest gap between two :meth:`BridgeCore.on_tick` calls [s] (the link's read
    timeout); the host watchdog trips one tick early rather than one tick late."""
    sample_time: float = 0.005
    """The device's sample period Ts [s] (one sequence number per period)."""
    sequence_slack: float = 0.1
    """Sequence jumps beyond elapsed time / sample_time + this / sample_time are refused [s]."""
    warm_commands: int = 20
    """Consecutive fresh commands (within command_timeout / 2) an arming requested ahead
    waits for: the control loop answers the samples in time (100 ms at 200 Hz)."""

    def __post_init__(self) -> None:
        for name in ('command_timeout', 'sample_timeout', 'answer_timeout', 'tick_period',
                     'sample_time', 'sequence_slack'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f'{name} must be a finite number > 0, got {value!r}')
        if not (isinstance(self.warm_commands, int) and self.warm_commands >= 0):
            raise ValueError(f'warm_commands must be an integer >= 0, got {self.warm_commands!r}')


@dataclass(frozen=True)
class AppliedCommand:
    """The device's report that the command answering sample ``seq`` took effect."""

    seq: int
    """``seq`` of the sample the command was computed from (its tag)."""
    stamp: float
    """Host time [s] (the core's clock) at which it took effect: its device time mapped
    like a sample's ``t_us``."""
    latency: float
    """Sample to command in force [s], in device time (``back`` periods minus ``age_us``)."""


@dataclass(frozen=True)
class JointSample:
    """One decoded sample, ready to publish on ``/joint_states``."""

    receipt: float
    """Host time the line was read [s] (the clock given to the core)."""
    stamp: float
    """Host time [s] (same clock) at which the device took the sample: its ``t_us``
    mapped by the :class:`~cartpole_hw.device_clock.DeviceClock`."""
    seq: int
    t_us: int
    x: float
    """Cart position [m], unwrapped counts times resolution (2.4)."""
    theta: float
    """Pendulum angle [rad], pi hanging after reset (2.3)."""
    flags: int
    missed: int = 0
    """Samples lost just before this one (the ``seq`` gap)."""
    applied: AppliedCommand | None = None
    """A newly reported command in force (protocol version 2), else None."""


@dataclass
class BridgeCounts:
    """The bridge's event counts (they only grow): the counters of the health report,
    :meth:`BridgeCore.health` (docs/rig.md, ``/cartpole/hw/health``)."""

    samples: int = 0
    """Valid samples passed on (samples discarded while homing are not)."""
    seq_gaps: int = 0
    """Gaps in the sequence numbers (each one or more lost samples)."""
    bad_lines: Counter[str] = field(default_factory=Counter)
    """Refused lines by reason (:data:`cartpole_hw.protocol.DECODE_REASONS`)."""
    watchdog_trips: int = 0
    """Host watchdog trips: no fresh force command for ``command_timeout`` while armed."""
    device_watchdog_trips: int = 0
    """The device's ``!,16`` notices (its watchdog zeroed the current)."""
    device_errors: Counter[int] = field(default_factory=Counter)
    """The device's ``!`` lines by error code."""
    ignored_commands: int = 0
    """Force commands received while disarmed (none is forwarded)."""
    bad_commands: int = 0
    """Non-finite or malformed force commands."""
    bad_samples: int = 0
    """Checksummed samples refused for a sequence jump the device cannot have made."""
    sequence_resyncs: int = 0
    """Times the sequence was taken up anew after three consecutive such samples."""
    stale_commands: int = 0
    """Force commands stamped more than ``command_timeout`` ago."""
    limit_inhibits: int = 0
    """Force commands zeroed for pushing towards a closed limit switch."""
    faults: int = 0
    """Disarming faults (the latest one's reason is :attr:`BridgeCore.last_error`)."""
    connects: int = 0
    """Times the port was opened (see :attr:`reconnects`)."""
    homes: int = 0
    """Completed homings (each moves the position reference: x = 0 now)."""
    actuation_reports: int = 0
    """Commands the device reported in force (protocol version 2), each counted once."""

    @property
    def reconnects(self) -> int:
        """Re-opened ports (``connects`` after the first)."""
        return max(0, self.connects - 1)


@dataclass
class Output:
    """What one event asks the link to do."""

    write: list[bytes] = field(default_factory=list)
    sample: JointSample | None = None


U_ZERO = jp.encode(jp.Setpoint(0))
E_ON = jp.encode(jp.Enable(True))
E_OFF = jp.encode(jp.Enable(False))
PING = jp.encode(jp.Ping())
RESET = jp.encode(jp.ResetCounters())
STREAM_ON = jp.encode(jp.Stream(True))
STREAM_OFF = jp.encode(jp.Stream(False))


class BridgeCore:
    """Host-side protocol state machine (see the module docstring).

    Why one class of about 350 lines: the host's protocol state machine
    (disconnected, connected, armed, fault) whose transitions (connect, arm, command,
    sample, device error, watchdog tick) all read and change the same state; the
    codec is :mod:`cartpole_hw.protocol`, the device clock :mod:`cartpole_hw.device_clock`.
    """

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
        self.tracker = jp.SequenceTracker()
        self.device_clock = DeviceClock()
        self._unwrap_cart = jp.CounterUnwrapper(self.config.calibration.counter_bits)
        self._unwrap_pend = jp.CounterUnwrapper(self.config.calibration.counter_bits)
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
