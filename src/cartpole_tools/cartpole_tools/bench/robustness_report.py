"""The report of ``cartpole bench robustness``: score tables, survived levels, heat map, JSON.

Reads what :func:`cartpole_tools.bench.robustness.score` computes; no runs here.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

import numpy as np

from .robustness import Cell, Sweep


def pair_name(pair: tuple[str, str]) -> str:
    return f'{pair[0]} + {pair[1]}'


def survived_ranges(scores: dict[str, Any], sweeps: Sequence[Sweep], category: str) -> list[str]:
    """Per quantity of ``category``, the levels survived from nominal in physical units.

    One-sided sweeps read ``delay 12.5 ms``; a quantity swept both ways reads
    ``cart mass 3.56-9.5 kg`` (lowest and highest level of the unbroken runs
    of counting levels from nominal); ``... fails at nominal`` if nominal
    does not count.
    """
    out: dict[str, dict[str, str | None]] = {}
    units: dict[str, str] = {}
    for sweep in sweeps:
        if sweep.category != category or sweep.name not in scores['sweeps']:
            continue
        i = scores['sweeps'][sweep.name]['survived']
        side = '-' if sweep.name.endswith(' -') else '+'
        out.setdefault(sweep.quantity, {})[side] = None if i is None else sweep.label(
            sweep.levels[i])
        units[sweep.quantity] = sweep.unit
    text = []
    for quantity, sides in out.items():
        if any(v is None for v in sides.values()):
            text.append(f'{quantity}: fails at nominal')
        elif len(sides) == 2:
            low, high = sides['-'], sides['+']
            unit = units[quantity]
            if unit and unit != 'x' and low.endswith(' ' + unit):
                low = low[:-len(unit) - 1]
            text.append(f'{quantity} {low} to {high}')
        else:
            text.append(f'{quantity} {next(iter(sides.values()))}')
    return text


def markdown_report(scores: dict[tuple[str, str], dict[str, Any]], sweeps: Sequence[Sweep],
                    seeds: int) -> str:
    """The overall table (a row per pair), then per pair: category, score, largest level survived."""
    categories = list(dict.fromkeys(s.category for s in sweeps))
    lines = ['### Scores\n',
             f'A level counts when more than half of its {seeds} seeds succeed (the strict '
             'rule: caught, no fall after the catch, no controller-manager fault, no impact on '
             'a stop, within 2 deg and 10 cm over the last 10 s); category score = counting '
             'levels / levels; overall = mean of the categories.\n',
             '| pair | ' + ' | '.join(categories) + ' | overall |',
             '|' + '---|' * (len(categories) + 2)]
    for pair, sc in scores.items():
        cells = [f"{sc['categories'][c]['score']:.2f}" if c in sc['categories'] else '-'
                 for c in categories]
        lines.append(f'| {pair_name(pair)} | ' + ' | '.join(cells) + f" | **{sc['overall']:.2f}** |")
    lines += ['', 'The sweeps, each from nominal outwards (heat map rows):', '']
    for c in categories:
        for s in sweeps:
            if s.category == c:
                levels = ', '.join(s.fmt.format(v) for v in s.levels)
                note = f' ({s.note})' if s.note else ''
                lines.append(f'- {c}: {s.name} [{s.unit}]{note}: {levels}')
    for pair, sc in scores.items():
        lines += ['', f'### {pair_name(pair)}: overall {sc["overall"]:.2f}\n',
                  '| category | score | counting / levels | largest level survived (from nominal) |',
                  '|---|---|---|---|']
        for c in categories:
            if c not in sc['categories']:
                continue
            cat = sc['categories'][c]
            lines.append(f"| {c} | {cat['score']:.2f} | {cat['counted']} / {cat['cells']} | "
                         + '; '.join(survived_ranges(sc, sweeps, c)) + ' |')
    return '\n'.join(lines) + '\n'


def results_json(cells: Sequence[Cell], results: Sequence[dict[str, Any]],
                 successes: Sequence[bool], sweeps: Sequence[Sweep],
                 scores: dict[tuple[str, str], dict[str, Any]], meta: dict[str, Any]) -> dict:
    """The raw JSON: the grid, every run (cell, level, success, summary) and the scores."""
    by_name = {s.name: s for s in sweeps}
    runs = []
    for cell, result, ok in zip(cells, results, successes):
        sweep = by_name[cell.sweep]
        level = sweep.levels[cell.level_index]
        runs.append({'swingup': cell.swingup, 'stabilizer': cell.stabilizer,
                     'category': sweep.category, 'sweep': sweep.name,
                     'level_index': cell.level_index, 'level': level,
                     'level_label': sweep.label(level), 'seed': cell.seed, 'counts_as_success': ok,
                     **result})
    return {**meta,
            'grid': [{'category': s.category, 'sweep': s.name, 'unit': s.unit,
                      'levels': list(s.levels), 'after_catch': s.after_catch} for s in sweeps],
            'scores': {pair_name(p): sc for p, sc in scores.items()},
            'runs': runs}


def _row_label(sweep: Sweep) -> str:
    return f'{sweep.name} [{sweep.unit}]' if sweep.unit else sweep.name


def plot_heatmap(scores: dict[tuple[str, str], dict[str, Any]], sweeps: Sequence[Sweep],
                 path: str | Path) -> str:
    """Success rate per sweep (rows) and level (columns, from nominal outwards), a panel a pair.

    Each cell is labelled with its level (the unit is in the row's label);
    a level that counts (more than half its seeds succeed) is outlined.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.patches import Rectangle

    pairs = list(scores)
    rows = [s for s in sweeps if any(s.name in scores[p]['sweeps'] for p in pairs)]
    width = max(len(s.levels) for s in rows)
    fig = Figure(figsize=(2.6 + 0.4 * width * len(pairs), 0.3 * len(rows) + 1.4))
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, len(pairs), squeeze=False, sharey=True)[0]
    image = None
    for ax, pair in zip(axes, pairs):
        grid = np.full((len(rows), width), np.nan)
        for r, sweep in enumerate(rows):
            row = scores[pair]['sweeps'].get(sweep.name)
            if row is None:
                continue
            grid[r, :len(row['rates'])] = row['rates']
            for j, (level, counts) in enumerate(zip(sweep.levels, row['counts'])):
                ax.text(j, r, sweep.fmt.format(level), ha='center', va='center', fontsize=5)
                if counts:
                    ax.add_patch(Rectangle((j - 0.5, r - 0.5), 1, 1, fill=False, lw=0.6,
                                           ec='black'))
        image = ax.imshow(grid, vmin=0.0, vmax=1.0, cmap='RdYlGn', aspect='auto')
        ax.set_xticks(range(width), [str(j) for j in range(width)], fontsize=6)
        ax.set_xlabel('level (0 = nominal)', fontsize=7)
        ax.set_title(f'{pair_name(pair)}: overall {scores[pair]["overall"]:.2f}', fontsize=8)
    axes[0].set_yticks(range(len(rows)), [_row_label(s) for s in rows], fontsize=6)
    fig.colorbar(image, ax=list(axes), fraction=0.02, pad=0.01, label='success rate')
    fig.suptitle('Robustness: success rate per level (outlined: the level counts)', fontsize=9)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=130, bbox_inches='tight')
    return str(path)
