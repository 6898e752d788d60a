"""Time-optimal swing-up: track a minimum-time plan with time-varying LQR, fall back to energy_saturated.

The plan is the solution of the minimum-time problem of
:mod:`cartpole_control.trajectory_optimization` from hanging rest at the
activation's cart position, for the controller's plant model (the manager's
nominal parameters), on the 5 ms control grid, with a fraction
``force_scale`` of the amplifier limits (the rest is headroom for the
feedback and the friction feedforward), ``rail_margin`` kept from both end
stops, and a calm hand-over: at the final time the pendulum is in the catch
region (|theta_w| <= 10 deg, energy within 5 %), the cart within
``terminal_window`` of x* and slower than ``terminal_speed``.

Design notes: docs/controllers.md ("Design notes by module", ``cartpole_control.controllers.time_optimal``).
"""
from __future__ import annotations

import logging
import math
import queue
import subprocess
import threading
import weakref
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from cartpole_core.model import CartPoleParameters

from ..controller import SWINGUP, ControlContext, Controller, ControllerState, ParameterSpec
from ..plan_cache import (CachedPlan, PlanError, Progress, TrajectoryCache,
                          cached_tracking_gains, solve_cached, start_background_solve)
from ..trajectory_optimization import CatchRegion, MinimumTimeProblem, Trajectory
from .energy_saturated import EnergySaturatedSwingUp

logger = logging.getLogger(__name__)

PLAN = 'plan'
FALLBACK = 'fallback'

PLAN_INTERVALS = 70
"""Shooting intervals of the plan's free-time solves (before the fixed 5 ms grid)."""


def plan_start(x0: float, travel: float) -> float:
    """The planned start for a hanging rest at ``x0``: rounded to 1 cm, on the rail."""
    return min(max(round(float(x0), 2), 0.0), travel)


def plan_problem(params: CartPoleParameters, x_ref: float, x0: float, gains) -> MinimumTimeProblem:
    """The minimum-time problem the plugin plans for a start at rest hanging at ``x0``."""
    return MinimumTimeProblem(
        params, (plan_start(x0, params.travel), math.pi, 0.0, 0.0),
        CatchRegion(angle=math.radians(float(gains['terminal_angle_deg'])),
                    energy_tolerance=float(gains['terminal_energy_tolerance'])),
        force_scale=float(gains['force_scale']), rail_margin=float(gains['rail_margin']),
        friction=True, terminal_cart_speed=float(gains['terminal_speed']),
        terminal_cart_window=float(gains['terminal_window']), terminal_cart_ref=float(x_ref),
        terminal_hold=float(gains['terminal_hold']))


def at_hanging_rest(state: ControllerState, gains: Mapping[str, Any]) -> bool:
    """Hanging (theta within ``start_tolerance_theta`` of pi) and at rest."""
    return (abs(math.remainder(state.theta - math.pi, 2.0 * math.pi))
            <= gains['start_tolerance_theta']
            and abs(state.theta_dot) <= gains['start_tolerance_rate']
            and abs(state.x_dot) <= gains['start_tolerance_rate'])


@dataclass(frozen=True)
class PreparedPlan:
    """A plan read from the cache with its TV-LQR gains: all an activation needs."""

    ident: tuple
    """(problem key, q, r): what it was prepared for."""
    plan: Trajectory
    gains: np.ndarray | None
    """K_k (N, 4); None for an unsuccessful plan."""


def solve_plan_for(plant: CartPoleParameters, x_ref: float, sample_time: float,
                   gains: Mapping[str, Any], x0: float,
                   progress: Progress | None = None) -> CachedPlan:
    """The plan the plugin with ``gains`` tracks from hanging rest at ``x0``: cached or solved now.

    Blocks for the solve (about 10 s of CPU); says so to ``progress`` first.
    Raises :class:`~cartpole_control.plan_cache.PlanError` when the solve raised.
    """
    problem = plan_problem(plant, x_ref, x0, gains)
    cache = TrajectoryCache(gains['cache_dir'] or None)
    if not cache.has(problem.key(sample_time)):
        _say(progress, f'time_optimal: solving the minimum-time plan from hanging rest at '
                       f'x = {problem.start[0]:.2f} m (not in the cache {cache.directory}; '
                       'about 10 s) ...')
    return solve_cached(problem, sample_time, cache, progress=progress, n_intervals=PLAN_INTERVALS)


