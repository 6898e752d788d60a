"""The physical limit for pushes: the largest push any controller can recover from (no ROS).

What the bound means. The robustness grid (``cartpole bench robustness``,
docs/robustness.md) pushes the balanced cart-pendulum at x* = the middle of
the travel: on the cart a constant force to the right for 0.1 s, on the
pendulum a constant torque towards increasing theta for 0.05 s (the
``Push`` of :mod:`cartpole_sim.scenario`, entering the model as an extra
force on the cart, or as a generalised force on theta in (4.17), i.e.
M(theta)^-1 [0, tau] added to (4.18)). The bound of this module is the
largest impulse of such a push after which *some* force history
F(t) in [F_min, F_max] (the amplifier's limits, Appendix C: -12 A and +11 A
times k_t / r = 3.1133 N/A, so -37.4 N and 34.2 N) brings the pendulum
upright and to rest with the cart inside ``[m, travel - m]`` all the time.
It is the limit of *any* controller: it knows the true state and the push
in advance (no noise, no delay, no estimation), acts during the push too
(the push adds to its force), and has the nominal plant exactly. A
controller of the grid that survives a push of a fraction r of the bound
recovers from r of what is physically possible; pushes above the bound
fail whatever the controller.

The problem, for an impulse P, a push of width w (force P / w or torque
P / w over [0, w]) and a horizon T:

    find        F(t), t in [0, T]
    subject to  s_dot = f(s, F + F_push(t)) + M(theta)^-1 [0, tau_push(t)]    (4.18)
                s(0) = (x*, 0, 0, 0)                     balanced at rest at x*
                F_min <= F(t) <= F_max                   Appendix C
                m <= x(t) <= travel - m                  the rail (m = 0: the end stops,
                                                         m = 0.02 m: the rail guard's margin)
                x_b(t) in [m + r, travel - m - r]        optional (``guard``): the rail guard's
                                                         braking envelope, below
                |theta(t)| <= 45 deg                     optional: the fall detector
                                                         (``fall.angle_deg``); a fall after
                                                         the catch fails a robustness run
                sin theta(T) = 0, cos theta(T) >= 0,     upright (any number of turns
                theta_dot(T) = 0, x_dot(T) = 0           without the fall constraint), at rest

solved as an *elastic* feasibility problem: the rail and angle constraints
get a common slack sigma >= 0 and IPOPT minimises sigma; P is feasible when
the minimum is (numerically) zero. Direct multiple shooting as
:mod:`cartpole_control.trajectory_optimization`: piecewise-constant force
on the 5 ms control grid (the sample time) during the push and shortly
after, on ``step`` (10 ms) later; one RK4 step of 2.5 ms or less per
substep; the rail and angle constraints at the nodes. The friction
(4.20)/(4.21) is kept, its Coulomb term smoothed to tanh(k v) with k = 100
as there (:func:`~cartpole_control.trajectory_optimization.casadi_dynamics`);
the current loop's 0.1 ms lag (4.4) is left out. :func:`largest_push`
bisects on P (to ``rel_tol``, 1 % by default), each solve warm-started from
the last feasible one. IPOPT finds local minima: a P it declares infeasible
is infeasible only as far as the solver could tell (several starts are
tried); a feasible P is certified by the solution itself (its dynamics
gaps and constraint violations are checked).

With ``guard`` the bound is the limit of any controller *behind this project's
rail guard* (:mod:`cartpole_control.rail_guard`, the manager's defaults): its
limiter bends every command so that the cart's stopping position under the
guard's own braking model, x_b = x + x_dot T_d + sign(x_dot) x_dot^2 / (2 a_b),
a_b = (F_b + c_c/2 - m_p (l theta_dot^2 + g)) / (m_c + m_p) with F_b = 30 N,
stays inside ``[m + r, travel - m - r]`` (r = ``rail.limit_reserve``, 5 cm):
a path constraint at every node (the term of the command during T_d, below
0.1 mm, is left out). That envelope is a safety choice of ours, not physics:
the gap between the two bounds is what the guard costs.

A closed-form check (:func:`cart_push_momentum_bound`) bounds the cart
push from above without the pendulum's details; see its docstring.
"""
from __future__ import annotations

