"""The scatter of the encoders' samples, measured from their fourth differences.

The on-line estimates that read (4.17) from positions alone
(:mod:`cartpole_control.actuator`) weigh each window's error by what the
encoders' noise puts into it. A rig's noise is not the model's: an encoder
with more ticks, a noisy cable, or the robustness grid's noise levels (up to
30 mrad) put up to six times the error the actuator estimate was tuned for
into its windows, and a too-small error variance reads noise as news (a dead
time of 90 ms where there is none). The fourth difference of evenly spaced
samples removes every cubic in time, so a smooth motion, even a swing-up, leaves
little of it, while white noise of variance sigma^2 gives 70 sigma^2; the rare
large ones (a step of the force) are clipped. No ROS import.
"""
from __future__ import annotations

from collections import deque

WINDOW = 1.0
"""[s] Time constant of the mean of the squared fourth differences."""
CLIP = 9.0
"""A squared fourth difference counts at most this many times the mean so far (a force's
step, a collision): about 3 % low for Gaussian noise."""
FOURTH_DIFFERENCE_GAIN = 70.0
"""Var(x_k - 4 x_k-1 + 6 x_k-2 - 4 x_k-3 + x_k-4) over sigma^2 for white noise."""
WARM_UP = 20
"""Samples averaged with equal weight before the clip applies."""


class EncoderNoise:
    """The variance [m^2, rad^2] of the cart and pendulum encoders' noise (see the module docstring).

    ``sample_time`` is the nominal Ts [s]: samples further apart (a lost one, a pause)
    start the differences afresh.
    """

    def __init__(self, sample_time: float) -> None:
        self.sample_time = float(sample_time)
        self.clear()
        self.samples = 0
        """Fourth differences taken."""
        self._mean = [0.0, 0.0]  # of the squared fourth differences, cart and pendulum

    def clear(self) -> None:
        """Start the differences afresh (a plant reset moved the positions); the estimate stays."""
        self._history: deque[tuple[float, float, float]] = deque(maxlen=5)

    @property
    def variance(self) -> tuple[float, float]:
        """The noise variance of the cart [m^2] and the pendulum [rad^2] encoder (0 until measured)."""
        return (self._mean[0] / FOURTH_DIFFERENCE_GAIN, self._mean[1] / FOURTH_DIFFERENCE_GAIN)

    def update(self, t: float, x: float, theta: float) -> None:
        """One sample at ``t`` [s]: cart position [m], pendulum angle [rad]."""
        history = self._history
        if history and abs(t - history[-1][0] - self.sample_time) > 0.25 * self.sample_time:
            history.clear()
        history.append((t, x, theta))
        if len(history) < 5:
            return
        (_, x0, a0), (_, x1, a1), (_, x2, a2), (_, x3, a3), _ = history
        self.samples += 1
        n = self.samples
        alpha = max(self.sample_time / WINDOW, 1.0 / n)
        mean = self._mean
        for i, d in ((0, x0 - 4.0 * x1 + 6.0 * x2 - 4.0 * x3 + x),
                     (1, a0 - 4.0 * a1 + 6.0 * a2 - 4.0 * a3 + theta)):
            d2 = d * d
            if n > WARM_UP and mean[i] > 0.0:  # (an encoder at rest may read no noise)
                d2 = min(d2, CLIP * mean[i])
            mean[i] += alpha * (d2 - mean[i])
