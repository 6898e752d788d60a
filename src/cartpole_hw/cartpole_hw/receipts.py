"""Which published sample a force command answers, and when that sample was received.

A command's ``header.stamp`` is the stamp of the sample it was computed
from. The bridge keeps, for its last :data:`RECEIPTS_KEPT` published samples,
the stamp, the node-clock time of the line's receipt and the ``seq``: the
command's age then counts from the receipt (the bridge's freshness rule;
the USB latency before it is the device watchdog's business) and a
version-2 device gets the command tagged with that ``seq`` (docs/rig.md,
"The latency report"). Thread-safe; no ROS import.
"""
from __future__ import annotations

import collections
import threading

RECEIPTS_KEPT = 400
"""Receipts kept (2 s of samples at 200 Hz); also the most samples waiting for the
executor in the node."""


class ReceiptLog:
    """The last :data:`RECEIPTS_KEPT` published samples: stamp [ns] -> (receipt [ns], seq)."""

    def __init__(self, kept: int = RECEIPTS_KEPT) -> None:
        self.kept = int(kept)
        self._lock = threading.Lock()
        self._received: dict[int, tuple[int, int]] = {}
        self._stamp_of_seq: dict[int, int] = {}
        self._order: collections.deque[tuple[int, int]] = collections.deque()

    def note(self, stamp_ns: int, received_ns: int, seq: int) -> None:
        """The sample ``seq`` stamped ``stamp_ns`` was received at ``received_ns``."""
        with self._lock:
            self._received[stamp_ns] = (received_ns, seq)
            self._stamp_of_seq[seq] = stamp_ns
            self._order.append((stamp_ns, seq))
            while len(self._order) > self.kept:
                old_stamp, old_seq = self._order.popleft()
                self._received.pop(old_stamp, None)
                if self._stamp_of_seq.get(old_seq) == old_stamp:
                    del self._stamp_of_seq[old_seq]

    def command_age(self, stamp_ns: int, now_ns: int) -> float:
        """Age [s] of a command answering the sample stamped ``stamp_ns``: from that
        sample's receipt when it is a noted one, else from the stamp itself."""
        with self._lock:
            received = self._received.get(stamp_ns)
        return (now_ns - (stamp_ns if received is None else received[0])) * 1e-9

    def seq_of(self, stamp_ns: int) -> int | None:
        """``seq`` of the noted sample stamped ``stamp_ns`` (None: not one of them)."""
        with self._lock:
            received = self._received.get(stamp_ns)
        return None if received is None else received[1]

    def stamp_of(self, seq: int) -> int | None:
        """Stamp [ns] of the noted sample ``seq`` (None: not one of them)."""
        with self._lock:
            return self._stamp_of_seq.get(seq)