import dataclasses
import functools
import math
import time
from dataclasses import dataclass

import numpy as np

from cartpole_core.model import CartPoleParameters, accelerations, torque_accelerations

from .trajectory_optimization import SMOOTH_FRICTION_STEEPNESS, casadi_dynamics

PUSH_TARGETS = ('cart', 'pendulum')
"""What a push acts on: an extra force on the cart, or a torque on the pendulum."""

PUSH_WIDTHS = {'cart': 0.1, 'pendulum': 0.05}
"""[s] The widths of the robustness grid's pushes (``bench.robustness.CART_PUSH_WIDTH`` and
``PENDULUM_PUSH_WIDTH``; a test checks they agree)."""

PUSH_UNITS = {'cart': 'N s', 'pendulum': 'N m s'}

FALL_ANGLE = math.pi / 4.0
"""[rad] The controller manager's fall detector (``fall.angle_deg`` 45): a fall after the
catch fails a robustness run."""

RAIL_GUARD_MARGIN = 0.02
"""[m] The rail guard's margin (``rail.margin``)."""

DEFAULT_HORIZON = 3.0
"""[s] From the start of the push to upright at rest (long enough: :func:`largest_push` with
4 s gives the same bounds, docs/robustness.md)."""

GUARD_RESERVE = 0.05
"""[m] The rail guard limiter's reserve (``rail.limit_reserve``)."""

FEASIBILITY_TOLERANCE = 1e-5
"""Largest slack sigma [m, rad] that still counts as feasible (10 um, 10 urad)."""


@dataclass(frozen=True)
class PushRecoveryProblem:
    """The recovery from one kind of push (module docstring), without its impulse.

    Parameters
    ----------
    params
        The plant (the nominal thesis parameters by default).
    target
        ``'cart'`` (a force to the right) or ``'pendulum'`` (a torque towards increasing theta).
    width
        Duration of the constant push [s]; None: the robustness grid's (:data:`PUSH_WIDTHS`).
    rail_margin
        m: the cart stays in ``[m, travel - m]`` [m].
    max_angle
        If set, |theta(t)| <= this all the time [rad] (:data:`FALL_ANGLE`: no fall).
    horizon
        T, from the start of the push to upright at rest [s].
    x0
        Cart position at the push [m]; None: the middle of the travel (x*).
    push_step
        Interval of the force during the push and the first ``fine_time`` [s] (5 ms: Ts).
    step
        Interval of the force after that [s].
    fine_time
        How long after the push's start the fine grid lasts [s].
    friction
        Keep the (smoothed) friction.
    reaction
        The controller's force is zero until this time [s] after the push starts: a
        controller that cannot act before it sees the push (0: it knows the push in advance).
    guard
        Also keep the rail guard's braking envelope (module docstring): the stopping
        position of the manager's default guard (margin ``rail_margin``, reserve
        :data:`GUARD_RESERVE`, brake 30 N) inside ``[m + r, travel - m - r]``.
    """

    params: CartPoleParameters = CartPoleParameters()
    target: str = 'cart'
    width: float | None = None
    rail_margin: float = 0.0
    max_angle: float | None = None
    horizon: float = DEFAULT_HORIZON
    x0: float | None = None
    push_step: float = 0.005
    step: float = 0.01
    fine_time: float = 0.5
    friction: bool = True
    reaction: float = 0.0
    guard: bool = False

    def __post_init__(self) -> None:
        if self.target not in PUSH_TARGETS:
            raise ValueError(f'target must be one of {PUSH_TARGETS}, got {self.target!r}')
        if self.width is None:
            object.__setattr__(self, 'width', PUSH_WIDTHS[self.target])
        if not self.width > 0.0:
            raise ValueError(f'width must be > 0, got {self.width!r}')
        if not 0.0 <= self.rail_margin < 0.5 * self.params.travel:
            raise ValueError(f'rail_margin must be in [0, travel/2), got {self.rail_margin!r}')
        if self.max_angle is not None and not 0.0 < self.max_angle < math.pi:
            raise ValueError(f'max_angle must be in (0, pi), got {self.max_angle!r}')
        if not self.horizon > self.width + self.push_step:
            raise ValueError(f'horizon must exceed the push width, got {self.horizon!r}')
        if not (0.0 < self.push_step <= self.step):
            raise ValueError('need 0 < push_step <= step')
        if not self.rail_margin <= self.start_x <= self.params.travel - self.rail_margin:
            raise ValueError(f'x0 = {self.start_x:g} m is outside the rail minus its margin')
        if not 0.0 <= self.reaction < self.horizon - self.width:
            raise ValueError(f'reaction must be in [0, horizon - width), got {self.reaction!r}')

    @property
    def start_x(self) -> float:
        return self.params.x_middle if self.x0 is None else float(self.x0)

    @property
    def unit(self) -> str:
        return PUSH_UNITS[self.target]

    def grid(self) -> np.ndarray:
        """The interval lengths: ``push_step`` over the push and ``fine_time``, then ``step``."""
        n_push = max(1, int(round(self.width / self.push_step)))
        h_push = self.width / n_push
        fine_end = max(self.width, min(self.fine_time, self.horizon))
        n_fine = int(round((fine_end - self.width) / self.push_step))
        rest = self.horizon - self.width - n_fine * self.push_step
        n_rest = max(1, int(math.ceil(rest / self.step - 1e-9)))
        return np.concatenate([np.full(n_push, h_push), np.full(n_fine, self.push_step),
                               np.full(n_rest, rest / n_rest)])

    def pushed_intervals(self) -> int:
        """The number of intervals the push lasts (the first ones)."""
        return max(1, int(round(self.width / self.push_step)))

    def replace(self, **changes) -> 'PushRecoveryProblem':
        return dataclasses.replace(self, **changes)


