"""``cartpole analyze BAG [BAG ...]``: the run summary (and plots) of recorded bags."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .. import boundary
from ..boundary import InputError
from ..options import (add_number_argument, add_output_arguments, add_plant_params_argument,
                       nominal_parameters, print_json, print_summary)

ANIMATION_SUFFIXES = ('.gif', '.mp4')


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

    from cartpole_analysis.analysis.animation import series_from_analysis
    from cartpole_analysis.analysis.animation import write_animation as render

    info = render(series_from_analysis(analysis), args.animate,
                  RigGeometry.from_parameters(nominal_parameters(args)), fps=args.fps,
                  speed=args.speed, width=args.width)
    return {'path': str(info.path), 'frames': info.frames, 'duration_s': info.duration_s,
            'render_s': info.render_s, 'size_bytes': info.size_bytes,
            'size_px': [info.width, info.height]}


def write_figures(analyses, directory: Path) -> list[Path]:
    """Per-run figures and, for several runs, the overlay; returns the paths."""
    from cartpole_analysis.analysis.plots import plot_overlay, run_title, write_plots

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
    from cartpole_analysis.analysis.timeline import names_that_ran
    spans = analysis.summary.get('controllers') or []
    out = {}
    for kind in ('swingup', 'stabilizer'):
        ran = ' -> '.join(names_that_ran(spans, kind)) or analysis.controllers.get(kind)
        if ran:
            out[kind] = ran
    return out


def checked_bag(bag: Path) -> Path:
    """``bag`` if it is a whole bag directory; InputError with the one "damaged" line if not
    (the same check as ``cartpole bag info``)."""
    from cartpole_analysis.bags.check import damage, damaged_line

    if not bag.exists():
        raise InputError(f'{bag}: no such bag (not a rosbag2 bag)')
    if bag.is_file():
        if bag.name == 'metadata.yaml' or bag.suffix == '.mcap':
            bag = bag.parent
        else:
            raise InputError(f'{bag}: is a file, a bag directory is needed')
    problem = damage(bag)
    if problem:
        raise InputError(damaged_line(bag, problem))
    return bag


def check(args: argparse.Namespace):
    """Every input, checked before any bag is analysed (InputError naming it): the nominal
    parameters and the bags."""
    params = nominal_parameters(args)
    if args.x_ref is not None:
        boundary.number('--x-ref', args.x_ref, 0.0, params.travel, unit='m')
    # the animation's options, checked with or without --animate (a bad value is never ignored)
    # at least 0.1 (tenfold slow motion): a slower one makes a video of hours
    boundary.number('--speed', args.speed, 0.1, 1000.0)
    boundary.number('--fps', args.fps, 0.0, 100.0, low_open=True)
    boundary.number('--width', args.width, 120, 3840)
    if args.animate is not None:
        if len(args.bags) != 1:
            raise InputError('--animate takes one bag')
        args.animate = boundary.output_file(args.animate, '--animate', ANIMATION_SUFFIXES)
        if args.animate.suffix.lower() == '.mp4':
            import shutil
            if shutil.which('ffmpeg') is None:
                raise InputError('--animate: an MP4 needs ffmpeg on the PATH (not found); '
                                 'write a .gif instead')
    if args.plots is not None:
        boundary.output_directory(args.plots, '--plots')
    return params, [checked_bag(bag) for bag in args.bags]


def main(args: argparse.Namespace) -> int:
    from cartpole_analysis.analysis.analyze import analyze_bag, comparison_table
    from cartpole_analysis.bags.check import damaged_line

    params, bags = check(args)
    analyses = []
    for given, bag in zip(args.bags, bags):
        try:
            analyses.append(analyze_bag(bag, x_ref=args.x_ref, params=params))
        except (OSError, ValueError, KeyError) as error:
            raise InputError(f'{given}: {error}') from None
        except Exception as error:  # rosbags' own errors: a bag damaged inside its records
            raise InputError(damaged_line(given, f'cannot be read ({type(error).__name__}: '
                                                 f'{error})')) from None
    try:
        plots = write_figures(analyses, args.plots) if args.plots else []
    except OSError as error:
        print(f'cartpole analyze: --plots {args.plots}: not written: {error}', file=sys.stderr)
        return 1
    animation = None
    if args.animate is not None:
        try:
            animation = write_animation(analyses[0], args)
        except ValueError as error:  # e.g. a run of fewer than two samples
            raise InputError(f'--animate: {error}') from None
        except (RuntimeError, OSError) as error:
            print(f'cartpole analyze: --animate: not written: {error}', file=sys.stderr)
            return 1
    if args.json:
        runs = [dict(a.summary, bag=str(a.path), source=a.source, **controllers_that_ran(a))
                for a in analyses]
        out = dict(runs[0]) if len(runs) == 1 else {'runs': runs}
        out['plots'] = [str(p) for p in plots]
        if animation is not None:
            out['animation'] = animation
        print_json(out)
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
