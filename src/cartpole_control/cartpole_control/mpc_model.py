"""The prediction model of the ``mpc`` stabiliser: plant, actuator lag and dead time, sampled.

The plant: the upright linearisation (8.13)/(8.14) with the integral of the cart error (the
LQI of :mod:`.controllers.lqg`), ``z = [x - x*, theta_w, x_dot, theta_dot, xi]``, driven by the
force on the cart F. Between the command u and F:

- a first-order lag ``tau F_dot = u - F`` (``lag``; the current loop's 0.1 ms (4.4) stays
  out); the state grows by F;
- a dead time ``d`` (``dead_time``), sampled exactly with u held (Astrom and Wittenmark,
  "Computer-Controlled Systems", 3rd ed., section 2.3): with ``d = (l - 1) Ts + d'``,
  ``0 < d' <= Ts``, ``s_{k+1} = Phi s_k + Gamma_1 u_{k-l} + Gamma_0 u_{k-l+1}``; the state
  grows by the l commands in flight.

Both 0 by default: the manager already predicts over the measured latency, so ``dead_time``
is only what that does not cover. The cost (8.15) over a sample is exact
(:func:`sampled_cost`; with a dead time less its O(Ts^2) cross term), the terminal cost the
discrete Riccati solution (:func:`terminal_lqr`). No ROS.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.linalg

PLANT_STATES = 5
"""z = [x - x*, theta_w, x_dot, theta_dot, xi]: the first states of every prediction model."""


def discretise(a: np.ndarray, b: np.ndarray, sample_time: float) -> tuple[np.ndarray, np.ndarray]:
    """(A_d, B_d) of ``z_dot = A z + B u`` with u held over ``sample_time`` (exact, by expm)."""
    n, m = b.shape
    block = np.zeros((n + m, n + m))
    block[:n, :n] = a
    block[:n, n:] = b
    e = scipy.linalg.expm(block * sample_time)
    return e[:n, :n], e[:n, n:]


def sampled_cost(a: np.ndarray, b: np.ndarray, q: np.ndarray, r: np.ndarray,
                 sample_time: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(Q_d, R_d, N_d): the continuous cost (8.15) over one sample with u held, exactly.

    ``int_0^Ts (z^T Q z + u^T R u) dt = z_k^T Q_d z_k + 2 z_k^T N_d u_k + u_k^T R_d u_k``
    along the zero-order-hold solution, by Van Loan's block exponential (C. F. Van
    Loan, "Computing integrals involving the matrix exponential", IEEE TAC 23(3), 1978;
    Franklin, Powell and Workman, "Digital Control of Dynamic Systems", section 9.4.4).
    """
    n, m = b.shape
    big = np.zeros((n + m, n + m))
    big[:n, :n] = a
    big[:n, n:] = b
    weight = scipy.linalg.block_diag(q, r)
    van_loan = np.zeros((2 * (n + m), 2 * (n + m)))
    van_loan[:n + m, :n + m] = -big.T
    van_loan[:n + m, n + m:] = weight
    van_loan[n + m:, n + m:] = big
    e = scipy.linalg.expm(van_loan * sample_time)
    w = e[n + m:, n + m:].T @ e[:n + m, n + m:]
    w = 0.5 * (w + w.T)
    return w[:n, :n], w[n:, n:], w[:n, n:]


