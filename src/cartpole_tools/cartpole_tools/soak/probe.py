"""The soak's node: what the graph publishes, counted, and the simulator's reset, called.

Subscribes the graph's sample-stamped topics (every message carries the stamp of
the 5 ms sample it belongs to) and counts what arrives in a stamp window, to be
compared with the bag afterwards; feeds the simulator's truth and the controller
status to :class:`~cartpole_tools.soak.judge.UprightJudge`; keeps the longest gap
between two samples, the manager's ``longest_cycle_gap_s`` and every ERROR on
/diagnostics. Counters only: the soak's own memory does not grow with the run.
"""
from __future__ import annotations

import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import Header
from std_srvs.srv import Trigger

from cartpole_bringup.graph.record_ledger import (ACTING, FORCE, JOINT_STATES, STATE, STATUS,
                                                  TRUE_STATE)
from cartpole_core.namespaces import relative
from cartpole_core.node_runner import PLANT_RESET_QOS

from .judge import UprightJudge

COUNTED = (JOINT_STATES, TRUE_STATE, STATE, FORCE, ACTING, STATUS)
"""The sample-stamped topics whose messages the bag must all hold."""


def _ns(stamp) -> int:
    return stamp.sec * 1_000_000_000 + stamp.nanosec


class SoakProbe(Node):
    """Node ``cartpole_soak``: counts, judges, and calls ``sim/reset``."""

    def __init__(self, judge: UprightJudge, clock_origin: float, **kwargs) -> None:
        super().__init__('cartpole_soak', **kwargs)
        self.judge = judge
        self.origin = clock_origin
        """time.monotonic() of the soak's start (segments are timed from it)."""
        self.published = {t: {'count': 0, 'first_ns': None, 'last_ns': None} for t in COUNTED}
        self.longest_sample_gap_s = 0.0
        self.manager_longest_cycle_gap_s = 0.0
        self.modes: dict[str, int] = {}
        """Controller statuses per mode."""
        self.stabilizer = ''
        """The stabiliser the latest status names."""
        self.diagnostic_errors: dict[str, int] = {}
        """/diagnostics ERROR messages per status name."""
        self._last_joint_ns: int | None = None
        qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        for topic in (JOINT_STATES, STATE, FORCE, ACTING):
            self.create_subscription(JointState, relative(topic), self._counter(topic), qos)
        self.create_subscription(JointState, relative(TRUE_STATE), self._on_truth, qos)
        self.create_subscription(DiagnosticArray, relative(STATUS), self._on_status, qos)
        self.create_subscription(DiagnosticArray, '/diagnostics', self._on_diagnostics, 100)
        self.create_subscription(Header, 'cartpole/plant_reset', self._on_reset, PLANT_RESET_QOS)
        self.reset_client = self.create_client(Trigger, 'sim/reset')

    def restart_counts(self) -> None:
        """Count from here on: the bag is compared from the first sample after this call (a
        recorder in its own process may miss the plant's very first samples while DDS
        discovery completes; that is the start, not a loss)."""
        self.published = {t: {'count': 0, 'first_ns': None, 'last_ns': None} for t in COUNTED}

    def now_s(self) -> float:
        return time.monotonic() - self.origin

    def _count(self, topic: str, stamp_ns: int) -> None:
        seen = self.published[topic]
        seen['count'] += 1
        if seen['first_ns'] is None:
            seen['first_ns'] = stamp_ns
        seen['last_ns'] = stamp_ns if seen['last_ns'] is None else max(seen['last_ns'], stamp_ns)

    def _counter(self, topic: str):
        def callback(msg: JointState) -> None:
            stamp = _ns(msg.header.stamp)
            self._count(topic, stamp)
            if topic == JOINT_STATES:
                if self._last_joint_ns is not None and stamp > self._last_joint_ns:
                    self.longest_sample_gap_s = max(self.longest_sample_gap_s,
                                                    (stamp - self._last_joint_ns) * 1e-9)
                self._last_joint_ns = stamp
        return callback

    def _on_truth(self, msg: JointState) -> None:
        stamp = _ns(msg.header.stamp)
        self._count(TRUE_STATE, stamp)
        if len(msg.position) >= 2:
            self.judge.sample(stamp, float(msg.position[1]))

    def _on_status(self, msg: DiagnosticArray) -> None:
        stamp = _ns(msg.header.stamp)
        self._count(STATUS, stamp)
        for status in msg.status:
            values = {kv.key: kv.value for kv in status.values}
            mode = values.get('mode', '')
            self.modes[mode] = self.modes.get(mode, 0) + 1
            self.stabilizer = values.get('stabilizer', self.stabilizer)
            try:
                gap = float(values.get('longest_cycle_gap_s', 0.0))
                self.judge.status(int(values.get('catch_count', 0)),
                                  int(values.get('fall_count', 0)), stamp)
            except ValueError:
                continue
            self.manager_longest_cycle_gap_s = max(self.manager_longest_cycle_gap_s, gap)

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.level == DiagnosticStatus.ERROR:
                key = f'{status.name}: {status.message}'[:200]
                if key not in self.diagnostic_errors and len(self.diagnostic_errors) >= 50:
                    key = '(other messages)'
                self.diagnostic_errors[key] = self.diagnostic_errors.get(key, 0) + 1

    def _on_reset(self, msg: Header) -> None:
        self.judge.plant_reset(_ns(msg.stamp))
