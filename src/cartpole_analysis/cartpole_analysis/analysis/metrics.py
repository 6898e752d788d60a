"""The run summary (docs/reference/summary.md, "The run summary"), from time series.

One module for every consumer: ``cartpole offline``, ``cartpole analyze`` and
the benchmarks compute the same numbers from the same code. Inputs are the
ground truth (simulation) or the estimate (hardware).
"""
from __future__ import annotations

import math
from typing import Any, Iterable, Sequence

import numpy as np

from cartpole_sim.plant import END_STOP_TOLERANCE

UPRIGHT_DEG = 10.0
"""Requirement 3.1.2-1: within +/-10 deg of upright."""
THETA_AMP_LIMIT_DEG = 2.0
"""Requirement 3.1.2-3: oscillations below +/-2 deg when stabilised."""
X_ERR_LIMIT_M = 0.10
"""Requirement 3.1.2-4: cart within 10 cm of x*."""
WINDOW_S = 10.0
"""The thesis's table 10.2 measures the last 10 s."""

SUMMARY_KEYS = ('catch_time_s', 'upright_time_s', 'theta_amp_deg', 'x_err_max_m',
                'mse_x', 'mse_theta', 'end_stop_contact', 'success', 'swingup_law',
                'force_rms_n', 'force_p2p_n')
STRICT_KEYS = ('falls_after_catch', 'impacts', 'first_impact_s', 'impact_speed_mps')
"""Keys of the strict rule, in the summary when the caller knows them (offline runs)."""


def wrap(theta: np.ndarray) -> np.ndarray:
    """theta_w, wrapped to (-pi, pi] (vectorised ``cartpole_core.model.wrap_angle``)."""
    w = np.mod(np.asarray(theta, dtype=float) + math.pi, 2.0 * math.pi)
    w = np.where(w <= 0.0, w + 2.0 * math.pi, w)
    return w - math.pi


def summarize(t: Sequence[float], x: Sequence[float], theta: Sequence[float], *,
              x_ref: float, catch_time: float | None, end_stop_contact: bool,
              window: float = WINDOW_S, fault: str | None = None,
              controllers: Sequence[dict[str, Any]] | None = None,
              longest_cycle_gap_s: float | None = None, swingup_law: str | None = None,
              force: Sequence[float] | None = None,
              t_force: Sequence[float] | None = None,
              falls_after_catch: int | None = None,
              impacts: Sequence[Any] | None = None) -> dict[str, Any]:
    """The run summary of one run from hanging rest.

    Parameters
    ----------
    t, x, theta
        Sample times [s], cart position [m], pendulum angle [rad] (any
        unwrapping; it is wrapped here).
    x_ref
        The cart reference x* [m].
    catch_time
        Time of the first switch to the stabiliser, or None.
    end_stop_contact
        Whether the cart hit an end stop (simulation: an impact, see ``impacts``;
        resting against a stop is not one).
    window
        Length of the final window for the amplitude, error, MSE and force figures.
    fault
        Why the run stopped early or lost control: a node that
        died, the controller manager's first fault; None when nothing went
        wrong. A run with a fault is not a success.
    controllers
        Each swing-up and stabiliser that ran, with its time span
        (:mod:`cartpole_analysis.analysis.timeline`).
    longest_cycle_gap_s
        The longest gap between two control cycles the controller manager
        reported [s]; None when not reported (offline).
    swingup_law
        What produced the swing-up: the swing-up plugin's law at the
        first catch (else at the end), e.g. ``pendulum_energy``,
        ``time_optimal:plan``, ``time_optimal:fallback(no plan)``; None when
        not known (a bag recorded before the status carried it).
    force, t_force
        The force commands [N] and their times [s] (``t_force`` defaults to
        ``t``); ``force_rms_n`` and ``force_p2p_n`` are null without them.
    falls_after_catch
        How often the pendulum fell after the first catch (the manager's
        ``fall`` events); when given, ``success`` also needs none (the strict
        rule), and the key is in the summary (null when not known).
    impacts
        The plant's impacts on a stop (objects with ``t`` [s] and ``speed``
        [m/s], :class:`cartpole_sim.plant.Impact`); when given, the summary
        has ``impacts`` (count), ``first_impact_s`` and ``impact_speed_mps``
        (the fastest arrival; 0.0 for impacts that only pressed).
    """
    t = np.asarray(t, dtype=float)
    x = np.asarray(x, dtype=float)
    theta_w = wrap(theta)
    if t.size == 0:
        raise ValueError('no samples to summarise')
    upright = np.nonzero(np.abs(theta_w) <= math.radians(UPRIGHT_DEG))[0]
    last = t >= t[-1] - window
    theta_amp = float(np.degrees(np.max(np.abs(theta_w[last]))))
    x_err = x[last] - x_ref
    x_err_max = float(np.max(np.abs(x_err)))
    long_enough = t[-1] - t[0] >= window
    success = bool(catch_time is not None and long_enough and theta_amp < THETA_AMP_LIMIT_DEG
                   and x_err_max <= X_ERR_LIMIT_M and not end_stop_contact and fault is None
                   and not falls_after_catch)
    extra: dict[str, Any] = {'falls_after_catch': None if falls_after_catch is None
                             else int(falls_after_catch)}
    if impacts is not None:
        extra.update(impacts=len(impacts),
                     first_impact_s=float(impacts[0].t) if impacts else None,
                     impact_speed_mps=max((float(i.speed) for i in impacts), default=None))
    return {
        'catch_time_s': None if catch_time is None else float(catch_time),
        'upright_time_s': float(t[upright[0]]) if upright.size else None,
        'theta_amp_deg': theta_amp,
        'x_err_max_m': x_err_max,
        'mse_x': float(np.mean(x_err ** 2)),
        'mse_theta': float(np.mean(theta_w[last] ** 2)),
        'end_stop_contact': bool(end_stop_contact),
        'success': success,
        'fault': fault,
        'controllers': [dict(c) for c in controllers or ()],
        'longest_cycle_gap_s': None if longest_cycle_gap_s is None else float(longest_cycle_gap_s),
        'swingup_law': swingup_law,
        **control_effort(force, t if t_force is None else t_force, t[-1] - window),
        **extra,
    }


