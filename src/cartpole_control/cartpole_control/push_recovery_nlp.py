"""The multiple-shooting NLP of a push recovery (CasADi + IPOPT), built once per problem.

The model (4.18) with a force on the cart and a torque on the pendulum,
friction smoothed as :func:`~cartpole_control.trajectory_optimization.casadi_dynamics`;
piecewise-constant force on the problem's grid, RK4 sub-steps, the rail and
angle constraints (and optionally the rail guard's braking envelope,
:mod:`cartpole_control.rail_guard`) sharing one slack. No ROS import.
"""
from __future__ import annotations

import functools
import math
import time

import numpy as np

from cartpole_core.model import CartPoleParameters, accelerations, torque_accelerations

from .push_problem import FEASIBILITY_TOLERANCE, GUARD_RESERVE, PushRecovery, PushRecoveryProblem
from .rail_guard import RailGuard
from .trajectory_optimization import SMOOTH_FRICTION_STEEPNESS, casadi_dynamics


def casadi_push_dynamics(params: CartPoleParameters, friction: bool = True,
                         steepness: float = SMOOTH_FRICTION_STEEPNESS):
    """CasADi Function ``f(s, F, tau) -> s_dot``: (4.18) with a force F on the cart and a
    torque tau on the pendulum, M(theta)^-1 [0, tau] added (as
    :func:`cartpole_core.model.torque_accelerations`); friction as
    :func:`~cartpole_control.trajectory_optimization.casadi_dynamics`."""
    import casadi as ca
    f = casadi_dynamics(params, friction, steepness)
    s = ca.SX.sym('s', 4)
    force = ca.SX.sym('F')
    torque = ca.SX.sym('tau')
    sn, cs = ca.sin(s[1]), ca.cos(s[1])
    m_p, l = params.m_p, params.l
    det = m_p * l * l * (params.m_c + m_p * sn ** 2)
    extra = ca.vertcat(0.0, 0.0, m_p * l * cs * torque / det, (params.m_c + m_p) * torque / det)
    return ca.Function('f_push', [s, force, torque], [f(s, force) + extra])


def _rk4(f, substep: float):
    """CasADi Function ``step(s, F, tau, h) -> s(h)``: RK4 in ``ceil(h / substep)`` steps."""
    import casadi as ca
    cache = {}

    def make(h: float):
        n = max(1, int(math.ceil(h / substep - 1e-9)))
        key = (round(h, 12), n)
        if key not in cache:
            s = ca.SX.sym('s', 4)
            force = ca.SX.sym('F')
            torque = ca.SX.sym('tau')
            y = s
            dt = h / n
            for _ in range(n):
                k1 = f(y, force, torque)
                k2 = f(y + 0.5 * dt * k1, force, torque)
                k3 = f(y + 0.5 * dt * k2, force, torque)
                k4 = f(y + dt * k3, force, torque)
                y = y + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
            cache[key] = ca.Function('step', [s, force, torque], [y])
        return cache[key]
    return make


