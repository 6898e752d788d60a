"""``cartpole analyze BAG [BAG ...]``: the run summary (and plots) of recorded bags."""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from ..options import (add_number_argument, add_output_arguments, add_plant_params_argument,
                       nominal_parameters, print_summary)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('bags', nargs='+', type=Path, metavar='BAG',
                        help='rosbag2 bag directories (as written by `cartpole run --record` '
                             'or the recorder node)')
    parser.add_argument('--plots', type=Path, default=None, metavar='DIR',
                        help='write PNG figures into DIR: <run>_timeseries.png (Figure 10.1 '
                             'layout), <run>_phase.png; with several bags also comparison.png')
    parser.add_argument('--x-ref', type=float, default=None, metavar='M',
                        help="cart reference x* [m] (default: the bag's x_ref, else mid-travel)")
    add_plant_params_argument(parser, 'nominal plant parameters (travel, l, g, E*)')
    a = parser.add_argument_group('animation (one bag)')
    a.add_argument('--animate', type=Path, default=None, metavar='FILE',
                   help='write the run as an animation: FILE.gif (Pillow) or FILE.mp4 (needs '
                        'ffmpeg); rail, cart, pendulum, tip trace, time, mode, catch')
    a.add_argument('--speed', type=float, default=1.0, metavar='F',
                   help='with --animate: run seconds per second of animation (default 1: real '
                        'speed)')
    add_number_argument(a, '--fps', 25.0, 'with --animate: frames per second of the animation',
                        metavar='N')
    add_number_argument(a, '--width', 480, 'with --animate: frame width in pixels', metavar='PX')
    add_output_arguments(parser)


def write_animation(analysis, args: argparse.Namespace) -> dict:
    """``--animate``: the animation of one analysed bag; returns what was written."""
    from cartpole_sim.geometry import RigGeometry

    from ..analysis.animation import series_from_analysis
    from ..analysis.animation import write_animation as render

    info = render(series_from_analysis(analysis), args.animate,
                  RigGeometry.from_parameters(nominal_parameters(args)), fps=args.fps,
                  speed=args.speed, width=args.width)
    return {'path': str(info.path), 'frames': info.frames, 'duration_s': info.duration_s,
            'render_s': info.render_s, 'size_bytes': info.size_bytes,
            'size_px': [info.width, info.height]}


def write_figures(analyses, directory: Path) -> list[Path]:
    """Per-run figures and, for several runs, the overlay; returns the paths."""
    from ..analysis.plots import plot_overlay, run_title, write_plots

    paths: list[Path] = []
    stems: set[str] = set()
    for i, analysis in enumerate(analyses):
        stem = analysis.series.label or f'run{i + 1}'
        if stem in stems:
            stem = f'{stem}_{i + 1}'
        stems.add(stem)
        title = f'{stem}: {run_title(analysis.series.controllers)}'.rstrip(': ')
        paths += write_plots(analysis.series, directory, stem, title=title)
    if len(analyses) > 1:
        paths.append(plot_overlay([a.series for a in analyses], directory / 'comparison.png'))
    return paths


def controllers_that_ran(analysis) -> dict[str, str]:
    """``swingup`` / ``stabilizer``: every one that ran, in order (``lqg -> smc``)."""
    from ..analysis.timeline import names_that_ran
    spans = analysis.summary.get('controllers') or []
    out = {}
    for kind in ('swingup', 'stabilizer'):
        ran = ' -> '.join(names_that_ran(spans, kind)) or analysis.controllers.get(kind)
        if ran:
            out[kind] = ran
    return out


def main(args: argparse.Namespace) -> int:
    from ..analysis.analyze import analyze_bag, comparison_table

    params = nominal_parameters(args)
    if args.animate is not None and len(args.bags) != 1:
        print('cartpole analyze: --animate takes one bag', file=sys.stderr)
        return 2
    if not (args.speed > 0 and args.fps > 0):
        print(f'cartpole analyze: --speed and --fps must be > 0, got {args.speed:g}, '
              f'{args.fps:g}', file=sys.stderr)
        return 2
    analyses = []
    for bag in args.bags:
        try:
            analyses.append(analyze_bag(bag, x_ref=args.x_ref, params=params))
        except (OSError, ValueError, KeyError) as error:
            print(f'cartpole analyze: {bag}: {error}', file=sys.stderr)
            return 2
    plots = write_figures(analyses, args.plots) if args.plots else []
    animation = None
    if args.animate is not None:
        try:
            animation = write_animation(analyses[0], args)
        except (ValueError, RuntimeError, OSError) as error:
            print(f'cartpole analyze: --animate: {error}', file=sys.stderr)
            return 2
    if args.json:
        runs = [dict(a.summary, bag=str(a.path), source=a.source, **controllers_that_ran(a))
                for a in analyses]
        out = dict(runs[0]) if len(runs) == 1 else {'runs': runs}
        out['plots'] = [str(p) for p in plots]
        if animation is not None:
            out['animation'] = animation
        print(json.dumps(out))
        return 0
    for a in analyses:
        controllers = ', '.join(f'{k} {v}' for k, v in controllers_that_ran(a).items())
        print(f'== {a.path} ({a.source}{"; " + controllers if controllers else ""})')
        print_summary(a.summary, as_json=False)
        print()
    if len(analyses) > 1:
        print('== comparison')
        print('\n'.join(comparison_table(analyses)))
        print()
    for p in plots:
        print(f'plot: {p}')
    if animation is not None:
        print(f"animation: {animation['path']} ({animation['frames']} frames, "
              f"{animation['duration_s']:.2f} s, {animation['size_bytes'] / 1e6:.2f} MB, "
              f"rendered in {animation['render_s']:.1f} s)")
    return 0
