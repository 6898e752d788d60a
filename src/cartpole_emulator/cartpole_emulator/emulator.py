"""``cartpole emulate``: the emulated rig on a new pseudo-terminal, until Ctrl-C or ``--duration``.

Parses the options (the link's faults, the plant's scenario, the device:
the firmware's Python mirror, :class:`~cartpole_emulator.emulated_rig.Emulator`,
or the compiled firmware in QEMU, :class:`~cartpole_emulator.qemu_device.QemuDevice`),
prints the port, runs the device under the loop processes' real-time hygiene
(:mod:`cartpole_core.realtime`) and prints its counts at the end. A refused
option is one line ``cartpole emulate: error: ...`` and exit status 2, like
every ``cartpole`` command. Options and what they do: docs/rig.md ("cartpole emulate").
"""
from __future__ import annotations

import argparse
import math
import os
import signal
import sys

from cartpole_core import realtime
from cartpole_core.model import CartPoleParameters
from cartpole_sim.plant import Scenario
from cartpole_sim.scenario_options import add_scenario_arguments, scenario_from_args

from .emulated_rig import Emulator, FaultConfig
from .qemu_device import QemuDevice, firmware_available

__all__ = ['Emulator', 'FaultConfig', 'build_parser', 'main']


# -- command line -------------------------------------------------------------------------------
MAX_DURATION_S = 3600.0
"""[s] Longest ``--duration`` (the rest of ``cartpole`` takes runs of at most an hour too);
without it the emulator runs until Ctrl-C, as a device does."""
MAX_STALL_MS = 60_000.0
"""[ms] Longest ``--stall`` of the link."""
MAX_LIMIT_MARGIN_M = 0.1
"""[m] Largest ``--limit-margin``: the switches close within 10 cm of a stop at most."""
MAX_NAME = 80
"""Longest ``--name`` (the ``V`` line has at most 96 bytes)."""


class Parser(argparse.ArgumentParser):
    """An argparse parser whose error is one line, ``cartpole emulate: error: MESSAGE``,
    exit 2, as every ``cartpole`` command's (the usage is in ``--help``)."""

    def error(self, message: str):
        self.exit(2, f'{self.prog}: error: {message}\n')


def _number(text: str, low: float, high: float, unit: str, low_open: bool = False) -> float:
    """A finite number in [low, high] (``(low, high]`` with ``low_open``), or the refusal."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'not a number: {text!r}') from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f'must be a finite number, got {text!r}')
    if (value <= low if low_open else value < low) or value > high:
        bracket = '(' if low_open else '['
        raise argparse.ArgumentTypeError(
            f'must be in {bracket}{low:g}, {high:g}] {unit}, got {value:g}')
    return value


def _duration(text: str) -> float:
    return _number(text, 0.0, MAX_DURATION_S, 's', low_open=True)


def _limit_margin(text: str) -> float:
    return _number(text, 0.0, MAX_LIMIT_MARGIN_M, 'm')


def _usb_jitter(text: str) -> float:
    return _number(text, 0.0, 1.0, 's')


def _pair(text: str, high: float, unit: str) -> tuple[float, float]:
    try:
        a, b = text.split(':')
        a_f, b_f = float(a), float(b)
    except ValueError:
        raise argparse.ArgumentTypeError(f'expected AT:VALUE (two numbers), got {text!r}')
    if not (math.isfinite(a_f) and math.isfinite(b_f) and 0 <= a_f <= MAX_DURATION_S
            and 0 < b_f <= high):
        raise argparse.ArgumentTypeError(
            f'expected AT in [0, {MAX_DURATION_S:g}] s and VALUE in (0, {high:g}] {unit}, '
            f'got {text!r}')
    return a_f, b_f


def _stall(text: str) -> tuple[float, float]:
    return _pair(text, MAX_STALL_MS, 'ms')


def _disconnect(text: str) -> tuple[float, float]:
    return _pair(text, MAX_DURATION_S, 's')


def _probability(text: str) -> float:
    return _number(text, 0.0, 1.0, '(a probability)')


def _name(text: str) -> str:
    """A firmware name the ``V`` line can carry: printable ASCII, no ``,`` or ``*``."""
    if not 0 < len(text) <= MAX_NAME or any(not 0x20 <= ord(c) <= 0x7E or c in ',*' for c in text):
        raise argparse.ArgumentTypeError(
            f'must be 1 to {MAX_NAME} printable ASCII characters without "," or "*", '
            f'got {text!r}')
    return text


def _file(text: str) -> str:
    if not os.path.isfile(text):
        raise argparse.ArgumentTypeError(f'{text}: no such file')
    if not os.access(text, os.R_OK):
        raise argparse.ArgumentTypeError(f'{text}: not readable (permission denied)')
    return text


def _link(text: str) -> str:
    parent = os.path.dirname(os.path.abspath(text)) or '/'
    if not os.path.isdir(parent):
        raise argparse.ArgumentTypeError(f'{text}: the directory {parent} does not exist')
    if os.path.isdir(text):
        raise argparse.ArgumentTypeError(f'{text}: is a directory, a link path is needed')
    return text


def load_parameters(path: str | None) -> CartPoleParameters:
    """``--params``: the plant's parameters from a CartPoleParameters YAML; ValueError with
    the file's name when it is not one (not YAML, a wrong key or value)."""
    if not path:
        return CartPoleParameters()
    try:
        return CartPoleParameters.from_yaml(path)
    except Exception as exc:  # noqa: BLE001 - yaml.YAMLError, TypeError, ...: one line
        text = ' '.join(str(exc).split())
        raise ValueError(f'--params {path}: not a CartPoleParameters YAML: {text}') from None


