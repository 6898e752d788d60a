"""The physical limit for pushes: the largest push any controller can recover from (no ROS).

The bound of a :class:`~cartpole_control.push_problem.PushRecoveryProblem` is
the largest impulse after which some force history within the amplifier's
limits brings the pendulum upright and to rest inside the rail: the limit of
any controller that knows the true state and the push in advance.
:func:`largest_push` bisects on the impulse, each solve of the elastic NLP
(:mod:`cartpole_control.push_recovery_nlp`) warm-started from the last
feasible one; :func:`cart_push_momentum_bound` bounds the cart push in closed
form. What the bounds are and what limits them: docs/robustness.md ("The
physical limit for pushes").
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from cartpole_core.model import CartPoleParameters

from .push_problem import (DEFAULT_HORIZON, FALL_ANGLE, FEASIBILITY_TOLERANCE,
                           GUARD_RESERVE, PUSH_TARGETS, PUSH_UNITS, PUSH_WIDTHS,
                           RAIL_GUARD_MARGIN, PushRecovery, PushRecoveryProblem)
from .push_recovery_nlp import casadi_push_dynamics, recovery_nlp

__all__ = ['DEFAULT_HORIZON', 'FALL_ANGLE', 'FEASIBILITY_TOLERANCE', 'GUARD_RESERVE',
           'PENDULUM_PUSH_SCALE', 'PUSH_TARGETS', 'PUSH_UNITS', 'PUSH_WIDTHS', 'RAIL_GUARD_MARGIN',
           'PushBound', 'PushRecovery', 'PushRecoveryProblem', 'cart_push_momentum_bound',
           'casadi_push_dynamics', 'impulse_scale', 'largest_push', 'push_bounds', 'recovery_nlp']


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
