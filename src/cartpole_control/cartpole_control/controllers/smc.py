"""Sliding-mode stabiliser, section 8.3, (8.26)-(8.42), with s-dot derived again.

Regular form (8.26)-(8.33). With ``eta = [theta, x_dot cos(theta)/l - theta_dot,
x - x*]`` and ``xi = theta_dot`` the input enters only through ``xi``: from the
second row of (4.17), ``l theta_ddot = g sin theta + x_ddot cos theta - B_p/(m_p l)``,
so

    d/dt eta_2 = x_ddot cos/l - x_dot theta_dot sin/l - theta_ddot
               = -(g sin theta + x_dot theta_dot sin theta) / l + B_p / (m_p l^2)

has no u. Linearised at the origin (8.36)-(8.38):
``A = [[0, 0, 0], [-g/l, 0, 0], [0, l, 0]]``, ``B = [1, v_p/(l^2 m_p), l]^T``.

Design notes: docs/controllers.md ("Design notes by module", ``cartpole_control.controllers.smc``).
"""
from __future__ import annotations

import math

import numpy as np

from cartpole_core.model import CartPoleParameters, accelerations

from ..controller import STABILIZER, CommandFeedback, Controller, ControllerState, ParameterSpec
from . import ConditionalIntegrator, StepClock, saturation


