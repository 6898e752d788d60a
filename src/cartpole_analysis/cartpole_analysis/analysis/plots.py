"""Figures of a run from plain arrays (no ROS): shared by ``analyze``, ``run`` and ``offline``.

- :func:`plot_run`: the layout of the thesis's Figure 10.1 (cart position with
  x* and the +/-10 cm band, pendulum angle theta_w, force command, pendulum
  energy E_p (7.3) with E* (6.8)); the catch is a red vertical line on each
  panel, every start of a controller (a catch, a fall, a switch by
  ``ros2 param set``) a grey dotted one, named at the top.
- :func:`plot_phase`: the phase portrait theta_w vs theta_dot with the
  heteroclinic orbits (6.10).
- :func:`plot_overlay`: several runs on shared axes, for comparisons.

Matplotlib is used through :class:`matplotlib.figure.Figure` and the Agg
canvas only (no pyplot, no global state, no display needed).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from cartpole_core.model import CartPoleParameters, pendulum_energy

from .metrics import X_ERR_LIMIT_M, wrap


@dataclass
class RunSeries:
    """The time series of one run, as plain arrays.

    Attributes
    ----------
    t, x, theta, theta_dot
        Sample times [s] (0 = start of the run), cart position [m], pendulum
        angle [rad] (any unwrapping) and rate [rad/s]; all of one length.
    force
        Force command [N], at ``t_force`` (or at ``t`` when ``t_force`` is None).
    energy
        Pendulum energy E_p (7.3) [J] at ``t``.
    x_ref
        The cart reference x* [m].
    upright_energy
        E* = 2 m_p g l (6.8) [J].
    catch_time
        Time of the first switch to the stabiliser [s], or None.
    t_force
        Times of ``force`` [s]; None when they are ``t``.
    pendulum_length, gravity
        l [m] and g [m/s^2] of the heteroclinic orbits (6.10).
    label
        Name of the run in titles and legends.
    controllers
        The controllers that ran, ``[{'kind', 'name', 'start_s', 'end_s'}]``
        (:mod:`cartpole_analysis.analysis.timeline`); their starts are marked.
    """

    t: np.ndarray
    x: np.ndarray
    theta: np.ndarray
    theta_dot: np.ndarray
    force: np.ndarray
    energy: np.ndarray
    x_ref: float
    upright_energy: float
    catch_time: float | None = None
    t_force: np.ndarray | None = None
    pendulum_length: float = CartPoleParameters.l
    gravity: float = CartPoleParameters.g
    label: str = ''
    controllers: list[dict] = field(default_factory=list)

    def __post_init__(self) -> None:
        for name in ('t', 'x', 'theta', 'theta_dot', 'force', 'energy'):
            setattr(self, name, np.asarray(getattr(self, name), dtype=float))
        if self.t_force is not None:
            self.t_force = np.asarray(self.t_force, dtype=float)
        n = self.t.size
        for name in ('x', 'theta', 'theta_dot', 'energy'):
            if getattr(self, name).size != n:
                raise ValueError(f'{name} has {getattr(self, name).size} samples, t has {n}')
        if self.force.size != (n if self.t_force is None else self.t_force.size):
            raise ValueError('force and its times differ in length')

    @classmethod
    def from_states(cls, t: Sequence[float], states: np.ndarray, force: Sequence[float], *,
                    params: CartPoleParameters, x_ref: float, catch_time: float | None,
                    t_force: Sequence[float] | None = None, label: str = '',
                    controllers: Sequence[dict] = ()) -> 'RunSeries':
        """Build from states ``[x, theta, x_dot, theta_dot]`` (shape (N, 4)) and forces.

        E_p (7.3) and E* (6.8) are computed with ``params`` (the controller's
        nominal parameters, so the energy is the one the swing-up regulates).
        """
        states = np.asarray(states, dtype=float).reshape(-1, 4)
        energy = [pendulum_energy(th, thd, params) for th, thd in states[:, [1, 3]]]
        return cls(t=np.asarray(t, dtype=float), x=states[:, 0], theta=states[:, 1],
                   theta_dot=states[:, 3], force=np.asarray(force, dtype=float),
                   energy=np.asarray(energy), x_ref=float(x_ref),
                   upright_energy=params.upright_energy, catch_time=catch_time,
                   t_force=None if t_force is None else np.asarray(t_force, dtype=float),
                   pendulum_length=params.l, gravity=params.g, label=label,
                   controllers=[dict(c) for c in controllers])

    @property
    def force_times(self) -> np.ndarray:
        return self.t if self.t_force is None else self.t_force


def heteroclinic_orbit(theta: np.ndarray, length: float, gravity: float) -> np.ndarray:
    """Upper heteroclinic orbit (6.10): theta_dot = sqrt(2 g / l (1 - cos theta)).

    The pendulum-only energy E_p = E* (6.9) with theta = 0 upright; the lower
    orbit is its negative. Zero at upright, 2 sqrt(g / l) when hanging.
    """
    return np.sqrt(2.0 * gravity / length * (1.0 - np.cos(np.asarray(theta, dtype=float))))


def _figure(rows: int, height: float):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(9.0, height), layout='constrained')
    FigureCanvasAgg(fig)
    axes = fig.subplots(rows, 1, sharex=True, squeeze=False)[:, 0]
    return fig, axes


def _save(fig, path: str | Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    return path


def _mark_catch(axes, catch_time: float | None) -> None:
    if catch_time is None:
        return
    for ax in axes:
        ax.axvline(catch_time, color='tab:red', linewidth=1.0, linestyle='-', alpha=0.7)


def _mark_controllers(axes, spans: Sequence[dict]) -> None:
    """A dotted line where each controller started, its name at the top of the first panel."""
    top = axes[0]
    for span in spans:
        for ax in axes:
            ax.axvline(span['start_s'], color='0.4', linewidth=0.8, linestyle=':')
        top.annotate(span['name'], xy=(span['start_s'], 1.0), xycoords=('data', 'axes fraction'),
                     xytext=(2, -2), textcoords='offset points', va='top', fontsize='x-small',
                     color='0.25', rotation=90)


def run_title(spans: Sequence[dict], fallback: str = '') -> str:
    """``swing-up + stabiliser`` of a run, every one that ran (``lqg -> smc``)."""
    from .timeline import names_that_ran
    parts = [' -> '.join(names_that_ran(spans, kind)) for kind in ('swingup', 'stabilizer')]
    parts = [p for p in parts if p]
    return ' + '.join(parts) if parts else fallback


def plot_run(series: RunSeries, path: str | Path, title: str = '') -> Path:
    """Figure 10.1 layout of one run into a PNG file; returns its path.

    Panels top to bottom: cart position x with x* (dashed) and the
    +/-10 cm band of requirement 3.1.2-4; theta_w [deg]; force command [N];
    pendulum energy E_p (7.3) with E* (6.8) dashed. A red vertical line marks
    the catch on each, a grey dotted one the start of each controller.
    """
    fig, (ax_x, ax_th, ax_f, ax_e) = _figure(4, 9.0)
    s = series
    ax_x.axhspan(s.x_ref - X_ERR_LIMIT_M, s.x_ref + X_ERR_LIMIT_M, color='tab:green', alpha=0.12,
                 label='x* +/- 10 cm')
    ax_x.axhline(s.x_ref, color='k', linestyle='--', linewidth=1.0, label='x*')
    ax_x.plot(s.t, s.x, color='tab:blue', linewidth=1.0, label='x')
    ax_x.set_ylabel('cart x [m]')
    ax_x.legend(loc='upper right', fontsize='small')
    ax_th.axhline(0.0, color='k', linestyle='--', linewidth=1.0)
    ax_th.plot(s.t, np.degrees(wrap(s.theta)), color='tab:blue', linewidth=1.0)
    ax_th.set_ylabel('theta_w [deg]')
    ax_th.set_ylim(-185.0, 185.0)
    ax_th.set_yticks([-180, -90, 0, 90, 180])
    ax_f.plot(s.force_times, s.force, color='tab:blue', linewidth=0.8)
    ax_f.set_ylabel('force command [N]')
    ax_e.axhline(s.upright_energy, color='k', linestyle='--', linewidth=1.0, label='E*')
    ax_e.plot(s.t, s.energy, color='tab:blue', linewidth=1.0, label='E_p')
    ax_e.set_ylabel('pendulum energy [J]')
    ax_e.set_xlabel('time [s]')
    ax_e.legend(loc='lower right', fontsize='small')
    axes = (ax_x, ax_th, ax_f, ax_e)
    _mark_controllers(axes, s.controllers)
    _mark_catch(axes, s.catch_time)
    for ax in axes:
        ax.grid(True, alpha=0.3)
    fig.suptitle(title or s.label or 'run')
    return _save(fig, path)


def plot_phase(series: RunSeries, path: str | Path, title: str = '') -> Path:
    """Phase portrait theta_w vs theta_dot with the heteroclinic orbits (6.10); returns the path."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(7.0, 5.5), layout='constrained')
    FigureCanvasAgg(fig)
    ax = fig.subplots()
    s = series
    grid = np.linspace(-math.pi, math.pi, 721)
    orbit = heteroclinic_orbit(grid, s.pendulum_length, s.gravity)
    ax.plot(grid, orbit, color='tab:red', linewidth=1.2, label='heteroclinic orbits (6.10)')
    ax.plot(grid, -orbit, color='tab:red', linewidth=1.2)
    theta_w = wrap(s.theta)
    # Break the line where theta_w wraps, so no horizontal jumps cross the plot.
    jumps = np.nonzero(np.abs(np.diff(theta_w)) > math.pi)[0] + 1
    th_plot = np.insert(theta_w, jumps, np.nan)
    thd_plot = np.insert(s.theta_dot, jumps, np.nan)
    ax.plot(th_plot, thd_plot, color='tab:blue', linewidth=0.7, label='run')
    if s.t.size:
        ax.plot(theta_w[0], s.theta_dot[0], 'o', color='tab:green', label='start')
    if s.catch_time is not None and s.t.size:
        k = int(np.searchsorted(s.t, s.catch_time))
        k = min(k, s.t.size - 1)
        ax.plot(theta_w[k], s.theta_dot[k], 'x', color='k', markersize=9, label='catch')
    ax.set_xlim(-math.pi, math.pi)
    ax.set_xticks([-math.pi, -math.pi / 2, 0.0, math.pi / 2, math.pi],
                  ['-pi', '-pi/2', '0', 'pi/2', 'pi'])
    ax.set_xlabel('theta_w [rad] (0 upright)')
    ax.set_ylabel('theta_dot [rad/s]')
    ax.grid(True, alpha=0.3)
    ax.legend(loc='upper right', fontsize='small')
    ax.set_title(title or s.label or 'phase portrait')
    return _save(fig, path)


