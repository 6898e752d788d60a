"""LQR stabiliser on the upright linearisation, section 8.2, with integral action (LQI).

The model linearised about upright rest, (8.13)/(8.14), comes from
:func:`cartpole_core.model.linearise_upright` (with the 1/m_c that the printed
A44 of (8.13) lacks). The gain minimising (8.15)

    J = int (x^T Q x + u^T R u) dt

is ``K = R^-1 B^T P`` (8.17) with P from the algebraic Riccati equation (8.18),
solved by :func:`scipy.linalg.solve_continuous_are`. The thesis's weights follow
Bryson's rule (8.19)-(8.23): Q = diag(100, 400, 100, 400), R = 0.01, which give
K = [-100, 983, -170.4, 267.0] on the model here (thesis (8.24):
[-100, 1012, -172.1, 266.8]) and the closed-loop poles -127.9,
-1.68 +- 1.41j, -1.00 ((8.25) is misprinted). The law (8.16), about the
reference,

    u = -K (x - x_ref),  x = [x, theta_w, x_dot, theta_dot],  x_ref = [x*, 0, 0, 0]

is a force [N]. The "G" of LQG is the EKF upstream (section 8.2, Figure 8.3).

Integral action (LQI, not in the thesis). A state feedback without an
integrator settles wherever its own inputs balance: an encoder reset with the
pendulum b off hanging (Appendix H) makes the measured upright angle -b, and
the cart settles ``K_theta b / K_x`` from x* (about 7 m per rad with the
plain gain) -- the thesis's Figure H.1; an under-compensated cart friction
shifts it too. The state is therefore augmented with the integral of the cart
error, ``xi = int (x - x*) dt``::

    z = [x - x*, theta_w, x_dot, theta_dot, xi]
    z_dot = A_aug z + B_aug u,  A_aug = [[A, 0], [e_1^T, 0]],  B_aug = [B; 0]
    Q_aug = diag(q, q_i),  K_aug = R^-1 B_aug^T P_aug  (the Riccati equation (8.18) of
    the augmented system),  u = -K_aug z = -K (x - x_ref) - K_i xi

In equilibrium xi is constant, so x = x*: whatever constant bias the angle,
the friction compensation or the model carries, the integrator takes it up
(the measured angle then settles at -b with the pendulum truly upright). The
pair (A_aug, B_aug) is controllable ((A, B) is, and the cart position's
transfer function has no zero at s = 0), and with q_i > 0 the integrator's
mode is seen by the cost, so P_aug exists. With q_i = 0 the integrator's mode
(eigenvalue 0, a marginal mode outside the cost) is not detectable and the
ARE has no stabilising solution: that case is the plain LQR of (8.17) with
K_i = 0, handled explicitly. ``lqg.q`` carries q_i as a fifth entry; four
entries are the plain LQR.

Anti-windup and bumplessness. The integrator starts from zero at every
activation (the first command is the law without it), does not run during
swing-up (the stabiliser is not active then), and takes back its increment
whenever the manager reports the command as cut, by the saturation or the
rail guard, in the direction the increment pushed it, or held
(:class:`~cartpole_control.controllers.ConditionalIntegrator`). It is not
clamped by the actuator range: with an angle bias b that the EKF does not
take out (its offset state off) the integral term settles at ``K_theta b``
(66 N at b = 0.05 rad), cancelled by the proportional term that sees the
biased angle; only the sum is a force.

Default weights (Bryson's rule (8.19) with other bounds, R = 0.01 as (8.23)):
q = [10, 10000, 10, 1, 400], i.e. the pendulum within 0.01 rad (0.57 deg), the
cart within 0.32 m and 0.32 m/s, the pendulum's rate within 1 rad/s and the
integral within 0.05 m s. K = [-341, 1328, -289, 160], K_i = -200 N/(m s);
closed-loop poles -18.8 +- 16.7j, -1.23, -0.66 +- 1.07j. Why not the thesis's
[100, 400, 100, 400] (K = [-100, 983, -170, 267], a pole at -128 1/s):

- the pendulum joint's Coulomb friction (3.8 mN m, Table 4.1) acts like a
  relay on theta_dot; with the thesis's weights (and with the earlier tuned
  default diag(400, 400, 400, 400)) the loop seen from the joint crosses the
  negative real axis where the relay's describing function predicts a limit
  cycle of 0.34-0.38 deg at about 3 rad/s, which is what the closed loop
  shows; a heavy angle weight and light rate weights put it at 0.23 deg;
- the light rate weight halves K_theta_dot (160 against 267-361 N s/rad):
  the rate estimate's noise reaches the force through it, and the fast pole
  near -130 1/s, which only that noise excites, is gone (-19 +- 17j);
- the cart's own weights can then be light (its poles -1.23, -0.66 +- 1.07j
  are about the thesis's): the integral, not a stiff cart loop, brings the
  cart back to x*, and the catch transients stay inside the rail for every
  swing-up of the bench grid.

The thesis's law (8.24) is one parameter away: ``lqg.q: [100, 400, 100, 400]``.
"""
from __future__ import annotations

