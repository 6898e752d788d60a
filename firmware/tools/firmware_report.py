#!/usr/bin/env python3
"""Size and timing of the bridge firmware on the Cortex-M3 (``make -C firmware arm``).

Usage: ``firmware_report.py IMAGE.elf [--size-tool arm-none-eabi-size] [--out REPORT.txt]
[--json] [--samples N] [--sram-budget BYTES] [--flash-budget BYTES]``

1. **Size**: the image's sections (``arm-none-eabi-size -A``): flash = code and
   read-only data plus the initial values of ``.data``; static SRAM = ``.data`` +
   ``.bss``.
2. **Run time**: the image runs in ``qemu-system-arm -M lm3s6965evb -icount
   shift=3,sleep=on`` (one instruction = 8 ns of guest time; idle time passes
   with the host's clock). A scripted host streams, arms, answers every ``S``
   with a tagged ``U`` (so the ``S`` lines carry the latency report, the
   longest), and mixes in pings, refused, malformed and overlong lines; a
   stand-in plant answers every ``T`` with moving counters. Then the firmware
   reports (``M``) its stack high-water mark (the stack is painted at reset)
   and the work it measured with SysTick: the worst sample (its deadline:
   watchdog, limits, output; its completion: the counters taken, the ``S`` line
   sent), the worst single host line and the busiest period (which also counts
   a pass of the loop for every batch of bytes the UART's FIFO hands over), in instructions (QEMU counts
   instructions: no cycles per instruction, no flash wait states).
3. **Budget**: the SAM3X8E of the Arduino Due has 512 KB of flash and 96 KB of
   SRAM. The check fails (exit status 1) unless flash fits and static SRAM plus
   the measured stack stay within half the SRAM (the margin for the Arduino
   core, its USB stack and what the measurement did not reach). The tick's
   figure is given as a fraction of the Due's 420 000 cycles per 5 ms at 84
   MHz, counting one cycle per instruction (the real figure is higher by the
   M3's multi-cycle instructions and the flash wait states, 4 at 84 MHz, which
   its 128-bit prefetch buffer mostly hides).

Standard library only (the QEMU launcher is ``src/cartpole_emulator/cartpole_emulator/qemu_board.py``,
loaded by path).
"""
from __future__ import annotations

import argparse
import importlib.util
import json
import random
import select
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
QEMU_BOARD = HERE.parents[1] / 'src' / 'cartpole_emulator' / 'cartpole_emulator' / 'qemu_board.py'
FLASH_BYTES = 512 * 1024
SRAM_BYTES = 96 * 1024
DUE_CYCLES_PER_TICK = 84_000_000 * 5 // 1000


def load_qemu_board():
    spec = importlib.util.spec_from_file_location('qemu_board', QEMU_BOARD)
    module = importlib.util.module_from_spec(spec)
    sys.modules['qemu_board'] = module   # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def sections(image: Path, size_tool: str) -> dict[str, int]:
    out = subprocess.run([size_tool, '-A', str(image)], capture_output=True, text=True,
                         check=True).stdout
    result = {}
    for line in out.splitlines():
        parts = line.split()
        if len(parts) == 3 and parts[0].startswith('.') and parts[1].isdigit():
            result[parts[0]] = int(parts[1])
    return result


def checksum_line(body: str) -> bytes:
    x = 0
    for c in body.encode():
        x ^= c
    return f'{body}*{x:02X}\n'.encode()


class Exercise:
    """The scripted host and the stand-in plant around the firmware (module docstring)."""

    def __init__(self, board, format_counts, samples: int, seed: int = 1) -> None:
        self.board = board
        self.format_counts = format_counts
        self.samples = samples
        self.rng = random.Random(seed)
        self.seen = 0
        self.statistics = None

    def host_lines(self, seq: int) -> bytes:
        out = checksum_line(f'U,{self.rng.randint(-2000, 2000)},{seq}')
        if seq % 10 == 3:
            out += checksum_line('P') + b'U,5*00\n'                     # bad checksum
        if seq % 50 == 7:
            out += b'X' * 300 + b'\n'                                  # overlong
        if seq % 100 == 11:
            out += checksum_line('R')                                  # refused while armed
        return out

    def run(self, timeout: float) -> None:
        host, plant = self.board.host, self.board.plant
        plant.sendall(b'G,1\n')
        host.sendall(checksum_line('P') + checksum_line('L,1') + checksum_line('E,1'))
        buffers = {host: b'', plant: b''}
        deadline = time.monotonic() + timeout
        cart = 0
        asked = False
        while self.statistics is None:
            if time.monotonic() > deadline:
                raise TimeoutError(f'the exercise did not finish ({self.seen} samples seen)')
            ready, _, _ = select.select([host, plant], [], [], 0.5)
            for s in ready:
                data = s.recv(65536)
                if not data:
                    raise ConnectionError('qemu-system-arm closed the link')
                buffers[s] += data
                *lines, buffers[s] = buffers[s].split(b'\n')
                for line in lines:
                    if s is plant:
                        cart = self.plant_line(line, cart)
                    elif line.startswith(b'S,'):
                        self.seen += 1
                        if self.seen < self.samples:
                            host.sendall(self.host_lines(int(line.split(b',')[1])))
                        elif not asked:
                            host.sendall(checksum_line('E,0'))
                            plant.sendall(b'Q\n')
                            asked = True

    def plant_line(self, line: bytes, cart: int) -> int:
        if line.startswith(b'T,'):
            cart = (cart + self.rng.randint(-300, 300)) & 0xFFFF
            pend = self.rng.randint(0, 0xFFFF)
            self.board.plant.sendall(self.format_counts(cart, pend, False, False))
        elif line.startswith(b'M,') and self.seen >= self.samples:
            self.statistics = line.decode()
        return cart