FALL_EVENT = 'fall'
"""The controller manager's event when the pendulum falls while stabilising."""


def falls_after_catch(events: Iterable[tuple[float, str]], catch_time: float | None) -> int:
    """How many ``fall`` events the controller manager reported at or after its first catch:
    ``events`` are (time, ``'event;event'``) pairs, in the unit of ``catch_time``."""
    if catch_time is None:
        return 0
    return sum(text.split(';').count(FALL_EVENT) for t, text in events if t >= catch_time)


def control_effort(force: Sequence[float] | None, t_force: Sequence[float],
                   since: float) -> dict[str, float | None]:
    """``force_rms_n`` and ``force_p2p_n`` of the commands stamped at or after ``since``.

    The root mean square of the force command and its peak-to-peak range
    over the window, what an amplifier sees: heat and noise. Null when no
    command falls in the window (or none was given).
    """
    if force is None:
        return {'force_rms_n': None, 'force_p2p_n': None}
    f = np.asarray(force, dtype=float)
    tf = np.asarray(t_force, dtype=float)
    if f.shape != tf.shape:
        raise ValueError(f'force and t_force differ in length ({f.size} and {tf.size})')
    f = f[tf >= since]
    if f.size == 0:
        return {'force_rms_n': None, 'force_p2p_n': None}
    return {'force_rms_n': float(np.sqrt(np.mean(f * f))),
            'force_p2p_n': float(np.max(f) - np.min(f))}


def end_stop_touched(x: Sequence[float], travel: float,
                     tolerance: float = END_STOP_TOLERANCE) -> bool:
    """Contact from positions: the cart went past [0, travel] by more than ``tolerance`` [m].

    The plant's own criterion (:data:`cartpole_sim.plant.END_STOP_TOLERANCE`),
    for series that do not carry the plant's contact state.
    """
    x = np.asarray(x, dtype=float)
    return bool(np.any(x < -tolerance) or np.any(x > travel + tolerance))
