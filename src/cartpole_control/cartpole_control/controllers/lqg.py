"""LQR stabiliser on the upright linearisation, section 8.2; with the EKF it is the LQG.

The model linearised about upright rest, (8.13)/(8.14), comes from
:func:`cartpole_sim.model.linearise_upright` (with the 1/m_c that the printed
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

Tuned default. With the thesis's Q the cart's poles (-1.68 +- 1.41j, -1.00)
are slow: after a catch at the edge of the window (30 deg, E_p within 5 % of
E*) the cart travels about 37 cm, and in the offline closed loop with a 10 %
heavier tip it reached the left rail guard and lost the pendulum. The default
is Bryson's rule (8.19) with 5 cm and 5 cm/s for the cart instead of 10 cm
and 10 cm/s, Q = diag(400, 400, 400, 400): K = [-200, 1398, -308, 324],
poles -132.9, -2.47 +- 1.78j, -1.00. The thesis's Q stays one parameter away
(``lqg.q: [100.0, 400.0, 100.0, 400.0]``).
"""
from __future__ import annotations

import numpy as np
import scipy.linalg

from cartpole_sim.model import linearise_upright

from ..controller import STABILIZER, Controller, ControllerState, ParameterSpec


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


class LqgStabilizer(Controller):
    """LQR state feedback (8.16)-(8.18) on the EKF estimate."""

    kind = STABILIZER
    name = 'lqg'
    parameters = (
        ParameterSpec('q', (400.0, 400.0, 400.0, 400.0),
                      'diagonal of the state weight Q of (8.15) for [x, theta, x_dot, theta_dot] '
                      '[1/m^2, 1/rad^2, s^2/m^2, s^2/rad^2]; thesis (8.21)/(8.22) '
                      '[100, 400, 100, 400] lets the cart swing ~37 cm after a catch (end stop); '
                      'tuned: Bryson with 5 cm, 5 cm/s', low=0.0, high=1e8, length=4),
        ParameterSpec('r', 0.01, 'input weight R of (8.15) [1/N^2]; Bryson (8.23)',
                      low=1e-8, high=1e6),
    )

    def __init__(self) -> None:
        super().__init__()
        self.gain = np.zeros(4)
        """K of (8.17), recomputed on every configure."""
        self._minus_gain = -self.gain

    def on_configure(self) -> None:
        """Solve (8.18) for the current Q, R and plant model; refuse an unstabilising choice."""
        a, b = linearise_upright(self.context.plant)
        q = np.diag(np.asarray(self.gains['q'], dtype=float))
        r = np.array([[float(self.gains['r'])]])
        self.gain = lqr_gain(a, b, q, r)[0]
        self._minus_gain = -self.gain  # -K of (8.16), negated once instead of every cycle

    def update(self, state: ControllerState) -> float:
        """u = -K (x - x*) (8.16), with the wrapped angle."""
        error = np.array([state.x - self.context.x_ref, state.theta_w, state.x_dot,
                          state.theta_dot])
        return float(self._minus_gain @ error)