def regular_form_linearisation(params: CartPoleParameters,
                               integral: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """(A, B) of the eta-subsystem linearised at the origin, (8.37)/(8.38).

    With ``integral`` the subsystem is extended by eta_4 = int (x - x*) dt
    (eta_4_dot = eta_3).
    """
    l, g = params.l, params.g
    a = np.array([[0.0, 0.0, 0.0], [-g / l, 0.0, 0.0], [0.0, l, 0.0]])
    b = np.array([[1.0], [params.v_p / (l * l * params.m_p)], [l]])
    if integral:
        a = np.pad(a, ((0, 1), (0, 1)))
        a[3, 2] = 1.0
        b = np.vstack([b, [[0.0]]])
    return a, b


def ackermann(a: np.ndarray, b: np.ndarray, poles) -> np.ndarray:
    """The single-input gain k with eig(A - B k) = ``poles`` (Ackermann's formula).

    ``k = e_n^T C^-1 phi(A)``, C the controllability matrix and phi the
    desired characteristic polynomial; exact for repeated poles, which
    :func:`scipy.signal.place_poles` refuses for a single input.
    """
    n = a.shape[0]
    ctrb = np.hstack([np.linalg.matrix_power(a, i) @ b for i in range(n)])
    if np.linalg.matrix_rank(ctrb) < n:
        raise ValueError('the regular form is not controllable')
    coeffs = np.real(np.poly(np.asarray(poles, dtype=complex)))
    phi = sum(c * np.linalg.matrix_power(a, n - i) for i, c in enumerate(coeffs))
    return np.linalg.solve(ctrb.T, np.eye(n)[:, -1]) @ phi


def manifold_gain(params: CartPoleParameters, poles: list[complex]) -> np.ndarray:
    """k of (8.35) placing the eigenvalues of A - B k at ``poles``, (8.36)-(8.39).

    Three poles: the thesis's manifold on [eta_1, eta_2, eta_3]; four: the
    manifold with the integral eta_4 = int (x - x*) dt (module docstring).
    """
    if len(poles) not in (3, 4):
        raise ValueError(f'smc: 3 poles (the thesis) or 4 (with the integral), got {len(poles)}')
    a, b = regular_form_linearisation(params, integral=len(poles) == 4)
    return ackermann(a, b, poles)


def poles_from_parameter(values) -> list[complex]:
    """The poles of ``smc.poles`` = [re_1, im_1, ..., re_n, im_n], n = 3 or 4; ValueError if unusable."""
    if len(values) not in (6, 8):
        raise ValueError(f'smc: poles needs 6 numbers (3 poles, the thesis\'s manifold) or 8 '
                         f'(4 poles, with the integral of the cart error), got {len(values)}')
    poles = [complex(values[i], values[i + 1]) for i in range(0, len(values), 2)]
    if any(p.real >= 0.0 for p in poles):
        raise ValueError(f'smc: every pole must have a negative real part, got {poles}')
    remaining = list(poles)
    while remaining:
        p = remaining.pop(0)
        if p.imag != 0.0:
            match = [q for q in remaining if q == p.conjugate()]
            if not match:
                raise ValueError(f'smc: the complex pole {p} needs its conjugate {p.conjugate()}')
            remaining.remove(match[0])
    return poles


class SlidingModeStabilizer(Controller):
    """Sliding-mode control (8.40)-(8.42) with a boundary layer and integral action on x."""

    kind = STABILIZER
    name = 'smc'
    running_state = ('_integral', '_clock', 's')
    parameters = (
        ParameterSpec('poles', (-1.0, 0.0, -4.0, 2.4, -4.0, -2.4, -1.0, 0.0),
                      'poles of the sliding motion (8.36) as [re1, im1, re2, im2, ...] [1/s], '
                      'complex ones in conjugate pairs: 3 poles (6 numbers) are the thesis\'s '
                      'manifold (-1, -4+-2.4j), 4 poles (8 numbers) add the integral of the cart '
                      'error (not in the thesis)', low=-100.0, high=100.0),
        ParameterSpec('reaching_gain', 8.0, 'reaching gain lambda_0 of (8.42): s_dot = -lambda_0 '
                      'outside the boundary layer [rad/s^2]', low=1e-6, high=1000.0),
        ParameterSpec('boundary', 0.1, 'boundary layer width phi_b replacing sgn(s) by '
                      'sat(s/phi_b) [rad/s] (0.01-0.5 work; not in the thesis)',
                      low=1e-4, high=10.0),
        ParameterSpec('cos_min', 0.2, 'floor of |cos theta| in Gamma = cos theta/(l d) [1], '
                      'keeps the law finite far from upright', low=0.01, high=1.0),
        ParameterSpec('friction_steepness', 200.0, 'k of the pendulum joint friction '
                      'c_p tanh(k theta_dot) in the model (6.11) [s/rad]; 0 leaves its Coulomb '
                      'part out', low=0.0, high=1000.0),
    )

    def __init__(self) -> None:
        super().__init__()
        self.k = np.zeros(4)
        """Manifold gain [k_1, k_2, k_3, k_4] of (8.35)/(8.39); k_4 = 0 with three poles."""
        self.s = 0.0
        """The sliding variable (8.40) of the last update [rad/s]."""
        self._integral = ConditionalIntegrator()
        self._clock = StepClock()

    @property
    def integral(self) -> float:
        """eta_4 = int (x - x*) dt [m s]."""
        return self._integral.value

    def on_configure(self) -> None:
        """Place the manifold's poles (8.36)-(8.39); refuse unusable poles."""
        p = self.context.plant
        k = manifold_gain(p, poles_from_parameter(self.gains['poles']))
        self.k = np.append(k, 0.0) if len(k) == 3 else k
        # The model of (6.11): the pendulum's friction, not the cart's (the feedforward's).
        self._model = p.replace(c_c_right=0.0, c_c_left=0.0, v_c=0.0,
                                friction_steepness_pendulum=max(self.gains['friction_steepness'],
                                                                1e-9),
                                c_p=p.c_p if self.gains['friction_steepness'] > 0.0 else 0.0)

    def on_activate(self, state: ControllerState) -> None:
        """Bumpless start: the integral starts from zero at this state."""
        self._integral.reset()
        self._clock.reset(state.t)

    def sliding_variable(self, state: ControllerState) -> float:
        """s of (8.40), with the integral term k_4 eta_4 as it stands."""
        k1, k2, k3, k4 = self.k
        l = self.context.plant.l
        eta2 = state.x_dot * math.cos(state.theta) / l - state.theta_dot
        return (state.theta_dot + k1 * state.theta_w + k2 * eta2
                + k3 * (state.x - self.context.x_ref) + k4 * self._integral.value)

    def update(self, state: ControllerState) -> float:
        """u = -(Phi + lambda_0 sat(s / phi_b)) / Gamma, (8.42) with s-dot derived again."""
        p = self.context.plant
        k1, k2, k3, k4 = self.k
        error_x = state.x - self.context.x_ref
        s_th, c_th = math.sin(state.theta), math.cos(state.theta)
        f_c, f_p = accelerations(state.x, state.theta, state.x_dot, state.theta_dot, 0.0,
                                 self._model)
        phi = ((1.0 - k2) * f_p + k2 * f_c * c_th / p.l + k1 * state.theta_dot
               + (k3 - k2 * state.theta_dot * s_th / p.l) * state.x_dot + k4 * error_x)
        c_floor = math.copysign(max(abs(c_th), self.gains['cos_min']), c_th)
        gamma = c_floor / (p.l * (p.m_c + p.m_p * s_th * s_th))
        reaching, boundary = self.gains['reaching_gain'], self.gains['boundary']
        if k4 != 0.0:
            dt = self._clock.step(state.t, self.context.sample_time)
            # d(force)/d(eta_4) inside the layer: -lambda_0 k_4 / (phi_b Gamma).
            self._integral.step(error_x, dt, -reaching * k4 / (boundary * gamma))
        self.s = self.sliding_variable(state)
        if k4 != 0.0 and abs(self.s) >= boundary:
            self._integral.hold()  # reaching phase: integrate on the manifold only
            self.s = self.sliding_variable(state)
        reach = reaching * saturation(self.s / boundary)
        return -(phi + reach) / gamma

    def command_applied(self, feedback: CommandFeedback) -> None:
        """Anti-windup: take back this cycle's integration if the command was cut or held."""
        self._integral.feedback(feedback)