def build_parser(prog: str = 'cartpole emulate') -> argparse.ArgumentParser:
    p = Parser(
        prog=prog,
        description='Emulate the Arduino Due rig (plant behind the Joint protocol) on a new '
                    'pseudo-terminal and print its path.')
    p.add_argument('--link', metavar='PATH', type=_link,
                   help='symlink pointing at the current pty (stable across disconnects), '
                        'e.g. /tmp/cartpole-emu; give this path to the bridge')
    p.add_argument('--firmware', choices=('python', 'qemu'), default='python',
                   help='the device: python (default) runs the firmware\'s Python mirror; qemu runs '
                        'the firmware compiled for the Cortex-M3 in qemu-system-arm (hardware in '
                        'the loop, needs gcc-arm-none-eabi, libnewlib-arm-none-eabi, '
                        'qemu-system-arm)')
    p.add_argument('--image', metavar='ELF', type=_file,
                   help='with --firmware qemu: the firmware image (default: make -C firmware '
                        'arm-image builds firmware/build/arm/cartpole_bridge.elf)')
    p.add_argument('--name', default='cartpole_emulator', type=_name,
                   help='firmware name in the V answer (python; the compiled firmware says '
                        'cartpole_bridge)')
    p.add_argument('--duration', type=_duration, default=None, metavar='S',
                   help=f'exit after S seconds (at most {MAX_DURATION_S:g}; without it: until '
                        'Ctrl-C)')
    p.add_argument('--params', metavar='FILE.yaml', type=_file,
                   help='plant parameters (CartPoleParameters YAML)')
    p.add_argument('--limit-margin', type=_limit_margin, default=0.003, metavar='M',
                   help='limit switches close this close to a stop (default 3 mm, at most '
                        f'{MAX_LIMIT_MARGIN_M:g} m)')
    p.add_argument('--drop-lines', type=_probability, default=0.0, metavar='P',
                   help='probability of losing any line sent (a link fault; --drop loses samples)')
    p.add_argument('--corrupt', type=_probability, default=0.0,
                   help='probability of corrupting one byte of a line')
    p.add_argument('--usb-jitter', type=_usb_jitter, default=0.0, metavar='S',
                   help='USB latency jitter: each line leaves up to S seconds late (uniform, '
                        'seeded by --seed, order kept; t_us stays the sample time)')
    p.add_argument('--stall', type=_stall, action='append', default=[], metavar='AT:MS',
                   help='freeze the link for MS milliseconds at device time AT seconds (repeatable)')
    p.add_argument('--disconnect', type=_disconnect, action='append', default=[], metavar='AT:S',
                   help='pull the cable at AT seconds for S seconds (repeatable)')
    add_scenario_arguments(p, title='emulated plant scenario')
    return p


