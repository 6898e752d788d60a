"""The quadratic program of the ``mpc`` stabiliser: built once, solved every cycle.

The model is the upright linearisation (8.13)/(8.14) augmented with the
integral of the cart error (as the LQI of :mod:`.controllers.lqg`), the state
``z = [x - x*, theta_w, x_dot, theta_dot, xi]``, discretised exactly at the
control period Ts (zero-order hold, :func:`discretise`)::

    z_{k+1} = A_d z_k + B_d u_k,   [[A_d, B_d], [0, 1]] = expm([[A_aug, B_aug], [0, 0]] Ts)

The cost (8.15) over one sample with u held is integrated exactly too
(:func:`sampled_cost`, Van Loan): ``z^T Q_d z + 2 z^T N_d u + u^T R_d u``. Over
N steps, with the terminal cost of the discrete Riccati equation of the same
model and weights (the discrete counterpart of (8.18), :func:`terminal_lqr`)::

    J = sum_{k=0}^{N-1} (z_k^T Q_d z_k + 2 z_k^T N_d u_k + u_k^T R_d u_k) + z_N^T P z_N
    K_d = (R_d + B_d^T P B_d)^-1 (B_d^T P A_d + N_d^T)     (the terminal LQR, u = -K_d z)

With that P the finite-horizon cost equals the infinite-horizon one as long
as no constraint is active, so the MPC's first move is exactly the terminal
LQR's ``-K_d z_0`` then (Scokaert and Rawlings, "Constrained linear quadratic
regulation", IEEE TAC 43(8), 1998; Mayne, Rawlings, Rao and Scokaert,
"Constrained model predictive control: stability and optimality",
Automatica 36, 2000): the unconstrained MPC *is* the LQR, the constraints are
what it adds.

Pre-stabilised (closed-loop paradigm) predictions: the moves are written as
``u_k = -K_d z_k + c_k`` (Rossiter, Kouvaritakis and Rice, "A numerically
robust state-space approach to stable-predictive control strategies",
Automatica 34(1), 1998), so the predictions use the stable ``A_d - B_d K_d``
instead of powers of the open-loop unstable A_d, and completing the square
with the Riccati equation gives

    J = z_0^T P z_0 + sum_k c_k^T (R_d + B_d^T P B_d) c_k

a *diagonal* Hessian and no linear term: the unconstrained optimum is c = 0
whatever z_0. The corrections are held over blocks of ``block`` steps (move
blocking; c = 0 is still in the blocked space, so the equality with the LQR
stays exact). Condensed (dense) QP in ``w = [c_1 .. c_M, s_1 .. s_S]``::

    minimise    1/2 w^T H w + rho sum_i s_i
    subject to  u_min <= -K_d z_k + c_k <= u_max             at each block's first step (hard)
                lo - s_i <= x_k + t_b x_dot_k <= hi + s_i    at each block's last step (soft)
                s_i >= 0

The rows are ``A w + G z_0`` with A, G and H computed once
(:class:`CondensedQp`); a cycle only computes ``G z_0`` into a preallocated
vector, subtracts it from the bounds and warm-starts the solver from the
previous working set. ``x + t_b x_dot`` (``braking_time``) is a linear upper
bound of the rail guard's stopping position, so the cart is kept where the
guard does not need to bend the command. Optionally (``tail``) the terminal
LQR's predicted cart positions and forces are checked over further steps
after the horizon (soft too; Gilbert and Tan's output admissible set over a
finite tail).

The rail is a *soft* constraint with an exact l1 penalty (Kerrigan and
Maciejowski, "Soft constraints and exact penalty functions in model
predictive control", UKACC Control 2000): each constrained point has its own
slack, and the linear weight ``rho`` on them is larger than the multipliers
of the hard-constrained problem, so whenever the rail can be kept the
solution is the hard-constrained one, and when it cannot (a push too large)
the QP is still feasible and the total excursion is minimised.

Solvers (``solver``, :data:`SOLVERS`): DAQP's own Python wheel
(``daqp.Model``: set up once, ``update`` of the vectors, warm start from the
last working set, no allocation in its solve), OSQP's wheel (``update`` of
the vectors, warm-started ADMM), and the QP solvers bundled with CasADi
(``casadi.conic``: DAQP, qpOASES, OSQP, ProxQP), which take the whole
problem at each call. Which is fastest is measured
(``python -m cartpole_tools.bench.mpc_solve``, docs/controllers.md).

The number of QPs built is counted in :attr:`CondensedQp.constructions` (a
class attribute: a test checks one construction per configure and none per
cycle). No ROS import.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
import scipy.linalg

INFINITY = 1e30
"""A bound that is not one (DAQP's and OSQP's infinity)."""

SOLVERS = ('daqp', 'osqp', 'casadi_daqp', 'casadi_qpoases', 'casadi_osqp', 'casadi_proxqp')
"""The QP solvers a :class:`CondensedQp` can use (see the module docstring). CasADi's HPIPM
is not one: its interface takes a multistage (OCP-structured) QP and refuses the dense
condensed one (``specified structure of A does not correspond to what the interface can
handle``)."""


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
    The discrete LQR of (A_d, B_d, Q_d, R_d, N_d) is the sampled-data optimum of the
    continuous cost (on this model its gain is about 9 % below the continuous LQI's of
    the same weights, the price of the 5 ms hold; Q Ts, R Ts without N_d gives the same
    to 0.1 %).
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
class QpSettings:
    """What fixes the QP's data (everything but z_0 and the cycle's warm start)."""

    horizon: int
    """N, prediction steps."""
    force_min: float
    """u_min [N] (the raw force, before the manager's feedforward)."""
    force_max: float
    """u_max [N]."""
    position_low: float
    """x_lo - x* [m]: the lowest cart position, relative to the reference."""
    position_high: float
    """x_hi - x* [m]."""
    rail_penalty: float
    """rho, the exact penalty's weight on the slack [cost per m]."""
    solver: str = 'daqp'
    budget: float = 0.002
    block: int = 1
    """Steps per free move (move blocking); 1: every step a free move."""
    braking_time: float = 0.0
    """[s] The rows bound ``x_k - x* + braking_time x_dot_k`` (a linear bound of the rail
    guard's stopping position) instead of the cart position alone."""
    tail: int = 0
    """T, steps after the horizon over which the terminal LQR's predicted forces and cart
    positions are checked (soft), every ``block`` steps."""
    """Solve time [s] above which the result is not used (the terminal LQR instead)."""


@dataclass
class Solution:
    """One cycle's answer of :meth:`CondensedQp.solve`."""

    force: float
    """u_0 [N]: the QP's first move, or the terminal LQR's if ``ok`` is False."""
    ok: bool
    """The solver reported an optimum within the budget."""
    solve_time: float
    """Wall time of the solve with its Python calls [s] (perf_counter)."""
    reason: str = ''


class CondensedQp:
    """The condensed MPC QP of the module docstring, built once for fixed settings.

    Parameters
    ----------
    a_d, b_d
        The discretised augmented model.
    q_d, r_d
        Stage weights (``Q Ts``, ``R Ts``).
    settings
        Horizon, bounds, penalty, solver, budget.
    """

    constructions: ClassVar[int] = 0
    """QPs built in this process (read by the tests: once per configure, never per cycle)."""

    FORCE_SCALE: ClassVar[float] = 0.01
    """[N per m] A tail force's excess counts like a cart excursion this many times smaller."""

    SLACK_WEIGHT: ClassVar[float] = 1e-3
    """A small quadratic weight on the slack, so that H is positive definite (DAQP, qpOASES)."""

    def __init__(self, a_d: np.ndarray, b_d: np.ndarray, q_d: np.ndarray, r_d: np.ndarray,
                 settings: QpSettings, n_d: np.ndarray | None = None) -> None:
        type(self).constructions += 1
        n = a_d.shape[0]
        big_n = int(settings.horizon)
        if big_n < 1:
            raise ValueError(f'horizon must be >= 1, got {big_n}')
        if not 1 <= int(settings.block) <= big_n:
            raise ValueError(f'block must be in [1, horizon], got {settings.block}')
        if settings.solver not in SOLVERS:
            raise ValueError(f'unknown QP solver {settings.solver!r}; one of {list(SOLVERS)}')
        if not settings.force_min < 0.0 < settings.force_max:
            raise ValueError(f'the force bounds [{settings.force_min:g}, {settings.force_max:g}] N '
                             'must contain 0')
        if not settings.position_low < 0.0 < settings.position_high:
            raise ValueError(f'the reference must lie inside the rail bounds (x - x* in '
                             f'[{settings.position_low:g}, {settings.position_high:g}] m)')
        self.settings = settings
        self.p, self.gain = terminal_lqr(a_d, b_d, q_d, r_d, n_d)
        self.gain_row = self.gain[0].copy()
        """K_d: the terminal LQR, u = -K_d z (also the fall-back law)."""
        # Pre-stabilised prediction: u_k = -K_d z_k + c_k, so z_{k+1} = Phi z_k + B_d c_k with
        # the stable Phi = A_d - B_d K_d; Z = S_z z_0 + S_c C for z_0 .. z_{N+T} (c_k = 0 from N).
        block = int(settings.block)
        tail = int(settings.tail)
        total = big_n + tail
        phi = a_d - b_d @ self.gain
        s_z = np.zeros(((total + 1) * n, n))
        s_c = np.zeros(((total + 1) * n, big_n))
        power = np.eye(n)
        columns = []  # Phi^j B_d
        for k in range(total + 1):
            s_z[k * n:(k + 1) * n] = power
            columns.append(power @ b_d[:, 0])
            power = phi @ power
        for k in range(1, total + 1):
            for j in range(min(k, big_n)):
                s_c[k * n:(k + 1) * n, j] = columns[k - 1 - j]
        # Move blocking: c_k = c_j for k in block j (``block`` steps each, the last one
        # shorter). c = 0 stays the unconstrained optimum.
        starts = list(range(0, big_n, block))
        m = len(starts)
        sizes = np.array([min(block, big_n - k) for k in starts], dtype=float)
        spread = np.zeros((big_n, m))
        for j, k in enumerate(starts):
            spread[k:k + block, j] = 1.0
        s_c = s_c @ spread
        # Constraint points: the force at each block's first step (hard: c_j can always meet
        # it); the cart position at each block's last step and, every ``block`` steps, over
        # the tail of T steps under the terminal LQR (Gilbert and Tan's output admissible
        # set, checked over a finite tail); the tail's forces too. Position and tail-force
        # rows are soft, each point with its own slack s_i >= 0 (l1 exact penalty).
        ends = [min(k + block, big_n) for k in starts]
        tail_points = list(range(big_n + block, total + 1, block))
        k_row = self.gain[0]

        def force_rows(steps):
            return (np.array([-k_row @ s_z[k * n:(k + 1) * n] for k in steps]).reshape(-1, n),
                    np.array([-k_row @ s_c[k * n:(k + 1) * n] for k in steps]).reshape(-1, m))

        hard_z, hard_c = force_rows(starts)
        hard_c = hard_c + np.eye(m)
        position_steps = ends + tail_points
        # The constrained "position" is the rail guard's stopping point, linearised:
        # x_k + braking_time x_dot_k (state entries 0 and 2).
        lead = float(settings.braking_time)
        position_z = np.array([s_z[k * n] + lead * s_z[k * n + 2] for k in position_steps])
        position_c = np.array([s_c[k * n] + lead * s_c[k * n + 2] for k in position_steps])
        tail_z, tail_c = force_rows(tail_points)
        # Tail forces are compared with the position's slack in metres: scaled by SOFT_FORCE.
        tail_z, tail_c = tail_z / self.FORCE_SCALE, tail_c / self.FORCE_SCALE
        n_p, n_t = len(position_steps), len(tail_points)
        n_s = n_p + n_t
        # J = z_0^T P z_0 + sum_k c_k^T (R_d + B_d^T P B_d) c_k: diagonal, no term in z_0.
        nv = m + n_s
        self.h = np.zeros((nv, nv))
        weight = 2.0 * float(r_d[0, 0] + b_d[:, 0] @ self.p @ b_d[:, 0])
        self.h[:m, :m] = np.diag(weight * sizes)
        self.h[m:, m:] = self.SLACK_WEIGHT * np.eye(n_s)
        # Rows: hard forces; positions upper [x_k - s_i <= x_hi], lower [x_k + s_i >= x_lo];
        # tail forces upper and lower (scaled) with their slacks.
        slack_p = np.zeros((n_p, n_s))
        slack_p[:, :n_p] = np.eye(n_p)
        slack_t = np.zeros((n_t, n_s))
        slack_t[:, n_p:] = np.eye(n_t)
        self.state_map = np.vstack([hard_z, position_z, position_z, tail_z, tail_z])
        """Each row's part that z_0 gives: row(w) + state_map z_0 is the constrained quantity."""
        self.a = np.vstack([
            np.hstack([hard_c, np.zeros((m, n_s))]),
            np.hstack([position_c, -slack_p]), np.hstack([position_c, slack_p]),
            np.hstack([tail_c, -slack_t]), np.hstack([tail_c, slack_t])])
        f_low, f_high = settings.force_min / self.FORCE_SCALE, settings.force_max / self.FORCE_SCALE
        self.bound_low = np.concatenate([
            np.full(m, settings.force_min), np.full(n_p, -INFINITY),
            np.full(n_p, settings.position_low), np.full(n_t, -INFINITY), np.full(n_t, f_low)])
        self.bound_high = np.concatenate([
            np.full(m, settings.force_max), np.full(n_p, settings.position_high),
            np.full(n_p, INFINITY), np.full(n_t, f_high), np.full(n_t, INFINITY)])
        n_rows = self.a.shape[0]
        self.n_vars, self.n_rows, self.horizon, self.moves = nv, n_rows, big_n, m
        self.variable_low = np.array([-INFINITY] * m + [0.0] * n_s)
        self.variable_high = np.full(nv, INFINITY)
        # Per-cycle buffers (no allocation in solve() beyond numpy's small temporaries).
        self.f = np.zeros(nv)
        self.f[m:] = settings.rail_penalty
        self.row_low = self.bound_low.copy()
        self.row_high = self.bound_high.copy()
        self._offset = np.zeros(n_rows)
        self._z = np.zeros(n)
        self.backend = _BACKENDS[settings.solver](self)

    def unconstrained_force(self, z0: Any) -> float:
        """The terminal LQR's force -K_d z_0 [N] (the fall-back)."""
        k = self.gain_row
        return -float(k @ np.asarray(z0, dtype=float))

    def first_force(self, c0: float) -> float:
        """u_0 = -K_d z_0 + c_0 [N] for the z_0 of this cycle."""
        return float(c0) - float(self.gain_row @ self._z)

    def reset(self) -> None:
        """Forget the warm start (a new activation starts cold)."""
        self.backend.reset()

    def solve(self, z0: Any, force_min: float | None = None,
              force_max: float | None = None) -> Solution:
        """The first move for the state ``z0``, the fall-back LQR's if the solve fails or is late.

        ``force_min``/``force_max`` replace this cycle's hard force bounds (the raw force
        range that depends on the feedforward the manager will add); default the settings'.
        """
        clock = time.perf_counter
        start = clock()
        z = self._z
        z[:] = z0
        m = self.moves
        s = self.settings
        self.bound_low[:m] = s.force_min if force_min is None else force_min
        self.bound_high[:m] = s.force_max if force_max is None else force_max
        np.dot(self.state_map, z, out=self._offset)
        np.subtract(self.bound_high, self._offset, out=self.row_high)
        np.subtract(self.bound_low, self._offset, out=self.row_low)
        try:
            force, ok, reason = self.backend.solve()
        except Exception as error:  # a solver that raises is a failed solve, not a fault
            force, ok, reason = math.nan, False, f'{type(error).__name__}: {error}'
        elapsed = clock() - start
        if ok and not math.isfinite(force):
            ok, reason = False, 'non-finite solution'
        if ok and elapsed > s.budget:
            ok, reason = False, f'over budget ({elapsed * 1e6:.0f} us)'
        if not ok:
            self.backend.reset()
            force = -float(self.gain_row @ z)
        return Solution(force, ok, elapsed, reason)


# -- solver back-ends -----------------------------------------------------------------------
class _DaqpBackend:
    """DAQP's wheel: ``daqp.Model`` set up once; each cycle ``update(f, bounds)`` and ``solve``.

    Warm start: the model keeps the last working set (``update`` without
    ``sense`` reuses it). Simple bounds come first in DAQP's bound vectors.
    """

    def __init__(self, qp: CondensedQp) -> None:
        import daqp
        self.qp = qp
        self.upper = np.concatenate([qp.variable_high, qp.row_high])
        self.lower = np.concatenate([qp.variable_low, qp.row_low])
        self.sense = np.zeros(qp.n_vars + qp.n_rows, dtype=np.int32)
        self.model = daqp.Model()
        self.model.settings = {'time_limit': qp.settings.budget}
        flag, _ = self.model.setup(qp.h, qp.f, qp.a, self.upper, self.lower, self.sense)
        if flag < 0:
            raise ValueError(f'DAQP refused the QP (setup exit flag {flag})')
        self._cold = False

    def reset(self) -> None:
        self._cold = True

    def solve(self) -> tuple[float, bool, str]:
        qp, nv = self.qp, self.qp.n_vars
        self.upper[nv:] = qp.row_high
        self.lower[nv:] = qp.row_low
        if self._cold:
            self.model.update(f=qp.f, bupper=self.upper, blower=self.lower, sense=self.sense)
            self._cold = False
        else:
            self.model.update(f=qp.f, bupper=self.upper, blower=self.lower)
        x, _, flag, _ = self.model.solve()
        if flag <= 0:
            return math.nan, False, f'DAQP exit flag {flag}'
        return self.qp.first_force(x[0]), True, ''


class _OsqpBackend:
    """OSQP's wheel: set up once with the sparse data; each cycle ``update(q, l, u)``.

    Warm start: ADMM starts from the last primal and dual iterate (``warm_starting``).
    """

    def __init__(self, qp: CondensedQp) -> None:
        import osqp
        import scipy.sparse as sparse
        self.qp = qp
        a = sparse.vstack([sparse.eye(qp.n_vars), sparse.csc_matrix(qp.a)]).tocsc()
        self.upper = np.concatenate([qp.variable_high, qp.row_high])
        self.lower = np.concatenate([qp.variable_low, qp.row_low])
        self.solver = osqp.OSQP()
        self.solver.setup(P=sparse.triu(qp.h).tocsc(), q=qp.f, A=a, l=self.lower, u=self.upper,
                          verbose=False, eps_abs=1e-7, eps_rel=1e-7, polishing=True,
                          warm_starting=True, max_iter=4000,
                          time_limit=qp.settings.budget)
        self._solved = osqp.SolverStatus.OSQP_SOLVED if hasattr(osqp, 'SolverStatus') else 1

    def reset(self) -> None:
        pass  # ADMM's warm start is only a starting point: a stale one costs iterations

    def solve(self) -> tuple[float, bool, str]:
        qp, nv = self.qp, self.qp.n_vars
        self.upper[nv:] = qp.row_high
        self.lower[nv:] = qp.row_low
        self.solver.update(q=qp.f, l=self.lower, u=self.upper)
        result = self.solver.solve()
        if result.info.status_val != self._solved:
            return math.nan, False, f'OSQP: {result.info.status}'
        return self.qp.first_force(result.x[0]), True, ''


class _CasadiBackend:
    """A QP solver bundled with CasADi (``casadi.conic``): the data go in at every call.

    Warm start: the previous primal and dual solution (``x0``, ``lam_x0``,
    ``lam_a0``), which the active-set solvers use as their initial guess.
    """

    PLUGINS: ClassVar[dict[str, tuple[str, dict]]] = {
        'casadi_daqp': ('daqp', {}),
        'casadi_qpoases': ('qpoases', {'printLevel': 'none', 'sparse': False,
                                       'schur': False}),
        'casadi_osqp': ('osqp', {'osqp': {'verbose': False, 'eps_abs': 1e-7, 'eps_rel': 1e-7,
                                          'polish': True, 'max_iter': 4000},
                                 'warm_start_primal': True, 'warm_start_dual': True}),
        'casadi_proxqp': ('proxqp', {'proxqp': {'eps_abs': 1e-9, 'verbose': False},
                                     'warm_start_primal': True, 'warm_start_dual': True}),
    }

    def __init__(self, qp: CondensedQp) -> None:
        import casadi
        self.qp = qp
        plugin, options = self.PLUGINS[qp.settings.solver]
        options = dict(options, error_on_fail=False, verbose=False)
        structure = {'h': casadi.Sparsity.dense(qp.n_vars, qp.n_vars),
                     'a': casadi.Sparsity.dense(qp.n_rows, qp.n_vars)}
        self.solver = casadi.conic('mpc', plugin, structure, options)
        self.h = casadi.DM(qp.h)
        self.a = casadi.DM(qp.a)
        self.lbx = casadi.DM(qp.variable_low)
        self.ubx = casadi.DM(qp.variable_high)
        self.reset()

    def reset(self) -> None:
        self.x0 = self.lam_x0 = self.lam_a0 = None

    def solve(self) -> tuple[float, bool, str]:
        qp = self.qp
        args = {'h': self.h, 'g': qp.f, 'a': self.a, 'lba': qp.row_low, 'uba': qp.row_high,
                'lbx': self.lbx, 'ubx': self.ubx}
        if self.x0 is not None:
            args.update(x0=self.x0, lam_x0=self.lam_x0, lam_a0=self.lam_a0)
        result = self.solver(**args)
        stats = self.solver.stats()
        if not stats.get('success', False):
            return math.nan, False, f'{qp.settings.solver}: {stats.get("return_status", "failed")}'
        self.x0, self.lam_x0, self.lam_a0 = result['x'], result['lam_x'], result['lam_a']
        return self.qp.first_force(float(result['x'][0])), True, ''


_BACKENDS = {'daqp': _DaqpBackend, 'osqp': _OsqpBackend,
             **{name: _CasadiBackend for name in _CasadiBackend.PLUGINS}}
