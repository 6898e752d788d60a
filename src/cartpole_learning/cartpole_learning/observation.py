"""What a learned policy sees: the features of the estimate a plugin receives on the rig.

The observation is built from the :class:`~cartpole_control.controller.ControllerState`
the controller manager hands every plugin (the EKF estimate predicted over the
loop's latency, with the model accelerations under the last applied force),
never from the true state, so the environment and the ``policy`` plugin build
it with this one function:

    o = [x - x*, sin theta, cos theta, x_dot, theta_dot, x_ddot, stabilizing]

sin/cos make the angle continuous through the bottom and over the top (an
unwrapped angle after a revolution is the same pendulum); ``x_ddot``, the
model's cart acceleration under the force the manager applied last, tells the
policy what it asked for one cycle ago (with the delay and the amplifier lag,
the pendulum still feels it), which a stateless network otherwise cannot know
at a hand-over between the swing-up and the stabiliser instance; ``stabilizing``
is 1 in the stabiliser role and 0 in the swing-up role (the manager's mode,
which the catch trigger and the fall detector set with a hysteresis the state
alone does not show: between 30 and 45 deg the pendulum may be either).
"""
from __future__ import annotations

import math

import numpy as np

OBSERVATION_NAMES = ('x_error', 'sin_theta', 'cos_theta', 'x_dot', 'theta_dot', 'x_ddot',
                     'stabilizing')
"""The order of the observation vector (stored in the policy file and checked on load)."""
OBSERVATION_SIZE = len(OBSERVATION_NAMES)
OBSERVATION_BOUND = np.array([2.0, 1.0, 1.0, 20.0, 200.0, 2000.0, 1.0], dtype=np.float32)
"""Each feature is clipped to +-this (the gymnasium observation space); far outside what
the rig reaches (the travel is 0.77 m, the amplifier gives 37 N on 4.75 kg)."""


def observation(x_error: float, theta: float, x_dot: float, theta_dot: float,
                x_ddot: float, stabilizing: bool, out: np.ndarray | None = None) -> np.ndarray:
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
    np.clip(out, -OBSERVATION_BOUND, OBSERVATION_BOUND, out=out)
    return out