def _qemu_device(args, scenario: Scenario, params: CartPoleParameters, faults: FaultConfig):
    """``--firmware qemu``: the compiled firmware in QEMU (:mod:`cartpole_emulator.qemu_device`)."""
    available, why = firmware_available()
    if not available:
        raise RuntimeError(why)
    return QemuDevice(scenario, params, link=args.link, faults=faults,
                      limit_margin=args.limit_margin, seed=args.seed, image=args.image)


def main(argv: list[str] | None = None) -> int:
    """``cartpole emulate`` / ``emulator``: run until Ctrl-C (or ``--duration``)."""
    args = build_parser().parse_args(argv)
    try:
        params = load_parameters(args.params)
        scenario = scenario_from_args(args)
        faults = FaultConfig(drop=args.drop_lines, corrupt=args.corrupt,
                             usb_jitter=args.usb_jitter, stalls=list(args.stall),
                             disconnects=list(args.disconnect))
        if args.firmware == 'qemu':
            emulator = _qemu_device(args, scenario, params, faults)
        else:
            emulator = Emulator(scenario, params, link=args.link, name=args.name, faults=faults,
                                limit_margin=args.limit_margin, seed=args.seed)
    except (ValueError, OSError, RuntimeError) as exc:
        print(f'cartpole emulate: error: {exc}', file=sys.stderr)
        return 2

    def announce(port: str) -> None:
        print(f'port: {port}' + (f'  link: {args.link}' if args.link else ''), flush=True)

    emulator.on_port_change = announce

    def _stop(signum, frame):  # noqa: ARG001
        emulator._stop.set()

    previous = {s: signal.signal(s, _stop) for s in (signal.SIGINT, signal.SIGTERM)}
    hygiene = None
    try:
        if args.firmware == 'qemu':
            emulator.power_on()
        emulator.open()
        priority = None
        if args.firmware == 'qemu':
            # the emulated device (QEMU and the plant's relay) has a CPU of its own on the rig:
            # one step above the host's loop, so the host's threads never hold it up
            base = realtime.priority_from_environment()
            priority = min(base + 1, realtime.MAX_PRIORITY) if base > 0 else 0
        hygiene = realtime.enter_loop(priority, what='emulator',
                                      log=lambda text: print(text, file=sys.stderr))
        if args.firmware == 'qemu' and hygiene.priority > 0:
            threads = emulator.board.prioritise(hygiene.priority)
            print(f'emulator: qemu-system-arm at SCHED_FIFO {hygiene.priority} on {threads} '
                  'threads', file=sys.stderr)
        emulator.run(args.duration)
    except (ValueError, RuntimeError, OSError) as exc:   # a bad CARTPOLE_REALTIME, QEMU failed
        print(f'cartpole emulate: error: {exc}', file=sys.stderr)
        return 2
    finally:
        if hygiene is not None:
            hygiene.leave()
        emulator.shutdown()
        for s, handler in previous.items():
            signal.signal(s, handler)
    print(f'emulator: {emulator.samples} samples, {emulator.lines_in} lines in, '
          f'{emulator.lines_out} lines out, {emulator.tx_dropped} dropped, '
          f'{emulator.overruns} overruns', flush=True)
    stats = getattr(emulator, 'statistics', None)
    if stats is not None:
        print(f'firmware: {stats.samples} samples, {stats.lines_in} lines in, '
              f'{stats.refused} refused, stack {stats.stack_bytes} bytes, '
              f'{stats.plant_timeouts} plant timeouts', flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
