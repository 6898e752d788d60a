"""The quadratic program of the ``mpc`` stabiliser: built once, solved every cycle.

The model is :mod:`.mpc_model`'s, the terminal cost the discrete Riccati
solution P of the same model and weights (the discrete (8.18)), so without
an active constraint the first move is the terminal LQR's ``-K_d s_0``
(Scokaert and Rawlings, IEEE TAC 43(8), 1998). The first ``free_steps``
forces are moves of their own with exact bounds; after them ``u_k = -K_d s_k
+ c_j`` (Rossiter, Kouvaritakis and Rice, Automatica 34(1), 1998), c held
over ``block`` steps, the cost-to-go from there ``s^T P s + sum c^T (R_d +
B_d^T P B_d) c``. Every later force and the rail guard's stopping point ``x +
t_b x_dot`` are soft with exact penalties (Kerrigan and Maciejowski, 2000):
always feasible, the hard-constrained solution whenever one exists. A cycle
writes only the bounds, ``G s_0`` and the cost's linear term into
preallocated vectors and warm-starts (:mod:`.mpc_solvers`). A failed or late
solve gives the previous plan shifted by one step. The formulation and its
measurements: docs/controllers.md, the ``mpc`` section. No ROS import.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any, ClassVar, Iterator

import numpy as np

from .mpc_model import PredictionModel, terminal_lqr
from .mpc_solvers import BACKENDS, SOLVERS

INFINITY = 1e30
"""A bound that is not one (DAQP's and OSQP's infinity)."""

QP = 'qp'
PLAN = 'plan'
LQR = 'lqr'
NONE = 'none'
SOURCES = (QP, PLAN, LQR, NONE)
"""Where a cycle's force came from: this cycle's QP, the previous plan shifted, the terminal
LQR clipped to the bounds (a failure before any plan of this activation), none (the plan is
used up: every solve of a whole horizon failed)."""


@dataclass(frozen=True)
class QpSettings:
    """What fixes the QP's data (everything but s_0, the bounds and the warm start)."""

    horizon: int
    """N, prediction steps."""
    force_min: float
    """u_min [N]: the default bound of every step (the raw force, before the feedforward)."""
    force_max: float
    """u_max [N]."""
    position_low: float
    """x_lo - x* [m]: the lowest cart position, relative to the reference."""
    position_high: float
    """x_hi - x* [m]."""
    rail_penalty: float
    """rho, the exact penalty's weight on the rail slacks [cost per m]."""
    solver: str = 'daqp'
    budget: float = 0.001
    """Solve time [s] above which the result is not used (the shifted plan instead); 0: no
    budget (a simulated loop, whose wall time says nothing of the plant)."""
    block: int = 1
    """Steps a correction c to the terminal LQR is held, after the free moves."""
    free_steps: int = 1
    """F, the first steps whose forces are moves of their own (each bounded exactly)."""
    braking_time: float = 0.0
    """[s] The rail rows bound ``x_k - x* + braking_time x_dot_k`` (a linear bound of the rail
    guard's stopping position) instead of the cart position alone."""
    rail_tolerance: float = 0.0
    """[m] The first this much of the rail slack of the first ``RAIL_GROUP`` steps costs only
    ``rail_tolerance_penalty``: a cart at rest on the boundary may move towards it by a few
    millimetres, as it must to come back (the pendulum first leans away), while beyond it,
    and later in the horizon, rho keeps the plan inside."""
    rail_tolerance_penalty: float = 1e4
    """rho_t [cost per m] of the slack within ``rail_tolerance``."""
    force_penalty: float = 1e6
    """rho_F, the exact l_inf penalty on sigma [cost per N]: as the rail's beyond its
    tolerance, so that a plan with no bounded solution still keeps its forces inside the
    amplifier (1 N outside it weighs like 1 m of rail)."""


@dataclass
class Solution:
    """One cycle's answer of :meth:`CondensedQp.solve`."""

    force: float
    """u_0 [N]: the QP's first move, else the shifted plan's (see ``source``)."""
    ok: bool
    """The solver reported an optimum within the budget."""
    solve_time: float
    """Wall time of the solve with its Python calls [s] (perf_counter)."""
    reason: str = ''
    source: str = QP
    """One of :data:`SOURCES`."""


