"""Sign-based swing-up, (7.33)-(7.36), with a saturation instead of the bare sign.

The largest constant effort in the direction that reduces |E* - E_p| (7.33),
plus the cart P-term of (7.36):

    u = u_max sat((E* - E_p) theta_dot cos theta / w) + k_c (x* - x)

with ``sat`` the unit saturation and ``w`` the width of its linear zone: the
thesis suggests replacing sgn by a saturation against chattering (section
7.3.3); ``w -> 0`` is the sign function of (7.36). Along the law
``dV_3/dt = -(E* - E_p) m_p l u theta_dot cos theta <= 0`` (7.35) for the
pumping part, as for the sign.

``u`` is a cart acceleration [m/s^2] and becomes a force through (7.10):
the thesis's ``u_max = 1`` means 1 m/s^2, about 5 N on the 5 kg cart (plus
the feedforward), its "switches between +-10" of Figure 7.13 including the
friction compensation (docs/controllers.md, "sign_based"). As a force, 1 N would not move the cart.
"""
from __future__ import annotations

import math

from ..controller import SWINGUP, Controller, ControllerState, ParameterSpec
from . import ADAPTIVE_TARGET, acceleration_to_force, energy_and_target, saturation


class SignBasedSwingUp(Controller):
    """Swing-up law (7.36): saturated sign of the energy-pumping direction plus cart P-term."""

    kind = SWINGUP
    name = 'sign_based'
    parameters = (
        ParameterSpec('u_max', 1.0, 'pumping acceleration u_max of (7.33)/(7.36) [m/s^2]; '
                      'thesis 1', low=0.0, high=20.0),
        ParameterSpec('k_c', 1.0, 'cart position gain k_c of (7.36) [1/s^2]; thesis 1 '
                      '(printed as k_x)', low=0.0, high=100.0),
        ParameterSpec('width', 0.05, 'width w of the saturation replacing sgn in (7.36) '
                      '[J rad/s]; small is close to the sign (not in the thesis)',
                      low=1e-6, high=100.0),
        ADAPTIVE_TARGET,
    )

    def acceleration(self, state: ControllerState) -> float:
        """The law's cart acceleration u [m/s^2], (7.36)."""
        g = self.gains
        energy, target = energy_and_target(state.theta, state.theta_dot, self.context,
                                           g['adaptive_target'])
        error = target - energy
        direction = error * state.theta_dot * math.cos(state.theta)
        return (g['u_max'] * saturation(direction / g['width'])
                + g['k_c'] * (self.context.x_ref - state.x))

    def update(self, state: ControllerState) -> float:
        return acceleration_to_force(self.acceleration(state), state, self.context.plant)
