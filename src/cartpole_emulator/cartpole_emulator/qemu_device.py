"""Hardware in the loop: the bridge firmware on an emulated Cortex-M3 behind the pty.

``cartpole emulate --firmware qemu``: :class:`QemuDevice` is the
:class:`~cartpole_emulator.emulated_rig.Emulator` with the compiled firmware
(:mod:`cartpole_emulator.qemu_board`) in place of its Python mirror. The
emulator's pseudo-terminal (``--link``, disconnects, stalls, link faults
unchanged) is relayed byte for byte to the firmware's UART0; the firmware's
UART1 is the plant channel: every ``O`` line (its DAC write, at its
``micros()``) brings the same :class:`cartpole_sim.plant.Plant` up to that
device time and changes the output, every ``T`` tick is answered with the
counters and limit switches. QEMU runs without ``-icount`` here, so the
device keeps real time like the rig. A scenario's ``drop`` loses the ``S``
line of its tick; the latency report is the firmware's own (its DAC write,
without a scenario ``delay``). docs/rig.md ("Firmware in QEMU").
"""
from __future__ import annotations

import select
import time
from collections import deque
from dataclasses import dataclass

from cartpole_core import realtime
from cartpole_core.model import CartPoleParameters
from cartpole_sim.plant import Scenario

from cartpole_hw import protocol as jp
from .emulated_rig import Emulator, FaultConfig
from .qemu_board import (FirmwareStatistics, QemuBoard, build_image, format_counts,
                         missing_message, missing_packages)

HOST_BACKLOG = 1 << 16
"""Host bytes waiting for the firmware's UART before the pty is no longer read [bytes]."""


@dataclass
class FirmwareOutput:
    """What the firmware last wrote to its "DAC" and enable pin (its ``O`` lines)."""

    dac_zero: int = 1953
    dac: int = 1953
    enabled: bool = False
    written_us: int = 0
    """Device time of the last write [us]."""
    last_u_us: int = 0
    """Device time [us] at which the firmware handled the last ``U`` (its output written then)."""

    def output_setpoint(self) -> int:
        """The setpoint the amplifier sees: 0 unless enabled."""
        return self.dac - self.dac_zero if self.enabled else 0

    def dac_value(self) -> int:
        return self.dac


