"""Pendulum energy swing-up with integral action and cart P-term, (7.32).

The pendulum energy (7.3) ``E_p = 1/2 J theta_dot^2 + m_p g l (cos theta + 1)``
changes under a cart acceleration ``u`` as ``dE_p/dt = m_p l u theta_dot cos theta``
(7.4), so the law

    u = (k_e (E* - E_p) + k_i int_0^t (E* - E_p) dt) theta_dot cos theta + k_c (x* - x)   (7.32)

pumps energy in while ``E_p < E*`` and takes it out above, with E* = 2 m_p g l
(6.8). The integral removes the steady-state error of (7.5) (section 7.3.2),
the P-term (7.31) keeps the cart near x*. ``u`` is a cart acceleration
[m/s^2]; it becomes a force through (7.10). Beyond the thesis, ``- k_v x_dot``
damps the P-term's spring once the energy is near E*: without it a cart that
drifted off x* while the pendulum circles at E* stays there (friction holds it
against k_c (x* - x)), and the catch, rightly, never comes. The integral
integrates only while the energy is within ``i_band`` of E* (conditional
integration): wound up over a long swing-up it kept pumping past E*.

Design notes: docs/controllers.md ("Design notes by module", ``cartpole_control.controllers.pendulum_energy``).
"""
from __future__ import annotations

import math

from ..controller import ControllerState, ParameterSpec
from . import ADAPTIVE_TARGET, acceleration_to_force, energy_and_target
from .energy_integral import EnergyIntegralSwingUp, i_max_parameter


DAMPING_BAND = 0.1
"""The damping ``k_v`` acts while the energy is within this fraction of E*: the pendulum
swings at its target and the cart has nothing left to pump."""


class PendulumEnergySwingUp(EnergyIntegralSwingUp):
    """Swing-up law (7.32): energy pumping with integral action and a damped cart P-term."""

    name = 'pendulum_energy'
    parameters = (
        ParameterSpec('k_e', 1.5, 'energy gain k_e of (7.32) [m/s^2 per (J rad/s)]; thesis 0.5',
                      low=0.0, high=100.0),
        ParameterSpec('k_i', 1.0, 'integral gain k_i on the energy error of (7.32) '
                      '[m/s^2 per (J s rad/s)]; thesis 0.02 (with i_band 1000)',
                      low=0.0, high=10.0),
        ParameterSpec('i_band', 0.1, 'the integral of (7.32) integrates while |E* - E_p| is '
                      'within this fraction of E* [1] (conditional integration, not in the thesis; '
                      '1000: at every energy, the thesis law)', low=0.0, high=1000.0),
        ParameterSpec('k_c', 1.0, 'cart position gain k_c of (7.31)/(7.32) [1/s^2]; thesis 1',
                      low=0.0, high=100.0),
        ParameterSpec('k_v', 1.0, 'cart velocity gain k_v, the damping of the P-term while the '
                      'energy is within 10 % of E* (not in the thesis; 0: the thesis law (7.32)) '
                      '[1/s]', low=0.0, high=100.0),
        i_max_parameter(10.0, 'E_p'),
        ParameterSpec('a_max', 4.0, 'bound of the pumping term of (7.32), the cart '
                      'acceleration [m/s^2] (Astrom-Furuta saturation, not in the thesis; 100: '
                      'unbounded, the thesis law)', low=0.0, high=100.0),
        ADAPTIVE_TARGET,
    )

    def energy_error(self, state: ControllerState) -> float:
        """E* - E_p, (6.8) and (7.3) [J] (of the estimated pendulum with ``adaptive_target``)."""
        energy, target = self._energy_and_target(state)
        return target - energy

    def _energy_and_target(self, state: ControllerState) -> tuple[float, float]:
        """(E_p, E*) of (7.3) and (6.8) [J]."""
        return energy_and_target(state.theta, state.theta_dot, self.context,
                                 self.gains['adaptive_target'])

    def acceleration(self, state: ControllerState) -> float:
        """The law's cart acceleration u [m/s^2], (7.32); updates the integral."""
        g = self.gains
        energy, target = self._energy_and_target(state)
        error = target - energy
        integral = self.integrate(state, error, abs(error) <= g['i_band'] * target)
        pump = (g['k_e'] * error + g['k_i'] * integral) * state.theta_dot * math.cos(state.theta)
        pump = max(-g['a_max'], min(g['a_max'], pump))
        u = pump + g['k_c'] * (self.context.x_ref - state.x)
        if abs(error) <= DAMPING_BAND * target:  # at E*: nothing to pump, centre the cart
            u -= g['k_v'] * state.x_dot
        return u

    def update(self, state: ControllerState) -> float:
        return acceleration_to_force(self.acceleration(state), state, self.context.plant)
