"""The loop's sensor-to-actuator latency, measured while it runs, and the commands still in flight.

A command computed from the sample taken at ``t_k`` acts on the cart only at
``t_k + L``: the host's computation, the link (a USB-serial adapter's latency
timer alone is 1-16 ms), the device's wait for its next loop. The plant says
when each command took effect (the simulator from its sample-and-hold, the
rig in device time: the ``back``, ``age_us`` fields of the Joint protocol's
sample line, version 2): a report ``(source, applied)`` pairs the stamp of the sample the command was
computed from with the time it reached the amplifier, so ``L = applied -
source`` needs no synchronised clocks beyond the plant's own.

Design notes: docs/controller_manager.md ("Design notes by module", ``cartpole_control.latency``).

No ROS import.
"""
from __future__ import annotations

from collections import deque

LATENCY_WINDOW = 200
"""Reports averaged (1 s of a 200 Hz loop)."""
LATENCY_MIN_REPORTS = 20
"""Reports before the estimate is used (0.1 s of a 200 Hz loop); until then it is 0."""
LATENCY_MAX = 0.1
"""[s] A report beyond this is not a latency of a running loop (a command applied
after a pause, a clock jump): it is counted and left out."""
FLIGHT_DEPTH = 64
"""Commands remembered (320 ms of a 200 Hz loop, more than :data:`LATENCY_MAX`)."""


class LatencyEstimator:
    """Mean sensor-to-actuator latency over the last ``window`` reports of the plant.

    Parameters
    ----------
    window
        Reports averaged.
    min_reports
        Reports needed before :attr:`latency` is other than 0.
    """

    def __init__(self, window: int = LATENCY_WINDOW,
                 min_reports: int = LATENCY_MIN_REPORTS) -> None:
        if window < 1 or min_reports < 1:
            raise ValueError('window and min_reports must be >= 1')
        self.window = int(window)
        self.min_reports = min(int(min_reports), self.window)
        self.reset()

    def reset(self) -> None:
        """Forget every report (a new plant, a reset)."""
        self._samples: deque[float] = deque()
        self._sum = 0.0
        self.reports = 0
        """Reports taken since :meth:`reset`."""
        self.rejected = 0
        """Reports left out: negative or beyond :data:`LATENCY_MAX`."""
        self.last = float('nan')
        """The latest report's latency [s]."""

    def report(self, source: float, applied: float) -> None:
        """The command computed from the sample stamped ``source`` took effect at ``applied`` [s]."""
        latency = applied - source
        if not (0.0 <= latency <= LATENCY_MAX):  # also refuses NaN
            self.rejected += 1
            return
        samples = self._samples
        samples.append(latency)
        self._sum += latency
        if len(samples) > self.window:
            self._sum -= samples.popleft()
        self.reports += 1
        self.last = latency

    @property
    def ready(self) -> bool:
        """Enough reports for the estimate to be used."""
        return len(self._samples) >= self.min_reports

    @property
    def latency(self) -> float:
        """The mean latency of the window [s]; 0 until :attr:`ready` (no compensation)."""
        n = len(self._samples)
        if n < self.min_reports:
            return 0.0
        return max(self._sum / n, 0.0)


