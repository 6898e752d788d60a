"""The soak's verdicts from what it saw: pendulum up when it should be, memory growth, the bag.

No ROS here: :mod:`.probe` feeds :class:`UprightJudge` the simulator's samples and
the controller status, :mod:`.session` the /proc samples (:func:`memory_growth`) and
the bag's counts (:func:`bag_verdict`). "Up" uses the thesis's catch window
(|theta_w| <= 30 deg, section 6.4): a pendulum caught there and then outside it has
fallen; "upright" is the spec's +-10 deg.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

FALL_RAD = math.radians(30.0)
"""|theta_w| beyond the catch window after a catch: the pendulum fell [rad]."""
UPRIGHT_RAD = math.radians(10.0)
"""|theta_w| within this is upright [rad] (the summary's ``upright_time_s``)."""
SETTLE_S = 5.0
"""Seconds after a catch before ``max_settled_deg`` counts (the catch transient)."""


def wrapped(theta: float) -> float:
    """theta_w: the pendulum angle from upright in (-pi, pi] (theta = 0 upright)."""
    return math.remainder(theta, 2.0 * math.pi)


@dataclass
class Segment:
    """One swing-up and what followed it, until the next restart (or the end)."""

    start_s: float
    """Wall seconds since the soak began, when the swing-up was (re)started."""
    from_stamp_ns: int | None = None
    """Stamp from which samples show this segment's plant (the simulator's reset
    announcement); None while it is awaited: nothing counts for the segment until then."""
    first_stamp_ns: int | None = None
    """Stamp of the segment's first sample of the plant."""
    catch_stamp_ns: int | None = None
    """Stamp of the cycle whose status first counted the catch."""
    samples_up: int = 0
    """Samples after the catch."""
    samples_fallen: int = 0
    """Samples after the catch with |theta_w| beyond :data:`FALL_RAD`."""
    max_after_catch_deg: float = 0.0
    max_settled_deg: float = 0.0
    """Largest |theta_w| from :data:`SETTLE_S` after the catch on [deg]."""
    falls: int = 0
    """Falls the controller manager reported (its ``fall_count`` rising)."""

    @property
    def catch_after_s(self) -> float | None:
        """Plant time from the segment's first sample to the catch [s]."""
        if self.catch_stamp_ns is None or self.first_stamp_ns is None:
            return None
        return (self.catch_stamp_ns - self.first_stamp_ns) * 1e-9

    def up_when_it_should_be(self) -> bool:
        return self.catch_stamp_ns is not None and self.samples_fallen == 0 and self.falls == 0


@dataclass
class UprightJudge:
    """Was the pendulum up whenever it should be? One :class:`Segment` a swing-up.

    ``catch_timeout`` [s]: a swing-up not caught within it is a failure of its segment.
    """

    catch_timeout: float = 30.0
    segments: list[Segment] = field(default_factory=list)
    ended: bool = False
    """Set when the soak's time is up: what the stop does to the pendulum is not judged."""
    _catch_count: int = 0
    _fall_count: int = 0

    def restart(self, now_s: float, from_stamp_ns: int | None = None) -> None:
        """A swing-up starts: the soak's start (``from_stamp_ns`` 0), or a restart it
        requested (the stamp comes with :meth:`plant_reset`)."""
        self.segments.append(Segment(start_s=now_s, from_stamp_ns=from_stamp_ns))
        self._catch_count = self._fall_count = 0  # the manager's counters start again

    def plant_reset(self, stamp_ns: int) -> None:
        """The simulator announced a reset: samples from ``stamp_ns`` on show the new run."""
        seg = self.segments[-1] if self.segments else None
        if seg is not None and seg.from_stamp_ns is None:
            before = [s.from_stamp_ns for s in self.segments[:-1] if s.from_stamp_ns is not None]
            if not before or stamp_ns > max(before):  # not an older reset kept for late joiners
                seg.from_stamp_ns = stamp_ns

    def _current(self, stamp_ns: int) -> Segment | None:
        seg = self.segments[-1] if self.segments and not self.ended else None
        if seg is None or seg.from_stamp_ns is None or stamp_ns < seg.from_stamp_ns:
            return None
        return seg

    def status(self, catch_count: int, fall_count: int, stamp_ns: int) -> None:
        """The controller status of the cycle of ``stamp_ns``: its catch and fall counters
        (they rise within a run and start at 0 again with a plant reset)."""
        seg = self._current(stamp_ns)
        if seg is None:
            return
        if catch_count > self._catch_count and seg.catch_stamp_ns is None:
            seg.catch_stamp_ns = stamp_ns
        if fall_count > self._fall_count:
            seg.falls += fall_count - self._fall_count
        self._catch_count = max(self._catch_count, catch_count)
        self._fall_count = max(self._fall_count, fall_count)

    def sample(self, stamp_ns: int, theta: float) -> None:
        """A sample of the simulator's true state (pendulum angle ``theta`` [rad])."""
        seg = self._current(stamp_ns)
        if seg is not None and seg.first_stamp_ns is None:
            seg.first_stamp_ns = stamp_ns
        if seg is None or seg.catch_stamp_ns is None or stamp_ns < seg.catch_stamp_ns:
            return
        angle = abs(wrapped(theta))
        seg.samples_up += 1
        if angle > FALL_RAD:
            seg.samples_fallen += 1
        deg = math.degrees(angle)
        seg.max_after_catch_deg = max(seg.max_after_catch_deg, deg)
        if stamp_ns >= seg.catch_stamp_ns + int(SETTLE_S * 1e9):
            seg.max_settled_deg = max(seg.max_settled_deg, deg)

    def verdict(self, now_s: float) -> dict:
        """``up_ok`` and the segments; a last segment younger than ``catch_timeout`` without
        a catch is not held against the run (it was cut by the end)."""
        rows, ok = [], True
        for k, seg in enumerate(self.segments):
            last = k == len(self.segments) - 1
            after = seg.catch_after_s
            pending = last and after is None and now_s - seg.start_s < self.catch_timeout
            late = after is not None and after > self.catch_timeout
            good = pending or (seg.up_when_it_should_be() and not late)
            ok = ok and good
            rows.append({'start_s': round(seg.start_s, 3),
                         'catch_after_s': None if after is None else round(after, 3),
                         'samples_up': seg.samples_up, 'samples_fallen': seg.samples_fallen,
                         'falls': seg.falls,
                         'max_after_catch_deg': round(seg.max_after_catch_deg, 3),
                         'max_settled_deg': round(seg.max_settled_deg, 3),
                         'ok': good, 'cut_by_end': pending})
        return {'up_ok': ok and bool(self.segments), 'segments': rows}


def memory_growth(times_s, rss_bytes, after_s: float) -> float | None:
    """Resident memory growth [MB per hour]: the least-squares slope of RSS over time from
    ``after_s`` on (None with fewer than 3 samples there). 1 MB = 1e6 bytes."""
    t = np.asarray(times_s, dtype=float)
    m = np.asarray(rss_bytes, dtype=float)
    keep = t >= after_s
    if np.count_nonzero(keep) < 3 or np.ptp(t[keep]) <= 0.0:
        return None
    slope = np.polyfit(t[keep], m[keep], 1)[0]  # bytes per second
    return float(slope * 3600.0 / 1e6)


def bag_verdict(published: dict[str, dict], recorded: dict[str, int], damage: str | None,
                recorder_missed: int | None) -> dict:
    """Is the bag complete? ``published``: per topic what the probe received (``count`` in
    the stamp window ``first_ns``..``last_ns``); ``recorded``: the bag's messages per topic in
    that same window. Complete: the bag is whole (``damage`` None), its recorder missed
    nothing it counts, and every topic holds at least what the probe received."""
    topics = {}
    for topic, seen in sorted(published.items()):
        n = recorded.get(topic, 0)
        topics[topic] = {'published_seen': seen['count'], 'recorded': n,
                         'missing': max(0, seen['count'] - n)}
    complete = (damage is None and recorder_missed == 0
                and all(t['missing'] == 0 for t in topics.values()) and bool(topics))
    return {'bag_ok': complete, 'damage': damage, 'recorder_missed': recorder_missed,
            'topics': topics}
