"""The combined-disturbance range table and its draws: every disturbance at once.

A rig is never wrong in one way only. :class:`RangeTable` holds, per factor,
the interval a run draws it from (uniformly): the plant's parameter errors as
factors on the nominal parameters (so the same table fits identified
parameters), the latency and the amplifier's errors, the encoders' offset,
measurement and force noise, lost samples, and a push on the cart or the
pendulum in a share of the runs. :func:`sample` turns a table and a random
generator (or a seed) into one :class:`~cartpole_sim.scenario.Scenario`;
:func:`factors` reads the drawn values back from a scenario.

The published defaults (``RangeTable()``) are the ones of docs/robustness.md
and of ``share/cartpole_sim/config/combined_ranges.yaml``; :func:`load_ranges`
reads a user's own YAML (the keys it gives replace the defaults, an unknown
key or a bad interval is refused with its name). No rclpy here: the
combined benchmark and the learning environment use the same draws.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

import numpy as np

from cartpole_core.yaml_problem import yaml_problem

from .scenario import DELAY_MAX, DROP_MAX, FORCE_MAX, SCALE_MAX, TIME_MAX, Push, Scenario

Interval = tuple[float, float]

SEED_LIMIT = 2 ** 31
"""A drawn scenario's own seed (its noise, jitter, drops) is below this."""


@dataclass(frozen=True)
class RangeTable:
    """Per factor, the interval [low, high] a run draws it from, uniformly.

    Factors (``cart_mass`` ... ``noise_scale``) multiply the nominal value;
    times are in seconds, angles in radians, forces in N, impulses in N s
    (cart) and N m s (pendulum). A push's sign is drawn too (either way).
    """

    cart_mass: Interval = (0.8, 1.25)
    """Factor on the equivalent cart mass m_c."""
    tip_mass: Interval = (0.7, 1.5)
    """Factor on the tip mass m_p."""
    pendulum_length: Interval = (0.85, 1.15)
    """Factor on the pendulum length l."""
    friction: Interval = (0.6, 1.6)
    """Factor on every cart and pendulum friction coefficient (``friction_scale``)."""
    delay: Interval = (0.0, 0.025)
    """Sensor-to-actuator latency [s]."""
    jitter: Interval = (0.0, 0.005)
    """Extra latency per sample, uniform in [0, jitter]; the jitter bound drawn here [s]."""
    actuator_gain: Interval = (0.7, 1.3)
    """Amplifier gain error G."""
    actuator_lag: Interval = (0.0, 0.030)
    """Time constant of an extra first-order lag of the amplifier [s]."""
    encoder_offset: Interval = (-0.05, 0.05)
    """Angle off hanging where the encoders were reset [rad] (the pendulum starts there)."""
    noise: bool = True
    """Measurement noise on."""
    noise_scale: Interval = (1.0, 1.0)
    """Factor on the nominal measurement noise (0.1 mm cart, 1.5 mrad pendulum)."""
    lost_samples: Interval = (0.0, 0.05)
    """Probability that a sample is lost on its way to the host."""
    force_noise: Interval = (0.0, 3.0)
    """Standard deviation of the force noise on the cart [N]."""
    push_share: float = 2 / 3
    """Share of the runs with one push (YAML takes a fraction such as ``2/3``)."""
    cart_push_share: float = 0.5
    """Of the pushes, the share on the cart; the others on the pendulum."""
    push_time: Interval = (10.0, 15.0)
    """When the push starts [s]: after the catch, before the last 10 s of a 30 s run."""
    cart_push: Interval = (0.0, 3.0)
    """Impulse of a cart push [N s], either way."""
    cart_push_width: float = 0.1
    """Duration of a cart push [s]."""
    pendulum_push: Interval = (0.0, 0.025)
    """Impulse of a pendulum push [N m s], either way."""
    pendulum_push_width: float = 0.05
    """Duration of a pendulum push [s]."""

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if f.name == 'noise':
                if not isinstance(value, bool):
                    raise ValueError(f'ranges: noise must be true or false, got {value!r}')
            elif f.name in _SINGLE:
                object.__setattr__(self, f.name, _number(f.name, value, *_SINGLE[f.name]))
            else:
                object.__setattr__(self, f.name, _interval(f.name, value, *_BOUNDS[f.name]))

    def to_dict(self) -> dict:
        """Plain values (intervals as lists), as :func:`dump_ranges` writes them."""
        return {f.name: (list(v) if isinstance(v := getattr(self, f.name), tuple) else v)
                for f in dataclasses.fields(self)}

    @classmethod
    def from_dict(cls, data) -> 'RangeTable':
        """The defaults with the given keys replaced; ValueError naming a bad or unknown key."""
        if data is None:
            data = {}
        if not isinstance(data, dict):
            raise ValueError(f'ranges: a mapping of factor: [low, high] is needed, got '
                             f'{type(data).__name__}')
        names = [f.name for f in dataclasses.fields(cls)]
        unknown = sorted(str(k) for k in set(data) - set(names))
        if unknown:
            raise ValueError(f'ranges: unknown factor(s) {unknown}; known: {names}')
        return cls(**data)