class QemuDevice(Emulator):
    """The emulated rig with the compiled firmware in QEMU (module docstring)."""

    def __init__(self, scenario: Scenario | None = None, params: CartPoleParameters | None = None,
                 link: str | None = None, faults: FaultConfig | None = None,
                 limit_margin: float = 0.003, seed: int = 0, image: str | None = None) -> None:
        super().__init__(scenario, params, link, name='cartpole_bridge', faults=faults,
                         limit_margin=limit_margin, seed=seed)
        self.device = FirmwareOutput(dac_zero=self.calibration.dac_zero,
                                     dac=self.calibration.dac_zero)
        self.board = QemuBoard(image, icount_shift=None) if image else None
        self.statistics: FirmwareStatistics | None = None
        self.outputs: deque[tuple[int, int, bool, str]] = deque(maxlen=4000)
        """The firmware's last output writes: ``(t_us, dac, enabled, cause)``."""
        self.deadlines: deque[int] = deque(maxlen=400)
        """Device times [us] of the firmware's last sample deadlines (its ``T`` lines)."""
        self.plant_timeouts = 0
        self._to_firmware = bytearray()
        self._from_firmware = b''
        self._from_plant = b''
        self._lost: set[int] = set()
        self._clock_started = False
        self._want_statistics = False

    # -- device time ---------------------------------------------------------------------
    def _device_time(self, t_us: int) -> int:
        """Unwrapped device time [us] of the firmware's stamp ``t_us`` (never backwards)."""
        if not self._clock_started:
            self._clock_started = True
            self.t_us, self._device_us = t_us, t_us
            return t_us
        delta = (t_us - self.t_us) % jp.UINT32
        if delta < jp.UINT32 // 2:
            self.t_us = t_us
            self._device_us += delta
        return self._device_us

    def _advance(self, to_us: int) -> None:
        """The plant up to device time ``to_us`` under the output the firmware wrote last."""
        if to_us <= self._plant_us:
            return
        force = self.calibration.setpoint_to_force(self.device.output_setpoint())
        self.plant.step(force, (to_us - self._plant_us) * 1e-6)
        self._plant_us = to_us
        self.plant.applied_commands()   # the firmware reports its own DAC writes

    # -- the plant channel (UART1) ---------------------------------------------------------
    def _plant_line(self, line: bytes) -> None:
        fields = line.split(b',')
        kind = fields[0]
        if kind == b'T':
            self.deadlines.append(int(fields[1]))
            self._advance(self._device_time(int(fields[1])))
            left, right = self.limits()
            cart, pend = self.counters()
            self.board.plant.sendall(format_counts(cart, pend, left, right))
            if self.plant.sample_lost():
                self._lost.add(self.samples % jp.UINT32)
            self.samples += 1
            self._scheduled_faults(self._device_us * 1e-6)
            realtime.collect_when_idle()   # the period's answer is out
        elif kind == b'O':
            t_us = int(fields[1])
            self._advance(self._device_time(t_us))
            out = self.device
            out.dac, out.enabled, out.written_us = int(fields[2]), fields[3] == b'1', t_us
            cause = fields[4].decode(errors='replace')
            if cause == 'U':
                out.last_u_us = t_us
            self.outputs.append((t_us, out.dac, out.enabled, cause))
        elif kind == b'R':
            self._advance(self._device_time(int(fields[1])))
            self._offset = self.plant.encoder_counts()
        elif kind == b'M':
            self.statistics = FirmwareStatistics.parse(line.decode())
            self.plant_timeouts = self.statistics.plant_timeouts

    def request_statistics(self) -> None:
        """Ask the firmware for its ``M`` line now (it also sends one every second)."""
        self._want_statistics = True

    # -- the host link (UART0 <-> pty) --------------------------------------------------------
    def feed(self, data: bytes, now_us: int) -> None:  # noqa: ARG002 (the firmware stamps)
        """Host bytes from the pty: on to the firmware's UART0."""
        self._to_firmware += data

    def _firmware_line(self, line: bytes) -> None:
        if self._lost and line.startswith(b'S,'):
            message = jp.decode_line(line, 'device')
            if isinstance(message, jp.Sample) and message.seq in self._lost:
                self._lost.discard(message.seq)
                return
        self._send(line)

    @staticmethod
    def _lines(channel, pending: bytes) -> tuple[list[bytes], bytes]:
        """The complete lines read from a UART's socket (without '\\n') and the rest."""
        data = channel.recv(65536)
        if not data:
            raise ConnectionError('the firmware board stopped (qemu-system-arm exited)')
        *lines, rest = (pending + data).split(b'\n')
        return lines, rest

    def _pump(self, readable: list, writable: list) -> None:
        board = self.board
        if board.plant in readable:
            lines, self._from_plant = self._lines(board.plant, self._from_plant)
            for line in lines:
                if line:
                    self._plant_line(line)
        if board.host in readable:
            lines, self._from_firmware = self._lines(board.host, self._from_firmware)
            for line in lines:
                self._firmware_line(line + b'\n')
        if board.host in writable and self._to_firmware:
            sent = board.host.send(self._to_firmware)
            del self._to_firmware[:sent]
        if self._master is not None and self._master in readable:
            self._receive()

    # -- main loop ------------------------------------------------------------------------------
    def power_on(self) -> None:
        """Start QEMU with the image (built by ``make -C firmware arm-image`` if not given)."""
        if self.board is None:
            self.board = QemuBoard(build_image(), icount_shift=None)
        if not self.board.running:
            self.board.start()
            self._boot()
            self.board.host.setblocking(False)

    def _boot(self) -> None:
        """Take the firmware's power-up lines (its output written, its counters reset)
        before anything else happens to the plant."""
        self._from_plant += self.board.boot()
        *lines, self._from_plant = self._from_plant.split(b'\n')
        for line in lines:
            if line:
                self._plant_line(line)

    def run(self, duration: float | None = None) -> None:
        """Relay and step the plant until :meth:`stop` (or ``duration`` seconds)."""
        self.power_on()
        if self._master is None and self._reconnect_at is None:
            self.open()
        t0 = time.monotonic()
        board = self.board
        left, right = self.limits()   # served from now on: the firmware starts its clock
        board.plant.sendall(f'G,{int(left) | int(right) << 1}\n'.encode())
        while not self._stop.is_set():
            now = time.monotonic()
            if duration is not None and now - t0 >= duration:
                break
            self._cable(now)
            if self._want_statistics:
                self._want_statistics = False
                board.plant.sendall(b'Q\n')
            release = self._flush_outbox(now)
            readable = [board.plant, board.host]
            stalled = now < self._stall_until
            if self._master is not None and not stalled and len(self._to_firmware) < HOST_BACKLOG:
                readable.append(self._master)
            writable = [board.host] if self._to_firmware else []
            timeout = 0.05 if release is None else min(0.05, max(release - now, 0.0))
            try:
                ready, can_write, _ = select.select(readable, writable, [], timeout)
            except (OSError, ValueError):
                ready, can_write = [], []   # the pty closed under us (a disconnect)
            self._pump(ready, can_write)

    def start(self) -> str:
        self.power_on()
        return super().start()

    def shutdown(self) -> None:
        self.close()
        if self.board is not None:
            self.board.stop()


def firmware_available() -> tuple[bool, str]:
    """Whether the ARM toolchain and QEMU are installed; else the message naming the packages."""
    missing = missing_packages()
    return (not missing, missing_message(missing) if missing else '')


