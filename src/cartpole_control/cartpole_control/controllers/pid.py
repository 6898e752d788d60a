"""Cascade PID stabiliser, section 8.1, (8.1)-(8.10), the pendulum loop's K_p, K_i of Table 8.1.

The cart loop's gains are faster than Table 8.1's, and the pendulum loop's K_d is 17.5, not
15: the thesis's leaves the pendulum mode little damping behind the amplifier's dead time.

Design notes: docs/controllers.md ("Design notes by module", ``cartpole_control.controllers.pid``).
"""
from __future__ import annotations

from ..controller import STABILIZER, CommandFeedback, Controller, ControllerState, ParameterSpec
from . import ConditionalIntegrator, StepClock, acceleration_to_force, integral_property


class PidStabilizer(Controller):
    """Cascade PID (8.1): cart position loop outside, pendulum angle loop inside."""

    kind = STABILIZER
    name = 'pid'
    running_state = ('_integral_x', '_integral_theta', 'theta_ref', '_clock')
    parameters = (
        ParameterSpec('cart_gains', (0.4, 0.1, 0.25),
                      '[K_p, K_i, K_d] of the cart position PID C_c (8.8), from x* - x [m] to the '
                      'pendulum reference theta* [rad]: rad/m, rad/(m s), rad s/m; Table 8.1 '
                      '[0.2, 0.03, 0.15] is slow to take up an offset', low=0.0, high=100.0,
                      length=3),
        ParameterSpec('pendulum_gains', (112.0, 15.0, 17.5),
                      '[K_p, K_i, K_d] of the pendulum angle PID C_p (8.8), from theta* - theta '
                      '[rad] to a cart acceleration [m/s^2] (then (7.10)); K_p must exceed g; '
                      'Table 8.1 [112, 15, 15] leaves the pendulum mode underdamped behind the '
                      "amplifier's dead time", low=0.0, high=10000.0, length=3),
        ParameterSpec('theta_max', 0.15, 'limit of the pendulum reference |theta*| [rad] '
                      '(anti-windup of C_c; not in the thesis)', low=0.0, high=0.5),
    )

    def __init__(self) -> None:
        super().__init__()
        self._integral_x = ConditionalIntegrator()
        self._integral_theta = ConditionalIntegrator()
        self.theta_ref = 0.0
        """theta* of the last update [rad]."""
        self._clock = StepClock()

    integral_x = integral_property('_integral_x', 'int (x* - x) dt [m s].')
    integral_theta = integral_property('_integral_theta', 'int (theta* - theta) dt [rad s].')

    def on_configure(self) -> None:
        """Refuse an inner loop that cannot hold the pendulum (K_p,p <= g)."""
        kp = self.gains['pendulum_gains'][0]
        g = self.context.plant.g
        if kp <= g:
            raise ValueError(f'pid: pendulum_gains K_p = {kp:g} must exceed g = {g:g} m/s^2, '
                             'or the inner loop cannot overcome gravity')

    def on_activate(self, state: ControllerState) -> None:
        """Bumpless start: both integrators start from zero at this state."""
        self._integral_x.reset()
        self._integral_theta.reset()
        self.theta_ref = 0.0
        self._clock.reset(state.t)

    def acceleration(self, state: ControllerState) -> float:
        """The cascade's cart acceleration u [m/s^2]; steps the integrators."""
        kpc, kic, kdc = self.gains['cart_gains']
        kpp, kip, kdp = self.gains['pendulum_gains']
        theta_max = self.gains['theta_max']
        p = self.context.plant
        mass = p.m_c + p.m_p  # d(force)/d(u) of (7.10)
        dt = self._clock.step(state.t, self.context.sample_time)

        # Outer loop C_c: theta* = -C_c (x* - x), derivative on -x_dot.
        e_x = self.context.x_ref - state.x
        integral_x = self._integral_x.step(e_x, dt, -mass * kpp * kic)
        theta_ref = -(kpc * e_x + kic * integral_x - kdc * state.x_dot)
        if abs(theta_ref) > theta_max:
            limited = max(-theta_max, min(theta_max, theta_ref))
            # Hold the integrator if integrating pushed theta* further out.
            if (theta_ref - limited) * (-kic * e_x) > 0.0:
                self._integral_x.hold()
            theta_ref = limited
        self.theta_ref = theta_ref

        # Inner loop C_p: u = C_p (theta* - theta), derivative on -theta_dot.
        e_theta = theta_ref - state.theta_w
        integral_theta = self._integral_theta.step(e_theta, dt, mass * kip)
        return kpp * e_theta + kip * integral_theta - kdp * state.theta_dot

    def update(self, state: ControllerState) -> float:
        return acceleration_to_force(self.acceleration(state), state, self.context.plant)

    def command_applied(self, feedback: CommandFeedback) -> None:
        """Anti-windup: take back this cycle's integration if the command was cut or held."""
        self._integral_x.feedback(feedback)
        self._integral_theta.feedback(feedback)
