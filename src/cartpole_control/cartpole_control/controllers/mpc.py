"""Constrained model-predictive stabiliser (MPC) on the upright linearisation, with integral action.

The model, the weights and the integral action are the LQI's
(:mod:`.lqg`): the linearisation about upright rest (8.13)/(8.14)
(:func:`cartpole_core.model.linearise_upright`, with the 1/m_c the printed A44
lacks), augmented with the integral of the cart error ``xi = int (x - x*) dt``,
the state ``z = [x - x*, theta_w, x_dot, theta_dot, xi]`` and the weights
``q = [10, 10000, 10, 1, 400]`` of the cost (8.15), with ``r = 0.008``
instead of 0.01: sampled at Ts the optimum of the LQI's weights is about 9 %
softer than the continuous LQI, and with 0.008 the terminal LQR's gain is
lqg's within 0.6 %. What the
MPC adds are the constraints the LQR (8.16)-(8.18) cannot see:

- the force: the amplifier's range [force_min, force_max] (Appendix C, -37.4 /
  +34.2 N) less the friction feedforward (6.12) that the manager adds to this
  raw force (``context.feedforward``): for a cart moving faster than the
  feedforward's velocity band that is its kinetic friction along the velocity
  whatever the command (so braking gets the amplifier's range plus the
  friction, pushing on its range less it), for a cart at rest either Coulomb
  level; hard bounds on every predicted move (the first one exact, the later
  ones with the present direction of motion);
- the cart: ``x + braking_time x_dot`` inside ``[margin + reserve + clearance,
  travel - margin - reserve - clearance]`` (``context.rail_margin``,
  ``context.rail_reserve``, the manager's ``rail.margin`` /
  ``rail.limit_reserve``, and ``mpc.rail_clearance``). ``x + t_b x_dot`` is
  a linear upper bound of the rail guard's stopping position (its dead time
  plus ``x_dot^2 / (2 a_b)``, :mod:`cartpole_control.rail_guard`) up to
  1.5 m/s, and the boundary is where the guard's limiter starts bending a
  moving cart's command: kept there, the cart never needs the guard, whose
  trip (``[margin, travel - margin]``) loses the pendulum. Soft, with an exact
  l1 penalty: the QP is always feasible.

Each cycle (Mayne et al., "Constrained model predictive control: stability and
optimality", Automatica 36, 2000; Rawlings, Mayne and Diehl, "Model Predictive
Control: Theory, Computation, and Design", 2nd ed., 2017, chapter 2) the QP
of :mod:`cartpole_control.mpc_qp` is solved over ``horizon`` steps of the
exactly discretised model (zero-order hold at Ts = ``context.sample_time``)
with the terminal cost P of the discrete Riccati equation of the same model
and weights (the discrete counterpart of (8.18)); its first move is applied.
Without an active constraint that move is exactly the terminal LQR's
``u = -K_d z`` (the finite-horizon cost with terminal cost P *is* the
infinite-horizon cost): the MPC only departs from the LQR where a constraint
bites. The predictions are written about the terminal LQR,
``u_k = -K_d z_k + c_k`` (Rossiter, Kouvaritakis and Rice, "A numerically
robust state-space approach to stable-predictive control strategies",
Automatica 34(1), 1998): the open-loop unstable pendulum's powers of A_d never
enter the QP, the Hessian is diagonal and the unconstrained optimum is c = 0.

The actuator's current loop (4.4), pole at a = 1.058e4 1/s, is left out of
the model: it settles in 0.1 ms, a fiftieth of the sample time, and its pole
discretised at Ts = 5 ms is exp(-a Ts) ~ 1e-23: it adds a state that is gone
within every sample and a DC gain of 1.0066 (10650/10580) that the integral
takes up. Including it would only make the QP larger (a sixth state).

What the constraints buy, measured (docs/controllers.md): little. The
robustness score is lqg's within a level either way; a 6 N s cart push is
recovered in 3 of 12 seeds, as by lqg, a 0.05 N m s pendulum push in none:
the loop sees the push too late (docs/robustness.md, "Behind the rail
guard, reacting to what the encoders show": even the time-optimal recovery
that starts 20 ms after the push recovers at most 0.0513 N m s behind the
guard), runs the cart into the guard's limiter boundary, and the braking
there swings the pendulum over towards the stop. The
rail penalty is 1e4, not larger: with 1e5 a cart that reached the boundary
at rest stays parked there (to come back it must first move towards the
stop, the cart's non-minimum phase, which such a penalty forbids).

Integral action, anti-windup and bumplessness are the LQI's: ``xi`` starts at
zero at every activation, the increment ``(x - x*) dt`` is taken at once and
taken back when the manager reports the command as cut in the direction it
pushed it, or held (:class:`~cartpole_control.controllers.ConditionalIntegrator`,
with the terminal LQR's d(force)/d(xi) = -K_d,xi as its effect), or when the
MPC's own first move sits on a force bound.

A solve that fails (status not optimal, an exception, a non-finite answer)
or takes longer than ``budget_us`` (wall time of the solve with its Python
calls) applies the terminal LQR law ``-K_d z`` for that cycle and is counted
(``mpc_fallbacks`` of :meth:`MpcStabilizer.status_values`): never a fault,
never a stale command. The QP is built once per configure (never in
:meth:`update`); a cycle only computes the bounds from z_0 and warm-starts.
"""
from __future__ import annotations

