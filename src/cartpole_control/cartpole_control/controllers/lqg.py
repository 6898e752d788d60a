"""LQR stabiliser on the upright linearisation, section 8.2, with integral action (LQI).

The model linearised about upright rest, (8.13)/(8.14)
(:func:`cartpole_core.model.linearise_upright`), augmented with the integral
of the cart error ``xi = int (x - x*) dt``; the gain ``K_aug = R^-1 B_aug^T
P_aug`` (8.17) with P_aug from the algebraic Riccati equation (8.18) of the
augmented system, solved by :func:`scipy.linalg.solve_continuous_are`. The
law (8.16) with integral action,

    u = -K (x - x_ref) - K_i xi,  x = [x, theta_w, x_dot, theta_dot],  x_ref = [x*, 0, 0, 0]

is a force [N]; ``lqg.q`` with four entries is the plain LQR (K_i = 0). Two gains: the
precise one of ``q`` near upright rest, the robust one (the pendulum's weights cut to
``pendulum_weight_min``) beyond twice ``precise_band``, blended in between; a measured dead
time cuts the precise one towards the robust one. The integrator starts from zero at every
activation and takes back its increment when the command is cut or held (anti-windup). The
"G" of LQG is the EKF upstream (Figure 8.3). The weights and what they give:
docs/controllers.md (``lqg``).
"""
from __future__ import annotations

import math

import numpy as np
import scipy.linalg

from cartpole_core.model import linearise_upright

from ..catch_region import DEFAULT_Q as CATCH_REGION_Q
from ..controller import STABILIZER, CommandFeedback, Controller, ControllerState, ParameterSpec
from . import ConditionalIntegrator, StepClock


def lqr_gain(a: np.ndarray, b: np.ndarray, q: np.ndarray, r: np.ndarray) -> np.ndarray:
    """K = R^-1 B^T P with P solving (8.18); raises ValueError if there is no stabilising P."""
    try:
        p = scipy.linalg.solve_continuous_are(a, b, q, r)
    except (np.linalg.LinAlgError, ValueError) as exc:
        raise ValueError(f'the Riccati equation (8.18) has no stabilising solution: {exc}') from exc
    k = np.linalg.solve(r, b.T @ p)
    if not np.all(np.isfinite(k)) or np.max(np.real(np.linalg.eigvals(a - b @ k))) >= 0.0:
        raise ValueError('the LQR gain does not stabilise the linearised model')
    return k


