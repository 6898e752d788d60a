"""One recorded open-loop test (:class:`Recording`) and its start (no ROS)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MIN_SAMPLES = 20
"""Fewest samples of a usable recording (0.1 s at Ts = 5 ms)."""


class IdentificationError(ValueError):
    """Unusable input: a bag without the topics, too few samples, a bad option."""


@dataclass(frozen=True)
class Recording:
    """One open-loop test: measured positions and the force commands that drove it.

    Parameters
    ----------
    t
        Sample times [s], strictly increasing (gaps allowed: the command is
        held over them, as the device holds its last setpoint).
    x, theta
        Measured cart position [m] and pendulum angle [rad] (continuous,
        pi hanging) at ``t``, quantised as the encoders give them.
    force
        Force command [N] applied from ``t[k]`` until ``t[k + 1]``
        (zero-order hold; docs/architecture.md, one control cycle).
    label
        A name for reports (the bag's directory name).
    """

    t: np.ndarray
    x: np.ndarray
    theta: np.ndarray
    force: np.ndarray
    label: str = ''

    def __post_init__(self) -> None:
        arrays = {}
        for name in ('t', 'x', 'theta', 'force'):
            a = np.asarray(getattr(self, name), dtype=float).reshape(-1)
            object.__setattr__(self, name, a)
            arrays[name] = a
        n = arrays['t'].size
        name = self.label or 'recording'
        if any(a.size != n for a in arrays.values()):
            raise IdentificationError(
                f'{name}: t, x, theta and force must have the same length, got '
                + ', '.join(f'{k} {a.size}' for k, a in arrays.items()))
        if n < MIN_SAMPLES:
            raise IdentificationError(
                f'{name}: {n} samples; at least {MIN_SAMPLES} are needed to fit anything')
        for key, a in arrays.items():
            if not np.all(np.isfinite(a)):
                raise IdentificationError(f'{name}: {key} has non-finite values')
        if not np.all(np.diff(arrays['t']) > 0.0):
            raise IdentificationError(f'{name}: sample times must be strictly increasing')

    @property
    def duration(self) -> float:
        return float(self.t[-1] - self.t[0])

    def window(self, t_start: float | None = None, t_end: float | None = None) -> 'Recording':
        """The samples with t_start <= t - t[0] <= t_end (seconds from the first sample)."""
        rel = self.t - self.t[0]
        keep = np.ones(rel.size, dtype=bool)
        if t_start is not None:
            keep &= rel >= t_start - 1e-9
        if t_end is not None:
            keep &= rel <= t_end + 1e-9
        return Recording(self.t[keep], self.x[keep], self.theta[keep], self.force[keep],
                         self.label)


def estimate_initial_state(rec: Recording, window: float = 0.05) -> np.ndarray:
    """[x, theta, x_dot, theta_dot] at ``rec.t[0]`` from a quadratic fit of the first samples.

    Positions and rates at the start, least squares over ``window`` seconds
    (at least 3 samples): a rate from two quantised samples would be off by a
    whole tick per 5 ms (18 mm/s, 0.6 rad/s); the fit averages that out. A
    test started from rest gives rates close to zero.
    """
    rel = rec.t - rec.t[0]
    n = max(3, int(np.searchsorted(rel, window, side='right')))
    tt = rel[:n]
    out = np.empty(4)
    for i, y in enumerate((rec.x[:n], rec.theta[:n])):
        c = np.polyfit(tt, y, 2)
        out[i] = c[2]
        out[2 + i] = c[1]
    return out


def quiet_lead_in(rec: Recording, window: float) -> int:
    """Samples from the start up to ``window`` seconds or the first non-zero command."""
    rel = rec.t - rec.t[0]
    n = int(np.searchsorted(rel, window, side='right'))
    active = np.flatnonzero(rec.force[:n] != 0.0)
    return int(active[0]) if active.size else n