import numpy as np

from cartpole_core.model import linearise_upright

from ..controller import STABILIZER, CommandFeedback, Controller, ControllerState, ParameterSpec
from ..mpc_qp import SOLVERS, CondensedQp, QpSettings, discretise, sampled_cost
from . import ConditionalIntegrator, StepClock
from .lqg import augmented_model

DEFAULT_HORIZON = 200
"""Prediction steps (1 s at 5 ms); see docs/controllers.md for the measurement behind it."""
DEFAULT_TAIL = 0
"""Steps after the horizon over which the terminal LQR's forces and cart positions are
checked (0: none; with the rail penalty it made the MPC trade the rail for tail forces)."""
DEFAULT_BLOCK = 5
"""Steps a free move is held (25 ms): 40 free moves over the default horizon."""


class MpcStabilizer(Controller):
    """Constrained MPC about upright with integral action; unconstrained it is the discrete LQI."""

    kind = STABILIZER
    name = 'mpc'
    running_state = ('_integral', '_clock')
    parameters = (
        ParameterSpec('q', (10.0, 10000.0, 10.0, 1.0, 400.0),
                      'diagonal of the state weight Q of (8.15) for [x - x*, theta, x_dot, '
                      'theta_dot, int (x - x*) dt] [1/m^2, 1/rad^2, s^2/m^2, s^2/rad^2, '
                      '1/(m^2 s^2)], as lqg.q; the integral weight must be > 0',
                      low=0.0, high=1e8, length=5),
        ParameterSpec('r', 0.008,
                      'input weight R of (8.15) [1/N^2]; 0.008 instead of the LQI\'s 0.01 because '
                      'the sampled optimum of the same weights is about 9 % softer: with 0.008 '
                      'the terminal LQR K_d equals lqg\'s continuous gain within 0.6 %',
                      low=1e-8, high=1e6),
        ParameterSpec('horizon', DEFAULT_HORIZON,
                      'prediction horizon N [samples of Ts] over which the force and rail '
                      'constraints are imposed; beyond it the terminal LQR cost', low=1, high=400),
        ParameterSpec('block', DEFAULT_BLOCK,
                      'move blocking [samples]: the correction to the terminal LQR is held '
                      'over blocks of this many steps, and the force and rail constraints are '
                      'imposed once a block (horizon / block free moves)', low=1, high=400),
        ParameterSpec('braking_time', 0.135,
                      'the rail constraint bounds x + braking_time * x_dot [s], a linear upper '
                      'bound of the rail guard\'s stopping position x + x_dot T_d + x_dot^2 / '
                      '(2 a_b) for |x_dot| up to 1.5 m/s (T_d = 5.1 ms, a_b = 5.75 m/s^2 with '
                      'the guard\'s default 30 N brake); 0 bounds the position alone',
                      low=0.0, high=2.0),
        ParameterSpec('tail', DEFAULT_TAIL,
                      'constraint-checking tail [samples]: after the horizon the terminal LQR\'s '
                      'predicted forces and cart positions are checked (soft) over this many '
                      'more steps, every block steps', low=0, high=2000),
        ParameterSpec('solver', 'daqp', f'QP solver, one of {list(SOLVERS)} (casadi_* are '
                      'the solvers bundled with CasADi; daqp and osqp their own wheels)',
                      choices=SOLVERS),
        ParameterSpec('budget_us', 2000.0,
                      'solve time [us] (wall, Python calls included) above which the '
                      'solution is not used: the terminal LQR law instead, counted in '
                      'mpc_fallbacks', low=50.0, high=1e6),
        ParameterSpec('rail_penalty', 1e4,
                      'penalty weight rho on the rail slack [cost per m of excursion per '
                      'constrained point] (l1, exact above the rail constraint\'s multipliers); '
                      'much larger (1e5) parks a cart that reached the boundary at rest there',
                      low=1.0, high=1e9),
        ParameterSpec('rail_clearance', 0.0,
                      'extra distance [m] kept inside the rail guard\'s limiter boundary '
                      '[margin + reserve, travel - margin - reserve]; negative lets the MPC '
                      'use that much of the reserve', low=-0.1, high=0.3),
    )

    def __init__(self) -> None:
        super().__init__()
        self.qp: CondensedQp | None = None
        self.gain = np.zeros(5)
        """K_d of the terminal LQR on z = [x - x*, theta_w, x_dot, theta_dot, xi]."""
        self._integral = ConditionalIntegrator()
        self._clock = StepClock()
        self._z = np.zeros(5)
        self._force_low = self._force_high = 0.0
        self._amplifier_min = self._amplifier_max = 0.0
        self._feedforward = None
        self._bounds = (0.0, 0.0)
        self.fallbacks = 0
        """Cycles whose solve failed or overran the budget (the terminal LQR was applied)."""
        self.solve_us = 0.0
        """Wall time of the last solve [us]."""
        self.last_reason = ''

    @property
    def integral(self) -> float:
        """xi = int (x - x*) dt [m s]."""
        return self._integral.value

    def on_configure(self) -> None:
        """Discretise, solve the discrete Riccati equation and build the QP (once)."""
        ctx = self.context
        p = ctx.plant
        q = [float(v) for v in self.gains['q']]
        if q[4] <= 0.0:
            raise ValueError('mpc: the integral weight q[4] must be > 0 (the integrator\'s mode '
                             'must be seen by the cost for the Riccati equation to have a '
                             'stabilising solution)')
        ts = float(ctx.sample_time)
        a, b = augmented_model(*linearise_upright(p))
        a_d, b_d = discretise(a, b, ts)
        q_d, r_d, n_d = sampled_cost(a, b, np.diag(q), np.array([[float(self.gains['r'])]]), ts)
        ff = ctx.feedforward
        coulomb = max(ff.c_right, ff.c_left)
        force_low, force_high = p.force_min + coulomb, p.force_max - coulomb
        inset = ctx.rail_margin + ctx.rail_reserve + float(self.gains['rail_clearance'])
        low, high = inset - ctx.x_ref, p.travel - inset - ctx.x_ref
        if not low < 0.0 < high:
            raise ValueError(f'mpc: x* = {ctx.x_ref:g} m is outside the rail bounds '
                             f'[{inset:g}, {p.travel - inset:g}] m')
        if int(self.gains['block']) > int(self.gains['horizon']):
            raise ValueError(f'mpc: block ({self.gains["block"]}) must not exceed the horizon '
                             f'({self.gains["horizon"]})')
        settings = QpSettings(int(self.gains['horizon']), force_low, force_high, low, high,
                              float(self.gains['rail_penalty']), str(self.gains['solver']),
                              1e-6 * float(self.gains['budget_us']), int(self.gains['block']),
                              float(self.gains['braking_time']), int(self.gains['tail']))
        self.qp = CondensedQp(a_d, b_d, q_d, r_d, settings, n_d)
        self.gain = self.qp.gain_row.copy()
        self._force_low, self._force_high = force_low, force_high
        self._amplifier_min, self._amplifier_max = p.force_min, p.force_max
        self._feedforward = ff

    def on_activate(self, state: ControllerState) -> None:
        """Bumpless start: the integral from zero at this state, the solver cold."""
        self._integral.reset()
        self._clock.reset(state.t)
        self.qp.reset()

    def update(self, state: ControllerState) -> float:
        """The first move of the constrained QP for z = [x - x*, theta_w, x_dot, theta_dot, xi]."""
        error_x = state.x - self.context.x_ref
        dt = self._clock.step(state.t, self.context.sample_time)
        k_i = float(self.gain[4])
        xi = self._integral.step(error_x, dt, -k_i)
        z = self._z
        z[0], z[1], z[2], z[3], z[4] = error_x, state.theta_w, state.x_dot, state.theta_dot, xi
        # The raw force range: what the amplifier gives less the feedforward the manager
        # adds. A moving cart (beyond the velocity band) gets its kinetic friction along
        # the velocity whatever the command; a cart at rest up to either Coulomb level.
        ff = self._feedforward
        band = ff.velocity_band
        if band > 0.0 and state.x_dot > band:
            low, high = self._amplifier_min - ff.c_right, self._amplifier_max - ff.c_right
        elif band > 0.0 and state.x_dot < -band:
            low, high = self._amplifier_min + ff.c_left, self._amplifier_max + ff.c_left
        else:
            low, high = self._force_low, self._force_high
        self._bounds = (low, high)
        solution = self.qp.solve(z, low, high)
        self.solve_us = solution.solve_time * 1e6
        if not solution.ok:
            self.fallbacks += 1
            self.last_reason = solution.reason
        u = solution.force
        effect = -k_i * error_x
        low, high = self._bounds
        if (u >= high - 1e-9 and effect > 0.0) or (u <= low + 1e-9 and effect < 0.0):
            self._integral.hold()  # the MPC's own bound: no windup against it
        return u

    def command_applied(self, feedback: CommandFeedback) -> None:
        """Anti-windup: take back this cycle's integration if the command was cut or held."""
        self._integral.feedback(feedback)

    def status_values(self) -> dict[str, float]:
        """``mpc_solve_us`` (the last solve's wall time) and ``mpc_fallbacks`` (count)."""
        return {'mpc_solve_us': self.solve_us, 'mpc_fallbacks': self.fallbacks}
