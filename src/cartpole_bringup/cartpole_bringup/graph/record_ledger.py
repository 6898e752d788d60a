"""What the recorder has of each sample: lockstep progress, repeats, and the messages it missed.

Every 200 Hz topic carries the stamp of its sample (``/joint_states``, ``/cartpole/true_state``,
``/clock``, ``/cartpole/state``, ``/cartpole/force_command``, ``/cartpole/force_acting``,
``/cartpole/controller_status``); that stamp is the sequence number the ledger counts by. No
ROS; the recorder node feeds it.

- **Progress** (lockstep): the oldest of the newest stamps recorded on each topic. At sample
  k's stamp the recorder holds every message up to k; the simulator steps at most
  ``recorder_window`` samples ahead, so no queue overflows on any load.
- **Repeats** (lockstep): sample 0 is re-published until a controller answers; a message with
  its topic's last stamp is not written twice (in real time such a repeat is written).
- **Missed** (real time): a message implies the ones it was computed from (status and acting
  force -> force command -> estimate -> encoder sample -> ground truth). A stamp absent on a
  topic it implies, once ``horizon_ns`` older than the newest, is a missed message; one implied
  before its topic's first message arrived (publisher not yet discovered) counts in
  ``missed_at_start``. Only topics that had a message are implied; a sample missed on every
  topic is not seen.
Details: docs/running.md ("Recording").
"""
from __future__ import annotations

from typing import Iterable

JOINT_STATES, STATE, FORCE = '/joint_states', '/cartpole/state', '/cartpole/force_command'
ACTING = '/cartpole/force_acting'
TRUE_STATE, STATUS, CLOCK = '/cartpole/true_state', '/cartpole/controller_status', '/clock'

PROGRESS_TOPIC = '/cartpole/recorder/progress'
"""Lockstep: the stamp up to which the recorder (or, without one, the run monitor) holds
every sample (std_msgs/Header); the simulator waits for it (``recorder_window``). Its
root-namespace name; the nodes publish it relative, in their graph's namespace."""

SAMPLE_TOPICS = (JOINT_STATES, TRUE_STATE, CLOCK, STATE, FORCE, ACTING, STATUS)
"""The topics with one message per sample, stamped with the sample's stamp."""

IMPLIES: dict[str, tuple[str, ...]] = {
    FORCE: (STATE,),
    ACTING: (FORCE,),
    STATUS: (FORCE, STATE),
    STATE: (JOINT_STATES,),
    JOINT_STATES: (TRUE_STATE,),
    CLOCK: (TRUE_STATE,),
}
"""A message of the key's topic implies one of the same stamp on each of these."""

HORIZON_NS = 2_000_000_000
"""How long [ns] a stamp waits for its other messages before a missing one is counted."""


class RecordLedger:
    """Per-stamp book of the sample topics the recorder takes; see the module docstring."""

    def __init__(self, topics: Iterable[str], *, skip_repeats: bool = False,
                 horizon_ns: int = HORIZON_NS) -> None:
        self.skip_repeats = skip_repeats
        self.topics = tuple(t for t in SAMPLE_TOPICS if t in set(topics))
        self._index = {t: i for i, t in enumerate(self.topics)}
        self._implies = {self._index[t]: tuple(self._index[u] for u in IMPLIES.get(t, ())
                                               if u in self._index) for t in self.topics}
        self._last: dict[str, int] = {}
        self._seen: dict[int, int] = {}  # stamp -> bit mask of the topics seen with it
        self._ever = 0  # bit mask of the topics that had a message
        self._first: dict[int, int] = {}  # topic index -> the stamp of its first message
        self._newest = -1
        self._horizon = int(horizon_ns)
        self.repeats = 0
        """Messages with the stamp their topic had last (not written when ``skip_repeats``)."""
        self.missed = 0
        """Messages implied by another one of the same stamp that never came, on a topic
        that had already had a message at that stamp (counted so far)."""
        self.missed_at_start = 0
        """Implied messages that never came, stamped before their topic's first message
        (its publisher not yet discovered)."""

    def take(self, topic: str, stamp_ns: int) -> bool:
        """Book one message; False when it is a repeat to skip (``skip_repeats``)."""
        if topic not in self._index:
            return True
        if self._last.get(topic) == stamp_ns:
            self.repeats += 1
            return not self.skip_repeats
        self._last[topic] = stamp_ns
        index = self._index[topic]
        bit = 1 << index
        if not self._ever & bit:
            self._first[index] = stamp_ns
        self._ever |= bit
        self._seen[stamp_ns] = self._seen.get(stamp_ns, 0) | bit
        if stamp_ns > self._newest:
            self._newest = stamp_ns
            if len(self._seen) > 64:
                self._settle(self._newest - self._horizon)
        return True

    def progress_ns(self) -> int | None:
        """The stamp up to which every sample topic has arrived; None before each has one."""
        if len(self._last) < len(self.topics) or not self.topics:
            return None
        return min(self._last.values())

    def _settle(self, before_ns: int | None) -> None:
        for stamp in [s for s in self._seen if before_ns is None or s < before_ns]:
            mask = self._seen.pop(stamp)
            needed = mask
            for i in range(len(self.topics)):
                if mask >> i & 1:
                    for j in self._implies[i]:
                        needed |= 1 << j
            absent = needed & ~mask & self._ever
            for j in range(len(self.topics)):
                if absent >> j & 1:
                    if stamp < self._first[j]:
                        self.missed_at_start += 1
                    else:
                        self.missed += 1

    def finish(self) -> int:
        """Count what is still open (the recording ended); returns :attr:`missed`."""
        # The last samples may still be on their way to the answering nodes: only
        # what an arrived message implies, and not for the newest stamp.
        newest = self._newest
        self._settle(newest)
        self._seen.clear()
        return self.missed
