"""Options shared by several `cartpole` subcommands, and what they build."""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any, Callable

from cartpole_sim import scenario_options
from cartpole_sim.model import CartPoleParameters
from cartpole_sim.scenario import Scenario


def add_scenario_arguments(parser: argparse.ArgumentParser) -> None:
    """Scenario options of the simulated plant (SPEC sections 5 and 8), and --plant-params.

    The scenario options themselves are :mod:`cartpole_sim.scenario_options`'s,
    which ``cartpole emulate`` shares.
    """
    g = scenario_options.add_scenario_arguments(parser)
    add_plant_params_argument(g, 'nominal plant parameters (CartPoleParameters YAML)')


def add_plant_params_argument(group, what: str) -> None:
    """``--plant-params FILE.yaml``, read by :func:`nominal_parameters`; ``what`` says what
    the file gives this command (without the thesis default, which is added)."""
    group.add_argument('--plant-params', type=Path, default=None, metavar='FILE.yaml',
                       help=f'{what}; default: thesis values')


def add_number_argument(group, flag: str, default: float, help: str,
                        metavar: str | None = None) -> None:
    """A number option of ``default``'s type whose help ends with that default, so the
    value is written once: ``(default 0.5)``."""
    group.add_argument(flag, type=type(default), default=default, metavar=metavar,
                       help=f'{help} (default {default:g})')


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
    """The scenario of the options; SystemExit with the reason if one is invalid."""
    try:
        return scenario_options.scenario_from_args(args)
    except ValueError as error:
        raise SystemExit(str(error)) from None


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
            from .analysis.timeline import describe
            text = describe(value)
        else:
            text = 'null' if value is None else str(value)
        print(f'{key:<{width}}  {text}')


def progress_printer(prefix: str) -> Callable[[str], None]:
    """A ``progress`` callback: one line on stderr (stdout stays the summary, e.g. JSON)."""
    def say(text: str) -> None:
        print(f'{prefix}: {text}', file=sys.stderr, flush=True)
    return say
