"""Constrained model-predictive stabiliser (MPC) about upright, with integral action.

The LQI of :mod:`.lqg` (the linearisation (8.13)/(8.14) with the integral of
the cart error, the weights of (8.15)) made to respect what the LQR
(8.16)-(8.18) cannot see: every predicted force inside what the amplifier
gives (Appendix C, scaled by the gain of the manager's plant estimate) less
the friction feedforward (6.12) the manager adds, and the cart inside the
rail guard's limiter boundary (soft, heavily weighted: the guard holds it).
Its model may hold the actuator's lag and a dead time
(:mod:`cartpole_control.mpc_model`); each cycle the QP of
:mod:`cartpole_control.mpc_qp`, built once per configure (and for the catch again for
the plant the manager estimated, as ``lqg`` solves its gain again: a piece a cycle while the
swing-up runs, :meth:`MpcStabilizer.standby`), is solved warm and
its first move applied (Mayne et al., Automatica 36, 2000). The terminal cost
is the discrete Riccati solution, so without an active constraint the move is
the terminal LQR's ``-K_d s``. A failed or late solve applies the previous
plan shifted by one step, counted (``mpc_fallbacks``); a whole horizon
without a solve is a fault. Design notes and measurements: docs/controllers.md.
"""
from __future__ import annotations

from typing import Iterator

import numpy as np

from cartpole_core.model import linearise_upright

from ..controller import STABILIZER, CommandFeedback, Controller, ControllerState, ParameterSpec
from ..mpc_model import PLANT_STATES, prediction_model
from ..mpc_qp import NONE, CondensedQp, QpSettings
from ..mpc_solvers import SOLVERS
from . import ConditionalIntegrator, StepClock
from .lqg import DEAD_TIME_WEIGHT_MAX, RESOLVE_TOLERANCE, augmented_model, catch_plant

DEFAULT_HORIZON = 200
"""Prediction steps (1 s at 5 ms); see docs/controllers.md for the measurement behind it."""
DEFAULT_FREE_STEPS = 40
"""Steps whose forces are moves of their own (200 ms: a push's saturated braking)."""
DEFAULT_BLOCK = 10
"""Steps a correction to the terminal LQR is held after them (50 ms)."""
RAIL_CLEARANCE = 0.05
"""[m] ``mpc.rail_clearance``: the plan keeps 5 cm inside the rail guard's limiter boundary, room
for the catch's transient to come back from it (docs/robustness.md, "The MPC keeps clear of the
guard")."""


