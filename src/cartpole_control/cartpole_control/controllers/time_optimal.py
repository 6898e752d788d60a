"""Time-optimal swing-up: track a minimum-time plan with time-varying LQR, fall back to energy_saturated.

The plan (issue #7) is the solution of the minimum-time problem of
:mod:`cartpole_control.trajectory_optimization` from hanging rest at the
activation's cart position, for the controller's plant model (the manager's
nominal parameters), on the 5 ms control grid, with a fraction
``force_scale`` of the amplifier limits (the rest is headroom for the
feedback and the friction feedforward), ``rail_margin`` kept from both end
stops, and a calm hand-over: at the final time the pendulum is in the catch
region (|theta_w| <= 10 deg, energy within 5 %), the cart within
``terminal_window`` of x* and slower than ``terminal_speed``.

Tracking. With the plan (xbar_k, Fbar_k) and the time-varying LQR gains
K_k of the RK4-discretised model linearised along it
(:func:`~cartpole_control.trajectory_optimization.tracking_gains`, stage cost
diag(q) and r), the desired actuator force is

    F_k = Fbar_k - K_k (x_k - xbar_k),   k = round((t - t_activation) / Ts).

The plan's model contains the cart friction, so Fbar already pays for it;
the manager adds the feedforward (6.12) c_c(x_dot) tanh(k u) on top of the
raw output. The plugin subtracts that (the manager's own feedforward, handed
over in :attr:`ControlContext.feedforward`), so the actuator gets F_k.

Fall-back to :class:`~.energy_saturated.EnergySaturatedSwingUp` (its default
gains) when

- no plan is ready for the start: the activation state is not hanging at
  rest within the ``start_tolerance_*`` of a planned start, or the plan for it
  is still being solved (or failed);
- the tracking error exceeds ``abort_x`` or ``abort_theta`` (the plan is no
  longer valid: a different plant, a push);
- the plan has ended without the manager's catch.

The loop never waits for IPOPT. Plans are solved in a background thread
(CasADi releases the GIL while IPOPT runs) and stored in an on-disk cache
(:class:`~cartpole_control.trajectory_optimization.TrajectoryCache`, key = hash
of the parameters, the start and the options): on configure for the default
start (``plan_x0``, hanging at rest) when ``precompute`` is true, and on an
activation from a hanging rest with no plan (that swing-up uses the
fall-back; the next one from there uses the plan). A lock file per key keeps
several instances from solving the same problem twice. A plan that was not
ready when the swing-up started is never used for it, so a run is
deterministic given the cache.

Assumptions: no stiction (the Coulomb friction of (4.20) with the level of
(4.27), smoothed), force limits as given (Appendix C), the nominal plant.
No ROS import.
"""
from __future__ import annotations

import math
import os
import threading
import time
from pathlib import Path

import numpy as np

from cartpole_sim.model import CartPoleParameters

from ..controller import SWINGUP, ControlContext, Controller, ControllerState, ParameterSpec
from ..trajectory_optimization import (CatchRegion, MinimumTimeProblem, Trajectory,
                                       TrajectoryCache, solve_minimum_time, tracking_gains)
from .energy_saturated import EnergySaturatedSwingUp

PLAN = 'plan'
FALLBACK = 'fallback'

LOCK_STALE_S = 900.0
"""A lock file older than this is from a solver that died; it is ignored."""


def plan_problem(params: CartPoleParameters, x_ref: float, x0: float, gains) -> MinimumTimeProblem:
    """The minimum-time problem the plugin plans for a start at rest hanging at ``x0``."""
    x0 = min(max(round(float(x0), 2), 0.0), params.travel)
    return MinimumTimeProblem(
        params, (x0, math.pi, 0.0, 0.0),
        CatchRegion(angle=math.radians(float(gains['terminal_angle_deg'])),
                    energy_tolerance=float(gains['terminal_energy_tolerance'])),
        force_scale=float(gains['force_scale']), rail_margin=float(gains['rail_margin']),
        friction=True, terminal_cart_speed=float(gains['terminal_speed']),
        terminal_cart_window=float(gains['terminal_window']), terminal_cart_ref=float(x_ref),
        terminal_hold=float(gains['terminal_hold']))