def terminal_lqr(a_d: np.ndarray, b_d: np.ndarray, q_d: np.ndarray, r_d: np.ndarray,
                 n_d: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(P, K_d) of the discrete Riccati equation (with the cross weight N_d); ValueError if
    there is no stabilising P. ``u = -K_d z``,
    K_d = (R_d + B_d^T P B_d)^-1 (B_d^T P A_d + N_d^T)."""
    if n_d is None:
        n_d = np.zeros(b_d.shape)
    try:
        p = scipy.linalg.solve_discrete_are(a_d, b_d, q_d, r_d, s=n_d)
    except (np.linalg.LinAlgError, ValueError) as exc:
        raise ValueError(f'the discrete Riccati equation has no stabilising solution: {exc}') \
            from exc
    k = np.linalg.solve(r_d + b_d.T @ p @ b_d, b_d.T @ p @ a_d + n_d.T)
    if not (np.all(np.isfinite(p)) and np.all(np.isfinite(k))) or \
            np.max(np.abs(np.linalg.eigvals(a_d - b_d @ k))) >= 1.0:
        raise ValueError('the terminal LQR gain does not stabilise the discretised model')
    return p, k


@dataclass(frozen=True)
class PredictionModel:
    """``s_{k+1} = A_d s_k + B_d u_k`` with stage cost ``s^T Q_d s + 2 s^T N_d u + u^T R_d u``.

    ``s = [z (5), F (if lag > 0), u_{k-l} .. u_{k-1} (l commands in flight)]``.
    """

    a_d: np.ndarray
    b_d: np.ndarray
    q_d: np.ndarray
    r_d: np.ndarray
    n_d: np.ndarray
    lag: float
    """tau [s] of the actuator's first-order lag (0: none, no F state)."""
    in_flight: int
    """l, commands in flight in the state (0: no dead time)."""

    @property
    def states(self) -> int:
        return self.a_d.shape[0]

    @property
    def actuator_slice(self) -> slice:
        """The states after z: the lag's F and the commands in flight."""
        return slice(PLANT_STATES, self.states)


def prediction_model(a: np.ndarray, b: np.ndarray, q: np.ndarray, r: float, sample_time: float,
                     lag: float = 0.0, dead_time: float = 0.0) -> PredictionModel:
    """The sampled model of the module docstring for the continuous (A, B) of z and weights.

    ``q`` is the diagonal of Q on z (length 5), ``r`` the weight on the command.
    """
    if lag < 0.0 or dead_time < 0.0 or not (math.isfinite(lag) and math.isfinite(dead_time)):
        raise ValueError(f'lag ({lag!r}) and dead time ({dead_time!r}) must be finite and >= 0')
    n = a.shape[0]
    weights = np.diag(np.asarray(q, dtype=float))
    if lag > 0.0:  # F joins the state: z_dot = A z + B F, tau F_dot = u - F
        a_c = np.zeros((n + 1, n + 1))
        a_c[:n, :n], a_c[:n, n] = a, b[:, 0]
        a_c[n, n] = -1.0 / lag
        b_c = np.zeros((n + 1, 1))
        b_c[n, 0] = 1.0 / lag
        weights = scipy.linalg.block_diag(weights, 0.0)
    else:
        a_c, b_c = a, b
    q_d, r_d, n_d = sampled_cost(a_c, b_c, weights, np.array([[float(r)]]), sample_time)
    ts = float(sample_time)
    in_flight = int(math.ceil(dead_time / ts - 1e-9)) if dead_time > 0.0 else 0
    if in_flight == 0:
        a_d, b_d = discretise(a_c, b_c, ts)
        return PredictionModel(a_d, b_d, q_d, r_d, n_d, float(lag), 0)
    fraction = dead_time - (in_flight - 1) * ts  # d' in (0, Ts]
    phi = discretise(a_c, b_c, ts)[0]
    # Over one sample the older command u_{k-l} acts for the first d', the newer for the rest.
    phi_newer, gamma_0 = discretise(a_c, b_c, ts - fraction)
    gamma_1 = phi_newer @ discretise(a_c, b_c, fraction)[1]
    m = a_c.shape[0]
    total = m + in_flight
    a_d = np.zeros((total, total))
    b_d = np.zeros((total, 1))
    a_d[:m, :m] = phi
    a_d[:m, m] = gamma_1[:, 0]                  # u_{k-l}, the oldest in flight
    if in_flight == 1:
        b_d[:m, 0] = gamma_0[:, 0]              # u_{k-l+1} = u_k
    else:
        a_d[:m, m + 1] = gamma_0[:, 0]
        for i in range(in_flight - 1):          # the queue moves on by one
            a_d[m + i, m + i + 1] = 1.0
    b_d[total - 1, 0] = 1.0                     # u_k joins the queue's end
    q_big = scipy.linalg.block_diag(q_d, np.zeros((in_flight, in_flight)))
    return PredictionModel(a_d, b_d, q_big, r_d, np.zeros((total, 1)), float(lag), in_flight)
