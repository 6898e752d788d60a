"""One simulated run's start, plant uncertainties and disturbances: :class:`Scenario`.

The same object configures the offline loop (``cartpole offline``), the simulator node
(``cartpole run --sim``) and the device emulator (``cartpole emulate``), and
:class:`~cartpole_sim.plant.Plant` applies it, so the three see the same plant. Every
disturbance is off by default (the thesis procedure of Appendix H, a perfect rig), and
every random one draws from its own generator seeded from ``seed``: the same scenario
gives the same run bit for bit, and switching one disturbance on leaves the draws of the
others as they were.

Where each acts on Figure 2.2's signal path: ``delay``/``jitter`` between the sample and
the amplifier (a FIFO, inside the plant's sample-and-hold); ``drop`` on the sample's way
to the host; ``actuator_gain`` and ``actuator_tau`` (a lag ahead of the current loop
(4.4)) in the amplifier; ``force_noise`` and ``pushes`` on the cart or the pendulum;
``tip_mass``, ``cart_mass``, ``friction_scale``, ``parameter_scales`` in the true plant,
which the EKF and the controllers do not know. Each option's range and meaning:
(docs/simulator.md, "Disturbances").
"""
from __future__ import annotations

import dataclasses
import math
import numbers
from dataclasses import dataclass

from cartpole_core.model import CartPoleParameters

DELAY_MAX = 0.04
"""[s] Largest sensor-to-actuator delay (and largest jitter) a scenario takes."""
ACTUATOR_TAU_MAX = 1.0
"""[s] Largest extra amplifier time constant a scenario takes."""
DROP_MAX = 0.99
"""Largest probability of a lost sample: one sample in a hundred still arrives, so the
simulator's lockstep (which steps past each lost sample at once) never spins on lost ones."""
POSITION_MAX = 100.0
"""[m] Largest |initial cart position| (the rail check needs the plant's travel: the caller's)."""
ANGLE_MAX = 100.0
"""[rad] Largest |initial angle| and |encoder offset| (about 16 turns)."""
SPEED_MAX = 1000.0
"""[m/s, rad/s] Largest |initial velocity|."""
MASS_MAX = 1000.0
"""[kg] Largest tip or cart mass."""
SCALE_MAX = 1000.0
"""Largest friction scale, amplifier gain error and parameter scale."""
FORCE_MAX = 1.0e4
"""[N, N m] Largest force noise std and push amplitude."""
TIME_MAX = 1.0e6
"""[s] Latest push start and longest push."""
PUSH_TARGETS = ('cart', 'pendulum')


