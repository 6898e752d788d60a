"""`cartpole bound`: the minimum-time swing-up bounds and the push bounds for the parameters in use.

Solves, by direct multiple shooting with free final time (CasADi + IPOPT,
:mod:`cartpole_control.trajectory_optimization`), the fastest swing-up with
the amplifier's force limits and the cart kept on the rail:

- ``middle``: from hanging rest in the middle of the rail to the catch region
  (|theta_w| <= 10 deg, energy within 5 %);
- ``left_stop``: the same from the left end stop;
- ``upright_at_rest``: from the middle to upright at rest.

and, asked for with ``--case`` (not by default), the physical limits for the
robustness grid's pushes (:mod:`cartpole_control.push_recovery`): the largest
impulse (``push_cart`` [N s], ``push_pendulum`` [N m s]) any controller within the
force limits recovers from, balanced at rest in the middle, per ``--margin``, with
and without the fall detector, ``--guard`` and ``--reaction`` (docs/robustness.md).

No ROS.
"""
from __future__ import annotations

import argparse

from .. import boundary
from ..options import (add_number_argument, add_output_arguments, add_plant_params_argument,
                       nominal_parameters, print_json)


PUSH_CASES = {'push_cart': 'cart', 'push_pendulum': 'pendulum'}
"""The push bounds (``--case``) and the target of their push."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from cartpole_control.trajectory_optimization import BOUND_CASES
    add_plant_params_argument(parser, 'plant parameters (CartPoleParameters YAML)')
    parser.add_argument('--case', action='append', choices=BOUND_CASES + tuple(PUSH_CASES),
                        default=None,
                        help='compute only this bound (repeatable); default: the three swing-up '
                             'bounds; push_cart / push_pendulum: the largest recoverable push')
    parser.add_argument('--no-friction', action='store_true',
                        help='frictionless model (default: the smoothed Coulomb/viscous friction)')
    add_number_argument(parser, '--intervals', 70, 'shooting intervals of the multi-start solves',
                        metavar='N')
    add_number_argument(parser, '--refine', 140, 'intervals of the final refinement, 0 for none',
                        metavar='N')
    g = parser.add_argument_group('push bounds (--case push_cart / push_pendulum)')
    g.add_argument('--margin', action='append', type=float, default=None, metavar='M',
                   help='keep the cart in [M, travel - M] [m] (repeatable); default: 0 and 0.02 '
                        '(the end stops, the rail guard\'s margin)')
    g.add_argument('--guard', action='store_true',
                   help='also keep the rail guard\'s braking envelope: the stopping position of '
                        'the manager\'s default guard 5 cm (rail.limit_reserve) inside the margin')
    add_number_argument(g, '--reaction', 0.0, 'the controller\'s force is zero this long after the '
                        'push starts [s]: one that only acts on what it has seen (0: it knows '
                        'the push in advance)', metavar='S')
    add_number_argument(g, '--fall-angle', 45.0, 'the no-fall bound keeps |theta| within this '
                        '[deg] (the fall detector); the other has no angle limit', metavar='DEG')
    add_number_argument(g, '--horizon', 3.0, 'time from the push to upright at rest [s]',
                        metavar='S')
    add_number_argument(g, '--tolerance', 0.01, 'relative accuracy of the bound', metavar='R')
    add_output_arguments(parser)


def _check_push_options(args: argparse.Namespace, params) -> None:
    """The push bounds' options, checked whether or not a push case is asked for."""
    for m in args.margin or ():
        boundary.number('--margin', m, 0.0, 0.5 * params.travel, high_open=True, unit='m')
    boundary.number('--fall-angle', args.fall_angle, 0.0, 180.0, low_open=True, high_open=True,
                    unit='deg')
    boundary.number('--horizon', args.horizon, 0.5, 20.0, low_open=True, unit='s')
    boundary.number('--tolerance', args.tolerance, 0.0, 0.5, low_open=True, high_open=True)
    boundary.number('--reaction', args.reaction, 0.0, 0.5 * args.horizon, unit='s')


def main(args: argparse.Namespace) -> int:
    from cartpole_control.trajectory_optimization import BOUND_CASES
    boundary.number('--intervals', args.intervals, 5, 2000)
    boundary.number('--refine', args.refine, 0, 4000)
    params = nominal_parameters(args)
    _check_push_options(args, params)
    cases = tuple(dict.fromkeys(args.case)) if args.case else BOUND_CASES
    swingup_cases = tuple(c for c in cases if c not in PUSH_CASES)
    push_cases = tuple(c for c in cases if c in PUSH_CASES)
    out, ok = {}, True
    if swingup_cases:
        swingup, ok = _swingup(args, params, swingup_cases, print_table=not args.json)
        out.update(swingup)
    if push_cases:
        if swingup_cases and not args.json:
            print()
        pushes, pushes_ok = _pushes(args, params, push_cases, print_table=not args.json)
        out.update(pushes)
        ok = ok and pushes_ok
    if args.json:
        print_json(out)
    return 0 if ok else 1


