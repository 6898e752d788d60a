"""What the host side of the Joint protocol is tuned with, counts and hands on.

:class:`BridgeConfig` (timeouts and the calibration), :class:`BridgeCounts`
(the counters of ``/cartpole/hw/health``), :class:`JointSample` and
:class:`AppliedCommand` (a decoded sample and the device's latency report),
:class:`Output` (what one event asks the link to do): the records of
:class:`cartpole_hw.bridge.BridgeCore`, kept apart from its rules. No ROS import.
"""
from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field

from .calibration import Calibration


@dataclass(frozen=True)
class BridgeConfig:
    """Tunables of the host side."""

    calibration: Calibration = field(default_factory=Calibration)
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
