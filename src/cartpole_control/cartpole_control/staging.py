"""Parameter changes staged outside the control cycle: the cycle only swaps.

A parameter change (a controller switch, new gains, a new reference) is
validated and turned into everything the next control cycle needs *before*
that cycle, in the caller's thread (the node's parameter callback, a test, a
batch run): the catch trigger, feedforward and rail guard rebuilt from the
new values, and, for each kind whose selected plugin is new or sees new gains
or a new context, a fresh plugin instance constructed and configured with
the real context (an LQR's Riccati solve, a time-optimal plan read from the
cache with its TV-LQR gains). The instance that validated the change is the
one that runs: there is no scratch copy built and thrown away.

Design notes: docs/controller_manager.md ("Design notes by module", ``cartpole_control.staging``).

No ROS import.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, Mapping

from cartpole_core.model import CartPoleParameters

from .catch import CatchTrigger
from .controller import KINDS, ControlContext, Controller, ParameterSpec
from .feedforward import FrictionFeedforward
from .natural_frequency import NaturalFrequencyEstimator
from .plant_estimate import PlantEstimate
from .rail_guard import GuardView, RailGuard

CONTEXT_KEYS = ('x_ref', 'feedforward.right', 'feedforward.left', 'feedforward.steepness',
                'feedforward.velocity_band', 'rail.margin', 'rail.limit_reserve')
"""Manager parameters that the plugins see through their ControlContext."""


def friction_feedforward(values: Mapping[str, Any]) -> FrictionFeedforward:
    """The cart friction feedforward (6.12) of the manager's parameter values."""
    return FrictionFeedforward(values['feedforward.right'], values['feedforward.left'],
                               values['feedforward.steepness'],
                               values['feedforward.velocity_band'])


def plugin_gains(name: str, values: Mapping[str, Any]) -> dict[str, Any]:
    """The ``<name>.<gain>`` entries of ``values`` as ``{gain: value}``."""
    prefix = name + '.'
    return {key[len(prefix):]: value for key, value in values.items() if key.startswith(prefix)}


@dataclass
class StagedChange:
    """A validated change, with everything built that the cycle swaps in."""

    changes: dict[str, Any]
    """The validated values of the changed parameters (all changes since the last swap)."""
    blocks: tuple[CatchTrigger, FrictionFeedforward, RailGuard]
    """Catch trigger, feedforward and rail guard built from the values after the change."""
    context: ControlContext | None
    """The new ControlContext, or None if the change leaves it as it was."""
    plugins: dict[str, Controller]
    """``{kind: configured instance}`` for each kind that needs a new one (not activated)."""

    def then(self, later: 'StagedChange') -> 'StagedChange':
        """This change followed by ``later`` (staged on top of this one's values)."""
        return StagedChange(dict(self.changes, **later.changes), later.blocks,
                            later.context if later.context is not None else self.context,
                            dict(self.plugins, **later.plugins))


