"""The node ``cartpole_run`` of ``cartpole run``: what the run sees of its graph.

It keeps the time series for the summary
(:class:`cartpole_analysis.analysis.analyze.SeriesBuilder`), the stamp of the latest
state (the run's clock: simulated time in lockstep), the force commands
(counts, the last one, zeros), and it can command zero force itself
(:meth:`RunMonitor.publish_zero_force`) when the controller manager is the
node that died. Its publisher on ``/cartpole/force_command`` exists from the
start, so that it is matched by the plant long before it may be needed; it
publishes nothing otherwise.

A lockstep run without a recorder takes its summary from this node's series,
so the monitor then stands where the recorder would (``progress``): it
publishes on ``/cartpole/recorder/progress`` the stamp up to which it holds
every sample's state, force command and status
(:class:`~cartpole_bringup.graph.record_ledger.RecordLedger`), and the
simulator does not step more than ``recorder_window`` samples ahead of it.
Without that a monitor slowed by load lost samples from its queues and two
identical lockstep runs reported different summaries.
"""
from __future__ import annotations

from typing import Callable

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState

from cartpole_analysis.analysis.analyze import FORCE, HW_HEALTH, STATE, STATUS, TRUE_STATE, SeriesBuilder
from cartpole_core.namespaces import relative
from .progress import LockstepProgress
from .record_ledger import RecordLedger

NODE_NAME = 'cartpole_run'
ZERO_FORCE_N = 1e-3
"""An actuator force below this [N] is zero (the current loop's lag leaves ~1e-20 N after Ts)."""


def _stamp_ns(stamp) -> int:
    return stamp.sec * 1_000_000_000 + stamp.nanosec


