"""Pole-placement stabiliser: full state feedback with the closed-loop poles chosen by hand.

The law is the state feedback of the thesis's section 8.2 with the gain
chosen by pole placement instead of LQR:

    u = -K (x - x*),   x = [x, theta_w, x_dot, theta_dot]        (8.15) with K by placement

where K places the eigenvalues of ``A - B K`` at the parameter ``poles``, with
(A, B) the linearisation about the upright rest (8.13)/(8.14) of the
manager's plant model (``cartpole_core.model.linearise_upright``) and
``scipy.signal.place_poles`` (Kautz, Nichols, Van Dooren). No integral action:
a Coulomb friction left over by the feedforward (6.12) leaves a small cart
offset from x*.

This module is what a lab writes to add its own law: a
``cartpole_control.controller.Controller`` subclass with ``kind``, ``name``
(the entry-point name in setup.py), ``parameters`` (declared as the ROS
parameters ``pole_placement.<name>``), ``on_configure`` (derived quantities,
ValueError refuses a gain), ``on_activate`` (bumpless start; nothing to reset
here) and ``update``. No rclpy.
"""
from __future__ import annotations

import numpy as np
from scipy.signal import place_poles

from cartpole_control.controller import STABILIZER, Controller, ControllerState, ParameterSpec
from cartpole_core.model import linearise_upright


class PolePlacementStabilizer(Controller):
    """u = -K (x - x*) with the poles of A - B K placed at ``poles`` (8.13)-(8.15)."""

    kind = STABILIZER
    name = 'pole_placement'
    parameters = (
        ParameterSpec('poles', (-2.0, -3.0, -12.0, -16.0),
                      'closed-loop poles of the linearisation (8.13)/(8.14) [1/s]: four '
                      'distinct negative reals', low=-200.0, high=-0.01, length=4),
    )

    def __init__(self) -> None:
        super().__init__()
        self.gain = np.zeros(4)
        """K of u = -K (x - x*), [N/m, N/rad, N s/m, N s/rad]."""

    def on_configure(self) -> None:
        """Place the poles on the controller's plant model; refuse repeated poles."""
        poles = np.array(self.gains['poles'])
        if len(set(poles)) != len(poles):
            raise ValueError(f'pole_placement: poles must be distinct (a single input places '
                             f'each pole once), got {list(poles)}')
        a, b = linearise_upright(self.context.plant)
        self.gain = place_poles(a, b, poles).gain_matrix[0]

    def on_activate(self, state: ControllerState) -> None:
        """Nothing to reset: the law has no internal state, so it starts without a bump."""

    def update(self, state: ControllerState) -> float:
        """u = -K [x - x*, theta_w, x_dot, theta_dot] [N]."""
        k = self.gain
        return -float(k[0] * (state.x - self.context.x_ref) + k[1] * state.theta_w
                      + k[2] * state.x_dot + k[3] * state.theta_dot)