class CondensedQp:
    """The condensed MPC QP of the module docstring, built once for fixed settings."""

    constructions: ClassVar[int] = 0
    """QPs built in this process (read by the tests: once per configure, never per cycle)."""

    RAIL_STEP: ClassVar[int] = 5
    """[steps] After the free steps the rail is checked this often."""

    RAIL_GROUP: ClassVar[int] = 10
    """[steps] One rail slack for the checks of each this many steps (l_inf within, l1 across)."""

    SLACK_WEIGHT: ClassVar[float] = 1e-3
    """A small quadratic weight on the slacks, so that H is positive definite (DAQP, qpOASES)."""

    PIECE_STEPS: ClassVar[int] = 50
    """[steps] The condensing of this many steps is one piece of :meth:`in_pieces`."""

    def __init__(self, model: PredictionModel, settings: QpSettings, *,
                 deferred: bool = False) -> None:
        """Built at once, or with ``deferred`` only by driving :attr:`_pieces` (what
        :meth:`in_pieces` does, which hands the QP out only when it is whole)."""
        self._pieces: Iterator[None] = self._construct(model, settings)
        if not deferred:
            for _ in self._pieces:
                pass

    @classmethod
    def in_pieces(cls, model: PredictionModel,
                  settings: QpSettings) -> Iterator['CondensedQp | None']:
        """The construction of ``CondensedQp(model, settings)`` a piece at a time: the terminal
        Riccati solution, the condensing of :attr:`PIECE_STEPS` steps, the constraint rows,
        the solver's set-up (each about a millisecond); None after each, the QP last. A loop
        builds one between its cycles so (:meth:`.controllers.mpc.MpcStabilizer.standby`)."""
        qp = cls(model, settings, deferred=True)
        yield from qp._pieces
        yield qp

    def _construct(self, model: PredictionModel, settings: QpSettings) -> Iterator[None]:
        """The body of :meth:`__init__`, pausing between the pieces of :meth:`in_pieces`."""
        type(self).constructions += 1
        big_n, free, block = int(settings.horizon), int(settings.free_steps), int(settings.block)
        if big_n < 1:
            raise ValueError(f'horizon must be >= 1, got {big_n}')
        if not 1 <= free <= big_n:
            raise ValueError(f'free_steps must be in [1, horizon], got {free}')
        if not 1 <= block <= big_n:
            raise ValueError(f'block must be in [1, horizon], got {block}')
        if settings.solver not in SOLVERS:
            raise ValueError(f'unknown QP solver {settings.solver!r}; one of {list(SOLVERS)}')
        if not settings.force_min < 0.0 < settings.force_max:
            raise ValueError(f'the force bounds [{settings.force_min:g}, {settings.force_max:g}] N '
                             'must contain 0')
        if not settings.position_low < 0.0 < settings.position_high:
            raise ValueError(f'the reference must lie inside the rail bounds (x - x* in '
                             f'[{settings.position_low:g}, {settings.position_high:g}] m)')
        self.settings, self.model = settings, model
        a_d, b_d = model.a_d, model.b_d
        n = a_d.shape[0]
        self.p, self.gain = terminal_lqr(a_d, b_d, model.q_d, model.r_d, model.n_d)
        k_row = self.gain_row = self.gain[0].copy()
        """K_d: the terminal LQR, u = -K_d s."""
        yield None
        phi = a_d - b_d @ self.gain
        starts = list(range(free, big_n, block))      # the blocks of c after the free moves
        m = free + len(starts)                        # moves: u_0 .. u_{F-1}, c_1 .. c_B
        move_of = list(range(free)) + [free + (k - free) // block for k in range(free, big_n)]
        # Propagate s_k = mz s_0 + mv v for the moves v, accumulating the cost's Hessian
        # and its part linear in s_0 (J = 1/2 v^T H v + v^T G_f s_0 + const).
        mz, mv = np.eye(n), np.zeros((n, m))
        q_d, r_d, n_d = model.q_d, float(model.r_d[0, 0]), model.n_d[:, 0]
        h = np.zeros((m, m))
        g_f = np.zeros((m, n))
        self.force_z, self.force_c = np.zeros((big_n, n)), np.zeros((big_n, m))
        position_z, position_c, position_steps = [], [], []
        lead = float(settings.braking_time)
        weight = 2.0 * float(r_d + b_d[:, 0] @ self.p @ b_d[:, 0])
        for k in range(big_n + 1):
            if k and (k <= free or (k - free) % self.RAIL_STEP == 0 or k == big_n):
                position_steps.append(k)  # the rail: at every free step, then every RAIL_STEP
                position_z.append(mz[0] + lead * mz[2])
                position_c.append(mv[0] + lead * mv[2])
            if k == free:  # from here on the terminal LQR's cost-to-go and its corrections
                h += 2.0 * mv.T @ self.p @ mv
                g_f += 2.0 * mv.T @ self.p @ mz
            if k == big_n:
                break
            if k and k % self.PIECE_STEPS == 0:
                yield None
            j = move_of[k]
            if k < free:   # u_k = v_j: stage cost s^T Q_d s + 2 s^T N_d u + R_d u^2
                qv = q_d @ mv
                h += 2.0 * mv.T @ qv
                h[:, j] += 2.0 * mv.T @ n_d
                h[j, :] += 2.0 * n_d @ mv
                h[j, j] += 2.0 * r_d
                g_f += 2.0 * mv.T @ q_d @ mz
                g_f[j] += 2.0 * n_d @ mz
                self.force_c[k, j] = 1.0
                mz, mv = a_d @ mz, a_d @ mv
                mv[:, j] += b_d[:, 0]
            else:          # u_k = -K_d s_k + c_j
                h[j, j] += weight
                self.force_z[k] = -k_row @ mz
                self.force_c[k] = -k_row @ mv
                self.force_c[k, j] += 1.0
                mz, mv = phi @ mz, phi @ mv
                mv[:, j] += b_d[:, 0]
        self.cost_map = g_f
        """The cost's linear term is cost_map s_0 (per cycle, with the slacks' penalties)."""
        yield None
        later = list(range(free, big_n))
        groups = [(k - 1) // self.RAIL_GROUP for k in position_steps]
        n_p, n_o, n_b = groups[-1] + 1, len(later), len(starts)
        n_t = 1 if settings.rail_tolerance > 0.0 else 0
        # w = [v (m moves), one rail slack a group of steps (n_p), one slack a block of c (n_b),
        #      the tolerated part of the first group's rail slack (n_t, up to rail_tolerance)]
        n_s = n_p + n_b + n_t
        nv = m + n_s
        self.h = np.zeros((nv, nv))
        self.h[:m, :m] = 0.5 * (h + h.T)
        self.h[m:, m:] = self.SLACK_WEIGHT * np.eye(n_s)
        slack_p = np.zeros((len(position_steps), n_s))
        slack_p[np.arange(len(position_steps)), groups] = 1.0
        if n_t:  # the near future only: the first group's points
            near = [i for i, group in enumerate(groups) if group == 0]
            slack_p[near, n_p + n_b] = 1.0
        slack_o = np.zeros((n_o, n_s))
        for i, k in enumerate(later):
            slack_o[i, n_p + move_of[k] - free] = 1.0
        position_z, position_c = np.array(position_z), np.array(position_c)
        soft_c = self.force_c[later]
        self.state_map = np.vstack([self.force_z[later], self.force_z[later],
                                    position_z, position_z])
        """Each row's part that s_0 gives: row(w) + state_map s_0 is the constrained quantity."""
        self.a = np.vstack([np.hstack([soft_c, -slack_o]), np.hstack([soft_c, slack_o]),
                            np.hstack([position_c, -slack_p]), np.hstack([position_c, slack_p])])
        n_r = len(position_steps)
        self.bound_low = np.concatenate([np.full(n_o, -INFINITY), np.full(n_o, settings.force_min),
                                         np.full(n_r, -INFINITY),
                                         np.full(n_r, settings.position_low)])
        self.bound_high = np.concatenate([np.full(n_o, settings.force_max), np.full(n_o, INFINITY),
                                          np.full(n_r, settings.position_high),
                                          np.full(n_r, INFINITY)])
        self._later_rows = n_o
        self.n_vars, self.n_rows, self.horizon, self.moves, self.free = \
            nv, self.a.shape[0], big_n, m, free
        self.variable_low = np.array([settings.force_min] * free + [-INFINITY] * n_b
                                     + [0.0] * n_s)
        self.variable_high = np.array([settings.force_max] * free + [INFINITY] * (n_b + n_p + n_b)
                                      + [settings.rail_tolerance] * n_t)
        self.penalty = np.zeros(nv)
        self.penalty[m:m + n_p] = settings.rail_penalty
        self.penalty[m + n_p:m + n_p + n_b] = settings.force_penalty
        self.penalty[m + n_p + n_b:] = settings.rail_tolerance_penalty
        self.f = self.penalty.copy()
        self.row_low = self.bound_low.copy()
        self.row_high = self.bound_high.copy()
        self._offset = np.zeros(self.n_rows)
        self._z = np.zeros(n)
        self._plan_z = np.zeros(n)
        self._plan_c = np.zeros(m)
        self._plan_age = -1                                 # no plan
        yield None
        self.backend = BACKENDS[settings.solver](self)

    def unconstrained_force(self, s0: Any) -> float:
        """The terminal LQR's force -K_d s_0 [N]."""
        return -float(self.gain_row @ np.asarray(s0, dtype=float))

    def predicted_forces(self) -> np.ndarray:
        """u_0 .. u_{N-1} [N] of the last plan (from the cycle it was solved in)."""
        return self.force_z @ self._plan_z + self.force_c @ self._plan_c

    def reset(self) -> None:
        """Forget the warm start and the plan (a new activation starts cold)."""
        self.backend.reset()
        self._plan_age = -1

    def solve(self, s0: Any, first: tuple[float, float] | None = None,
              later: tuple[float, float] | None = None) -> Solution:
        """The first move for ``s0``; the shifted previous plan if the solve fails or is late.

        ``first`` = (u_lo, u_hi) bounds this cycle's move, ``later`` every later step of the
        horizon [N] (default: the settings' for both).
        """
        clock = time.perf_counter
        start = clock()
        z = self._z
        z[:] = s0
        s = self.settings
        first = first or (s.force_min, s.force_max)
        later = later or (s.force_min, s.force_max)
        o = self._later_rows
        self.bound_high[:o] = later[1]
        self.bound_low[o:2 * o] = later[0]
        self.variable_low[:self.free] = later[0]
        self.variable_high[:self.free] = later[1]
        self.variable_low[0], self.variable_high[0] = first
        np.dot(self.state_map, z, out=self._offset)
        np.subtract(self.bound_high, self._offset, out=self.row_high)
        np.subtract(self.bound_low, self._offset, out=self.row_low)
        np.dot(self.cost_map, z, out=self.f[:self.moves])
        try:
            w, ok, reason = self.backend.solve()
        except Exception as error:  # a solver that raises is a failed solve, not a fault
            w, ok, reason = None, False, f'{type(error).__name__}: {error}'
            self.backend.reset()
        force = math.nan
        if ok:
            force = float(w[0])
            if not math.isfinite(force):
                ok, reason = False, 'non-finite solution'
        elapsed = clock() - start
        if ok and 0.0 < s.budget < elapsed:
            ok, reason = False, f'over budget ({elapsed * 1e6:.0f} us)'
        if ok:
            self._plan_z[:] = z
            self._plan_c[:] = w[:self.moves]
            self._plan_age = 0
            return Solution(force, True, elapsed, '', QP)
        if w is not None and not math.isfinite(force):
            self.backend.reset()
        elif w is None:
            self.backend.failed()  # a late solution keeps its warm start
        low, high = first
        if self._plan_age < 0:  # nothing planned since the activation
            force = min(max(-float(self.gain_row @ z), low), high)
            return Solution(force, False, elapsed, reason, LQR)
        self._plan_age += 1
        age = self._plan_age
        if age >= self.horizon:
            return Solution(math.nan, False, elapsed, reason, NONE)
        force = float(self.force_z[age] @ self._plan_z + self.force_c[age] @ self._plan_c)
        return Solution(min(max(force, low), high), False, elapsed, reason, PLAN)
