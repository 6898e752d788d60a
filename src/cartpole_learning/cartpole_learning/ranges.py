"""Per-episode randomisation: the combined benchmark's range table, fitted to an episode.

The plant of each episode is one draw of :func:`cartpole_sim.scenario_ranges.sample`
from a :class:`~cartpole_sim.scenario_ranges.RangeTable` (every disturbance at
once, the published ranges of docs/robustness.md by default, a user's own
with ``cartpole train --ranges FILE.yaml``), never from the robustness grid's
levels. Two things differ from a benchmark run, both to fit a short episode:

- the push comes within the episode (``push_time``, e.g. 2.5-5 s of a 6 s
  episode) instead of the table's 10-15 s of a 30 s run;
- a fraction ``upright_start`` of the episodes starts near upright at x*
  (within 0.1 m, 0.25 rad, 0.5 rad/s), so balancing is trained from the start.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from cartpole_sim.scenario import Scenario
from cartpole_sim.scenario_ranges import RangeTable, sample


def draw(table: RangeTable, rng: np.random.Generator, x_ref: float, upright_start: float,
         push_time: tuple[float, float] | None = None) -> Scenario:
    """An episode's scenario from ``table`` (module docstring); ``push_time`` None keeps the
    table's. The draws of :func:`sample` come first, in its fixed order."""
    if push_time is not None:
        table = dataclasses.replace(table, push_time=tuple(push_time))
    scenario = sample(table, rng)
    if rng.uniform() < upright_start:
        scenario = scenario.replace(x0=x_ref + float(rng.uniform(-0.1, 0.1)),
                                    theta0=float(rng.uniform(-0.25, 0.25)),
                                    theta_dot0=float(rng.uniform(-0.5, 0.5)))
    return scenario
