"""`cartpole`: the one front door (SPEC section 5).

Each subcommand lives in ``cartpole_bringup.commands.<name>`` with
``add_arguments(parser)`` and ``main(args) -> int``; this module only
dispatches, importing the chosen subcommand alone (so ``cartpole offline``
never imports rclpy).
"""
from __future__ import annotations

import argparse
import importlib
import sys

SUBCOMMANDS = {
    'run': 'start the node graph on the simulator or the rig (optionally recorded)',
    'offline': 'the same closed loop without ROS, far faster than real time',
    'analyze': 'run summary and plots from recorded bags',
    'bag': 'bags: repair one whose recording was killed, show what is in one',
    'bench': 'benchmarks: controller comparison, loop latency, offline speed',
    'emulate': 'device emulator (the plant behind the Joint protocol) on a new pseudo-terminal',
    'identify': 'fit plant parameters to a recorded test',
    'bound': 'minimum-time swing-up bounds for the parameters in use',
    'plan': 'solve and cache the minimum-time plan of the time_optimal swing-up for a start',
}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog='cartpole', description='Cart-pole swing-up and stabilisation on ROS 2 Jazzy.')
    sub = parser.add_subparsers(dest='command', metavar='COMMAND', required=True)
    for name, help_text in SUBCOMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        p.set_defaults(_module=f'cartpole_bringup.commands.{name}')
        if name == 'emulate':
            # The emulator parses its own options (cartpole_hw.emulator).
            p.add_argument('emulator_args', nargs=argparse.REMAINDER, help=argparse.SUPPRESS)
            continue
        try:
            module = importlib.import_module(f'cartpole_bringup.commands.{name}')
        except ImportError as exc:
            p.set_defaults(_unavailable=str(exc))
            continue
        module.add_arguments(p)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ['emulate']:
        from cartpole_hw.emulator import main as emulate
        return emulate(argv[1:]) or 0
    parser = build_parser()
    args = parser.parse_args(argv)
    if getattr(args, '_unavailable', None):
        parser.error(f'{args.command} is not available: {args._unavailable}')
    module = importlib.import_module(args._module)
    return module.main(args) or 0


if __name__ == '__main__':
    sys.exit(main())
