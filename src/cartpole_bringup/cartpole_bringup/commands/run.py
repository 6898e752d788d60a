"""``cartpole run --sim | --hw --port DEV``: the node graph, optionally recorded, then its summary.

See the README, "Running the graph, recording, analysing". The graph itself is :mod:`cartpole_bringup.graph.graph`.
"""
from __future__ import annotations

import argparse
import datetime as _dt
import math
import os
import signal
import sys
import tempfile
from pathlib import Path
from typing import Any

import yaml

from .. import boundary, options

DISCOVERY_RANGES = ('localhost', 'subnet', 'system_default')



def add_arguments(parser: argparse.ArgumentParser) -> None:
    plant = parser.add_mutually_exclusive_group(required=True)
    plant.add_argument('--sim', action='store_true', help='run on the simulated plant')
    plant.add_argument('--hw', action='store_true', help='run on the rig through the serial bridge')
    hw = parser.add_argument_group('hardware')
    hw.add_argument('--port', default=None, metavar='DEV',
                    help='serial device of the rig (with --hw), e.g. /dev/ttyACM0 or an '
                         '`cartpole emulate` pseudo-terminal')
    hw.add_argument('--hw-arm', action='store_true',
                    help='home the encoders at start (cart at the left stop, pendulum hanging '
                         'still) and arm the bridge (lifecycle activate: the amplifier enabled) '
                         'once the controller answers; never armed by default')
    g = parser.add_argument_group('graph')
    g.add_argument('--lockstep', action='store_true',
                   help='simulator in lockstep: one Ts per force command, /clock, all nodes on '
                        'sim time (deterministic, faster than real time)')
    g.add_argument('--processes', action='store_true',
                   help='one OS process a node (the installed executables) instead of one '
                        'process and executor')
    g.add_argument('--duration', type=float, default=None, metavar='S',
                   help='stop after S seconds (simulated in lockstep, wall otherwise); '
                        'default: until Ctrl-C')
    g.add_argument('--window', type=float, default=None, metavar='S',
                   help='the final window the run summary scores (amplitude, cart error, MSE, '
                        'force) [s]; default 10, the thesis\'s table 10.2; at most --duration')
    g.add_argument('--record', type=Path, default=None, metavar='DIR',
                   help='record a bag into DIR/<UTC time>_<swingup>_<stabilizer>/bag')
    g.add_argument('--plots', nargs='?', const='', default=None, metavar='DIR',
                   help='write the PNG figures (into the run directory with --record, else DIR)')
    g.add_argument('--domain-id', type=int, default=None, metavar='N',
                   help='ROS_DOMAIN_ID of the graph (default: the environment\'s, else 0)')
    g.add_argument('--namespace', default='', metavar='NS',
                   help='ROS namespace of every node, topic and service of the graph (e.g. '
                        'rig2: /rig2/joint_states, /rig2/clock), so that graphs in other '
                        'namespaces share the domain; default: the root (/joint_states)')
    g.add_argument('--discovery', choices=DISCOVERY_RANGES, default='localhost',
                   help='ROS_AUTOMATIC_DISCOVERY_RANGE of the graph (default localhost: the '
                        'graph is invisible to other machines)')
    g.add_argument('--executor', choices=('events', 'single'), default='events',
                   help='executor of the one-process graph: the C++ EventsExecutor of '
                        'rclpy.experimental (default; about 3x less overhead) or rclpy\'s '
                        'SingleThreadedExecutor')
    g.add_argument('--view', nargs='?', const='', default=None, metavar='HOST:PORT',
                   help='serve a live view for Foxglove / Lichtblick (the viewer node in its '
                        'own process; default 127.0.0.1:8765; port 0: any free port)')
    g.add_argument('--allow-duplicates', action='store_true',
                   help='start even when another graph runs in the same namespace of the '
                        'domain (the two then drive each other\'s nodes); default: refuse, '
                        'naming the namespace and the node found')
    g.add_argument('--realtime', metavar='on|off|PRIORITY', default=None,
                   help='SCHED_FIFO priority of the loop\'s threads in every node of the run: on '
                        '(default: 20), off, or 1..49; the same as CARTPOLE_REALTIME, which '
                        'this sets for the run\'s processes; not permitted: one log line, the '
                        'run goes on at normal priority')
    g.add_argument('--log-level', default='warn',
                   choices=('debug', 'info', 'warn', 'error', 'fatal'),
                   help='ROS log level of the nodes (default warn)')
    options.add_controller_arguments(parser)
    options.add_scenario_arguments(parser)
    options.add_output_arguments(parser)


