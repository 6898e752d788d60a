"""The run monitor paces a lockstep run without a recorder: progress = what it holds of every sample."""
from __future__ import annotations

import pytest

pytestmark = pytest.mark.ros

TRUE_STATE = '/cartpole/true_state'
FORCE = '/cartpole/force_command'
STATUS = '/cartpole/controller_status'


def _stamped(msg, stamp_ns: int):
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
    return msg


def test_progress_is_the_oldest_newest_sample_of_state_force_and_status(ros_context, spin_until):
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Header

    from cartpole_bringup.graph.record_ledger import PROGRESS_TOPIC
    from cartpole_bringup.graph.run_monitor import RunMonitor

    monitor = RunMonitor(progress=True, context=ros_context)
    peer = Node('_monitor_peer', context=ros_context)
    reliable = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
    pubs = {t: peer.create_publisher(JointState, t, reliable) for t in (TRUE_STATE, FORCE)}
    pubs[STATUS] = peer.create_publisher(DiagnosticArray, STATUS, reliable)
    progress: list[int] = []
    peer.create_subscription(Header, PROGRESS_TOPIC, lambda m: progress.append(
        m.stamp.sec * 10**9 + m.stamp.nanosec), reliable)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(monitor)
    executor.add_node(peer)
    try:
        assert spin_until(executor, lambda: all(p.get_subscription_count() >= 1
                                                for p in pubs.values())
                          and monitor.count_subscribers(PROGRESS_TOPIC) >= 1)
        ts = 5_000_000
        for k in range(3):  # three samples of state and force ...
            pubs[TRUE_STATE].publish(_stamped(JointState(name=['cart'], effort=[1.0]), k * ts))
            pubs[FORCE].publish(_stamped(JointState(name=['cart'], effort=[1.0]), k * ts))
        assert spin_until(executor, lambda: monitor.forces == 3)
        assert progress == []  # ... but no status yet: nothing is held of every topic
        status = DiagnosticArray(status=[DiagnosticStatus(name='controller_manager')])
        pubs[STATUS].publish(_stamped(status, 1 * ts))
        assert spin_until(executor, lambda: progress == [1 * ts])
        pubs[STATUS].publish(_stamped(status, 2 * ts))
        assert spin_until(executor, lambda: progress == [1 * ts, 2 * ts])
    finally:
        executor.shutdown()
        peer.destroy_node()
        monitor.destroy_node()


def test_without_progress_the_monitor_publishes_none(ros_context):
    from cartpole_bringup.graph.record_ledger import PROGRESS_TOPIC
    from cartpole_bringup.graph.run_monitor import RunMonitor

    monitor = RunMonitor(context=ros_context)
    try:
        assert monitor.count_publishers(PROGRESS_TOPIC) == 0
    finally:
        monitor.destroy_node()


def test_a_sample_stamped_zero_takes_the_commands_stamp_before_any_state_is_seen(ros_context):
    """On a loaded machine the plant's states may still be undiscovered when the controller
    manager dies; the zero then answers the sample after the last command's, the one the
    lockstep simulator waits for, never the wall clock (which sorts after the whole run)."""
    from sensor_msgs.msg import JointState

    from cartpole_bringup.graph.run_monitor import RunMonitor

    monitor = RunMonitor(context=ros_context)
    sent = []
    try:
        monitor._force_pub.publish = sent.append  # what the monitor would send
        for nanosec in (105_000_000, 110_000_000):
            command = JointState(name=['cart'], effort=[4.7])
            command.header.stamp.sec, command.header.stamp.nanosec = 2, nanosec
            monitor._on_force(command)
        assert monitor.last_stamp_ns is None
        monitor.publish_zero_force(sample_stamp=True)
        stamp = sent[-1].header.stamp
        assert (stamp.sec, stamp.nanosec, list(sent[-1].effort)) == (2, 115_000_000, [0.0])
        monitor.publish_zero_force(sample_stamp=False)  # the hardware's: this node's clock
        assert sent[-1].header.stamp.sec > 1_000_000_000
    finally:
        monitor.destroy_node()
