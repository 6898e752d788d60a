"""The report of ``cartpole bench robustness --combined N``: rates with their intervals,
failures by kind and by factor (a plot), and a replayable scenario file for every failure.

Reads what :mod:`.combined` computes; no runs here.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

import numpy as np

from cartpole_sim.scenario import Scenario
from cartpole_sim.scenario_options import save_scenario
from cartpole_sim.scenario_ranges import RangeTable

from .combined import KINDS, SIGNIFICANCE

BINS = 5
"""Equal-width bins of each factor in the by-factor plot."""
PUSHES = ('cart_push', 'pendulum_push')
"""Factors binned by |impulse| over the runs pushed that way only (the others have none)."""


def pair_name(pair: tuple[str, str]) -> str:
    return f'{pair[0]} + {pair[1]}'


def _file_name(pair: tuple[str, str], index: int) -> str:
    return f'{pair[0]}-{pair[1]}-{index:04d}.json'


def write_failures(out: Path, pairs: Sequence[tuple[str, str]], drawn: Sequence[Scenario],
                   tallies: dict[tuple[str, str], dict[str, Any]],
                   duration: float) -> list[dict[str, Any]]:
    """Write ``out/failures/<swingup>-<stabilizer>-<index>.json`` for every failed run.

    Returns one row per failure: pair, index, kind, file and the command that
    replays it exactly (``cartpole offline --scenario FILE ...``).
    """
    rows = []
    folder = Path(out) / 'failures'
    for pair in pairs:
        for index, kind in enumerate(tallies[pair]['kinds']):
            if kind is None:
                continue
            folder.mkdir(parents=True, exist_ok=True)
            path = save_scenario(drawn[index], folder / _file_name(pair, index))
            rows.append({'swingup': pair[0], 'stabilizer': pair[1], 'index': index,
                         'kind': kind, 'file': str(path),
                         'replay': f'cartpole offline --scenario {path} --swingup {pair[0]} '
                                   f'--stabilizer {pair[1]} --duration {duration!r} '
                                   '--stop-on-failure'})
    return rows


def markdown_report(tallies: dict[tuple[str, str], dict[str, Any]], table: RangeTable,
                    failures: Sequence[dict[str, Any]], n: int, seed: int,
                    duration: float, ranges: str,
                    paired: Sequence[dict[str, Any]] = ()) -> str:
    """The success table (rate, Wilson 95 % interval, failures by kind), the paired
    comparison of every two pairs (:func:`.combined.paired_comparison`), the range table
    and the failures with their replay commands."""
    lines = ['### Combined disturbances: strict success\n',
             f'{n} scenarios drawn from {ranges} with --seed {seed} (every factor at once, '
             f'the same scenarios for every pair), {duration:g} s each. A run succeeds when the '
             'pendulum is caught and never falls after the catch, the controller manager never '
             'faults, the cart never hits a stop (an impact: arriving faster than 20 mm/s or '
             'pressed in by more than 5 N of our force) and the last 10 s are within 2 deg and '
             '10 cm.\n',
             '| pair | success | rate | 95 % interval (Wilson) | ' + ' | '.join(KINDS) + ' |',
             '|' + '---|' * (4 + len(KINDS))]
    for pair, t in tallies.items():
        low, high = t['interval']
        lines.append(f"| {pair_name(pair)} | {t['successes']} / {t['n']} | **{t['rate']:.3f}** "
                     f'| {low:.3f}-{high:.3f} | '
                     + ' | '.join(str(t['failures'][k]) for k in KINDS) + ' |')
    lines += ['', 'Failure kinds: impact (on a stop), fault (controller manager), fall (after '
              'the catch), never caught, off target (caught, no fall, but the last 10 s are '
              'outside 2 deg or 10 cm).', '']
    if paired:
        lines += paired_lines(paired)
    lines += ['### The range table\n',
              '| factor | drawn from |', '|---|---|']
    for name, value in table.to_dict().items():
        text = f'{value[0]:g} to {value[1]:g}' if isinstance(value, list) else f'{value}'
        lines.append(f'| {name} | {text} |')
    if failures:
        lines += ['', f'### Failures ({len(failures)}): each replays exactly\n',
                  '| pair | run | kind | replay |', '|---|---|---|---|']
        for f in failures:
            lines.append(f"| {f['swingup']} + {f['stabilizer']} | {f['index']} | {f['kind']} | "
                         f"`{f['replay']}` |")
    return '\n'.join(lines) + '\n'


def paired_lines(paired: Sequence[dict[str, Any]]) -> list[str]:
    """The paired comparison's table and how to read it."""
    lines = ['### Pair against pair, draw by draw\n',
             'On the same scenarios, what tells two pairs apart is the draws one holds and the '
             'other loses; p is the exact McNemar (sign) test\'s two-sided probability of a '
             'split at least that uneven if both were equally good. A pair is better when p < '
             f'{SIGNIFICANCE:g}.\n',
             '| first | second | first only | second only | both | neither | p | better |',
             '|---|---|---|---|---|---|---|---|']
    for row in paired:
        better = pair_name(tuple(row['better'])) if row['better'] else 'not shown'
        lines.append(f"| {pair_name(tuple(row['first']))} | {pair_name(tuple(row['second']))} "
                     f"| {row['first_only']} | {row['second_only']} | {row['both']} "
                     f"| {row['neither']} | {row['p']:.3g} | {better} |")
    return lines + ['']