def _finite(name: str, value: float, low: float | None = None, high: float | None = None,
            low_open: bool = False, high_open: bool = False) -> None:
    """ValueError naming ``name`` unless ``value`` is a finite number in the range."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ValueError(f'{name} must be a finite number, got {value!r}')
    if low is not None and (value <= low if low_open else value < low):
        raise ValueError(f'{name} must be {">" if low_open else ">="} {low:g}, got {value!r}')
    if high is not None and (value >= high if high_open else value > high):
        raise ValueError(f'{name} must be {"<" if high_open else "<="} {high:g}, got {value!r}')


@dataclass(frozen=True)
class Push:
    """A rectangular pulse: ``amplitude`` from time ``t`` for ``width`` seconds.

    On the ``cart`` an extra force [N], positive to the right; on the
    ``pendulum`` a torque [N m] about the joint, positive towards increasing
    theta (it leans the pendulum left): a generalised force on theta in the
    equations of motion (4.17). The impulse is ``amplitude * width`` [N s] or
    [N m s].
    """

    t: float
    target: str
    amplitude: float
    width: float

    def __post_init__(self) -> None:
        if self.target not in PUSH_TARGETS:
            raise ValueError(f'push target must be one of {PUSH_TARGETS}, got {self.target!r}')
        _finite('push time', self.t, 0.0, TIME_MAX)
        _finite('push amplitude', self.amplitude, -FORCE_MAX, FORCE_MAX)
        _finite('push width', self.width, 0.0, TIME_MAX, low_open=True)

    @property
    def impulse(self) -> float:
        return self.amplitude * self.width

    def __str__(self) -> str:
        """``T:TARGET:AMPLITUDE:WIDTH``, exact (:func:`parse_push` gives this push back)."""
        return f'{self.t!r}:{self.target}:{self.amplitude!r}:{self.width!r}'


def parse_push(text: str) -> Push:
    """``T:TARGET:AMPLITUDE:WIDTH`` (e.g. ``12:cart:10:0.1``) as a :class:`Push`; ValueError if bad."""
    parts = str(text).split(':')
    if len(parts) != 4:
        raise ValueError(f'a push is T:TARGET:AMPLITUDE:WIDTH (e.g. 12:cart:10:0.1), got {text!r}')
    t, target, amplitude, width = parts
    try:
        values = float(t), float(amplitude), float(width)
    except ValueError:
        raise ValueError(f'a push is T:TARGET:AMPLITUDE:WIDTH with numbers T, AMPLITUDE, '
                         f'WIDTH, got {text!r}') from None
    return Push(values[0], target.strip().lower(), values[1], values[2])


_FLOAT_PARAMETERS = tuple(f.name for f in dataclasses.fields(CartPoleParameters)
                          if f.type in ('float', float))


@dataclass(frozen=True)
class Scenario:
    """Initial state, plant uncertainties and disturbances of one simulated run.

    The default is the thesis procedure (Appendix H, section 10.1): cart at
    the left end stop, pendulum hanging at rest, encoders reset there, no
    disturbance. Every field is validated on construction (ValueError naming
    it). See the module docstring for where each disturbance acts.
    """

    x0: float = 0.0
    """Initial cart position [m] from the left end stop."""
    theta0: float = math.pi
    """Initial pendulum angle [rad]; pi is hanging."""
    x_dot0: float = 0.0
    theta_dot0: float = 0.0
    tip_mass: float | None = None
    """Tip mass m_p [kg] of the plant; None keeps the parameters' value."""
    friction_scale: float = 1.0
    """Multiplies every cart and pendulum friction coefficient of the plant."""
    encoder_offset: float = 0.0
    """Pendulum angle minus pi when the encoders were reset [rad] (Appendix H):
    the measured angle is biased by minus this much."""
    noise: bool = False
    """Add Gaussian measurement noise before quantisation."""
    noise_std_cart: float = 1.0e-4
    """Cart position noise [m] (about one tick)."""
    noise_std_pendulum: float = 1.5e-3
    """Pendulum angle noise [rad] (about half a tick)."""
    seed: int = 0
    cart_mass: float | None = None
    """Equivalent cart mass m_c [kg] of the plant; None keeps the parameters' value."""
    parameter_scales: tuple[tuple[str, float], ...] = ()
    """(name, factor) pairs: multiply these float fields of the plant's
    parameters (e.g. ``(('l', 1.1),)``), after ``tip_mass``, ``cart_mass``
    and ``friction_scale``."""
    delay: float = 0.0
    """Sensor-to-actuator latency [s], 0 to :data:`DELAY_MAX`."""
    jitter: float = 0.0
    """Extra latency per sample, uniform in [0, jitter] [s], 0 to :data:`DELAY_MAX`."""
    drop: float = 0.0
    """Probability that a sample is lost on the way to the host, 0 to :data:`DROP_MAX`."""
    force_noise: float = 0.0
    """Standard deviation [N] of the force noise on the cart (one draw per sample period)."""
    actuator_gain: float = 1.0
    """Amplifier gain error G: the current is G times the commanded one (before saturation)."""
    actuator_tau: float = 0.0
    """Time constant [s] of an extra first-order lag of the amplifier; 0 = none."""
    pushes: tuple[Push, ...] = ()
    """Rectangular pushes on the cart or the pendulum (:class:`Push`)."""

    def __post_init__(self) -> None:
        _finite('x0', self.x0, -POSITION_MAX, POSITION_MAX)
        for name in ('theta0', 'encoder_offset'):
            _finite(name, getattr(self, name), -ANGLE_MAX, ANGLE_MAX)
        for name in ('x_dot0', 'theta_dot0'):
            _finite(name, getattr(self, name), -SPEED_MAX, SPEED_MAX)
        _finite('friction_scale', self.friction_scale, 0.0, SCALE_MAX)
        _finite('noise_std_cart', self.noise_std_cart, 0.0, POSITION_MAX)
        _finite('noise_std_pendulum', self.noise_std_pendulum, 0.0, ANGLE_MAX)
        for name in ('tip_mass', 'cart_mass'):
            if getattr(self, name) is not None:
                _finite(name, getattr(self, name), 0.0, MASS_MAX, low_open=True)
        _finite('delay', self.delay, 0.0, DELAY_MAX)
        _finite('jitter', self.jitter, 0.0, DELAY_MAX)
        _finite('drop', self.drop, 0.0, DROP_MAX)
        _finite('force_noise', self.force_noise, 0.0, FORCE_MAX)
        _finite('actuator_gain', self.actuator_gain, 0.0, SCALE_MAX, low_open=True)
        _finite('actuator_tau', self.actuator_tau, 0.0, ACTUATOR_TAU_MAX)
        if isinstance(self.seed, bool) or not isinstance(self.seed, numbers.Integral) \
                or self.seed < 0:
            raise ValueError(f'seed must be an integer >= 0, got {self.seed!r}')
        object.__setattr__(self, 'seed', int(self.seed))
        scales = tuple((str(n), float(f)) for n, f in self.parameter_scales)
        for name, factor in scales:
            if name not in _FLOAT_PARAMETERS:
                raise ValueError(f'parameter_scales: {name!r} is not a float plant parameter; '
                                 f'known: {list(_FLOAT_PARAMETERS)}')
            _finite(f'parameter_scales[{name}]', factor, 0.0, SCALE_MAX)
        object.__setattr__(self, 'parameter_scales', scales)
        pushes = tuple(p if isinstance(p, Push) else parse_push(p) for p in self.pushes)
        object.__setattr__(self, 'pushes', tuple(sorted(pushes, key=lambda p: p.t)))

    @property
    def disturbs_the_hold(self) -> bool:
        """Some disturbance acts inside the sample-and-hold (delay, jitter, force
        noise, extra lag, pushes): the plant then takes its general path."""
        return bool(self.delay or self.jitter or self.force_noise or self.actuator_tau
                    or self.pushes)

    def plant_parameters(self, nominal: CartPoleParameters) -> CartPoleParameters:
        """The plant's true parameters under this scenario."""
        p = nominal.with_scenario(self.tip_mass, self.friction_scale)
        changes: dict[str, float] = {}
        if self.cart_mass is not None:
            changes['m_c'] = float(self.cart_mass)
        for name, factor in self.parameter_scales:
            changes[name] = changes.get(name, getattr(p, name)) * factor
        return p.replace(**changes) if changes else p

    def initial_state(self) -> tuple[float, float, float, float]:
        return (float(self.x0), float(self.theta0), float(self.x_dot0), float(self.theta_dot0))

    def replace(self, **changes) -> 'Scenario':
        """A copy with ``changes`` applied (validated again)."""
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict:
        """Every field as plain JSON/YAML values (:meth:`from_dict` gives this scenario back,
        bit for bit: floats are written with ``repr``, which round-trips exactly)."""
        out = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        out['parameter_scales'] = [[n, f] for n, f in self.parameter_scales]
        out['pushes'] = [dataclasses.asdict(p) for p in self.pushes]
        return out

    @classmethod
    def from_dict(cls, data) -> 'Scenario':
        """The scenario of a mapping such as :meth:`to_dict` writes (missing fields keep
        their defaults); ValueError naming an unknown field or a bad value."""
        if not isinstance(data, dict):
            raise ValueError(f'a scenario is a mapping of its fields, got {type(data).__name__}')
        names = [f.name for f in dataclasses.fields(cls)]
        unknown = sorted(set(data) - set(names))
        if unknown:
            raise ValueError(f'unknown scenario field(s) {unknown}; known: {names}')
        values = dict(data)
        scales = values.get('parameter_scales', ())
        if isinstance(scales, dict):
            scales = list(scales.items())
        if not isinstance(scales, (list, tuple)) or not all(
                isinstance(s, (list, tuple)) and len(s) == 2 for s in scales):
            raise ValueError('parameter_scales must be a list of [name, factor] pairs, '
                             f'got {scales!r}')
        values['parameter_scales'] = tuple((n, f) for n, f in scales)
        pushes = values.get('pushes', ())
        if not isinstance(pushes, (list, tuple)):
            raise ValueError(f'pushes must be a list, got {pushes!r}')
        values['pushes'] = tuple(_push_of(p) for p in pushes)
        return cls(**values)


def _push_of(item) -> Push:
    """A :class:`Push` of a mapping (t, target, amplitude, width) or of ``T:TARGET:A:W``."""
    if isinstance(item, str):
        return parse_push(item)
    keys = ('t', 'target', 'amplitude', 'width')
    if not isinstance(item, dict) or set(item) != set(keys):
        raise ValueError(f'a push is a mapping of {list(keys)}, got {item!r}')
    return Push(**item)
