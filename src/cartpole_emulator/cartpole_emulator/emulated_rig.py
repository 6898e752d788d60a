"""The emulated rig: the simulated plant behind the Joint protocol on a pseudo-terminal.

The rig as the host sees it over USB: :class:`cartpole_sim.plant.Plant`
(actuator (4.4), saturation, end stops, 16-bit encoders) driven through the
firmware's command logic (:class:`~cartpole_hw.device.DeviceLogic`, the mirror
of ``joint_protocol.cpp``) and the DAC (F = setpoint / 56.744, (A.3)), one 5 ms
sample per period on a ``time.monotonic`` deadline schedule. Host lines act at
their own device time, as the firmware handles them at ``micros()``; the
scenario's disturbances run in the plant, a dropped sample skips its ``seq``.
:class:`FaultConfig` injects the link's faults (lost or corrupted lines, USB
jitter, stalls, a pulled cable) for testing the bridge. The schedule, the
latency report and every fault in detail: docs/rig.md ("cartpole emulate").
The command line is :mod:`cartpole_emulator.emulator`; the compiled firmware
in QEMU is :mod:`cartpole_emulator.qemu_device`.
"""
from __future__ import annotations

import math
import os
import random
import select
import threading
import time
import tty
from collections import deque
from dataclasses import dataclass, field

from cartpole_core import realtime
from cartpole_core.model import CartPoleParameters, wrap_counter
from cartpole_sim.plant import Plant, Scenario

from cartpole_hw import protocol as jp
from cartpole_hw.calibration import Calibration
from cartpole_hw.device import DeviceLogic
from cartpole_hw.line_splitter import LineSplitter


@dataclass
class FaultConfig:
    """Fault injection of the emulated link (see the module docstring)."""

    drop: float = 0.0
    corrupt: float = 0.0
    usb_jitter: float = 0.0
    """Largest extra latency of an outgoing line [s] (uniform in [0, usb_jitter])."""
    stalls: list[tuple[float, float]] = field(default_factory=list)
    """(device time [s], duration [ms]) of link stalls."""
    disconnects: list[tuple[float, float]] = field(default_factory=list)
    """(device time [s], duration [s]) of disconnects."""

    def __post_init__(self) -> None:
        if not (math.isfinite(self.usb_jitter) and 0.0 <= self.usb_jitter <= 1.0):
            raise ValueError(f'usb_jitter must be in [0, 1] s, got {self.usb_jitter!r}')
        for name in ('drop', 'corrupt'):
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise ValueError(f'{name} must be a probability in [0, 1], got {value!r}')


