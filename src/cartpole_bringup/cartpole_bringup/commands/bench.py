"""`cartpole bench control|loop|offline|all`: the benchmarks of SPEC section 6.

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


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest='bench', metavar='BENCH', required=True)

    c = sub.add_parser('control', help='every swing-up x stabiliser pair over the scenario grid')
    _common(c)
    c.add_argument('--seeds', type=int, default=3, help='runs per pair and scenario (default 3)')
    c.add_argument('--duration', type=float, default=30.0, metavar='S', help='simulated seconds per run')
    c.add_argument('--swingups', nargs='*', default=None, metavar='NAME', help='default: all registered')
    c.add_argument('--stabilizers', nargs='*', default=None, metavar='NAME', help='default: all registered')
    c.add_argument('--scenarios', nargs='*', default=None, metavar='NAME',
                   help='default: the whole grid (nominal, mass-20%%, mass-10%%, mass+10%%, friction x0.8, '
                        'friction x1.2, offset +0.05, offset -0.05)')
    c.add_argument('--workers', type=int, default=os.cpu_count() or 1,
                   help='local process pool size (default: the number of cores; 1 = serial)')
    c.add_argument('--no-bound', action='store_true',
                   help='skip the minimum-time bound (an IPOPT solve of some seconds)')
    c.add_argument('--dask', default=None, metavar='ADDRESS',
                   help='run the sweep on a Dask distributed scheduler instead (tcp://host:8786)')

    o = sub.add_parser('offline', help='simulated seconds per wall second of the offline loop, per stage')
    _common(o)
    o.add_argument('--duration', type=float, default=30.0, metavar='S')
    o.add_argument('--repeat', type=int, default=3, help='runs; the best is reported')

    lp = sub.add_parser('loop', help='sample-to-command latency of the real node graph vs bare rclpy')
    _common(lp)
    lp.add_argument('--duration', type=float, default=60.0, metavar='S', help='wall seconds per mode')
    lp.add_argument('--modes', nargs='*', default=['single', 'processes'],
                    choices=['single', 'processes'])
    lp.add_argument('--view', type=int, nargs='?', const=3, default=0, metavar='ROUNDS',
                    help='also measure the viewer\'s cost: ROUNDS (default 3) alternating pairs '
                         'of runs without and with the live viewer (cartpole run --view) and a '
                         'Foxglove WebSocket client attached')

    a = sub.add_parser('all', help='control, offline and loop with their defaults')
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

    from .. import bench_control as bc

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


def bench_offline(args: argparse.Namespace, argv: list[str]) -> dict:
    import time

    from ..closed_loop import run_closed_loop

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
    from ..bench_loop import run_loop_benchmark

    out = _out_dir(args, 'loop')
    if getattr(args, 'view', 0) < 0:
        raise SystemExit('--view ROUNDS must be >= 0')
    result = run_loop_benchmark(duration=args.duration, modes=args.modes,
                                view_rounds=getattr(args, 'view', 0))
    report = header('Loop latency (`cartpole bench loop`)', argv) + result['markdown']
    (out / 'loop.md').write_text(report)
    (out / 'loop.json').write_text(json.dumps(result['results'], indent=1))
    return {'report': report, 'results': result['results'], 'dir': str(out)}


def main(args: argparse.Namespace) -> int:
    argv = sys.argv[1:]
    benches = {'control': bench_control, 'offline': bench_offline, 'loop': bench_loop}
    if args.bench == 'all':
        defaults = argparse.ArgumentParser()
        add_arguments(defaults)
        todo = []
        for name in ('offline', 'control', 'loop'):
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