class Stager:
    """Validates changes and builds the objects they need (see the module docstring).

    Parameters
    ----------
    plant, sample_time
        The controllers' plant model and control period.
    registry
        ``{kind: {name: Controller subclass}}``.
    specs
        Every parameter of the manager and the plugins, by full name.
    real_time
        :attr:`ControlContext.real_time` of the contexts built.
    pendulum
        :attr:`ControlContext.pendulum` of the contexts built (the manager's estimate).
    plant_estimate
        :attr:`ControlContext.plant_estimate` of the contexts built.
    """

    def __init__(self, plant: CartPoleParameters, sample_time: float,
                 registry: Mapping[str, Mapping[str, type[Controller]]],
                 specs: Mapping[str, ParameterSpec], real_time: bool = True,
                 pendulum: NaturalFrequencyEstimator | None = None,
                 plant_estimate: PlantEstimate | None = None) -> None:
        self.plant = plant
        self.rail_guard = GuardView()
        """:attr:`ControlContext.rail_guard` of the contexts built: the manager puts its guard
        behind it."""
        self.pendulum = pendulum
        self.plant_estimate = plant_estimate
        self.real_time = real_time
        self.sample_time = sample_time
        self.registry = registry
        self.specs = specs
        self.constructions = 0
        """Plugin instances built so far (configured ones and validation scratch ones)."""

    def context(self, values: Mapping[str, Any]) -> ControlContext:
        return ControlContext(plant=self.plant, x_ref=float(values['x_ref']),
                              sample_time=self.sample_time,
                              feedforward=friction_feedforward(values), real_time=self.real_time,
                              rail_margin=float(values['rail.margin']),
                              rail_reserve=float(values['rail.limit_reserve']),
                              pendulum=self.pendulum, plant_estimate=self.plant_estimate,
                              rail_guard=self.rail_guard)

    def blocks(self, v: Mapping[str, Any]) -> tuple[CatchTrigger, FrictionFeedforward, RailGuard]:
        """Catch trigger (6.4), feedforward (6.12), rail guard; ValueError on a bad combination."""
        trigger = CatchTrigger(energy_tolerance=v['catch.energy_tolerance'],
                               angle=math.radians(v['catch.angle_deg']),
                               fall_angle=math.radians(v['fall.angle_deg']))
        guard = RailGuard(self.plant, margin=v['rail.margin'],
                          max_brake_force=v['rail.max_brake_force'],
                          latency=v['rail.latency'], rest_speed=v['rail.rest_speed'],
                          creep_speed=v['rail.creep_speed'], limit=v['rail.limit'],
                          limit_reserve=v['rail.limit_reserve'],
                          actuator_dead_time=v['rail.actuator_dead_time'],
                          reserve_time=v['rail.reserve_time'])
        return trigger, friction_feedforward(v), guard

    def plugin(self, kind: str, name: str, values: Mapping[str, Any],
               context: ControlContext) -> Controller:
        """A new instance of plugin ``name`` configured from ``values`` (raises as configure does)."""
        self.constructions += 1
        plugin = self.registry[kind][name]()
        plugin.configure(plugin_gains(name, values), context)
        return plugin

    def checked_plugin(self, kind: str, name: str, values: Mapping[str, Any],
                        context: ControlContext) -> Controller:
        try:
            return self.plugin(kind, name, values, context)
        except ValueError as error:
            raise ValueError(f'{name}: {error}') from None
        except Exception as error:  # a plugin bug must not take the manager down
            raise ValueError(f'{name} refused its configuration: '
                             f'{type(error).__name__}: {error}') from None

    def validated(self, changes: Mapping[str, Any]) -> dict[str, Any]:
        """Each change checked against its spec; ValueError with the reason if any is wrong."""
        out: dict[str, Any] = {}
        for name, value in changes.items():
            spec = self.specs.get(name)
            if spec is None:
                raise ValueError(f'unknown parameter {name!r}')
            if name in KINDS and isinstance(value, str) and value not in self.registry[name]:
                raise ValueError(f'unknown {name} controller {value!r}; registered: '
                                 f'{list(self.registry[name])}')
            out[name] = spec.validate(value)
        return out

    def stage(self, changes: Mapping[str, Any], values: Mapping[str, Any]) -> StagedChange:
        """Validate ``changes`` on top of the current ``values`` and build what they need.

        Slow work happens here (milliseconds: a Riccati solve, a plan read
        with its TV-LQR gains), never in the cycle. ValueError with the
        reason if anything is refused; then nothing is kept.
        """
        out = self.validated(changes)
        candidate = dict(values)
        candidate.update(out)
        blocks = self.blocks(candidate)  # cross-checks, e.g. the fall angle above the catch angle
        context_changed = any(key in CONTEXT_KEYS and out[key] != values[key] for key in out)
        context = self.context(candidate)
        scratch = dataclasses.replace(context, validation_only=True)
        plugins: dict[str, Controller] = {}
        for kind in KINDS:
            selected = candidate[kind]
            for name in self.registry[kind]:
                touched = context_changed or any(key.startswith(name + '.') for key in out)
                if name == selected and (touched or selected != values[kind]):
                    plugins[kind] = self.checked_plugin(kind, name, candidate, context)
                elif touched:
                    self.checked_plugin(kind, name, candidate, scratch)
        return StagedChange(out, blocks, context if context_changed else None, plugins)
