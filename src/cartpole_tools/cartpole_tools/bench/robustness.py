"""The sim-to-real gap, scored: ``cartpole bench robustness``.

After the robustness leaderboard of the DFKI double_pendulum benchmark: each
category of uncertainty is swept over levels from nominal outwards, several
seeds a level; a run succeeds by the strict rule (:func:`succeeded`): caught,
no fall after the catch, no controller-manager fault (the rail guard's: it
leaves the pendulum to fall), no impact on a stop, and |theta| < 2 deg and
|x - x*| <= 10 cm over the last 10 s; a level *counts* when more than half
of its seeds succeed; a category's score is the fraction of its levels that
count, the overall score the mean over the categories.

A category holds one or more *sweeps* (one quantity in one direction, e.g.
"cart mass -"), each starting at the nominal level; its score counts every
(sweep, level) cell. Every run starts from the default start (left stop,
hanging at rest) with measurement noise on and one disturbance changed
(:data:`SWEEPS`). Each run is an offline closed loop, a pure function of its
:class:`RobustnessRun`, so the grid gives the same results serially, on a
process pool or on Dask (:func:`.sweep.run_parallel`); identical runs (every
sweep's nominal level) are run once.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np

from cartpole_core.model import CartPoleParameters
from cartpole_sim.plant import Push, Scenario

from .sweep import run_parallel

NOMINAL = CartPoleParameters()
PUSH_TIME = 12.0
"""[s] Pushes come at 12 s: after every pair's catch (about 3 s), 8 s before the
last-10-s window that decides success."""
CART_PUSH_WIDTH = 0.1
"""[s] Width of the pushes on the cart (1 N s = 10 N for 0.1 s)."""
PENDULUM_PUSH_WIDTH = 0.05
"""[s] Width of the pushes on the pendulum."""
JITTER_PER_DELAY = 0.2
"""The delay sweep adds jitter U[0, 0.2 x delay] (10 ms of delay with 2 ms of jitter)."""
DEFAULT_SEEDS = 3
DEFAULT_DURATION = 30.0


@dataclass(frozen=True)
class Sweep:
    """One quantity swept in one direction, from nominal (``levels[0]``) outwards."""

    category: str
    name: str
    unit: str
    levels: tuple[float, ...]
    changes: Callable[[float], dict[str, Any]]
    """The Scenario fields of a level (over the nominal scenario)."""
    fmt: str = '{:g}'
    after_catch: bool = False
    """Pushes: the pendulum must also not fall after the catch."""
    note: str = ''
    """What else the level sets, for the report."""

    def label(self, level: float) -> str:
        """The level in physical units, e.g. ``12.5 ms`` (factors as ``x1.2``)."""
        text = self.fmt.format(level)
        if self.unit == 'x':
            return 'x' + text
        return f'{text} {self.unit}' if self.unit else text

    @property
    def quantity(self) -> str:
        """The name without its direction: ``cart mass`` for ``cart mass -`` and ``+``."""
        return self.name[:-2] if self.name.endswith((' -', ' +')) else self.name


def _scale(*names: str) -> Callable[[float], dict[str, Any]]:
    return lambda factor: {'parameter_scales': tuple((n, factor) for n in names)}


def _noise(std_pendulum_mrad: float) -> dict[str, Any]:
    k = std_pendulum_mrad / (1e3 * Scenario.noise_std_pendulum)
    return {'noise_std_pendulum': 1e-3 * std_pendulum_mrad,
            'noise_std_cart': k * Scenario.noise_std_cart}


def _delay(ms: float) -> dict[str, Any]:
    return {'delay': ms * 1e-3, 'jitter': JITTER_PER_DELAY * ms * 1e-3}


def _offset(mrad: float) -> dict[str, Any]:
    # Appendix H, as bench control: the encoders are reset with the pendulum this far off
    # hanging (it starts there, at rest; the measured angle is biased by minus as much).
    return {'theta0': math.pi + mrad * 1e-3, 'encoder_offset': mrad * 1e-3}


def _push(target: str, width: float) -> Callable[[float], dict[str, Any]]:
    return lambda impulse: ({'pushes': (Push(PUSH_TIME, target, impulse / width, width),)}
                            if impulse else {})


def _times(unit: float, *factors: float) -> tuple[float, ...]:
    """Levels ``unit * factor`` (rounded to 12 digits, so 0.3345 m x 1.1 reads 367.95 mm)."""
    return tuple(round(unit * f, 12) for f in factors)


M_C, M_P, L = NOMINAL.m_c, NOMINAL.m_p, NOMINAL.l

SWEEPS: tuple[Sweep, ...] = (
    Sweep('model', 'cart mass -', 'kg',
          _times(M_C, 1, .95, .9, .85, .8, .75, .7, .65, .6, .5), lambda kg: {'cart_mass': kg},
          '{:.3g}'),
    Sweep('model', 'cart mass +', 'kg',
          _times(M_C, 1, 1.2, 1.4, 1.6, 1.8, 2, 2.25, 2.5, 3, 4), lambda kg: {'cart_mass': kg},
          '{:.3g}'),
    Sweep('model', 'tip mass -', 'g', _times(1e3 * M_P, 1, .9, .8, .7, .6, .5, .4, .3, .2, .1),
          lambda g: {'tip_mass': g * 1e-3}, '{:.0f}'),
    Sweep('model', 'tip mass +', 'g', _times(1e3 * M_P, 1, 1.5, 2, 3, 4, 6, 8, 10, 15, 20),
          lambda g: {'tip_mass': g * 1e-3}, '{:.0f}'),
    Sweep('model', 'pendulum length -', 'mm',
          _times(1e3 * L, 1, .97, .94, .91, .88, .85, .8, .75, .7, .6),
          lambda mm: _scale('l')(mm * 1e-3 / L), '{:.4g}'),
    Sweep('model', 'pendulum length +', 'mm',
          _times(1e3 * L, 1, 1.05, 1.1, 1.15, 1.2, 1.3, 1.4, 1.5, 1.75, 2),
          lambda mm: _scale('l')(mm * 1e-3 / L), '{:.4g}'),
    Sweep('model', 'cart friction -', 'x', _times(1, 1, .9, .8, .7, .6, .5, .4, .3, .2, .1, 0),
          _scale('c_c_right', 'c_c_left', 'v_c'), note='c_c,R 3.4 N and c_c,L 2.45 N scaled'),
    Sweep('model', 'cart friction +', 'x', _times(1, 1, 1.1, 1.2, 1.3, 1.4, 1.5, 1.6, 1.8, 2, 2.5),
          _scale('c_c_right', 'c_c_left', 'v_c'), note='c_c,R 3.4 N and c_c,L 2.45 N scaled'),
    Sweep('model', 'pendulum Coulomb friction +', 'x',
          _times(1, 1, 1.5, 2, 2.5, 3, 4, 5, 7, 10, 20), _scale('c_p'), note='c_p 3.8 mN m scaled'),
    Sweep('model', 'pendulum viscous friction +', 'x',
          _times(1, 1, 2, 3, 5, 7, 10, 15, 20, 30, 50), _scale('v_p'),
          note='v_p 0.67 mN m s/rad scaled'),
    Sweep('measurement noise', 'measurement noise', 'mrad',
          _times(1, 1.5, 3, 4.5, 6, 9, 12, 15, 22.5, 30, 45), _noise,
          note='std of the pendulum angle noise; the cart position noise scales alike '
               '(0.1 mm at the nominal 1.5 mrad)'),
    Sweep('force noise', 'force noise', 'N', _times(1, 0, 1, 2, 4, 6, 8, 10, 12, 15, 20),
          lambda n: {'force_noise': n}, note='std, a new draw each 5 ms sample'),
    Sweep('actuator gain', 'actuator gain -', 'x',
          _times(1, 1, .95, .9, .85, .8, .75, .7, .6, .5, .3), lambda g: {'actuator_gain': g}),
    Sweep('actuator gain', 'actuator gain +', 'x',
          _times(1, 1, 1.1, 1.2, 1.3, 1.4, 1.5, 1.6, 1.8, 2, 3), lambda g: {'actuator_gain': g}),
    Sweep('actuator lag', 'actuator lag', 'ms',
          _times(1, 0, 5, 10, 15, 20, 30, 40, 60, 80, 100), lambda ms: {'actuator_tau': ms * 1e-3},
          note='time constant of an extra first-order lag ahead of the current loop (4.4)'),
    Sweep('delay', 'delay', 'ms',
          _times(1, 0, 2.5, 5, 7.5, 10, 12.5, 15, 20, 25, 30, 35, 40), _delay,
          note='plus a jitter uniform in [0, 20 % of the delay] per sample'),
    Sweep('lost samples', 'lost samples', '%',
          _times(1, 0, 5, 10, 15, 20, 30, 40, 50, 60, 70, 80, 90),
          lambda pct: {'drop': pct / 100.0}),
    Sweep('encoder offset', 'encoder offset -', 'mrad',
          _times(-1, 0, 2.5, 5, 7.5, 10, 15, 20, 30, 50, 100), _offset),
    Sweep('encoder offset', 'encoder offset +', 'mrad',
          _times(1, 0, 2.5, 5, 7.5, 10, 15, 20, 30, 50, 100), _offset),
    Sweep('push', 'cart push', 'N s',
          _times(1, 0, 1, 2, 3, 4, 5, 6, 8, 10, 12.5), _push('cart', CART_PUSH_WIDTH),
          after_catch=True, note=f'impulse of a {CART_PUSH_WIDTH:g} s push at {PUSH_TIME:g} s, '
                                 'to the right, after the catch'),
    Sweep('push', 'pendulum push', 'N m s',
          _times(1, 0, .01, .02, .03, .04, .05, .06, .08, .1, .15),
          _push('pendulum', PENDULUM_PUSH_WIDTH), after_catch=True,
          note=f'impulse of a {PENDULUM_PUSH_WIDTH:g} s torque at {PUSH_TIME:g} s, towards '
               'increasing theta, after the catch'),
)
"""The default grid: every category of the robustness benchmark (docs/benchmarks.md), each sweep from nominal outwards."""

CATEGORIES = tuple(dict.fromkeys(s.category for s in SWEEPS))


def sweeps_of(categories: Sequence[str] | None = None,
              sweeps: Sequence[Sweep] = SWEEPS) -> list[Sweep]:
    """The sweeps of the named categories (all by default); ValueError naming unknown ones."""
    if not categories:
        return list(sweeps)
    known = list(dict.fromkeys(s.category for s in sweeps))
    unknown = [c for c in categories if c not in known]
    if unknown:
        raise ValueError(f'unknown categories {unknown}; known: {known}')
    return [s for s in sweeps if s.category in categories]


@dataclass(frozen=True)
class RobustnessRun:
    """One offline closed-loop run of the grid (picklable: what a worker gets)."""

    swingup: str
    stabilizer: str
    scenario: Scenario
    duration: float = DEFAULT_DURATION


@dataclass(frozen=True)
class Cell:
    """Where a run belongs in the grid: pair, sweep, level, seed."""

    swingup: str
    stabilizer: str
    sweep: str
    level_index: int
    seed: int


def scenario_of(sweep: Sweep, level: float, seed: int) -> Scenario:
    """The scenario of one level of a sweep: noise on, the level's changes, the seed.

    The first level is nominal: the nominal scenario itself (so every
    sweep's nominal runs are the same runs, run once).
    """
    changes = {} if level == sweep.levels[0] else sweep.changes(level)
    return Scenario(noise=True, seed=seed, **changes)


def make_grid(pairs: Sequence[tuple[str, str]], sweeps: Sequence[Sweep], seeds: int,
              duration: float = DEFAULT_DURATION) -> tuple[list[Cell], list[RobustnessRun]]:
    """Every cell of the grid and its run (the same run object for identical scenarios)."""
    cells, runs = [], []
    for swingup, stabilizer in pairs:
        for sweep in sweeps:
            for i, level in enumerate(sweep.levels):
                for seed in range(seeds):
                    cells.append(Cell(swingup, stabilizer, sweep.name, i, seed))
                    runs.append(RobustnessRun(swingup, stabilizer, scenario_of(sweep, level, seed),
                                              duration))
    return cells, runs


def run_one(run: RobustnessRun) -> dict[str, Any]:
    """One offline run: its run summary (``falls_after_catch`` and the impacts included) and
    the manager's faults.

    The run stops early once it cannot succeed (an impact on a stop, a fall
    after the catch, or a manager fault such as the rail guard's: the
    pendulum is left to fall), ``stopped_at_s`` in the summary.
    """
    from cartpole_bringup.offline.closed_loop import run_closed_loop

    result = run_closed_loop(NOMINAL, run.scenario, duration=run.duration,
                             manager_parameters={'swingup': run.swingup,
                                                 'stabilizer': run.stabilizer},
                             stop_on_failure=True)
    faults = sorted({e for _, text in result.events for e in text.split(';')
                     if e.startswith('fault:')})
    return {**result.summary, 'faults': faults}


def run_grid(runs: Sequence[RobustnessRun], *, workers: int = 1, dask_address: str | None = None,
             progress: Callable[[int, int], None] | None = None) -> list[dict[str, Any]]:
    """The result of every run, in order; identical runs are computed once."""
    unique = list(dict.fromkeys(runs))
    done = run_parallel(run_one, unique, workers=workers, dask_address=dask_address,
                        progress=progress)
    by_run = dict(zip(unique, done))
    return [by_run[r] for r in runs]


def strict_success(summary: dict[str, Any]) -> bool:
    """The strict rule: caught, no fall after the catch, no manager fault, no impact on a
    stop, and within 2 deg and 10 cm over the last 10 s.

    The offline run summary's ``success`` already needs all of it; the
    manager's fault events, the falls and the impacts are checked again so
    that a summary without the strict keys (a bag's) cannot pass for strict.
    """
    return (bool(summary['success']) and not summary.get('faults')
            and summary.get('falls_after_catch') == 0 and not summary.get('impacts'))


def succeeded(sweep: Sweep, summary: dict[str, Any]) -> bool:
    """:func:`strict_success`, the same for every sweep (``sweep`` kept for the callers)."""
    return strict_success(summary)


def run_by_majority(cells: Sequence[Cell], runs: Sequence[RobustnessRun], sweeps: Sequence[Sweep],
                    seeds: int, *, workers: int = 1, dask_address: str | None = None,
                    progress: Callable[[int, int], None] | None = None
                    ) -> tuple[list[Cell], list[dict[str, Any]]]:
    """Run the grid's seeds only as far as each level's majority needs them.

    A level counts when more than half of its ``seeds`` succeed. The first
    ``seeds // 2 + 1`` seeds of every level run first; a level they decide
    (all succeed, or too few can still succeed) is done, and only the
    undecided levels run their remaining seeds. Every level's count is the
    one all seeds would give, and its success rate over the seeds run stays
    on the same side of one half; about a third of the runs are saved.
    Returns the cells that ran and their results, in grid order.
    """
    by_name = {s.name: s for s in sweeps}
    first = seeds // 2 + 1
    phase1 = [i for i, c in enumerate(cells) if c.seed < first]
    rest = [i for i, c in enumerate(cells) if c.seed >= first]
    total = len(set(runs[i] for i in phase1)) + len(set(runs[i] for i in rest))
    results: dict[int, dict[str, Any]] = {}

    def _phase(indices: list[int], offset: int) -> None:
        done = run_grid([runs[i] for i in indices], workers=workers, dask_address=dask_address,
                        progress=(lambda d, n: progress(offset + d, total)) if progress else None)
        results.update(zip(indices, done))

    _phase(phase1, 0)
    wins: dict[tuple[str, str, str, int], list[bool]] = {}
    for i in phase1:
        c = cells[i]
        wins.setdefault((c.swingup, c.stabilizer, c.sweep, c.level_index), []).append(
            succeeded(by_name[c.sweep], results[i]))

    def _undecided(c: Cell) -> bool:
        ok = wins[(c.swingup, c.stabilizer, c.sweep, c.level_index)]
        successes, remaining = sum(ok), seeds - len(ok)
        return not (successes > seeds / 2 or successes + remaining <= seeds / 2)

    later = [i for i in rest if _undecided(cells[i])]
    total = len(set(runs[i] for i in phase1)) + len(set(runs[i] for i in later))
    _phase(later, len(set(runs[i] for i in phase1)))
    order = sorted(results)
    return [cells[i] for i in order], [results[i] for i in order]


def score(cells: Sequence[Cell], successes: Sequence[bool],
          sweeps: Sequence[Sweep]) -> dict[tuple[str, str], dict[str, Any]]:
    """The robustness score of each pair from the success of each cell's run.

    Returns, per ``(swingup, stabilizer)``: ``sweeps`` (per sweep: the success
    rate of each level, which levels count, ``survived``: the index of the
    last level of the unbroken run of counting levels from nominal, or None
    if nominal does not count), ``categories`` (per category: ``score`` =
    counting cells / cells, and its sweeps' names) and ``overall`` (the mean
    of the category scores).
    """
    by_name = {s.name: s for s in sweeps}
    tally: dict[tuple[str, str], dict[str, dict[int, list[bool]]]] = {}
    for cell, ok in zip(cells, successes):
        pair = (cell.swingup, cell.stabilizer)
        tally.setdefault(pair, {}).setdefault(cell.sweep, {}).setdefault(
            cell.level_index, []).append(bool(ok))
    out = {}
    for pair, per_sweep in tally.items():
        sweep_rows, categories = {}, {}
        for name, levels in per_sweep.items():
            sweep = by_name[name]
            rates = [float(np.mean(levels[i])) for i in sorted(levels)]
            counts = [rate > 0.5 for rate in rates]
            survived = None
            for i, c in enumerate(counts):
                if not c:
                    break
                survived = i
            sweep_rows[name] = {'category': sweep.category, 'rates': rates, 'counts': counts,
                                'survived': survived}
            cat = categories.setdefault(sweep.category, {'cells': 0, 'counted': 0, 'sweeps': []})
            cat['cells'] += len(counts)
            cat['counted'] += sum(counts)
            cat['sweeps'].append(name)
        for cat in categories.values():
            cat['score'] = cat['counted'] / cat['cells']
        overall = float(np.mean([c['score'] for c in categories.values()]))
        out[pair] = {'sweeps': sweep_rows, 'categories': categories, 'overall': overall}
    return out


def default_pairs(stabilizers: Sequence[str], default: tuple[str, str]) -> list[tuple[str, str]]:
    """The default pair, then every stabiliser with ``pendulum_energy`` (no repeats)."""
    pairs = [default] + [('pendulum_energy', s) for s in stabilizers]
    return list(dict.fromkeys(pairs))
