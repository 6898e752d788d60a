"""Saturated energy swing-up (Åström and Furuta) with cart centring and a rail brake.

The pendulum energy E_p (7.3) obeys dE_p/dt = m_p l u theta_dot cos theta
(7.4) for a cart acceleration u. Åström and Furuta's law (the thesis's [15],
the bang-bang limit of (7.5)/(7.33)) pumps with the largest acceleration the
rig can give, saturated at n g:

    a_E = sat_{n g}( k g (E* - E_p) / E* sgn(theta_dot cos theta) )

(sgn replaced by a saturation of width ``sign_width`` against chattering, as
section 7.3.3 suggests), plus a cart-centring PD term.

Design notes: docs/controllers.md ("Design notes by module", ``cartpole_control.controllers.energy_saturated``).
"""
from __future__ import annotations

import math
from typing import Any, Mapping

from cartpole_core.model import CartPoleParameters, pendulum_energy

from ..controller import SWINGUP, Controller, ControllerState, ParameterSpec
from . import ADAPTIVE_TARGET, energy_and_target, saturation

DEFAULT_GAINS: dict[str, float] = {
    'k': 10.0,
    'n': 0.7,
    'k_x': 2.0,
    'k_v': 3.0,
    'a_max': 7.0,
    'sign_width': 0.3,
    'kick_energy': 0.02,
    'rail_margin': 0.06,
    'brake_acceleration': 5.0,
    'dead_time': 0.01,
}
"""Tuned defaults (see the README, "Fast swing-up near the physical limit", for the tuning runs)."""


def exact_force_for_acceleration(a: float, theta: float, theta_dot: float,
                                 params: CartPoleParameters) -> float:
    """Force [N] giving the cart acceleration ``a`` on the frictionless model.

    (7.10), F = (m_c + m_p) a - m_p l cos(theta) theta_ddot + m_p l sin(theta) theta_dot^2,
    with theta_ddot = (a cos theta + g sin theta) / l from the pendulum row (7.2).
    """
    s, c = math.sin(theta), math.cos(theta)
    return ((params.m_c + params.m_p * s * s) * a - params.m_p * params.g * s * c
            + params.m_p * params.l * s * theta_dot * theta_dot)


def saturated_energy_acceleration(x: float, theta: float, x_dot: float, theta_dot: float,
                                  params: CartPoleParameters, x_ref: float,
                                  gains: Mapping[str, Any] | None = None,
                                  energy: tuple[float, float] | None = None) -> float:
    """The law's cart acceleration a [m/s^2] (module docstring; pumping term after [15], (7.4)).

    Parameters
    ----------
    x, theta, x_dot, theta_dot
        The state (4.34).
    params
        The model of the plant (E*, masses, travel).
    x_ref
        Cart reference x* [m].
    gains
        Any subset of :data:`DEFAULT_GAINS`; the rest take their defaults.
    energy
        (E_p, E*) to pump with; default (7.3)/(6.8) of ``params``.
    """
    g = dict(DEFAULT_GAINS)
    if gains:
        g.update(gains)
    if energy is None:
        e_p, e_star = pendulum_energy(theta, theta_dot, params), params.upright_energy
    else:
        e_p, e_star = energy
    pump = theta_dot * math.cos(theta)
    direction = saturation(pump / g['sign_width'])
    if abs(pump) < g['sign_width'] and e_p < g['kick_energy'] * e_star:
        direction = 1.0 if x_ref >= x else -1.0
    limit = g['n'] * params.g
    a_e = max(-limit, min(limit, g['k'] * params.g * (e_star - e_p) / e_star * direction))
    a = a_e + g['k_x'] * (x_ref - x) - g['k_v'] * x_dot
    a = max(-g['a_max'], min(g['a_max'], a))
    # Rail brake: stop before the margin, whatever the pumping wants.
    if x_dot != 0.0:
        sign = 1.0 if x_dot > 0.0 else -1.0
        stop = x + x_dot * g['dead_time'] + sign * x_dot * x_dot / (2.0 * g['brake_acceleration'])
        low, high = g['rail_margin'], params.travel - g['rail_margin']
        if (sign > 0.0 and stop > high) or (sign < 0.0 and stop < low):
            a = -sign * max(g['brake_acceleration'], abs(a) if a * sign < 0.0 else 0.0)
    return a


class EnergySaturatedSwingUp(Controller):
    """Åström–Furuta saturated energy swing-up with cart centring and a rail brake.

    The law is in the module docstring.
    """

    kind = SWINGUP
    name = 'energy_saturated'
    parameters = (
        ParameterSpec('k', DEFAULT_GAINS['k'], 'energy gain k: a_E = sat_{n g}(k g (E* - E_p)/E* '
                      'sgn(theta_dot cos theta)) [-]', low=0.0, high=1000.0),
        ParameterSpec('n', DEFAULT_GAINS['n'], 'saturation of the pumping acceleration, in g [-]',
                      low=0.0, high=2.0),
        ParameterSpec('k_x', DEFAULT_GAINS['k_x'], 'cart centring position gain k_x [1/s^2]',
                      low=0.0, high=100.0),
        ParameterSpec('k_v', DEFAULT_GAINS['k_v'], 'cart centring velocity gain k_v [1/s]',
                      low=0.0, high=100.0),
        ParameterSpec('a_max', DEFAULT_GAINS['a_max'], 'limit of the total cart acceleration '
                      '[m/s^2]', low=0.1, high=30.0),
        ParameterSpec('sign_width', DEFAULT_GAINS['sign_width'], 'linear zone of the saturation '
                      'replacing sgn(theta_dot cos theta) [rad/s]', low=1e-6, high=10.0),
        ParameterSpec('kick_energy', DEFAULT_GAINS['kick_energy'], 'below this fraction of E*, '
                      'a pendulum at rest is kicked towards x* [-]', low=0.0, high=1.0),
        ParameterSpec('rail_margin', DEFAULT_GAINS['rail_margin'], 'rail brake: distance kept '
                      'from each end stop [m]', low=0.0, high=0.3),
        ParameterSpec('brake_acceleration', DEFAULT_GAINS['brake_acceleration'], 'rail brake: '
                      'deceleration assumed and commanded [m/s^2]', low=0.5, high=20.0),
        ParameterSpec('dead_time', DEFAULT_GAINS['dead_time'], 'rail brake: latency before a '
                      'brake acts [s]', low=0.0, high=0.2),
        ADAPTIVE_TARGET,
    )

    def on_configure(self) -> None:
        p = self.context.plant
        if 2.0 * self.gains['rail_margin'] >= p.travel:
            raise ValueError(f'rail_margin {self.gains["rail_margin"]:g} leaves no travel '
                             f'({p.travel:g} m)')

    def acceleration(self, state: ControllerState) -> float:
        """The law's cart acceleration [m/s^2]."""
        energy = energy_and_target(state.theta, state.theta_dot, self.context,
                                   self.gains['adaptive_target'])
        return saturated_energy_acceleration(state.x, state.theta, state.x_dot, state.theta_dot,
                                             self.context.plant, self.context.x_ref, self.gains,
                                             energy)

    def update(self, state: ControllerState) -> float:
        """Raw force [N]: the acceleration through (7.10)/(7.2)."""
        return exact_force_for_acceleration(self.acceleration(state), state.theta,
                                            state.theta_dot, self.context.plant)