@dataclass(frozen=True)
class PushRecovery:
    """One solve of the elastic feasibility problem for one impulse."""

    impulse: float
    """P [N s or N m s]."""
    violation: float
    """The least slack sigma the solver found [m or rad]; 0 = recoverable."""
    feasible: bool
    """sigma <= :data:`FEASIBILITY_TOLERANCE` and the dynamics are met (gaps < 1e-6)."""
    times: np.ndarray
    """(N + 1,) node times [s] from the start of the push."""
    states: np.ndarray
    """(N + 1, 4) node states (x, theta, x_dot, theta_dot)."""
    forces: np.ndarray
    """(N,) the controller's force [N] over each interval (without the push)."""
    status: str = ''
    solve_time: float = 0.0


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

        from .rail_guard import RailGuard
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


@dataclass(frozen=True)
class PushBound:
    """The largest recoverable impulse of one :class:`PushRecoveryProblem`."""

    problem: PushRecoveryProblem
    impulse: float
    """The largest impulse found feasible [N s or N m s] (the bound, to ``rel_tol``)."""
    infeasible: float
    """The smallest impulse found infeasible (the bound lies in [impulse, infeasible])."""
    recovery: PushRecovery
    """The solution at :attr:`impulse`."""
    solves: int
    solve_time: float

    def to_dict(self) -> dict:
        s = self.recovery.states
        return {'target': self.problem.target, 'unit': self.problem.unit,
                'width_s': self.problem.width, 'rail_margin_m': self.problem.rail_margin,
                'rail_guard': self.problem.guard, 'reaction_s': self.problem.reaction,
                'max_angle_deg': (None if self.problem.max_angle is None
                                  else round(math.degrees(self.problem.max_angle), 6)),
                'horizon_s': self.problem.horizon, 'x0_m': self.problem.start_x,
                'impulse': round(self.impulse, 5),
                'infeasible_from': (round(self.infeasible, 5) if math.isfinite(self.infeasible)
                                    else None),
                'x_range_m': [round(float(s[:, 0].min()), 4), round(float(s[:, 0].max()), 4)],
                'theta_range_deg': [round(math.degrees(float(s[:, 1].min())), 2),
                                    round(math.degrees(float(s[:, 1].max())), 2)],
                'solves': self.solves, 'solve_s': round(self.solve_time, 2)}