def solve_plan(problem: MinimumTimeProblem, cache: TrajectoryCache, grid: float) -> Trajectory:
    """Solve ``problem`` on ``grid`` (or read it from ``cache``), storing the result.

    A lock file ``<key>.lock`` marks a solve in progress for other instances.
    """
    key = problem.key(grid)
    cached = cache.get(key)
    if cached is not None:
        return cached
    traj = solve_minimum_time(problem, n_intervals=70, grid=grid)
    cache.put(key, traj)
    return traj


class TimeOptimalSwingUp(Controller):
    """Minimum-time plan tracked by TV-LQR, energy_saturated fall-back (module docstring)."""

    kind = SWINGUP
    name = 'time_optimal'
    parameters = (
        ParameterSpec('force_scale', 0.9, 'fraction of the amplifier limits the plan may use',
                      low=0.3, high=1.0),
        ParameterSpec('rail_margin', 0.05, 'distance the plan keeps from each end stop [m]',
                      low=0.0, high=0.2),
        ParameterSpec('terminal_angle_deg', 10.0, 'plan: |theta_w| at the final time below '
                      'this [deg] (the issue\'s catch region: 10)', low=1.0, high=30.0),
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
        ParameterSpec('precompute', True, 'on configure, solve (in the background) the plan for '
                      'the default start plan_x0'),
        ParameterSpec('plan_on_activation', True, 'on an activation from a hanging rest with '
                      'no plan, solve one in the background for the next swing-up from there'),
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
        self._plan: Trajectory | None = None
        self._gains_k: np.ndarray | None = None
        self._t0 = 0.0
        self._theta_offset = 0.0
        self._threads: list[threading.Thread] = []

    # -- set-up -------------------------------------------------------------------------------
    @property
    def cache(self) -> TrajectoryCache:
        return TrajectoryCache(self.gains['cache_dir'] or None)

    def problem_for(self, x0: float) -> MinimumTimeProblem:
        """The plan problem for a hanging rest at ``x0`` with the current gains and context."""
        c = self.context
        return plan_problem(c.plant, c.x_ref, x0, self.gains)

    def on_configure(self) -> None:
        c: ControlContext = self.context
        self.fallback.configure({}, c)
        if c.plant.travel - 2.0 * self.gains['rail_margin'] <= 0.1:
            raise ValueError(f'rail_margin {self.gains["rail_margin"]:g} leaves no travel')
        if self.gains['plan_x0'] > c.plant.travel:
            raise ValueError(f'plan_x0 {self.gains["plan_x0"]:g} is beyond the travel '
                             f'{c.plant.travel:g} m')
        if self.gains['precompute'] and not c.validation_only:
            self.request_plan(self.gains['plan_x0'])

    def request_plan(self, x0: float) -> bool:
        """Start a background solve for the hanging rest at ``x0`` unless cached or running.

        Returns True if a solve was started.
        """
        problem = self.problem_for(x0)
        cache = self.cache
        grid = self.context.sample_time
        key = problem.key(grid)
        if cache.path(key).is_file():
            return False
        lock = cache.path(key).with_suffix('.lock')
        try:
            lock.parent.mkdir(parents=True, exist_ok=True)
            if lock.exists() and time.time() - lock.stat().st_mtime > LOCK_STALE_S:
                lock.unlink(missing_ok=True)
            fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
            os.close(fd)
        except FileExistsError:
            return False
        except OSError:
            return False  # no writable cache: the fall-back runs, nothing else breaks

        def work() -> None:
            try:
                solve_plan(problem, cache, grid)
            except Exception:  # a failed solve leaves no plan; the fall-back covers it
                pass
            finally:
                Path(lock).unlink(missing_ok=True)

        thread = threading.Thread(target=work, name=f'time_optimal-{key[:8]}', daemon=True)
        self._threads = [t for t in self._threads if t.is_alive()] + [thread]
        thread.start()
        return True

    def wait_for_plans(self, timeout: float | None = None) -> bool:
        """Block until this instance's background solves end (for batch use and tests)."""
        deadline = None if timeout is None else time.monotonic() + timeout
        for thread in list(self._threads):
            remaining = None if deadline is None else max(0.0, deadline - time.monotonic())
            thread.join(remaining)
        return not any(t.is_alive() for t in self._threads)

    # -- lifecycle ---------------------------------------------------------------------------------
    def _at_hanging_rest(self, state: ControllerState) -> bool:
        g = self.gains
        return (abs(math.remainder(state.theta - math.pi, 2.0 * math.pi)) <= g['start_tolerance_theta']
                and abs(state.theta_dot) <= g['start_tolerance_rate']
                and abs(state.x_dot) <= g['start_tolerance_rate'])

    def activate(self, state: ControllerState) -> None:
        """Use the cached plan for this start if there is one, else the fall-back (and plan)."""
        super().activate(state)
        self._plan = None
        self._gains_k = None
        reason = ''
        if not self._at_hanging_rest(state):
            reason = 'start is not a hanging rest'
        else:
            problem = self.problem_for(state.x)
            plan = self.cache.get(problem.key(self.context.sample_time))
            if plan is None:
                reason = 'no plan for this start yet'
                if self.gains['plan_on_activation'] and self.request_plan(state.x):
                    reason += ' (solving in the background)'
            elif not plan.success:
                reason = 'the optimiser found no plan for this start'
            elif abs(plan.states[0, 0] - state.x) > self.gains['start_tolerance_x']:
                reason = 'start too far from the planned one'
            else:
                self._plan = plan
                self._gains_k = tracking_gains(problem, plan, self.gains['q'], self.gains['r'])
                # The plan's theta runs from pi; follow the unwrapped angle of this start.
                self._theta_offset = state.theta - math.remainder(state.theta - math.pi,
                                                                  2.0 * math.pi) - math.pi
        self._t0 = state.t
        if self._plan is not None:
            self.mode, self.fallback_reason = PLAN, ''
        else:
            self._fall_back(state, reason)

    def _fall_back(self, state: ControllerState, reason: str) -> None:
        self.mode = FALLBACK
        self.fallback_reason = reason
        self._plan = None
        self.fallback.activate(state)

    def deactivate(self) -> None:
        super().deactivate()
        if self.fallback.active:
            self.fallback.deactivate()

    # -- the law -----------------------------------------------------------------------------------
    def planned_force(self, state: ControllerState) -> float | None:
        """F_k = Fbar_k - K_k (x_k - xbar_k), or None when the plan is invalid or over."""
        plan, gains_k = self._plan, self._gains_k
        k = int(round((state.t - self._t0) / plan.dt))
        if k >= len(plan.forces):
            self.fallback_reason = 'plan ended before the catch'
            return None
        k = max(k, 0)
        ref = plan.states[k]
        dev = np.array([state.x - ref[0], state.theta - self._theta_offset - ref[1],
                        state.x_dot - ref[2], state.theta_dot - ref[3]])
        if abs(dev[0]) > self.gains['abort_x'] or abs(dev[1]) > self.gains['abort_theta']:
            self.fallback_reason = (f'tracking error x {dev[0]:+.3f} m, theta {dev[1]:+.3f} rad '
                                    f'at {k * plan.dt:.3f} s')
            return None
        return float(plan.forces[k] - gains_k[k] @ dev)

    def update(self, state: ControllerState) -> float:
        """Raw force [N]: the tracked plan minus the manager's feedforward, or the fall-back's."""
        if self.mode == PLAN:
            force = self.planned_force(state)
            if force is not None:
                return force - self.context.feedforward(state.x_dot, force)
            self._fall_back(state, self.fallback_reason)
        return self.fallback.update(state)
