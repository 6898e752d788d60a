"""``cartpole bench robustness --combined N``: draw, run, tally, write the report.

The command's glue between the options and :mod:`.combined` (the runs and the
strict rule) and :mod:`.combined_report` (tables, the by-factor plot, the
failure files). Writes ``combined.md``, ``combined.json``,
``combined_factors.png`` and ``failures/*.json`` under ``--out``.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any, Callable, Sequence

from cartpole_sim.scenario_ranges import RangeTable, load_ranges

from . import combined as cb
from . import combined_report as cr


def check_size(n: int, pairs: int, duration: float) -> None:
    """ValueError unless N x pairs x duration stays within :data:`.combined.MAX_SIMULATED_S`."""
    total = n * pairs * duration
    if total > cb.MAX_SIMULATED_S:
        raise ValueError(f'--combined {n} x {pairs} pair(s) x --duration {duration:g} s = '
                         f'{total:g} simulated seconds; at most {cb.MAX_SIMULATED_S:g} (about '
                         '30 minutes on 2 cores): fewer runs, pairs or seconds')


def bench_combined(args: argparse.Namespace, argv: list[str], pairs: Sequence[tuple[str, str]],
                   make_out: Callable[[], Path], header: str,
                   progress: Callable[[int, int], None] | None) -> dict[str, Any]:
    """Run the combined benchmark of ``args`` for ``pairs``; the report, raw results, dir.

    The options are checked first (InputError naming the option); ``make_out()``
    then gives the output directory.
    """
    from cartpole_bringup.boundary import InputError

    from . import control as bc

    try:
        check_size(args.combined, len(pairs), args.duration)
    except ValueError as error:
        raise InputError(str(error)) from None
    try:
        table = load_ranges(args.ranges) if args.ranges is not None else RangeTable()
    except ValueError as error:
        raise InputError(f'--ranges {error}') from None
    out = make_out()
    ranges = str(args.ranges) if args.ranges is not None else 'the published range table'
    drawn = cb.scenarios(table, args.combined, args.seed)
    runs = cb.make_runs(pairs, drawn, args.duration)
    bc.prepare([su for su, _ in pairs])
    t0 = time.perf_counter()
    results = cb.run_combined(runs, workers=args.workers, dask_address=args.dask,
                              progress=progress)
    wall = time.perf_counter() - t0
    tallies = cb.tally(pairs, drawn, results)
    paired = cb.paired_comparison(tallies)
    failures = cr.write_failures(out, pairs, drawn, tallies, args.duration)
    factor_values = cb.factor_table(drawn)
    figure = cr.plot_factors(tallies, factor_values, out / 'combined_factors.png')
    where = 'Dask' if args.dask else f'{args.workers} worker(s)'
    report = header + (f'{len(runs)} runs ({len(pairs)} pairs x {args.combined} scenarios) in '
                       f'{wall:.0f} s wall on {where}.\n\n')
    report += cr.markdown_report(tallies, table, failures, args.combined, args.seed,
                                 args.duration, ranges, paired)
    report += f'\n![failure rate by factor]({Path(figure).name})\n'
    raw = {'pairs': [list(p) for p in pairs], 'n': args.combined, 'seed': args.seed,
           'duration_s': args.duration, 'wall_s': wall, 'ranges': table.to_dict(),
           'ranges_file': None if args.ranges is None else str(args.ranges),
           'scores': {cr.pair_name(p): {k: v for k, v in t.items() if k != 'kinds'}
                      for p, t in tallies.items()},
           'paired': paired,
           'factors': factor_values, 'failures': failures,
           'runs': [{'swingup': r.swingup, 'stabilizer': r.stabilizer,
                     'index': i % args.combined, 'kind': cb.failure_kind(res),
                     'scenario': r.scenario.to_dict(), **res}
                    for i, (r, res) in enumerate(zip(runs, results))]}
    (out / 'combined.md').write_text(report)
    (out / 'combined.json').write_text(json.dumps(raw, separators=(',', ':')))
    return {'report': report, 'results': raw, 'dir': str(out)}
