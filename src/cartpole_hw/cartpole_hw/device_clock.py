"""Device time on the host's clock: the stamp of each sample from the device's ``t_us``.

The device samples every 5 ms on its own crystal and sends ``t_us``, its
``micros()`` (uint32, wraps every 71.6 min); the line reaches the host after
a latency that is never below some minimum and often milliseconds above it.
With device time ``tau`` and receipt ``r``: ``r = c + (1 + e) tau + d``,
``d >= d_min``. :class:`DeviceClock` estimates the host time of the sample,
``c + (1 + e) tau``, as NTP and PTP filter their offsets: the least-delayed
observation per ``block`` (a lower envelope spikes never move), the drift
``e`` as the Theil-Sen slope of those minima over ``window``, and the offset
applied to the stamps slewed by at most ``max_slew`` a sample (stepped beyond
``step_limit``), so the EKF sees the device's even 5 ms steps, not the host's
jitter. A ``t_us`` going back means a restarted device: the mapping starts
again. Figures and reasoning: docs/rig.md ("Conversions, device-time stamps
and the safety rules"). No ROS.
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

UINT32 = 2 ** 32


@dataclass(frozen=True)
class DeviceClockConfig:
    """Tuning of :class:`DeviceClock` (module docstring)."""

    block: float = 0.5
    """Device seconds per block; the least-delayed observation of each is kept."""
    window: float = 20.0
    """Device seconds of blocks the drift and offset are estimated from."""
    max_slew: float = 2e-5
    """Largest change of the applied offset per sample [s]."""
    step_limit: float = 0.05
    """An offset error beyond this is stepped, not slewed [s]."""
    max_drift: float = 1e-3
    """Drift estimates are clamped to +/- this (1000 ppm: no crystal is worse)."""

    def __post_init__(self) -> None:
        for name in ('block', 'window', 'max_slew', 'step_limit', 'max_drift'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f'{name} must be > 0, got {value!r}')
        if self.window < 2.0 * self.block:
            raise ValueError(f'window {self.window:g} s must hold at least two blocks of '
                             f'{self.block:g} s')


class DeviceClock:
    """Maps the device's ``t_us`` to host time (module docstring)."""

    def __init__(self, config: DeviceClockConfig | None = None) -> None:
        self.config = config or DeviceClockConfig()
        self.resets = 0
        """Restarts of the mapping after the first (a device restart, a host clock jump)."""
        self.steps = 0
        """Offset steps (the first sample's included)."""
        self.reset()
        self.resets = 0

    def reset(self) -> None:
        """Forget the mapping: the next sample starts it again."""
        self.resets += 1
        self._last_raw: int | None = None
        self._device_us = 0
        """Unwrapped device time since the first sample [us] (an int: exact)."""
        self._blocks: deque[tuple[float, float]] = deque()
        """(tau, y) of the least-delayed observation of each finished block."""
        self._block_start = 0.0
        self._block_min: tuple[float, float] | None = None
        self.drift = 0.0
        """Estimated relative drift e of the device clock against the host's."""
        self._offset_applied: float | None = None
        self._tau_last = 0.0
        self.offset_error = 0.0
        """Estimate minus applied offset at the last sample [s] (what is still being slewed)."""
        self.latency = math.nan
        """Receipt minus stamp of the last sample [s]: its latency above the smallest seen."""

    def device_time(self, t_us: int) -> float | None:
        """Unwrapped device seconds since the mapping started; None (and a reset) if ``t_us``
        went backwards."""
        t_us = int(t_us) % UINT32
        if self._last_raw is not None:
            delta = (t_us - self._last_raw) % UINT32
            if delta >= UINT32 // 2:
                return None
            self._device_us += delta
        self._last_raw = t_us
        return self._device_us * 1e-6

    def stamp(self, t_us: int, receipt: float) -> float:
        """The host time [s] at which the device took the sample stamped ``t_us``, received at
        ``receipt`` (host seconds)."""
        tau = self.device_time(t_us)
        if tau is None:
            self.reset()
            tau = self.device_time(t_us)
        y = receipt - tau
        self._observe(tau, y)
        target = self._estimate(tau)
        if self._offset_applied is None:
            applied = target
            self.steps += 1
        else:
            predicted = self._offset_applied + self.drift * (tau - self._tau_last)
            error = target - predicted
            if abs(error) > self.config.step_limit:
                # A host clock jump or a device restart: start the mapping again here.
                self.reset()
                return self.stamp(t_us, receipt)
            else:
                slew = self.config.max_slew
                applied = predicted + max(-slew, min(slew, error))
        self._offset_applied, self._tau_last = applied, tau
        self.offset_error = target - applied
        stamp = tau + applied
        self.latency = receipt - stamp
        return stamp

    def stamp_of(self, t_us: int) -> float | None:
        """The host time [s] of another device time ``t_us`` near the last sample's (before
        or after it, within 2**31 us), on the mapping the last sample was stamped with
        (its applied offset carried along the drift): how a time the device reports
        besides its samples' (when a command took effect) is put on the host clock, exactly
        as the samples' are. None before the first sample. Changes nothing."""
        if self._last_raw is None or self._offset_applied is None:
            return None
        delta = (int(t_us) - self._last_raw) % UINT32
        if delta >= UINT32 // 2:
            delta -= UINT32
        d = delta * 1e-6
        return self._tau_last + d + self._offset_applied + self.drift * d

    # -- the estimate -------------------------------------------------------------------------
    def _observe(self, tau: float, y: float) -> None:
        cfg = self.config
        if self._block_min is None:
            self._block_start, self._block_min = tau, (tau, y)
            return
        if tau - self._block_start >= cfg.block:
            self._blocks.append(self._block_min)
            while self._blocks and tau - self._blocks[0][0] > cfg.window:
                self._blocks.popleft()
            self._block_start, self._block_min = tau, (tau, y)
            self.drift = self._slope()
        elif y < self._block_min[1]:
            self._block_min = (tau, y)

    def _slope(self) -> float:
        """Theil-Sen slope of the finished blocks' minima (0 with fewer than three)."""
        points = list(self._blocks)
        if len(points) < 3:
            return 0.0
        slopes = sorted((y2 - y1) / (t2 - t1) for i, (t1, y1) in enumerate(points)
                        for t2, y2 in points[i + 1:] if t2 > t1)
        middle = len(slopes) // 2
        slope = slopes[middle] if len(slopes) % 2 else 0.5 * (slopes[middle - 1] + slopes[middle])
        bound = self.config.max_drift
        return max(-bound, min(bound, slope))

    def _estimate(self, tau: float) -> float:
        """The lower envelope at ``tau``: the lowest observation kept, carried along the drift."""
        e = self.drift
        lowest = min((y + e * (tau - t) for t, y in self._blocks), default=math.inf)
        t, y = self._block_min
        return min(lowest, y + e * (tau - t))
