"""The thin ROS side of the input checks: judge, log once, report, name foreign publishers.

A node makes one :class:`InputGuard` and asks :meth:`InputGuard.accept` in each
subscription callback before it takes a message (:mod:`cartpole_core.message_checks`
judges it; a refused message is dropped and the loop goes on as after a lost
sample). The first refusal is logged once on ``/rosout``; :meth:`InputGuard.health`
turns the node's OK health into a WARN that keeps the counts, and names the
publishers of the node's topics whose nodes are not part of the graph
(:data:`GRAPH_NODES`; ``foreign_publishers``, logged once per name).
docs/troubleshooting.md ("Messages from outside the graph").
"""
from __future__ import annotations

import time
from typing import Sequence

from rcl_interfaces.msg import FloatingPointRange, ParameterDescriptor
from rclpy.node import Node

from .diagnostics import OK, WARN, Health
from .message_checks import STAMP_TOLERANCE_RANGE, InputJudge, RigLimits

GRAPH_NODES = frozenset({'sim', 'hw_bridge', 'ekf', 'controller_manager', 'recorder', 'viewer',
                         'viewer_tap', 'cartpole_run', 'pulse_player'})
"""The names of the graph's nodes (and of the tools that publish on its topics):
any other publisher on a topic the graph owns is foreign."""

UNKNOWN_NODE = '_NODE_NAME_UNKNOWN_'
"""The node name DDS gives a publisher whose node it has not discovered yet (a graph's own
node at start-up, too): not named foreign until its name is known."""

NOT_FOREIGN = GRAPH_NODES | {UNKNOWN_NODE}
"""Publishers' node names that are never named foreign."""

FOREIGN_CHECK_PERIOD = 1.0
"""Seconds between two looks at a topic's publishers (graph introspection is not free)."""

STAMP_TOLERANCE = 10.0
"""Default of every node's ``stamp_tolerance`` [s]: longer than any stall of a process."""


def declare_stamp_tolerance(node: Node, default: float = STAMP_TOLERANCE) -> float:
    """Declare the node's read-only ``stamp_tolerance`` parameter and return its value."""
    node.declare_parameter('stamp_tolerance', float(default), ParameterDescriptor(
        description='Messages stamped further than this from the node clock [s], or with a '
                    'zero stamp, are dropped and counted (refused_inputs); 0 = stamps not '
                    'judged (synthetic or replayed stamps).', read_only=True,
        floating_point_range=[FloatingPointRange(from_value=STAMP_TOLERANCE_RANGE[0],
                                                   to_value=STAMP_TOLERANCE_RANGE[1], step=0.0)]))
    return float(node.get_parameter('stamp_tolerance').value)


class InputGuard:
    """A node's judge of its inputs (see the module docstring)."""

    def __init__(self, node: Node, limits: RigLimits, topics: Sequence[str]) -> None:
        self.judge = InputJudge(limits)
        self.topics = tuple(topics)
        """The graph's topics the node subscribes (relative names)."""
        self._node = node
        self._foreign: dict[str, list[str]] = {}
        self._named: set[tuple[str, str]] = set()
        self._looked_at = -FOREIGN_CHECK_PERIOD

    def accept(self, msg, kind: str, topic: str, now_ns: int | None = None) -> bool:
        """True if ``msg`` may be taken; else it is counted (and the first one logged).
        ``now_ns``: the time the stamps are judged against [ns] (default: the node clock)."""
        if now_ns is None:
            now_ns = self._node.get_clock().now().nanoseconds
        if self.judge.accept(msg, kind, topic, now_ns):
            return True
        self._tell()
        return False

    def accept_stamps(self, topic: str, *stamps, now_ns: int | None = None) -> bool:
        """True if the stamps (builtin_interfaces/Time) of a message without joints may be
        the rig's now; else it is counted (and the first one logged)."""
        if now_ns is None:
            now_ns = self._node.get_clock().now().nanoseconds
        if self.judge.accept_stamps([s.sec * 1_000_000_000 + s.nanosec for s in stamps], topic,
                                    now_ns):
            return True
        self._tell()
        return False

    def refuse(self, topic: str, reason: str) -> None:
        """Count a message the node refused by itself."""
        self.judge.count(topic, reason)
        self._tell()

    def _tell(self) -> None:
        news = self.judge.first_news()
        if news:
            self._node.get_logger().warning(news)

    def foreign_publishers(self) -> dict[str, list[str]]:
        """Topic -> the nodes publishing on it that are not the graph's (graph introspection,
        at most once a :data:`FOREIGN_CHECK_PERIOD`)."""
        now = time.monotonic()
        if now - self._looked_at < FOREIGN_CHECK_PERIOD:
            return self._foreign
        self._looked_at = now
        found: dict[str, list[str]] = {}
        for topic in self.topics:
            name = self._node.resolve_topic_name(topic)
            try:
                infos = self._node.get_publishers_info_by_topic(name)
            except Exception:  # noqa: BLE001 - the context is going: nothing to name
                return self._foreign
            nodes = sorted({f'{info.node_namespace.rstrip("/")}/{info.node_name}'
                            for info in infos if info.node_name not in NOT_FOREIGN})
            if nodes:
                found[topic] = nodes
                for who in nodes:
                    if (topic, who) not in self._named:
                        self._named.add((topic, who))
                        self._node.get_logger().warning(
                            f'foreign publisher {who} on {name}: not a node of the graph')
        self._foreign = found
        return found

    def values(self) -> dict[str, object]:
        """Health values: the judge's counts and ``foreign_publishers``."""
        foreign = self.foreign_publishers()
        text = '; '.join(f'{topic}: {", ".join(nodes)}' for topic, nodes in foreign.items())
        return {**self.judge.values(), 'foreign_publishers': text}

    def health(self, health: Health) -> Health:
        """``health`` with the guard's values; an OK health becomes WARN once a message
        was refused (the count stays in the values and the message)."""
        values = {**health.values, **self.values()}
        refused = self.judge.refused
        if not refused:
            return Health(health.level, health.message, values)
        note = f'{refused} input(s) dropped that the rig cannot produce ({self.judge.last})'
        message = f'{health.message}; {note}' if health.message else note
        return Health(WARN if health.level == OK else health.level, message, values)
