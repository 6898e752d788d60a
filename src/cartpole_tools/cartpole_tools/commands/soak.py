"""`cartpole soak --duration S`: the real-time graph for a long time, its verdict (docs/soak.md).

Runs :func:`cartpole_tools.soak.session.run_soak`, prints the verdict and writes
``soak.json`` and ``soak.md`` (and the bag) under ``--out``. Exit 0 when every
target is met, 1 otherwise; SIGINT / SIGTERM end the soak early (reported as not
run to the end).
"""
from __future__ import annotations

import argparse
import datetime as _dt
import json
import signal
import sys
from pathlib import Path

HELP = 'the real-time graph for a long time: faults, upright, bag, memory growth'
"""The line of ``cartpole --help``."""

MAX_SOAK_S = 8 * 3600.0
"""Longest soak [s]: a bag of about 0.7 GB an hour is written."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--duration', type=float, required=True, metavar='S',
                        help=f'wall seconds to run (at most {MAX_SOAK_S:g})')
    parser.add_argument('--switch-every', type=float, default=60.0, metavar='S',
                        help='switch the stabiliser every S seconds (default 60)')
    parser.add_argument('--restart-every', type=float, default=600.0, metavar='S',
                        help='restart the swing-up from hanging every S seconds (default 600)')
    parser.add_argument('--sample-every', type=float, default=5.0, metavar='S',
                        help='read each process\'s memory, open files and CPU every S seconds '
                             '(default 5)')
    parser.add_argument('--settle', type=float, default=300.0, metavar='S',
                        help='memory growth counts from S seconds on (default 300)')
    parser.add_argument('--catch-timeout', type=float, default=30.0, metavar='S',
                        help='a swing-up not caught within S seconds fails (default 30)')
    parser.add_argument('--stabilizers', nargs='+', default=None, metavar='NAME',
                        help='stabilisers to switch through in turn (default: every registered '
                             'one, the default first)')
    parser.add_argument('--out', type=Path, default=None, metavar='DIR',
                        help='where the report and the bag go (default: runs/soak/<UTC time>; '
                             'it must not hold a bag)')
    parser.add_argument('--json', action='store_true', help='print the results as JSON')


def check(args: argparse.Namespace) -> None:
    """Every option checked before the graph starts (InputError naming it)."""
    from cartpole_bringup import boundary

    boundary.number('--duration', args.duration, 0.0, MAX_SOAK_S, low_open=True, unit='s')
    boundary.number('--switch-every', args.switch_every, 1.0, MAX_SOAK_S, unit='s')
    boundary.number('--restart-every', args.restart_every, 10.0, MAX_SOAK_S, unit='s')
    boundary.number('--sample-every', args.sample_every, 0.5, 3600.0, unit='s')
    boundary.number('--settle', args.settle, 0.0, MAX_SOAK_S, unit='s')
    boundary.number('--catch-timeout', args.catch_timeout, 5.0, 600.0, unit='s')
    if args.stabilizers:
        from cartpole_control.registry import load_controllers
        known = sorted(load_controllers('stabilizer'))
        unknown = [n for n in args.stabilizers if n not in known]
        if unknown:
            raise boundary.InputError(f'--stabilizers: unknown {", ".join(unknown)}; '
                                      f'registered: {", ".join(known)}')
    if args.out is not None:
        boundary.output_directory(args.out, '--out')
        if (args.out / 'bag').exists():
            raise boundary.InputError(f'--out: {args.out / "bag"} exists (a bag is never '
                                      'overwritten)')


def markdown(result: dict) -> str:
    """The soak's figures as the table of docs/soak.md."""
    c = result['config']
    md = [f'Soak of {result["elapsed_s"]:.0f} s (asked {c["duration"]:g} s): stabiliser switched '
          f'every {c["switch_every"]:g} s ({result["switches"]} switches), swing-up restarted '
          f'every {c["restart_every"]:g} s ({result["restarts"]} restarts). Verdict: '
          f'{"PASS" if result["ok"] else "FAIL"}.\n',
          f'- faults: {", ".join(result["faults"]) or "none"}',
          f'- pendulum up whenever it should be: {result["up_ok"]} '
          f'({len(result["segments"])} swing-ups; catch after '
          f'{", ".join(str(s["catch_after_s"]) for s in result["segments"])} s; largest '
          f'|theta_w| after settling {max([s["max_settled_deg"] for s in result["segments"]] or [0]):.2f} deg)',
          f'- bag complete: {result["bag_ok"]} (damage: {result["damage"] or "none"}, recorder '
          f'missed {result["recorder_missed"]}; before discovering their publisher: '
          f'{result.get("recorder_missed_at_start")})',
          f'- longest gap between two samples: {result["longest_sample_gap_s"] * 1e3:.1f} ms; '
          f'longest gap between two control cycles: {result["longest_cycle_gap_s"] * 1e3:.1f} ms',
          f'- memory growth judged: {result["memory_ok"]} (limit {result["memory_limit_mb_per_h"]:g} '
          f'MB/h after {c["settle"]:g} s)',
          f'- load average at the end: {" / ".join(f"{x:.2f}" for x in result["load_average"])}\n',
          '| topic | messages seen by the probe | recorded (same stamps) | missing |',
          '|---|---|---|---|']
    for topic, t in result['topics'].items():
        md.append(f'| {topic} | {t["published_seen"]} | {t["recorded"]} | {t["missing"]} |')
    md += ['', '| process | RSS first / last / max [MB] | growth after settle [MB/h] '
               '| open files first / last / max | CPU [%] |', '|---|---|---|---|---|']
    for name, p in result['processes'].items():
        if not p.get('samples'):
            continue
        growth = '-' if p['growth_mb_per_h'] is None else f'{p["growth_mb_per_h"]:+.2f}'
        cpu = '-' if p['cpu_percent'] is None else f'{p["cpu_percent"]:.1f}'
        md.append(f'| {name} | {p["rss_first_mb"]:.1f} / {p["rss_last_mb"]:.1f} / '
                  f'{p["rss_max_mb"]:.1f} | {growth} | {p["fds_first"]} / {p["fds_last"]} / '
                  f'{p["fds_max"]} | {cpu} |')
    return '\n'.join(md) + '\n'


def main(args: argparse.Namespace) -> int:
    check(args)
    from cartpole_bringup import boundary
    from cartpole_bringup.graph.graph import GraphError

    from ..soak.session import SoakConfig, run_soak

    out = args.out or Path('runs') / 'soak' / _dt.datetime.now(_dt.timezone.utc).strftime(
        '%Y%m%dT%H%M%SZ')
    config = SoakConfig(duration=args.duration, out=out, switch_every=args.switch_every,
                        restart_every=args.restart_every, sample_every=args.sample_every,
                        settle=args.settle, catch_timeout=args.catch_timeout,
                        stabilizers=tuple(args.stabilizers or ()))
    stop = {'requested': False}
    previous = {sig: signal.signal(sig, lambda *_: stop.update(requested=True))
                for sig in (signal.SIGINT, signal.SIGTERM)}
    say = (lambda text: None) if args.json else (
        lambda text: print(f'cartpole soak: {text}', file=sys.stderr, flush=True))
    try:
        result = run_soak(config, should_stop=lambda: stop['requested'], say=say)
    except GraphError as error:
        print(f'cartpole soak: {error}', file=sys.stderr)
        return 1
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    (out / 'soak.json').write_text(boundary.json_text(result, indent=2) + '\n')
    report = markdown(result)
    (out / 'soak.md').write_text(report)
    print(boundary.json_text(result, indent=2) if args.json else report)
    return 0 if result['ok'] else 1