class _RecoveryNLP:
    """The multiple-shooting NLP of one :class:`PushRecoveryProblem`, built once.

    Decision vector w = [P, sigma, X (4 x (N + 1), column-major), U (N)]. Two uses:

    - :meth:`elastic`: P fixed, minimise sigma (the slack of the rail and angle
      constraints): P is recoverable when the minimum is zero;
    - :meth:`maximise`: sigma fixed at 0, maximise P (the bound directly).

    Both add a tiny force-smoothness term (it makes the solution unique). ``symbolic``
    ``'SX'`` builds in seconds and solves fast; ``'MX'`` builds at once, solves slower.
    """

    SUBSTEP = 0.005
    """[s] Longest RK4 step inside an interval."""

    def __init__(self, problem: PushRecoveryProblem, max_iter: int = 500, symbolic: str = 'SX'):
        import casadi as ca
        self.problem = problem
        p = problem.params
        self.h = problem.grid()
        n = self.n = len(self.h)
        self.times = np.concatenate([[0.0], np.cumsum(self.h)])
        make = _rk4(casadi_push_dynamics(p, problem.friction), self.SUBSTEP)
        n_push = problem.pushed_intervals()
        sym = ca.MX.sym if symbolic == 'MX' else ca.SX.sym
        P = sym('P')
        sigma = sym('sigma')
        X = sym('X', 4, n + 1)
        U = sym('U', 1, n)
        weights = sym('weights', 2)  # (of sigma, of -P)
        push = P / problem.width
        gaps = []
        k = 0
        while k < n:  # runs of equal intervals share one mapped RK4 Function
            j = k
            while j < n and abs(self.h[j] - self.h[k]) < 1e-12 and (j < n_push) == (k < n_push):
                j += 1
            step = make(float(self.h[k])).map(j - k)
            pushed = k < n_push
            force = U[:, k:j] + (push if pushed and problem.target == 'cart' else 0.0)
            torque = ca.repmat(push if pushed and problem.target == 'pendulum' else 0.0, 1, j - k)
            gaps.append(ca.reshape(X[:, k + 1:j + 1] - step(X[:, k:j], force, torque), -1, 1))
            k = j
        inf = np.inf
        g = [ca.vertcat(*gaps)]
        lbg, ubg = [0.0] * (4 * n), [0.0] * (4 * n)
        self.n_gaps = 4 * n
        lo, hi = problem.rail_margin, p.travel - problem.rail_margin
        # The rail with slack: x_k - lo + sigma >= 0 and hi - x_k + sigma >= 0 (k >= 1).
        g += [ca.reshape(X[0, 1:] - lo + sigma, -1, 1), ca.reshape(hi - X[0, 1:] + sigma, -1, 1)]
        lbg += [0.0] * (2 * n)
        ubg += [inf] * (2 * n)
        if problem.guard:
            g += self._guard_envelope(problem, X, sigma)
            lbg += [0.0] * (2 * n)
            ubg += [inf] * (2 * n)
        if problem.max_angle is not None:
            a = problem.max_angle
            g += [ca.reshape(a + sigma - X[1, 1:], -1, 1), ca.reshape(a + sigma + X[1, 1:], -1, 1)]
            lbg += [0.0] * (2 * n)
            ubg += [inf] * (2 * n)
        # Upright at T (sin theta = 0, cos theta >= 0: any number of turns), at rest (bounds).
        g.append(ca.vertcat(ca.sin(X[1, n]), ca.cos(X[1, n])))
        lbg += [0.0, 0.0]
        ubg += [0.0, inf]
        self.lbg, self.ubg = np.array(lbg), np.array(ubg)
        self.x0 = np.array([problem.start_x, 0.0, 0.0, 0.0])
        lbx = np.full((n + 1, 4), -inf)
        ubx = np.full((n + 1, 4), inf)
        lbx[0] = ubx[0] = self.x0
        lbx[n, 2:] = ubx[n, 2:] = 0.0
        lbu, ubu = np.full(n, p.force_min), np.full(n, p.force_max)
        blind = self.times[:-1] < problem.reaction - 1e-9  # intervals starting before it sees
        lbu[blind] = ubu[blind] = 0.0
        self.lbw = np.concatenate([[0.0, 0.0], lbx.ravel(), lbu])
        self.ubw = np.concatenate([[inf, inf], ubx.ravel(), ubu])
        self.impulse_scale = 10.0 if problem.target == 'cart' else 0.1
        scale_u = max(p.force_max, -p.force_min)
        w = ca.vertcat(P, sigma, ca.reshape(X, -1, 1), ca.reshape(U, -1, 1))
        objective = (weights[0] * sigma - weights[1] * P / self.impulse_scale
                     + 1e-6 * ca.sumsqr(ca.diff(U, 1, 1) / scale_u) / n)
        self.solver = ca.nlpsol('push_recovery', 'ipopt',
                                {'x': w, 'p': weights, 'f': objective, 'g': ca.vertcat(*g)},
                                {'print_time': False,
                                 'ipopt': {'print_level': 0, 'sb': 'yes', 'max_iter': max_iter,
                                           'tol': 1e-8, 'acceptable_tol': 1e-6,
                                           'acceptable_iter': 10, 'mu_strategy': 'adaptive',
                                           'max_cpu_time': 60.0}})

    @staticmethod
    def _guard_envelope(problem: PushRecoveryProblem, X, sigma) -> list:
        """The rail guard's stopping positions inside its limiter's boundary, with slack:
        ``x_b,k - (m + r) + sigma >= 0`` and ``travel - m - r - x_b,k + sigma >= 0`` (k >= 1);
        the guard's own numbers (:class:`~cartpole_control.rail_guard.RailGuard`)."""
        import casadi as ca

        p = problem.params
        guard = RailGuard(p, margin=problem.rail_margin, limit_reserve=GUARD_RESERVE)
        x, v, w = X[0, 1:], X[2, 1:], X[3, 1:]
        a_left = guard.deceleration(-1.0, w, ca.fmax)
        a_right = guard.deceleration(1.0, w, ca.fmax)
        ahead = x + v * guard.dead_time
        left = ahead - ca.fmin(v, 0.0) ** 2 / (2.0 * a_left)
        right = ahead + ca.fmax(v, 0.0) ** 2 / (2.0 * a_right)
        lo = problem.rail_margin + GUARD_RESERVE
        hi = p.travel - problem.rail_margin - GUARD_RESERVE
        return [ca.reshape(left - lo + sigma, -1, 1), ca.reshape(hi - right + sigma, -1, 1)]

    def rest_guess(self, impulse: float) -> np.ndarray:
        """Every node at the start, no force."""
        n = self.n
        return np.concatenate([[impulse, 0.0], np.tile(self.x0, n + 1), np.zeros(n)])

    def brake_guess(self, impulse: float) -> np.ndarray:
        """The plant (4.18) under a cart-only law, F = sat(-60 (x - x0) - 20 x_dot), pushed.

        The law ignores the pendulum: it falls and swings. A start for the branch on
        which the pendulum is let go and swung up again (no angle limit); simulated with
        RK4 at 1 ms on :func:`cartpole_core.model.accelerations` (unsmoothed friction).
        """
        pr = self.problem
        p = pr.params
        push = impulse / pr.width
        n_push = pr.pushed_intervals()
        s = self.x0.copy()
        states, forces = [s.copy()], []

        def derivative(y, force, torque):
            a, b = accelerations(y[0], y[1], y[2], y[3], force, p, friction=pr.friction)
            if torque:
                da, db = torque_accelerations(y[1], torque, p)
                a, b = a + da, b + db
            return np.array([y[2], y[3], a, b])

        for k, h in enumerate(self.h):
            u = min(max(-60.0 * (s[0] - self.x0[0]) - 20.0 * s[2], p.force_min), p.force_max)
            forces.append(u)
            pushed = k < n_push
            force = u + (push if pushed and pr.target == 'cart' else 0.0)
            torque = push if pushed and pr.target == 'pendulum' else 0.0
            m = max(1, int(math.ceil(h / 0.001 - 1e-9)))
            dt = h / m
            for _ in range(m):
                k1 = derivative(s, force, torque)
                k2 = derivative(s + 0.5 * dt * k1, force, torque)
                k3 = derivative(s + 0.5 * dt * k2, force, torque)
                k4 = derivative(s + dt * k3, force, torque)
                s = s + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
            states.append(s.copy())
        xs = np.array(states)
        lo, hi = pr.rail_margin, p.travel - pr.rail_margin
        sigma = max(0.0, float(np.max(lo - xs[:, 0])), float(np.max(xs[:, 0] - hi)))
        return np.concatenate([[impulse, sigma], xs.ravel(), forces])

    def _solve(self, w0: np.ndarray, weights: tuple[float, float], lbw: np.ndarray,
               ubw: np.ndarray) -> tuple[PushRecovery, np.ndarray]:
        t0 = time.perf_counter()
        sol = self.solver(x0=w0, p=weights, lbx=lbw, ubx=ubw, lbg=self.lbg, ubg=self.ubg)
        elapsed = time.perf_counter() - t0
        stats = self.solver.stats()
        status = stats.get('return_status', '')
        w = np.array(sol['x']).ravel()
        g = np.array(sol['g']).ravel()
        n = self.n
        impulse, sigma = float(w[0]), max(0.0, float(w[1]))
        gap = float(np.max(np.abs(g[:self.n_gaps])))
        # The other constraints, checked on the returned point.
        other = g[self.n_gaps:]
        violation = float(max(np.max(self.lbg[self.n_gaps:] - other),
                              np.max(other - self.ubg[self.n_gaps:]), 0.0))
        converged = bool(stats.get('success', False)) or status == 'Solved_To_Acceptable_Level'
        feasible = (converged and gap < 1e-6 and violation < 1e-6
                    and sigma <= FEASIBILITY_TOLERANCE)
        result = PushRecovery(impulse=impulse, violation=sigma if converged else math.inf,
                              feasible=feasible, times=self.times.copy(),
                              states=w[2:2 + 4 * (n + 1)].reshape(n + 1, 4),
                              forces=w[2 + 4 * (n + 1):], status=status, solve_time=elapsed)
        return result, w

    def elastic(self, impulse: float, guess: np.ndarray | str | None = None
                ) -> tuple[PushRecovery, np.ndarray]:
        """The least slack sigma for the impulse P from ``guess``: a decision vector,
        ``'brake'`` (:meth:`brake_guess`) or None (:meth:`rest_guess`)."""
        if guess is None or isinstance(guess, str):
            w0 = self.brake_guess(impulse) if guess == 'brake' else self.rest_guess(impulse)
        else:
            w0 = guess.copy()
        w0[0] = impulse
        lbw, ubw = self.lbw.copy(), self.ubw.copy()
        lbw[0] = ubw[0] = impulse
        return self._solve(w0, (1.0, 0.0), lbw, ubw)

    def maximise(self, guess: np.ndarray) -> tuple[PushRecovery, np.ndarray]:
        """The largest P with sigma = 0, from ``guess`` (a solution of :meth:`elastic`)."""
        w0 = guess.copy()
        w0[1] = 0.0
        ubw = self.ubw.copy()
        ubw[1] = 0.0
        return self._solve(w0, (0.0, 1.0), self.lbw, ubw)


@functools.lru_cache(maxsize=8)
def recovery_nlp(problem: PushRecoveryProblem, max_iter: int = 500) -> _RecoveryNLP:
    """The NLP of ``problem``, built once per process (a build takes seconds)."""
    return _RecoveryNLP(problem, max_iter)
