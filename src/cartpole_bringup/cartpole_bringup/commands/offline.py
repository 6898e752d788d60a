"""`cartpole offline`: the closed loop without ROS, far faster than real time (SPEC 5)."""
from __future__ import annotations

import argparse

from .. import options


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--duration', type=float, default=30.0, metavar='S',
                        help='simulated seconds (default 30)')
    parser.add_argument('--plot', default=None, metavar='FILE.png',
                        help='draw cart position, angle, force and energy (Figure 10.1 layout)')
    options.add_controller_arguments(parser)
    options.add_scenario_arguments(parser)
    options.add_output_arguments(parser)


def manager_parameters_from_args(args: argparse.Namespace) -> dict:
    """controller_manager parameters: the --params file's section, then --swingup/--stabilizer."""
    params = options.load_ros_parameters(args.params, 'controller_manager')
    if args.swingup:
        params['swingup'] = args.swingup
    if args.stabilizer:
        params['stabilizer'] = args.stabilizer
    return params


def ekf_config_from_args(args: argparse.Namespace):
    """The filter's configuration: the --params file's ``ekf`` section (the node's parameters)."""
    from cartpole_estimation.ekf_config import EkfConfig, changes_from_parameters
    return EkfConfig(**changes_from_parameters(options.load_ros_parameters(args.params, 'ekf')))


def main(args: argparse.Namespace) -> int:
    from ..closed_loop import run_closed_loop

    if not args.duration > 0:
        raise SystemExit('--duration must be > 0')
    try:
        run = run_closed_loop(options.nominal_parameters(args), options.scenario_from_args(args),
                              duration=args.duration,
                              manager_parameters=manager_parameters_from_args(args),
                              ekf_config=ekf_config_from_args(args),
                              progress=options.progress_printer('cartpole offline'))
    except ValueError as exc:
        raise SystemExit(f'cartpole offline: {exc}') from None
    options.print_summary(run.summary, args.json)
    if args.plot:
        from ..plots import plot_offline_run
        plot_offline_run(run, args.plot)
        if not args.json:
            print(f'plot: {args.plot}')
    return 0
