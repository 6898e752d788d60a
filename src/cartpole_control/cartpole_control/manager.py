"""The controller manager: switching, catch trigger, feedforward, saturation, rail guard (chapter 6).

One control cycle (Figure 6.1, section 9.1), :meth:`ControllerManager.update`:
apply the changes queued since the last cycle (a bumpless switch, never in the
middle of a cycle); predict the estimate over the loop's latency under the
commands in flight (:mod:`cartpole_control.prediction`); the catch trigger
(6.4) or the fall detector (:mod:`cartpole_control.catch`); the active plugin's
raw force; the cart friction feedforward (6.12); the saturation (Appendix C);
the rail guard (:mod:`cartpole_control.rail_guard`); and the plugin hears what
became of its force (anti-windup). What the loop measures of the plant (latency,
actuator, natural frequency) is :mod:`cartpole_control.plant_estimate`.

Modes: ``idle``, ``swingup``, ``stabilizing`` and ``fault`` (zero force until
:meth:`~ControllerManager.restart`, but for the rail guard's brake). The cycle
step by step: docs/controller_manager.md.

No ROS import: the offline closed loop and the ROS node use this class alike.
"""
from __future__ import annotations

import logging
import math
import threading
from typing import Any, Callable, Mapping

from cartpole_core.model import CartPoleParameters, acceleration_function, pendulum_energy

from .catch_region import CatchRegion
from .controller import KINDS, STABILIZER, SWINGUP, CommandFeedback, Controller, \
    ControllerState, ParameterSpec
from .manager_output import FAULT, IDLE, LOOP_FIGURES, MODES, STABILIZING, STATUS_KEYS, \
    SWINGUP_MODE, ManagerOutput, SetResult, restart_answer
from .manager_parameters import DEFAULT_CONTROLLERS, checked_registry, parameter_specs
from .plant_estimate import PlantEstimate
from .prediction import predict_over_commands
from .rail_guard import BRAKING, STOPPED
from .staging import StagedChange, Stager, plugin_gains

__all__ = ['ControllerManager', 'DEFAULT_CONTROLLERS', 'FAULT', 'IDLE', 'LOOP_FIGURES',
           'MODES', 'STABILIZING', 'STATUS_KEYS', 'SWINGUP_MODE', 'ManagerOutput', 'SetResult']

logger = logging.getLogger(__name__)

_MODE_OF_KIND = {SWINGUP: SWINGUP_MODE, STABILIZER: STABILIZING}
_KIND_OF_MODE = {SWINGUP_MODE: SWINGUP, STABILIZING: STABILIZER}


