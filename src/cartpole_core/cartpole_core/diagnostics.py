"""A node's health on ``/diagnostics``, the way ROS's diagnostic_updater publishes it.

Every node of the graph publishes, once a second of its clock, a
diagnostic_msgs/DiagnosticArray with one DiagnosticStatus named ``<node name>: <what>``
(``ekf: estimation``) and a ``hardware_id``, which rqt_robot_monitor, the diagnostic
aggregator and Foxglove show. The levels mean what they say: ``OK`` working or idle,
``WARN`` an event counter grew since the previous report, ``ERROR`` a fault, ``STALE`` an
input stopped arriving (the node's own ERROR wins).

The node supplies its health as a :class:`Health` (level, message, values);
:class:`HealthReport` adds what changed since its previous report and builds the
message, :class:`NodeDiagnostics` publishes it on a timer; values are plain numbers as
text (:func:`plain`). diagnostic_updater is not on PyPI, so this module does the little
of it the nodes need, with the same messages.
Each node's statuses and levels: (docs/architecture.md, "Diagnostics and logs").
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Mapping, Sequence

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node

DIAGNOSTICS_TOPIC = '/diagnostics'
"""Absolute, as ROS convention has it: every node of every namespace reports there."""

DIAGNOSTICS_PERIOD = 1.0
"""Seconds of the node clock between two reports (diagnostic_updater's default)."""

OK, WARN, ERROR, STALE = (DiagnosticStatus.OK, DiagnosticStatus.WARN, DiagnosticStatus.ERROR,
                          DiagnosticStatus.STALE)

_RANK = {OK: 0, WARN: 1, ERROR: 2, STALE: 3}


def plain(value: object) -> str:
    """A health value as text: integers (counts) plain (``3``), floats as Python
    writes them back exactly (``0.25``, ``8.0``, ``nan``), booleans ``true``/``false``,
    anything else ``str``."""
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, (int, float)):
        return repr(value)
    return str(value)


def _number(value: object) -> float | None:
    try:
        number = float(value)
    except (TypeError, ValueError):
        return None
    return number if math.isfinite(number) else None


@dataclass
class Health:
    """A node's health now: its own verdict and figures."""

    level: bytes = OK
    """OK (working or idle), WARN (degraded), ERROR (a fault) or STALE (the node knows
    an input stopped)."""
    message: str = ''
    values: Mapping[str, object] = field(default_factory=dict)
    """Figures by key: numbers, booleans or text (formatted by :func:`plain`)."""


class HealthReport:
    """One stream of reports of a node's health, with what changed since its previous one.

    ``inputs``: keys of counters of what the node receives; one that grew before and
    not since the previous report makes the report STALE (``no <key> since the last
    report``). ``degraded``: keys of event counters; one that grew since the previous
    report makes an OK report WARN (``<key> +n``).
    """

    def __init__(self, name: str, hardware_id: str, inputs: Sequence[str] = (),
                 degraded: Sequence[str] = ()) -> None:
        self.name = name
        self.hardware_id = hardware_id
        self.inputs = tuple(inputs)
        self.degraded = tuple(degraded)
        self._previous: dict[str, float] = {}

    def status(self, health: Health) -> DiagnosticStatus:
        """The DiagnosticStatus of ``health``; remembers its counters for the next one."""
        counters = {k: _number(health.values.get(k)) for k in self.inputs + self.degraded}
        previous, self._previous = self._previous, {k: v for k, v in counters.items()
                                                   if v is not None}
        level, notes = health.level, []
        stopped = [k for k in self.inputs
                   if counters[k] is not None and counters[k] > 0 and k in previous
                   and counters[k] <= previous[k]]
        if stopped and _RANK[level] < _RANK[ERROR]:
            level = STALE
            notes += [f'no {k} since the last report' for k in stopped]
        grown = [(k, counters[k] - previous[k]) for k in self.degraded
                 if counters[k] is not None and k in previous and counters[k] > previous[k]]
        if grown and level == OK:
            level = WARN
        notes += [f'{k} +{n:g}' for k, n in grown]
        message = '; '.join(m for m in [health.message] + notes if m)
        return DiagnosticStatus(level=level, name=self.name, message=message,
                                hardware_id=self.hardware_id,
                                values=[KeyValue(key=k, value=plain(v))
                                        for k, v in health.values.items()])


class NodeDiagnostics:
    """Publishes ``node``'s health on ``/diagnostics`` every :data:`DIAGNOSTICS_PERIOD`
    of the node clock, as the status ``<node name>: <what>`` (the name with the node's
    namespace when it has one: ``rig1/sim: simulation``).

    ``health()`` is called from the node's executor, like every callback of the node;
    ``inputs`` and ``degraded`` as in :class:`HealthReport`.
    """

    def __init__(self, node: Node, what: str, hardware_id: str, health: Callable[[], Health],
                 *, inputs: Sequence[str] = (), degraded: Sequence[str] = (),
                 period: float = DIAGNOSTICS_PERIOD) -> None:
        self._node = node
        self._health = health
        # The node's name with its namespace, if any (``rig1/sim``): one /diagnostics for all.
        name = node.get_fully_qualified_name().lstrip('/')
        self.report = HealthReport(f'{name}: {what}', hardware_id, inputs, degraded)
        self._period_ns = int(period * 1e9)
        self._last_ns: int | None = None
        self._publisher = node.create_publisher(DiagnosticArray, DIAGNOSTICS_TOPIC, 10)
        self._timer = node.create_timer(period, self._on_timer)

    def _on_timer(self) -> None:
        # A timer held up (a busy start-up) may catch up with a second call at once: the
        # reports stay about a period apart by their stamps.
        now = self._node.get_clock().now().nanoseconds
        if self._last_ns is not None and 0 <= now - self._last_ns < self._period_ns // 2:
            return
        self.publish()

    def publish(self) -> DiagnosticArray:
        """Report now; returns the message published."""
        now = self._node.get_clock().now()
        self._last_ns = now.nanoseconds
        msg = DiagnosticArray(status=[self.report.status(self._health())])
        msg.header.stamp = now.to_msg()
        self._publisher.publish(msg)
        return msg