PENDULUM_PUSH_SCALE = 0.15
"""[N m s] The largest pendulum push of the robustness grid: the scale of the pendulum's starts."""


@functools.lru_cache(maxsize=8)
def recovery_nlp(problem: PushRecoveryProblem, max_iter: int = 500) -> _RecoveryNLP:
    """The NLP of ``problem``, built once per process (a build takes seconds)."""
    return _RecoveryNLP(problem, max_iter)


def impulse_scale(problem: PushRecoveryProblem) -> float:
    """A scale of the bound, for the starts of :func:`largest_push`.

    The cart: :func:`cart_push_momentum_bound` (an upper bound). The pendulum: the grid's
    largest push, :data:`PENDULUM_PUSH_SCALE`.
    """
    if problem.target == 'cart':
        return cart_push_momentum_bound(problem.params, problem.width, problem.rail_margin,
                                        problem.max_angle, problem.start_x)
    return PENDULUM_PUSH_SCALE


DEFAULT_STARTS: tuple[tuple[float, str], ...] = ((0.25, 'rest'), (0.5, 'rest'), (0.6, 'brake'),
                                                 (0.8, 'brake'))
"""(fraction of :func:`impulse_scale`, initial guess) of the starts of :func:`largest_push`;
the ``'brake'`` starts (the pendulum let go) only without an angle limit."""


def largest_push(problem: PushRecoveryProblem, rel_tol: float = 0.01,
                 starts: tuple[tuple[float, str], ...] = DEFAULT_STARTS, max_iter: int = 500,
                 retry_from_rest: bool = True, progress=None) -> PushBound:
    """The largest impulse :class:`PushRecoveryProblem` recovers from, to ``rel_tol``.

    1. For each start (f, guess): the elastic problem at P = f :func:`impulse_scale` from
       ``guess`` (``'rest'``: every node at the start; ``'brake'``: a simulation with the
       pendulum let go, tried only without an angle limit); if feasible, P is maximised from
       that solution directly (P a decision variable, sigma = 0), which gives a feasible
       impulse certified by its solution.
    2. Bisection on P between the largest feasible impulse lo and the smallest infeasible
       one hi (at first lo (1 + ``rel_tol``)), each elastic solve from the last feasible
       solution and, if infeasible from there, from rest (``retry_from_rest``); a feasible
       one is maximised from
       again. Stops when hi - lo <= ``rel_tol`` lo: the bound is in [lo, hi].

    Infeasible means: the solver found no recovery from these starts (a local solver
    proves feasibility, not infeasibility).
    """
    started = time.perf_counter()
    nlp = recovery_nlp(problem, max_iter)
    scale = impulse_scale(problem)
    solves = 0
    limit = ('no angle limit' if problem.max_angle is None
             else f'|theta| <= {math.degrees(problem.max_angle):g} deg')

    def say(kind: str, r: PushRecovery) -> None:
        if progress:
            verdict = 'feasible' if r.feasible else f'infeasible (sigma {r.violation:.3g})'
            progress(f'{problem.target} push, margin {problem.rail_margin:g} m, {limit}: '
                     f'{kind} {r.impulse:.5g} {problem.unit}: {verdict} '
                     f'[{r.status}, {r.solve_time:.1f} s]')

    def elastic(impulse: float, warm, kind: str = 'elastic'):
        nonlocal solves
        r, w = nlp.elastic(impulse, warm)
        solves += 1
        say(kind, r)
        if not r.feasible and retry_from_rest and not (warm is None or isinstance(warm, str)):
            cold, wc = nlp.elastic(impulse, None)
            solves += 1
            say('elastic from rest', cold)
            if cold.feasible or cold.violation < r.violation:
                r, w = cold, wc
        return r, w

    def maximise(w: np.ndarray):
        nonlocal solves
        r, wm = nlp.maximise(w)
        solves += 1
        say('maximised', r)
        return r, wm

    best, best_w = elastic(0.0, None)
    if not best.feasible:
        raise RuntimeError(f'no push is recoverable: {best.status}, sigma {best.violation:.3g}')
    for f, guess in starts:
        if guess != 'rest' and problem.max_angle is not None:
            continue
        r, w = elastic(f * scale, guess, f'elastic from {guess}')
        if not r.feasible:
            continue
        if r.impulse > best.impulse:
            best, best_w = r, w
        m, wm = maximise(w)
        if m.feasible and m.impulse > best.impulse:
            best, best_w = m, wm
    hi = math.inf
    while hi - best.impulse > rel_tol * best.impulse * (1.0 + 1e-9):
        trial = best.impulse * (1.0 + rel_tol) if math.isinf(hi) else 0.5 * (best.impulse + hi)
        r, w = elastic(trial, best_w)
        if not r.feasible:
            hi = trial
            continue
        best, best_w = r, w
        m, wm = maximise(w)
        if m.feasible and m.impulse > best.impulse:
            best, best_w = m, wm
            if best.impulse >= hi:  # the maximiser found a branch past an earlier failure
                hi = math.inf
    return PushBound(problem=problem, impulse=best.impulse, infeasible=hi, recovery=best,
                     solves=solves, solve_time=time.perf_counter() - started)