def _say(progress: Progress | None, text: str) -> None:
    if progress is not None:
        progress(text)
    else:
        logger.warning(text)


class TimeOptimalSwingUp(Controller):
    """Minimum-time swing-up plan tracked by time-varying LQR, energy_saturated as fall-back.

    The plan, its tracking and the fall-backs are in the module docstring.
    """

    kind = SWINGUP
    name = 'time_optimal'
    parameters = (
        ParameterSpec('force_scale', 0.9, 'fraction of the amplifier limits the plan may use',
                      low=0.3, high=1.0),
        ParameterSpec('rail_margin', 0.05, 'distance the plan keeps from each end stop [m]',
                      low=0.0, high=0.2),
        ParameterSpec('terminal_angle_deg', 10.0, 'plan: |theta_w| at the final time below '
                      'this [deg] (the upright region of the run summary: 10)', low=1.0, high=30.0),
        ParameterSpec('terminal_energy_tolerance', 0.03, 'plan: |E_p - E*| <= this E* at the '
                      'final time (tighter than the catch trigger\'s 0.05: calmer hand-over)',
                      low=0.005, high=0.2),
        ParameterSpec('terminal_speed', 0.15, 'plan: |x_dot| at the final time below this [m/s]',
                      low=0.0, high=5.0),
        ParameterSpec('terminal_window', 0.1, 'plan: |x - x*| at the final time below this [m]',
                      low=0.0, high=0.4),
        ParameterSpec('terminal_hold', 0.15, 'plan: the energy band and the cart bounds hold '
                      'over the last this many seconds (the catch trigger may fire there) [s]',
                      low=0.0, high=0.5),
        ParameterSpec('q', (300.0, 300.0, 10.0, 10.0), 'TV-LQR state weights on the deviation '
                      'from the plan (x, theta, x_dot, theta_dot)', low=0.0, high=1e6, length=4),
        ParameterSpec('r', 0.02, 'TV-LQR force weight [1/N^2]', low=1e-6, high=1e3),
        ParameterSpec('abort_x', 0.12, 'fall back when |x - xbar| exceeds this [m]',
                      low=0.001, high=1.0),
        ParameterSpec('abort_theta', 0.5, 'fall back when |theta - thetabar| exceeds this [rad]',
                      low=0.001, high=math.pi),
        ParameterSpec('start_tolerance_x', 0.03, 'a planned start is used within this distance '
                      '[m]', low=0.0, high=0.2),
        ParameterSpec('start_tolerance_theta', 0.08, 'a start counts as hanging within this '
                      'angle of pi [rad]', low=0.0, high=0.5),
        ParameterSpec('start_tolerance_rate', 0.15, 'a start counts as at rest below these '
                      'rates [m/s, rad/s]', low=0.0, high=2.0),
        ParameterSpec('precompute', True, 'on configure, load the plan for the default start '
                      'plan_x0 and build its TV-LQR gains (if it is not cached, solve it in a '
                      'background process)'),
        ParameterSpec('plan_on_activation', True, 'on an activation from a hanging rest with '
                      'no plan loaded, load it (or solve it in a background process) for the '
                      'next swing-up from there'),
        ParameterSpec('plan_x0', 0.0, 'default start: cart position of the hanging rest to plan '
                      'for on configure [m] (0: the left stop, the thesis procedure)',
                      low=0.0, high=0.769),
        ParameterSpec('cache_dir', '', 'directory of the plan cache; empty: '
                      '$CARTPOLE_CACHE_DIR or ~/.cache/cartpole/trajectories'),
    )

    def __init__(self) -> None:
        super().__init__()
        self.fallback = EnergySaturatedSwingUp()
        self.mode = FALLBACK
        self.fallback_reason = ''
        self._law = self.name
        self._prepared: dict[float, PreparedPlan] = {}
        """Plans ready for an activation, by planned start (:func:`plan_start`)."""
        self._requested: set[str] = set()
        """Problem keys this instance has started a background solve for (once each)."""
        self._workers: list[subprocess.Popen] = []
        self._loading: set[float] = set()
        self._requests: queue.SimpleQueue | None = None
        """Loads asked for by activations, for the dispatcher thread (see _load_later)."""
        """Starts a worker thread is loading a plan for."""
        self._why: tuple[str, str] = ('', '')
        self._plan: Trajectory | None = None
        self._gains_k: np.ndarray | None = None
        self._t0 = 0.0
        self._theta_offset = 0.0

    @property
    def law(self) -> str:
        """``time_optimal`` before the first activation, then ``time_optimal:plan`` or
        ``time_optimal:fallback(<why>)`` (module docstring)."""
        return self._law

    # -- preparation (outside the control cycle) ----------------------------------------------
    @property
    def cache(self) -> TrajectoryCache:
        return TrajectoryCache(self.gains['cache_dir'] or None)

    def problem_for(self, x0: float) -> MinimumTimeProblem:
        """The plan problem for a hanging rest at ``x0`` with the current gains and context."""
        c = self.context
        return plan_problem(c.plant, c.x_ref, x0, self.gains)

    @classmethod
    def prepare(cls, gains: Mapping[str, Any], context: ControlContext, start: ControllerState,
                progress: Progress | None = None) -> dict[str, Any]:
        """Solve the plan for a run from ``start`` now if it is not cached (blocks, seconds).

        Returns the gains that make the run's instance load it on configure
        (``plan_x0`` = the start, ``precompute``) and solve nothing in the
        background during a run that was prepared (``plan_on_activation`` false).
        """
        g = cls.defaults()
        g.update(cls.validate_gains(gains))
        if not at_hanging_rest(start, g):
            _say(progress, f'time_optimal: the start (theta = {start.theta:.3f} rad) is not a '
                           'hanging rest: no plan; energy_saturated swings up')
            return {'precompute': False, 'plan_on_activation': False}
        x0 = plan_start(start.x, context.plant.travel)
        overrides = {'plan_x0': x0, 'plan_on_activation': False}
        try:
            result = solve_plan_for(context.plant, context.x_ref, context.sample_time, g, x0,
                                    progress)
        except PlanError as error:
            _say(progress, f'time_optimal: the plan solve failed ({error}); energy_saturated '
                           'swings up')
            return dict(overrides, precompute=False)
        plan = result.plan
        if plan.success:  # built now, read by the run's configure
            problem = plan_problem(context.plant, context.x_ref, x0, g)
            cached_tracking_gains(problem, plan, problem.key(context.sample_time),
                                  tuple(g['q']), g['r'], TrajectoryCache(g['cache_dir'] or None))
        if result.solved or not plan.success:
            _say(progress, f'time_optimal: plan from x = {x0:.2f} m: ' + (
                f'T = {plan.final_time:.3f} s (solved in {plan.solve_time:.1f} s, {result.path})'
                if plan.success else f'the optimiser found none ({result.path}); '
                'energy_saturated swings up'))
        return dict(overrides, precompute=True)

    def on_configure(self) -> None:
        c: ControlContext = self.context
        self.fallback.configure({}, c)
        if c.plant.travel - 2.0 * self.gains['rail_margin'] <= 0.1:
            raise ValueError(f'rail_margin {self.gains["rail_margin"]:g} leaves no travel')
        if self.gains['plan_x0'] > c.plant.travel:
            raise ValueError(f'plan_x0 {self.gains["plan_x0"]:g} is beyond the travel '
                             f'{c.plant.travel:g} m')
        if c.validation_only:
            return
        self._workers = [w for w in self._workers if w.poll() is None]
        # Plans prepared for other gains or another context are no longer valid.
        self._prepared = {x0: p for x0, p in self._prepared.items()
                          if p.ident == self._ident(x0, self.gains, c)}
        if self.gains['precompute']:
            self.load_plan(self.gains['plan_x0'], solve_missing=c.real_time)
        if self.gains['plan_on_activation'] and self._requests is None:
            # Started here, outside the control cycle: an activation only queues a request.
            self._requests = queue.SimpleQueue()
            threading.Thread(target=_dispatch_loads, args=(weakref.ref(self), self._requests),
                             name='time_optimal-loads', daemon=True).start()

    @staticmethod
    def _ident(x0: float, gains: Mapping[str, Any], context: ControlContext) -> tuple:
        problem = plan_problem(context.plant, context.x_ref, x0, gains)
        return (problem.key(context.sample_time), tuple(gains['q']), gains['r'])

    def load_plan(self, x0: float, solve_missing: bool) -> PreparedPlan | None:
        """Read the plan for a hanging rest at ``x0`` and build its gains (milliseconds).

        A plan not in the cache is solved in a background process if
        ``solve_missing`` (announced); None then.
        """
        gains, context = self.gains, self.context  # a worker thread: the values at its start
        x0 = plan_start(x0, context.plant.travel)
        ident = self._ident(x0, gains, context)
        have = self._prepared.get(x0)
        if have is not None and have.ident == ident:
            return have
        problem = plan_problem(context.plant, context.x_ref, x0, gains)
        cache = TrajectoryCache(gains['cache_dir'] or None)
        plan = cache.get(ident[0])
        if plan is None:
            if solve_missing:
                self._solve_in_background(problem, cache, x0, context.sample_time,
                                          (ident[1], ident[2]))
            return None
        if plan.success:
            k_gains = cached_tracking_gains(problem, plan, *ident, cache)
            prepared = PreparedPlan(ident, plan, k_gains)
        else:
            prepared = PreparedPlan(ident, plan, None)
            logger.warning('time_optimal: the optimiser found no plan from x = %.2f m (%s); '
                           'swing-ups from there use energy_saturated', x0, cache.path(ident[0]))
        if self.gains is gains:  # not reconfigured meanwhile (a worker thread)
            self._prepared[x0] = prepared
        return prepared

    def _solve_in_background(self, problem: MinimumTimeProblem, cache: TrajectoryCache,
                             x0: float, grid: float, tvlqr: tuple) -> None:
        key = problem.key(grid)
        if key in self._requested:
            return  # once per instance: a failing solve is not started again and again
        self._requested.add(key)
        previous = cache.failure(key)
        try:
            worker = start_background_solve(problem, grid, cache, tvlqr,
                                            n_intervals=PLAN_INTERVALS)
        except OSError as error:
            logger.warning('time_optimal: cannot start the plan solve for x = %.2f m (%s); '
                           'swing-ups from there use energy_saturated', x0, error)
            return
        if worker is None:
            logger.warning('time_optimal: no plan for hanging rest at x = %.2f m yet; another '
                           'process is solving it (%s)', x0, cache.lock(key).path)
            return
        self._workers.append(worker)
        logger.warning('time_optimal: no plan for hanging rest at x = %.2f m yet: solving it in '
                       'background process %d (log %s); swing-ups from there use '
                       'energy_saturated until it is loaded%s', x0, worker.pid,
                       cache.log_path(key), f' (the last solve failed: {previous})'
                       if previous else '')

    def _load_later(self, x0: float) -> None:
        """After an activation without a plan: load it (or solve it) off the cycle.

        The cycle only queues the request (microseconds); the dispatcher
        thread started at configure starts the worker. Starting a thread in
        the cycle cost up to the interpreter's 5 ms switch interval: the new
        thread ran first, holding the GIL.
        """
        if x0 in self._loading:
            return
        self._loading.add(x0)
        if self._requests is not None:
            self._requests.put(x0)
        else:
            self._start_load(x0)

    def _start_load(self, x0: float) -> None:
        def work() -> None:
            try:
                self.load_plan(x0, solve_missing=True)
            except Exception:  # a damaged cache must not go unnoticed, nor break the loop
                logger.exception('time_optimal: loading the plan for x = %.2f m failed', x0)
            finally:
                self._loading.discard(x0)

        # Not a daemon: milliseconds of work, joined before the interpreter exits.
        threading.Thread(target=work, name=f'time_optimal-load-{x0:.2f}').start()

    # -- lifecycle ---------------------------------------------------------------------------------
    def on_activate(self, state: ControllerState) -> None:
        """Track the plan prepared for this start, else the fall-back (module docstring)."""
        self._plan = self._gains_k = None
        self._t0 = state.t
        if not at_hanging_rest(state, self.gains):
            self._fall_back(state, 'not at hanging rest')
            return
        x0 = plan_start(state.x, self.context.plant.travel)
        prepared = self._prepared.get(x0)
        if prepared is None:
            self._fall_back(state, 'no plan', f'none loaded for x = {x0:.2f} m')
            if self.gains['plan_on_activation']:
                self._load_later(x0)
        elif prepared.gains is None:
            self._fall_back(state, 'no feasible plan',
                            f'the optimiser found none from x = {x0:.2f} m')
        elif abs(prepared.plan.states[0, 0] - state.x) > self.gains['start_tolerance_x']:
            self._fall_back(state, 'start off the plan')
        else:
            self._plan, self._gains_k = prepared.plan, prepared.gains
            # The plan's theta runs from pi; follow the unwrapped angle of this start.
            self._theta_offset = state.theta - math.remainder(state.theta - math.pi,
                                                              2.0 * math.pi) - math.pi
            self.mode, self.fallback_reason = PLAN, ''
            self._law = f'{self.name}:{PLAN}'

    running_state = ('mode', 'fallback_reason', '_law', '_plan', '_gains_k', '_t0',
                     '_theta_offset', '_why')

    def take_over(self, previous: Controller, state: ControllerState) -> None:
        """Go on with ``previous``'s swing-up (new gains while it runs): the plan it tracks
        (with its gains) or its fall-back; nothing is looked up or logged."""
        self.active = True
        for attribute in self.running_state:
            setattr(self, attribute, getattr(previous, attribute))
        if self.mode == FALLBACK:
            self.fallback.take_over(previous.fallback, state)

    def _fall_back(self, state: ControllerState, why: str, detail: str = '') -> None:
        self.mode = FALLBACK
        self.fallback_reason = f'{why}: {detail}' if detail else why
        self._law = f'{self.name}:{FALLBACK}({why})'
        self._plan = None
        logger.warning('time_optimal: swing-up at t = %.3f s from x = %.3f m falls back to '
                       'energy_saturated: %s', state.t, state.x, self.fallback_reason)
        self.fallback.activate(state)

    def on_deactivate(self) -> None:
        if self.fallback.active:
            self.fallback.deactivate()

    # -- the law -----------------------------------------------------------------------------------
    def planned_force(self, state: ControllerState) -> float | None:
        """F_k = Fbar_k - K_k (x_k - xbar_k), or None when the plan is invalid or over."""
        plan, gains_k = self._plan, self._gains_k
        k = int(round((state.t - self._t0) / plan.dt))
        if k >= len(plan.forces):
            self._why = 'plan ended', 'before the catch'
            return None
        k = max(k, 0)
        ref = plan.states[k]
        dev = np.array([state.x - ref[0], state.theta - self._theta_offset - ref[1],
                        state.x_dot - ref[2], state.theta_dot - ref[3]])
        if abs(dev[0]) > self.gains['abort_x'] or abs(dev[1]) > self.gains['abort_theta']:
            self._why = 'tracking error', (f'x {dev[0]:+.3f} m, theta {dev[1]:+.3f} rad at '
                                           f'{k * plan.dt:.3f} s')
            return None
        return float(plan.forces[k] - gains_k[k] @ dev)

    def update(self, state: ControllerState) -> float:
        """Raw force [N]: the tracked plan minus the manager's feedforward, or the fall-back's."""
        if self.mode == PLAN:
            force = self.planned_force(state)
            if force is not None:
                return force - self.context.feedforward(state.x_dot, force)
            self._fall_back(state, *self._why)
        return self.fallback.update(state)


def _dispatch_loads(owner: 'weakref.ref[TimeOptimalSwingUp]', requests: queue.SimpleQueue) -> None:
    """Start the plan loads that ``owner``'s activations queued; end with the plugin.

    A daemon: it only waits and starts the (non-daemon) load workers, so
    nothing is cut short when the interpreter exits.
    """
    while True:
        try:
            x0 = requests.get(timeout=1.0)
        except queue.Empty:
            if owner() is None:
                return
            continue
        plugin = owner()
        if plugin is None:
            return
        plugin._start_load(x0)
        del plugin
