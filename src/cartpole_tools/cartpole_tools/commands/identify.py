"""``cartpole identify BAG [BAG ...]``: fit the plant parameters to recorded open-loop tests.

Thesis (4.22)-(4.26) and section 4.3.2; the work is in
:mod:`cartpole_tools.identification`, this module reads the options, the bags,
prints the result and writes the parameters file.
"""
from __future__ import annotations

import argparse
import datetime as _dt
import math
import os
import sys
import tempfile
from pathlib import Path

from cartpole_bringup import boundary
from cartpole_bringup.boundary import InputError
from cartpole_bringup.options import (add_number_argument, add_output_arguments, add_plant_params_argument,
                       nominal_parameters, print_json)

PROG = 'cartpole identify'


HELP = 'fit plant parameters to a recorded test'
"""The line of ``cartpole --help``."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from ..identification.fit import DEFAULT_FREE

    parser.add_argument('bags', nargs='*', type=Path, metavar='BAG',
                        help='rosbag2 bags of open-loop tests (/joint_states and '
                             '/cartpole/force_command); all are fitted with one parameter set')
    fit = parser.add_argument_group('fit')
    fit.add_argument('--free', default=','.join(DEFAULT_FREE), metavar='NAMES',
                     help='comma-separated CartPoleParameters fields to fit '
                          f'(default {",".join(DEFAULT_FREE)})')
    fit.add_argument('--bound', action='append', default=[], metavar='NAME=LO:HI',
                     help='search bounds of a free parameter (repeatable); the thesis used '
                          'm_c=1:5, c_c_right=1:5, c_c_left=1:5')
    add_plant_params_argument(fit, 'starting values and the fixed parameters '
                                   '(CartPoleParameters YAML)')
    add_number_argument(fit, '--weight-cart', 1.0, 'weight of the cart position error [1/m]',
                        metavar='W')
    fit.add_argument('--weight-pendulum', type=float, default=None, metavar='W',
                     help='weight of the pendulum angle error [1/rad] (default l = 0.3345, '
                          'an angle error counted as the arc length at the tip)')
    fit.add_argument('--refine-initial-state', action='store_true',
                     help="fit every bag's initial state jointly with the parameters "
                          '(about twice the time)')
    add_number_argument(fit, '--integration-step', 0.001, 'RK4 step of the simulated plant [s]',
                        metavar='S')
    add_number_argument(fit, '--max-nfev', 30,
                        'most residual evaluations per pass, about the iterations', metavar='N')
    data = parser.add_argument_group('data')
    data.add_argument('--t-start', type=float, default=None, metavar='S',
                      help='use samples from S seconds after the first one (every bag)')
    data.add_argument('--t-end', type=float, default=None, metavar='S',
                      help='use samples up to S seconds after the first one (every bag)')
    data.add_argument('--zero-force', action='store_true',
                      help='accept bags without /cartpole/force_command (free swings): zero force')
    out = parser.add_argument_group('output')
    out.add_argument('--output', '-o', type=Path, default=None, metavar='FILE.yaml',
                     help='write the fitted parameters (CartPoleParameters YAML, for '
                          '--plant-params and the nodes\' plant_params_file)')
    out.add_argument('--plot', type=Path, default=None, metavar='FILE.png',
                     help='measured vs simulated positions before and after the fit')
    out.add_argument('--verbose', '-v', action='store_true',
                     help='print every residual evaluation on stderr')
    pulse = parser.add_argument_group(
        'pulse test (instead of BAGs): play force pulses open loop on the rig or the simulator')
    pulse.add_argument('--pulse-plan', default=None, metavar='F:L,...',
                       help='pulses FORCE[N]:LENGTH[s], e.g. 15:0.25,-9:0.25 (starting with a '
                            'negative force: --pulse-plan=-15:0.25,9:0.25); each after the '
                            'cart has stood still; rehearsed on the model first and refused if '
                            'the cart would come near a stop')
    pulse.add_argument('--rehearse', action='store_true',
                       help='only rehearse the plan on the model (--plant-params) and print it')
    pulse.add_argument('--x0', type=float, default=0.0, metavar='M',
                       help='start of the rehearsal (default 0, the left stop); live, the '
                            'first sample')
    pulse.add_argument('--record', type=Path, default=None, metavar='DIR',
                       help='record the test into this bag (in-process recorder)')
    pulse.add_argument('--arm', action='store_true',
                       help='arm the hw bridge after the rehearsal (its lifecycle activate, '
                            'after zero-force answers; deactivated at the end); the bridge '
                            'must be configured (ros2 lifecycle set /hw_bridge configure)')
    pulse.add_argument('--namespace', default='', metavar='NS',
                       help='ROS namespace of the graph to play on (that of its cartpole run '
                            '--namespace); default: the root')
    add_number_argument(pulse, '--margin', 0.1,
                        'rail guard: no pulse towards a stop closer than this, and the '
                        'rehearsal must keep the cart this far from both stops', metavar='M')
    add_number_argument(pulse, '--settle', 1.0,
                        'the cart stands still this long before the next pulse', metavar='S')
    add_number_argument(pulse, '--lead-in', 0.5, 'zero force at the start of the test',
                        metavar='S')
    add_number_argument(pulse, '--timeout', 120.0, 'give up after this many wall seconds',
                        metavar='S')
    add_output_arguments(parser)


def parse_bounds(items: list[str]) -> dict[str, tuple[float, float]]:
    """``['m_c=1:5', ...]`` -> {'m_c': (1.0, 5.0)}; ValueError on a malformed item."""
    out: dict[str, tuple[float, float]] = {}
    for item in items:
        name, sep, rng = item.partition('=')
        lo, sep2, hi = rng.partition(':')
        try:
            if not (sep and sep2 and name.strip()):
                raise ValueError
            out[name.strip()] = (float(lo), float(hi))
        except ValueError:
            raise ValueError(f"--bound {item!r} is not NAME=LO:HI (e.g. m_c=1:5)") from None
    return out


def _fail(message: str) -> int:
    """A refused input: the one line ``cartpole identify: error: ...``, exit 2."""
    print(f'{PROG}: error: {message}', file=sys.stderr)
    return 2


def check_bounds(bounds: dict[str, tuple[float, float]], nominal) -> None:
    """Each ``--bound`` finite, low < high, and both ends valid values of the parameter."""
    for name, (lo, hi) in bounds.items():
        item = f'--bound {name}={lo:g}:{hi:g}'
        if not (math.isfinite(lo) and math.isfinite(hi)):
            raise InputError(f'{item}: the bounds must be finite numbers')
        if not lo < hi:
            raise InputError(f'{item}: the bounds must have low < high')
        if not hasattr(nominal, name):
            continue  # not a parameter: the fit names it (with the known ones)
        for end in (lo, hi):
            try:
                nominal.replace(**{name: end})
            except (ValueError, TypeError) as error:
                raise InputError(f'{item}: {error}') from None


def check_fit_inputs(args: argparse.Namespace) -> None:
    """The numbers and output paths of a fit, before any bag is read (InputError naming one)."""
    boundary.number('--weight-cart', args.weight_cart, 0.0, 1e6, low_open=True)
    if args.weight_pendulum is not None:
        boundary.number('--weight-pendulum', args.weight_pendulum, 0.0, 1e6, low_open=True)
    # at least 0.1 ms: a finer step makes one fit take hours (the default 2.5 ms, seconds)
    boundary.number('--integration-step', args.integration_step, 1e-4, 0.005, unit='s')
    boundary.number('--max-nfev', args.max_nfev, 1, 100_000)
    for name in ('t_start', 't_end'):
        if getattr(args, name) is not None:
            boundary.number(f'--{name.replace("_", "-")}', getattr(args, name), 0.0,
                            boundary.MAX_DURATION_S, unit='s')
    if args.t_start is not None and args.t_end is not None and not args.t_end > args.t_start:
        raise InputError(f'--t-end {args.t_end:g} s must be after --t-start {args.t_start:g} s')
    if args.output is not None:
        args.output = boundary.output_file(args.output, '--output', ('.yaml', '.yml'))
    if args.plot is not None:
        args.plot = boundary.figure_file(args.plot, '--plot')


def write_parameters(result, path: Path, bags: list[Path]) -> None:
    """The fitted parameters as CartPoleParameters YAML, with a provenance comment.

    Written to a temporary file first and renamed, so a failure never leaves
    half a file (or destroys the previous one).
    """
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix='.identify-', suffix='.yaml', dir=path.parent or '.')
    os.close(fd)
    try:
        result.params.to_yaml(tmp)
        body = Path(tmp).read_text()
        stamp = _dt.datetime.now(_dt.timezone.utc).strftime('%Y-%m-%dT%H:%M:%SZ')
        lines = [f'# Plant parameters fitted by `cartpole identify` on {stamp}',
                 f'# from: {", ".join(str(b) for b in bags)}',
                 f'# free: {", ".join(result.free)}; cart RMSE sum (4.22) '
                 f'{result.cost_before:.4g} m -> {result.cost_after:.4g} m']
        for name in result.free:
            lines.append(f'#   {name} = {result.values[name]:.6g} +/- '
                         f'{result.std_errors[name]:.2g} (was {result.initial_values[name]:.6g})')
        Path(tmp).write_text('\n'.join(lines) + '\n' + body)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def write_plot(result, recordings, path: Path) -> Path:
    """Measured and simulated x and theta per recording, before and after the fit."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    n = len(recordings)
    fig, axes = plt.subplots(2, n, figsize=(5.5 * n, 6.0), squeeze=False, sharex='col')
    for b, (rec, traj) in enumerate(zip(recordings, result.trajectories)):
        t = rec.t - rec.t[0]
        x_before, th_before, x_after, th_after = traj
        for row, (meas, before, after, unit) in enumerate(
                ((rec.x, x_before, x_after, 'x [m]'),
                 (rec.theta, th_before, th_after, 'theta [rad]'))):
            ax = axes[row][b]
            ax.plot(t, meas, 'k', lw=1.2, label='measured')
            ax.plot(t, before, 'C1--', lw=1.0, label='model, initial parameters')
            ax.plot(t, after, 'C0', lw=1.0, label='model, fitted parameters')
            ax.set_ylabel(unit)
            ax.grid(True, alpha=0.3)
        axes[0][b].set_title(result.recordings[b].label)
        axes[1][b].set_xlabel('t [s]')
        force_ax = axes[0][b].twinx()
        force_ax.step(t, rec.force, 'C2', lw=0.8, where='post', alpha=0.6)
        force_ax.set_ylabel('force command [N]', color='C2')
    axes[0][0].legend(loc='best', fontsize=8)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def pulse_main(args: argparse.Namespace) -> int:
    """``--pulse-plan``: rehearse a pulse test on the model, then play (and record) it."""
    import math

    from ..identification.pulse_plan import parse_pulse_plan
    from ..identification.pulse_player import PulsePlayer, rehearsal_warnings, rehearse

    if args.bags:
        return _fail('give either BAGs to fit or --pulse-plan to play, not both')
    params = nominal_parameters(args)
    try:
        pulses = parse_pulse_plan(args.pulse_plan, params)
    except (OSError, ValueError) as error:
        return _fail(f'--pulse-plan: {error}' if '--pulse-plan' not in str(error) else str(error))
    if args.record is not None and args.record.exists():
        return _fail(f'--record {args.record}: already exists; choose a new bag directory')
    from cartpole_core import namespaces
    try:
        namespace = namespaces.normalize(args.namespace)
    except ValueError as error:
        return _fail(f'--namespace: {error}')
    options = dict(lead_in=args.lead_in, settle=args.settle, margin=args.margin)

    def check(x0: float, theta0: float) -> tuple[list[str], object]:
        rec, player = rehearse(pulses, params, x0=min(max(x0, 0.0), params.travel),
                               theta0=theta0, **options)
        return rehearsal_warnings(rec, player), rec

    problems, rec = check(args.x0, math.pi)
    stops = _settled_positions(rec)
    summary = {'pulses': [[p.force, p.length] for p in pulses], 'rehearsal': {
        'x0': args.x0, 'x_min': float(rec.x.min()), 'x_max': float(rec.x.max()),
        'x_after_pulses': stops, 'duration_s': rec.duration, 'problems': problems}}
    if args.rehearse:
        if args.json:
            print_json(summary)
        else:
            print(f'rehearsal on the model from x = {args.x0:g} m: cart between '
                  f'{rec.x.min():.3f} and {rec.x.max():.3f} m, stands after the pulses at '
                  + (', '.join(f'{x:.3f} m' for x in stops) or '(none played)')
                  + f'; {rec.duration:.1f} s')
            for problem in problems:
                print(f'unsafe: {problem}')
        return 0 if not problems else 1

    from ..identification.node import run_pulse_plan

    player = PulsePlayer(pulses, params, **options)
    try:
        played = run_pulse_plan(player, record=args.record, arm=args.arm, timeout=args.timeout,
                                ros_arguments=namespaces.ros_arguments(namespace),
                                check=lambda x0, theta0: check(x0, theta0)[0],
                                log=lambda line: print(line, file=sys.stderr))
    except RuntimeError as error:  # the test failed while it played
        print(f'{PROG}: the pulse test failed: {error}', file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f'{PROG}: interrupted; zero force sent', file=sys.stderr)
        return 130
    summary['played'] = played
    if args.json:
        print_json(summary)
    else:
        print(f'played {played["pulses"]} pulse(s) over {played["samples"]} samples'
              + (f'; {played["guard"]}' if played['guard'] else ''))
        if played['bag']:
            print(f'recorded: {played["bag"]}; fit with: cartpole identify {played["bag"]}')
    return 0 if not played['guard'] else 1