def report(image: Path, size_tool: str, samples: int, sram_budget: int,
           flash_budget: int) -> tuple[dict, bool]:
    qb = load_qemu_board()
    missing = qb.missing_packages()
    if missing:
        raise SystemExit(f'firmware_report: {qb.missing_message(missing)}')
    sec = sections(image, size_tool)
    flash = sec.get('.text', 0) + sec.get('.ARM.exidx', 0) + sec.get('.data', 0)
    static = sec.get('.data', 0) + sec.get('.bss', 0)
    board = qb.QemuBoard(image, icount_shift=qb.ICOUNT_SHIFT, realtime=True)
    board.start()
    board.boot()
    try:
        exercise = Exercise(board, qb.format_counts, samples)
        exercise.run(timeout=120.0)
    finally:
        board.stop()
    stats = qb.FirmwareStatistics.parse(exercise.statistics)
    sram = static + stats.stack_bytes
    tick = stats.instructions(stats.tick_max + stats.sample_max)
    period = stats.instructions(stats.period_max)
    line = stats.instructions(stats.line_max)
    figures = {
        'flash_bytes': flash, 'flash_budget': flash_budget,
        'sram_static_bytes': static, 'stack_high_water_bytes': stats.stack_bytes,
        'stack_reserved_bytes': sec.get('.stack', 0),
        'sram_bytes': sram, 'sram_budget': sram_budget,
        'samples': stats.samples, 'lines_in': stats.lines_in, 'refused': stats.refused,
        'oversized': stats.oversized, 'tx_dropped': stats.tx_dropped,
        'overruns': stats.overruns, 'plant_timeouts': stats.plant_timeouts,
        'tick_instructions_max': tick, 'line_instructions_max': line,
        'period_instructions_max': period,
        'due_cycles_per_tick': DUE_CYCLES_PER_TICK,
        'tick_fraction_of_tick': tick / DUE_CYCLES_PER_TICK,
        'period_fraction_of_tick': period / DUE_CYCLES_PER_TICK,
        'icount_shift': qb.ICOUNT_SHIFT,
    }
    fits = flash <= flash_budget and sram <= sram_budget
    return figures, fits


def text(f: dict, fits: bool) -> str:
    kb = 1024
    return '\n'.join([
        'cartpole_bridge on the Cortex-M3 (QEMU lm3s6965evb; budget: Arduino Due, SAM3X8E)',
        f'  flash  {f["flash_bytes"]:7d} B  of {FLASH_BYTES // kb} KB '
        f'({100 * f["flash_bytes"] / FLASH_BYTES:.1f} %), limit {f["flash_budget"]} B',
        f'  SRAM   {f["sram_bytes"]:7d} B  of {SRAM_BYTES // kb} KB '
        f'({100 * f["sram_bytes"] / SRAM_BYTES:.1f} %): static {f["sram_static_bytes"]} B + '
        f'stack high-water {f["stack_high_water_bytes"]} B (of {f["stack_reserved_bytes"]} B '
        f'reserved); limit {f["sram_budget"]} B (half the SRAM)',
        f'  run    {f["samples"]} samples, {f["lines_in"]} host lines ({f["refused"]} refused, '
        f'{f["oversized"]} overlong), {f["overruns"]} overruns, {f["tx_dropped"]} lines dropped',
        f'  work   worst sample (deadline + S line) {f["tick_instructions_max"]} instructions = '
        f'{100 * f["tick_fraction_of_tick"]:.2f} % of the Due\'s {f["due_cycles_per_tick"]} '
        f'cycles per 5 ms at one cycle per instruction; worst host line '
        f'{f["line_instructions_max"]}; busiest period {f["period_instructions_max"]} '
        f'({100 * f["period_fraction_of_tick"]:.2f} %, with the loop passes of every byte batch received)',
        '         (QEMU -icount counts instructions, not the SAM3X\'s cycles or flash wait states)',
        f'  budget {"OK" if fits else "EXCEEDED"}',
    ])


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    p.add_argument('image', type=Path)
    p.add_argument('--size-tool', default='arm-none-eabi-size')
    p.add_argument('--out', type=Path, help='also write the report here')
    p.add_argument('--json', action='store_true', help='print the figures as JSON')
    p.add_argument('--samples', type=int, default=600, help='samples of the exercise (600)')
    p.add_argument('--sram-budget', type=int, default=SRAM_BYTES // 2, metavar='BYTES')
    p.add_argument('--flash-budget', type=int, default=FLASH_BYTES, metavar='BYTES')
    args = p.parse_args(argv)
    figures, fits = report(args.image, args.size_tool, args.samples, args.sram_budget,
                           args.flash_budget)
    body = text(figures, fits)
    if args.out:
        args.out.write_text(body + '\n')
    print(json.dumps({**figures, 'fits': fits}) if args.json else body)
    if not fits:
        print('firmware_report: the firmware would not fit the Arduino Due with half its SRAM '
              'to spare', file=sys.stderr)
    return 0 if fits else 1


if __name__ == '__main__':
    sys.exit(main())
