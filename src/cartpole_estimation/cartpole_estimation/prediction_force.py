"""The force the EKF node predicts an interval with: the commands, or the force as it acts.

The filter's prediction (5.15) needs the force on the cart over the interval that
ends at a sample. The controller manager answers each sample with a command
(``cartpole/force_command``) and, with ``force_input`` ``acting``, with the force it
estimates the cart feels over the next interval (``cartpole/force_acting``: its
commands in flight, each acting the measured latency plus the actuator's dead time
after its sample, times the estimated gain). Both are stamped with the sample they
answer, so they are matched by stamp whatever order DDS delivers them in. Without a
match the command held as the plant holds it is used: a command older than
``command_timeout`` counts as zero, as the simulator's and the bridge's watchdogs do.
No ROS import.
"""
from __future__ import annotations

from .ekf_config import check_force_input

REMEMBERED = 64
"""Commands (and acting forces) remembered by stamp; the oldest half is dropped beyond it."""

Stamp = tuple[int, int]
"""(sec, nanosec) of the sample a command answers."""


class PredictionForce:
    """Commands and acting forces by the stamp of the sample they answer (see the module docstring)."""

    def __init__(self, force_input: str = 'acting', command_timeout: float = 0.05) -> None:
        check_force_input(force_input)
        self.force_input = force_input
        self.command_timeout = float(command_timeout)
        self.acting_seen = False
        """An acting force has arrived (the manager publishes them): lockstep waits for them."""
        self.clear()

    def clear(self) -> None:
        """Forget the commands (a plant reset: those of the run before it)."""
        self._commands: dict[Stamp, float] = {}
        self._acting: dict[Stamp, float] = {}
        self._held = 0.0
        self._held_since: float | None = None

    def command(self, stamp: Stamp, force: float, newest_sample_t: float | None) -> None:
        """The command ``force`` [N] answering the sample ``stamp`` arrived when the newest
        sample estimated was stamped ``newest_sample_t`` [s]."""
        self._held, self._held_since = force, newest_sample_t
        _remember(self._commands, stamp, force)

    def acting(self, stamp: Stamp, force: float) -> None:
        """The force [N] the manager estimates acts over the interval after sample ``stamp``."""
        self.acting_seen = True
        _remember(self._acting, stamp, force)

    def ready(self, stamp: Stamp) -> bool:
        """Everything the interval after ``stamp`` is predicted with has arrived (lockstep)."""
        if stamp not in self._commands:
            return False
        return self.force_input != 'acting' or not self.acting_seen or stamp in self._acting

    def for_interval(self, stamp: Stamp | None, sample_t: float | None) -> float:
        """The force [N] over the interval after the sample ``stamp`` (stamped ``sample_t`` [s]).

        The acting force answering it (``force_input`` ``acting``), else the command
        answering it, else the latest command as the plant holds it (zero once older
        than ``command_timeout``, or before any).
        """
        if self.force_input == 'acting':
            acting = self._acting.get(stamp)
            if acting is not None:
                return acting
        matched = self._commands.get(stamp)
        if matched is not None:
            return matched
        if self._held_since is None or sample_t is None:
            return 0.0
        if sample_t - self._held_since > self.command_timeout + 1.0e-9:
            return 0.0
        return self._held


def _remember(by_stamp: dict[Stamp, float], stamp: Stamp, force: float) -> None:
    by_stamp[stamp] = force
    if len(by_stamp) > REMEMBERED:
        for old in sorted(by_stamp)[:REMEMBERED // 2]:
            del by_stamp[old]
