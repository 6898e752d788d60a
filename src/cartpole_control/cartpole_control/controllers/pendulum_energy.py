"""Pendulum energy swing-up with integral action and cart P-term, (7.32).

The pendulum energy (7.3) ``E_p = 1/2 J theta_dot^2 + m_p g l (cos theta + 1)``
changes under a cart acceleration ``u`` as ``dE_p/dt = m_p l u theta_dot cos theta``
(7.4), so the law

    u = (k_e (E* - E_p) + k_i int_0^t (E* - E_p) dt) theta_dot cos theta + k_c (x* - x)   (7.32)

pumps energy in while ``E_p < E*`` and takes it out above, with E* = 2 m_p g l
(6.8). The integral removes the steady-state error of (7.5) (section 7.3.2),
the P-term (7.31) keeps the cart near x*. ``u`` is a cart acceleration
[m/s^2]; it becomes a force through (7.10).

The integral is clamped to ``+-i_max`` (anti-windup, not in the thesis): the
energy error changes sign only after E* is reached, so an unbounded integral
keeps pumping and overshoots (the thesis saw "several full revolutions").
"""
from __future__ import annotations

import math

from cartpole_sim.model import pendulum_energy

from ..controller import SWINGUP, Controller, ControllerState, ParameterSpec
from . import StepClock, acceleration_to_force


class PendulumEnergySwingUp(Controller):
    """Swing-up law (7.32): energy pumping with integral action and cart P-term."""

    kind = SWINGUP
    name = 'pendulum_energy'
    running_state = ('integral', '_clock')
    parameters = (
        ParameterSpec('k_e', 0.5, 'energy gain k_e of (7.32) [m/s^2 per (J rad/s)]; thesis 0.5',
                      low=0.0, high=100.0),
        ParameterSpec('k_i', 0.02, 'integral gain k_i on the energy error of (7.32) '
                      '[m/s^2 per (J s rad/s)]; thesis 0.02', low=0.0, high=10.0),
        ParameterSpec('k_c', 1.0, 'cart position gain k_c of (7.31)/(7.32) [1/s^2]; thesis 1',
                      low=0.0, high=100.0),
        ParameterSpec('i_max', 10.0, 'anti-windup: bound of the energy-error integral '
                      'int (E* - E_p) dt [J s] (not in the thesis)', low=0.0, high=1000.0),
    )

    def __init__(self) -> None:
        super().__init__()
        self.integral = 0.0
        """int_0^t (E* - E_p) dt [J s] since activation."""
        self._clock = StepClock()

    def activate(self, state: ControllerState) -> None:
        """Start a new swing-up: the energy integral starts from zero now."""
        super().activate(state)
        self.integral = 0.0
        self._clock.reset(state.t)

    def energy_error(self, state: ControllerState) -> float:
        """E* - E_p, (6.8) and (7.3) [J]."""
        p = self.context.plant
        return p.upright_energy - pendulum_energy(state.theta, state.theta_dot, p)

    def acceleration(self, state: ControllerState) -> float:
        """The law's cart acceleration u [m/s^2], (7.32); updates the integral."""
        g = self.gains
        error = self.energy_error(state)
        dt = self._clock.step(state.t, self.context.sample_time)
        i_max = g['i_max']
        self.integral = max(-i_max, min(i_max, self.integral + error * dt))
        pump = (g['k_e'] * error + g['k_i'] * self.integral) * state.theta_dot * math.cos(state.theta)
        return pump + g['k_c'] * (self.context.x_ref - state.x)

    def update(self, state: ControllerState) -> float:
        return acceleration_to_force(self.acceleration(state), state, self.context.plant)