def plot_overlay(runs: Sequence[RunSeries], path: str | Path, title: str = '') -> Path:
    """Several runs overlaid (x, theta_w, force, E_p), each in its own colour; returns the path."""
    if not runs:
        raise ValueError('no runs to overlay')
    fig, (ax_x, ax_th, ax_f, ax_e) = _figure(4, 9.0)
    ref = runs[0]
    ax_x.axhspan(ref.x_ref - X_ERR_LIMIT_M, ref.x_ref + X_ERR_LIMIT_M, color='tab:green',
                 alpha=0.12)
    ax_x.axhline(ref.x_ref, color='k', linestyle='--', linewidth=1.0)
    ax_e.axhline(ref.upright_energy, color='k', linestyle='--', linewidth=1.0)
    for i, s in enumerate(runs):
        colour = f'C{i % 10}'
        label = s.label or f'run {i + 1}'
        ax_x.plot(s.t, s.x, color=colour, linewidth=1.0, label=label)
        ax_th.plot(s.t, np.degrees(wrap(s.theta)), color=colour, linewidth=0.8)
        ax_f.plot(s.force_times, s.force, color=colour, linewidth=0.6, alpha=0.8)
        ax_e.plot(s.t, s.energy, color=colour, linewidth=1.0)
        if s.catch_time is not None:
            for ax in (ax_x, ax_th, ax_f, ax_e):
                ax.axvline(s.catch_time, color=colour, linewidth=0.8, linestyle=':')
    ax_x.set_ylabel('cart x [m]')
    ax_th.set_ylabel('theta_w [deg]')
    ax_th.set_ylim(-185.0, 185.0)
    ax_f.set_ylabel('force command [N]')
    ax_e.set_ylabel('pendulum energy [J]')
    ax_e.set_xlabel('time [s]')
    ax_x.legend(loc='upper right', fontsize='small')
    for ax in (ax_x, ax_th, ax_f, ax_e):
        ax.grid(True, alpha=0.3)
    fig.suptitle(title or 'comparison')
    return _save(fig, path)


def write_plots(series: RunSeries, directory: str | Path, stem: str = 'run',
                title: str = '') -> list[Path]:
    """``<stem>_timeseries.png`` (:func:`plot_run`) and ``<stem>_phase.png`` in ``directory``."""
    directory = Path(directory)
    return [plot_run(series, directory / f'{stem}_timeseries.png', title),
            plot_phase(series, directory / f'{stem}_phase.png', title)]


def plot_offline_run(run, path: str | Path, title: str = '') -> Path:
    """:func:`plot_run` of a :class:`cartpole_bringup.offline.closed_loop.RunResult` (``cartpole offline --plot``).

    Uses the run's ground truth, its force commands and its own E_p / E*.
    """
    series = RunSeries(t=run.t, x=run.x, theta=run.theta, theta_dot=run.theta_dot,
                       force=run.force, energy=run.energy, x_ref=run.x_ref,
                       upright_energy=run.upright_energy, catch_time=run.catch_time,
                       label=title or 'offline run',
                       controllers=list(run.summary.get('controllers') or ()))
    return plot_run(series, path, title or run_title(series.controllers))
