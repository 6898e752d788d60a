"""The controller plugin contract: what a swing-up law or a stabiliser provides.

Design notes: docs/controller_manager.md ("Design notes by module", ``cartpole_control.controller``).
"""
from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Callable, ClassVar, Mapping, Sequence, final

from cartpole_core.model import CartPoleParameters, wrap_angle

from .feedforward import FrictionFeedforward

if TYPE_CHECKING:
    from .natural_frequency import NaturalFrequencyEstimator
    from .plant_estimate import PlantEstimate

API_VERSION = 2
"""Version of this contract. Bump on any incompatible change (2: activate/deactivate
became template methods around the on_activate/on_deactivate hooks)."""

AUTO = 'auto'
"""The value of an ``auto`` parameter that the loop measures itself (:class:`ParameterSpec`)."""
SWINGUP = 'swingup'
STABILIZER = 'stabilizer'
KINDS = (SWINGUP, STABILIZER)


@dataclass(frozen=True)
class ParameterSpec:
    """One tunable of a controller, declared as the ROS parameter ``<name>.<spec.name>``.

    ``default`` fixes the type: float, int, bool, str or a tuple of floats
    (a double array). ``low``/``high`` bound numbers (and every element of a
    double array); ``length`` fixes the length of a double array. With
    ``auto`` the parameter is a number in ``[low, high]`` or the string
    ``'auto'`` (a value the loop measures itself); its default is ``'auto'``.
    """

    name: str
    default: Any
    description: str
    low: float | None = None
    high: float | None = None
    length: int | None = None
    choices: tuple[str, ...] | None = None
    auto: bool = False

    def validate(self, value: Any) -> Any:
        """Return ``value`` converted to this parameter's type, or raise ValueError with the reason."""
        d = self.default
        if self.auto:
            if isinstance(value, str):
                if value != AUTO:
                    raise ValueError(f"{self.name} must be 'auto' or a number, got {value!r}")
                return value
            return self._number(value)
        if isinstance(d, bool):
            if not isinstance(value, bool):
                raise ValueError(f'{self.name} must be a bool, got {value!r}')
            return value
        if isinstance(d, str):
            if not isinstance(value, str):
                raise ValueError(f'{self.name} must be a string, got {value!r}')
            if self.choices is not None and value not in self.choices:
                raise ValueError(f'{self.name} must be one of {list(self.choices)}, got {value!r}')
            return value
        if isinstance(d, (tuple, list)):
            if isinstance(value, (str, bytes)) or not isinstance(value, Sequence):
                raise ValueError(f'{self.name} must be a list of numbers, got {value!r}')
            values = tuple(self._number(v) for v in value)
            if self.length is not None and len(values) != self.length:
                raise ValueError(f'{self.name} needs {self.length} numbers, got {len(values)}')
            return values
        number = self._number(value)
        if isinstance(d, int):
            if number != int(number):
                raise ValueError(f'{self.name} must be an integer, got {value!r}')
            return int(number)
        return number

    def _number(self, value: Any) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ValueError(f'{self.name} must be a number, got {value!r}')
        value = float(value)
        if not math.isfinite(value):
            raise ValueError(f'{self.name} must be finite, got {value!r}')
        if self.low is not None and value < self.low:
            raise ValueError(f'{self.name} = {value:g} is below its minimum {self.low:g}')
        if self.high is not None and value > self.high:
            raise ValueError(f'{self.name} = {value:g} is above its maximum {self.high:g}')
        return value


@dataclass(frozen=True)
class ControllerState:
    """The estimated state a controller acts on (from the EKF), at time ``t``.

    ``theta`` may be unwrapped; laws that need the wrapped angle use
    :attr:`theta_w`. ``x_ddot``/``theta_ddot`` are the model accelerations at
    the estimate under the last applied force (what (7.10) needs).
    """

    t: float
    x: float
    theta: float
    x_dot: float
    theta_dot: float
    x_ddot: float = 0.0
    theta_ddot: float = 0.0

    @property
    def theta_w(self) -> float:
        """theta wrapped to (-pi, pi]."""
        return wrap_angle(self.theta)


