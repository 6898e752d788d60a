"""Every disturbance at once: ``cartpole bench robustness --combined N``.

The one-factor grid (:mod:`.robustness`) moves one disturbance at a time; a
rig is never wrong in one way only. Here each of N runs draws every factor
of the range table (:mod:`cartpole_sim.scenario_ranges`) at once, from a
generator seeded by ``(seed, run index)``, so scenario i is the same for
every pair, every worker count and on Dask. A run succeeds by the strict
rule (:func:`.robustness.strict_success`): caught, no fall after the catch, no manager
fault, no impact on a stop, and the run summary's end-of-run precision.
A failure is classified by :func:`failure_kind`; the success rate comes
with its Wilson 95 % interval (:func:`wilson_interval`), and two pairs on
the same scenarios are compared draw by draw (:func:`paired_comparison`).
"""
from __future__ import annotations

import math
from typing import Any, Callable, Sequence

import numpy as np

from cartpole_sim.scenario import Scenario
from cartpole_sim.scenario_ranges import RangeTable, factors, sample

from .robustness import DEFAULT_DURATION, RobustnessRun, run_grid, strict_success

MAX_RUNS = 1000
"""Largest ``--combined N``: 1000 runs of 30 s are about 10 minutes on 2 cores per pair."""
MAX_DURATION = 120.0
"""[s] Longest run of the robustness benchmarks."""
MAX_SIMULATED_S = 100_000.0
"""[s] Largest N x pairs x duration of one combined command: about 30 minutes on 2 cores
(one 30 s run costs about 0.6 s of one core when nothing fails early)."""
KINDS = ('impact', 'fault', 'fall', 'never caught', 'off target')
"""Failure kinds, in the order :func:`failure_kind` tests them."""
Z95 = 1.959963984540054
"""The standard normal's 97.5 % quantile."""
SIGNIFICANCE = 0.05
"""A paired difference is shown when the exact test's two-sided p is below this."""


def scenarios(table: RangeTable, n: int, seed: int = 0) -> list[Scenario]:
    """The ``n`` scenarios of a combined run: scenario i drawn from ``default_rng([seed, i])``
    (adding runs keeps the first ones)."""
    return [sample(table, np.random.default_rng([int(seed), i])) for i in range(n)]


def make_runs(pairs: Sequence[tuple[str, str]], drawn: Sequence[Scenario],
              duration: float = DEFAULT_DURATION) -> list[RobustnessRun]:
    """Every pair on every drawn scenario, pair by pair."""
    return [RobustnessRun(su, st, s, duration) for su, st in pairs for s in drawn]


def run_combined(runs: Sequence[RobustnessRun], *, workers: int = 1,
                 dask_address: str | None = None,
                 progress: Callable[[int, int], None] | None = None) -> list[dict[str, Any]]:
    """Each run's summary (with ``falls_after_catch`` and ``faults``), in order."""
    return run_grid(runs, workers=workers, dask_address=dask_address, progress=progress)


def failure_kind(summary: dict[str, Any]) -> str | None:
    """None for a strict success, else the first of :data:`KINDS` that applies."""
    if strict_success(summary):
        return None
    if summary.get('impacts') or summary.get('end_stop_contact'):
        return 'impact'
    if summary.get('faults') or summary.get('fault'):
        return 'fault'
    if summary.get('falls_after_catch'):
        return 'fall'
    if summary.get('catch_time_s') is None:
        return 'never caught'
    return 'off target'


def wilson_interval(successes: int, n: int, z: float = Z95) -> tuple[float, float]:
    """The Wilson score interval of a success rate (95 % by default); (0, 1) when n = 0.

    Unlike p +/- z sqrt(p(1-p)/n) it stays inside [0, 1] and does not shrink
    to a point at 0 or n successes.
    """
    if n <= 0:
        return 0.0, 1.0
    p = successes / n
    denominator = 1.0 + z * z / n
    centre = (p + z * z / (2 * n)) / denominator
    half = z / denominator * math.sqrt(p * (1.0 - p) / n + z * z / (4.0 * n * n))
    return max(0.0, centre - half), min(1.0, centre + half)


def sign_test(wins: int, losses: int) -> float:
    """Two-sided p of the exact McNemar (sign) test on the discordant draws: the chance of
    a split at least this uneven of ``wins + losses`` draws if either pair were as likely
    to hold each of them (binomial, 1/2); 1 when there is none."""
    n = wins + losses
    if n <= 0:
        return 1.0
    tail = sum(math.comb(n, i) for i in range(min(wins, losses) + 1)) / 2.0 ** n
    return min(1.0, 2.0 * tail)


def paired_comparison(tallies: dict[tuple[str, str], dict[str, Any]]) -> list[dict[str, Any]]:
    """Every two pairs of :func:`tally` (on the same scenarios), draw by draw: the draws only
    the first holds (``first_only``), only the second, both, neither, the exact McNemar p
    (:func:`sign_test`) and the verdict. Two success rates' intervals overlap long after
    the draws say which is better; the draws both hold or both lose say nothing of it."""
    rows = []
    pairs = list(tallies)
    for i, first in enumerate(pairs):
        for second in pairs[i + 1:]:
            a = [k is None for k in tallies[first]['kinds']]
            b = [k is None for k in tallies[second]['kinds']]
            first_only = sum(1 for x, y in zip(a, b) if x and not y)
            second_only = sum(1 for x, y in zip(a, b) if y and not x)
            both = sum(1 for x, y in zip(a, b) if x and y)
            p = sign_test(first_only, second_only)
            better = None
            if p < SIGNIFICANCE:
                better = list(first if first_only > second_only else second)
            rows.append({'first': list(first), 'second': list(second),
                         'first_only': first_only, 'second_only': second_only, 'both': both,
                         'neither': len(a) - first_only - second_only - both, 'p': p,
                         'better': better})
    return rows


def tally(pairs: Sequence[tuple[str, str]], drawn: Sequence[Scenario],
          results: Sequence[dict[str, Any]]) -> dict[tuple[str, str], dict[str, Any]]:
    """Per pair: successes, n, rate, its Wilson interval, failures by kind and each run's
    kind (None for a success), from ``results`` in :func:`make_runs` order."""
    out = {}
    n = len(drawn)
    for p, pair in enumerate(pairs):
        kinds = [failure_kind(r) for r in results[p * n:(p + 1) * n]]
        k = sum(1 for kind in kinds if kind is None)
        low, high = wilson_interval(k, n)
        out[pair] = {'successes': k, 'n': n, 'rate': k / n if n else 0.0,
                     'interval': [low, high],
                     'failures': {kind: kinds.count(kind) for kind in KINDS},
                     'kinds': kinds}
    return out


def factor_table(drawn: Sequence[Scenario]) -> dict[str, list[float]]:
    """Each drawn factor's value per scenario (:func:`cartpole_sim.scenario_ranges.factors`)."""
    rows = [factors(s) for s in drawn]
    return {name: [row[name] for row in rows] for name in rows[0]} if rows else {}
