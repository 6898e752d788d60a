"""What a learned policy sees: the features of the estimate a plugin receives on the rig.

The observation is built from the :class:`~cartpole_control.controller.ControllerState`
the controller manager hands every plugin (the EKF estimate predicted over the loop's
latency, with the model accelerations under the last applied force) and the manager's
estimate of the plant (:attr:`ControlContext.plant_estimate`), never from the true state;
the environment, the trainer and the ``policy`` plugin build it with one :class:`Observer`:

    o = [x - x*, sin theta, cos theta, x_dot, theta_dot, x_ddot, stabilizing,
         omega_0^2 / omega_0,nom^2 - 1, dead time, unmodelled force,
         and in the stabiliser role (0 in the swing-up role):
         x - x*, theta_w, x_dot, theta_dot, int (x - x*) dt]

The plant estimate is what the thesis's laws read (the LQR is solved again at the catch
for the measured omega_0^2 and dead time); the stabiliser role's copies are normalised
over balancing alone, and the integral is the one the LQR with integral action (8.16)
keeps. Why each feature: (docs/learning.md, "The environment").
"""
from __future__ import annotations

import math

import numpy as np

from cartpole_control.controllers import ConditionalIntegrator, StepClock
from cartpole_core.model import wrap_angle

UPRIGHT_NAMES = ('upright_x_error', 'upright_theta', 'upright_x_dot', 'upright_theta_dot',
                 'upright_x_integral')
OBSERVATION_NAMES = ('x_error', 'sin_theta', 'cos_theta', 'x_dot', 'theta_dot', 'x_ddot',
                     'stabilizing', 'omega_sq_error', 'dead_time', 'disturbance') + UPRIGHT_NAMES
"""The order of the observation vector (stored in the policy file and checked on load)."""
OBSERVATION_SIZE = len(OBSERVATION_NAMES)
OBSERVATION_BOUND = np.array([2.0, 1.0, 1.0, 20.0, 200.0, 2000.0, 1.0, 1.0, 0.2, 50.0,
                              2.0, 3.2, 20.0, 200.0, 20.0], dtype=np.float32)
"""Each feature is clipped to +-this (the gymnasium observation space); far outside what
the rig reaches (the travel is 0.77 m, the amplifier gives 37 N on 4.75 kg)."""
VARIANCE_FLOOR = np.array([1e-4, 1e-4, 1e-4, 1e-4, 1e-4, 1e-4, 0.25, 0.05 ** 2, 0.005 ** 2,
                           1.0, 1e-6, 1e-6, 1e-6, 1e-6, 1e-6], dtype=np.float64)
"""The least variance a policy's normalisation assumes per feature: the role flag stays a
unit step, and a feature a range table hardly varies (a fixed delay) is not blown up."""


def observation(x_error: float, theta: float, x_dot: float, theta_dot: float,
                x_ddot: float, stabilizing: bool, out: np.ndarray | None = None,
                omega_sq_error: float = 0.0, dead_time: float = 0.0,
                disturbance: float = 0.0, x_integral: float = 0.0) -> np.ndarray:
    """The observation vector (float32) of the module docstring, clipped to
    :data:`OBSERVATION_BOUND`; written into ``out`` if given."""
    if out is None:
        out = np.empty(OBSERVATION_SIZE, dtype=np.float32)
    out[0] = x_error
    out[1] = math.sin(theta)
    out[2] = math.cos(theta)
    out[3] = x_dot
    out[4] = theta_dot
    out[5] = x_ddot
    out[6] = 1.0 if stabilizing else 0.0
    out[7] = omega_sq_error
    out[8] = dead_time
    out[9] = disturbance
    if stabilizing:
        out[10] = x_error
        out[11] = wrap_angle(theta)
        out[12] = x_dot
        out[13] = theta_dot
        out[14] = x_integral
    else:
        out[10:] = 0.0
    np.clip(out, -OBSERVATION_BOUND, OBSERVATION_BOUND, out=out)
    return out


class Observer:
    """Builds a plugin's observations (module docstring) and keeps the integral they carry.

    One per plugin instance: :meth:`reset` at its activation (the integral starts from
    zero, as the LQR's), :meth:`observe` every cycle, :meth:`feedback` with the manager's
    :class:`~cartpole_control.controller.CommandFeedback` (the increment is taken back
    while the command is cut in its direction or held, the LQR's conditional integration).
    """

    def __init__(self) -> None:
        self._integral = ConditionalIntegrator()
        self._clock = StepClock()

    def reset(self, t: float | None = None) -> None:
        self._integral.reset()
        self._clock.reset(t)

    def observe(self, state, context, stabilizing: bool,
                out: np.ndarray | None = None) -> np.ndarray:
        """The observation of ``state`` (a ControllerState) in ``context`` (the plugin's
        ControlContext); without a plant estimate (outside a manager) the nominal plant's."""
        x_error = state.x - context.x_ref
        integral = 0.0
        if stabilizing:
            dt = self._clock.step(state.t, context.sample_time)
            integral = self._integral.step(x_error, dt, -1.0)
        estimate = context.plant_estimate
        omega_sq_error = dead_time = disturbance = 0.0
        if estimate is not None:
            natural = estimate.natural_frequency
            omega_sq_error = natural.omega_sq / natural.nominal - 1.0
            dead_time = estimate.dead_time
            disturbance = estimate.disturbance
        return observation(x_error, state.theta, state.x_dot, state.theta_dot, state.x_ddot,
                           stabilizing, out, omega_sq_error, dead_time, disturbance, integral)

    def feedback(self, feedback) -> None:
        self._integral.feedback(feedback)
