"""Solve time of the ``mpc`` stabiliser per control cycle, in the closed loop.

The offline closed loop (plant with noise, EKF, controller manager; the blocks of
:func:`cartpole_bringup.offline.closed_loop.run_closed_loop`), stepped here so that the
stabiliser's :meth:`~cartpole_control.controller.Controller.status_values` are read after
every cycle: ``mpc_solve_us`` (wall time of the QP solve with its Python calls) and
``mpc_fallbacks``, over the cycles the MPC runs (after the catch). By default each run gets
cart pushes (4 N s right at 8 s, left at 14 s) so that the constraints become active.
With a loop delay (``--delay-ms``) the manager measures a dead time and the MPC's QP for the
catch is built again for it (ahead, between the swing-up's cycles: ``catch_cycle_us`` is the
manager's whole cycle at each catch, ``between_max_us`` the longest work between two cycles).

Cycles are paced at the sample time, as the controller manager runs them; ``--flat-out``
runs them back to back, and a busy scheduler then pre-empts solves, so its tail measures
the machine's load more than the solver.

``python -m cartpole_tools.bench.mpc_solve --solvers daqp --horizons 100 200`` prints the
table of docs/controllers.md; ``cartpole bench loop`` uses :func:`solve_times`. No ROS.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from typing import Any, Mapping, Sequence

import numpy as np

from cartpole_control.manager import STABILIZING, ControllerManager
from cartpole_estimation.ekf import EkfConfig, ExtendedKalmanFilter
from cartpole_core.model import CartPoleParameters
from cartpole_sim.plant import Plant, Push, Scenario

DEFAULT_PUSHES = (Push(8.0, 'cart', 40.0, 0.1), Push(14.0, 'cart', -40.0, 0.1))
"""Pushes that make the rail and force constraints active (4 N s each way)."""


def solve_times(parameters: Mapping[str, Any] | None = None, duration: float = 30.0,
                seed: int = 1, pushes: Sequence[Push] = DEFAULT_PUSHES,
                paced: bool = True, delay: float = 0.0) -> dict[str, Any]:
    """Closed loop with ``stabilizer: mpc`` and ``parameters``; solve-time statistics [us].

    Returns the cycles counted, p50 / p99 / p99.9 / max of ``mpc_solve_us``, the
    fall-backs, whether the pendulum stayed up (no fall, no fault), the load average
    (1 min) before and after, and ``paced``: each cycle started on the sample clock
    (``duration`` of wall time), else back to back; the manager's cycle at the catches and
    the longest :meth:`~ControllerManager.between_cycles` [us], with ``delay`` [s] of loop delay.
    """
    load_before = os.getloadavg()[0]
    nominal = CartPoleParameters()
    scenario = Scenario(noise=True, seed=seed, pushes=tuple(pushes), delay=delay)
    plant = Plant(nominal, scenario)
    ekf = ExtendedKalmanFilter(nominal, EkfConfig())
    manager = ControllerManager(nominal, sample_time=nominal.sample_time, real_time=False,
                                stabilizer='mpc', **dict(parameters or {}))
    times: list[float] = []
    force = 0.0
    falls = faults = 0
    fallbacks = catch_builds = 0
    catch_cycles: list[float] = []
    between = 0.0
    clock, period = time.perf_counter, nominal.sample_time
    start = clock()
    for k in range(int(round(duration / period)) + 1):
        if paced:  # the manager's cycle: on the sample clock, idle in between
            wait = start + k * period - clock()
            if wait > 0.0:
                time.sleep(wait)
        meas = plant.measure()
        for source, applied in plant.applied_commands():
            manager.command_applied(source, applied)
        manager.measured(meas.t, meas.x, meas.theta)
        est = ekf.update(meas.t, meas.x, meas.theta, force)
        cycle = clock()
        out = manager.update_values(est.t, est.x, est.theta, est.x_dot, est.theta_dot)
        cycle = clock() - cycle
        force = out.force
        if out.mode == STABILIZING:
            values = manager.active_plugins()['stabilizer'].status_values()
            times.append(values['mpc_solve_us'])
            fallbacks = int(values['mpc_fallbacks'])
            catch_builds = int(values['mpc_catch_builds'])
        if 'catch' in out.event.split(';'):
            catch_cycles.append(cycle * 1e6)
        falls = out.fall_count
        faults += out.event.count('fault:')
        idle = clock()
        manager.between_cycles()
        between = max(between, clock() - idle)
        plant.step(force, None, meas.t)
    t = np.array(times)
    return {'cycles': int(t.size),
            'p50_us': float(np.percentile(t, 50)) if t.size else None,
            'p99_us': float(np.percentile(t, 99)) if t.size else None,
            'p999_us': float(np.percentile(t, 99.9)) if t.size else None,
            'max_us': float(t.max()) if t.size else None,
            'fallbacks': fallbacks, 'falls': int(falls), 'faults': faults,
            'balanced': bool(t.size and falls == 0 and faults == 0), 'paced': paced,
            'delay_s': delay, 'catch_cycle_us': catch_cycles, 'catch_builds': catch_builds,
            'between_max_us': between * 1e6,
            'load_before': load_before, 'load_after': os.getloadavg()[0]}


def table(rows: Sequence[dict[str, Any]]) -> str:
    """Markdown table of :func:`solve_times` results (each with ``solver`` and ``horizon``)."""
    out = ['| solver | horizon | cycles | p50 [us] | p99 [us] | p99.9 [us] | max [us] | fall-backs '
           '| balanced | clock | load before / after | catch cycles [us] | between, max [us] |',
           '|---|---|---|---|---|---|---|---|---|---|---|---|---|']
    for r in rows:
        if r.get('error'):
            out.append(f'| {r["solver"]} | {r["horizon"]} | {r["error"]} | | | | | | | | | | |')
            continue
        out.append(f'| {r["solver"]} | {r["horizon"]} | {r["cycles"]} | {r["p50_us"]:.0f} | '
                   f'{r["p99_us"]:.0f} | {r["p999_us"]:.0f} | {r["max_us"]:.0f} | {r["fallbacks"]} | '
                   f'{"yes" if r["balanced"] else "no"} | '
                   f'{"paced" if r.get("paced", True) else "flat out"} | '
                   f'{r.get("load_before", float("nan")):.2f} / '
                   f'{r.get("load_after", float("nan")):.2f} | '
                   f'{" ".join(f"{c:.0f}" for c in r.get("catch_cycle_us", [])) or "-"} | '
                   f'{r.get("between_max_us", float("nan")):.0f} |')
    return '\n'.join(out) + '\n'


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--solvers', nargs='*', default=['daqp'])
    parser.add_argument('--horizons', nargs='*', type=int, default=[200])
    parser.add_argument('--duration', type=float, default=30.0, metavar='S')
    parser.add_argument('--budget-us', type=float, default=1e6,
                        help='mpc.budget_us for the measurement (default 1e6: no fall-back, '
                             'so that every solve is timed)')
    parser.add_argument('--delay-ms', type=float, default=0.0, metavar='MS',
                        help='loop delay of the simulated plant [ms] (default 0): the catch '
                             'builds the QP again for the dead time measured')
    parser.add_argument('--flat-out', action='store_true',
                        help='cycles back to back instead of on the 5 ms sample clock')
    parser.add_argument('--json', action='store_true')
    args = parser.parse_args(argv)
    if not 0.0 <= args.delay_ms <= 100.0:
        parser.error(f'--delay-ms must be in [0, 100] ms, got {args.delay_ms:g}')
    rows = []
    load = os.getloadavg()
    for solver in args.solvers:
        for horizon in args.horizons:
            params = {'mpc.solver': solver, 'mpc.horizon': horizon,
                      'mpc.budget_us': args.budget_us}
            try:
                r = solve_times(params, duration=args.duration, paced=not args.flat_out,
                                delay=1e-3 * args.delay_ms)
            except Exception as error:  # a solver that cannot run is a row, not an abort
                r = {'error': f'{type(error).__name__}: {error}'[:120]}
            rows.append({'solver': solver, 'horizon': horizon, **r})
    if args.json:
        print(json.dumps({'load_before': load, 'load_after': os.getloadavg(), 'rows': rows}))
    else:
        print(f'load average before {load[0]:.2f}, after {os.getloadavg()[0]:.2f} '
              f'({os.cpu_count()} CPUs)')
        print(table(rows))
    return 0


if __name__ == '__main__':
    sys.exit(main())
