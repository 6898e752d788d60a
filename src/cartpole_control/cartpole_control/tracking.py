"""Time-varying LQR along a minimum-time plan: the gains the ``time_optimal`` swing-up tracks with.

The discrete model is the Jacobian of the plan's RK4 step (the model of
:mod:`cartpole_control.trajectory_optimization`) about each node of the plan;
the gains come from the backward Riccati recursion. No ROS import.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from .trajectory_optimization import MinimumTimeProblem, Trajectory, casadi_dynamics, casadi_step


def tracking_gains(problem: MinimumTimeProblem, trajectory: Trajectory, q: Sequence[float],
                   r: float, q_final: Sequence[float] | None = None) -> np.ndarray:
    """Time-varying LQR gains K_k (N, 4) along ``trajectory`` (u_k = F_k - K_k (x_k - xbar_k)).

    The discrete model is the Jacobian of the RK4 step over h = ``trajectory.dt`` at
    (xbar_k, Fbar_k): dx_{k+1} = A_k dx_k + B_k du_k; the gains come from the backward
    Riccati recursion with stage cost dx' Q dx + r du^2 and terminal cost ``q_final``.
    """
    import casadi as ca
    f = casadi_dynamics(problem.params, problem.friction)
    step = casadi_step(f, 1)
    s = ca.SX.sym('s', 4)
    u = ca.SX.sym('u')
    y = step(s, u, trajectory.dt)
    jac = ca.Function('linearised_step', [s, u], [ca.jacobian(y, s), ca.jacobian(y, u)])
    n = len(trajectory.forces)
    jm = jac.map(n)
    a_all, b_all = jm(trajectory.states[:-1].T, trajectory.forces.reshape(1, -1))
    a_all = np.array(a_all).reshape(4, n, 4)  # [i, k, j] = A_k[i, j]
    b_all = np.array(b_all)
    qm = np.diag(np.asarray(q, dtype=float))
    p_mat = np.diag(np.asarray(q_final if q_final is not None else q, dtype=float))
    gains = np.zeros((n, 4))
    for k in range(n - 1, -1, -1):
        a = a_all[:, k, :]
        b = b_all[:, k].reshape(4, 1)
        s_mat = r + (b.T @ p_mat @ b).item()
        kk = (b.T @ p_mat @ a) / s_mat
        gains[k] = kk.ravel()
        p_mat = qm + a.T @ p_mat @ (a - b @ kk)
        p_mat = 0.5 * (p_mat + p_mat.T)
    return gains
