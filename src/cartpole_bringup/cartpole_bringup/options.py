"""Options shared by several `cartpole` subcommands, and what they build."""
from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any

from cartpole_sim.model import CartPoleParameters
from cartpole_sim.plant import Scenario


def add_scenario_arguments(parser: argparse.ArgumentParser) -> None:
    """Scenario options of the simulated plant (SPEC section 5)."""
    g = parser.add_argument_group('simulated plant scenario')
    g.add_argument('--tip-mass', type=float, default=None, metavar='KG',
                   help='tip mass of the simulated plant (default: the thesis 0.251 kg)')
    g.add_argument('--friction-scale', type=float, default=1.0, metavar='F',
                   help='multiply every cart and pendulum friction coefficient of the plant')
    g.add_argument('--theta0', type=float, default=math.pi, metavar='RAD',
                   help='initial pendulum angle (default pi, hanging)')
    g.add_argument('--x0', type=float, default=0.0, metavar='M',
                   help='initial cart position from the left stop (default 0)')
    g.add_argument('--encoder-offset', type=float, default=0.0, metavar='RAD',
                   help='pendulum angle minus pi when the encoders were reset (Appendix H)')
    g.add_argument('--noise', action='store_true', help='add measurement noise before quantisation')
    g.add_argument('--seed', type=int, default=0, help='seed of the noise generator')
    g.add_argument('--plant-params', type=Path, default=None, metavar='FILE.yaml',
                   help='nominal plant parameters (CartPoleParameters YAML); default: thesis values')


def add_controller_arguments(parser: argparse.ArgumentParser) -> None:
    g = parser.add_argument_group('controllers')
    g.add_argument('--swingup', default=None, metavar='NAME',
                   help='swing-up plugin (default: the controller manager default)')
    g.add_argument('--stabilizer', default=None, metavar='NAME',
                   help='stabiliser plugin (default: the controller manager default)')
    g.add_argument('--params', type=Path, default=None, metavar='FILE.yaml',
                   help='ROS 2 parameters file (controller_manager section used offline)')


def add_output_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--json', action='store_true', help='print one JSON object instead of a table')


def nominal_parameters(args: argparse.Namespace) -> CartPoleParameters:
    path = getattr(args, 'plant_params', None)
    return CartPoleParameters.from_yaml(path) if path else CartPoleParameters()


def scenario_from_args(args: argparse.Namespace) -> Scenario:
    if args.tip_mass is not None and not args.tip_mass > 0:
        raise SystemExit(f'--tip-mass must be > 0, got {args.tip_mass}')
    if not args.friction_scale >= 0:
        raise SystemExit(f'--friction-scale must be >= 0, got {args.friction_scale}')
    return Scenario(x0=args.x0, theta0=args.theta0, tip_mass=args.tip_mass,
                    friction_scale=args.friction_scale, encoder_offset=args.encoder_offset,
                    noise=args.noise, seed=args.seed)


def load_ros_parameters(path: Path | None, node_name: str) -> dict[str, Any]:
    """The ``ros__parameters`` of ``node_name`` in a ROS 2 parameters YAML file, flattened.

    Nested mappings become dotted names (``lqg: {q: [...]}`` -> ``lqg.q``), as
    rclpy does. Sections for ``/**`` apply to every node.
    """
    if path is None:
        return {}
    import yaml
    data = yaml.safe_load(Path(path).read_text()) or {}
    out: dict[str, Any] = {}
    for key in ('/**', node_name, '/' + node_name):
        section = data.get(key)
        if isinstance(section, dict) and isinstance(section.get('ros__parameters'), dict):
            out.update(_flatten(section['ros__parameters']))
    return out


def _flatten(d: dict[str, Any], prefix: str = '') -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in d.items():
        name = f'{prefix}{k}'
        if isinstance(v, dict):
            out.update(_flatten(v, name + '.'))
        else:
            out[name] = tuple(v) if isinstance(v, list) else v
    return out


def print_summary(summary: dict[str, Any], as_json: bool) -> None:
    """The run summary as a table, or one JSON object with ``--json``."""
    if as_json:
        print(json.dumps(summary, sort_keys=False))
        return
    width = max(len(k) for k in summary)
    for key, value in summary.items():
        if isinstance(value, float):
            text = f'{value:.6g}'
        elif key == 'controllers' and isinstance(value, list):
            from .timeline import describe
            text = describe(value)
        else:
            text = 'null' if value is None else str(value)
        print(f'{key:<{width}}  {text}')