class RunMonitor(Node):
    """Watches a run (node ``cartpole_run``): series, sim time, forces.

    Parameters
    ----------
    state_topic
        The state it times the run by (``/cartpole/true_state`` on the
        simulator, ``/cartpole/state`` on the rig).
    collect
        Also subscribe the controller status (and the hw health) for the
        in-memory summary; not needed when a bag is recorded.
    progress
        Publish the lockstep progress of what it collected (module docstring).
    """

    def __init__(self, state_topic: str = TRUE_STATE, collect: bool = True,
                 progress: bool = False, **kwargs) -> None:
        super().__init__(NODE_NAME, **kwargs)
        self.builder = SeriesBuilder()
        self._collect = collect
        # The status is booked only where it is subscribed (collect): a ledger waiting for a
        # topic this node never takes would hold the progress back for good.
        booked = (state_topic, FORCE) + ((STATUS,) if collect else ())
        self._progress = LockstepProgress(self, RecordLedger(booked)) if progress else None
        self.last_stamp_ns: int | None = None
        """Stamp of the latest state sample (simulated time in lockstep)."""
        self.last_command_stamp_ns: int | None = None
        """Stamp of the latest force command seen (the sample it answered)."""
        self._command_period_ns = 0
        """The step between the last two commands' stamps (the sample period in lockstep)."""
        self.forces = 0
        self.last_force: float | None = None
        self.zero_forces = 0
        self.own_zero_forces = 0
        """Zero force commands this node published itself."""
        self.zero_force_samples = 0
        """Simulator samples whose actuator force (``effort[0]`` of the truth) is zero."""
        self._zero_stamp_ns: int | None = None
        """Stamp of the last sample-stamped zero this node published (lockstep fault stop:
        from the first, every later sample is answered with zero too)."""
        qos = QoSProfile(depth=200, reliability=ReliabilityPolicy.RELIABLE)
        # Relative names: the topics of the graph in this node's namespace; the series
        # keep the root names (as the analysis of a bag reads them).
        self.create_subscription(JointState, relative(state_topic), self._state_cb(state_topic),
                                 qos)
        self.create_subscription(JointState, relative(FORCE), self._on_force, qos)
        self._force_pub = self.create_publisher(JointState, relative(FORCE), 10)
        if collect:
            self.create_subscription(DiagnosticArray, relative(STATUS), self._diag_cb(STATUS),
                                     qos)
            if state_topic == STATE:
                self.create_subscription(DiagnosticArray, relative(HW_HEALTH),
                                         self._diag_cb(HW_HEALTH), qos)

    def _state_cb(self, topic: str) -> Callable[[JointState], None]:
        def callback(msg: JointState) -> None:
            stamp = _stamp_ns(msg.header.stamp)
            if self._collect:  # else the bag holds the series: nothing grows here with the run
                self.builder.joint_state(topic, stamp, msg.position, msg.velocity, msg.effort)
            if topic == TRUE_STATE and len(msg.effort) and abs(msg.effort[0]) < ZERO_FORCE_N:
                self.zero_force_samples += 1
            if self.last_stamp_ns is None or stamp > self.last_stamp_ns:
                self.last_stamp_ns = stamp
            if self._zero_stamp_ns is not None and stamp > self._zero_stamp_ns:
                # Lockstep fault stop: this node stands in for the controller, so every new
                # sample is answered at once with zero force; the simulator steps on (no
                # lockstep_timeout per sample) and the zero reaches the plant in a few samples.
                self._zero_stamp_ns = stamp
                self._publish_zero(stamp)
            self._book(topic, stamp)
        return callback

    def _book(self, topic: str, stamp_ns: int) -> None:
        """Lockstep progress: book a sample message, publish the new progress."""
        if self._progress is not None:
            self._progress.ledger.take(topic, stamp_ns)
            self._progress.update()

    def _on_force(self, msg: JointState) -> None:
        stamp = _stamp_ns(msg.header.stamp)
        last = self.last_command_stamp_ns
        if last is None or stamp > last:
            self._command_period_ns = 0 if last is None else stamp - last
            self.last_command_stamp_ns = stamp
        if self._collect:
            self.builder.joint_state(FORCE, stamp, msg.position, msg.velocity, msg.effort)
        self._book(FORCE, stamp)
        if len(msg.effort):
            self.forces += 1
            self.last_force = float(msg.effort[0])
            if self.last_force == 0.0:
                self.zero_forces += 1
            elif self._zero_stamp_ns is not None and stamp >= self._zero_stamp_ns:
                # A command of the dead manager still in flight answered a later sample
                # than this node's zero: answer that sample with zero too, so that the
                # last command of every sample is zero (the plant and the bag agree).
                self._publish_zero(stamp)

    def _diag_cb(self, topic: str) -> Callable[[DiagnosticArray], None]:
        def callback(msg: DiagnosticArray) -> None:
            stamp = _stamp_ns(msg.header.stamp)
            for status in msg.status:
                values = {kv.key: kv.value for kv in status.values}
                if topic == STATUS:
                    self.builder.status(stamp, values)
                else:
                    self.builder.hw_health(stamp, values)
            if topic == STATUS:
                self._book(STATUS, stamp)
        return callback

    def publish_zero_force(self, sample_stamp: bool) -> None:
        """Command zero force (``name=['cart']``, ``effort=[0.0]``) in place of the manager.

        ``sample_stamp``: stamped with the latest state sample (what the lockstep
        simulator waits for) or, while no state has been seen (on a loaded machine the
        plant's states may still be undiscovered; the commands' publisher is matched before
        the plant starts), with the sample after the last command's; else with this node's
        clock (fresh for the hardware bridge, which drops commands older than its timeout).
        """
        if sample_stamp and self.last_stamp_ns is not None:
            self._zero_stamp_ns = self.last_stamp_ns
            self._publish_zero(self.last_stamp_ns)
        elif sample_stamp and self.last_command_stamp_ns is not None:
            self._zero_stamp_ns = self.last_command_stamp_ns  # later samples are answered too
            self._publish_zero(self.last_command_stamp_ns + self._command_period_ns)
        else:
            self._publish_zero(None)

    def _publish_zero(self, stamp_ns: int | None) -> None:
        msg = JointState(name=['cart'], effort=[0.0])
        if stamp_ns is not None:
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
        else:
            msg.header.stamp = self.get_clock().now().to_msg()
        self._force_pub.publish(msg)
        self.own_zero_forces += 1
