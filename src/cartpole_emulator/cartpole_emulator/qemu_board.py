"""The bridge firmware compiled for the Cortex-M3, running in ``qemu-system-arm``.

``firmware/qemu_lm3s6965/`` is the firmware's board layer for QEMU's
``lm3s6965evb`` machine. :class:`QemuBoard` starts QEMU with that image and
hands out its two serial channels as connected Unix sockets: UART0, the host
link (Joint protocol lines, as the Due's USB serial carries them), and UART1,
the plant channel standing in for the Due's pins (``T`` ticks answered with
the HCTL-2021 bus bytes, ``O`` outputs, ``R`` counter resets, ``M``
statistics, :class:`FirmwareStatistics`). With ``-icount`` the firmware's own
SysTick measures its work in instructions. The plant channel's lines in
detail: docs/rig.md ("Firmware in QEMU").

Only the standard library: ``firmware/tools/firmware_report.py`` loads this
file by path for ``make -C firmware arm``.
"""
from __future__ import annotations

import ctypes
import os
import re
import shutil
import signal
import socket
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

PACKAGES = ('gcc-arm-none-eabi', 'libnewlib-arm-none-eabi', 'qemu-system-arm')
"""The Debian packages the ARM build and the QEMU device need."""
TOOLS = {'arm-none-eabi-g++': 'gcc-arm-none-eabi', 'qemu-system-arm': 'qemu-system-arm'}
MACHINE = 'lm3s6965evb'
"""QEMU's machine for the firmware's board layer (``firmware/qemu_lm3s6965/``)."""
ICOUNT_SHIFT = 3
"""-icount shift: one instruction is 2**3 = 8 ns of device time (125 MIPS, the Due runs 84 MHz)."""
SAMPLE_PERIOD_US = 5000
DUE_CLOCK_HZ = 84_000_000
"""The SAM3X8E's core clock: the Due's budget per 5 ms tick is 420 000 cycles."""


def _die_with_parent():
    """A ``preexec_fn`` for QEMU: SIGTERM to it when the thread that started it ends (Linux
    prctl PR_SET_PDEATHSIG), so a killed emulator leaves no board running; None elsewhere.
    Looked up here, in the parent: the child between fork and exec must not import."""
    try:
        prctl = ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):
        return None
    return lambda: prctl(1, signal.SIGTERM, 0, 0, 0)


def missing_packages() -> list[str]:
    """The Debian packages (of :data:`PACKAGES`) whose tools are not on PATH, and newlib."""
    missing = [package for tool, package in TOOLS.items() if shutil.which(tool) is None]
    gcc = shutil.which('arm-none-eabi-gcc')
    if gcc is not None:
        probe = subprocess.run([gcc, '-print-file-name=libc_nano.a'], capture_output=True,
                               text=True)
        if not os.path.isabs(probe.stdout.strip()):
            missing.append('libnewlib-arm-none-eabi')
    return missing


def missing_message(missing: list[str]) -> str:
    return (f'the ARM toolchain / QEMU is missing (Debian packages {" ".join(missing)}): '
            f'apt-get install {" ".join(PACKAGES)}, or `make -C firmware arm-deps` as root')


def firmware_dir() -> Path:
    """The repository's ``firmware/`` (next to ``src/``: this file is src/cartpole_hw/cartpole_hw/)."""
    return Path(os.path.realpath(__file__)).parents[3] / 'firmware'


def default_image() -> Path:
    return firmware_dir() / 'build' / 'arm' / 'cartpole_bridge.elf'


def build_image(firmware: Path | None = None) -> Path:
    """``make -C firmware arm-image`` (incremental); returns the image's path."""
    firmware = firmware or firmware_dir()
    result = subprocess.run(['make', '-s', '-C', str(firmware), 'arm-image'],
                            capture_output=True, text=True, timeout=300)
    if result.returncode != 0:
        raise RuntimeError(f'building the firmware image failed:\n{result.stdout}{result.stderr}')
    return firmware / 'build' / 'arm' / 'cartpole_bridge.elf'


@dataclass(frozen=True)
class FirmwareStatistics:
    """The firmware's ``M`` line: its counters and its measured work.

    Work is in SysTick clocks of the emulated 25 MHz CPU clock; with
    ``-icount shift=N`` one clock is 40 ns / 2**N instructions
    (:meth:`instructions`).
    """

    samples: int
    tick_max: int
    """Worst deadline: watchdog, limits, output written, the plant asked (``T``)."""
    sample_max: int
    """Worst completion of a sample: the plant's counts taken, the ``S`` line sent."""
    period_max: int
    """Busiest 5 ms period: all the loop's work in it (its sample, the host lines handled,
    and one pass of the loop per handful of bytes the UART's FIFO delivers)."""
    line_max: int
    """Worst single host byte (the one completing a line: decode, act, reply)."""
    stack_bytes: int
    """High-water mark of the main stack (painted at reset)."""
    lines_in: int
    refused: int
    oversized: int
    tx_dropped: int
    overruns: int
    plant_timeouts: int
    """Samples lost because the plant's process was 40 samples (200 ms) behind."""
    pending_max: int
    """Most samples waiting for the plant's answer at once."""
    clock_hz: int

    @classmethod
    def parse(cls, line: str) -> 'FirmwareStatistics':
        fields = line.strip().split(',')
        if fields[0] != 'M' or len(fields) != 15:
            raise ValueError(f'not a statistics line: {line!r}')
        return cls(*(int(f) for f in fields[1:]))

    def instructions(self, clocks: int, shift: int = ICOUNT_SHIFT) -> int:
        """Instructions executed in ``clocks`` SysTick clocks under ``-icount shift``."""
        return round(clocks * (1e9 / self.clock_hz) / 2 ** shift)


