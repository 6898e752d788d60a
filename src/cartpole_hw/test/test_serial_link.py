"""The serial link's reader loop on a fake port, in simulated time: a stall of the host
process must not be mistaken for a silent device, nor a late writer for a dead port."""
import fcntl
import os

import pytest

from cartpole_hw import protocol as jp
from cartpole_hw.bridge import BridgeCore
from cartpole_hw.serial_link import SerialLink, write_all


def pipe():
    """A non-blocking pipe (as pyserial opens a port): (read end, write end)."""
    r, w = os.pipe()
    for fd in (r, w):
        fcntl.fcntl(fd, fcntl.F_SETFL, fcntl.fcntl(fd, fcntl.F_GETFL) | os.O_NONBLOCK)
    return r, w


class FakePort:
    """What pyserial's Serial offers the link: read, in_waiting, fileno (writes)."""

    def __init__(self):
        self.pending = b''
        self.read_times_out = False
        self._r, self._w = pipe()

    def fileno(self):
        return self._w

    @property
    def written(self):
        out = b''
        while True:
            try:
                chunk = os.read(self._r, 65536)
            except BlockingIOError:
                return out
            out += chunk

    @property
    def in_waiting(self):
        return len(self.pending)

    def read(self, n):
        if self.read_times_out:          # the read that was under way when the stall began
            self.read_times_out = False
            return b''
        data, self.pending = self.pending[:n], self.pending[n:]
        return data


class Clock:
    def __init__(self):
        self.now = 0.0

    def __call__(self):
        return self.now


def armed_link():
    clock = Clock()
    core = BridgeCore()
    core.on_connect(0.0)
    core.on_line(jp.encode(jp.Version(1, 'dev'))[:-1], 0.0)
    core.home(0.0)
    core.on_line(jp.encode(jp.Version(1, 'dev'))[:-1], 0.0)
    assert core.arm(0.0)[0]
    link = SerialLink(core, 'fake', clock=clock)
    port = FakePort()
    link._serial = port
    return link, port, clock


def s_line(seq):
    return jp.encode(jp.Sample(seq, seq * 5000, 0, 0, jp.FLAG_ENABLED))


def test_lines_that_piled_up_during_a_host_stall_are_read_before_the_watchdogs_run():
    link, port, clock = armed_link()
    for seq in range(1, 4):
        clock.now = seq * 0.005
        port.pending += s_line(seq)
        link._poll(port)
    assert link.core.armed and link.core.counts.samples == 3
    # The process stalls for 200 ms in the middle of a read that then returns empty;
    # meanwhile the device went on sampling and its 40 lines wait in the port.
    port.read_times_out = True
    port.pending += b''.join(s_line(seq) for seq in range(4, 44))
    clock.now += 0.2
    link._poll(port)
    assert link.core.armed, link.core.last_error
    link._poll(port)
    assert link.core.armed and link.core.counts.faults == 0
    assert link.core.counts.samples == 43 and link.core.tracker.lost == 0


def test_a_silent_device_still_trips_the_sample_timeout():
    link, port, clock = armed_link()
    clock.now = 0.005
    port.pending += s_line(1)
    link._poll(port)
    clock.now += 0.06                    # nothing arrives for 60 ms
    link._poll(port)
    assert not link.core.armed and 'no valid sample' in link.core.last_error
    assert port.written.endswith(jp.encode(jp.Setpoint(0)) + jp.encode(jp.Enable(False)))


def test_a_late_writer_is_not_a_dead_port_but_a_full_one_is():
    r, w = pipe()
    try:
        write_all(w, b'U,0*49\n', timeout=0.0)      # no time left, but writable: written
        assert os.read(r, 100) == b'U,0*49\n'
        while True:                                   # fill the pipe: nobody reads it
            try:
                os.write(w, b'x' * 65536)
            except BlockingIOError:
                break
        with pytest.raises(TimeoutError, match='not writable'):
            write_all(w, b'U,0*49\n', timeout=0.01)
    finally:
        os.close(r)
        os.close(w)


def test_the_reader_thread_takes_the_real_time_priority_of_the_thread_that_starts_it(tmp_path):
    """Configured after the process took SCHED_FIFO (cartpole_core.realtime), the reader
    thread runs at it too (a new thread would otherwise start at normal priority)."""
    import threading

    try:
        os.sched_setscheduler(0, os.SCHED_FIFO | os.SCHED_RESET_ON_FORK, os.sched_param(5))
    except OSError:
        pytest.skip('SCHED_FIFO not permitted here')
    tried = threading.Event()
    try:
        link = SerialLink(BridgeCore(), str(tmp_path / 'no-port'), reconnect_period=10.0,
                          logger=lambda text: tried.set())
        link.start()
        assert tried.wait(5.0)          # it tried to open the port: its priority is set
        tid = link._thread.native_id
        policy = os.sched_getscheduler(tid) & ~os.SCHED_RESET_ON_FORK
        priority = os.sched_getparam(tid).sched_priority
        link.stop()
    finally:
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    assert (policy, priority) == (os.SCHED_FIFO, 5)
