"""The encoders' last 2T + 1 samples, evenly spaced: the window both on-line estimates weigh.

:mod:`cartpole_control.natural_frequency` and :mod:`cartpole_control.actuator`
each read one row of (4.17) from positions alone, integrated against the
triangle ``k(s) = T - |s|`` over ``[t - T, t + T]``. This holds the samples
of such a window and says when the next window is due: every ``every``
samples once ``2 half_window + 1`` evenly spaced ones are held. Up to
:data:`MAX_FILLED` lost samples in a row are filled in on the straight line between
their neighbours (a link that loses one sample in twenty would otherwise almost never
hold 41 in a row); a longer gap (a pause) or :meth:`PositionWindow.clear` (a plant
reset) starts afresh. No ROS import.
"""
from __future__ import annotations

MAX_GAP_FACTOR = 1.5
"""Samples at most this many sample periods apart are neighbours; the sums assume evenly
spaced samples."""
MAX_FILLED = 2
"""Lost samples in a row that are filled in by linear interpolation. The error of one
filled in is a h^2 / 8 (0.13 mm at 10 m/s^2 and h = 10 ms); it cancels in the window's
sums of differences except at the window's centre (about 4e-4 N s^2 of the actuator's
momentum balance, a tenth of its noise)."""


class PositionWindow:
    """``t``, ``x``, ``theta`` of the last ``2 half_window + 1`` evenly spaced samples.

    Parameters
    ----------
    sample_time
        Ts [s] of the samples.
    half_window
        T of the window, in samples.
    every
        A window is due every this many samples (the windows overlap).
    """

    def __init__(self, sample_time: float, half_window: int, every: int) -> None:
        if half_window < 2 or every < 1:
            raise ValueError('half_window >= 2 and every >= 1 needed')
        self.sample_time = float(sample_time)
        self.half_window = int(half_window)
        self.every = int(every)
        self.t: list[float] = []
        self.x: list[float] = []
        self.theta: list[float] = []
        self._since = 0

    def clear(self) -> None:
        """Forget the samples held (the next window starts with the next sample)."""
        self.t.clear()
        self.x.clear()
        self.theta.clear()
        self._since = 0

    def push(self, t: float, x: float, theta: float) -> bool:
        """Take one sample; True when a full window is held and one is due now (or fell due
        at a sample filled in before it)."""
        times = self.t
        due = False
        if times:
            gap = t - times[-1]
            ts = self.sample_time
            if not 0.0 < gap <= MAX_GAP_FACTOR * ts:
                missing = int(round(gap / ts)) - 1
                if 1 <= missing <= MAX_FILLED and abs(gap - (missing + 1) * ts) \
                        <= (MAX_GAP_FACTOR - 1.0) * ts:
                    t0, x0, th0 = times[-1], self.x[-1], self.theta[-1]
                    for i in range(1, missing + 1):
                        f = i / (missing + 1)
                        due |= self._append(t0 + f * gap, x0 + f * (x - x0),
                                            th0 + f * (theta - th0))
                else:
                    self.clear()
        return self._append(t, x, theta) or due

    def _append(self, t: float, x: float, theta: float) -> bool:
        times = self.t
        times.append(t)
        self.x.append(x)
        self.theta.append(theta)
        if len(times) > 2 * self.half_window + 1:
            del times[0], self.x[0], self.theta[0]
        self._since += 1
        if len(times) < 2 * self.half_window + 1 or self._since < self.every:
            return False
        self._since = 0
        return True

    @property
    def step(self) -> float:
        """The spacing h of the samples held [s] (their span over 2 half_window)."""
        return (self.t[-1] - self.t[0]) / (2 * self.half_window)