class ControllerManager:
    """Holds one swing-up and one stabiliser plugin and runs the cycle of the module docstring.

    Parameters
    ----------
    plant
        The controllers' model of the plant (nominal parameters).
    sample_time
        Control period Ts [s].
    registry
        ``{kind: {name: Controller subclass}}``; None discovers the installed
        plugins through their entry points (:mod:`cartpole_control.registry`).
    real_time
        :attr:`ControlContext.real_time`; False for batch runs (they :meth:`prepare`).
    **initial_parameters
        Initial values by parameter name (see :meth:`parameter_specs`), e.g.
        ``stabilizer='smc'`` or ``**{'lqg.r': 0.02}``. A bad value raises
        ValueError with the reason.
    """

    def __init__(self, plant: CartPoleParameters, sample_time: float = 0.005,
                 registry: Mapping[str, Mapping[str, type[Controller]]] | None = None,
                 real_time: bool = True, **initial_parameters: Any) -> None:
        if not (math.isfinite(sample_time) and sample_time > 0.0):
            raise ValueError(f'sample_time must be > 0, got {sample_time!r}')
        self.plant = plant
        self.sample_time = float(sample_time)
        # Read once: the model (4.18), the actuator's limits (Appendix C), E* (6.8)
        self._acc = acceleration_function(plant)
        self._force_min, self._force_max = plant.force_min, plant.force_max
        self._upright_energy = plant.upright_energy
        self._registry = checked_registry(registry)
        self._specs = parameter_specs(plant, self.sample_time, self._registry)
        self.plant_estimate = estimate = PlantEstimate(plant, self.sample_time)
        """What the loop has measured of the plant (:mod:`cartpole_control.plant_estimate`)."""
        self.latency, self.natural_frequency, self.actuator, self._in_flight = (
            estimate.latency, estimate.natural_frequency, estimate.actuator, estimate.in_flight)
        self._gain = 1.0
        self.catch_region = CatchRegion(plant, self.sample_time)
        """The stabiliser's region of attraction on the estimated plant (``catch.region``)."""
        self._stager = Stager(plant, self.sample_time, self._registry, self._specs, real_time,
                              self.natural_frequency, self.plant_estimate)
        self._values: dict[str, Any] = {name: spec.default for name, spec in self._specs.items()}
        self._lock = threading.Lock()  # values, pending change, restart request: short holds
        self._staging = threading.RLock()  # serialises staging: each change on the one before
        staged = self._stager.stage(initial_parameters, self._values)
        self._values.update(staged.changes)
        self._trigger, self._feedforward, self._guard = staged.blocks
        self._stager.rail_guard.guard = self._guard
        context = self._stager.context(self._values)
        self._names = {kind: self._values[kind] for kind in KINDS}
        self._plugins: dict[str, Controller] = {
            kind: staged.plugins.get(kind) or self._stager.checked_plugin(
                kind, self._names[kind], self._values, context) for kind in KINDS}
        self._enabled = bool(self._values['enabled'])
        self._pending: StagedChange | None = None
        self._version = 0
        """Changes taken; a checked change is reused only if none came since."""
        self._offer: tuple[dict[str, Any], int, StagedChange] | None = None
        """The change :meth:`check_parameters` staged last, for :meth:`set_parameters` to take."""
        self._restart_requested = False
        self.reset()

    # -- parameters -------------------------------------------------------------------
    def parameter_specs(self) -> dict[str, ParameterSpec]:
        """The manager's parameters and every registered plugin's as ``<plugin>.<param>``."""
        return dict(self._specs)

    def registered(self, kind: str) -> list[str]:
        """Names of the registered plugins of ``kind``."""
        return list(self._registry[kind])

    def get_parameters(self) -> dict[str, Any]:
        """Current values (accepted changes included, even before the next cycle applies them)."""
        with self._lock:
            return dict(self._values)

    @property
    def plugin_constructions(self) -> int:
        """Plugin instances built since start (staged ones and validation scratch ones)."""
        return self._stager.constructions

    def _stage(self, changes: Mapping[str, Any]) -> StagedChange:
        """Stage ``changes`` (caller holds ``_staging``), reusing the last check's if it matches."""
        offer, self._offer = self._offer, None
        changes = dict(changes)
        if offer is not None and offer[0] == changes and offer[1] == self._version:
            return offer[2]
        with self._lock:
            values = dict(self._values)
        return self._stager.stage(changes, values)

    def check_parameters(self, changes: Mapping[str, Any]) -> SetResult:
        """Validate ``changes`` as :meth:`set_parameters` would, without taking them.

        What it builds is kept: a :meth:`set_parameters` of the same changes next (the node's
        post-set callback) takes it without building again.
        """
        with self._staging:
            try:
                staged = self._stage(changes)
            except ValueError as error:
                return SetResult(False, str(error))
            self._offer = (dict(changes), self._version, staged)
        return SetResult(True)

    def set_parameters(self, changes: Mapping[str, Any]) -> SetResult:
        """Validate all ``changes``; take all of them (applied at the next cycle) or none.

        Refused, with the reason and nothing changed: an unknown name, a wrong type, a value
        out of range, an unregistered controller name (the reason lists the registered ones), a
        gain combination a plugin's ``on_configure`` refuses. What the change needs is built
        here, in the caller's thread (:mod:`cartpole_control.staging`); the cycle swaps it in.
        """
        with self._staging:
            try:
                staged = self._stage(changes)
            except ValueError as error:
                return SetResult(False, str(error))
            with self._lock:
                self._values.update(staged.changes)
                self._pending = staged if self._pending is None else self._pending.then(staged)
                self._version += 1
        return SetResult(True)

    def prepare(self, start: ControllerState,
                progress: Callable[[str], None] | None = None) -> dict[str, Any]:
        """Before a batch or lockstep run from ``start``: each configured plugin's
        :meth:`Controller.prepare` (blocking: e.g. a missing plan is solved now).

        The gain changes the plugins ask for are queued like :meth:`set_parameters` and returned
        as ``<plugin>.<gain>`` parameters (for a graph started later). ValueError if refused.
        """
        with self._lock:
            values = dict(self._values)
        context = self._stager.context(values)
        changes: dict[str, Any] = {}
        for kind in KINDS:
            name = values[kind]
            asked = self._registry[kind][name].prepare(plugin_gains(name, values), context, start,
                                                       progress)
            changes.update({f'{name}.{key}': value for key, value in asked.items()})
        if changes:
            result = self.set_parameters(changes)
            if not result.successful:
                raise ValueError(f'prepared parameters refused: {result.reason}')
        return changes

    # -- what the plant reports -----------------------------------------------------------
    def command_applied(self, source: float, applied: float) -> None:
        """The command computed from the sample stamped ``source`` took effect at ``applied`` [s].

        The plant's report (the simulator's sample-and-hold, the rig's device clock): one
        sample of the loop's latency, queued for the cycle (:meth:`PlantEstimate.take_reports`).
        """
        self.plant_estimate.command_applied(source, applied)

    def measured(self, t: float, x: float, theta: float) -> None:
        """The encoders' sample at ``t``: cart position [m], pendulum angle [rad] (unwrapped).

        Feeds the natural-frequency estimate while no stabiliser runs and the actuator's; queued.
        """
        self.plant_estimate.measured(t, x, theta)

    # -- requests -----------------------------------------------------------------------
    def restart(self) -> SetResult:
        """Request a new swing-up from idle or fault at the next cycle (re-arms the catch trigger).

        A fault is cleared and the rail guard re-armed (after its brake has stopped the cart).
        The answer says what will happen, for the service reply: ``successful`` is False when
        there is nothing to restart (control running, or idle because ``enabled`` is false)
        and then nothing is requested.
        """
        mode = self.mode
        with self._lock:
            enabled = bool(self._values['enabled'])
            if mode == FAULT or (mode == IDLE and enabled):
                self._restart_requested = True
        return restart_answer(mode, enabled, self.fault_reason, self._guard.status == BRAKING)

    def reset(self) -> None:
        """Back to the start of a run: counters cleared, guard re-armed, swing-up (or idle) next.

        Parameter changes already accepted stay queued.
        """
        active = getattr(self, '_active', None)
        if active is not None and active.active:
            active.deactivate()
        self._active: Controller | None = None
        self.mode = SWINGUP_MODE if self._enabled else IDLE
        self.fault_reason = ''
        self.catch_count = 0
        self.fall_count = 0
        self.catch_time: float | None = None
        self._last_force = 0.0
        self._energy = math.nan
        self._target = self._upright_energy
        self._horizon = 0.0
        self.plant_estimate.new_run()
        self.catch_region.reset()
        self._guard.reset()
        with self._lock:
            self._restart_requested = False

    # -- switching ------------------------------------------------------------------------
    def _set_mode(self, mode: str, state: ControllerState | None) -> None:
        """Enter ``mode``: deactivate the running plugin, activate the mode's one from ``state``."""
        plugin = self._plugins[_KIND_OF_MODE[mode]] if mode in _KIND_OF_MODE else None
        if self._active is not None and self._active is not plugin:
            if self._active.active:
                self._active.deactivate()
            self._active = None
        self.mode = mode
        if plugin is not None and state is not None and self._active is None:
            plugin.activate(state)
            self._active = plugin

    def _fault(self, reason: str, events: list[str]) -> None:
        if self.mode == FAULT:
            return
        self._set_mode(FAULT, None)
        self.fault_reason = reason
        events.append(f'fault:{reason}')

    def _apply_pending(self, state: ControllerState, events: list[str]) -> None:
        """Apply the queued changes and requests: the ``do_switch`` between two cycles."""
        if self._pending is None and not self._restart_requested:
            return  # the usual cycle; a change queued right now is taken at the next one
        with self._lock:
            staged, restart, self._pending, self._restart_requested = \
                self._pending, self._restart_requested, None, False
        if staged is not None:
            pending = staged.changes
            guard_status = self._guard.status
            self._trigger, self._feedforward, self._guard = staged.blocks
            self._guard.status = guard_status
            self._stager.rail_guard.guard = self._guard
            for kind, new in staged.plugins.items():
                live = self._plugins[kind]
                if self._active is live:
                    live.deactivate()
                    if new.name == live.name:
                        new.take_over(live, state)  # new gains: the run goes on
                    else:
                        new.activate(state)
                    self._active = new
                self._plugins[kind] = new
                if self._names[kind] != new.name:
                    self._names[kind] = new.name
                    events.append(f'switch:{kind}={new.name}')
            if 'enabled' in pending and bool(pending['enabled']) != self._enabled:
                self._enabled = bool(pending['enabled'])
                if self._enabled:
                    restart = True
                elif self.mode != IDLE:
                    self._set_mode(IDLE, state)
                    self.fault_reason = ''
        if restart and self._guard.status == BRAKING:
            with self._lock:
                self._restart_requested = True  # wait until the brake has stopped the cart
        elif restart and self.mode in (IDLE, FAULT):
            self._guard.reset()
            self.fault_reason = ''
            self._set_mode(SWINGUP_MODE if self._enabled else IDLE, state)
            events.append('restart')

    # -- the cycle ----------------------------------------------------------------------------
    def update(self, state: ControllerState) -> ManagerOutput:
        """One control cycle for the estimated ``state``; see the module docstring.

        Only ``t``, ``x``, ``theta``, ``x_dot``, ``theta_dot`` of ``state`` are used (step 2).
        """
        return self.update_values(state.t, state.x, state.theta, state.x_dot, state.theta_dot)

    def update_values(self, t: float, x: float, theta: float, x_dot: float,
                      theta_dot: float) -> ManagerOutput:
        """:meth:`update` for the estimate given as numbers (no ControllerState to build)."""
        events: list[str] = []
        isfinite = math.isfinite
        if not (isfinite(t) and isfinite(x) and isfinite(theta) and isfinite(x_dot)
                and isfinite(theta_dot)):
            self._fault('non-finite state', events)
            self._last_force = 0.0
            self._energy = math.nan
            return self._output(t, 0.0, 0.0, 0.0, events)
        estimate = self.plant_estimate
        if estimate.reports or estimate.samples:
            estimate.take_reports(t, self.mode == STABILIZING)
        self._guard.measured_x_dot = x_dot  # after a trip judged beside the predicted x_dot
        guard_x, guard_theta, guard_x_dot, guard_theta_dot = x, theta, x_dot, theta_dot
        values = self._values
        horizon = values['predict.horizon']
        if horizon == 'auto':
            horizon = self.latency.latency
        gain, delay = values['actuator.gain'], values['actuator.delay']
        actuator = self.actuator
        self._gain = gain = actuator.compensation if gain == 'auto' else gain
        estimate.delay_known = delay != 'auto' or actuator.delay_known
        delay = actuator.delay_compensation if delay == 'auto' else delay
        estimate.used_gain, estimate.used_delay = gain, delay
        horizon += delay
        self._horizon = horizon
        if horizon > 0.0:
            segments = self._in_flight.segments(t, horizon)
            if gain != 1.0:
                segments = [(duration, gain * command) for duration, command in segments]
            x, theta, x_dot, theta_dot = predict_over_commands(
                self._acc, x, theta, x_dot, theta_dot, segments)
            # The rail guard, too, judges the cart where this command will meet it (its
            # own rail.latency then covers the hold); not the plain estimate, which the
            # commands already in flight move on before this one acts.
            guard_x, guard_theta, guard_x_dot, guard_theta_dot = x, theta, x_dot, theta_dot
        x_ddot, theta_ddot = self._acc(x, theta, x_dot, theta_dot, self._last_force)
        state = ControllerState(t, x, theta, x_dot, theta_dot, x_ddot, theta_ddot)

        self._apply_pending(state, events)

        # (7.3) and (6.8): of the estimated pendulum if the swing-up aims at its target
        if self._plugins[SWINGUP].adaptive_target:
            natural = self.natural_frequency
            energy, self._target = natural.energy(theta, theta_dot), natural.upright_energy
        else:
            energy, self._target = pendulum_energy(theta, theta_dot, self.plant), \
                self._upright_energy
        self._energy = energy
        mode = self.mode
        trigger = self._trigger
        # (6.4), then the region the stabiliser holds on the estimated plant (catch.region)
        if mode == SWINGUP_MODE and trigger.energy_condition(energy, self._target) \
                and trigger.angle_condition(theta) and (not values['catch.region'] or (
                    self.catch_region.admits(state, values['x_ref'], estimate.omega_sq, gain,
                                             self._guard))):
            self._set_mode(STABILIZING, state)
            self.catch_count += 1
            if self.catch_time is None:
                self.catch_time = t
            events.append('catch')
        elif mode == STABILIZING and trigger.has_fallen(theta):
            self._set_mode(SWINGUP_MODE, state)
            self.fall_count += 1
            self.catch_region.fell()
            events.append('fall')
        elif mode in _KIND_OF_MODE and self._active is None:
            self._set_mode(mode, state)  # first cycle: activate from this state
        guard = self._guard  # this cycle's envelope, for the plugin (context.rail_guard) too
        guard.balancing = self.mode == STABILIZING  # its reserve then follows the speed
        guard.set_actuator(gain, estimate.disturbance, estimate.uncovered_dead_time)
        friction = values['actuator.friction']  # (6.12) scaled to the rig's friction
        estimate.used_friction = friction = \
            actuator.friction_compensation if friction == 'auto' else friction
        raw = feedforward = force = 0.0
        active = self._active
        if active is not None:
            try:
                raw = float(active.update(state))
            except Exception as error:  # a plugin bug: fail safe, say why
                logger.exception('controller %s failed', active.name)
                self._fault(f'{active.name} failed: {type(error).__name__}: {error}', events)
                raw = 0.0
            else:
                if not isfinite(raw):
                    self._fault(f'{active.name} gave a non-finite force', events)
                    raw = 0.0
                else:
                    if self.mode == STABILIZING:
                        feedforward = friction * self._feedforward.stabilizing(x_dot, raw)
                    else:  # (6.12) and, in swing-up, the unmodelled force cancelled
                        disturbance = values['actuator.disturbance']
                        if disturbance == 'auto':
                            disturbance = self.plant_estimate.swingup_disturbance
                        feedforward = friction * self._feedforward(x_dot, raw) - disturbance
                    force = min(max(raw + feedforward, gain * self._force_min),
                                gain * self._force_max)
        # After a trip the guard keeps hold: a stopped cart dragged towards a stop is braked.
        if self.mode in _KIND_OF_MODE or guard.status == BRAKING or guard.status == STOPPED:
            force, tripped = guard.command(guard_x, guard_x_dot, guard_theta_dot, force,
                                           guard_theta)
            if tripped:
                self._fault('rail guard', events)
        if active is not None and active is self._active \
                and not self._tell_plugin(active, raw, raw + feedforward, force, events):
            force = 0.0
        self._last_force = force  # the force the cart feels; the command is force / G
        if gain != 1.0:
            force = min(max(force / gain, self._force_min), self._force_max)
        self._in_flight.sent(t, force)
        return self._output(t, force, raw, feedforward, events)

    def _tell_plugin(self, plugin: Controller, raw: float, wanted: float, force: float,
                     events: list[str]) -> bool:
        """Step 8: the plugin's anti-windup input; False if the plugin raised (then a fault)."""
        limited = 1 if wanted > force else (-1 if wanted < force else 0)
        held = self._guard.status == BRAKING or self._guard.status == STOPPED
        try:
            plugin.command_applied(CommandFeedback(raw, force, limited, held))
        except Exception as error:  # a plugin bug: fail safe, say why
            logger.exception('controller %s failed', plugin.name)
            self._fault(f'{plugin.name} failed: {type(error).__name__}: {error}', events)
            return False
        return True

    def between_cycles(self) -> None:
        """Work that must not delay a command; call it after the command is out: the actuator's
        window this cycle's samples completed (:meth:`PlantEstimate.finish`) and, while the
        swing-up runs, the configured stabiliser's :meth:`Controller.standby` (its catch)."""
        self.plant_estimate.finish()
        stabilizer = self._plugins[STABILIZER]
        if self.mode == SWINGUP_MODE and self._pending is None and not stabilizer.active:
            try:
                stabilizer.standby()
            except Exception:  # a plugin bug: the activation does the work itself
                logger.exception('controller %s failed in standby', stabilizer.name)

    def stale(self, t: float) -> ManagerOutput:
        """No state for ``state_timeout``: zero force and fault 'stale state' (until restart)."""
        events: list[str] = []
        self._fault('stale state', events)
        self._last_force = 0.0
        return self._output(t, 0.0, 0.0, 0.0, events)

    state_timeout = property(lambda self: float(self._values['state_timeout']))

    @property
    def actuator_gain(self) -> float:
        """The actuator gain the last command was divided by (``actuator.gain``)."""
        return self._gain

    @property
    def prediction_horizon(self) -> float:
        """The prediction horizon of the last cycle [s] (``predict.horizon``, ``auto``: the latency)."""
        return self._horizon

    enabled = property(lambda self: self._enabled)

    @property
    def guard_status(self) -> str:
        """The rail guard's status: armed, limited, braking or stopped."""
        return self._guard.status

    def active_plugins(self) -> dict[str, Controller]:
        """The live plugin instance of each kind (for inspection and tests)."""
        return dict(self._plugins)

    def _output(self, t: float, force: float, raw: float, feedforward: float,
                events: list[str]) -> ManagerOutput:
        energy, names, active = self._energy, self._names, self._active
        return ManagerOutput(
            t, force, self.mode, names[SWINGUP], names[STABILIZER], self._enabled, energy,
            self._target - energy, raw, feedforward, ';'.join(events) if events else '',
            self.catch_count, self.fall_count, self.catch_time, self.fault_reason,
            self._plugins[SWINGUP].law, self.latency.latency, self._horizon,
            self.natural_frequency.omega_sq, self._gain, self.actuator.delay,
            self.actuator.friction_scale, active.status_values() if active is not None else {})
