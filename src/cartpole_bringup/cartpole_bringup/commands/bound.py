"""`cartpole bound`: the minimum-time swing-up bounds for the parameters in use.

Solves, by direct multiple shooting with free final time (CasADi + IPOPT,
:mod:`cartpole_control.trajectory_optimization`), the fastest swing-up with
the amplifier's force limits and the cart kept on the rail:

- ``middle``: from hanging rest in the middle of the rail to the catch region
  (|theta_w| <= 10 deg, energy within 5 %);
- ``left_stop``: the same from the left end stop;
- ``upright_at_rest``: from the middle to upright at rest.

No ROS.
"""
from __future__ import annotations

import argparse

from .. import boundary
from ..options import (add_number_argument, add_output_arguments, add_plant_params_argument,
                       nominal_parameters, print_json)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from cartpole_control.trajectory_optimization import BOUND_CASES
    add_plant_params_argument(parser, 'plant parameters (CartPoleParameters YAML)')
    parser.add_argument('--case', action='append', choices=BOUND_CASES, default=None,
                        help='compute only this bound (repeatable); default: all three')
    parser.add_argument('--no-friction', action='store_true',
                        help='frictionless model (default: the smoothed Coulomb/viscous friction)')
    add_number_argument(parser, '--intervals', 70, 'shooting intervals of the multi-start solves',
                        metavar='N')
    add_number_argument(parser, '--refine', 140, 'intervals of the final refinement, 0 for none',
                        metavar='N')
    add_output_arguments(parser)


def main(args: argparse.Namespace) -> int:
    from cartpole_control.trajectory_optimization import BOUND_CASES, ISSUE_BOUNDS, swingup_bounds
    boundary.number('--intervals', args.intervals, 5, 2000)
    boundary.number('--refine', args.refine, 0, 4000)
    params = nominal_parameters(args)
    cases = tuple(args.case) if args.case else BOUND_CASES
    results = swingup_bounds(params, cases, n_intervals=args.intervals,
                             refine_intervals=args.refine or None,
                             friction=not args.no_friction)
    out = {}
    for case, traj in results.items():
        signs = [f > 0.0 for f in traj.forces if abs(f) > 0.5 * params.force_max]
        switches = int(sum(1 for a, b in zip(signs[:-1], signs[1:]) if a != b))
        forces = traj.forces
        out[case] = {'time_s': round(traj.final_time, 4) if traj.success else None,
                     'converged': traj.success,
                     'intervals': len(forces),
                     'full_force_switches': switches,
                     'x_range_m': [round(float(traj.states[:, 0].min()), 4),
                                   round(float(traj.states[:, 0].max()), 4)],
                     'solve_s': round(traj.solve_time, 2),
                     'issue_s': ISSUE_BOUNDS[case] if params == type(params)() else None}
    if args.json:
        print_json(out)
        return 0 if all(v['converged'] for v in out.values()) else 1
    print(f'{"case":<16} {"bound [s]":>9} {"issue [s]":>9} {"switches":>8} {"x range [m]":>16} {"solve [s]":>9}')
    for case, v in out.items():
        t = f'{v["time_s"]:.3f}' if v['time_s'] is not None else 'failed'
        issue = f'{v["issue_s"]:.2f}' if v['issue_s'] is not None else '-'
        xr = f'{v["x_range_m"][0]:.3f}..{v["x_range_m"][1]:.3f}'
        print(f'{case:<16} {t:>9} {issue:>9} {v["full_force_switches"]:>8} {xr:>16} {v["solve_s"]:>9.1f}')
    return 0 if all(v['converged'] for v in out.values()) else 1
