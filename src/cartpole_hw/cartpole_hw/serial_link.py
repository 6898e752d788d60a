"""The serial port around :class:`~cartpole_hw.bridge.BridgeCore`: a reader thread.

The port is opened by :meth:`SerialLink.open` (the node's configure, which
reports a port that cannot be opened) or by the thread, which re-opens it
every ``reconnect_period`` while it is gone. The thread reads with a timeout
of the core's ``tick_period`` (2 ms), splits lines, hands each to the core and
runs the core's watchdogs once nothing waits in the port, so after a stall of
this process the piled-up lines are taken first and the watchdogs judge the
device, not this process's scheduling. Samples go to ``notify`` (the node
queues them for its executor: nothing is published from this thread). Writes
from this thread and the caller's hold ``lock``, the core's, so the lines on
the wire are in the order of the core's decisions; a write fails only when the
port stays unwritable for :data:`WRITE_TIMEOUT`. A failed read or write closes
the port and the core disarms. docs/rig.md ("Conversions, device-time stamps
and the safety rules"). No ROS.
"""
from __future__ import annotations

import os
import select
import threading
import time
from typing import Callable

import serial

from .line_splitter import LineSplitter
from .bridge import BridgeCore
from .bridge_records import JointSample

WRITE_TIMEOUT = 0.05
"""Longest time the port may stay unwritable before the link counts as broken [s]."""
MAX_DEFERRED_TICKS = 16
"""Reads in a row that may put the watchdogs off because more bytes are waiting."""


def _scheduling() -> tuple[int, int] | None:
    """(policy, priority) of the calling thread if it is a real-time one (Linux), else None."""
    if not hasattr(os, 'sched_getscheduler'):
        return None
    policy = os.sched_getscheduler(0)
    if policy & ~getattr(os, 'SCHED_RESET_ON_FORK', 0) == os.SCHED_OTHER:
        return None
    return policy, os.sched_getparam(0).sched_priority


def write_all(fd: int, data: bytes, timeout: float) -> None:
    """Write every byte to the non-blocking ``fd``; TimeoutError only if it stays
    unwritable until ``timeout`` s after the call (a late thread is not a dead port)."""
    deadline = time.monotonic() + timeout
    view = memoryview(data)
    while view:
        try:
            view = view[os.write(fd, view):]
            continue
        except BlockingIOError:
            pass
        _, ready, _ = select.select([], [fd], [], max(0.0, deadline - time.monotonic()))
        if not ready:
            raise TimeoutError(f'port not writable for {timeout:g} s '
                               f'({len(view)} of {len(data)} bytes unsent)')


