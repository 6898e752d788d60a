"""`cartpole bench control|robustness|loop|offline|all`: the benchmarks (docs/benchmarks.md).

Each benchmark prints a markdown report and writes it (and its figures and raw
JSON) under ``--out``. No benchmark asserts anything: they measure.
"""
from __future__ import annotations

import argparse
import datetime as _dt
import json
import os
import platform
import sys
from pathlib import Path


HELP = 'benchmarks: controller comparison, loop latency, offline speed'
"""The line of ``cartpole --help``."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest='bench', metavar='BENCH', required=True)

    c = sub.add_parser('control', help='every swing-up x stabiliser pair over the scenario grid')
    _common(c)
    c.add_argument('--seeds', type=int, default=3, help='runs per pair and scenario (default 3)')
    c.add_argument('--duration', type=float, default=30.0, metavar='S', help='simulated seconds per run')
    c.add_argument('--swingups', nargs='*', default=None, metavar='NAME', help='default: all registered')
    c.add_argument('--stabilizers', nargs='*', default=None, metavar='NAME', help='default: all registered')
    c.add_argument('--scenarios', nargs='*', default=None, metavar='NAME',
                   help='default: the whole grid (nominal, mass-20%%, mass-10%%, mass+10%%, friction '
                        'x0.8, x1.2 and x1.5, offset +-0.01, +-0.02, +-0.05 and +-0.1, '
                        'offset +0.05 mass-20%%)')
    c.add_argument('--workers', type=int, default=os.cpu_count() or 1,
                   help='local process pool size (default: the number of cores; 1 = serial)')
    c.add_argument('--no-bound', action='store_true',
                   help='skip the minimum-time bound (an IPOPT solve of some seconds)')
    c.add_argument('--dask', default=None, metavar='ADDRESS',
                   help='run the sweep on a Dask distributed scheduler instead (tcp://host:8786)')

    r = sub.add_parser('robustness', help='the sim-to-real gap, scored: every disturbance swept '
                                          'from nominal outwards')
    _common(r)
    r.add_argument('--pairs', nargs='*', default=None, metavar='SWINGUP:STABILIZER',
                   help='default: the default pair and every stabiliser with pendulum_energy')
    r.add_argument('--categories', nargs='*', default=None, metavar='NAME',
                   help='default: all (model, measurement noise, force noise, actuator gain, '
                        'actuator lag, delay, lost samples, encoder offset, push)')
    r.add_argument('--max-levels', type=int, default=None, metavar='N',
                   help='only the first N levels of each sweep (a quick look; default: all)')
    r.add_argument('--seeds', type=int, default=3, help='runs per level (default 3)')
    r.add_argument('--duration', type=float, default=30.0, metavar='S',
                   help='simulated seconds per run (default 30)')
    r.add_argument('--all-seeds', action='store_true',
                   help='run every seed of every level (default: a level stops once its '
                        'majority is decided; the scores are the same)')
    r.add_argument('--workers', type=int, default=os.cpu_count() or 1,
                   help='local process pool size (default: the number of cores; 1 = serial)')
    r.add_argument('--dask', default=None, metavar='ADDRESS',
                   help='run the grid on a Dask distributed scheduler instead (tcp://host:8786)')
    r.add_argument('--combined', type=int, default=None, metavar='N',
                   help='instead of the grid: N scenarios with every disturbance drawn at once '
                        'from the range table (docs/robustness.md), strict success with its '
                        '95 %% interval, failures by kind and by factor, a replayable scenario '
                        'file for each failure')
    r.add_argument('--ranges', type=Path, default=None, metavar='FILE.yaml',
                   help='with --combined: your own range table (keys left out keep the '
                        'published ones, share/cartpole_sim/config/combined_ranges.yaml)')
    r.add_argument('--seed', type=int, default=0,
                   help='with --combined: seed of the draws (scenario i from (seed, i); '
                        'default 0)')

    o = sub.add_parser('offline', help='simulated seconds per wall second of the offline loop, per stage')
    _common(o)
    o.add_argument('--duration', type=float, default=30.0, metavar='S')
    o.add_argument('--repeat', type=int, default=3, help='runs; the best is reported')

    lp = sub.add_parser('loop', help='sample-to-command latency of the real node graph vs bare rclpy')
    _common(lp)
    lp.add_argument('--duration', type=float, default=60.0, metavar='S', help='wall seconds per mode')
    lp.add_argument('--warmup', type=float, default=3.0, metavar='S',
                    help='wall seconds after the first command before each measurement (default 3)')
    lp.add_argument('--modes', nargs='*', default=['single', 'processes'],
                    choices=['single', 'processes'])
    lp.add_argument('--executors', nargs='*', default=['events', 'single'],
                    choices=['events', 'single'],
                    help='executors of the one-process graph and its floor (default both; one '
                         'process a node always spins the SingleThreadedExecutor)')
    lp.add_argument('--view', type=int, nargs='?', const=3, default=0, metavar='ROUNDS',
                    help='also measure the viewer\'s cost: ROUNDS (default 3) alternating pairs '
                         'of runs without and with the live viewer (cartpole run --view) and a '
                         'Foxglove WebSocket client attached, on the first of --executors')
    lp.add_argument('--mpc-solve', action='store_true',
                    help='also measure the mpc stabiliser\'s QP solve time per control cycle '
                         '(p50/p99/max over a 30 s closed loop with pushes, '
                         'cartpole_tools.bench.mpc_solve)')

    a = sub.add_parser('all', help='control, robustness, offline and loop with their defaults')
    _common(a)


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument('--out', type=Path, default=None, metavar='DIR',
                   help='where to write the report (default: runs/bench/<UTC time>)')
    p.add_argument('--json', action='store_true', help='print the raw results as JSON')


def _out_dir(args: argparse.Namespace, name: str) -> Path:
    stamp = _dt.datetime.now(_dt.timezone.utc).strftime('%Y%m%dT%H%M%SZ')
    out = args.out or Path('runs') / 'bench' / stamp
    out = out / name if getattr(args, 'bench', None) == 'all' else out
    out.mkdir(parents=True, exist_ok=True)
    return out


def machine_line() -> str:
    return (f'{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}, '
            f'{platform.system()} {platform.release()}')


def header(title: str, argv: list[str]) -> str:
    now = _dt.datetime.now(_dt.timezone.utc).strftime('%Y-%m-%d %H:%M UTC')
    return (f'## {title}\n\nDate: {now}. Machine: {machine_line()}.\n'
            f'Command: `cartpole {" ".join(argv)}`\n\n')


def _progress(done: int, total: int) -> None:
    width = 30
    filled = int(width * done / total)
    sys.stderr.write(f'\r[{"#" * filled}{"." * (width - filled)}] {done}/{total}')
    if done == total:
        sys.stderr.write('\n')
    sys.stderr.flush()


def bench_control(args: argparse.Namespace, argv: list[str]) -> dict:
    from cartpole_control.registry import load_controllers

    from ..bench import control as bc

    swingups = args.swingups or list(load_controllers('swingup'))
    stabilizers = args.stabilizers or list(load_controllers('stabilizer'))
    scenarios = args.scenarios or list(bc.SCENARIOS)
    cases = bc.make_cases(swingups, stabilizers, scenarios, args.seeds, args.duration)
    bc.prepare(swingups)
    results = bc.run_sweep(cases, workers=args.workers, dask_address=args.dask,
                           progress=None if args.json else _progress)
    rows = bc.aggregate(results)
    out = _out_dir(args, 'control')
    report = header('Controller comparison (`cartpole bench control`)', argv)
    report += (f'{len(cases)} runs: {len(swingups)} swing-ups x {len(stabilizers)} stabilisers x '
               f'{len(scenarios)} scenarios x {args.seeds} seeds, {args.duration:g} s each, '
               'measurement noise on, encoder quantisation and 5 ms sampling always on.\n\n')
    bound = None if args.no_bound else bc.left_stop_bound()
    report += bc.markdown_report(rows, results, bound)
    figures = bc.plot_report(rows, results, out)
    report += '\n' + '\n'.join(f'![{Path(f).stem}]({Path(f).name})' for f in figures) + '\n'
    (out / 'control.md').write_text(report)
    (out / 'control.json').write_text(json.dumps(results, indent=1))
    return {'report': report, 'results': results, 'rows': rows, 'bound_s': bound, 'dir': str(out)}


def _pairs(args: argparse.Namespace) -> list[tuple[str, str]]:
    from cartpole_control.controller import STABILIZER, SWINGUP
    from cartpole_control.manager import DEFAULT_CONTROLLERS
    from cartpole_control.registry import load_controllers

    from ..bench.robustness import default_pairs

    swingups, stabilizers = load_controllers('swingup'), load_controllers('stabilizer')
    if not args.pairs:
        return default_pairs(list(stabilizers),
                             (DEFAULT_CONTROLLERS[SWINGUP], DEFAULT_CONTROLLERS[STABILIZER]))
    pairs = []
    for text in args.pairs:
        swingup, _, stabilizer = text.partition(':')
        if swingup not in swingups or stabilizer not in stabilizers:
            raise SystemExit(f'--pairs {text!r}: expected SWINGUP:STABILIZER with a swing-up in '
                             f'{sorted(swingups)} and a stabiliser in {sorted(stabilizers)}')
        pairs.append((swingup, stabilizer))
    return list(dict.fromkeys(pairs))


def bench_robustness(args: argparse.Namespace, argv: list[str]) -> dict:
    import dataclasses
    import time

    from ..bench import control as bc
    from ..bench import robustness as br
    from ..bench import robustness_report as rr

    if args.seeds < 1 or not args.duration > 0:
        raise SystemExit('--seeds must be >= 1 and --duration > 0')
    pairs = _pairs(args)
    if getattr(args, 'combined', None) is not None:
        from ..bench.combined_bench import bench_combined
        return bench_combined(args, argv, pairs, lambda: _out_dir(args, 'robustness'),
                              header('Combined disturbances (`cartpole bench robustness '
                                     '--combined`)', argv) + f'Load average at the start: '
                              f'{_load()}.\n\n', None if args.json else _progress)
    try:
        sweeps = br.sweeps_of(args.categories)
    except ValueError as error:
        raise SystemExit(f'--categories: {error}') from None
    if args.max_levels is not None:
        if args.max_levels < 1:
            raise SystemExit('--max-levels must be >= 1')
        sweeps = [dataclasses.replace(s, levels=s.levels[:args.max_levels]) for s in sweeps]
    grid_cells, runs = br.make_grid(pairs, sweeps, args.seeds, args.duration)
    bc.prepare([su for su, _ in pairs])
    load = _load()
    t0 = time.perf_counter()
    progress = None if args.json else _progress
    if args.all_seeds:
        cells = grid_cells
        results = br.run_grid(runs, workers=args.workers, dask_address=args.dask,
                              progress=progress)
    else:
        cells, results = br.run_by_majority(grid_cells, runs, sweeps, args.seeds,
                                            workers=args.workers, dask_address=args.dask,
                                            progress=progress)
    wall = time.perf_counter() - t0
    by_name = {s.name: s for s in sweeps}
    successes = [br.succeeded(by_name[c.sweep], r) for c, r in zip(cells, results)]
    scores = br.score(cells, successes, sweeps)
    out = _out_dir(args, 'robustness')
    run_of = dict(zip(grid_cells, runs))
    unique = len({run_of[c] for c in cells})
    report = header('Robustness score (`cartpole bench robustness`)', argv)
    report += (f'{len(pairs)} pairs x {len(sweeps)} sweeps ({sum(len(s.levels) for s in sweeps)} '
               f'levels) x {args.seeds} seeds = {len(grid_cells)} cells; '
               f'{len(cells)} needed ({"every seed" if args.all_seeds else "a level stops once its majority is decided"}), '
               f'{unique} distinct runs of {args.duration:g} s, measurement noise on. Wall time '
               f'{wall:.0f} s on {"Dask" if args.dask else f"{args.workers} worker(s)"} '
               f'(load average at the start: {load}).\n\n')
    report += rr.markdown_report(scores, sweeps, args.seeds)
    figure = rr.plot_heatmap(scores, sweeps, out / 'robustness_heatmap.png')
    report += f'\n![robustness heat map]({Path(figure).name})\n'
    meta = {'pairs': [list(p) for p in pairs], 'seeds': args.seeds, 'duration_s': args.duration,
            'wall_s': wall, 'load_average_at_start': load, 'cells': len(grid_cells),
            'cells_run': len(cells), 'distinct_runs': unique}
    raw = rr.results_json(cells, results, successes, sweeps, scores, meta)
    (out / 'robustness.md').write_text(report)
    (out / 'robustness.json').write_text(json.dumps(raw, separators=(',', ':')))
    return {'report': report, 'results': raw, 'dir': str(out)}


def _load() -> str:
    try:
        return ' '.join(f'{v:.2f}' for v in os.getloadavg())
    except OSError:
        return 'n/a'


def bench_offline(args: argparse.Namespace, argv: list[str]) -> dict:
    import time

    from cartpole_bringup.offline.closed_loop import run_closed_loop

    best = None
    for _ in range(max(1, args.repeat)):
        profile: dict[str, float] = {}
        t0 = time.perf_counter()
        run_closed_loop(duration=args.duration)
        wall = time.perf_counter() - t0
        run_closed_loop(duration=args.duration, profile=profile)
        if best is None or wall < best[0]:
            best = (wall, profile)
    wall, profile = best
    steps = profile['steps']
    stage_us = {k: 1e6 * profile[k] / steps for k in ('plant', 'ekf', 'controller')}
    result = {'duration_s': args.duration, 'wall_s': wall, 'speed_x_real_time': args.duration / wall,
              'per_step_us': stage_us, 'steps': steps}
    out = _out_dir(args, 'offline')
    report = header('Offline speed (`cartpole bench offline`)', argv)
    report += (f'Default scenario and controllers, {args.duration:g} simulated seconds, best of '
               f'{args.repeat}, one core.\n\n'
               f'| measure | value |\n|---|---|\n'
               f'| simulated seconds per wall second | {result["speed_x_real_time"]:.1f} |\n'
               f'| wall time | {wall:.3f} s |\n')
    for k, v in stage_us.items():
        report += f'| {k} per 5 ms step (profiled run) | {v:.1f} us |\n'
    (out / 'offline.md').write_text(report)
    (out / 'offline.json').write_text(json.dumps(result, indent=1))
    return {'report': report, 'results': result, 'dir': str(out)}


def bench_loop(args: argparse.Namespace, argv: list[str]) -> dict:
    from ..bench.loop import run_loop_benchmark

    out = _out_dir(args, 'loop')
    if getattr(args, 'view', 0) < 0:
        raise SystemExit('--view ROUNDS must be >= 0')
    if args.warmup < 0:
        raise SystemExit('--warmup S must be >= 0')
    result = run_loop_benchmark(duration=args.duration, modes=args.modes,
                                executors=args.executors, view_rounds=getattr(args, 'view', 0),
                                warmup=args.warmup)
    report = header('Loop latency (`cartpole bench loop`)', argv) + result['markdown']
    if getattr(args, 'mpc_solve', False):
        from ..bench.mpc_solve import solve_times, table
        solve = solve_times({'mpc.budget_us': 1e6})
        result['results']['mpc_solve'] = solve
        report += ('\nMPC solve time per cycle (the `mpc` stabiliser\'s QP with its Python '
                   f'calls, load average {os.getloadavg()[0]:.2f}):\n\n'
                   + table([{'solver': 'daqp', 'horizon': 'default', **solve}]))
    (out / 'loop.md').write_text(report)
    (out / 'loop.json').write_text(json.dumps(result['results'], indent=1))
    return {'report': report, 'results': result['results'], 'dir': str(out)}


BENCH_NUMBERS = {  # option: (attribute, low, high, integer); checked before any bench runs
    '--seeds': ('seeds', 1, 100, True),
    '--workers': ('workers', 1, 256, True),
    '--max-levels': ('max_levels', 1, 1000, True),
    '--repeat': ('repeat', 1, 100, True),
    '--warmup': ('warmup', 0.0, 600.0, False),
    '--view': ('view', 0, 100, True),
    '--combined': ('combined', 1, 1000, True),
    '--seed': ('seed', 0, 2 ** 31 - 1, True),
}
"""The bench's own numbers and their ranges (``--duration`` is any run's duration)."""


def check_arguments(args: argparse.Namespace) -> None:
    """Refuse a bad number or output directory before any run (InputError naming the option)."""
    from cartpole_bringup.boundary import InputError, duration, number, output_directory
    if getattr(args, 'duration', None) is not None:
        duration(args.duration)
        if args.bench == 'robustness':
            number('--duration', args.duration, 0.0, 120.0, low_open=True, unit='s')
    if getattr(args, 'ranges', None) is not None and getattr(args, 'combined', None) is None:
        raise InputError('--ranges FILE.yaml takes effect with --combined N only')
    for option, (name, low, high, integer) in BENCH_NUMBERS.items():
        value = getattr(args, name, None)
        if value is None:
            continue
        number(option, value, low, high)
        if integer and value != int(value):
            raise InputError(f'{option} must be an integer, got {value!r}')
    if args.out is not None:
        output_directory(args.out, '--out')


def main(args: argparse.Namespace) -> int:
    check_arguments(args)
    argv = sys.argv[1:]
    benches = {'control': bench_control, 'robustness': bench_robustness,
               'offline': bench_offline, 'loop': bench_loop}
    if args.bench == 'all':
        defaults = argparse.ArgumentParser()
        add_arguments(defaults)
        todo = []
        for name in ('offline', 'control', 'robustness', 'loop'):
            ns = defaults.parse_args([name])
            ns.out, ns.json, ns.bench = args.out, args.json, 'all'
            todo.append((name, ns))
    else:
        todo = [(args.bench, args)]
    outputs = {}
    for name, ns in todo:
        outputs[name] = benches[name](ns, argv)
        if not args.json:
            print(outputs[name]['report'])
            print(f'written to {outputs[name]["dir"]}')
    if args.json:
        print(json.dumps({k: v['results'] for k, v in outputs.items()}))
    return 0