import numpy as np
import scipy.linalg

from cartpole_core.model import linearise_upright

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


class LqgStabilizer(Controller):
    """LQR state feedback (8.16)-(8.18) with integral action on the cart position, on the EKF estimate."""

    kind = STABILIZER
    name = 'lqg'
    running_state = ('_integral', '_clock')
    parameters = (
        ParameterSpec('q', (10.0, 10000.0, 10.0, 1.0, 400.0),
                      'diagonal of the state weight Q of (8.15) for [x, theta, x_dot, theta_dot] '
                      '[1/m^2, 1/rad^2, s^2/m^2, s^2/rad^2] and, as a fifth entry, of the '
                      'integral int (x - x*) dt [1/(m^2 s^2)] (LQI, not in the thesis); 4 entries '
                      'are the plain LQR (8.16) without integral action, thesis (8.21)/(8.22) '
                      '[100, 400, 100, 400]', low=0.0, high=1e8),
        ParameterSpec('r', 0.01, 'input weight R of (8.15) [1/N^2]; Bryson (8.23)',
                      low=1e-8, high=1e6),
    )

    def __init__(self) -> None:
        super().__init__()
        self.gain = np.zeros(4)
        """K of (8.17) on [x - x*, theta_w, x_dot, theta_dot], recomputed on every configure."""
        self.integral_gain = 0.0
        """K_i on int (x - x*) dt [N/(m s)]; 0 without the integral weight (or with q_i = 0)."""
        self._integral = ConditionalIntegrator()
        self._clock = StepClock()
        self._minus_gain = (0.0, 0.0, 0.0, 0.0)

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
        a, b = linearise_upright(self.context.plant)
        q_i = weights[4] if len(weights) == 5 else 0.0
        r = np.array([[float(self.gains['r'])]])
        k_aug = lqi_gain(a, b, np.diag(weights[:4]), r, q_i)[0]
        self.gain = k_aug[:4]
        self.integral_gain = float(k_aug[4])
        # -K of (8.16), negated once instead of every cycle
        self._minus_gain = tuple(float(-k) for k in self.gain)

    def on_activate(self, state: ControllerState) -> None:
        """Bumpless start: the integral starts from zero at this state."""
        self._integral.reset()
        self._clock.reset(state.t)

    def update(self, state: ControllerState) -> float:
        """u = -K (x - x*) - K_i int (x - x*) dt, with the wrapped angle."""
        error_x = state.x - self.context.x_ref
        k0, k1, k2, k3 = self._minus_gain
        u = k0 * error_x + k1 * state.theta_w + k2 * state.x_dot + k3 * state.theta_dot
        k_i = self.integral_gain
        if k_i != 0.0:
            dt = self._clock.step(state.t, self.context.sample_time)
            u -= k_i * self._integral.step(error_x, dt, -k_i)
        return u

    def command_applied(self, feedback: CommandFeedback) -> None:
        """Anti-windup: take back this cycle's integration if the command was cut or held."""
        self._integral.feedback(feedback)
