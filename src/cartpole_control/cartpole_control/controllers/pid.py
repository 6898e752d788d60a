"""Cascade PID stabiliser, section 8.1, (8.1)-(8.10), gains of Table 8.1.

Two PID controllers of the form (8.8), ``C = K_p + K_i / s + K_d s``:

- outer, cart position: ``theta* = -C_c (x* - x)`` [rad], the angle the
  pendulum must lean to bring the cart back. The sign: to move the cart
  right the pendulum must first lean right, i.e. theta < 0 (the tip is at
  ``x - l sin theta``); the other sign catches and then loses the pendulum
  (SPEC section 7).
- inner, pendulum angle: ``u = C_p (theta* - theta)``, a cart acceleration
  [m/s^2] (the input u_2 of (8.6)/(8.7)), turned into a force by (7.10). A
  pendulum leaning left (theta > theta*) gives u < 0: the cart accelerates
  left, under the tip.

With u a cart acceleration, the inner loop's characteristic polynomial is
``l s^3 + (K_d,p + v_p / (m_p l)) s^2 + (K_p,p - g) s + K_i,p`` (from (8.7)
and (8.8)); with Table 8.1 its roots are -36.5, -8.18, -0.150 on this model's
v_p (the thesis's (8.9), -37.187, -8.033, -0.15, matches a larger v_p of
about 0.016 N m s/rad). The whole linearised loop (derivative on the
measurement, see below) has the poles -13.0 +- 7.4j, -0.84 +- 1.36j, -0.171,
-0.133.

Discrete form (Ts from the state stamps): forward-Euler integrators; the
derivative acts on the measurement, i.e. on the estimated rates
``-x_dot`` and ``-theta_dot`` of the EKF (no numerical differentiation, no
kick when x* changes). Anti-windup (not in the thesis) by conditional
integration: theta* is limited to ``+-theta_max`` and the force to the
actuator's range; an integrator stops while its loop is saturated in the
direction it would push further. Activation resets both integrators
(bumpless: the first output depends only on the current state).
"""
from __future__ import annotations

from ..controller import STABILIZER, Controller, ControllerState, ParameterSpec
from . import StepClock, acceleration_to_force


class PidStabilizer(Controller):
    """Cascade PID (8.1): cart position loop outside, pendulum angle loop inside."""

    kind = STABILIZER
    name = 'pid'
    parameters = (
        ParameterSpec('cart_gains', (0.2, 0.03, 0.15),
                      '[K_p, K_i, K_d] of the cart position PID C_c (8.8), Table 8.1, from '
                      'x* - x [m] to the pendulum reference theta* [rad]: rad/m, rad/(m s), rad s/m',
                      low=0.0, high=100.0, length=3),
        ParameterSpec('pendulum_gains', (112.0, 15.0, 15.0),
                      '[K_p, K_i, K_d] of the pendulum angle PID C_p (8.8), Table 8.1, from '
                      'theta* - theta [rad] to a cart acceleration [m/s^2] (then (7.10)); '
                      'K_p must exceed g', low=0.0, high=10000.0, length=3),
        ParameterSpec('theta_max', 0.15, 'limit of the pendulum reference |theta*| [rad] '
                      '(anti-windup of C_c; not in the thesis)', low=0.0, high=0.5),
    )

    def __init__(self) -> None:
        super().__init__()
        self.integral_x = 0.0
        """int (x* - x) dt [m s]."""
        self.integral_theta = 0.0
        """int (theta* - theta) dt [rad s]."""
        self.theta_ref = 0.0
        """theta* of the last update [rad]."""
        self._clock = StepClock()

    def on_configure(self) -> None:
        """Refuse an inner loop that cannot hold the pendulum (K_p,p <= g)."""
        kp = self.gains['pendulum_gains'][0]
        g = self.context.plant.g
        if kp <= g:
            raise ValueError(f'pid: pendulum_gains K_p = {kp:g} must exceed g = {g:g} m/s^2, '
                             'or the inner loop cannot overcome gravity')

    def activate(self, state: ControllerState) -> None:
        """Bumpless start: both integrators start from zero at this state."""
        super().activate(state)
        self.integral_x = 0.0
        self.integral_theta = 0.0
        self.theta_ref = 0.0
        self._clock.reset(state.t)

    def acceleration(self, state: ControllerState) -> float:
        """The cascade's cart acceleration u [m/s^2]; updates the integrators."""
        kpc, kic, kdc = self.gains['cart_gains']
        kpp, kip, kdp = self.gains['pendulum_gains']
        theta_max = self.gains['theta_max']
        p = self.context.plant
        dt = self._clock.step(state.t, self.context.sample_time)

        # Outer loop C_c: theta* = -C_c (x* - x), derivative on -x_dot.
        e_x = self.context.x_ref - state.x
        integral_x = self.integral_x + e_x * dt
        theta_ref = -(kpc * e_x + kic * integral_x - kdc * state.x_dot)
        if abs(theta_ref) > theta_max:
            limited = max(-theta_max, min(theta_max, theta_ref))
            # Hold the integrator if integrating pushed theta* further out.
            if (theta_ref - limited) * (-kic * e_x) > 0.0:
                integral_x = self.integral_x
            theta_ref = limited
        self.integral_x = integral_x
        self.theta_ref = theta_ref

        # Inner loop C_p: u = C_p (theta* - theta), derivative on -theta_dot.
        e_theta = theta_ref - state.theta_w
        integral_theta = self.integral_theta + e_theta * dt
        u = kpp * e_theta + kip * integral_theta - kdp * state.theta_dot
        force = acceleration_to_force(u, state, p)
        if (force > p.force_max and e_theta > 0.0) or (force < p.force_min and e_theta < 0.0):
            integral_theta = self.integral_theta
            u = kpp * e_theta + kip * integral_theta - kdp * state.theta_dot
        self.integral_theta = integral_theta
        return u

    def update(self, state: ControllerState) -> float:
        return acceleration_to_force(self.acceleration(state), state, self.context.plant)
