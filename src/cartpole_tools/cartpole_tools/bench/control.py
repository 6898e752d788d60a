"""Controller comparison under uncertainty: every swing-up x stabiliser pair over a scenario grid.

The thesis compared its controllers on one run each (Table 10.2); this sweep
runs many, with robustness scenarios: tip mass -20 %,
-10 %, +10 % (section 10.3), cart and pendulum friction x0.8, x1.2 and x1.5,
the encoders reset with the pendulum 0.01 to 0.1 rad off hanging (Appendix H:
the encoder then reads pi while the pendulum is not at pi; it is released from
there at rest), that offset together with a 20 % lighter tip, measurement
noise on, several seeds. Besides the run summary (with the control effort
``force_rms_n``/``force_p2p_n``) each run reports ``x_err_mean_m``, the mean
|x - x*| over its last 5 s: what is left of an offset once the transients of
the catch are over (the "offset-free" measure).

Each case is one offline closed-loop run (:func:`run_case`), a pure function
of its :class:`BenchCase`, so the sweep gives the same numbers serially, on a
local process pool, or on a Dask cluster.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any, Callable, Iterable, Sequence

import numpy as np

from cartpole_core.model import CartPoleParameters
from cartpole_sim.plant import Scenario

from .sweep import run_parallel

NOMINAL_TIP_MASS = CartPoleParameters().m_p

def _offset(b: float, **more: float) -> dict[str, float]:
    """Encoders zeroed with the pendulum at rest b off hanging (Appendix H)."""
    return {'theta0': math.pi + b, 'encoder_offset': b, **more}


SCENARIOS: dict[str, dict[str, float]] = {
    'nominal': {},
    'mass-20%': {'tip_mass': NOMINAL_TIP_MASS * 0.8},
    'mass-10%': {'tip_mass': NOMINAL_TIP_MASS * 0.9},
    'mass+10%': {'tip_mass': NOMINAL_TIP_MASS * 1.1},
    'friction x0.8': {'friction_scale': 0.8},
    'friction x1.2': {'friction_scale': 1.2},
    'friction x1.5': {'friction_scale': 1.5},
    'offset +0.01': _offset(0.01),
    'offset -0.01': _offset(-0.01),
    'offset +0.02': _offset(0.02),
    'offset -0.02': _offset(-0.02),
    'offset +0.05': _offset(0.05),
    'offset -0.05': _offset(-0.05),
    'offset +0.1': _offset(0.1),
    'offset -0.1': _offset(-0.1),
    'offset +0.05 mass-20%': _offset(0.05, tip_mass=NOMINAL_TIP_MASS * 0.8),
}
"""The scenario grid (docs/benchmarks.md, "Controller comparison"), by name."""

SETTLE_WINDOW_S = 5.0
"""``x_err_mean_m`` is the mean |x - x*| over the last this many seconds."""

THESIS_TABLE_10_2 = {
    'pid': (2.640e-3, 20.99e-6),
    'lqg': (4.120e-3, 14.00e-6),
    'smc': (1.811e-3, 16.29e-6),
}
"""MSE of the cart [m^2] and of the pendulum [rad^2] over the last 10 s on the rig (Table 10.2)."""


@dataclass(frozen=True)
class BenchCase:
    """One run of the sweep."""

    swingup: str
    stabilizer: str
    scenario: str
    seed: int
    duration: float = 30.0
    noise: bool = True

    def make_scenario(self) -> Scenario:
        return Scenario(noise=self.noise, seed=self.seed, **SCENARIOS[self.scenario])


def run_case(case: BenchCase) -> dict[str, Any]:
    """Run one case offline; returns the case, its run summary and the catch time."""
    from cartpole_bringup.offline.closed_loop import run_closed_loop

    run = run_closed_loop(CartPoleParameters(), case.make_scenario(), duration=case.duration,
                          manager_parameters={'swingup': case.swingup,
                                              'stabilizer': case.stabilizer})
    last = run.t >= run.t[-1] - SETTLE_WINDOW_S
    x_err_mean = float(np.mean(np.abs(run.x[last] - run.x_ref)))
    return {**asdict(case), **run.summary, 'x_err_mean_m': x_err_mean}


def make_cases(swingups: Sequence[str], stabilizers: Sequence[str], scenarios: Sequence[str],
               seeds: int, duration: float = 30.0) -> list[BenchCase]:
    unknown = sorted(set(scenarios) - set(SCENARIOS))
    if unknown:
        raise ValueError(f'unknown scenario(s) {unknown}; known: {list(SCENARIOS)}')
    return [BenchCase(su, st, sc, seed, duration)
            for su in swingups for st in stabilizers for sc in scenarios for seed in range(seeds)]


def run_sweep(cases: Sequence[BenchCase], *, workers: int = 1, dask_address: str | None = None,
              progress: Callable[[int, int], None] | None = None) -> list[dict[str, Any]]:
    """Run every case; results in the order of ``cases`` whatever the executor.

    ``workers`` > 1 uses a local process pool; ``dask_address`` a Dask
    distributed scheduler (``tcp://host:8786``, or an existing
    ``distributed.Client`` object's address). See :func:`.sweep.run_parallel`.
    """
    return run_parallel(run_case, cases, workers=workers, dask_address=dask_address,
                        progress=progress)


def prepare(swingups: Sequence[str], progress=None) -> None:
    """Do, once before the sweep, the plugins' slow work for the runs' start.

    ``time_optimal`` solves its plan (blocking) if it is not cached, so that
    the pool's workers do not all wait for it at their first run. Every
    scenario starts at hanging rest at the left stop, the default start.
    """
    from cartpole_control.controller import ControllerState
    from cartpole_control.manager import ControllerManager

    p = CartPoleParameters()
    start = ControllerState(0.0, *Scenario().initial_state())
    for name in swingups:
        manager = ControllerManager(p, sample_time=p.sample_time, real_time=False)
        if manager.set_parameters({'swingup': name}).successful:
            manager.prepare(start, progress)


def _percentile(values: Iterable[float], q: float) -> float | None:
    arr = np.array([v for v in values if v is not None], dtype=float)
    return float(np.percentile(arr, q)) if arr.size else None


def aggregate(results: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per pair and scenario: success rate, catch time p50/p90/max, worst amplitudes, mean MSEs, contacts."""
    groups: dict[tuple[str, str, str], list[dict[str, Any]]] = {}
    for r in results:
        groups.setdefault((r['swingup'], r['stabilizer'], r['scenario']), []).append(r)
    rows = []
    for (su, st, sc), rs in groups.items():
        catches = [r['catch_time_s'] for r in rs]
        rows.append({
            'swingup': su, 'stabilizer': st, 'scenario': sc, 'runs': len(rs),
            'success_rate': sum(r['success'] for r in rs) / len(rs),
            'catch_p50_s': _percentile(catches, 50), 'catch_p90_s': _percentile(catches, 90),
            'catch_max_s': max((c for c in catches if c is not None), default=None),
            'caught': sum(c is not None for c in catches),
            'theta_amp_deg_max': max(r['theta_amp_deg'] for r in rs),
            'x_err_max_m': max(r['x_err_max_m'] for r in rs),
            'mse_x': float(np.mean([r['mse_x'] for r in rs])),
            'mse_theta': float(np.mean([r['mse_theta'] for r in rs])),
            'x_err_mean_m_max': _max(r.get('x_err_mean_m') for r in rs),
            'force_rms_n_max': _max(r.get('force_rms_n') for r in rs),
            'force_p2p_n_max': _max(r.get('force_p2p_n') for r in rs),
            'end_stop_contacts': sum(r['end_stop_contact'] for r in rs),
        })
    return rows


def _max(values: Iterable[float | None]) -> float | None:
    known = [v for v in values if v is not None]
    return max(known) if known else None


def _fmt(v: Any, spec: str = '.3g') -> str:
    if v is None:
        return '-'
    if isinstance(v, float):
        return format(v, spec)
    return str(v)


def left_stop_bound(params: CartPoleParameters | None = None) -> float:
    """The minimum-time swing-up bound from the default start (``cartpole bound``), in seconds."""
    from cartpole_control.trajectory_optimization import swingup_bounds
    params = params or CartPoleParameters()
    return float(swingup_bounds(params, ['left_stop'], n_intervals=70,
                                refine_intervals=None)['left_stop'].final_time)


def markdown_report(rows: Sequence[dict[str, Any]], results: Sequence[dict[str, Any]],
                    bound: float | None = None) -> str:
    """Markdown: per-pair summary beside requirements 3.1 and Table 10.2, then every pair x scenario.

    With ``bound`` (the minimum-time bound from the start of the runs) each
    pair's median catch time is also given as a ratio to it.
    """
    out = []
    pairs: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for r in results:
        pairs.setdefault((r['swingup'], r['stabilizer']), []).append(r)
    out.append('### Per pair, all scenarios\n')
    out.append('Requirements (thesis 3.1): catch < 10 s, |theta| < 2 deg, |x - x*| <= 0.10 m, '
               'no end-stop contact. Table 10.2 gives the rig\'s MSE (cart / pendulum) over the last 10 s.\n')
    if bound:
        out.append(f'Minimum-time bound from the start of these runs (left stop, hanging at rest; '
                   f'`cartpole bound --case left_stop`): {bound:.3f} s.\n')
    out.append('| swing-up | stabiliser | runs | success | nominal success | catch p50 / p90 / max [s] '
               '| catch p50 / bound | worst theta amp [deg] | worst x err [m] | MSE x (nominal) '
               '| MSE theta (nominal) | thesis MSE x / theta | force rms / p2p (nominal) [N] '
               '| end-stop contacts |')
    out.append('|' + '---|' * 14)
    for (su, st), rs in pairs.items():
        nominal = [r for r in rs if r['scenario'] == 'nominal']
        catches = [r['catch_time_s'] for r in rs]
        thesis = THESIS_TABLE_10_2.get(st)
        out.append('| ' + ' | '.join([
            su, st, str(len(rs)),
            f"{100 * sum(r['success'] for r in rs) / len(rs):.0f} %",
            f"{100 * sum(r['success'] for r in nominal) / len(nominal):.0f} %" if nominal else '-',
            ' / '.join(_fmt(v) for v in (_percentile(catches, 50), _percentile(catches, 90),
                                         max((c for c in catches if c is not None), default=None))),
            _fmt(_percentile(catches, 50) / bound) if bound and _percentile(catches, 50) else '-',
            _fmt(max(r['theta_amp_deg'] for r in rs)),
            _fmt(max(r['x_err_max_m'] for r in rs)),
            _fmt(float(np.mean([r['mse_x'] for r in nominal])) if nominal else None, '.3e'),
            _fmt(float(np.mean([r['mse_theta'] for r in nominal])) if nominal else None, '.3e'),
            f'{thesis[0]:.3e} / {thesis[1]:.3e}' if thesis else '-',
            f"{_fmt(_max(r.get('force_rms_n') for r in nominal), '.2f')} / "
            f"{_fmt(_max(r.get('force_p2p_n') for r in nominal), '.1f')}" if nominal else '-',
            str(sum(r['end_stop_contact'] for r in rs)),
        ]) + ' |')
    out += offset_table(rows)
    out.append('\n### Per pair and scenario\n')
    out.append('Worst run of each cell for the amplitude, the errors and the force; "x err mean" '
               f'is the mean |x - x*| over the last {SETTLE_WINDOW_S:g} s, "force rms / p2p" '
               'the force command over the last 10 s.\n')
    out.append('| swing-up | stabiliser | scenario | runs | success | catch p50 / p90 / max [s] '
               '| theta amp max [deg] | x err max [m] | x err mean [m] | force rms / p2p [N] '
               '| MSE x | MSE theta | end-stop contacts |')
    out.append('|' + '---|' * 13)
    for row in rows:
        out.append('| ' + ' | '.join([
            row['swingup'], row['stabilizer'], row['scenario'], str(row['runs']),
            f"{100 * row['success_rate']:.0f} %",
            ' / '.join(_fmt(row[k]) for k in ('catch_p50_s', 'catch_p90_s', 'catch_max_s')),
            _fmt(row['theta_amp_deg_max']), _fmt(row['x_err_max_m']),
            _fmt(row.get('x_err_mean_m_max'), '.4f'),
            f"{_fmt(row.get('force_rms_n_max'), '.2f')} / {_fmt(row.get('force_p2p_n_max'), '.1f')}",
            _fmt(row['mse_x'], '.3e'), _fmt(row['mse_theta'], '.3e'),
            str(row['end_stop_contacts'])]) + ' |')
    return '\n'.join(out) + '\n'


def offset_table(rows: Sequence[dict[str, Any]]) -> list[str]:
    """Markdown lines: per pair, success and worst mean |x - x*| (last 5 s) per encoder offset.

    Empty when the sweep ran no offset scenario. The measure of Appendix H:
    an offset that no integrator takes up leaves the cart K_theta b / K_x off.
    """
    names = [n for n in SCENARIOS if n.startswith('offset') and any(r['scenario'] == n
                                                                     for r in rows)]
    if not names:
        return []
    cells = {(r['swingup'], r['stabilizer'], r['scenario']): r for r in rows}
    pairs = sorted({(r['swingup'], r['stabilizer']) for r in rows})
    out = ['\n### Encoder offsets (Appendix H)\n',
           f'Success rate / worst mean |x - x*| over the last {SETTLE_WINDOW_S:g} s [cm].\n',
           '| swing-up | stabiliser | ' + ' | '.join(names) + ' |',
           '|' + '---|' * (len(names) + 2)]
    for su, st in pairs:
        row = []
        for n in names:
            r = cells.get((su, st, n))
            err = None if r is None else r.get('x_err_mean_m_max')
            row.append('-' if r is None else f"{100 * r['success_rate']:.0f} % / "
                       f"{_fmt(None if err is None else 100 * err, '.2f')}")
        out.append(f'| {su} | {st} | ' + ' | '.join(row) + ' |')
    return out


def plot_report(rows: Sequence[dict[str, Any]], results: Sequence[dict[str, Any]],
                directory) -> list[str]:
    """Success-rate heat map (pair x scenario) and catch-time distributions per pair."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    from pathlib import Path

    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    pairs = sorted({(r['swingup'], r['stabilizer']) for r in rows})
    scenarios = [s for s in SCENARIOS if any(r['scenario'] == s for r in rows)]
    grid = np.full((len(pairs), len(scenarios)), np.nan)
    for r in rows:
        grid[pairs.index((r['swingup'], r['stabilizer'])), scenarios.index(r['scenario'])] = \
            100 * r['success_rate']
    fig, ax = plt.subplots(figsize=(1.2 * len(scenarios) + 3, 0.45 * len(pairs) + 1.5))
    im = ax.imshow(grid, vmin=0, vmax=100, cmap='RdYlGn', aspect='auto')
    ax.set_xticks(range(len(scenarios)), scenarios, rotation=30, ha='right')
    ax.set_yticks(range(len(pairs)), [f'{a} + {b}' for a, b in pairs])
    for i in range(len(pairs)):
        for j in range(len(scenarios)):
            if not np.isnan(grid[i, j]):
                ax.text(j, i, f'{grid[i, j]:.0f}', ha='center', va='center', fontsize=8)
    fig.colorbar(im, ax=ax, label='success rate [%]')
    ax.set_title('Success rate per pair and scenario')
    fig.tight_layout()
    heat = directory / 'success_heatmap.png'
    fig.savefig(heat, dpi=110)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(max(6, 0.6 * len(pairs) + 2), 4))
    data = [[r['catch_time_s'] for r in results
             if (r['swingup'], r['stabilizer']) == p and r['catch_time_s'] is not None] for p in pairs]
    ax.boxplot([d if d else [np.nan] for d in data])
    ax.set_xticks(range(1, len(pairs) + 1), [f'{a}\n{b}' for a, b in pairs], fontsize=7)
    ax.axhline(10.0, color='r', ls='--', lw=1, label='requirement 3.1: 10 s')
    ax.set_ylabel('catch time [s]')
    ax.set_title('Catch-time distribution per pair (all scenarios)')
    ax.legend()
    fig.tight_layout()
    box = directory / 'catch_times.png'
    fig.savefig(box, dpi=110)
    plt.close(fig)
    return [str(heat), str(box)]