def controller_names(args: argparse.Namespace) -> dict[str, str]:
    """swing-up / stabiliser names: the option, else the params file, else the manager default."""
    from cartpole_control.manager import DEFAULT_CONTROLLERS
    from cartpole_control.controller import STABILIZER, SWINGUP

    file_values = options.load_ros_parameters(args.params, 'controller_manager')
    return {
        'swingup': args.swingup or str(file_values.get('swingup', DEFAULT_CONTROLLERS[SWINGUP])),
        'stabilizer': (args.stabilizer
                       or str(file_values.get('stabilizer', DEFAULT_CONTROLLERS[STABILIZER]))),
    }


def node_parameters(args: argparse.Namespace) -> dict[str, dict[str, Any]]:
    """The explicit ROS parameters of each node from the command-line options."""
    out: dict[str, dict[str, Any]] = {'controller_manager': {}, 'ekf': {}}
    if args.swingup:
        out['controller_manager']['swingup'] = args.swingup
    if args.stabilizer:
        out['controller_manager']['stabilizer'] = args.stabilizer
    if args.sim:
        sim: dict[str, Any] = {
            'x0': float(args.x0), 'theta0': float(args.theta0),
            'friction_scale': float(args.friction_scale),
            'encoder_offset': float(args.encoder_offset), 'noise': bool(args.noise),
            'seed': int(args.seed),
        }
        if args.tip_mass is not None:
            sim['tip_mass'] = float(args.tip_mass)
        if args.cart_mass is not None:
            sim['cart_mass'] = float(args.cart_mass)
        for name, default in (('delay', 0.0), ('jitter', 0.0), ('drop', 0.0),
                              ('force_noise', 0.0), ('actuator_gain', 1.0),
                              ('actuator_tau', 0.0)):
            if getattr(args, name) != default:  # the disturbances that are on
                sim[name] = float(getattr(args, name))
        if args.push:
            sim['pushes'] = ' '.join(str(push) for push in args.push)
        out['sim'] = sim
    else:
        out['hw_bridge'] = {'port': args.port}
        if args.hw_arm:
            # The bridge arms (activate, GraphSpec.hw_arm) only with homed encoders: home
            # them at its configure (the thesis's start: cart at the left stop, pendulum hanging still).
            out['hw_bridge']['home_on_start'] = True
    if args.plant_params is not None:
        # The nominal parameters of the plant model, the EKF and the controllers alike.
        for node in ('sim', 'ekf', 'controller_manager'):
            if node in out:
                out[node]['plant_params_file'] = str(args.plant_params.resolve())
    return out


def run_directory(root: Path, names: dict[str, str], now: _dt.datetime | None = None) -> Path:
    """``root/<UTC timestamp>_<swingup>_<stabilizer>`` (a suffix if it exists already)."""
    now = now or _dt.datetime.now(_dt.timezone.utc)
    base = root / f'{now.strftime("%Y%m%dT%H%M%SZ")}_{names["swingup"]}_{names["stabilizer"]}'
    path, n = base, 1
    while path.exists():
        n += 1
        path = base.with_name(f'{base.name}_{n}')
    return path


def _validate(args: argparse.Namespace) -> str | None:
    """The reason the options are refused (one line), None if they are fine."""
    try:
        check(args)
    except boundary.InputError as error:
        return str(error)
    return None