class CommandsInFlight:
    """The force commands sent, by the stamp of the sample each was computed from.

    ``sent(t, force)`` once per cycle; :meth:`segments` gives the force the
    cart feels over ``[t, t + horizon]`` when each command acts ``horizon``
    after its sample. Stamps must not go back (a reset clears the history).
    """

    def __init__(self, depth: int = FLIGHT_DEPTH) -> None:
        self._stamps: deque[float] = deque(maxlen=depth)
        self._forces: deque[float] = deque(maxlen=depth)

    def reset(self) -> None:
        self._stamps.clear()
        self._forces.clear()

    def sent(self, t: float, force: float) -> None:
        """The command ``force`` [N] was computed from the sample stamped ``t`` [s]."""
        stamps = self._stamps
        if stamps and t < stamps[-1]:
            self.reset()  # time went back: a new run
        elif stamps and t == stamps[-1]:
            self._forces[-1] = force  # the same sample answered again
            return
        stamps.append(t)
        self._forces.append(force)

    def force_at(self, t: float) -> float | None:
        """The command computed from the sample stamped ``t``, None if not (or no longer) known."""
        stamps = self._stamps
        for i in range(len(stamps) - 1, -1, -1):
            if stamps[i] == t:
                return self._forces[i]
            if stamps[i] < t:
                break
        return None

    def segments(self, t: float, horizon: float) -> list[tuple[float, float]]:
        """``[(duration, force), ...]`` covering ``[t, t + horizon]`` in order.

        The force at time ``s`` is the latest command computed from a sample
        at or before ``s - horizon``; before the first one, the first one
        (nothing older is known; at start that is the zero of an idle loop).
        Durations add up to ``horizon``; an empty list for ``horizon <= 0``
        or when nothing was sent.
        """
        stamps, forces = self._stamps, self._forces
        if horizon <= 0.0 or not stamps:
            return []
        start = t - horizon
        # The command in force at t: the latest whose sample is at or before t - horizon.
        i = len(stamps) - 1
        while i > 0 and stamps[i] > start:
            i -= 1
        out: list[tuple[float, float]] = []
        begin, force = t, forces[i]
        for j in range(i + 1, len(stamps)):
            arrival = stamps[j] + horizon
            if arrival >= t + horizon:
                break
            if arrival > begin:
                out.append((arrival - begin, force))
                begin = arrival
            force = forces[j]
        out.append((t + horizon - begin, force))
        return out

    def mean_force(self, start: float, end: float, delay: float) -> float | None:
        """The mean command the cart feels over ``[start, end]`` [N] when each acts ``delay`` [s]
        after its sample: at time ``s`` the latest computed from a sample at or before ``s -
        delay`` (before the first, the first); None with nothing sent or ``end <= start``."""
        stamps, forces = self._stamps, self._forces
        if not stamps or end <= start:
            return None
        a, b = start - delay, end - delay  # on the samples' time line
        i = len(stamps) - 1
        while i > 0 and stamps[i] > a:
            i -= 1
        total, begin, force = 0.0, a, forces[i]
        for j in range(i + 1, len(stamps)):
            if stamps[j] >= b:
                break
            if stamps[j] > begin:
                total += (stamps[j] - begin) * force
                begin = stamps[j]
            force = forces[j]
        if begin == a:
            return force  # one command over the whole interval: itself, not a rounded mean
        return (total + (b - begin) * force) / (b - a)

    @property
    def last_stamp(self) -> float | None:
        """The stamp of the sample the latest command was computed from, None if none."""
        return self._stamps[-1] if self._stamps else None


AGE_WINDOW = 200
"""Received samples over which :class:`SampleAge` averages (about 1 s of a 200 Hz loop)."""


class SampleAge:
    """How old, on average over the cycles, the newest encoder sample is because samples are lost.

    A sample followed by ``k`` lost ones serves ``k + 1`` cycles at ages 0, Ts, ... k Ts; over
    the last :data:`AGE_WINDOW` received samples the mean age is sum k (k + 1) / 2 over sum
    (k + 1), times Ts: p / (1 - p) Ts for independent losses of probability p (80 % lost:
    4 Ts). An estimate that old is what the controller acts on: a dead time of its own.
    Gaps longer than :data:`LATENCY_MAX` (a pause, a new run) are not losses and are skipped.
    """

    def __init__(self, sample_time: float, window: int = AGE_WINDOW) -> None:
        self.sample_time = float(sample_time)
        self._gaps: deque[int] = deque(maxlen=int(window))
        self._last = None

    def reset(self) -> None:
        """Forget the samples seen (a new run)."""
        self._gaps.clear()
        self._last = None

    def sample(self, t: float) -> None:
        """A sample stamped ``t`` [s] arrived."""
        last, self._last = self._last, t
        if last is None or not (0.0 < t - last <= LATENCY_MAX):
            return
        self._gaps.append(max(round((t - last) / self.sample_time) - 1, 0))

    @property
    def age(self) -> float:
        """The mean age of the newest sample over the cycles [s]; 0 with nothing lost."""
        gaps = self._gaps
        cycles = sum(gaps) + len(gaps)
        if not cycles:
            return 0.0
        return self.sample_time * sum(k * (k + 1) / 2 for k in gaps) / cycles
