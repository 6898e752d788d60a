"""The pendulum's natural frequency, estimated on line, and the energy target it gives.

The energy laws of chapter 7 bring the pendulum energy (7.3)

    E_p = 1/2 J theta_dot^2 + m_p g l (cos theta + 1),   J = m_p l^2

to E* = 2 m_p g l (6.8). Computed with the *nominal* m_p and l, that target
belongs to the nominal pendulum; what it really depends on is the square of
the natural frequency of the hanging pendulum, omega_0^2 = m_p g l / J, which
this module estimates from the encoders while the pendulum swings.

Design notes: docs/controller_manager.md ("Design notes by module", ``cartpole_control.natural_frequency``).

No ROS import.
"""
from __future__ import annotations

import math

from cartpole_core.model import CartPoleParameters

from .position_window import PositionWindow

HALF_WINDOW = 20
"""T of the window, in samples (0.1 s at 5 ms)."""
EVERY = 5
"""A window is taken every this many samples (they overlap)."""
FORGETTING = 0.995
"""Weight kept by the past per window (memory about 20 s)."""
PRIOR_WEIGHT = 1.0e-4
"""sum(phi^2) the nominal value counts for [s^4] (phi of a T = 0.1 s window of a
0.1 rad swing is about 1e-3 s^2, so the prior weighs about a hundred such windows)."""
BOUNDS = (0.25, 4.0)
"""The estimate stays within these factors of the nominal omega_0^2."""
PHI_MIN = 3.0e-4
"""[s^2] Windows with less gravity in them (a swing below about 0.03 rad) are left out,
and the past is not forgotten over them: a pendulum hanging still says nothing of
omega_0^2 but the encoders' noise (10 minutes idle would otherwise make it noise)."""
GATE = 0.5
"""A window whose residual is beyond this fraction of the gravity term it measures (plus
:data:`NOISE`) is left out: a push or a knock, not the pendulum's own swing."""
NOISE = 0.01
"""[rad] The encoders' noise in a window's second difference of theta."""
GATE_AFTER = 40
"""Windows taken before the gate applies (the first ones set the estimate)."""
RATE = 0.02
"""Largest change of omega_0^2 per window, as a fraction of the nominal (0.8 per second)."""


class NaturalFrequencyEstimator:
    """omega_0^2 = m_p g l / J of the pendulum on the rig, from the swings; see the module docstring.

    Parameters
    ----------
    plant
        The nominal model: the prior omega_0^2 = g / l, J = m_p l^2 and the
        pendulum friction (4.21).
    """

    def __init__(self, plant: CartPoleParameters, sample_time: float | None = None,
                 half_window: int = HALF_WINDOW, forgetting: float = FORGETTING,
                 prior_weight: float = PRIOR_WEIGHT) -> None:
        if not (0.0 < forgetting <= 1.0 and prior_weight > 0.0):
            raise ValueError('forgetting in (0, 1] and prior_weight > 0 needed')
        self.g = plant.g
        self.inertia = plant.m_p * plant.l * plant.l
        """J of (7.3) with the nominal tip mass and length [kg m^2]."""
        self.nominal = plant.m_p * plant.g * plant.l / self.inertia
        """omega_0^2 of the nominal model, g / l [1/s^2]."""
        self._c_p = plant.c_p
        self._k_p = plant.friction_steepness_pendulum
        self._v_p = plant.v_p
        self.window = PositionWindow(sample_time or plant.sample_time, half_window, EVERY)
        """The encoders' samples of the next window."""
        self.forgetting = float(forgetting)
        self.prior_weight = float(prior_weight)
        self._low, self._high = BOUNDS[0] * self.nominal, BOUNDS[1] * self.nominal
        self.reset()

    def reset(self) -> None:
        """Back to the nominal omega_0^2, no data."""
        self._sum_pp = self.prior_weight
        self._sum_py = self.prior_weight * self.nominal
        self.omega_sq = self.nominal
        """The estimate of omega_0^2 [1/s^2]."""
        self.windows = 0
        """Windows taken into the estimate."""
        self.skipped = 0
        """Windows left out for too little swing (:data:`PHI_MIN`)."""
        self.gated = 0
        """Windows left out for their residual (:data:`GATE`)."""
        self.window.clear()

    @property
    def omega(self) -> float:
        """The estimated natural frequency omega_0 [rad/s]."""
        return math.sqrt(self.omega_sq)

    def energy(self, theta: float, theta_dot: float) -> float:
        """E_p of (7.3) with the estimated omega_0^2: J (1/2 theta_dot^2 + omega_0^2 (cos theta + 1)) [J]."""
        return self.inertia * (0.5 * theta_dot * theta_dot + self.omega_sq * (math.cos(theta) + 1.0))

    @property
    def upright_energy(self) -> float:
        """E* of (6.8) for the estimated omega_0^2: 2 J omega_0^2 [J]."""
        return 2.0 * self.inertia * self.omega_sq

    def _friction(self, theta_dot: float) -> float:
        """B_p(theta_dot) / J of (4.21) with the nominal friction [1/s^2]."""
        return (self._c_p * math.tanh(self._k_p * theta_dot) + self._v_p * theta_dot) / self.inertia

    def forget_samples(self) -> None:
        """Start the next window afresh (a plant reset moved the positions); the estimate stays."""
        self.window.clear()

    def update(self, t: float, x: float, theta: float) -> None:
        """Take the estimated cart position and (unwrapped) angle of one sample at ``t`` [s]."""
        if self.window.push(t, x, theta):
            self._take_window()

    def _take_window(self) -> None:
        """One (phi, y) from the 2T + 1 samples held, into the least squares."""
        window = self.window
        xs, ths = window.x, window.theta
        m = window.half_window
        h = window.step
        sin, cos = math.sin, math.cos
        g = self.g
        phi_gravity = 0.0
        phi_cart = 0.0
        friction = 0.0
        for i in range(2 * m):  # the interval [s_i, s_i+1], by its midpoint
            k_mid = (m - abs(i + 0.5 - m)) * h
            slope = 1.0 if i < m else -1.0
            th_mid = 0.5 * (ths[i] + ths[i + 1])
            d_th = ths[i + 1] - ths[i]
            d_x = xs[i + 1] - xs[i]
            s_mid = sin(th_mid)
            phi_gravity += k_mid * s_mid * h
            phi_cart += -slope * cos(th_mid) * d_x + k_mid * s_mid * d_th * d_x / h
            friction += k_mid * self._friction(d_th / h) * h
        phi = phi_gravity + phi_cart / g
        if abs(phi) < PHI_MIN:
            self.skipped += 1
            return
        y = ths[2 * m] - 2.0 * ths[m] + ths[0] + friction
        predicted = self.omega_sq * phi
        if self.windows >= GATE_AFTER and abs(y - predicted) > GATE * abs(predicted) + NOISE:
            self.gated += 1
            return
        lam = self.forgetting
        self._sum_pp = lam * self._sum_pp + phi * phi
        self._sum_py = lam * self._sum_py + phi * y
        self.windows += 1
        rate = RATE * self.nominal
        target = min(max(self._sum_py / self._sum_pp, self._low), self._high)
        self.omega_sq = min(max(target, self.omega_sq - rate), self.omega_sq + rate)
