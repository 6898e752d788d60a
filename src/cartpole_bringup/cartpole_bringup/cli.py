"""`cartpole`: the one front door (docs/reference/cli.md, "The `cartpole` command").

Each subcommand is a module with ``add_arguments(parser)`` and ``main(args) -> int``:
this package's own in ``cartpole_bringup.commands.<name>``, the tools' (``bench``,
``identify``) found through the ``cartpole.commands`` entry points, so the
orchestrator never imports the packages built on it. This module only dispatches
(so ``cartpole offline`` never imports rclpy).

Exit codes (the README's "Exit codes"): 0 a correct result; 1 a run or an
operation that failed (its summary or reason printed); 2 a refused input, one
line ``cartpole SUB: error: ...`` on stderr and nothing else, before any work
(an argparse error, or :class:`~cartpole_bringup.boundary.InputError` from a
subcommand); 130 / 143 stopped by SIGINT / SIGTERM.
"""
from __future__ import annotations

import argparse
import importlib
import signal
import sys
from importlib.metadata import entry_points

from cartpole_core.middleware import use_profiles

from .boundary import InputError


class Parser(argparse.ArgumentParser):
    """An argparse parser whose error is one line, ``PROG: error: MESSAGE``, exit 2
    (the usage is in ``--help``)."""

    def error(self, message: str):
        self.exit(2, f'{self.prog}: error: {message}\n')

SUBCOMMANDS = {
    'run': 'start the node graph on the simulator or the rig (optionally recorded)',
    'offline': 'the same closed loop without ROS, far faster than real time',
    'analyze': 'run summary and plots from recorded bags',
    'bag': 'bags: repair one whose recording was killed, show what is in one',
    'emulate': 'device emulator (the plant behind the Joint protocol) on a new pseudo-terminal',
    'bound': 'minimum-time swing-up bounds for the parameters in use',
    'plan': 'solve and cache the minimum-time plan of the time_optimal swing-up for a start',
}


ENTRY_POINT_GROUP = 'cartpole.commands'
"""Subcommands of other packages: ``name = module`` (the module has ``HELP``)."""


def subcommand_modules() -> dict[str, str]:
    """Subcommand name -> module: this package's, then the ``cartpole.commands`` entry points."""
    modules = {name: f'cartpole_bringup.commands.{name}' for name in SUBCOMMANDS}
    for entry in sorted(entry_points(group=ENTRY_POINT_GROUP), key=lambda e: e.name):
        modules.setdefault(entry.name, entry.value)
    return modules


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(
        prog='cartpole', description='Cart-pole swing-up and stabilisation on ROS 2 Jazzy.')
    sub = parser.add_subparsers(dest='command', metavar='COMMAND', required=True)
    for name, module_name in subcommand_modules().items():
        if name == 'emulate':
            # The emulator parses its own options (cartpole_emulator.emulator).
            p = sub.add_parser(name, help=SUBCOMMANDS[name], description=SUBCOMMANDS[name])
            p.set_defaults(_module=module_name, _parser=p)
            p.add_argument('emulator_args', nargs=argparse.REMAINDER, help=argparse.SUPPRESS)
            continue
        try:
            module = importlib.import_module(module_name)
        except ImportError as exc:
            help_text = SUBCOMMANDS.get(name, '(not available)')
            p = sub.add_parser(name, help=help_text, description=help_text)
            p.set_defaults(_module=module_name, _parser=p, _unavailable=str(exc))
            continue
        help_text = SUBCOMMANDS.get(name) or module.HELP
        p = sub.add_parser(name, help=help_text, description=help_text)
        p.set_defaults(_module=module_name, _parser=p)
        module.add_arguments(p)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    use_profiles()  # a service's reply never holds the loop (cartpole_core.middleware)
    if argv[:1] == ['emulate']:
        from cartpole_emulator.emulator import main as emulate
        return emulate(argv[1:]) or 0
    parser = build_parser()
    args = parser.parse_args(argv)
    if getattr(args, '_unavailable', None):
        parser.error(f'{args.command} is not available: {args._unavailable}')
    _refuse_dash_values(args._parser, args)
    module = importlib.import_module(args._module)
    prog = getattr(args, '_prog', None) or args._parser.prog
    stop_signals = _raise_on_sigterm() if args.command != 'run' else {}
    try:
        return module.main(args) or 0
    except InputError as error:
        print(f'{prog}: error: {error}', file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f'{prog}: stopped by {_Stopped.name}', file=sys.stderr)
        return 128 + _Stopped.signum
    finally:
        for sig, handler in stop_signals.items():
            signal.signal(sig, handler)


def _refuse_dash_values(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """``--x0=--``: argparse drops the value '--' and stores []; refuse it like a bad value."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            chosen = action.choices.get(getattr(args, action.dest, None))
            if chosen is not None:
                _refuse_dash_values(chosen, args)
            continue
        if action.nargs is not None or not action.option_strings:
            continue
        value = getattr(args, action.dest, None)
        if isinstance(action, argparse._AppendAction):
            dashed = isinstance(value, list) and any(v == [] for v in value)
        else:
            dashed = isinstance(value, list) and value == []
        if dashed:
            parser.error(f"argument {'/'.join(action.option_strings)}: expected one value, "
                         "got '--'")


class _Stopped:
    """The signal that stopped the subcommand (SIGINT unless SIGTERM came)."""
    signum = int(signal.SIGINT)
    name = 'SIGINT'


def _raise_on_sigterm() -> dict:
    """SIGTERM stops like Ctrl-C (KeyboardInterrupt; ``cartpole run`` has its own stop)."""
    def handler(signum, frame):
        _Stopped.signum, _Stopped.name = int(signum), signal.Signals(signum).name
        raise KeyboardInterrupt

    def on_sigint(signum, frame):
        _Stopped.signum, _Stopped.name = int(signal.SIGINT), 'SIGINT'
        raise KeyboardInterrupt
    try:
        return {signal.SIGTERM: signal.signal(signal.SIGTERM, handler),
                signal.SIGINT: signal.signal(signal.SIGINT, on_sigint)}
    except ValueError:  # not the main thread (an embedding test): leave the handlers alone
        return {}


if __name__ == '__main__':
    sys.exit(main())