def check(args: argparse.Namespace) -> None:
    """Every input of the run, checked before anything starts (InputError naming the option)."""
    if args.hw and not args.port:
        raise boundary.InputError('--hw needs --port DEV')
    if args.sim and (args.port or args.hw_arm):
        raise boundary.InputError('--port and --hw-arm are for --hw')
    if args.lockstep and not args.sim:
        raise boundary.InputError('--lockstep needs --sim')
    if args.duration is not None:
        boundary.duration(args.duration)
    if args.window is not None:
        boundary.number('--window', args.window, 0.0,
                        boundary.MAX_DURATION_S if args.duration is None else args.duration,
                        low_open=True, unit='s')
    if args.realtime is not None:
        from cartpole_core.realtime import ENVIRONMENT_SWITCH, priority_from_environment
        try:
            priority_from_environment({ENVIRONMENT_SWITCH: args.realtime})
        except ValueError as exc:
            raise boundary.InputError(f'--realtime: {exc}') from None
    if args.plots == '' and args.record is None:
        raise boundary.InputError('--plots without DIR needs --record (the figures go into the '
                                  'run directory)')
    if args.plots:
        boundary.output_directory(args.plots, '--plots')
    if args.record is not None:
        boundary.output_directory(args.record, '--record')
    if args.domain_id is not None and not 0 <= args.domain_id <= 232:
        raise boundary.InputError(f'--domain-id must be in [0, 232], got {args.domain_id}')
    from cartpole_core import namespaces
    try:
        namespaces.normalize(args.namespace)
    except ValueError as error:
        raise boundary.InputError(f'--namespace: {error}') from None
    options.check_view_address(args.view)
    nominal = options.nominal_parameters(args)
    options.manager_parameters(nominal, args)
    from .offline import ekf_config_from_args
    ekf_config_from_args(args)  # the ekf section: known names, valid values
    if args.sim:
        options.scenario_from_args(args, nominal, args.duration)


class _StopRequest:
    """Ctrl-C / SIGTERM: the first asks for a clean stop, a second one aborts."""

    def __init__(self) -> None:
        self.requested = False
        self.previous: dict[int, Any] = {}

    def __call__(self, signum, frame) -> None:
        if self.requested and signum == signal.SIGINT:
            raise KeyboardInterrupt
        self.requested = True

    def install(self) -> None:
        for sig in (signal.SIGINT, signal.SIGTERM):
            self.previous[sig] = signal.signal(sig, self)

    def restore(self) -> None:
        for sig, handler in self.previous.items():
            signal.signal(sig, handler)


