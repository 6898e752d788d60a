"""The viewer's feed from inside the graph: decimated raw samples over a local Unix socket.

A viewer that subscribes the graph's 200 Hz topics from another process is a remote DDS
reader, served inside the publisher's call on the loop's critical path (the loop's p99
latency about 1.9 times that with this feed). ``cartpole run --view`` therefore taps the
topics where they are delivered anyway, in the graph's own process (:class:`FeedTap`,
hosted by the ``viewer_tap`` node of :mod:`cartpole_analysis.viewer.tap`): the tap reads
only each message's stamp, keeps what the viewer will draw (at most 60 samples a second,
by the viewer's own decimation) and sends those, still serialized, over a non-blocking
local Unix socket to the viewer process. A full socket drops the message (counted); the
loop never waits. Design and measurements: (docs/live_view.md, "The live view").

A message (one ``SOCK_SEQPACKET`` packet) is one kind byte (:data:`TRUTH`,
:data:`MEASUREMENT`, :data:`ESTIMATE`, :data:`STATUS`) followed by the graph's message in
its CDR bytes.
"""
from __future__ import annotations

import collections
import os
import socket
import struct
import time

from ..bags.writer import cdr_stamp_ns
from .server import MAX_RATE_HZ, Decimator

TRUTH = b'T'
"""``/cartpole/true_state``."""
MEASUREMENT = b'M'
"""``/joint_states``."""
ESTIMATE = b'E'
"""``/cartpole/state``."""
STATUS = b'S'
"""``/cartpole/controller_status``."""
KINDS = (TRUTH, MEASUREMENT, ESTIMATE, STATUS)
MAX_MESSAGE = 65536


def status_has_event(data: bytes | memoryview) -> bool:
    """Whether a serialized controller status carries a non-empty ``event`` value.

    Reads only the length of the string after the key ``event`` (the
    DiagnosticArray layout of :mod:`cartpole_analysis.viewer.diagnostics_cdr`),
    without decoding the message; a message without that key has no event.
    """
    buf = bytes(data)
    if len(buf) < 4:
        return False
    order = '<' if buf[1] & 1 else '>'
    key = struct.pack(order + 'I', 6) + b'event\x00'
    at = buf.find(key)
    if at < 0:
        return False
    pos = at + len(key) - 4  # relative to the payload start (after the 4-byte header)
    pos += (-pos) % 4
    if 4 + pos + 4 > len(buf):
        return False
    (length,) = struct.unpack_from(order + 'I', buf, 4 + pos)
    return length > 1  # the length counts the terminating NUL


SEND_BUFFER = 1 << 20
"""Bytes the socket holds for a viewer that is behind (about 3 s of samples)."""
RECONNECT_PERIOD = 1.0
"""Seconds between attempts to reach a viewer that is not (or no longer) listening."""


class FeedSender:
    """The sending end: a non-blocking Unix ``SOCK_SEQPACKET`` connection to ``path``.

    Sequenced packets keep each message whole, and unlike Unix datagrams
    (whose queue holds ten by default) the connection buffers
    :data:`SEND_BUFFER` bytes. It connects on the first message and, while
    no viewer listens, tries again at most every :data:`RECONNECT_PERIOD`.
    """

    def __init__(self, path: str, clock=time.monotonic) -> None:
        self.path = path
        self.clock = clock
        self._socket: socket.socket | None = None
        self._next_attempt = 0.0
        self.sent = 0
        self.dropped = 0
        """Messages not sent: the buffer full, or no viewer listening."""

    def _connect(self) -> bool:
        now = self.clock()
        if now < self._next_attempt:
            return False
        self._next_attempt = now + RECONNECT_PERIOD
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, SEND_BUFFER)
        sock.setblocking(False)
        try:
            sock.connect(self.path)
        except OSError:
            sock.close()
            return False
        self._socket = sock
        return True

    def send(self, kind: bytes, data: bytes | memoryview) -> None:
        if self._socket is None and not self._connect():
            self.dropped += 1
            return
        try:
            self._socket.send(kind + bytes(data))
            self.sent += 1
        except BlockingIOError:  # the viewer is behind: drop, never wait
            self.dropped += 1
        except OSError:  # the viewer went away: reconnect later
            self.dropped += 1
            self._socket.close()
            self._socket = None

    def close(self) -> None:
        if self._socket is not None:
            self._socket.close()
            self._socket = None


class FeedReceiver:
    """The receiving end: listens on ``path`` (removed again on :meth:`close`) for one sender."""

    def __init__(self, path: str) -> None:
        self.path = path
        if os.path.exists(path):
            os.unlink(path)
        self._listener = socket.socket(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        self._listener.bind(path)
        self._listener.listen(1)
        self._connection: socket.socket | None = None

    def receive(self, timeout: float | None) -> tuple[bytes, bytes] | None:
        """The next message as (kind, CDR bytes); None on timeout or a bad message."""
        try:
            if self._connection is None:
                self._listener.settimeout(timeout)
                self._connection, _ = self._listener.accept()
            self._connection.settimeout(timeout)
            message = self._connection.recv(MAX_MESSAGE)
        except (TimeoutError, OSError):
            return None
        if not message:  # the sender closed: wait for the next one
            self._connection.close()
            self._connection = None
            return None
        if message[:1] not in KINDS:
            return None
        return message[:1], message[1:]

    def close(self) -> None:
        if self._connection is not None:
            self._connection.close()
        self._listener.close()
        try:
            os.unlink(self.path)
        except OSError:
            pass


class FeedTap:
    """What the graph sends its viewer: the samples the viewer will draw, and every event.

    The decimation is the viewer's (:class:`~cartpole_analysis.viewer.server.Decimator`
    on the estimates' stamps), so the tap sends exactly the samples the viewer
    shows: for each, the plant's state of the same stamp, then the estimate,
    then the controller status; plus every status that carries an event.
    Per message it reads the stamp (eight bytes), nothing else.
    """

    HISTORY = 16

    def __init__(self, sender: FeedSender, max_rate: float = MAX_RATE_HZ) -> None:
        self.sender = sender
        self.decimator = Decimator(max_rate)
        self._plant: dict[int, tuple[bytes, bytes]] = {}
        self._shown: collections.deque[int] = collections.deque(maxlen=self.HISTORY)

    def plant(self, kind: bytes, data: bytes | memoryview) -> None:
        """The truth or the measurement of a sample (it arrives before the estimate)."""
        stamp = cdr_stamp_ns(data)
        if self.decimator.wanted(stamp):
            self._plant[stamp] = (kind, bytes(data))
            if len(self._plant) > self.HISTORY:
                del self._plant[min(self._plant)]

    def estimate(self, data: bytes | memoryview) -> None:
        stamp = cdr_stamp_ns(data)
        if not self.decimator.due(stamp):
            return
        self._shown.append(stamp)
        plant = self._plant.pop(stamp, None)
        if plant is not None:
            self.sender.send(*plant)
        self.sender.send(ESTIMATE, data)

    def status(self, data: bytes | memoryview) -> None:
        if cdr_stamp_ns(data) in self._shown or status_has_event(data):
            self.sender.send(STATUS, data)
