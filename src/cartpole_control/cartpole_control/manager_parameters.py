"""The controller manager's own parameters (chapter 6): catch, feedforward, rail guard, prediction.

The declarations :class:`~cartpole_control.manager.ControllerManager` checks
every change against (and the node declares as ROS parameters); the plugin
choice and the plugins' own parameters are added by the manager from its
registry.

No ROS import.
"""
from __future__ import annotations

import dataclasses
import logging
from typing import Mapping

from cartpole_core.model import CartPoleParameters

from .controller import AUTO, KINDS, STABILIZER, SWINGUP, Controller, ParameterSpec
from .rail_guard import ACTUATOR_DEAD_TIME, RESERVE_TIME
from .registry import load_controllers

logger = logging.getLogger(__name__)

DEFAULT_CONTROLLERS = {SWINGUP: 'pendulum_energy', STABILIZER: 'lqg'}
"""Default plugins (the thesis's pairing in section 9.2.1)."""

LOCKSTEP_WAIT_RANGE = (0.001, 10.0)
"""[wall s] The range of the node's read-only ``lockstep_wait`` (manager_node)."""

MANAGER_PREFIXES = ('actuator', 'catch', 'fall', 'feedforward', 'predict', 'rail')
"""Parameter groups of the manager itself; a plugin cannot take these names."""


def checked_registry(registry: Mapping[str, Mapping[str, type[Controller]]] | None
                     ) -> dict[str, dict[str, type[Controller]]]:
    """The plugins by kind and name; None discovers the installed ones (their entry points).

    A plugin named like a manager parameter or like a plugin of the other kind
    is skipped with a warning; ValueError if a kind has none left.
    """
    reserved = set(MANAGER_PREFIXES) | {'swingup', 'stabilizer', 'enabled', 'x_ref',
                                        'state_timeout'}
    out: dict[str, dict[str, type[Controller]]] = {}
    taken: dict[str, type[Controller]] = {}
    for kind in KINDS:
        found = load_controllers(kind) if registry is None else dict(registry.get(kind, {}))
        out[kind] = {}
        for name, cls in sorted(found.items()):
            # One name in both groups is one plugin in two roles (a learned policy): allowed
            # when both declare the same parameters, the one set of `<name>.<param>`.
            if name in reserved or (name in taken and taken[name].parameters != cls.parameters):
                logger.warning('skipping %s controller %r: the name is taken', kind, name)
                continue
            taken[name] = cls
            out[kind][name] = cls
        if not out[kind]:
            raise ValueError(f'no {kind} controller is registered (entry-point group '
                             f'cartpole_control.{kind}); run `make build`?')
    return out


def parameter_specs(p: CartPoleParameters, ts: float,
                    registry: Mapping[str, Mapping[str, type[Controller]]]
                    ) -> dict[str, ParameterSpec]:
    """Every parameter by full name: the plugin choice, the manager's own, each plugin's."""
    specs: list[ParameterSpec] = []
    for kind, title in ((SWINGUP, 'Swing-up law (chapter 7)'),
                        (STABILIZER, 'Stabiliser (chapter 8)')):
        names = tuple(registry[kind])
        default = DEFAULT_CONTROLLERS[kind] if DEFAULT_CONTROLLERS[kind] in names else names[0]
        specs.append(ParameterSpec(kind, default, f'{title}: one of the registered plugins '
                                   f'{list(names)}; switched bumplessly between two cycles',
                                   choices=names))
    specs += manager_parameter_specs(p, ts)
    out = {spec.name: spec for spec in specs}
    for kind in KINDS:
        for name, cls in registry[kind].items():
            for spec in cls.parameters:
                full = f'{name}.{spec.name}'
                out[full] = dataclasses.replace(spec, name=full)
    return out