def main(args: argparse.Namespace) -> int:
    check(args)  # InputError: `cartpole run: error: ...`, exit 2
    if args.window is None:  # the thesis's table 10.2: the last 10 s
        from cartpole_analysis.analysis.metrics import WINDOW_S
        args.window = WINDOW_S
    if args.realtime is not None:  # read by every node of the run, in this process or its own
        from cartpole_core.realtime import ENVIRONMENT_SWITCH
        os.environ[ENVIRONMENT_SWITCH] = args.realtime
    if args.domain_id is not None:
        os.environ['ROS_DOMAIN_ID'] = str(args.domain_id)
    if args.discovery != 'system_default':  # with the profiles that go with it
        from cartpole_core.middleware import set_discovery_range
        set_discovery_range(args.discovery)

    import rclpy
    from rclpy.context import Context
    from rclpy.signals import SignalHandlerOptions

    from cartpole_analysis.analysis.analyze import JOINTS, TRUE_STATE
    from ..graph.graph import DuplicateNodeError, Graph, GraphError, GraphSpec

    names = controller_names(args)
    nominal = options.nominal_parameters(args)
    file_x_ref = options.load_ros_parameters(args.params, 'controller_manager').get('x_ref')
    x_ref = float(file_x_ref) if file_x_ref is not None else nominal.x_middle
    parameters = node_parameters(args)
    if args.lockstep:  # slow plugin work (a time_optimal plan) before the run, not during it
        from .plan import prepare_for_run
        try:
            parameters['controller_manager'].update(prepare_for_run(args, nominal, 'cartpole run'))
        except ValueError as error:  # checked above: the plugin's own refusal of its start
            print(f'cartpole run: the run failed before it started: {error}', file=sys.stderr)
            return 1
    run_dir = bag = None
    if args.record is not None:
        run_dir = run_directory(args.record, names)
        run_dir.mkdir(parents=True)
        bag = run_dir / 'bag'
    custom = {'x_ref': repr(x_ref), 'lockstep': str(bool(args.lockstep)).lower(),
              'window_s': repr(float(args.window)),
              'plant': 'sim' if args.sim else 'hw', **names,
              'command': ' '.join(['cartpole', 'run'] + sys.argv[2:])[:1000]}
    scratch = tempfile.TemporaryDirectory(prefix='cartpole-run-')  # the run's own files
    spec = GraphSpec(plant='sim' if args.sim else 'hw_bridge', parameters=parameters,
                     params_file=_params_file(args, Path(scratch.name)),
                     lockstep=args.lockstep, processes=args.processes, record=bag,
                     custom_data=custom, log_level=args.log_level, executor=args.executor,
                     allow_duplicates=args.allow_duplicates, namespace=args.namespace,
                     hw_arm=bool(args.hw_arm))

    viewer = None
    if args.view is not None:
        from cartpole_analysis.viewer.process import start_viewer
        try:
            viewer = start_viewer(args.view, plant_params=args.plant_params,
                                  log_level=args.log_level, ros_arguments=spec.ros_arguments)
        except RuntimeError as exc:
            raise boundary.InputError(f'--view: {exc}') from None
        print(f'cartpole run: live view on {viewer.url} (Foxglove WebSocket)', file=sys.stderr,
              flush=True)
    ros_args = ['--ros-args', '--log-level', args.log_level]
    if spec.params_file:
        ros_args += ['--params-file', str(spec.params_file)]
    stop = _StopRequest()
    context = Context()
    try:
        rclpy.init(args=['cartpole_run'] + ros_args, context=context,
                   signal_handler_options=SignalHandlerOptions.NO)
    except BaseException:
        if viewer is not None:   # started above: never left behind on port 8765
            viewer.close()
        scratch.cleanup()
        raise
    stop.install()
    warnings: list[str] = []
    graph = None
    try:
        graph = Graph(spec, context, should_stop=lambda: stop.requested)
        if viewer is not None:
            viewer.attach(graph.executor, context, TRUE_STATE if args.sim else JOINTS,
                          **spec.node_options())
        if not args.json:
            print(_banner(args, names, bag, spec.namespace), file=sys.stderr, flush=True)
        graph.start()
        queried = graph.get_parameter('controller_manager', 'x_ref', timeout=2.0)
        if isinstance(queried, (int, float)) and math.isfinite(queried):
            x_ref = float(queried)
        graph.run_for(args.duration)
        elapsed = graph.elapsed()
        warnings += graph.close()
    except DuplicateNodeError as exc:
        print(f'cartpole run: error: refused: {exc}', file=sys.stderr)
        return 2
    except GraphError as exc:
        print(f'cartpole run: {exc}', file=sys.stderr)
        return 1
    finally:
        if graph is not None:
            warnings += graph.close()
        if viewer is not None:
            warnings += viewer.close()
        stop.restore()
        rclpy.try_shutdown(context=context)
        scratch.cleanup()
    for w in warnings:
        print(f'cartpole run: warning: {w}', file=sys.stderr)
    end_ns = run_end_ns(graph.stop_stamp_ns, args.duration if args.lockstep else None)
    series, summary = summarize_run(graph, bag, end_ns=end_ns, x_ref=x_ref, params=nominal,
                                    lockstep=args.lockstep, window=args.window)
    return report(args, names, summary, series, run_dir=run_dir, bag=bag, elapsed=elapsed,
                  fault=graph.fault)


def _params_file(args: argparse.Namespace, scratch: Path) -> Path | None:
    """``--params`` as the graph's nodes read it: in a namespace, a copy in ``scratch`` whose
    node sections (``controller_manager:``) name the nodes there (``/rig2/controller_manager:``)."""
    from cartpole_core import namespaces
    from ..graph.processes import NODES

    if args.params is None:
        return None
    namespace = namespaces.normalize(args.namespace)
    if namespace == namespaces.ROOT:
        return args.params.resolve()
    data = boundary.read_yaml(args.params, '--params') or {}
    path = scratch / 'params.yaml'
    path.write_text(yaml.safe_dump(namespaces.parameters_in_namespace(data, namespace, NODES),
                                   default_flow_style=False, sort_keys=False))
    return path


def _banner(args: argparse.Namespace, names: dict[str, str], bag: Path | None,
            namespace: str = '/') -> str:
    where = f' recording into {bag}' if bag else ''
    ns = f', namespace {namespace}' if namespace != '/' else ''
    return (f'cartpole run: {"simulator" if args.sim else "rig " + args.port}, '
            f'{"lockstep" if args.lockstep else "real time"}, '
            f'{"one process a node" if args.processes else "one process"}, '
            f'{names["swingup"]} + {names["stabilizer"]}, ROS_DOMAIN_ID='
            f'{os.environ.get("ROS_DOMAIN_ID", "0")}{ns}{where}; '
            f'{"for %g s" % args.duration if args.duration else "Ctrl-C stops"}')