def failure_rates(values: Sequence[float], failed: Sequence[bool], push: bool = False
                  ) -> tuple[list[float], list[float], list[int]]:
    """Bin centres, failure rate per bin and runs per bin, :data:`BINS` equal-width bins
    over the drawn values (pushes: |impulse| of the runs pushed that way); empty bins left out."""
    v = np.abs(np.asarray(values, dtype=float)) if push else np.asarray(values, dtype=float)
    f = np.asarray(failed, dtype=bool)
    if push:
        v, f = v[v > 0.0], f[v > 0.0]
    if v.size == 0:
        return [], [], []
    low, high = float(v.min()), float(v.max())
    if high <= low:
        return [low], [float(f.mean())], [int(v.size)]
    edges = np.linspace(low, high, BINS + 1)
    which = np.clip(np.digitize(v, edges[1:-1]), 0, BINS - 1)
    centres, rates, counts = [], [], []
    for b in range(BINS):
        mask = which == b
        if mask.any():
            centres.append(float(0.5 * (edges[b] + edges[b + 1])))
            rates.append(float(f[mask].mean()))
            counts.append(int(mask.sum()))
    return centres, rates, counts


def plot_factors(tallies: dict[tuple[str, str], dict[str, Any]],
                 factor_values: dict[str, list[float]], path: str | Path) -> str:
    """A panel per drawn factor: failure rate per bin of its value, a line per pair."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    names = list(factor_values)
    cols = 4
    rows = -(-len(names) // cols)
    fig = Figure(figsize=(3.2 * cols, 2.4 * rows))
    FigureCanvasAgg(fig)
    axes = fig.subplots(rows, cols, squeeze=False).ravel()
    for ax, name in zip(axes, names):
        for pair, t in tallies.items():
            failed = [k is not None for k in t['kinds']]
            x, y, _ = failure_rates(factor_values[name], failed, push=name in PUSHES)
            ax.plot(x, y, marker='o', ms=3, lw=1, label=pair_name(pair))
        ax.set_ylim(-0.02, 1.02)
        ax.set_title(name + (' |impulse|, pushed runs' if name in PUSHES else ''), fontsize=8)
        ax.tick_params(labelsize=6)
        ax.grid(alpha=0.3)
    for ax in axes[len(names):]:
        ax.set_visible(False)
    axes[0].set_ylabel('failure rate', fontsize=7)
    axes[0].legend(fontsize=5, loc='upper left')
    fig.suptitle('Combined disturbances: failure rate against each drawn factor '
                 f'({BINS} equal-width bins)', fontsize=9)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    return str(path)