def _settled_positions(rec) -> list[float]:
    """Cart positions at the end of each zero-force stretch that follows a pulse."""
    import numpy as np
    active = rec.force != 0.0
    ends = np.flatnonzero(active[:-1] & ~active[1:])  # last sample of each pulse
    starts = np.flatnonzero(~active[:-1] & active[1:])
    out = []
    for e in ends:
        nxt = starts[starts > e]
        k = int(nxt[0]) if nxt.size else rec.x.size - 1
        out.append(float(rec.x[k]))
    return out


def check_pulse_options(args: argparse.Namespace, params) -> None:
    """The pulse test's options, checked with or without ``--pulse-plan`` (InputError)."""
    boundary.number('--x0', args.x0, 0.0, params.travel, unit='m')
    boundary.number('--margin', args.margin, 0.0, 0.5 * params.travel, unit='m')
    boundary.number('--settle', args.settle, 0.0, 60.0, unit='s')
    boundary.number('--lead-in', args.lead_in, 0.0, 60.0, unit='s')
    boundary.number('--timeout', args.timeout, 0.0, 3600.0, low_open=True, unit='s')
    if args.record is not None:
        boundary.output_directory(args.record.parent, '--record')


def main(args: argparse.Namespace) -> int:
    from ..identification.bag_input import load_recording
    from ..identification.fit import identify, parse_free
    from ..identification.recording import IdentificationError

    check_pulse_options(args, nominal_parameters(args))
    if args.pulse_plan is not None:
        return pulse_main(args)
    if not args.bags:
        return _fail('give one or more BAGs to fit (or --pulse-plan to record a test)')
    nominal = nominal_parameters(args)
    try:
        free = parse_free(args.free)
        bounds = parse_bounds(args.bound)
    except (OSError, ValueError) as error:
        return _fail(str(error))
    check_bounds(bounds, nominal)
    check_fit_inputs(args)
    from cartpole_bringup.commands.analyze import checked_bag
    for bag in args.bags:
        if bag.is_dir() and not (bag / 'metadata.yaml').exists() and not any(bag.glob('*.mcap')):
            continue  # not a bag at all: load_recording says so
        checked_bag(bag)
    recordings = []
    for bag in args.bags:
        try:
            recordings.append(load_recording(bag, t_start=args.t_start, t_end=args.t_end,
                                             sample_time=nominal.sample_time,
                                             zero_force=args.zero_force))
        except (OSError, ValueError) as error:
            return _fail(f'{bag}: {error}' if str(bag) not in str(error) else str(error))
    progress = (lambda line: print(line, file=sys.stderr)) if args.verbose else None
    try:
        result = identify(recordings, nominal, free=free, bounds=bounds,
                          weight_cart=args.weight_cart, weight_pendulum=args.weight_pendulum,
                          refine_initial_state=args.refine_initial_state,
                          integration_step=args.integration_step, max_nfev=args.max_nfev,
                          progress=progress)
    except IdentificationError as error:
        return _fail(str(error))
    written = []
    try:
        if args.output is not None:
            write_parameters(result, args.output, list(args.bags))
            written.append(str(args.output))
        if args.plot is not None:
            written.append(str(write_plot(result, recordings, args.plot)))
    except OSError as error:
        print(f'{PROG}: cannot write: {error}', file=sys.stderr)
        return 1
    if not result.success:
        print(f'{PROG}: warning: the fit did not converge ({result.message}); the result is the '
              'best point found, raise --max-nfev or check the data', file=sys.stderr)
    if args.json:
        out = result.to_dict()
        out['bags'] = [str(b) for b in args.bags]
        out['output'] = str(args.output) if args.output is not None else None
        out['plot'] = str(args.plot) if args.plot is not None else None
        print_json(out)
        return 0
    print('\n'.join(format_report(result)))
    for path in written:
        print(f'wrote: {path}')
    return 0