@dataclass(frozen=True)
class ControlContext:
    """What every controller may know about the loop it runs in."""

    plant: CartPoleParameters
    """The controller's model of the plant (nominal parameters, not the truth)."""
    x_ref: float
    """Cart reference x* [m]."""
    sample_time: float
    """Control period Ts [s]."""
    feedforward: FrictionFeedforward = FrictionFeedforward()
    """The cart friction feedforward (6.12) the manager adds to every raw
    output; a law whose plan already pays for friction subtracts it."""
    real_time: bool = True
    """The loop runs in real time and never waits: slow work a plugin finds missing
    (a plan) is started in the background. False for batch and lockstep runs,
    which call :meth:`Controller.prepare` before their first cycle: nothing is
    started in the background then."""
    rail_margin: float = 0.02
    """The distance the manager's rail guard keeps from each end stop [m]
    (``rail.margin``); a law that plans the cart's path keeps it inside
    ``[rail_margin, travel - rail_margin]``."""
    rail_reserve: float = 0.05
    """How much further in the guard's limiter starts bending a moving cart's
    command (``rail.limit_reserve``) [m]."""
    pendulum: 'NaturalFrequencyEstimator | None' = None
    """The manager's on-line estimate of the pendulum's natural frequency and the
    energy (7.3) and target (6.8) it gives (:mod:`cartpole_control.natural_frequency`);
    updated by the manager while the plugin runs. None outside a manager: the
    energy laws then use the nominal model."""
    plant_estimate: 'PlantEstimate | None' = None
    """The manager's estimate of the plant (:class:`~cartpole_control.plant_estimate.PlantEstimate`):
    the actuator's gain, dead time and the force limits at the cart
    (:meth:`~cartpole_control.plant_estimate.PlantEstimate.force_limits`), the
    unmodelled force on the cart, the pendulum's omega_0^2 and the plant they give
    (:meth:`~cartpole_control.plant_estimate.PlantEstimate.estimated_plant`);
    updated by the manager every cycle. None outside a manager."""
    rail_guard: 'GuardView | None' = None
    """The manager's rail guard (:class:`~cartpole_control.rail_guard.GuardView`): the force it
    passes unchanged at a state, which a law that plans its forces takes as its first move's
    bounds. None outside a manager: every force passes."""
    validation_only: bool = False
    """True when the manager configures a scratch instance only to check a
    change of gains (it is never activated): do no expensive or side-effecting
    work then (no background solves, no files), just refuse bad gains."""


@dataclass(frozen=True)
class CommandFeedback:
    """What the manager did with the active plugin's raw force in one cycle.

    The input of the anti-windup of every integrator (conditional
    integration): an integrator must not grow while its push does not reach
    the cart.
    """

    raw: float
    """The plugin's force u of this cycle [N]."""
    force: float
    """The force command sent to the actuator [N], after the feedforward (6.12),
    the saturation to [force_min, force_max] (Appendix C) and the rail guard."""
    limited: int
    """+1 if the command was cut from above (saturated at force_max, or the rail
    guard withheld a push to the right), -1 if cut from below, 0 if it passed:
    the sign of ``u + B_ff(x_dot, u) - force``."""
    held: bool = False
    """The force is not the law's at all (the rail guard brakes or holds the
    cart): every integrator keeps its value."""

    def blocks(self, effect: float) -> bool:
        """True if an increment changing the force by ``effect`` [N] must not be taken.

        That is while the force is held, or while the command is limited in
        the direction the increment would push it further.
        """
        return self.held or self.limited * effect > 0.0


