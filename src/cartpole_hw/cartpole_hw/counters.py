"""The device's wrapping counters made continuous: sample sequence numbers and encoder counts.

The Due sends a uint32 ``seq`` per 5 ms sample and the raw int16 HCTL-2021
counts (section 2.3); both wrap. :class:`SequenceTracker` turns the sequence
into lost / duplicate / restart counts, :class:`CounterUnwrapper` a wrapping
count into a continuous one. No ROS import.
"""
from __future__ import annotations

from dataclasses import dataclass

from cartpole_core.model import wrap_counter

from .protocol import UINT32


@dataclass
class SequenceTracker:
    """Counts lost samples from the uint32 sequence numbers of ``S`` lines.

    ``seq`` wraps from 2**32 - 1 to 0 (about 248 days at 200 Hz); a step of
    ``d = (seq - last) mod 2**32`` with ``0 < d < 2**31`` means ``d - 1`` lost
    samples, ``d == 0`` a duplicate, anything else a jump backwards
    (the device restarted, or a stale line): counted in :attr:`restarts` and
    the tracker resynchronises on it.
    """

    received: int = 0
    lost: int = 0
    duplicates: int = 0
    restarts: int = 0
    last: int | None = None

    def update(self, seq: int) -> int:
        """Account for ``seq``; returns the samples lost just before it
        (-1 for a restart/backwards jump, 0 for a duplicate or none lost)."""
        self.received += 1
        if self.last is None:
            self.last = seq
            return 0
        delta = (seq - self.last) % UINT32
        if delta == 0:
            self.duplicates += 1
            return 0
        self.last = seq
        if delta < UINT32 // 2:
            self.lost += delta - 1
            return delta - 1
        self.restarts += 1
        return -1

    def resync(self, seq: int) -> None:
        """Take ``seq`` as the next number (no loss counted): the sequence really moved."""
        self.last = (seq - 1) % UINT32

    def reset(self) -> None:
        self.last = None


@dataclass
class CounterUnwrapper:
    """Rebuilds a continuous count from a wrapping signed counter (the HCTL-2021's int16).

    Correct as long as the counter moves less than half its range between two
    reads (16 revolutions of the pendulum in 5 ms is far beyond the rig).
    """

    bits: int = 16
    _last: int | None = None
    _total: int = 0

    def update(self, raw: int) -> int:
        if self._last is None:
            self._total = raw
        else:
            self._total += wrap_counter(raw - self._last, self.bits)
        self._last = raw
        return self._total

    def reset(self) -> None:
        self._last = None
        self._total = 0
