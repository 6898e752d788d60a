"""Options shared by several `cartpole` subcommands, and what they build."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any, Callable

from cartpole_sim import scenario_options
from cartpole_core.model import CartPoleParameters
from cartpole_sim.scenario import Scenario

from . import boundary


def add_scenario_arguments(parser: argparse.ArgumentParser) -> None:
    """Scenario options of the simulated plant (docs/simulator.md, "Disturbances"), and
    --plant-params.

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
    """``--plant-params`` (thesis values without it); InputError naming the file if bad."""
    return boundary.plant_parameters(getattr(args, 'plant_params', None))


def scenario_from_args(args: argparse.Namespace, nominal: CartPoleParameters | None = None,
                       duration: float | None = None) -> Scenario:
    """The scenario of the options, checked whole (InputError naming the option).

    With ``nominal`` also against the rail (``--x0`` on it) and the plant
    (the scenario's true parameters valid); with ``duration`` [s] against the
    run: every ``--push`` starts inside it, and with ``--drop`` some sample
    reaches the host (the scenario's own seeded draws, so exactly as the run
    would lose them).
    """
    try:
        scenario = scenario_options.scenario_from_args(args)
    except ValueError as error:
        raise boundary.InputError(str(error)) from None
    if nominal is not None:
        if not 0.0 <= scenario.x0 <= nominal.travel:
            raise boundary.InputError(f'--x0 {scenario.x0:g} m is outside the travel [0, '
                                      f'{nominal.travel:g}] m')
        try:
            scenario.plant_parameters(nominal)
        except ValueError as error:
            raise boundary.InputError(f'the scenario gives no valid plant: {error}') from None
    if duration is not None:
        for push in scenario.pushes:
            if push.t >= duration:
                raise boundary.InputError(f'--push {push}: starts at {push.t:g} s, after the end '
                                          f'of the {duration:g} s run')
        if scenario.drop and nominal is not None and no_sample_arrives(scenario, nominal,
                                                                       duration):
            raise boundary.InputError(
                f'--drop {scenario.drop:g}: with --seed {scenario.seed} every sample of the '
                f'{duration:g} s run is lost; nothing would reach the controller')
    return scenario


def no_sample_arrives(scenario: Scenario, nominal: CartPoleParameters, duration: float) -> bool:
    """Whether ``scenario``'s drop loses every sample of a ``duration`` run (its own seeded
    draws, one a sample, as the offline loop and the simulator draw them)."""
    from cartpole_sim.plant import Plant
    plant = Plant(nominal, scenario.replace(pushes=()))
    steps = int(round(duration / nominal.sample_time)) + 1
    return all(plant.sample_lost() for _ in range(steps))


def load_ros_parameters(path: Path | None, node_name: str) -> dict[str, Any]:
    """The ``ros__parameters`` of ``node_name`` in ``--params``, flattened (InputError if bad)."""
    return boundary.ros_parameters(path, node_name)


def manager_node_parameters() -> dict[str, tuple[float | None, float | None]]:
    """The controller_manager node's own parameters a ``ros2 param dump`` holds, with the
    ranges it declares them with (None: a boolean); the node applies them, the offline loop
    has no use for them. (Imported here: the manager's modules are slow for every command.)"""
    from cartpole_control.manager_parameters import LOCKSTEP_WAIT_RANGE
    from cartpole_core.message_checks import STAMP_TOLERANCE_RANGE
    return {'lockstep': (None, None), 'use_sim_time': (None, None),
            'lockstep_wait': LOCKSTEP_WAIT_RANGE, 'stamp_tolerance': STAMP_TOLERANCE_RANGE}


def _node_value(value: Any, low: float | None, high: float | None, source: str) -> None:
    if low is not None:
        boundary.number(source, value, low, high)
    elif not isinstance(value, bool):
        raise boundary.InputError(f'{source} must be true or false, got {value!r}')


def manager_section(nominal: CartPoleParameters, args: argparse.Namespace) -> dict[str, Any]:
    """The ``--params`` file's controller_manager section without the node's own parameters.

    The construction parameters stay when they differ from what the loop uses (a copy of
    the installed controller_manager.yaml has them at those values), and are refused then;
    :func:`manager_node_parameters` are checked against their ranges and taken out.
    """
    params = dict(load_ros_parameters(getattr(args, 'params', None), 'controller_manager'))
    for name, same in (('plant_params_file', ''), ('sample_time', nominal.sample_time)):
        if params.get(name) == same:
            del params[name]
    for name, (low, high) in manager_node_parameters().items():
        if name in params:
            _node_value(params.pop(name), low, high,
                        f'--params {args.params}: controller_manager: {name}')
    return params


def manager_parameters(nominal: CartPoleParameters, args: argparse.Namespace) -> dict[str, Any]:
    """controller_manager parameters: the ``--params`` file's section, then ``--swingup`` and
    ``--stabilizer``; InputError with the manager's reason, naming the file or the option."""
    params = manager_section(nominal, args)
    if params:
        _manager_takes(nominal, params, f'--params {args.params}: controller_manager')
    for name in ('swingup', 'stabilizer'):
        if getattr(args, name, None):
            params[name] = getattr(args, name)
            _manager_takes(nominal, params, f'--{name} {getattr(args, name)}')
    return params


def _manager_takes(nominal: CartPoleParameters, parameters: dict[str, Any], source: str) -> None:
    from cartpole_control.manager import ControllerManager
    manager = ControllerManager(nominal, sample_time=nominal.sample_time, real_time=False)
    try:
        result = manager.set_parameters(dict(parameters))
    except (ValueError, TypeError) as error:
        raise boundary.InputError(f'{source}: {error}') from None
    if not result.successful:
        raise boundary.InputError(f'{source}: {result.reason}')


def check_view_address(value: str | None) -> None:
    """``--view HOST:PORT`` refused before anything starts (InputError naming it); None: no view."""
    if value is None:
        return
    from cartpole_analysis.viewer.server import parse_address
    try:
        parse_address(value)
    except ValueError as error:
        raise boundary.InputError(f'--view: {error}') from None


def print_json(obj: Any) -> None:
    """The one way a ``--json`` object is printed: strict JSON (no NaN, no Infinity; such a
    value is null, with its reason under ``null_reasons``)."""
    print(boundary.json_text(obj), flush=True)


def print_summary(summary: dict[str, Any], as_json: bool) -> None:
    """The run summary as a table, or one JSON object with ``--json``."""
    if as_json:
        print_json(summary)
        return
    width = max(len(k) for k in summary)
    for key, value in summary.items():
        if isinstance(value, float):
            text = f'{value:.6g}'
        elif key == 'controllers' and isinstance(value, list):
            from cartpole_analysis.analysis.timeline import describe
            text = describe(value)
        else:
            text = 'null' if value is None else str(value)
        print(f'{key:<{width}}  {text}')


def progress_printer(prefix: str) -> Callable[[str], None]:
    """A ``progress`` callback: one line on stderr (stdout stays the summary, e.g. JSON)."""
    def say(text: str) -> None:
        print(f'{prefix}: {text}', file=sys.stderr, flush=True)
    return say
