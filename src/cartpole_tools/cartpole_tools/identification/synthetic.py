"""Synthetic pulse tests on the simulated plant: to rehearse the procedure or test the fit."""
from __future__ import annotations

from typing import Sequence

import numpy as np

from cartpole_core.model import CartPoleParameters
from cartpole_sim.plant import Plant, Scenario

from .recording import Recording


def pulse_forces(t: np.ndarray, pulses: Sequence[tuple[float, float, float]]) -> np.ndarray:
    """Force commands of a pulse test (section 4.3.1) at sample times ``t``.

    ``pulses`` are (start [s], length [s], force [N]); the command is the
    pulse's force for start <= t < start + length, zero elsewhere.
    """
    t = np.asarray(t, dtype=float)
    force = np.zeros(t.size)
    for start, length, value in pulses:
        force[(t >= start - 1e-9) & (t < start + length - 1e-9)] = value
    return force


def simulate_test(params: CartPoleParameters, force: Sequence[float] | np.ndarray,
                  scenario: Scenario | None = None, *, integration_step: float = 0.001,
                  label: str = 'simulated') -> Recording:
    """A recording of an open-loop test on the simulated plant (encoders quantised).

    ``force[k]`` is held over the k-th sample period (Ts = ``params.sample_time``);
    the measurements are :meth:`Plant.measure` (quantised, noisy if the
    scenario says so) at t = k Ts.
    """
    force = np.asarray(force, dtype=float)
    plant = Plant(params, scenario or Scenario(), integration_step=integration_step)
    n = force.size
    t = np.empty(n)
    x = np.empty(n)
    theta = np.empty(n)
    for k in range(n):
        m = plant.measure()
        t[k], x[k], theta[k] = m.t, m.x, m.theta
        plant.step(float(force[k]))
    return Recording(t, x, theta, force, label)