def run_end_ns(stop_stamp_ns: int | None, lockstep_duration: float | None) -> int | None:
    """Where the run's summary ends: its ``--duration`` in lockstep, else where the stop began.

    In lockstep the simulated time runs on while the stop takes its wall
    time; ending at the duration makes the summary the same for the same
    run, however long the stop took.
    """
    if lockstep_duration is not None:
        end = int(round(lockstep_duration * 1e9))
        return end if stop_stamp_ns is None else min(end, stop_stamp_ns)
    return stop_stamp_ns


def summarize_run(graph, bag: Path | None, *, end_ns: int | None, x_ref: float, params,
                  lockstep: bool, window: float = 10.0):
    """(series, summary) of the run: from its bag (repaired if need be), else from the monitor.

    The bag's custom_data gets ``run_end_ns`` and ``fault``, so that
    ``cartpole analyze`` of the bag reports the same. (None, None) when no
    summary can be made (the reason is printed).
    """
    from cartpole_analysis.analysis.analyze import analyze_bag
    from cartpole_analysis.bags.writer import update_custom_data
    from cartpole_analysis.bags.repair import RepairError, needs_repair, repair_bag

    try:
        if bag is None:
            series, summary = graph.monitor.builder.summarize(
                params=params, x_ref=x_ref, lockstep=lockstep, label='run', end_ns=end_ns,
                fault=graph.fault, window=window)
            if summary is not None:
                summary['recorder_missed'] = None  # no bag: nothing was recorded, nothing counted
            return series, summary
        if needs_repair(bag):  # the recorder was killed
            print(f'cartpole run: {repair_bag(bag).describe()}', file=sys.stderr)
        update_custom_data(bag, {'run_end_ns': None if end_ns is None else str(end_ns),
                                 'fault': graph.fault})
        analysis = analyze_bag(bag, x_ref=x_ref, params=params, window=window)
        return analysis.series, analysis.summary
    except (ValueError, OSError, RepairError) as exc:
        print(f'cartpole run: no summary: {exc}', file=sys.stderr)
        return None, None


def window_warning(summary, window: float) -> str | None:
    """Why a summary's verdict says little of the balance: its scored window (the last
    ``window`` s) starts before the catch, so the swing-up is scored as if fallen."""
    catch, spans = (summary or {}).get('catch_time_s'), (summary or {}).get('controllers')
    if catch is None or not spans:
        return None
    start = max(span['end_s'] for span in spans) - window
    if start >= catch:
        return None
    return (f'the scored window (the last {window:g} s, from {start:.2f} s) starts before the '
            f'catch at {catch:.2f} s: too short a run to judge the balance; run longer '
            '(--duration) or score less (--window)')


def report(args: argparse.Namespace, names: dict[str, str], summary, series, *,
           run_dir: Path | None, bag: Path | None, elapsed: float, fault: str | None) -> int:
    """Plots, ``summary.json``, the printed summary; the exit code (1 after a fault)."""
    from cartpole_analysis.analysis.plots import run_title, write_plots
    from cartpole_analysis.analysis.timeline import names_that_ran

    spans = (summary or {}).get('controllers') or []
    ran = {kind: ' -> '.join(names_that_ran(spans, kind)) or names[kind]
           for kind in ('swingup', 'stabilizer')}
    plots: list[Path] = []
    if series is not None and args.plots is not None:
        plot_dir = run_dir if args.plots == '' else Path(args.plots)
        plots = write_plots(series, plot_dir, 'run',
                            title=run_title(spans, f'{names["swingup"]} + {names["stabilizer"]}'))
    extra = {'elapsed_s': elapsed, 'lockstep': bool(args.lockstep), 'window_s': args.window,
             **ran,
             'run_dir': str(run_dir) if run_dir else None, 'bag': str(bag) if bag else None,
             'plots': [str(p) for p in plots]}
    short = window_warning(summary, args.window)
    if short is not None:
        print(f'cartpole run: warning: {short}', file=sys.stderr)
    result = dict(summary) if summary is not None else {'fault': fault, 'success': False}
    result.update(extra)
    if run_dir is not None:
        (run_dir / 'summary.json').write_text(boundary.json_text(result, indent=2) + '\n')
    if args.json:
        options.print_json(result)
    else:
        if summary is not None:
            options.print_summary(summary, as_json=False)
        for key in ('run_dir', 'bag'):
            if extra[key]:
                print(f'{key}: {extra[key]}')
        for p in plots:
            print(f'plot: {p}')
    return 0 if summary is not None and not summary.get('fault') else 1
