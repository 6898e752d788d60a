"""The measurement noise the rig has: R matched to the encoders' scatter near an equilibrium.

The thesis's R (9.1) stands for its encoders' quantisation. With R too small for a noisier
encoder the filter reads the noise as motion, and the encoder offset b, hardly observable
in the first 0.3 s, takes up tens of mrad. The scatter is measured without the model from
the second differences d2_k = y_k - 2 y_k-1 + y_k-2: for white noise neighbours correlate
as E[d2_k d2_k-1] = -4 sigma^2, while a smooth motion adds h^4 a^2 >= 0, so
-d2_k d2_k-1 / 4 estimates sigma^2 and motion (a busy balancing loop) can only lower it:
never a larger R that slows the estimate and feeds the motion. Taken near an equilibrium
(the offset gate's tests), over the samples so far and then as an exponential mean of time
constant ``window``. R is that variance (on the filter's scale) less the configured R,
never below the configured R (the floor) nor above ``limit`` times it: the scatter moves R
once it is twice what R stands for, so the simulator's nominal noise (0.75 of it) and the
estimate's own scatter (12 %) leave the thesis's R. docs/estimation.md.

No ROS import.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass

__all__ = ['MeasurementNoise']


@dataclass
class MeasurementNoise:
    """R of the cart and the pendulum encoder, matched to their scatter.

    ``r`` is the configured R (on the filter's scale), ``scale`` the filter's scale
    [1/rad^2]: R_theta over the real variance it stands for (the measurements are real, R
    is on the scale); ``window`` the time constant [s] of the mean (0: R fixed, the
    thesis's); ``limit`` the largest factor over ``r``; ``sample_time`` the nominal Ts [s]
    (a second difference across a lost sample is not taken).
    """

    r: tuple[float, float]
    scale: float
    window: float
    limit: float
    sample_time: float

    def __post_init__(self) -> None:
        self.variance = [r / self.scale for r in self.r]  # real, m^2 and rad^2
        self.used = tuple(self.r)
        self.samples = 0
        self._history: deque[tuple[float, float, float]] = deque(maxlen=3)  # (t, y_x, y_theta)
        self._d2: tuple[float, float] | None = None  # the previous sample's second differences

    @property
    def factors(self) -> tuple[float, float]:
        """R in use over the configured R, cart and pendulum (1.0: the configured R)."""
        return self.used[0] / self.r[0], self.used[1] / self.r[1]

    def update(self, t: float, y_x: float, y_theta: float,
               near_equilibrium: bool) -> tuple[float, float]:
        """One accepted sample at ``t`` [s] [m, rad]; returns R to use.

        Counted only ``near_equilibrium``, and with the three samples before it Ts apart."""
        if self.window <= 0.0:
            return self.used
        history = self._history
        if history and abs(t - history[-1][0] - self.sample_time) > 0.25 * self.sample_time:
            history.clear()
            self._d2 = None
        history.append((t, y_x, y_theta))  # the last three, Ts apart
        d2 = None
        if len(history) == 3:
            (_, x2, th2), (_, x1, th1), _ = history
            d2 = (y_x - 2.0 * x1 + x2, y_theta - 2.0 * th1 + th2)
        previous, self._d2 = self._d2, d2
        if not near_equilibrium or d2 is None or previous is None:
            return self.used
        self.samples += 1
        alpha = max(min(1.0, self.sample_time / self.window), 1.0 / self.samples)
        used = []
        for i in (0, 1):
            # E[d2_k d2_k-1] = -4 sigma^2 for white noise; + h^4 a^2 for a smooth motion.
            self.variance[i] += alpha * (-0.25 * d2[i] * previous[i] - self.variance[i])
            r = self.variance[i] * self.scale - self.r[i]  # the floor's dead band
            used.append(min(max(r, self.r[i]), self.limit * self.r[i]))
        self.used = (used[0], used[1])
        return self.used