class MpcStabilizer(Controller):
    """Constrained MPC about upright with integral action; unconstrained it is the discrete LQI."""

    kind = STABILIZER
    name = 'mpc'
    running_state = ('_integral', '_clock', '_actuator_state')
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
        ParameterSpec('dead_time_weight_max', DEAD_TIME_WEIGHT_MAX,
                      'at the catch the QP is built again with R (1 + (D / 10 ms)^2) for the '
                      'loop\'s measured dead time D, at most this many times R, as '
                      'lqg.dead_time_weight_max; 1 keeps R [-]', low=1.0, high=100.0),
        ParameterSpec('horizon', DEFAULT_HORIZON,
                      'prediction horizon N [samples of Ts] over which the force and rail '
                      'constraints are imposed; beyond it the terminal LQR cost', low=1, high=400),
        ParameterSpec('free_steps', DEFAULT_FREE_STEPS,
                      'the first steps of the horizon whose forces are moves of their own, '
                      'each bounded exactly (hard) [samples]', low=1, high=400),
        ParameterSpec('block', DEFAULT_BLOCK,
                      'move blocking after the free steps [samples]: the correction to the '
                      'terminal LQR is held over blocks of this many steps, its forces bounded '
                      'at every step (soft, exact penalty); the rail is bounded at every '
                      'block\'s end', low=1, high=400),
        ParameterSpec('braking_time', 0.135,
                      'the rail constraint bounds x + braking_time * x_dot [s], a linear upper '
                      'bound of the rail guard\'s stopping position x + x_dot T_d + x_dot^2 / '
                      '(2 a_b) for |x_dot| up to 1.5 m/s (T_d = 5.1 ms, a_b = 5.75 m/s^2 with '
                      'the guard\'s default 30 N brake); 0 bounds the position alone',
                      low=0.0, high=2.0),
        ParameterSpec('lag', 0.0,
                      'time constant tau [s] of a first-order actuator lag in the prediction '
                      'model (tau F_dot = u - F; its F joins the state, from the commands the '
                      'manager applied); 0: none (the current loop (4.4) is 0.1 ms)',
                      low=0.0, high=0.2),
        ParameterSpec('dead_time', 0.0,
                      'dead time [s] in the prediction model beyond what the manager\'s '
                      'prediction covers (it hands the state predicted over the measured '
                      'latency); the commands in flight join the state', low=0.0, high=0.1),
        ParameterSpec('solver', 'daqp', f'QP solver, one of {list(SOLVERS)} (casadi_* are '
                      'the solvers bundled with CasADi; daqp and osqp their own wheels)',
                      choices=SOLVERS),
        ParameterSpec('budget_us', 1000.0,
                      'solve time [us] (wall, Python calls included) above which the '
                      'solution is not used: the previous plan shifted by one step instead, '
                      'counted in mpc_fallbacks; only in a real-time loop (a batch or '
                      'lockstep run is not paced by the wall clock, so its solves are always '
                      'used and the run is the same however busy the machine)',
                      low=50.0, high=1e6),
        ParameterSpec('rail_penalty', 1e6,
                      'penalty weight rho on the rail slack beyond rail_tolerance [cost per m '
                      'of excursion per group of constrained points] (l1, exact above the rail '
                      'constraint\'s multipliers): the guard enforces its boundary anyway, so a '
                      'plan that needs to cross it is not one the cart can follow',
                      low=1.0, high=1e9),
        ParameterSpec('rail_tolerance', 0.02,
                      'the first part of the rail slack of the first 10 steps [m] that costs '
                      'only 1e4 per m: a cart at rest on the bound must first move towards '
                      'it to come back (the pendulum leans away first); within '
                      'rail_clearance, so the guard\'s boundary stays clear; 0: rail_penalty '
                      'throughout', low=0.0, high=0.1),
        ParameterSpec('rail_clearance', RAIL_CLEARANCE,
                      'extra distance [m] kept inside the rail guard\'s limiter boundary '
                      '[margin + reserve, travel - margin - reserve]: a plan that parks the '
                      'cart on the boundary with the pendulum leaning towards the stop cannot '
                      'be followed (the guard withholds every push further in); 0: the '
                      'boundary itself; negative lets the MPC use that much of the reserve',
                      low=-0.1, high=0.3),
    )

    def __init__(self) -> None:
        super().__init__()
        self.qp: CondensedQp | None = None
        self.gain = np.zeros(PLANT_STATES)
        """K_d of the terminal LQR on s (its first five entries act on z)."""
        self.force_limits = (0.0, 0.0)
        """(low, high) [N]: the force at the cart the amplifier delivers, which the bounds of
        the last cycle were built from (the plant estimate's, else the nominal Appendix C)."""
        self._integral = ConditionalIntegrator()
        self._clock = StepClock()
        self._s = np.zeros(PLANT_STATES)
        self._actuator_state = np.zeros(0)
        self._actuator_a = self._actuator_b = np.zeros(0)
        self._feedforward = None
        self._ff = 0.0
        self._bounds = (0.0, 0.0)
        self.fallbacks = 0
        """Cycles whose force is not this cycle's QP's (failed or late solves)."""
        self.solve_us = 0.0
        """Wall time of the last solve [us]."""
        self.last_reason = ''
        self.last_source = ''
        self._ahead: tuple | None = None
        """(plant, r_factor, pieces): the catch's QP being built between cycles."""
        self._ready: tuple | None = None
        """(plant, r_factor, QP or None): the catch's QP built ahead (None: no stabilising
        solution for that plant, the configured QP serves)."""
        self.catch_builds = 0
        """Catches whose QP was built in the catch cycle: none built ahead for the estimate."""

    @property
    def integral(self) -> float:
        """xi = int (x - x*) dt [m s]."""
        return self._integral.value

    def on_configure(self) -> None:
        """Build the prediction model, solve the discrete Riccati equation, build the QP (once)."""
        ctx = self.context
        q = [float(v) for v in self.gains['q']]
        if q[4] <= 0.0:
            raise ValueError('mpc: the integral weight q[4] must be > 0 (the integrator\'s mode '
                             'must be seen by the cost for the Riccati equation to have a '
                             'stabilising solution)')
        for name in ('block', 'free_steps'):
            if int(self.gains[name]) > int(self.gains['horizon']):
                raise ValueError(f'mpc: {name} ({self.gains[name]}) must not exceed the '
                                 f'horizon ({self.gains["horizon"]})')
        self._feedforward = ctx.feedforward
        self.force_limits = (ctx.plant.force_min, ctx.plant.force_max)
        self.qp = self._qp_for(ctx.plant)
        self.gain = self.qp.gain_row.copy()
        model = self.qp.model
        self._s = np.zeros(model.states)
        act = model.actuator_slice
        self._actuator_a = model.a_d[act, act].copy()
        self._actuator_b = model.b_d[act, 0].copy()
        self._actuator_state = np.zeros(model.states - PLANT_STATES)
        self._nominal = (self.qp, self.gain)
        self.solved_for = ctx.plant
        """The plant model of the QP in use (the nominal one, or the estimate at the catch)."""
        self._ahead = self._ready = None

    def _qp_pieces(self, plant, r_factor: float = 1.0) -> Iterator[CondensedQp | None]:
        """The QP for ``plant`` with R times ``r_factor`` (its prediction model, terminal LQR)
        a piece at a time: None after each, the QP last (:meth:`.CondensedQp.in_pieces`)."""
        ctx = self.context
        g = self.gains
        a, b = augmented_model(*linearise_upright(plant))
        model = prediction_model(a, b, [float(v) for v in g['q']], r_factor * float(g['r']),
                                 float(ctx.sample_time), float(g['lag']), float(g['dead_time']))
        low, high = self._later_bounds()
        inset = ctx.rail_margin + ctx.rail_reserve + float(g['rail_clearance'])
        x_low, x_high = inset - ctx.x_ref, ctx.plant.travel - inset - ctx.x_ref
        if not x_low < 0.0 < x_high:
            raise ValueError(f'mpc: x* = {ctx.x_ref:g} m is outside the rail bounds '
                             f'[{inset:g}, {ctx.plant.travel - inset:g}] m')
        settings = QpSettings(int(g['horizon']), low, high, x_low, x_high,
                              float(g['rail_penalty']), solver=str(g['solver']),
                              rail_tolerance=float(g['rail_tolerance']),
                              budget=1e-6 * float(g['budget_us']) if ctx.real_time else 0.0,
                              block=int(g['block']),
                              free_steps=int(g['free_steps']),
                              braking_time=float(g['braking_time']))
        yield None
        yield from CondensedQp.in_pieces(model, settings)

    def _qp_for(self, plant, r_factor: float = 1.0) -> CondensedQp:
        """The QP of :meth:`_qp_pieces` in one go; ValueError if the plant has none."""
        for piece in self._qp_pieces(plant, r_factor):
            if piece is not None:
                return piece
        raise AssertionError('the pieces ended without a QP')

    def standby(self) -> None:
        """Between two swing-up cycles: one piece (a few milliseconds at most) of the QP the
        catch will need for the plant estimated now (:func:`.lqg.catch_plant`), so that
        :meth:`on_activate` finds it built and the catch cycle is not late. An estimate that
        moves by more than RESOLVE_TOLERANCE starts it again."""
        again = catch_plant(self.context, float(self.gains['dead_time_weight_max']))
        if again is None or (self._ready is not None and _same_catch(self._ready, again)):
            self._ahead = None
            return
        if self._ahead is None or not _same_catch(self._ahead, again):
            self._ahead = (*again, self._qp_pieces(*again))
        try:
            piece = next(self._ahead[2])
        except ValueError:  # no stabilising solution for that plant: the configured QP
            piece = None
            self._ready, self._ahead = (*self._ahead[:2], None), None
        if piece is not None:
            self._ready, self._ahead = (*self._ahead[:2], piece), None

    def _read_amplifier(self) -> None:
        """:attr:`force_limits` for this cycle: the manager's plant estimate's (its gain times
        the limits of Appendix C); outside a manager they stay nominal."""
        estimate = self.context.plant_estimate
        if estimate is not None:
            self.force_limits = estimate.force_limits()

    def _friction_scale(self) -> float:
        """The scale the manager multiplies the feedforward (6.12) by to the rig's friction
        (``PlantEstimate.used_friction``); 1 outside a manager."""
        estimate = self.context.plant_estimate
        return 1.0 if estimate is None else estimate.used_friction

    def _coulomb(self) -> tuple[float, float]:
        """``(c_L, c_R)`` [N] of the feedforward the manager adds (:meth:`_friction_scale`)."""
        ff, scale = self._feedforward, self._friction_scale()
        return scale * ff.c_left, scale * ff.c_right

    def _later_bounds(self) -> tuple[float, float]:
        """The raw force range whatever the feedforward's sign: every step after the first."""
        low, high = self.force_limits
        c_left, c_right = self._coulomb()
        return low + c_left, high - c_right

    def _first_bounds(self, state: ControllerState) -> tuple[float, float]:
        """The raw force range of this cycle's move: what the amplifier delivers and the rail
        guard passes from this state (:attr:`.ControlContext.rail_guard`: a push it would
        withhold or bend is not the move the plan predicts), less the feedforward.

        A cart moving beyond the velocity band gets its kinetic friction along the velocity
        whatever the command; a cart at rest either Coulomb level."""
        low, high = self.force_limits
        guard = self.context.rail_guard
        if guard is not None:
            low, high = guard.passed_range(state.x, state.x_dot, state.theta_dot, low, high,
                                           state.theta)
        x_dot = state.x_dot
        band = self._feedforward.velocity_band
        c_left, c_right = self._coulomb()
        if band > 0.0 and x_dot > band:
            return low - c_right, high - c_right
        if band > 0.0 and x_dot < -band:
            return low + c_left, high + c_left
        coulomb = max(c_right, c_left)
        return low + coulomb, high - coulomb

    def on_activate(self, state: ControllerState) -> None:
        """Bumpless start: the integral from zero at this state, the solver cold, no plan.

        At the catch the QP is the one for the plant the manager has estimated and R
        weighed by the loop's measured dead time (:func:`.lqg.catch_plant`), as ``lqg``
        solves its gain again (:meth:`.lqg.LqgStabilizer.on_activate`): built ahead by
        :meth:`standby` if that was for the same estimate, else now (counted in
        ``mpc_catch_builds``: a late cycle in a real-time loop). Else the configured QP.
        """
        self._integral.reset()
        self._clock.reset(state.t)
        again = catch_plant(self.context, float(self.gains['dead_time_weight_max']))
        qp, gain = self._nominal
        solved_for = self.context.plant
        if again is not None:
            ready = self._ready
            if ready is None or not _same_catch(ready, again):
                self.catch_builds += 1
                try:
                    ready = (*again, self._qp_for(*again))
                except ValueError:  # no stabilising solution for the estimate: the model's QP
                    ready = (*again, None)
                self._ready = ready
            if ready[2] is not None:
                qp, gain, solved_for = ready[2], ready[2].gain_row.copy(), ready[0]
        self._ahead = None
        self.qp, self.gain, self.solved_for = qp, gain, solved_for
        self._actuator_state[:] = 0.0
        self.qp.reset()

    def update(self, state: ControllerState) -> float:
        """The first move of the QP for s = [x - x*, theta_w, x_dot, theta_dot, xi, actuator]."""
        error_x = state.x - self.context.x_ref
        dt = self._clock.step(state.t, self.context.sample_time)
        k_i = float(self.gain[4])
        xi = self._integral.step(error_x, dt, -k_i)
        s = self._s
        s[0], s[1], s[2], s[3], s[4] = error_x, state.theta_w, state.x_dot, state.theta_dot, xi
        s[PLANT_STATES:] = self._actuator_state
        self._read_amplifier()
        first = self._first_bounds(state)
        self._bounds = first
        solution = self.qp.solve(s, first, self._later_bounds())
        self.solve_us = solution.solve_time * 1e6
        self.last_source = solution.source
        if not solution.ok:
            self.fallbacks += 1
            self.last_reason = solution.reason
            if solution.source == NONE:
                raise RuntimeError(f'no QP solved over the whole horizon ({self.qp.horizon} '
                                   f'cycles); last: {solution.reason}')
        u = solution.force
        self._ff = self._friction_scale() * self._feedforward.stabilizing(state.x_dot, u)
        effect = -k_i * error_x
        low, high = first
        if (u >= high - 1e-9 and effect > 0.0) or (u <= low + 1e-9 and effect < 0.0):
            self._integral.hold()  # the MPC's own bound: no windup against it
        return u

    def command_applied(self, feedback: CommandFeedback) -> None:
        """Anti-windup, and the actuator's states (lag, commands in flight) move on with the
        force that was applied, less the feedforward: the model's u."""
        self._integral.feedback(feedback)
        if self._actuator_state.size:
            applied = feedback.force - self._ff
            self._actuator_state[:] = (self._actuator_a @ self._actuator_state
                                       + self._actuator_b * applied)

    def status_values(self) -> dict[str, float]:
        """``mpc_solve_us`` (the last solve's wall time), ``mpc_fallbacks`` and
        ``mpc_catch_builds`` (counts)."""
        return {'mpc_solve_us': self.solve_us, 'mpc_fallbacks': self.fallbacks,
                'mpc_catch_builds': self.catch_builds}


def _same_catch(built: tuple, wanted: tuple) -> bool:
    """A QP built for ``built`` = (plant, r_factor, ...) serves ``wanted`` = (plant, r_factor):
    pendulum length and R within :data:`.lqg.RESOLVE_TOLERANCE`."""
    return abs(built[0].l / wanted[0].l - 1.0) <= RESOLVE_TOLERANCE and \
        abs(built[1] / wanted[1] - 1.0) <= RESOLVE_TOLERANCE
