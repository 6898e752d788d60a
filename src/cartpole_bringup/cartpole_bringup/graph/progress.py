"""Lockstep progress on ``/cartpole/recorder/progress``: what the simulator waits for.

The recorder (with ``--record``) or the run monitor (without) books every
sample message it takes in a :class:`~cartpole_bringup.graph.record_ledger.RecordLedger`;
:class:`LockstepProgress` publishes the ledger's progress, the stamp up to
which it holds every sample topic, each time it advances. The lockstep
simulator steps past sample k only once that reaches k - ``recorder_window``.
"""
from __future__ import annotations

from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_msgs.msg import Header

from cartpole_core.namespaces import relative
from .record_ledger import PROGRESS_TOPIC, RecordLedger


class LockstepProgress:
    """Publishes the progress of ``ledger`` for ``node`` (std_msgs/Header, ``stamp`` = progress)."""

    def __init__(self, node: Node, ledger: RecordLedger) -> None:
        self.ledger = ledger
        self._published_ns = -1
        self._pub = node.create_publisher(Header, relative(PROGRESS_TOPIC), QoSProfile(
            depth=10, reliability=ReliabilityPolicy.RELIABLE))

    def update(self) -> None:
        """Publish the ledger's progress if it advanced since the last call."""
        progress = self.ledger.progress_ns()
        if progress is not None and progress > self._published_ns:
            self._published_ns = progress
            msg = Header()
            msg.stamp.sec, msg.stamp.nanosec = divmod(progress, 1_000_000_000)
            self._pub.publish(msg)
