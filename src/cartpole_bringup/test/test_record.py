"""The recorder node: what it writes reads back with rosbags; refusals; the installed executable."""
from __future__ import annotations

import os
import signal
import subprocess
from pathlib import Path

import pytest

from cartpole_core.child_process import reap

pytestmark = pytest.mark.ros


def read_bag(path):
    from rosbags.highlevel import AnyReader
    with AnyReader([Path(path)]) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        messages = [(c.topic, t, reader.deserialize(raw, c.msgtype))
                    for c, t, raw in reader.messages()]
    return types, messages


class Publisher:
    """Publishes synthetic graph messages with known stamps."""

    def __init__(self, context):
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.node import Node
        from rosgraph_msgs.msg import Clock
        from sensor_msgs.msg import JointState

        self.node = Node('synthetic_graph', context=context)
        # Depth 100 (the graph's PUBLISH_DEPTH): a reader that matches the writer late is
        # still sent every message of a burst (a depth of 10 lost the first 40 of 50).
        depth = 100
        self.pubs = {t: self.node.create_publisher(JointState, t, depth)
                     for t in ('/joint_states', '/cartpole/true_state', '/cartpole/force_command')}
        self.pubs['/cartpole/controller_status'] = self.node.create_publisher(
            DiagnosticArray, '/cartpole/controller_status', depth)
        self.pubs['/clock'] = self.node.create_publisher(Clock, '/clock', depth)

    def matched(self, recorders: int) -> bool:
        """Every writer has matched every reader the graph shows on its topic, ``recorders``
        of them a node named recorder's (another reader on the domain must not stand in for
        a recorder that has not subscribed yet)."""
        for topic, pub in self.pubs.items():
            readers = self.node.get_subscriptions_info_by_topic(topic)
            if sum(r.node_name == 'recorder' for r in readers) < recorders:
                return False
            if pub.get_subscription_count() < len(readers):
                return False
        return True

    def publish(self, k: int) -> None:
        from builtin_interfaces.msg import Time
        from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
        from rosgraph_msgs.msg import Clock
        from sensor_msgs.msg import JointState

        ns = k * 5_000_000
        stamp = Time(sec=ns // 10**9, nanosec=ns % 10**9)
        js = JointState(name=['cart', 'pendulum'], position=[0.001 * k, 3.14])
        js.header.stamp = stamp
        self.pubs['/joint_states'].publish(js)
        truth = JointState(name=['cart', 'pendulum'], position=[0.001 * k, 3.14],
                           velocity=[0.0, 0.0], effort=[1.0, 0.0])
        truth.header.stamp = stamp
        self.pubs['/cartpole/true_state'].publish(truth)
        force = JointState(name=['cart'], effort=[float(k)])
        force.header.stamp = stamp
        self.pubs['/cartpole/force_command'].publish(force)
        if k % 10 == 0:
            status = DiagnosticArray(status=[DiagnosticStatus(
                name='controller_manager', message='swingup',
                values=[KeyValue(key='mode', value='swingup')])])
            status.header.stamp = stamp
            self.pubs['/cartpole/controller_status'].publish(status)
        self.pubs['/clock'].publish(Clock(clock=stamp))


def test_recorded_bag_reads_back_with_topics_types_counts_and_stamps(ros_context, spin_until,
                                                                     tmp_path):
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter

    from cartpole_analysis.bags.writer import bag_custom_data
    from cartpole_bringup.graph.recorder import RecorderNode

    bag = tmp_path / 'bag'
    recorder = RecorderNode(context=ros_context, parameter_overrides=[
        Parameter('output', value=str(bag)),
        Parameter('custom_data', value=['x_ref=0.3845', 'swingup=pendulum_energy'])])
    source = Publisher(ros_context)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(recorder)
    executor.add_node(source.node)
    try:
        assert spin_until(executor, lambda: source.matched(1), 10.0)
        n = 100
        for k in range(n):
            source.publish(k)
            executor.spin_once(timeout_sec=0.0)
        assert spin_until(executor, lambda: sum(recorder.counts.values()) >= 4 * n + n // 10, 10.0)
    finally:
        executor.remove_node(recorder)
        recorder.destroy_node()  # closes the bag
        source.node.destroy_node()
    assert (bag / 'metadata.yaml').is_file()
    assert list(bag.glob('*.mcap'))
    types, messages = read_bag(bag)
    assert types == {'/joint_states': 'sensor_msgs/msg/JointState',
                     '/cartpole/true_state': 'sensor_msgs/msg/JointState',
                     '/cartpole/force_command': 'sensor_msgs/msg/JointState',
                     '/cartpole/controller_status': 'diagnostic_msgs/msg/DiagnosticArray',
                     '/clock': 'rosgraph_msgs/msg/Clock'}
    counts = {}
    for topic, log_time, msg in messages:
        counts[topic] = counts.get(topic, 0) + 1
        stamp = msg.clock if topic == '/clock' else msg.header.stamp
        # Log time = the message's own stamp (simulated time in lockstep).
        assert log_time == stamp.sec * 10**9 + stamp.nanosec
    assert counts == {'/joint_states': n, '/cartpole/true_state': n,
                      '/cartpole/force_command': n, '/cartpole/controller_status': n // 10,
                      '/clock': n}
    forces = [m.effort[0] for t, _, m in messages if t == '/cartpole/force_command']
    assert forces == [float(k) for k in range(n)]
    # recorder_missed: every status's force command and every sample's truth is there.
    assert bag_custom_data(bag) == {'x_ref': '0.3845', 'swingup': 'pendulum_energy',
                                    'recorder_missed': '0', 'recorder_missed_at_start': '0'}
    # metadata.yaml: version 9, MCAP, the right counts (what `ros2 bag info` reads).
    import yaml
    info = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert info['version'] == 9 and info['storage_identifier'] == 'mcap'
    assert info['message_count'] == 4 * n + n // 10


def test_recorder_refuses_an_existing_bag_and_unknown_topics(ros_context, tmp_path):
    """Refused, and the refused recorder leaves nothing on the graph: a half-built one once
    kept its subscriptions in the test process, and acknowledged the next test's messages
    in place of a recorder that had not subscribed yet."""
    from rclpy.node import Node
    from rclpy.parameter import Parameter

    from cartpole_bringup.graph.recorder import RecorderNode

    probe = Node('_refusal_probe', context=ros_context)
    (tmp_path / 'exists').mkdir()
    with pytest.raises(FileExistsError, match='already exists'):
        RecorderNode(context=ros_context,
                     parameter_overrides=[Parameter('output', value=str(tmp_path / 'exists'))])
    with pytest.raises(ValueError, match='cannot record'):
        RecorderNode(context=ros_context, parameter_overrides=[
            Parameter('output', value=str(tmp_path / 'new')),
            Parameter('topics', value=['/joint_states', '/tf'])])
    assert not (tmp_path / 'new').exists()
    try:
        # one participant a context: this process's own nodes are in its graph at once
        assert 'recorder' not in probe.get_node_names()
        assert probe.get_subscriptions_info_by_topic('/joint_states') == []
    finally:
        probe.destroy_node()


def installed(package, exe):
    from ament_index_python.packages import get_package_prefix
    path = Path(get_package_prefix(package)) / 'lib' / package / exe
    assert os.access(path, os.X_OK), f'{path} not installed; run make build'
    return path


def test_installed_recorder_closes_the_bag_on_sigint_and_sigterm(ros_context, spin_until,
                                                                  tmp_path):
    """Two recorders at once: one stopped by SIGINT, one by SIGTERM; both write every
    message that had arrived and close their bags."""
    from rclpy.duration import Duration
    from rclpy.executors import SingleThreadedExecutor

    exe = str(installed('cartpole_bringup', 'cartpole_recorder'))
    bags = {sig: tmp_path / sig.name for sig in (signal.SIGINT, signal.SIGTERM)}
    # Two nodes named recorder on one domain: allowed explicitly (one graph per domain).
    procs = {sig: subprocess.Popen([exe, '--ros-args', '-p', f'output:={bag}',
                                    '-p', 'allow_duplicates:=true'],
                                   stderr=subprocess.PIPE, text=True)
             for sig, bag in bags.items()}
    source = Publisher(ros_context)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(source.node)
    try:
        assert spin_until(executor, lambda: source.matched(2), 20.0), 'recorders did not subscribe'
        # Warm-up (stamp -0.05 s, not counted): acknowledged by both recorders once their
        # readers have matched our writers too, so none of the 50 below is dropped as coming
        # from a writer not yet matched.
        source.publish(-10)
        for pub in source.pubs.values():
            assert pub.wait_for_all_acked(Duration(seconds=10))
        for k in range(50):
            source.publish(k)
            executor.spin_once(timeout_sec=0.0)
        # Every message is in both recorders' readers (acknowledged); a recorder writes
        # what has arrived before it closes the bag.
        for pub in source.pubs.values():
            assert pub.wait_for_all_acked(Duration(seconds=10))
        for sig, proc in procs.items():
            proc.send_signal(sig)
        for sig, proc in procs.items():
            _, err = proc.communicate(timeout=10)
            assert proc.returncode == 0, f'{sig.name}: {err}'
    finally:
        for proc in procs.values():
            reap(proc)
        source.node.destroy_node()
    for sig, bag in bags.items():
        assert (bag / 'metadata.yaml').is_file(), f'{sig.name}: bag not closed'
        types, messages = read_bag(bag)
        messages = [(t, lt, m) for t, lt, m in messages
                    if (m.clock if t == '/clock' else m.header.stamp).sec >= 0]  # no warm-up
        counts = {}
        for topic, _, _ in messages:
            counts[topic] = counts.get(topic, 0) + 1
        forces = [m.effort[0] for t, _, m in messages if t == '/cartpole/force_command']
        assert counts == {'/joint_states': 50, '/cartpole/true_state': 50,
                          '/cartpole/force_command': 50, '/cartpole/controller_status': 5,
                          '/clock': 50}, (sig.name, forces)
