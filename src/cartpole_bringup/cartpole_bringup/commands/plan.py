"""`cartpole plan`: solve and cache the minimum-time plan ``time_optimal`` tracks (no ROS).

The plan is the one the ``time_optimal`` swing-up uses from hanging rest at
the start (:mod:`cartpole_control.controllers.time_optimal`), for the
controllers' plant model and the ``time_optimal.*`` gains of ``--params``;
it goes into the plan cache (:mod:`cartpole_control.plan_cache`), where the
controller finds it on configure. Printed: the minimum-time bound from that
start (full force, whole rail, as `cartpole bound`), the plan's duration, and
the file.

Also here: :func:`prepare_for_run`, the plugins' slow work before a lockstep
`cartpole run`.
"""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Any

from .. import boundary, options

BOUND_INTERVALS = (70, 140)
"""Shooting intervals of the bound's multi-start solves and of its refinement (`cartpole bound`)."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--x0', type=float, default=None, metavar='M',
                        help='cart position of the hanging rest to plan from [m] (default: '
                             'time_optimal.plan_x0 of --params, else 0: the left stop, where '
                             'every run starts by default)')
    parser.add_argument('--params', type=Path, default=None, metavar='FILE.yaml',
                        help='ROS 2 parameters file: its controller_manager section '
                             '(time_optimal.* gains, x_ref)')
    parser.add_argument('--plant-params', type=Path, default=None, metavar='FILE.yaml',
                        help="the controllers' plant model (CartPoleParameters YAML); default: "
                             'thesis values')
    parser.add_argument('--force', action='store_true',
                        help='solve again even if the plan is cached')
    parser.add_argument('--no-bound', action='store_true',
                        help='skip the minimum-time bound (another solve of some seconds, cached '
                             'too)')
    options.add_output_arguments(parser)


def _manager(nominal, parameters: dict[str, Any]):
    from cartpole_control.manager import ControllerManager
    manager = ControllerManager(nominal, sample_time=nominal.sample_time, real_time=False)
    result = manager.set_parameters(parameters)
    if not result.successful:
        raise ValueError(result.reason)
    return manager


def prepare_for_run(args: argparse.Namespace, nominal, label: str) -> dict[str, Any]:
    """Before a lockstep run: the configured plugins' slow work for its start (blocking).

    ``time_optimal`` solves a missing plan now, with progress lines on stderr,
    so that the manager (in this process or its own) finds it in the cache.
    Returns the controller_manager parameters the plugins ask for.
    """
    from cartpole_control.controller import ControllerState

    from .offline import manager_parameters_from_args
    manager = _manager(nominal, manager_parameters_from_args(args))
    return manager.prepare(ControllerState(0.0, args.x0, args.theta0, 0.0, 0.0),
                           options.progress_printer(label))


def main(args: argparse.Namespace) -> int:
    from cartpole_control.controllers.time_optimal import (TimeOptimalSwingUp, plan_problem,
                                                           solve_plan_for)
    from cartpole_control.plan_cache import (PlanError, TrajectoryCache, cached_tracking_gains,
                                             solve_cached)
    from cartpole_control.trajectory_optimization import MinimumTimeProblem

    say = options.progress_printer('cartpole plan')
    nominal = options.nominal_parameters(args)
    parameters = options.manager_parameters(nominal, args)  # the file's section, whole
    parameters['swingup'] = TimeOptimalSwingUp.name
    try:
        values = _manager(nominal, parameters).get_parameters()
    except (ValueError, TypeError) as error:
        raise boundary.InputError(f'--params {args.params}: controller_manager: {error}') \
            from None
    prefix = TimeOptimalSwingUp.name + '.'
    gains = {k[len(prefix):]: v for k, v in values.items() if k.startswith(prefix)}
    x0 = float(gains['plan_x0'] if args.x0 is None else args.x0)
    if not (math.isfinite(x0) and 0.0 <= x0 <= nominal.travel):
        option = '--x0' if args.x0 is not None else f'--params {args.params}: time_optimal.plan_x0'
        raise boundary.InputError(f'{option} {x0} m is outside the travel [0, '
                                  f'{nominal.travel}] m')
    x_ref, ts = float(values['x_ref']), nominal.sample_time
    problem = plan_problem(nominal, x_ref, x0, gains)
    cache = TrajectoryCache(gains['cache_dir'] or None)
    if args.force:
        cache.path(problem.key(ts)).unlink(missing_ok=True)
    try:
        result = solve_plan_for(nominal, x_ref, ts, gains, x0, say)
    except PlanError as error:
        print(f'cartpole plan: the solve failed: {error}', file=sys.stderr)
        return 1
    plan = result.plan
    if plan.success:  # the TV-LQR gains too, so that the controller's configure only reads
        cached_tracking_gains(problem, plan, problem.key(ts), tuple(gains['q']), gains['r'],
                              cache)
    bound = None
    if not args.no_bound:
        problem = MinimumTimeProblem(nominal, (round(x0, 2), math.pi, 0.0, 0.0), friction=True)
        if not cache.has(problem.key(None)):
            say(f'solving the minimum-time bound from x = {x0:.2f} m (full force, whole rail) ...')
        try:
            found = solve_cached(problem, None, cache, progress=say,
                                 n_intervals=BOUND_INTERVALS[0], refine_intervals=BOUND_INTERVALS[1])
            bound = found.plan.final_time if found.plan.success else None
        except PlanError as error:
            say(f'the bound solve failed: {error}')
    out = {'x0_m': round(x0, 2), 'x_ref_m': x_ref,
           'bound_s': None if bound is None else round(bound, 4),
           'plan_duration_s': round(plan.final_time, 4) if plan.success else None,
           'plan_success': plan.success,
           'ratio_to_bound': (round(plan.final_time / bound, 3)
                              if plan.success and bound else None),
           'solved': result.solved, 'solve_time_s': round(plan.solve_time, 2),
           'file': str(result.path)}
    if args.json:
        options.print_json(out)
    else:
        print(f'time_optimal plan from hanging rest at x = {out["x0_m"]:.2f} m (x* = {x_ref:.4g} m)')
        print(f'  minimum-time bound (full force, whole rail): '
              f'{"-" if bound is None else f"{bound:.3f} s"}')
        if plan.success:
            ratio = f' ({out["ratio_to_bound"]:.2f} x the bound)' if bound else ''
            print(f'  plan duration: {plan.final_time:.3f} s on the {ts * 1e3:g} ms grid{ratio}; '
                  f'force_scale {gains["force_scale"]:g}, rail_margin {gains["rail_margin"]:g} m, '
                  f'calm over the last {gains["terminal_hold"]:g} s (the catch comes there)')
        else:
            print('  plan: the optimiser found none (stored as unsuccessful: the swing-up falls '
                  'back to energy_saturated from this start)')
        print(f'  file: {result.path} ('
              + (f'solved now in {plan.solve_time:.1f} s' if result.solved else 'from the cache')
              + ')')
    return 0 if plan.success else 1