_BOUNDS: dict[str, tuple[float, float]] = {
    'cart_mass': (0.0, SCALE_MAX), 'tip_mass': (0.0, SCALE_MAX),
    'pendulum_length': (0.0, SCALE_MAX), 'friction': (0.0, SCALE_MAX),
    'delay': (0.0, DELAY_MAX), 'jitter': (0.0, DELAY_MAX), 'actuator_gain': (0.0, SCALE_MAX),
    'actuator_lag': (0.0, 1.0), 'encoder_offset': (-math.pi, math.pi),
    'noise_scale': (0.0, SCALE_MAX), 'lost_samples': (0.0, DROP_MAX),
    'force_noise': (0.0, FORCE_MAX), 'push_time': (0.0, TIME_MAX),
    'cart_push': (0.0, FORCE_MAX), 'pendulum_push': (0.0, FORCE_MAX),
}
"""Each interval's admissible [low, high] (those of :class:`Scenario`); a factor must be > 0."""
_POSITIVE = ('cart_mass', 'tip_mass', 'pendulum_length', 'actuator_gain')
_SINGLE: dict[str, tuple[float, float]] = {
    'push_share': (0.0, 1.0), 'cart_push_share': (0.0, 1.0),
    'cart_push_width': (1e-3, 10.0), 'pendulum_push_width': (1e-3, 10.0),
}


def _number(name: str, value, low: float, high: float) -> float:
    if isinstance(value, str):
        try:
            value = float(Fraction(value.strip()))
        except (ValueError, ZeroDivisionError):
            raise ValueError(f'ranges: {name} must be a number or a fraction such as 2/3, '
                             f'got {value!r}') from None
    if isinstance(value, bool) or not isinstance(value, (int, float)) \
            or not math.isfinite(value) or not low <= value <= high:
        raise ValueError(f'ranges: {name} must be a number in [{low:g}, {high:g}], '
                         f'got {value!r}')
    return float(value)


def _interval(name: str, value, low: float, high: float) -> Interval:
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        raise ValueError(f'ranges: {name} must be [low, high], got {value!r}')
    a, b = (_number(name, v, low, high) for v in value)
    if a > b:
        raise ValueError(f'ranges: {name} must have low <= high, got [{a:g}, {b:g}]')
    if name in _POSITIVE and a <= 0.0:
        raise ValueError(f'ranges: {name} is a factor and must be > 0, got [{a:g}, {b:g}]')
    return (a, b)


def load_ranges(path: str | Path) -> RangeTable:
    """A range table from a YAML file; ValueError naming the file and what is wrong."""
    import yaml

    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text())
    except OSError as error:
        raise ValueError(f'{path}: cannot read the ranges file ({error.strerror})') from None
    except yaml.YAMLError as error:
        raise ValueError(f'{path}: not valid YAML ({yaml_problem(error)})') from None
    try:
        return RangeTable.from_dict(data)
    except (TypeError, ValueError) as error:
        raise ValueError(f'{path}: {error}') from None


