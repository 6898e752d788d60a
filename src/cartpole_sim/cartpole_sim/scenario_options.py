"""The scenario's command-line options, one definition for ``cartpole offline``,
``cartpole run --sim`` and ``cartpole emulate`` (docs/simulator.md, "Disturbances").

Here rather than in ``cartpole_bringup`` because the emulator
(``cartpole_hw``) takes them too and must not depend on the bringup package.
"""
from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

from cartpole_core.yaml_problem import yaml_problem

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


def add_scenario_file_argument(group) -> None:
    """``--scenario FILE`` (:func:`scenario_from_args` reads it), for a command whose
    plant takes the whole :class:`Scenario` (``cartpole offline``)."""
    group.add_argument('--scenario', type=Path, default=None, metavar='FILE',
                       help='the whole scenario from a JSON or YAML file of its fields (as '
                            '`cartpole bench robustness --combined` writes for each failure); '
                            'the other scenario options are then refused')


def load_scenario(path: str | Path) -> Scenario:
    """The :class:`Scenario` of a JSON or YAML file of its fields (:meth:`Scenario.to_dict`);
    ValueError naming the file and what is wrong."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as error:
        raise ValueError(f'--scenario {path}: cannot read it ({error.strerror})') from None
    if path.suffix.lower() == '.json':
        try:
            data = json.loads(text)
        except ValueError as error:
            raise ValueError(f'--scenario {path}: not valid JSON ({error})') from None
    else:
        import yaml
        try:
            data = yaml.safe_load(text)
        except yaml.YAMLError as error:
            raise ValueError(f'--scenario {path}: not valid YAML ({yaml_problem(error)})') from None
    try:
        return Scenario.from_dict(data)
    except (TypeError, ValueError) as error:
        raise ValueError(f'--scenario {path}: {error}') from None


def save_scenario(scenario: Scenario, path: str | Path) -> Path:
    """Write ``scenario`` as JSON (:func:`load_scenario` reads it back equal, bit for bit)."""
    path = Path(path)
    path.write_text(json.dumps(scenario.to_dict(), indent=1) + '\n')
    return path


def scenario_from_args(args: argparse.Namespace) -> Scenario:
    """The :class:`Scenario` of parsed options; ValueError (naming the option) if invalid.

    With ``--scenario FILE`` the file's scenario, and any other scenario
    option given as well is refused (the file is the whole scenario).
    """
    if getattr(args, 'scenario', None) is not None:
        given = [f'--{name.replace("_", "-")}' for name, default in _OPTION_DEFAULTS.items()
                 if getattr(args, name, default) != default]
        if given:
            raise ValueError(f'--scenario {args.scenario} is the whole scenario; drop '
                             f'{", ".join(given)} (or edit the file)')
        return load_scenario(args.scenario)
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


_OPTION_DEFAULTS = {'x0': 0.0, 'theta0': math.pi, 'tip_mass': None, 'cart_mass': None,
                    'friction_scale': 1.0, 'encoder_offset': 0.0, 'noise': False, 'seed': 0,
                    'delay': 0.0, 'jitter': 0.0, 'drop': 0.0, 'force_noise': 0.0,
                    'actuator_gain': 1.0, 'actuator_tau': 0.0, 'push': []}
"""Each scenario option's default (``--push`` as its ``dest``): what --scenario refuses."""
_OPTION_FIELDS = ('x0', 'theta0', 'tip_mass', 'cart_mass', 'friction_scale', 'encoder_offset',
                  'seed', 'delay', 'jitter', 'drop', 'force_noise', 'actuator_gain',
                  'actuator_tau')