def format_report(result) -> list[str]:
    """The result as text: parameters, errors per recording, the solver's word."""
    lines = [f'{"parameter":<12} {"initial":>11} {"fitted":>11} {"std. error":>11}'
             f' {"change":>8}']
    for name in result.free:
        v0, v, se = result.initial_values[name], result.values[name], result.std_errors[name]
        change = f'{(v - v0) / v0 * 100:+.1f} %' if v0 else ''
        flag = '  (at a bound)' if name in result.at_bound else ''
        lines.append(f'{name:<12} {v0:>11.5g} {v:>11.5g} {se:>11.2g} {change:>8}{flag}')
    lines.append('')
    lines.append(f'{"recording":<20} {"samples":>7} {"RMSE x [mm]":>21} '
                 f'{"RMSE theta [mrad]":>21}')
    lines.append(f'{"":<20} {"":>7} {"before":>10} {"after":>10} {"before":>10} {"after":>10}')
    for r in result.recordings:
        lines.append(f'{r.label[:20]:<20} {r.samples:>7} {r.rmse_x_before_m * 1e3:>10.3f} '
                     f'{r.rmse_x_after_m * 1e3:>10.3f} {r.rmse_theta_before_rad * 1e3:>10.3f} '
                     f'{r.rmse_theta_after_rad * 1e3:>10.3f}')
    lines.append('')
    lines.append(f'cost (4.22), sum of cart RMSE: {result.cost_before * 1e3:.3f} mm -> '
                 f'{result.cost_after * 1e3:.3f} mm')
    strong = [(result.free[i], result.free[j], result.correlation[i][j])
              for i in range(len(result.free)) for j in range(i + 1, len(result.free))
              if abs(result.correlation[i][j]) > 0.95]
    for a, b, c in strong:
        lines.append(f'note: {a} and {b} are strongly correlated ({c:+.3f}); the tests '
                     'barely tell them apart')
    lines.append(f'solver: {result.message} ({result.nfev} evaluations, '
                 f'{result.simulations} simulations)')
    return lines