class SerialLink:
    """Owns the port and the reader thread of one bridge."""

    def __init__(self, core: BridgeCore, port: str, baud: int = 115200,
                 notify: Callable[[list[JointSample]], None] | None = None,
                 reconnect_period: float = 0.5, lock: threading.Lock | None = None,
                 clock: Callable[[], float] = time.monotonic,
                 logger: Callable[[str], None] | None = None) -> None:
        self.core = core
        self.port = port
        self.baud = int(baud)
        self.notify = notify
        self.reconnect_period = float(reconnect_period)
        self.lock = lock or threading.RLock()
        self.clock = clock
        self.log = logger or (lambda text: None)
        self._serial: serial.Serial | None = None
        self._broken: str | None = None
        self._splitter = LineSplitter()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._deferred = 0
        self._polled = threading.Condition()
        self.open_error = ''

    # -- public ------------------------------------------------------------------------------
    def open(self) -> str:
        """Open the port now, in the caller's thread: '' on success, else the reason."""
        return '' if self._open() else self.open_error

    def wait_for(self, predicate: Callable[[BridgeCore], bool], timeout: float) -> bool:
        """Wait (in the caller's thread) until ``predicate(core)`` holds after a read of the
        reader thread, at most ``timeout`` s; the reader must be running."""
        deadline = self.clock() + timeout
        with self._polled:
            while True:
                with self.lock:
                    if predicate(self.core):
                        return True
                remaining = deadline - self.clock()
                if remaining <= 0 or self._thread is None:
                    return False
                self._polled.wait(min(remaining, 0.1))

    def start(self) -> None:
        """Start the reader thread, at the scheduling of the calling thread (a thread
        created after the process took its real-time priority would run at normal
        priority: ``SCHED_RESET_ON_FORK`` resets it for new threads too)."""
        self._stop.clear()
        scheduling = _scheduling()
        self._thread = threading.Thread(target=self._run, args=(scheduling,),
                                        name='cartpole-hw-link', daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Zero force, disable, stop streaming, close: the last words on the port."""
        with self.lock:
            self.write(self.core.shutdown())
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        self._close('shutdown')

    def call(self, request: Callable[[BridgeCore, float], tuple[bool, str, list[bytes]]]
             ) -> tuple[bool, str]:
        """Run ``request(core, now)`` under the lock and write the lines it returns."""
        with self.lock:
            ok, reason, lines = request(self.core, self.clock())
            self.write(lines)
        return ok, reason

    def write(self, lines: list[bytes]) -> None:
        """Send lines (call with :attr:`lock` held). A failure marks the port broken."""
        if not lines:
            return
        port = self._serial
        if port is None:
            return
        try:
            write_all(port.fileno(), b''.join(lines), WRITE_TIMEOUT)
        except (serial.SerialException, OSError, ValueError) as exc:
            self._broken = f'write failed: {exc}'

    @property
    def is_open(self) -> bool:
        return self._serial is not None

    # -- thread ----------------------------------------------------------------------------------
    def _open(self) -> bool:
        try:
            port = serial.Serial(self.port, self.baud, timeout=self.core.config.tick_period,
                                 exclusive=True)
        except (serial.SerialException, OSError, ValueError) as exc:
            if str(exc) != self.open_error:
                self.log(f'cannot open {self.port}: {exc}')
            self.open_error = str(exc)
            return False
        self.open_error = ''
        self._splitter.reset()
        self._broken = None
        with self.lock:
            self._serial = port
            self.write(self.core.on_connect(self.clock()))
        self.log(f'opened {self.port}')
        return True

    def _close(self, reason: str) -> None:
        with self.lock:
            port, self._serial = self._serial, None
            if port is not None:
                self.core.on_disconnect(self.clock(), reason, orderly=reason == 'shutdown')
        if port is not None and reason != 'shutdown' and self.notify is not None:
            self.notify([])
        if port is not None:
            try:
                port.close()
            except (serial.SerialException, OSError):
                pass
            if reason != 'shutdown':
                self.log(f'closed {self.port}: {reason}')

    @staticmethod
    def _bytes_waiting(port: serial.Serial) -> int:
        try:
            return port.in_waiting
        except (serial.SerialException, OSError, TypeError, AttributeError):
            return 0  # the next read reports the failure

    def _run(self, scheduling: tuple[int, int] | None = None) -> None:
        if scheduling is not None:
            try:
                os.sched_setscheduler(0, scheduling[0], os.sched_param(scheduling[1]))
            except OSError as exc:   # not permitted: the thread runs at normal priority
                self.log(f'reader thread at normal priority: {exc}')
        next_attempt = 0.0
        while not self._stop.is_set():
            if self._serial is None:
                now = self.clock()
                if now >= next_attempt:
                    next_attempt = now + self.reconnect_period
                    if self._open():
                        continue
                with self.lock:
                    self.write(self.core.on_tick(self.clock()))
                self._stop.wait(min(0.02, max(0.0, next_attempt - self.clock())))
                continue
            if self._broken:
                self._close(self._broken)
                continue
            self._poll(self._serial)

    def _poll(self, port: serial.Serial) -> None:
        """One read of the port: lines to the core, watchdogs, samples to ``notify``."""
        try:
            data = port.read(max(1, port.in_waiting))
        except (serial.SerialException, OSError, TypeError, AttributeError) as exc:
            self._close(f'read failed: {exc}')
            return
        now = self.clock()
        samples: list[JointSample] = []
        with self.lock:
            armed = self.core.armed
            for item in self._splitter.feed(data) if data else ():
                out = self.core.on_line(item, now)
                self.write(out.write)
                if out.sample is not None:
                    samples.append(out.sample)
            # The watchdogs judge time `tick_time` only if every byte that came before
            # it has been read; else the next read takes them first (a bounded number of
            # times, so a flood cannot keep the watchdogs away).
            tick_time = self.clock()
            if self._bytes_waiting(port) and self._deferred < MAX_DEFERRED_TICKS:
                self._deferred += 1
            else:
                self._deferred = 0
                self.write(self.core.on_tick(tick_time))
            changed = self.core.armed != armed
        if self.notify is not None and (samples or changed):
            self.notify(samples)
        with self._polled:
            self._polled.notify_all()
