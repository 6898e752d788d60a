"""Which controller ran when: the run summary's ``controllers``, without ROS.

Only one controller runs at a time (thesis section 6.4): the swing-up law in
mode ``swingup``, the stabiliser in mode ``stabilizing``, none in ``idle``
or ``fault``. A span is one stretch of one controller: it starts at the
first cycle it ran (its mode entered, or it was switched in by ``ros2 param
set``) and ends where the next span starts, where control stopped (idle,
fault) or at the end of the run. Built from the controller manager's
per-cycle output: live or from a bag out of ``/cartpole/controller_status``
(``mode``, ``swingup``, ``stabilizer``), offline out of the modes and the
``switch:<kind>=<name>`` events.
"""
from __future__ import annotations

from typing import Any, Iterable, Sequence

SWINGUP_MODE = 'swingup'


def active_controller(mode: str, swingup: str, stabilizer: str) -> tuple[str, str] | None:
    """(kind, name) of the controller that runs in ``mode``; None when none does."""
    mode = mode.strip().lower().replace('-', '').replace('_', '')
    if mode == SWINGUP_MODE:
        return ('swingup', swingup)
    if mode.startswith('stabili'):  # stabilizing / stabilising
        return ('stabilizer', stabilizer)
    return None


class ControllerTimeline:
    """Accumulates the active controller cycle by cycle; :meth:`spans` gives the summary's list.

    Feed :meth:`update` in time order (times in any unit, typically ns).
    """

    def __init__(self) -> None:
        self._changes: list[tuple[int | float, tuple[str, str] | None]] = []
        self._last_t: int | float | None = None

    def update(self, t: int | float, mode: str, swingup: str, stabilizer: str) -> None:
        active = active_controller(mode, swingup, stabilizer)
        if not self._changes or self._changes[-1][1] != active:
            self._changes.append((t, active))
        self._last_t = t

    @property
    def empty(self) -> bool:
        return not self._changes

    @property
    def first_start(self) -> int | float | None:
        """When a controller first ran (the start of control); None if none did."""
        return next((t for t, active in self._changes if active is not None), None)

    def spans(self, *, origin: int | float = 0, scale: float = 1.0,
              end: int | float | None = None) -> list[dict[str, Any]]:
        """``[{'kind', 'name', 'start_s', 'end_s'}, ...]`` in time order.

        Times are ``(t - origin) * scale`` [s]; the cycles after ``end`` are
        ignored and a span still open is closed at ``end`` (default: the last
        cycle fed).
        """
        last = self._last_t if end is None else end
        out: list[dict[str, Any]] = []
        changes = [c for c in self._changes if end is None or c[0] <= end]
        for i, (t, active) in enumerate(changes):
            if active is None:
                continue
            stop = changes[i + 1][0] if i + 1 < len(changes) else last
            if stop is None or stop < t:
                stop = t
            out.append({'kind': active[0], 'name': active[1],
                        'start_s': float((t - origin) * scale),
                        'end_s': float((stop - origin) * scale)})
        return out


def spans_from_modes(t: Sequence[float], modes: Sequence[str],
                     events: Iterable[tuple[float, str]], swingup: str,
                     stabilizer: str) -> list[dict[str, Any]]:
    """The spans of an offline run: per-sample ``modes`` and the manager's ``events``.

    ``swingup`` / ``stabilizer`` are the names the manager started with; a
    ``switch:<kind>=<name>`` event changes them from its cycle on.
    """
    names = {'swingup': swingup, 'stabilizer': stabilizer}
    switches: dict[float, list[tuple[str, str]]] = {}
    for when, text in events:
        for event in text.split(';'):
            if event.startswith('switch:') and '=' in event:
                kind, _, name = event[len('switch:'):].partition('=')
                switches.setdefault(when, []).append((kind, name))
    timeline = ControllerTimeline()
    for time, mode in zip(t, modes):
        for kind, name in switches.get(time, ()):
            names[kind] = name
        timeline.update(float(time), mode, names['swingup'], names['stabilizer'])
    return timeline.spans()


def describe(spans: Sequence[dict[str, Any]]) -> str:
    """One line for the summary table: ``pendulum_energy 0-2.81 s, lqg 2.81-30 s``."""
    if not spans:
        return 'none'
    return ', '.join(f'{s["name"]} {s["start_s"]:.4g}-{s["end_s"]:.4g} s' for s in spans)


def names_that_ran(spans: Sequence[dict[str, Any]], kind: str) -> list[str]:
    """The names of ``kind`` in the order they first ran (no repeats)."""
    out: list[str] = []
    for s in spans:
        if s['kind'] == kind and s['name'] not in out:
            out.append(s['name'])
    return out