def augmented_model(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(A_aug, B_aug) of the state [x - x*, theta_w, x_dot, theta_dot, int (x - x*) dt]."""
    n = a.shape[0]
    a_aug = np.zeros((n + 1, n + 1))
    a_aug[:n, :n] = a
    a_aug[n, 0] = 1.0
    b_aug = np.vstack([b, np.zeros((1, b.shape[1]))])
    return a_aug, b_aug


def lqi_gain(a: np.ndarray, b: np.ndarray, q: np.ndarray, r: np.ndarray,
             q_i: float) -> np.ndarray:
    """K_aug = [K, K_i] of the augmented Riccati equation; q_i = 0 is the plain LQR, K_i = 0.

    Raises ValueError if there is no stabilising solution.
    """
    if q_i == 0.0:
        return np.hstack([lqr_gain(a, b, q, r), np.zeros((b.shape[1], 1))])
    a_aug, b_aug = augmented_model(a, b)
    q_aug = scipy.linalg.block_diag(q, [[q_i]])
    return lqr_gain(a_aug, b_aug, q_aug, r)


RESOLVE_TOLERANCE = 0.01
"""The estimated pendulum length differs from the model's by more than this fraction: the
gain is solved again at the catch."""
DEAD_TIME_SCALE = 0.01
"""[s] The loop's measured dead time D weighs the input by R (1 + (D / this)^2) at the catch
(docs/robustness.md, "The stabiliser's gain and the dead time")."""
DEAD_TIME_WEIGHT_MAX = 2.0
"""The most the dead time multiplies R by (``lqg.dead_time_weight_max``): softer, the cart
wanders in a friction limit cycle on a rig with more cart friction than the model's
(docs/robustness.md, "R at most doubled by the dead time")."""


def dead_time_weight(r: float, dead_time: float,
                     most: float = DEAD_TIME_WEIGHT_MAX) -> float:
    """R of (8.15) for a loop with ``dead_time`` [s]: R (1 + (D / D_s)^2), D_s = 10 ms, at
    most ``most`` R.

    The prediction over the measured latency is only as good as the model, and the
    amplifier's lag is not in it: the faster the gain, the less of that it tolerates. With
    no dead time R stays. Why 10 ms and 2 R: docs/robustness.md ("The stabiliser's gain and
    the dead time", "R at most doubled by the dead time").
    """
    return r * min(1.0 + (max(dead_time, 0.0) / DEAD_TIME_SCALE) ** 2, most)


PENDULUM_WEIGHT_SCALE = 0.005
"""[s] At the catch the loop's measured dead time D scales the pendulum's weights (theta,
theta_dot) of Q by 1 / (1 + (D / this)^2), not below ``lqg.pendulum_weight_min``."""
PENDULUM_WEIGHT_MIN = 1.0 / 3.0
"""The least share of the pendulum's weights a long dead time leaves (``lqg.pendulum_weight_min``)."""


ROBUST_GAIN = {'q': CATCH_REGION_Q, 'pendulum_weight_min': 1.0}
"""``lqg``'s settings for its robust gain alone: the default ``q`` with the pendulum's weights
at :data:`PENDULUM_WEIGHT_MIN`, one gain. It is the LQR the catch region simulates (a catch is
beyond the precise band), ``lqg``'s default until 2026-12-05, and the learned policy's teacher."""


PRECISE_BAND = (0.03, math.radians(2.0), 0.1, 0.25)
"""``lqg.precise_band``: within 3 cm, 2 deg, 10 cm/s and 0.25 rad/s of upright rest at x* the
precise gain acts (the balanced cart's friction cycle reaches 1.2 cm, 0.3 deg, 4 cm/s and
0.08 rad/s); beyond twice any the robust one (a catch, a push)."""


def dead_time_pendulum_share(dead_time: float, least: float = PENDULUM_WEIGHT_MIN) -> float:
    """The share of Q's pendulum weights for a loop with ``dead_time`` [s]: 1 / (1 + (D /
    5 ms)^2), at least ``least``; 1 with no dead time."""
    return max(least, 1.0 / (1.0 + (max(dead_time, 0.0) / PENDULUM_WEIGHT_SCALE) ** 2))


def catch_plant(context, most: float):
    """``(plant, r_factor)`` to solve a stabiliser again for at the catch, or None to keep the
    configured one: the plant the manager estimated (:attr:`ControlContext.plant_estimate`),
    when its pendulum differs from the model's by more than :data:`RESOLVE_TOLERANCE` or the
    loop's dead time weighs R (:func:`dead_time_weight`, at most ``most``) by more than that."""
    estimate = context.plant_estimate
    if estimate is None:
        return None
    plant = estimate.estimated_plant()
    r_factor = dead_time_weight(1.0, estimate.dead_time, most)
    if abs(plant.l / context.plant.l - 1.0) > RESOLVE_TOLERANCE or \
            r_factor > 1.0 + RESOLVE_TOLERANCE:
        return plant, r_factor
    return None


class LqgStabilizer(Controller):
    """LQR state feedback (8.16)-(8.18) with integral action on the cart position, on the EKF estimate."""

    kind = STABILIZER
    name = 'lqg'
    running_state = ('_integral', '_clock')
    parameters = (
        ParameterSpec('q', (10.0, 30000.0, 10.0, 3.0, 400.0),
                      'diagonal of the state weight Q of (8.15) for [x, theta, x_dot, theta_dot] '
                      '[1/m^2, 1/rad^2, s^2/m^2, s^2/rad^2] and, as a fifth entry, of the '
                      'integral int (x - x*) dt [1/(m^2 s^2)] (LQI, not in the thesis); 4 entries '
                      'are the plain LQR (8.16) without integral action, thesis (8.21)/(8.22) '
                      '[100, 400, 100, 400]', low=0.0, high=1e8),
        ParameterSpec('r', 0.01, 'input weight R of (8.15) [1/N^2]; Bryson (8.23)',
                      low=1e-8, high=1e6),
        ParameterSpec('dead_time_weight_max', DEAD_TIME_WEIGHT_MAX,
                      'at the catch R is solved again as R (1 + (D / 10 ms)^2) for the loop\'s '
                      'measured dead time D, at most this many times R; 1 keeps R [-]',
                      low=1.0, high=100.0),
        ParameterSpec('pendulum_weight_min', PENDULUM_WEIGHT_MIN,
                      'the robust gain\'s share of the pendulum weights of q (theta, theta_dot); '
                      'at the catch the loop\'s measured dead time D scales them for the precise '
                      'gain by 1 / (1 + (D / 5 ms)^2), not below this; 1: one gain [-]',
                      low=0.01, high=1.0),
        ParameterSpec('precise_band', PRECISE_BAND,
                      'the state deviations [|x - x*| m, |theta_w| rad, |x_dot| m/s, |theta_dot| '
                      'rad/s] within which the precise gain acts; beyond twice any of them the '
                      'robust one, blended linearly in between', low=1e-6, high=10.0, length=4),
    )

    def __init__(self) -> None:
        super().__init__()
        self.gain = np.zeros(4)
        """K of (8.17) on [x - x*, theta_w, x_dot, theta_dot] near upright rest (the precise
        gain), recomputed on every configure and at the catch."""
        self.integral_gain = 0.0
        """K_i on int (x - x*) dt [N/(m s)]; 0 without the integral weight (or with q_i = 0)."""
        self.robust_gain = np.zeros(4)
        """K of (8.17) with the pendulum's weights cut to ``pendulum_weight_min``: the gain
        beyond twice ``precise_band`` (:data:`PRECISE_BAND`)."""
        self.robust_integral_gain = 0.0
        self._integral = ConditionalIntegrator()
        self._clock = StepClock()
        self._minus_gain = self._minus_robust = (0.0, 0.0, 0.0, 0.0)
        self._blend = False
        self._inverse_band = (0.0, 0.0, 0.0, 0.0)

    @property
    def integral(self) -> float:
        """xi = int (x - x*) dt [m s]."""
        return self._integral.value

    def on_configure(self) -> None:
        """Solve the (augmented) Riccati equation for Q (and q_i), R; refuse an unstabilising choice."""
        weights = [float(v) for v in self.gains['q']]
        if len(weights) not in (4, 5):
            raise ValueError(f'lqg: q needs 4 entries (the plain LQR) or 5 (with the integral '
                             f'weight q_i), got {len(weights)}')
        self._inverse_band = tuple(1.0 / float(v) for v in self.gains['precise_band'])
        self._use(self.context.plant)
        self._nominal = self._in_use()
        self.solved_for = self.context.plant
        """The plant model of the gain in use (the nominal one, or the estimate at the catch)."""

    def _solve(self, plant, r_factor: float, pendulum_share: float) -> tuple[np.ndarray, float]:
        """``(K, K_i)`` of (8.17) for ``plant``, R times ``r_factor``, the pendulum's weights
        (theta, theta_dot) of Q times ``pendulum_share``."""
        weights = [float(v) for v in self.gains['q']]
        weights[1] *= pendulum_share
        weights[3] *= pendulum_share
        a, b = linearise_upright(plant)
        q_i = weights[4] if len(weights) == 5 else 0.0
        r = np.array([[r_factor * float(self.gains['r'])]])
        k_aug = lqi_gain(a, b, np.diag(weights[:4]), r, q_i)[0]
        return k_aug[:4], float(k_aug[4])

    def _use(self, plant, r_factor: float = 1.0, pendulum_share: float = 1.0) -> None:
        """The precise gain for ``pendulum_share`` (at least ``pendulum_weight_min``) and the
        robust one, both for ``plant`` and R times ``r_factor``."""
        least = float(self.gains['pendulum_weight_min'])
        share = max(pendulum_share, least)
        self.gain, self.integral_gain = self._solve(plant, r_factor, share)
        if share > least:
            self.robust_gain, self.robust_integral_gain = self._solve(plant, r_factor, least)
        else:
            self.robust_gain, self.robust_integral_gain = self.gain, self.integral_gain
        # -K of (8.16), negated once instead of every cycle
        self._minus_gain = tuple(float(-k) for k in self.gain)
        self._minus_robust = tuple(float(-k) for k in self.robust_gain)
        self._blend = share > least

    def _in_use(self) -> tuple:
        return (self.gain, self.integral_gain, self.robust_gain, self.robust_integral_gain,
                self._minus_gain, self._minus_robust, self._blend)

    def on_activate(self, state: ControllerState) -> None:
        """Bumpless start: the integral starts from zero at this state.

        At the catch the Riccati equation (8.18) is solved again for the plant
        the manager has estimated (:attr:`ControlContext.plant_estimate`): the
        pendulum's omega_0^2, if it differs from the model by more than
        :data:`RESOLVE_TOLERANCE`, and the loop's dead time, which weighs R
        (:func:`dead_time_weight`; :func:`catch_plant`) and, with the mean age of the samples
        (lost ones), cuts the precise gain's pendulum weights
        (:func:`dead_time_pendulum_share`); else the configured gains stay.
        """
        self._integral.reset()
        self._clock.reset(state.t)
        again = catch_plant(self.context, float(self.gains['dead_time_weight_max']))
        estimate = self.context.plant_estimate
        share = 1.0 if estimate is None else dead_time_pendulum_share(
            estimate.dead_time + estimate.sample_age.age, float(self.gains['pendulum_weight_min']))
        if again is None and share < 1.0 - RESOLVE_TOLERANCE:
            again = (estimate.estimated_plant(), 1.0)
        if again is not None:
            try:
                self._use(*again, share)
                self.solved_for = again[0]
                return
            except ValueError:
                pass  # no stabilising solution for the estimate: the model's gains
        (self.gain, self.integral_gain, self.robust_gain, self.robust_integral_gain,
         self._minus_gain, self._minus_robust, self._blend) = self._nominal
        self.solved_for = self.context.plant

    def update(self, state: ControllerState) -> float:
        """u = -K (x - x*) - K_i int (x - x*) dt, with the wrapped angle; K the precise gain
        within ``precise_band``, the robust one beyond twice it, blended linearly between."""
        error_x = state.x - self.context.x_ref
        theta_w = state.theta_w
        k0, k1, k2, k3 = self._minus_gain
        k_i = self.integral_gain
        if self._blend:
            bx, bt, bv, bw = self._inverse_band
            rho = max(abs(error_x) * bx, abs(theta_w) * bt, abs(state.x_dot) * bv,
                      abs(state.theta_dot) * bw)
            if rho > 1.0:
                w = 2.0 - rho if rho < 2.0 else 0.0  # the precise gain's share
                r0, r1, r2, r3 = self._minus_robust
                k0, k1, k2, k3 = (r0 + w * (k0 - r0), r1 + w * (k1 - r1), r2 + w * (k2 - r2),
                                  r3 + w * (k3 - r3))
                k_i = self.robust_integral_gain + w * (k_i - self.robust_integral_gain)
        u = k0 * error_x + k1 * theta_w + k2 * state.x_dot + k3 * state.theta_dot
        if k_i != 0.0:
            dt = self._clock.step(state.t, self.context.sample_time)
            u -= k_i * self._integral.step(error_x, dt, -k_i)
        return u

    def command_applied(self, feedback: CommandFeedback) -> None:
        """Anti-windup: take back this cycle's integration if the command was cut or held."""
        self._integral.feedback(feedback)