def _swingup(args: argparse.Namespace, params, cases, print_table: bool) -> tuple[dict, bool]:
    """The minimum-time swing-up bounds of ``cases``: their JSON and whether all converged."""
    from cartpole_control.trajectory_optimization import ISSUE_BOUNDS, swingup_bounds
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
    ok = all(v['converged'] for v in out.values())
    if not print_table:
        return out, ok
    print(f'{"case":<16} {"bound [s]":>9} {"issue [s]":>9} {"switches":>8} {"x range [m]":>16} {"solve [s]":>9}')
    for case, v in out.items():
        t = f'{v["time_s"]:.3f}' if v['time_s'] is not None else 'failed'
        issue = f'{v["issue_s"]:.2f}' if v['issue_s'] is not None else '-'
        xr = f'{v["x_range_m"][0]:.3f}..{v["x_range_m"][1]:.3f}'
        print(f'{case:<16} {t:>9} {issue:>9} {v["full_force_switches"]:>8} {xr:>16} {v["solve_s"]:>9.1f}')
    return out, ok


def _pushes(args: argparse.Namespace, params, cases, print_table: bool) -> tuple[dict, bool]:
    """The push bounds of ``cases`` for every margin, without and with the angle limit."""
    import math

    from cartpole_control.push_recovery import (PUSH_WIDTHS, PushRecoveryProblem,
                                                cart_push_momentum_bound, largest_push)

    from ..options import progress_printer
    margins = tuple(args.margin) if args.margin else (0.0, 0.02)
    say = progress_printer('cartpole bound')
    angles = (None, math.radians(args.fall_angle))
    out, ok = {}, True
    for case in cases:
        target = PUSH_CASES[case]
        rows = []
        for margin in margins:
            for angle in angles:
                problem = PushRecoveryProblem(params, target, rail_margin=margin, max_angle=angle,
                                              horizon=args.horizon, friction=not args.no_friction,
                                              guard=args.guard, reaction=args.reaction)
                bound = largest_push(problem, args.tolerance)
                row = bound.to_dict()
                row['converged'] = math.isfinite(bound.infeasible)
                ok = ok and row['converged']
                if target == 'cart':
                    row['momentum_bound'] = round(cart_push_momentum_bound(
                        params, problem.width, margin, angle, problem.start_x), 4)
                limit = ('no angle limit' if angle is None
                         else f'|theta| <= {args.fall_angle:g} deg')
                say(f'{case} margin {margin:g} m{" + guard" if args.guard else ""}, {limit}: '
                    f'{row["impulse"]:g} {row["unit"]} ({row["solve_s"]:.0f} s)')
                rows.append(row)
        out[case] = {'unit': rows[0]['unit'], 'width_s': PUSH_WIDTHS[target], 'bounds': rows}
    if not print_table:
        return out, ok
    print(f'{"case":<14} {"margin [m]":>10} {"|theta| max":>11} {"bound":>8} {"unit":<6} '
          f'{"infeasible":>10} {"x range [m]":>14} {"theta [deg]":>14} {"momentum":>8} '
          f'{"solve [s]":>9}')
    for case, v in out.items():
        for r in v['bounds']:
            angle = 'none' if r['max_angle_deg'] is None else f'{r["max_angle_deg"]:g} deg'
            xr = f'{r["x_range_m"][0]:.3f}..{r["x_range_m"][1]:.3f}'
            th = f'{r["theta_range_deg"][0]:.0f}..{r["theta_range_deg"][1]:.0f}'
            infeasible = (f'{r["infeasible_from"]:.4g}' if r['infeasible_from'] is not None
                          else 'not found')
            momentum = f'{r["momentum_bound"]:.2f}' if 'momentum_bound' in r else '-'
            margin = f'{r["rail_margin_m"]:g}' + ('+guard' if r['rail_guard'] else '')
            print(f'{case:<14} {margin:>10} {angle:>11} {r["impulse"]:>8.4g} '
                  f'{r["unit"]:<6} {infeasible:>10} {xr:>14} {th:>14} {momentum:>8} '
                  f'{r["solve_s"]:>9.1f}')
    return out, ok