def dump_ranges(table: RangeTable) -> str:
    """The table as YAML text (:func:`load_ranges` reads it back to an equal table)."""
    lines = []
    for name, value in table.to_dict().items():
        text = 'true' if value is True else 'false' if value is False else (
            f'[{value[0]!r}, {value[1]!r}]' if isinstance(value, list) else repr(value))
        lines.append(f'{name}: {text}')
    return '\n'.join(lines) + '\n'


def _uniform(rng: np.random.Generator, interval: Interval) -> float:
    low, high = interval
    return float(rng.uniform(low, high)) if high > low else float(low)


def sample(table: RangeTable, rng: np.random.Generator | int) -> Scenario:
    """One scenario with every factor of ``table`` drawn at once.

    ``rng`` is a numpy Generator (e.g. a gymnasium environment's
    ``np_random``) or a seed. The draws come in a fixed order, a fixed number
    of them whatever the values, so the same generator state gives the same
    scenario. The start is the thesis procedure's (left stop, at rest) with
    the pendulum ``encoder_offset`` off hanging, where the encoders were reset.
    """
    if not isinstance(rng, np.random.Generator):
        rng = np.random.default_rng(rng)
    u = rng.uniform
    cart_mass, tip_mass, length, friction = (_uniform(rng, getattr(table, n)) for n in (
        'cart_mass', 'tip_mass', 'pendulum_length', 'friction'))
    delay, jitter, gain, lag, offset, noise_scale, drop, force_noise = (
        _uniform(rng, getattr(table, n)) for n in (
            'delay', 'jitter', 'actuator_gain', 'actuator_lag', 'encoder_offset', 'noise_scale',
            'lost_samples', 'force_noise'))
    pushed, on_cart, sign = u() < table.push_share, u() < table.cart_push_share, u() < 0.5
    push_time = _uniform(rng, table.push_time)
    impulse = _uniform(rng, table.cart_push if on_cart else table.pendulum_push)
    seed = int(rng.integers(SEED_LIMIT))
    pushes = ()
    if pushed and impulse > 0.0:
        width = table.cart_push_width if on_cart else table.pendulum_push_width
        pushes = (Push(push_time, 'cart' if on_cart else 'pendulum',
                       (impulse if sign else -impulse) / width, width),)
    scales = tuple((n, f) for n, f in (('m_c', cart_mass), ('m_p', tip_mass), ('l', length))
                   if f != 1.0)
    return Scenario(theta0=math.pi + offset, encoder_offset=offset, friction_scale=friction,
                    parameter_scales=scales, noise=table.noise,
                    noise_std_cart=Scenario.noise_std_cart * noise_scale,
                    noise_std_pendulum=Scenario.noise_std_pendulum * noise_scale,
                    seed=seed, delay=delay, jitter=jitter, drop=drop, force_noise=force_noise,
                    actuator_gain=gain, actuator_tau=lag, pushes=pushes)


FACTORS = ('cart_mass', 'tip_mass', 'pendulum_length', 'friction', 'delay', 'jitter',
           'actuator_gain', 'actuator_lag', 'encoder_offset', 'lost_samples', 'force_noise',
           'cart_push', 'pendulum_push')
"""The drawn factors :func:`factors` reports (the failure-by-factor plot's panels)."""


def factors(scenario: Scenario) -> dict[str, float]:
    """The value of each of :data:`FACTORS` in ``scenario`` (1.0 for an unscaled parameter,
    0.0 for no push; a push's impulse signed, [N s] on the cart, [N m s] on the pendulum)."""
    scales = dict(scenario.parameter_scales)
    impulses = {'cart': 0.0, 'pendulum': 0.0}
    for push in scenario.pushes:
        impulses[push.target] += push.impulse
    return {'cart_mass': scales.get('m_c', 1.0), 'tip_mass': scales.get('m_p', 1.0),
            'pendulum_length': scales.get('l', 1.0), 'friction': scenario.friction_scale,
            'delay': scenario.delay, 'jitter': scenario.jitter,
            'actuator_gain': scenario.actuator_gain, 'actuator_lag': scenario.actuator_tau,
            'encoder_offset': scenario.encoder_offset, 'lost_samples': scenario.drop,
            'force_noise': scenario.force_noise, 'cart_push': impulses['cart'],
            'pendulum_push': impulses['pendulum']}
