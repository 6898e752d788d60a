"""The scenario's command-line options, one definition for ``cartpole offline``,
``cartpole run --sim`` and ``cartpole emulate`` (docs/simulator.md, "Disturbances").

Here rather than in ``cartpole_bringup`` because the emulator
(``cartpole_hw``) takes them too and must not depend on the bringup package.
"""
from __future__ import annotations

import argparse
import math

from .scenario import DELAY_MAX, DROP_MAX, Scenario, parse_push


def _push(text: str):
    try:
        return parse_push(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def _probability(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'not a number: {text!r}') from None
    if not 0.0 <= value <= DROP_MAX:  # (NaN fails too)
        raise argparse.ArgumentTypeError(f'a probability in [0, {DROP_MAX:g}] is needed, got '
                                         f'{value} (at most {DROP_MAX:g}: some sample must '
                                         'reach the host)')
    return value


def add_scenario_arguments(parser: argparse.ArgumentParser,
                           title: str = 'simulated plant scenario') -> argparse._ArgumentGroup:
    """Add the scenario options (start, plant uncertainties, disturbances) to ``parser``."""
    g = parser.add_argument_group(title)
    g.add_argument('--tip-mass', type=float, default=None, metavar='KG',
                   help='tip mass of the simulated plant (default: the thesis 0.251 kg)')
    g.add_argument('--cart-mass', type=float, default=None, metavar='KG',
                   help='equivalent cart mass of the simulated plant (default: the thesis '
                        '4.75 kg); the EKF and the controllers keep the nominal one')
    g.add_argument('--friction-scale', type=float, default=1.0, metavar='F',
                   help='multiply every cart and pendulum friction coefficient of the plant')
    g.add_argument('--theta0', type=float, default=math.pi, metavar='RAD',
                   help='initial pendulum angle (default pi, hanging)')
    g.add_argument('--x0', type=float, default=0.0, metavar='M',
                   help='initial cart position from the left stop (default 0)')
    g.add_argument('--encoder-offset', type=float, default=0.0, metavar='RAD',
                   help='pendulum angle minus pi when the encoders were reset (Appendix H)')
    g.add_argument('--noise', action='store_true', help='add measurement noise before quantisation')
    g.add_argument('--seed', type=int, default=0,
                   help='seed of every random disturbance (noise, jitter, drops, force noise)')
    g.add_argument('--delay', type=float, default=0.0, metavar='S',
                   help=f'sensor-to-actuator latency, 0-{DELAY_MAX:g} s, fractions of the 5 ms '
                        'sample too: the command computed from a sample takes effect S later')
    g.add_argument('--jitter', type=float, default=0.0, metavar='S',
                   help='extra latency per sample, uniform in [0, S]')
    g.add_argument('--drop', type=_probability, default=0.0, metavar='P',
                   help='each sample is lost on its way to the host with probability P in '
                        f'[0, {DROP_MAX:g}] (the EKF sees a gap)')
    g.add_argument('--force-noise', type=float, default=0.0, metavar='N',
                   help='Gaussian force noise of this std on the cart, one draw per sample')
    g.add_argument('--actuator-gain', type=float, default=1.0, metavar='G',
                   help='amplifier gain error: applied force = G x command (before saturation)')
    g.add_argument('--actuator-tau', type=float, default=0.0, metavar='S',
                   help='an extra first-order lag of the amplifier with this time constant')
    g.add_argument('--push', type=_push, action='append', default=[],
                   metavar='T:TARGET:AMPLITUDE:WIDTH',
                   help='a rectangular push at T s of AMPLITUDE on the cart [N] or the pendulum '
                        '[N m, towards increasing theta] for WIDTH s (repeatable)')
    return g


def scenario_from_args(args: argparse.Namespace) -> Scenario:
    """The :class:`Scenario` of parsed options; ValueError (naming the option) if invalid."""
    try:
        return Scenario(x0=args.x0, theta0=args.theta0, tip_mass=args.tip_mass,
                        cart_mass=args.cart_mass, friction_scale=args.friction_scale,
                        encoder_offset=args.encoder_offset, noise=args.noise, seed=args.seed,
                        delay=args.delay, jitter=args.jitter, drop=args.drop,
                        force_noise=args.force_noise, actuator_gain=args.actuator_gain,
                        actuator_tau=args.actuator_tau, pushes=tuple(args.push))
    except ValueError as error:
        message = str(error)
        name, _, rest = message.partition(' ')
        if name in _OPTION_FIELDS:  # 'cart_mass must be ...' -> '--cart-mass must be ...'
            message = f'--{name.replace("_", "-")} {rest}'
        elif name == 'push':  # 'push time must be ...' -> '--push: time must be ...'
            message = f'--push: {rest}'
        raise ValueError(message) from None


_OPTION_FIELDS = ('x0', 'theta0', 'tip_mass', 'cart_mass', 'friction_scale', 'encoder_offset',
                  'seed', 'delay', 'jitter', 'drop', 'force_noise', 'actuator_gain',
                  'actuator_tau')