def manager_parameter_specs(p: CartPoleParameters, ts: float) -> list[ParameterSpec]:
    """The manager's parameters for plant ``p`` and sample time ``ts`` [s]."""
    return [
        ParameterSpec('enabled', True, 'Control on; false: idle, zero force. Setting it true '
                      'again restarts the swing-up (and clears a fault).'),
        ParameterSpec('x_ref', p.x_middle, 'Cart reference x* [m] from the left end stop; '
                      'default the middle of the travel', low=round(0.1 * p.travel, 6),
                      high=round(0.9 * p.travel, 6)),
        ParameterSpec('catch.energy_tolerance', 0.05, 'Catch trigger (6.4): switch to the '
                      'stabiliser when |E* - E_p| <= this times E*', low=0.001, high=1.0),
        ParameterSpec('catch.angle_deg', 30.0, 'Catch trigger (6.4): and |theta_w| <= this '
                      '[deg]', low=1.0, high=90.0),
        ParameterSpec('catch.region', True, 'Catch only where the stabiliser can hold it: '
                      'inside the (6.4) window, wait until the LQR of the estimated plant, under '
                      'the force the amplifier delivers, settles the pendulum from the state in '
                      'a simulated catch (cartpole_control.catch_region); false: (6.4) alone'),
        ParameterSpec('fall.angle_deg', 45.0, 'Fall detector: while stabilising, |theta_w| '
                      'beyond this [deg] hands back to swing-up; larger than catch.angle_deg',
                      low=2.0, high=180.0),
        ParameterSpec('feedforward.right', 3.3, 'Cart friction feedforward (6.12): c_c,R used '
                      'while x_dot >= 0 [N] (thesis 9.2.1: 3.3)', low=0.0, high=20.0),
        ParameterSpec('feedforward.left', 2.8, 'Cart friction feedforward (6.12): c_c,L used '
                      'while x_dot < 0 [N] (thesis 9.2.1: 2.8)', low=0.0, high=20.0),
        ParameterSpec('feedforward.steepness', 20.0, 'k of tanh(k u) in (6.12) [1/N]; 0 turns '
                      'the feedforward off', low=0.0, high=1000.0),
        ParameterSpec('feedforward.velocity_band', 0.0005, 'Cart friction feedforward while '
                      'stabilising: above this |x_dot| [m/s] the kinetic friction is '
                      'compensated along the velocity, below it blended into (6.12); '
                      '0 = (6.12) at every speed', low=0.0, high=1.0),
        ParameterSpec('rail.margin', 0.02, 'Rail guard: distance kept from each end stop [m]',
                      low=0.0, high=0.15),
        ParameterSpec('rail.max_brake_force', 30.0, 'Rail guard: braking force F_b [N], '
                      'further limited by the amplifier', low=1.0, high=40.0),
        ParameterSpec('rail.latency', ts, 'Rail guard: loop latency before a command acts [s]',
                      low=0.0, high=0.1),
        ParameterSpec('rail.rest_speed', 0.02, 'Rail guard: |x_dot| below which the cart is at '
                      'rest [m/s]', low=0.001, high=0.5),
        ParameterSpec('rail.creep_speed', 0.1, 'Rail guard: inside a margin a cart slower '
                      'than this counts as at rest [m/s] (the noisy velocity of a cart '
                      'resting at a stop)', low=0.0, high=0.5),
        ParameterSpec('rail.limit', True, 'Rail guard: limit the command of a moving cart to '
                      'the braking envelope before tripping (false: trip at once)'),
        ParameterSpec('rail.limit_reserve', 0.05, 'Rail guard: the limiter keeps the '
                      'stopping position this much further from the stops than the trip '
                      'test [m]', low=0.0, high=0.3),
        ParameterSpec('rail.reserve_time', RESERVE_TIME, 'Rail guard: while the stabiliser '
                      'balances, the limiter\'s reserve is the distance the cart covers in this '
                      'time, at most rail.limit_reserve (an unmodelled dead time moves a slow '
                      'cart\'s stop by little; at rest the margin alone) [s]; 0 = the whole '
                      'reserve at every speed', low=0.0, high=1.0),
        ParameterSpec('rail.actuator_dead_time', ACTUATOR_DEAD_TIME, 'Rail guard: the '
                      "actuator's dead time beyond the reported latency (a lag) that the braking "
                      'envelope assumes until the plant estimate has measured it (with actuator.delay '
                      'auto; a number there counts as measured) [s]', low=0.0, high=0.2),
        ParameterSpec('predict.horizon', AUTO, 'Delay compensation: the controllers and the '
                      'catch trigger see the estimate predicted this far ahead under the '
                      'commands in flight (cartpole_control.prediction) [s]; auto = the '
                      "loop's latency measured from the plant's reports of when each command "
                      'took effect (0 until 20 reports; a plant that reports nothing: 0); a '
                      'number fixes it, 0 = off', low=0.0, high=0.1, auto=True),
        ParameterSpec('actuator.gain', AUTO, 'Actuator gain G: the force the cart feels per '
                      'newton commanded [1]; the command is the wanted force divided by G (and '
                      'the prediction multiplies by it); auto = estimated from the cart\'s '
                      'motion under large commands (cartpole_control.actuator; 1 until then); '
                      '1 = the model\'s actuator (4.4)', low=0.4, high=2.5, auto=True),
        ParameterSpec('actuator.delay', AUTO, 'Actuator dead time after the plant applied a '
                      'command (a lag the plant cannot report) [s], added to the prediction '
                      'horizon; auto = estimated with the gain (0 until then); 0 = none',
                      low=0.0, high=0.1, auto=True),
        ParameterSpec('actuator.disturbance', AUTO, 'Unmodelled force on the cart that the '
                      'swing-up cancels [N, positive to the right]; auto = the estimate of the '
                      'plant estimate (cartpole_control.plant_estimate) beyond a 1 N band, at '
                      'most 10 N; 0 = none', low=-20.0, high=20.0, auto=True),
        ParameterSpec('actuator.friction', AUTO, "Scale of the cart's friction feedforward "
                      '(6.12) [1]; auto = the friction scale estimated with the gain '
                      '(cartpole_control.actuator), 1 within 10 % of the model; 1 = the '
                      "model's friction (4.20)", low=0.3, high=3.0, auto=True),
        ParameterSpec('state_timeout', 0.05, 'No state for this long while the manager '
                      'runs (a stall of its own process does not count; in lockstep at least '
                      "lockstep_wait): zero force, fault 'stale state' [s]",
                      low=round(1.2 * ts, 9), high=10.0),
    ]
