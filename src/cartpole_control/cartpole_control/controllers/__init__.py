"""The controller plugins of the thesis, one module a law.

Swing-up laws (chapter 7), entry-point group ``cartpole_control.swingup``:

- :mod:`.pendulum_energy` -- pendulum energy method with integral action and
  cart P-term (7.32);
- :mod:`.full_energy` -- full energy method with integral action (7.27) and
  the singularity guard (7.28)-(7.30);
- :mod:`.sign_based` -- sign-based method (7.36), sign replaced by a saturation.

Stabilisers (chapter 8), entry-point group ``cartpole_control.stabilizer``:

- :mod:`.pid` -- cascade PID (8.1)-(8.10), Table 8.1;
- :mod:`.lqg` -- LQR on the linearisation (8.13)/(8.14), (8.15)-(8.24); the
  "G" of LQG is the EKF upstream;
- :mod:`.smc` -- sliding-mode control (8.26)-(8.42).

This package module holds only the few helpers the laws share. No rclpy.
"""
from __future__ import annotations

import math

from cartpole_sim.model import CartPoleParameters, force_for_acceleration

from ..controller import ControllerState

__all__ = ['acceleration_to_force', 'saturation', 'StepClock']


def acceleration_to_force(u: float, state: ControllerState, params: CartPoleParameters) -> float:
    """Force [N] for a desired cart acceleration ``u`` [m/s^2], (7.10) (section 7.1.1).

    As in the thesis, ``theta``, ``theta_dot`` and ``theta_ddot`` come from the
    estimate; ``theta_ddot`` is the model's angular acceleration under the
    last applied force (:attr:`ControllerState.theta_ddot`).
    """
    return force_for_acceleration(u, state.theta, state.theta_dot, state.theta_ddot, params)


def saturation(value: float) -> float:
    """sat(v) = v clipped to [-1, 1], the continuous replacement of sgn(v)."""
    return max(-1.0, min(1.0, value))


class StepClock:
    """Time since the previous update, for the discrete integrators.

    The step is the difference of the states' stamps; the first update after
    :meth:`reset`, a stamp that does not increase, or a gap longer than
    ``max_gap`` uses the nominal sample time instead (a gap is not integrated).
    """

    def __init__(self, max_gap: float = 0.1) -> None:
        self.max_gap = max_gap
        self._last: float | None = None

    def reset(self, t: float | None = None) -> None:
        self._last = t

    def step(self, t: float, sample_time: float) -> float:
        last, self._last = self._last, t
        if last is None or not math.isfinite(t):
            return sample_time
        dt = t - last
        if not (0.0 < dt <= self.max_gap):
            return sample_time if dt > self.max_gap else 0.0
        return dt
