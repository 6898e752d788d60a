"""Per-episode randomisation of the plant: every disturbance at once, from a range table.

The table is the combined-disturbance benchmark's (docs/robustness.md, issue
"Robust when everything is a little wrong"): each run draws every factor at
once from moderate, physical ranges, never from the robustness grid's levels.
:data:`DEFAULT_TABLE` holds the published ranges; a user trains for their own
rig with their own table (``cartpole train --ranges FILE.yaml``, the same
keys, e.g. narrower around identified parameters). :func:`sample` turns one
draw into a :class:`~cartpole_sim.scenario.Scenario`, the object the plant,
the simulator node and the offline loop all take.

Scale factors multiply the nominal parameters (``cart_mass``, ``tip_mass``,
``length``), the others are the scenario's own fields. A push is drawn in
``push_probability`` of the episodes, on the cart or the pendulum with equal
odds, with a uniform impulse up to the table's bound and either sign, as a
rectangle ``push_width`` long starting uniformly in ``push_window`` [s].
"""
from __future__ import annotations

import math
from typing import Any, Mapping

import numpy as np

from cartpole_core.model import CartPoleParameters
from cartpole_sim.scenario import Push, Scenario

DEFAULT_TABLE: dict[str, Any] = {
    'cart_mass': (0.8, 1.25),
    'tip_mass': (0.7, 1.5),
    'length': (0.85, 1.15),
    'friction_scale': (0.6, 1.6),
    'delay': (0.0, 0.025),
    'jitter': (0.0, 0.005),
    'actuator_gain': (0.7, 1.3),
    'actuator_tau': (0.0, 0.03),
    'encoder_offset': (-0.05, 0.05),
    'drop': (0.0, 0.02),
    'force_noise': (0.0, 3.0),
    'push_probability': 2.0 / 3.0,
    'cart_push_impulse': 3.0,
    'pendulum_push_impulse': 0.025,
    'push_width': 0.1,
    'push_window': (2.5, 7.0),
    'noise': True,
}
"""The combined benchmark's ranges: ``(low, high)`` uniform, factors on the nominal plant
for the masses and the length; impulses in N s (cart) and N m s (pendulum)."""

_RANGE_KEYS = ('cart_mass', 'tip_mass', 'length', 'friction_scale', 'delay', 'jitter',
               'actuator_gain', 'actuator_tau', 'encoder_offset', 'drop', 'force_noise',
               'push_window')


def checked_table(table: Mapping[str, Any]) -> dict[str, Any]:
    """``DEFAULT_TABLE`` updated with ``table``; ValueError naming a bad or unknown key."""
    out = dict(DEFAULT_TABLE)
    for key, value in table.items():
        if key not in DEFAULT_TABLE:
            raise ValueError(f'range table: unknown key {key!r}; known: {sorted(DEFAULT_TABLE)}')
        if key in _RANGE_KEYS:
            try:
                low, high = (float(v) for v in value)
            except (TypeError, ValueError):
                raise ValueError(f'range table: {key} must be [low, high], got {value!r}') from None
            if not (math.isfinite(low) and math.isfinite(high) and low <= high):
                raise ValueError(f'range table: {key} must be finite with low <= high, '
                                 f'got {value!r}')
            out[key] = (low, high)
        elif key == 'noise':
            out[key] = bool(value)
        else:
            v = float(value)
            if not (math.isfinite(v) and v >= 0.0):
                raise ValueError(f'range table: {key} must be a number >= 0, got {value!r}')
            out[key] = v
    if out['push_probability'] > 1.0:
        raise ValueError('range table: push_probability must be at most 1')
    return out


def sample(table: Mapping[str, Any], rng: np.random.Generator,
           nominal: CartPoleParameters | None = None, **start: float) -> Scenario:
    """One scenario drawn from ``table`` (see :func:`checked_table`) with ``rng``.

    ``start`` overrides the initial state (``x0``, ``theta0``, ...); by
    default the thesis's start: the cart at the left stop, hanging at rest.
    The scenario's own seed (its noise streams) is drawn from ``rng`` too.
    """
    p = nominal or CartPoleParameters()
    t = table

    def u(key: str) -> float:
        low, high = t[key]
        return float(rng.uniform(low, high))

    fields: dict[str, Any] = dict(
        cart_mass=p.m_c * u('cart_mass'), tip_mass=p.m_p * u('tip_mass'),
        parameter_scales=(('l', u('length')),), friction_scale=u('friction_scale'),
        delay=u('delay'), jitter=u('jitter'), actuator_gain=u('actuator_gain'),
        actuator_tau=u('actuator_tau'), encoder_offset=u('encoder_offset'), drop=u('drop'),
        force_noise=u('force_noise'), noise=bool(t['noise']),
        seed=int(rng.integers(0, 2**31 - 1)))
    if rng.uniform() < t['push_probability']:
        width = float(t['push_width'])
        sign = 1.0 if rng.uniform() < 0.5 else -1.0
        if rng.uniform() < 0.5:
            target, impulse = 'cart', t['cart_push_impulse']
        else:
            target, impulse = 'pendulum', t['pendulum_push_impulse']
        amplitude = sign * float(rng.uniform(0.0, impulse)) / width
        fields['pushes'] = (Push(u('push_window'), target, amplitude, width),)
    fields.update(start)
    return Scenario(**fields)


def draw(table: Mapping[str, Any], rng: np.random.Generator, nominal: CartPoleParameters,
         x_ref: float, upright_start: float) -> Scenario:
    """An episode's scenario: :func:`sample`, started near upright at ``x_ref`` (within
    0.1 m, 0.25 rad, 0.5 rad/s) in a fraction ``upright_start`` of the draws, else from
    the thesis's start (the left stop, hanging)."""
    if rng.uniform() < upright_start:
        return sample(table, rng, nominal, x0=x_ref + float(rng.uniform(-0.1, 0.1)),
                      theta0=float(rng.uniform(-0.25, 0.25)),
                      theta_dot0=float(rng.uniform(-0.5, 0.5)))
    return sample(table, rng, nominal)