class Controller(ABC):
    """Base class of every swing-up law and stabiliser plugin.

    Subclasses set :attr:`kind` and :attr:`name`, list their tunables in
    :attr:`parameters`, and implement :meth:`update`. The lifecycle is:
    ``configure`` (on a new instance, outside the control cycle; the manager
    swaps configured instances in between cycles), ``activate`` (bumpless,
    from the current state) or :meth:`take_over` (new gains while running),
    ``update`` once per cycle, each followed by the manager's
    :meth:`command_applied`, ``deactivate``. Subclasses put their start and
    stop work into :meth:`on_activate` / :meth:`on_deactivate`.
    """

    api_version: ClassVar[int] = API_VERSION
    kind: ClassVar[str] = ''
    name: ClassVar[str] = ''
    parameters: ClassVar[tuple[ParameterSpec, ...]] = ()
    running_state: ClassVar[tuple[str, ...]] = ()
    """Attributes that carry a run (integrators, step clocks), handed on by :meth:`take_over`."""

    _TEMPLATE_METHODS: ClassVar[dict[str, str]] = {'activate': 'on_activate',
                                                   'deactivate': 'on_deactivate'}

    def __init_subclass__(cls, **kwargs: Any) -> None:
        """Refuse a subclass that overrides a template method instead of its hook."""
        super().__init_subclass__(**kwargs)
        for method, hook in Controller._TEMPLATE_METHODS.items():
            if method in vars(cls):
                raise TypeError(f'{cls.__module__}.{cls.__qualname__} overrides {method}(); '
                                f'override {hook}() instead ({method}() keeps the manager\'s '
                                f'bookkeeping and calls it)')

    def __init__(self) -> None:
        self.gains: dict[str, Any] = {spec.name: spec.default for spec in self.parameters}
        self.context: ControlContext | None = None
        self.active = False

    @classmethod
    def defaults(cls) -> dict[str, Any]:
        return {spec.name: spec.default for spec in cls.parameters}

    @classmethod
    def validate_gains(cls, gains: Mapping[str, Any]) -> dict[str, Any]:
        """Validated copy of ``gains`` (a subset is fine); raise ValueError with the reason."""
        specs = {spec.name: spec for spec in cls.parameters}
        out = {}
        for key, value in gains.items():
            if key not in specs:
                raise ValueError(f'{cls.name} has no parameter {key!r}; it has {sorted(specs)}')
            out[key] = specs[key].validate(value)
        return out

    def configure(self, gains: Mapping[str, Any], context: ControlContext) -> None:
        """Take new gains (validated first; nothing changes on error) and the loop context.

        Subclasses recompute derived quantities in :meth:`on_configure`,
        which may also raise ValueError to refuse a combination of gains.
        """
        new = dict(self.gains)
        new.update(self.validate_gains(gains))
        old_gains, old_context = self.gains, self.context
        self.gains, self.context = new, context
        try:
            self.on_configure()
        except Exception:
            self.gains, self.context = old_gains, old_context
            if old_context is not None:
                self.on_configure()
            raise

    def on_configure(self) -> None:
        """Recompute derived quantities from :attr:`gains` and :attr:`context`."""

    @classmethod
    def prepare(cls, gains: Mapping[str, Any], context: ControlContext, start: ControllerState,
                progress: Callable[[str], None] | None = None) -> dict[str, Any]:
        """Do the slow work a run from ``start`` needs before it starts; may block for long.

        Batch and lockstep runs call it once before their first cycle (a
        real-time loop never waits for it), with the run's ``gains`` and
        ``context``. Returns the gain changes that make the run's instance
        use that work (e.g. the start to load a plan for); ``progress``
        takes one-line messages for the user. Default: nothing to do.
        """
        return {}

    @property
    def adaptive_target(self) -> bool:
        """The swing-up aims at the energy target of the estimated pendulum
        (:attr:`ControlContext.pendulum`), and the catch trigger (6.4) with it:
        the plugin's ``adaptive_target`` gain (the energy laws have one), else False
        (the nominal E* (6.8))."""
        return bool(self.gains.get('adaptive_target', False))

    @property
    def law(self) -> str:
        """What produces the output now (``swingup_law`` of the status and summary).

        The plugin's name; a plugin that switches between laws says which,
        as ``<name>:<law>`` (e.g. ``time_optimal:plan``,
        ``time_optimal:fallback(no plan)``). Read every cycle: keep it cheap.
        """
        return self.name

    @final
    def activate(self, state: ControllerState) -> None:
        """Start from ``state``: mark the plugin active, then call :meth:`on_activate`.

        Not to be overridden (see :meth:`__init_subclass__`). The plugin is
        marked active before its hook runs, so that a hook that raises still
        leaves a plugin the manager deactivates.
        """
        self.active = True
        self.on_activate(state)

    def on_activate(self, state: ControllerState) -> None:
        """Start from ``state`` without a bump (reset integrators, filters). Default: nothing."""

    def take_over(self, previous: 'Controller', state: ControllerState) -> None:
        """Go on with the run of ``previous`` (this plugin, other gains) from ``state``.

        The manager calls it between two cycles when new gains of the running
        plugin are applied: this instance was built and configured with them
        outside the cycle, ``previous`` is deactivated. The run goes on as a
        reconfiguration in place would let it: activated, then the
        :attr:`running_state` attributes of ``previous`` taken over (the
        integrators keep their values). Must be cheap (it runs in the cycle).
        """
        self.activate(state)
        for attribute in self.running_state:
            setattr(self, attribute, getattr(previous, attribute))

    @abstractmethod
    def update(self, state: ControllerState) -> float:
        """The law's raw force [N] for ``state`` (before feedforward and saturation)."""

    def command_applied(self, feedback: CommandFeedback) -> None:
        """What became of the force of the last :meth:`update` (the anti-windup's input).

        Called by the manager once after every update of the active plugin,
        in the same cycle. The default does nothing; a law with an integrator
        takes back the increment of this cycle when
        ``feedback.blocks(effect)`` (see :class:`CommandFeedback`). A plugin
        used without the manager simply never hears of it.
        """

    def standby(self) -> None:
        """Work ahead for an activation, in pieces (the configured stabiliser, while the
        swing-up runs): the manager calls it between two cycles, after the command is out
        (:meth:`.manager.ControllerManager.between_cycles`); each call must stay well inside
        a sample time. Not a promise: activation still works without it. Default: nothing."""

    def status_values(self) -> Mapping[str, float]:
        """Figures of the running law for the controller status and the run summary.

        Plain numbers by name (e.g. ``{'mpc_solve_us': 212.0, 'mpc_fallbacks': 0}``),
        read by the manager once per cycle after :meth:`update`: keep it
        cheap. Default: none.
        """
        return {}

    @final
    def deactivate(self) -> None:
        """Stop: call :meth:`on_deactivate`, then mark the plugin inactive (even if the hook raises).

        Not to be overridden (see :meth:`__init_subclass__`).
        """
        try:
            self.on_deactivate()
        finally:
            self.active = False

    def on_deactivate(self) -> None:
        """Stop work started by :meth:`on_activate` (e.g. a fall-back law). Default: nothing."""
