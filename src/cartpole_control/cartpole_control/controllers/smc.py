"""Sliding-mode stabiliser, section 8.3, (8.26)-(8.42), with s-dot derived again.

Regular form (8.26)-(8.33). With ``eta = [theta, x_dot cos(theta)/l - theta_dot,
x - x*]`` and ``xi = theta_dot`` the input enters only through ``xi``: from the
second row of (4.17), ``l theta_ddot = g sin theta + x_ddot cos theta - B_p/(m_p l)``,
so

    d/dt eta_2 = x_ddot cos/l - x_dot theta_dot sin/l - theta_ddot
               = -(g sin theta + x_dot theta_dot sin theta) / l + B_p / (m_p l^2)

has no u. Linearised at the origin (8.36)-(8.38):
``A = [[0, 0, 0], [-g/l, 0, 0], [0, l, 0]]``, ``B = [1, v_p/(l^2 m_p), l]^T``.

Manifold (8.35), (8.40). ``phi(eta) = -k eta`` with k from pole placement
(:func:`scipy.signal.place_poles`) for the poles of ``A - B k``; the thesis's
-1, -4 +- 2.4j give k = [9.77, -1.015, -2.218] (thesis (8.39): k ~ [10, -1, -2])::

    s = xi + k eta = theta_dot + k_1 theta_w + k_2 (x_dot cos(theta)/l - theta_dot) + k_3 (x - x*)

Derivative of s, derived again from (4.34) (SPEC section 7: the printed (8.41)
puts the term ``(k_3 - k_2 sin/l) x_dot`` into Gamma and drops the theta_dot
of ``d/dt cos theta = -theta_dot sin theta``). With ``x_ddot = f_c + g_c u``,
``theta_ddot = f_p + g_p u`` (8.27), ``d = m_c + m_p sin^2 theta``,
``g_c = 1/d``, ``g_p = cos theta / (l d)``::

    s_dot = theta_ddot + k_1 theta_dot
            + k_2 (x_ddot cos/l - x_dot theta_dot sin/l - theta_ddot) + k_3 x_dot
          = Phi + Gamma u
    Phi   = (1 - k_2) f_p + k_2 f_c cos(theta)/l + k_1 theta_dot
            + (k_3 - k_2 theta_dot sin(theta)/l) x_dot
    Gamma = (1 - k_2) g_p + k_2 g_c cos(theta)/l = g_p = cos theta / (l d)

(Gamma equals g_p for every k: the u-terms of eta cancel, which is what the
regular form is for.) f_c and f_p are the model accelerations without
friction (the cart's Coulomb friction is the feedforward's job (6.12), the
pendulum's is negligible here).

Control law (8.42) with a boundary layer against chattering::

    u = -(Phi + lambda sat(s / phi_b)) / Gamma

so that ``s_dot = -lambda sat(s/phi_b)``: s reaches the layer |s| <= phi_b in
finite time and then decays with the rate ``lambda/phi_b``. The thesis makes
``lambda = |Phi/Gamma| + lambda_0``, which adds a force to an angular
acceleration; here lambda is the constant reaching gain ``lambda_0``
[rad/s^2]. Gamma vanishes with cos theta at +-90 deg; |cos theta| is floored
at ``cos_min`` so the law stays finite away from upright (the catch window is
+-30 deg, cos >= 0.87).
"""
from __future__ import annotations

import math

import numpy as np
import scipy.signal

from cartpole_sim.model import CartPoleParameters, accelerations

from ..controller import STABILIZER, Controller, ControllerState, ParameterSpec
from . import saturation


def regular_form_linearisation(params: CartPoleParameters) -> tuple[np.ndarray, np.ndarray]:
    """(A, B) of the eta-subsystem linearised at the origin, (8.37)/(8.38)."""
    l, g = params.l, params.g
    a = np.array([[0.0, 0.0, 0.0], [-g / l, 0.0, 0.0], [0.0, l, 0.0]])
    b = np.array([[1.0], [params.v_p / (l * l * params.m_p)], [l]])
    return a, b


def manifold_gain(params: CartPoleParameters, poles: list[complex]) -> np.ndarray:
    """k of (8.35) placing the eigenvalues of A - B k at ``poles``, (8.36)-(8.39)."""
    a, b = regular_form_linearisation(params)
    try:
        result = scipy.signal.place_poles(a, b, np.asarray(poles))
    except ValueError as exc:
        raise ValueError(f'smc: cannot place the poles {poles}: {exc}') from exc
    return np.asarray(result.gain_matrix, dtype=float)[0]


def poles_from_parameter(values) -> list[complex]:
    """The poles of ``smc.poles`` = [re_1, im_1, re_2, im_2, re_3, im_3]; ValueError if unusable."""
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
    """Sliding-mode control (8.40)-(8.42) with a boundary layer."""

    kind = STABILIZER
    name = 'smc'
    parameters = (
        ParameterSpec('poles', (-1.0, 0.0, -4.0, 2.4, -4.0, -2.4),
                      'poles of the sliding motion (8.36) as [re1, im1, re2, im2, re3, im3] '
                      '[1/s]; complex ones in conjugate pairs; thesis -1, -4+-2.4j',
                      low=-100.0, high=100.0, length=6),
        ParameterSpec('reaching_gain', 4.0, 'reaching gain lambda_0 of (8.42): s_dot = -lambda_0 '
                      'outside the boundary layer [rad/s^2]', low=1e-6, high=1000.0),
        ParameterSpec('boundary', 0.2, 'boundary layer width phi_b replacing sgn(s) by '
                      'sat(s/phi_b) [rad/s] (0.01-0.5 work; not in the thesis)',
                      low=1e-4, high=10.0),
        ParameterSpec('cos_min', 0.2, 'floor of |cos theta| in Gamma = cos theta/(l d) [1], '
                      'keeps the law finite far from upright', low=0.01, high=1.0),
    )

    def __init__(self) -> None:
        super().__init__()
        self.k = np.zeros(3)
        """Manifold gain k of (8.35)/(8.39)."""
        self.s = 0.0
        """The sliding variable (8.40) of the last update [rad/s]."""

    def on_configure(self) -> None:
        """Place the manifold's poles (8.36)-(8.39); refuse unusable poles."""
        self.k = manifold_gain(self.context.plant, poles_from_parameter(self.gains['poles']))

    def sliding_variable(self, state: ControllerState) -> float:
        """s of (8.40)."""
        k1, k2, k3 = self.k
        l = self.context.plant.l
        eta2 = state.x_dot * math.cos(state.theta) / l - state.theta_dot
        return state.theta_dot + k1 * state.theta_w + k2 * eta2 + k3 * (state.x - self.context.x_ref)

    def update(self, state: ControllerState) -> float:
        p = self.context.plant
        k1, k2, k3 = self.k
        s_th, c_th = math.sin(state.theta), math.cos(state.theta)
        f_c, f_p = accelerations(state.x, state.theta, state.x_dot, state.theta_dot, 0.0, p,
                                 friction=False)
        phi = ((1.0 - k2) * f_p + k2 * f_c * c_th / p.l + k1 * state.theta_dot
               + (k3 - k2 * state.theta_dot * s_th / p.l) * state.x_dot)
        c_floor = math.copysign(max(abs(c_th), self.gains['cos_min']), c_th)
        gamma = c_floor / (p.l * (p.m_c + p.m_p * s_th * s_th))
        self.s = self.sliding_variable(state)
        reach = self.gains['reaching_gain'] * saturation(self.s / self.gains['boundary'])
        return -(phi + reach) / gamma
