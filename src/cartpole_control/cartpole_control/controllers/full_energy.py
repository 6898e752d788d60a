"""Full energy swing-up with integral action, (7.27), and its singularity guard (7.28)-(7.30).

With the energy of the whole system (7.11)
``E = 1/2 q_dot^T M(theta) q_dot + m_p g l (cos theta + 1)``, whose rate is
``dE/dt = x_dot u`` (7.13) for a force ``u`` on the cart (cart friction
compensated by the feedforward (6.12)), the function (7.14)
``V_2 = k_e/2 (E* - E)^2 + k_v/2 x_dot^2 + k_x/2 (x* - x)^2`` decreases as
``-k_d x_dot^2`` (7.21) under (7.20). Section 7.3.1 adds integral action:

    u = (-k_d x_dot + k_x (x* - x) - k_v beta(theta, theta_dot))
        / (-k_e (E* - E) + k_v alpha(theta))
        + theta_dot cos theta k_i int_0^t (E* - E) dt                 (7.27)

Design notes: docs/controllers.md ("Design notes by module", ``cartpole_control.controllers.full_energy``).
"""
from __future__ import annotations

import math

import numpy as np

from cartpole_core.model import pendulum_energy, system_energy

from ..controller import ControllerState, ParameterSpec
from . import ADAPTIVE_TARGET, energy_and_target
from .energy_integral import EnergyIntegralSwingUp, i_max_parameter


class FullEnergySwingUp(EnergyIntegralSwingUp):
    """Swing-up law (7.27): Lyapunov redesign on the full energy, with integral action."""

    name = 'full_energy'
    parameters = (
        ParameterSpec('k_x', 12.0, 'cart position weight k_x of (7.14)/(7.27) [N^2] '
                      '(k_e dimensionless, V_2 in J^2); thesis 12', low=0.0, high=1000.0),
        ParameterSpec('k_d', 1.0, 'cart velocity damping k_d of (7.19)/(7.21) [N^2 s]; thesis 1',
                      low=0.0, high=1000.0),
        ParameterSpec('k_v', 8.3, 'velocity weight k_v of (7.14)/(7.27) [N^2 s^2 = J kg]; must satisfy '
                      'k_v/k_e > E*(m_c+m_p) (7.28)-(7.30); thesis 8.3',
                      low=1e-6, high=1000.0),
        ParameterSpec('k_e', 1.0, 'energy weight k_e of (7.14)/(7.27) [1]; thesis 1',
                      low=0.0, high=1000.0),
        ParameterSpec('k_i', 0.2, 'integral gain k_i on the energy error of (7.27) '
                      '[N/J]; thesis 0.012 (needs > 30 s to swing up on this '
                      'model, tuned 0.2)', low=0.0, high=10.0),
        i_max_parameter(20.0, 'E'),
        ParameterSpec('d_min', 0.0, 'floor of the denominator of (7.27) [J]; 0 is the '
                      'thesis law (not in the thesis)', low=0.0, high=10.0),
        ADAPTIVE_TARGET,
    )

    def __init__(self) -> None:
        super().__init__()
        self.denominator_min = 0.0
        """Smallest possible denominator of (7.27) over all states, k_v/(m_c+m_p) - k_e E*."""

    def on_configure(self) -> None:
        """Check the singularity guard (7.28)-(7.30) for the gains and the plant model."""
        g, p = self.gains, self.context.plant
        bound = p.upright_energy * (p.m_c + p.m_p)
        if g['k_e'] > 0.0 and not g['k_v'] / g['k_e'] > bound:
            raise ValueError(
                f'full_energy: k_v/k_e = {g["k_v"] / g["k_e"]:.4g} must exceed '
                f'E*(m_c + m_p) = {bound:.4g} J kg (7.28)-(7.30), or the denominator of (7.27) '
                f'changes sign and drives the cart into an end stop; raise k_v or lower k_e')
        self.denominator_min = g['k_v'] / (p.m_c + p.m_p) - g['k_e'] * p.upright_energy

    def energy_error(self, state: ControllerState) -> float:
        """E* - E with E the full system energy (7.11) [J].

        With ``adaptive_target`` the pendulum's part of (7.11), (7.3), and E* are
        those of the estimated pendulum (the cart's kinetic energy and the
        coupling term stay nominal).
        """
        p = self.context.plant
        e = system_energy(np.array([state.x, state.theta, state.x_dot, state.theta_dot]), p)
        if not self.gains['adaptive_target'] or self.context.pendulum is None:
            return p.upright_energy - e
        energy, target = energy_and_target(state.theta, state.theta_dot, self.context, True)
        return target - (e - pendulum_energy(state.theta, state.theta_dot, p) + energy)

    def update(self, state: ControllerState) -> float:
        g, p = self.gains, self.context.plant
        error = self.energy_error(state)
        integral = self.integrate(state, error)
        s, c = math.sin(state.theta), math.cos(state.theta)
        d = p.m_c + p.m_p * s * s
        alpha = 1.0 / d                                                       # (7.17)
        beta = p.m_p * s * (-p.l * state.theta_dot ** 2 + p.g * c) / d          # (7.18)
        numerator = (-g['k_d'] * state.x_dot + g['k_x'] * (self.context.x_ref - state.x)
                     - g['k_v'] * beta)
        denominator = max(-g['k_e'] * error + g['k_v'] * alpha, g['d_min'], 1e-9)
        # The integral term pumps only while E < E* (gate, not in the thesis).
        pump = state.theta_dot * c * g['k_i'] * integral if error > 0.0 else 0.0
        return numerator / denominator + pump
