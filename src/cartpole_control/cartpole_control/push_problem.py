"""The push-recovery problem: one kind of push on the balanced cart-pendulum, and a solve of it.

A push as the robustness grid applies it (a constant force on the cart for
0.1 s, or a constant torque on the pendulum for 0.05 s, at x* = the middle of
the travel); is there a force history within the amplifier's limits
(Appendix C) that brings the pendulum upright and to rest with the cart
inside the rail, optionally without a fall (45 deg) and behind the rail
guard's braking envelope? The formulation, its method and the bounds found:
docs/robustness.md ("The physical limit for pushes"). The NLP is
:mod:`cartpole_control.push_recovery_nlp`, the bound search
:mod:`cartpole_control.push_recovery`. No ROS import.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from cartpole_core.model import CartPoleParameters

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