class Emulator:
    """The emulated rig on a pty. ``open()``, then ``run()`` (or ``start()`` a thread); the
    firmware's state machine is :class:`cartpole_hw.device.DeviceLogic`, the plant
    :class:`cartpole_sim.plant.Plant`."""

    def __init__(self, scenario: Scenario | None = None, params: CartPoleParameters | None = None,
                 link: str | None = None, name: str = 'cartpole_emulator',
                 faults: FaultConfig | None = None, limit_margin: float = 0.003,
                 seed: int = 0) -> None:
        self.params = params or CartPoleParameters()
        self.scenario = scenario or Scenario()
        self.plant = Plant(self.params, self.scenario)
        self.calibration = Calibration.from_parameters(self.params)
        self.device = DeviceLogic(name=name, dac_zero=self.calibration.dac_zero,
                                  dac_max=self.calibration.dac_max,
                                  sample_period_us=int(round(self.params.sample_time * 1e6)))
        self.link = link
        self.faults = faults or FaultConfig()
        self.limit_margin = float(limit_margin)
        self._rng = random.Random(seed)
        self._usb_rng = random.Random(f'{seed}:usb')   # jitter does not change the faults' draws
        self._outbox: deque[tuple[float, bytes]] = deque()
        """Lines held back by the USB jitter: (release time, line), in order."""
        self._splitter = LineSplitter()
        self._master: int | None = None
        self._slave: int | None = None
        self.port: str | None = None
        self._offset = (0, 0)       # raw counts at the last R (HCTL RST)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._stall_until = -1.0
        self._reconnect_at: float | None = None
        self._pending_disconnect: float | None = None
        self.t_us = 0
        """Device time of the coming sample period [us] (uint32, wraps like ``micros()``)."""
        self._device_us = 0
        """The same, unwrapped (the plant's clock: plant time = device time)."""
        self._plant_us = 0
        """Unwrapped device time the plant has been brought up to [us]."""
        self.applied: deque[tuple[int, int, int]] = deque(maxlen=1000)
        """``(tag, t_us of the tagged sample, applied t_us)`` of the latest tagged commands
        that took effect on the plant: the device's own record of the loop's latency."""
        self._tag_sample_us: dict[int, int] = {}
        """seq -> t_us of the recent samples (the last 100), for :attr:`applied`."""
        self.samples = 0
        self.overruns = 0
        self.lines_in = 0
        self.lines_out = 0
        self.tx_dropped = 0
        self.disconnect_count = 0
        self.received: list[bytes] = []   # last host lines, for tests and debugging
        self.on_port_change = None        # callback(path) after (re)opening a pty

    # -- pty management --------------------------------------------------------------
    def open(self) -> str:
        """Open a new pseudo-terminal; returns the slave path (and points the link at it)."""
        master, slave = os.openpty()
        tty.setraw(slave)
        os.set_blocking(master, False)
        self._master, self._slave = master, slave
        self.port = os.ttyname(slave)
        self._splitter.reset()
        if self.link:
            tmp = f'{self.link}.tmp{os.getpid()}'
            try:
                os.unlink(tmp)
            except FileNotFoundError:
                pass
            os.symlink(self.port, tmp)
            os.replace(tmp, self.link)
        if self.on_port_change:
            self.on_port_change(self.port)
        return self.port

    def close(self) -> None:
        """Close the pty (the slave device vanishes) and remove the link."""
        for fd in (self._master, self._slave):
            if fd is not None:
                try:
                    os.close(fd)
                except OSError:
                    pass
        self._master = self._slave = None
        self._outbox.clear()   # lines still in flight are lost with the cable
        if self.link and os.path.islink(self.link):
            try:
                os.unlink(self.link)
            except FileNotFoundError:
                pass

    @property
    def connected(self) -> bool:
        return self._master is not None

    # -- fault requests (thread-safe) ----------------------------------------------------
    def disconnect(self, duration: float) -> None:
        """Pull the cable for ``duration`` seconds (done by the emulator's loop)."""
        with self._lock:
            self._pending_disconnect = float(duration)

    def stall(self, duration_ms: float) -> None:
        with self._lock:
            self._stall_until = time.monotonic() + duration_ms / 1000.0

    def set_faults(self, drop: float | None = None, corrupt: float | None = None) -> None:
        with self._lock:
            if drop is not None:
                self.faults.drop = float(drop)
            if corrupt is not None:
                self.faults.corrupt = float(corrupt)

    # -- I/O ---------------------------------------------------------------------------------
    def _send(self, line: bytes) -> None:
        if self._master is None or time.monotonic() < self._stall_until:
            self.tx_dropped += 1
            return
        with self._lock:
            drop, corrupt = self.faults.drop, self.faults.corrupt
        if drop and self._rng.random() < drop:
            self.tx_dropped += 1
            return
        if corrupt and self._rng.random() < corrupt and len(line) > 1:
            data = bytearray(line)
            i = self._rng.randrange(len(data) - 1)
            choices = [b for b in range(256) if b not in (0x0A, data[i])]
            data[i] = self._rng.choice(choices)
            line = bytes(data)
        jitter = self.faults.usb_jitter
        if jitter > 0.0:
            release = time.monotonic() + self._usb_rng.uniform(0.0, jitter)
            if self._outbox:
                release = max(release, self._outbox[-1][0])  # USB keeps the order
            self._outbox.append((release, line))
            return
        self._write(line)

    def _flush_outbox(self, now: float) -> float | None:
        """Write the held-back lines that are due; the next release time, if any."""
        while self._outbox and self._outbox[0][0] <= now:
            self._write(self._outbox.popleft()[1])
        return self._outbox[0][0] if self._outbox else None

    def _write(self, line: bytes) -> None:
        if self._master is None:
            self.tx_dropped += 1
            return
        try:
            os.write(self._master, line)
            self.lines_out += 1
        except (BlockingIOError, OSError):
            self.tx_dropped += 1   # nobody reads the pty: its buffer is full

    def _receive(self, now_us: int | None = None) -> None:
        """Read the pty and handle its lines at device time ``now_us`` (default: the
        coming period's)."""
        if self._master is None or time.monotonic() < self._stall_until:
            return
        try:
            data = os.read(self._master, 4096)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            return
        self.feed(data, self.t_us if now_us is None else now_us)

    def feed(self, data: bytes, now_us: int) -> None:
        """Host bytes arriving at device time ``now_us`` [us] (at most one period before
        the coming one): the plant is brought up to then, and every complete line acts."""
        items = self._splitter.feed(data)
        if items:
            self._advance(self._device_us - (self.t_us - now_us) % jp.UINT32)
        for item in items:
            if isinstance(item, jp.DecodeError):
                self._send(self.device.error(jp.ERROR_CODES[item.reason], item.reason))
                continue
            self.lines_in += 1
            self.received.append(item)
            del self.received[:-200]
            replies, reset = self.device.handle_line(item, now_us)
            if reset:
                self._offset = self.plant.encoder_counts()
            for reply in replies:
                self._send(reply)

    def _advance(self, to_us: int) -> None:
        """Run the plant up to the unwrapped device time ``to_us`` under the output in
        force (the DAC's setpoint, zero-order hold); a tagged command written since the
        last call goes in with its tag, and the plant's reports of tagged commands that
        acted become the device's latency report."""
        if to_us <= self._plant_us:
            return
        tag = self.device.take_pending()
        force = self.calibration.setpoint_to_force(self.device.output_setpoint())
        self.plant.step(force, (to_us - self._plant_us) * 1e-6, tag)
        self._plant_us = to_us
        for tag_, applied in self.plant.applied_commands():
            applied_us = int(round(applied * 1e6)) % jp.UINT32
            self.device.command_applied(int(tag_), applied_us)
            sampled = self._tag_sample_us.get(int(tag_))
            if sampled is not None:
                self.applied.append((int(tag_), sampled, applied_us))

    def device_time_us(self, until_next_period: float) -> int:
        """Device time [us] ``until_next_period`` wall seconds before the coming period."""
        ahead = min(max(int(until_next_period * 1e6), 0), self.device.sample_period_us - 1)
        return (self.t_us - ahead) % jp.UINT32

    # -- one sample period ---------------------------------------------------------------
    def limits(self) -> tuple[bool, bool]:
        """Limit switches: the cart within ``limit_margin`` of an end stop or in it."""
        x = self.plant.state[0]
        return x <= self.limit_margin, x >= self.plant.true_params.travel - self.limit_margin

    def counters(self) -> tuple[int, int]:
        """The HCTL-2021 counters: raw plant counts since the last ``R``, 16-bit."""
        cart, pend = self.plant.encoder_counts()
        bits = self.params.counter_bits
        return (wrap_counter(cart - self._offset[0], bits), wrap_counter(pend - self._offset[1], bits))

    def sample_period(self) -> None:
        """One 5 ms period of the firmware loop: the plant up to its start, limit switches,
        watchdog, the sample."""
        self._advance(self._device_us)
        left, right = self.limits()
        for line in self.device.tick(self.t_us, left, right):
            self._send(line)
        cart, pend = self.counters()
        lost = self.plant.sample_lost()  # scenario drop: this sample never reaches the host
        seq = self.device.seq
        self._tag_sample_us[seq] = self.t_us
        self._tag_sample_us.pop((seq - 100) % jp.UINT32, None)
        line = self.device.sample_line(self.t_us, cart, pend)
        if line is not None and not lost:
            self._send(line)
        self.samples += 1
        period_us = int(round(self.params.sample_time * 1e6))
        self.t_us = (self.t_us + period_us) % jp.UINT32
        self._device_us += period_us

    def _scheduled_faults(self, t: float) -> None:
        for at, ms in list(self.faults.stalls):
            if t >= at:
                self.faults.stalls.remove((at, ms))
                self.stall(ms)
        for at, duration in list(self.faults.disconnects):
            if t >= at:
                self.faults.disconnects.remove((at, duration))
                self.disconnect(duration)

    # -- main loop -------------------------------------------------------------------------
    def _cable(self, now: float) -> None:
        """Pull the cable if asked (:meth:`disconnect`), plug it back in when it is time."""
        with self._lock:
            pending, self._pending_disconnect = self._pending_disconnect, None
        if pending is not None and self._master is not None:
            self.close()
            self.disconnect_count += 1
            self._reconnect_at = now + pending
        if self._reconnect_at is not None and now >= self._reconnect_at:
            self._reconnect_at = None
            self.open()

    def run(self, duration: float | None = None) -> None:
        """Serve until :meth:`stop` (or ``duration`` seconds), in simulated real time."""
        if self._master is None and self._reconnect_at is None:
            self.open()
        ts = self.params.sample_time
        t0 = time.monotonic()
        k = 0
        while not self._stop.is_set():
            now = time.monotonic()
            if duration is not None and now - t0 >= duration:
                break
            self._cable(now)
            deadline = t0 + k * ts
            release = self._flush_outbox(now)
            if now >= deadline:
                self._receive()
                self._scheduled_faults(k * ts)
                self.sample_period()
                realtime.collect_when_idle()   # the period's work is done
                k += 1
                if now - (t0 + k * ts) > 0.2:      # far behind (suspended?): resynchronise
                    self.overruns += 1
                    k = int((now - t0) / ts) + 1
                continue
            timeout = min(deadline - now, 0.05,
                          max(release - now, 0.0) if release is not None else 0.05)
            if self._master is not None:
                try:
                    ready, _, _ = select.select([self._master], [], [], timeout)
                except (OSError, ValueError):
                    ready = []
                if ready:
                    self._receive(self.device_time_us(deadline - time.monotonic()))
            else:
                self._stop.wait(timeout)

    def start(self) -> str:
        """Open the pty and run the loop on a daemon thread; returns the port path."""
        port = self.open()
        self._stop.clear()
        self._thread = threading.Thread(target=self.run, name='cartpole-emulator', daemon=True)
        self._thread.start()
        return port

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        self.shutdown()

    def shutdown(self) -> None:
        """The end of the device: the pty closed (a subclass also powers its board off)."""
        self.close()

    def __enter__(self) -> 'Emulator':
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()