def format_counts(cart: int, pend: int, left: bool, right: bool) -> bytes:
    """The plant's answer to ``T``: the two 16-bit counters as bus bytes, the limit switches."""
    cart &= 0xFFFF
    pend &= 0xFFFF
    return f'C,{cart:04X}{pend:04X}{int(left) | int(right) << 1:X}\n'.encode()


class QemuBoard:
    """``qemu-system-arm -M lm3s6965evb`` running ``image``; :meth:`start`, then use
    :attr:`host` and :attr:`plant` (blocking sockets), :meth:`stop` at the end."""

    def __init__(self, image: str | os.PathLike, qemu: str = 'qemu-system-arm',
                 icount_shift: int | None = ICOUNT_SHIFT, realtime: bool = True) -> None:
        self.image = Path(image)
        self.qemu = qemu
        self.icount_shift = icount_shift
        self.realtime = realtime
        self.process: subprocess.Popen | None = None
        self.host: socket.socket | None = None
        self.plant: socket.socket | None = None
        self._dir: tempfile.TemporaryDirectory | None = None

    def command(self, host_path: str, plant_path: str) -> list[str]:
        return [self.qemu, '-M', MACHINE, '-display', 'none', '-monitor', 'none', '-nic', 'none',
                *self.icount_args(),
                '-chardev', f'socket,id=host,path={host_path}',
                '-chardev', f'socket,id=plant,path={plant_path}',
                '-serial', 'chardev:host', '-serial', 'chardev:plant',
                '-kernel', str(self.image)]

    def icount_args(self) -> list[str]:
        if self.icount_shift is None:
            return []
        return ['-icount', f'shift={self.icount_shift},sleep={"on" if self.realtime else "off"}']

    def start(self, timeout: float = 20.0) -> None:
        if not self.image.is_file():
            raise FileNotFoundError(f'firmware image not found: {self.image} '
                                    '(make -C firmware arm-image)')
        self._dir = tempfile.TemporaryDirectory(prefix='cartpole-qemu-')
        listeners = {}
        for name in ('host', 'plant'):
            path = os.path.join(self._dir.name, f'{name}.sock')
            s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            s.bind(path)
            s.listen(1)
            s.settimeout(timeout)
            listeners[name] = (s, path)
        try:
            self.process = subprocess.Popen(
                self.command(listeners['host'][1], listeners['plant'][1]),
                stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                preexec_fn=_die_with_parent())
            # QEMU connects its chardevs in the order given, before the guest runs
            for name, (s, _) in listeners.items():
                try:
                    conn, _ = s.accept()
                except socket.timeout:
                    raise RuntimeError(f'qemu-system-arm did not connect its {name} UART: '
                                       f'{self._stderr()}') from None
                conn.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 1 << 16)
                setattr(self, name, conn)
        except BaseException:
            self.stop()
            raise
        finally:
            for s, _ in listeners.values():
                s.close()

    def boot(self, timeout: float = 10.0) -> bytes:
        """Wait for the firmware's power-up lines on the plant channel (its output written,
        its decoders' counters reset: ``R,<t_us>``) and return the bytes that came. Its UARTs
        are set up then: a byte sent before may be lost, as setting up a PL011's FIFOs
        empties them (and on a real board a byte before the UART is enabled is lost too)."""
        plant = self.plant
        received = b''
        plant.settimeout(timeout)
        try:
            while not re.search(rb'(^|\n)R,\d+\n', received):
                data = plant.recv(4096)
                if not data:
                    raise ConnectionError('the firmware board stopped while booting')
                received += data
        except TimeoutError:
            raise RuntimeError('the firmware did not boot (no counter reset on its plant '
                               f'channel): {self._stderr()}') from None
        finally:
            plant.settimeout(None)
        return received

    def _stderr(self) -> str:
        if self.process is None:
            return ''
        if self.process.poll() is None:
            self.process.kill()
        return self.process.communicate(timeout=5)[1].decode(errors='replace')[-2000:]

    def prioritise(self, priority: int) -> int:
        """SCHED_FIFO ``priority`` for every QEMU thread (the emulated CPU must not be
        descheduled while its clock, the host's, runs on); returns how many took it."""
        done = 0
        try:
            tids = [int(t) for t in os.listdir(f'/proc/{self.process.pid}/task')]
        except (OSError, AttributeError):
            return 0
        for tid in tids:
            try:
                os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(priority))
                done += 1
            except OSError:
                continue
        return done

    @property
    def running(self) -> bool:
        return self.process is not None and self.process.poll() is None

    def stop(self) -> None:
        for name in ('host', 'plant'):
            s = getattr(self, name)
            if s is not None:
                s.close()
                setattr(self, name, None)
        if self.process is not None:
            if self.process.poll() is None:
                self.process.terminate()
                try:
                    self.process.wait(timeout=5)
                except subprocess.TimeoutExpired:
                    self.process.kill()
                    self.process.wait()
            if self.process.stderr is not None:
                self.process.stderr.close()
            self.process = None
        if self._dir is not None:
            self._dir.cleanup()
            self._dir = None
