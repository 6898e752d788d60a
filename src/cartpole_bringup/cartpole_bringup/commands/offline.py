"""`cartpole offline`: the closed loop without ROS, far faster than real time."""
from __future__ import annotations

import argparse
import sys
import time

from cartpole_sim.scenario_options import add_scenario_file_argument

from .. import boundary, options

LINGER_S = 1.0
"""With --view: wall seconds the server stays up after the run, so that its last messages
reach the clients before the connection closes."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    options.add_number_argument(parser, '--duration', 30.0, 'simulated seconds', metavar='S')
    parser.add_argument('--stop-on-failure', action='store_true',
                        help='end the run at the first sample after which it cannot succeed '
                             '(an impact, a fall after the catch, a manager fault), as the '
                             'benchmarks run it: a failure file of `cartpole bench robustness '
                             '--combined` replays to the same summary')
    parser.add_argument('--plot', default=None, metavar='FILE.png',
                        help='draw cart position, angle, force and energy (Figure 10.1 layout)')
    v = parser.add_argument_group('live view (Foxglove WebSocket, no ROS)')
    v.add_argument('--view', nargs='?', const='', default=None, metavar='HOST:PORT',
                   help='play the run in real time to a Foxglove / Lichtblick client (the '
                        "viewer's channels and layout; default 127.0.0.1:8765, port 0: any "
                        'free port)')
    options.add_number_argument(v, '--speed', 1.0, 'with --view: simulated seconds per wall second',
                                metavar='F')
    v.add_argument('--no-wait', action='store_true',
                   help='with --view: start at once instead of waiting for a client to '
                        'subscribe to the scene')
    options.add_controller_arguments(parser)
    options.add_scenario_arguments(parser)
    add_scenario_file_argument(parser)
    options.add_output_arguments(parser)


def manager_parameters_from_args(args: argparse.Namespace) -> dict:
    """controller_manager parameters: the --params file's section, then --swingup/--stabilizer."""
    params = options.manager_section(options.nominal_parameters(args), args)
    if args.swingup:
        params['swingup'] = args.swingup
    if args.stabilizer:
        params['stabilizer'] = args.stabilizer
    return params


def ekf_config_from_args(args: argparse.Namespace):
    """The filter's configuration: the --params file's ``ekf`` section (the node's parameters)."""
    from cartpole_estimation.ekf_config import EkfConfig, changes_from_parameters
    try:
        return EkfConfig(**changes_from_parameters(boundary.ekf_parameters(args.params)))
    except (ValueError, TypeError) as error:
        if isinstance(error, boundary.InputError):
            raise
        raise boundary.InputError(f'--params {args.params}: ekf: {error}') from None


def checked(args: argparse.Namespace):
    """Every input of the run, checked before it starts (InputError naming the option):
    (nominal parameters, scenario, manager parameters, EKF configuration, plot path)."""
    boundary.duration(args.duration)
    boundary.number('--speed', args.speed, 0.01, 1000.0)
    plot = boundary.figure_file(args.plot, '--plot') if args.plot else None
    options.check_view_address(args.view)
    nominal = options.nominal_parameters(args)
    scenario = options.scenario_from_args(args, nominal, args.duration)
    manager = options.manager_parameters(nominal, args)
    return nominal, scenario, manager, ekf_config_from_args(args), plot


def main(args: argparse.Namespace) -> int:
    from ..offline.closed_loop import run_closed_loop

    nominal, scenario, manager, ekf_config, plot = checked(args)
    server = observer = None
    if args.view is not None:
        server, observer = _start_view(args, nominal, manager)
    try:
        run = run_closed_loop(nominal, scenario, duration=args.duration,
                              manager_parameters=manager, ekf_config=ekf_config,
                              progress=options.progress_printer('cartpole offline'),
                              observer=observer, stop_on_failure=args.stop_on_failure)
    except ValueError as exc:  # checked above; a plugin's own refusal at its start
        print(f'cartpole offline: the run failed: {exc}', file=sys.stderr)
        return 1
    finally:
        if server is not None:
            time.sleep(LINGER_S)  # let the last messages reach the clients
            server.stop()
    options.print_summary(run.summary, args.json)
    if plot is not None:
        from cartpole_analysis.analysis.plots import plot_offline_run
        try:
            plot_offline_run(run, plot)
        except (OSError, ValueError) as error:
            print(f'cartpole offline: --plot {plot}: not written: {error}', file=sys.stderr)
            return 1
        if not args.json:
            print(f'plot: {plot}')
    return 0


def _start_view(args: argparse.Namespace, nominal, manager: dict):
    """The viewer's server and the loop's real-time observer (waits for a client unless told)."""
    from cartpole_sim.geometry import RigGeometry

    from cartpole_analysis.viewer.server import LiveView, ViewerServer, parse_address
    from cartpole_analysis.viewer.offline import RealTimePlayer

    try:
        host, port = parse_address(args.view)
        server = ViewerServer(host, port)
    except ValueError as exc:
        raise boundary.InputError(f'--view {args.view}: {exc}') from None
    except RuntimeError as exc:
        raise boundary.InputError(f'--view {args.view}: {exc}') from None
    x_ref = manager.get('x_ref')
    view = LiveView(server, RigGeometry.from_parameters(nominal),
                    float(x_ref) if x_ref is not None else nominal.x_middle)
    print(f'cartpole offline: live view on {server.url} (Foxglove WebSocket)', file=sys.stderr,
          flush=True)
    if not args.no_wait:
        print('cartpole offline: waiting for a client to subscribe (Foxglove: Open connection, '
              f'Foxglove WebSocket, {server.url}); Ctrl-C stops', file=sys.stderr, flush=True)
        try:
            while not server.wait_for_client(0.2):
                pass
        except KeyboardInterrupt:
            server.stop()
            raise SystemExit(130) from None
    return server, RealTimePlayer(view, speed=args.speed)