def cart_push_momentum_bound(params: CartPoleParameters, width: float = PUSH_WIDTHS['cart'],
                             rail_margin: float = 0.0, max_angle: float | None = None,
                             x0: float | None = None) -> float:
    """A closed-form upper bound of the recoverable cart push [N s], from momentum alone.

    The reasoning. x is a cyclic coordinate of the Lagrangian of (4.17): the horizontal
    momentum p = (m_c + m_p) x_dot - m_p l cos(theta) theta_dot, the momentum conjugate
    to x, changes only by the generalised force on x, dp/dt = F + F_push - B_c(x_dot)
    (the first row of (4.18); the pendulum's friction and the centripetal term are
    internal). p = M X_dot with M = m_c + m_p and X = x - (m_p / M) l sin(theta) the
    horizontal position of the centre of mass (4.5): the centre of mass moves like a
    point mass M under the external forces, whatever the pendulum does. The most they
    can brake it is the amplifier's F_min plus the cart's largest Coulomb friction,
    B = |F_min| + c_c,R (Table 4.1; the friction pushes right when the cart moves left,
    so it never brakes more). Starting at rest at X = x0, pushed with P / w over [0, w],
    X(t) is at least the path of full braking from t = 0, which stops at t_s = P / B
    (for P >= B w) after

        D = (P^2 / (2 B) - P w / 2) / M.

    The cart stays in [m, travel - m] and the centre of mass is at most
    (m_p / M) l |sin theta| <= (m_p / M) l sin(a) (a = ``max_angle``, pi/2 without one)
    from it, so a recoverable P has x0 + D <= travel - m + (m_p / M) l sin(a):

        P <= B w / 2 + sqrt((B w / 2)^2 + 2 B M d),  d = travel - m - x0 + (m_p / M) l sin(a).

    It is an upper bound (the true one is lower: the pendulum must also be brought back
    upright, and the cart cannot brake at full force while doing that).
    """
    p = params
    m = p.m_c + p.m_p
    brake = -p.force_min + max(p.c_c_right, p.c_c_left)
    x_start = p.x_middle if x0 is None else float(x0)
    lean = 1.0 if max_angle is None or max_angle >= 0.5 * math.pi else math.sin(max_angle)
    room = p.travel - rail_margin - x_start + p.m_p * p.l * lean / m
    half = 0.5 * brake * width
    return half + math.sqrt(half * half + 2.0 * brake * m * room)


def push_bounds(params: CartPoleParameters = CartPoleParameters(),
                targets=PUSH_TARGETS, margins=(0.0, RAIL_GUARD_MARGIN),
                max_angles=(None, FALL_ANGLE), horizon: float = DEFAULT_HORIZON,
                rel_tol: float = 0.01, progress=None) -> list[PushBound]:
    """:func:`largest_push` for every target x margin x angle limit (the docs' table)."""
    out = []
    for target in targets:
        for margin in margins:
            for angle in max_angles:
                problem = PushRecoveryProblem(params, target, rail_margin=margin,
                                              max_angle=angle, horizon=horizon)
                out.append(largest_push(problem, rel_tol, progress=progress))
    return out
