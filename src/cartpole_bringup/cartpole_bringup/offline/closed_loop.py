"""The closed loop without ROS: plant, 5 ms sampling, quantisation, EKF, controller manager.

The very objects the ROS nodes host, wired the way the node graph wires them
(docs/architecture.md, "The closed loop, one control cycle"), stepped as fast as Python goes.
Deterministic: the same parameters, scenario and controller settings give the
same run bit for bit.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping

import numpy as np

from cartpole_control.controller import ControllerState
from cartpole_control.manager import FAULT, ControllerManager, ManagerOutput
from cartpole_estimation.ekf import EkfConfig, ExtendedKalmanFilter, StateEstimate
from cartpole_core.model import CartPoleParameters, pendulum_energy
from cartpole_sim.plant import Measurement, Plant, Scenario

from cartpole_analysis.analysis import metrics
from cartpole_analysis.analysis.timeline import spans_from_modes


@dataclass
class RunResult:
    """Time series of one offline run (ground truth and what the loop saw) and its summary."""

    t: np.ndarray
    x: np.ndarray
    """True cart position [m]."""
    theta: np.ndarray
    """True pendulum angle [rad] (continuous)."""
    x_dot: np.ndarray
    theta_dot: np.ndarray
    x_est: np.ndarray
    theta_est: np.ndarray
    x_dot_est: np.ndarray
    theta_dot_est: np.ndarray
    force: np.ndarray
    """Force command [N] computed at each sample."""
    energy: np.ndarray
    """Pendulum energy E_p (7.3) of the true state [J]."""
    mode: list[str]
    events: list[tuple[float, str]]
    catch_time: float | None
    end_stop_contact: bool
    x_ref: float
    upright_energy: float
    summary: dict[str, Any] = field(default_factory=dict)
    lost_samples: int = 0
    """Samples the plant lost on the way to the host (scenario ``drop``)."""
    lost_at: tuple[float, ...] = ()
    """Their sample times [s]."""
    ekf_missed_samples: int = 0
    """Missed samples the EKF bridged by prediction (it saw the gaps)."""


def run_closed_loop(nominal: CartPoleParameters | None = None,
                    scenario: Scenario | None = None,
                    duration: float = 30.0,
                    manager_parameters: Mapping[str, Any] | None = None,
                    ekf_config: EkfConfig | None = None,
                    integration_step: float = 0.001,
                    profile: dict[str, float] | None = None,
                    stop_on_failure: bool = False, prepare: bool = True,
                    progress: Callable[[str], None] | None = None,
                    observer: Callable[[Measurement, StateEstimate, ManagerOutput, list[float]],
                                       None] | None = None) -> RunResult:
    """Run the closed loop for ``duration`` simulated seconds and summarise it (the run summary).

    ``nominal`` are the parameters the EKF and the controllers use; the plant
    is ``scenario`` applied to them (tip mass, friction scale, start, noise).
    ``manager_parameters`` are the controller manager's parameters (e.g.
    ``{'swingup': 'full_energy', 'lqg.q': [...]}``); a refused one raises
    ValueError with the manager's reason. With ``profile`` (a dict) the wall
    time spent in each stage (``plant``, ``ekf``, ``controller``) is added to it.

    A sample the scenario loses (``drop``) never reaches the EKF and the
    controller manager, as on the graph: no estimate, no new command, the
    plant holds the last one; the EKF predicts across the gap at the next
    sample and reports it (``StateEstimate.missed_samples``). Its row repeats
    the last estimate (NaN before the first). With ``drop`` the summary gets
    ``lost_samples`` and ``ekf_missed_samples``.

    With ``stop_on_failure`` the run ends at the first sample after which it
    cannot succeed: the cart hit an end stop (an impact), the pendulum fell
    after the catch, or the manager is in fault mode (offline nothing
    restarts it: no swing-up, no stabiliser any more).
    The summary is then of the shorter run, with ``success`` False and
    ``stopped_at_s`` (the benchmarks use it to save time on failed runs).

    With ``prepare`` (default) the plugins do their slow work for the start
    first (:meth:`ControllerManager.prepare`: ``time_optimal`` solves a missing
    plan, blocking, and says so to ``progress``), so the run is the same
    whether the cache was warm or cold.

    ``observer(measurement, estimate, output, true_state)`` is called for
    each sample that arrives (not for a lost one), after the controller and
    before the plant steps (``cartpole offline --view`` shows the run with
    it); ``true_state`` is ``[x, theta, x_dot, theta_dot]`` of the plant.
    """
    nominal = nominal or CartPoleParameters()
    scenario = scenario or Scenario()
    plant = Plant(nominal, scenario, integration_step=integration_step)
    ekf = ExtendedKalmanFilter(nominal, ekf_config or EkfConfig())
    manager = ControllerManager(nominal, sample_time=nominal.sample_time, real_time=False)
    if manager_parameters:
        result = manager.set_parameters(dict(manager_parameters))
        if not result.successful:
            raise ValueError(result.reason)
    started_with = manager.get_parameters()  # the plugins the run starts with
    if prepare:
        manager.prepare(ControllerState(0.0, *scenario.initial_state()), progress)
    x_ref = float(manager.get_parameters()['x_ref'])
    steps = int(round(duration / nominal.sample_time)) + 1
    samples: list[tuple[float, ...]] = []  # one row of the result per sample
    modes: list[str] = []
    events: list[tuple[float, str]] = []
    force = 0.0
    law = None  # the swing-up law at the first catch
    true_params = plant.true_params
    # Bound once: this loop runs 200 times a simulated second.
    measure, step, ekf_update = plant.measure, plant.step, ekf.update
    control = manager.update_values  # manager.update(ControllerState(...)) without the object
    between_cycles = manager.between_cycles
    measured, applied_commands = manager.measured, plant.applied_commands
    command_applied = manager.command_applied
    # The EKF predicts with the force the manager estimates acts (cartpole/force_acting)
    for_filter = manager.plant_estimate.filter_force(ekf.config.force_input)
    ekf_force = 0.0
    add_row, add_mode = samples.append, modes.append
    clock = time.perf_counter if profile is not None else None
    t_plant = t_ekf = t_ctrl = 0.0
    sample_lost = plant.sample_lost if scenario.drop else None
    nan = float('nan')
    x = theta = x_dot = theta_dot = nan  # no estimate before the first sample arrives
    mode = manager.mode
    lost_at: list[float] = []
    stopped_at = None
    plugin_status: Mapping[str, float] = {}
    out = None  # no sample may arrive at all (a scenario that loses every one)
    for k in range(steps):
        if clock:
            t0 = clock()
        meas = measure()
        if clock:
            t1 = clock()
        t = meas.t
        if sample_lost and sample_lost():
            lost_at.append(t)
            s = plant.state
            add_row((t, s[0], s[1], s[2], s[3], x, theta, x_dot, theta_dot, force))
            add_mode(mode)
            if k + 1 < steps:
                step(force)  # the held command
            continue
        for source, applied in applied_commands():  # the plant's reports, as on the graph
            command_applied(source, applied)
        measured(t, meas.x, meas.theta)
        est = ekf_update(t, meas.x, meas.theta, ekf_force)
        if clock:
            t2 = clock()
        x, theta, x_dot, theta_dot = est.x, est.theta, est.x_dot, est.theta_dot
        out = control(est.t, x, theta, x_dot, theta_dot)
        if clock:
            t3 = clock()
            t_plant += t1 - t0
            t_ekf += t2 - t1
            t_ctrl += t3 - t2
        force = out.force
        ekf_force = for_filter(est.t, force)
        between_cycles()  # as the node does once the command is out
        mode = out.mode
        if out.plugin_status:
            plugin_status = out.plugin_status
        s = plant.state
        if observer is not None:
            observer(meas, est, out, s)
        add_row((t, s[0], s[1], s[2], s[3], x, theta, x_dot, theta_dot, force))
        add_mode(mode)
        fell = False
        if out.event:
            events.append((t, out.event))
            if law is None and manager.catch_time is not None:
                law = out.swingup_law
            fell = manager.catch_time is not None and metrics.FALL_EVENT in out.event.split(';')
        if stop_on_failure and (mode == FAULT or plant.end_stop_contact or fell):
            stopped_at = t
            break
        if k + 1 < steps:
            if clock:
                t0 = clock()
                step(force, None, t)
                t_plant += clock() - t0
            else:
                step(force, None, t)
    if profile is not None:
        for key, value in (('plant', t_plant), ('ekf', t_ekf), ('controller', t_ctrl)):
            profile[key] = profile.get(key, 0.0) + value
        profile['steps'] = profile.get('steps', 0) + steps
    rows = np.array(samples, dtype=float).reshape(len(samples), 10)
    energy = np.array([pendulum_energy(th, thd, true_params) for th, thd in zip(rows[:, 2], rows[:, 4])])
    catch_time = manager.catch_time  # the manager keeps the time of its first catch
    run = RunResult(t=rows[:, 0], x=rows[:, 1], theta=rows[:, 2], x_dot=rows[:, 3],
                    theta_dot=rows[:, 4], x_est=rows[:, 5], theta_est=rows[:, 6],
                    x_dot_est=rows[:, 7], theta_dot_est=rows[:, 8], force=rows[:, 9],
                    energy=energy, mode=modes, events=events, catch_time=catch_time,
                    end_stop_contact=plant.end_stop_contact, x_ref=x_ref,
                    upright_energy=true_params.upright_energy,
                    lost_samples=plant.lost_samples, lost_at=tuple(lost_at),
                    ekf_missed_samples=ekf.missed_samples_total)
    run.summary = metrics.summarize(
        run.t, run.x, run.theta, x_ref=x_ref, catch_time=catch_time,
        end_stop_contact=plant.end_stop_contact, fault=first_fault(events),
        controllers=spans_from_modes(run.t, modes, events, started_with['swingup'],
                                     started_with['stabilizer']),
        swingup_law=law if law is not None else (out.swingup_law if out is not None else None),
        force=run.force, falls_after_catch=metrics.falls_after_catch(events, catch_time),
        impacts=plant.impacts)
    run.summary.update(loop_summary(manager, plugin_status))
    for key in metrics.STRICT_KEYS:  # after the older keys: their order is kept
        run.summary[key] = run.summary.pop(key)
    if scenario.drop:
        run.summary.update(lost_samples=run.lost_samples,
                           ekf_missed_samples=run.ekf_missed_samples)
        if out is None:
            run.summary.update(success=False,
                               fault=f'no sample reached the host (all {len(lost_at)} lost)')
    if stopped_at is not None:
        run.summary.update(success=False, stopped_at_s=stopped_at)
    return run


def loop_summary(manager: ControllerManager,
                 plugin_status: Mapping[str, float] | None = None) -> dict[str, Any]:
    """What the manager learnt of the loop, for the run summary: the latency it measured and
    the prediction horizon it used [s], the pendulum's omega_0^2 [1/s^2] it estimated, and
    the last status of a plugin that reports figures (e.g. ``mpc_fallbacks``)."""
    out = {'latency_s': round(manager.latency.latency, 6),
           'predict_horizon_s': round(manager.prediction_horizon, 6),
           'omega0_sq': round(manager.natural_frequency.omega_sq, 4),
           'actuator_gain': round(manager.actuator_gain, 4),
           'actuator_delay_s': round(manager.actuator.delay, 6),
           'friction_scale': round(manager.actuator.friction_scale, 4)}
    out.update(plugin_status or {})
    return out


def first_fault(events: list[tuple[float, str]]) -> str | None:
    """The reason of the manager's first ``fault:<reason>`` event, None if it never faulted."""
    for _, text in events:
        for event in text.split(';'):
            if event.startswith('fault:'):
                return event[len('fault:'):]
    return None
