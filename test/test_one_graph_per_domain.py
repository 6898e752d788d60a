"""One graph per namespace of a ROS domain: a second node of the same role is refused.

A node executable (through cartpole_core.node_runner.run_node) and `cartpole run`
refuse to start when a node of their role runs in their namespace already
(whatever it is called), with a message naming the namespace, ROS_DOMAIN_ID,
the node found and the fixes; `-p allow_duplicates:=true` (or
`--allow-duplicates`) starts anyway. Graphs in two namespaces:
test/test_namespaces.py.
"""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from cartpole_core.child_process import interrupt
from cartpole_core.domain_guard import DuplicateNodeError, claim_roles, domain_id, graph_duplicates

pytestmark = pytest.mark.ros


def installed(package: str, exe: str) -> str:
    from ament_index_python.packages import get_package_prefix
    path = Path(get_package_prefix(package)) / 'lib' / package / exe
    assert os.access(path, os.X_OK), f'{path} not installed; run make build'
    return str(path)


def test_a_claimed_role_is_refused_with_the_holder_and_the_fix():
    first = claim_roles(['cartpole_test_guard'], names={'cartpole_test_guard': 'renamed'},
                        namespace='/lab/rig3')
    try:
        with pytest.raises(DuplicateNodeError) as refused:
            claim_roles(['cartpole_test_guard'], namespace='/lab/rig3')
        text = str(refused.value)
        assert '\n' not in text
        assert 'node /lab/rig3/renamed' in text and 'namespace /lab/rig3 ' in text
        assert f'ROS_DOMAIN_ID={domain_id()}' in text and f'PID {os.getpid()}' in text
        assert 'export ROS_DOMAIN_ID=' in text and '--allow-duplicates' in text
        assert '--namespace' in text and '__ns:=' in text
        for namespace in ('/', '/lab', '/lab_rig3', '/lab/rig3/sub'):  # other namespaces: free
            claim_roles(['cartpole_test_guard'], namespace=namespace).release()
    finally:
        first.release()
    claim_roles(['cartpole_test_guard'], namespace='/lab/rig3').release()  # free once released


def test_the_graph_look_finds_a_role_by_what_it_publishes_in_the_namespace(ros_context):
    """A plant is the node publishing joint_states in the namespace, whatever its name."""
    from rclpy.node import Node
    from sensor_msgs.msg import JointState
    plant = Node('renamed_plant', context=ros_context)
    plant.create_publisher(JointState, 'joint_states', 1)
    other = Node('ekf', namespace='/robot2', context=ros_context)
    other.create_publisher(JointState, 'cartpole/state', 1)
    probe = Node('_probe', context=ros_context)
    try:
        assert graph_duplicates(probe, ['sim', 'ekf'], wait=5.0) == [
            'node /renamed_plant publishes /joint_states']
        assert graph_duplicates(probe, ['ekf'], wait=0.0) == []
        assert graph_duplicates(probe, ['ekf'], namespace='/robot2', wait=5.0) == [
            'node /robot2/ekf publishes /robot2/cartpole/state']
        assert graph_duplicates(probe, ['recorder'], wait=0.0) == []  # no topic of its own
    finally:
        for node in (plant, other, probe):
            node.destroy_node()


def test_a_second_graph_on_the_domain_is_refused(ros_context, spin_until):
    """A sim_node runs: a second one (renamed: its role counts) and `cartpole run` refuse;
    allow_duplicates starts."""
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node

    sim = installed('cartpole_sim', 'sim_node')
    first = subprocess.Popen([sim, '--ros-args', '-p', 'lockstep:=true'],
                             stderr=subprocess.PIPE, text=True)
    watcher = Node('_watcher', context=ros_context)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(watcher)
    allowed = None
    try:
        def count_sims():
            return sum(1 for n, ns in watcher.get_node_names_and_namespaces()
                       if n == 'sim' and ns == '/')
        assert spin_until(executor, lambda: count_sims() == 1, 30.0), 'sim_node did not start'
        second = subprocess.run([sim, '--ros-args', '-r', '__node:=plant'], capture_output=True,
                                text=True, timeout=60)
        assert second.returncode == 2
        assert 'sim node /sim (PID' in second.stderr and 'namespace / ' in second.stderr
        assert f'ROS_DOMAIN_ID={domain_id()}' in second.stderr
        assert 'allow_duplicates:=true' in second.stderr and 'Traceback' not in second.stderr
        run = subprocess.run([sys.executable, '-m', 'cartpole_bringup.cli', 'run', '--sim',
                              '--lockstep', '--duration', '1'],
                             capture_output=True, text=True, timeout=120)
        assert run.returncode == 2
        assert 'refused' in run.stderr and f'ROS_DOMAIN_ID={domain_id()}' in run.stderr
        assert '--allow-duplicates' in run.stderr and 'Traceback' not in run.stderr
        allowed = subprocess.Popen([sim, '--ros-args', '-p', 'allow_duplicates:=true',
                                    '-p', 'lockstep:=true'], stderr=subprocess.PIPE, text=True)
        assert spin_until(executor, lambda: count_sims() == 2, 30.0), 'allowed sim did not start'
    finally:
        for proc in (first, allowed):
            if proc is not None:
                interrupt(proc, 10.0)
        watcher.destroy_node()
    assert first.returncode == 0 and allowed.returncode == 0
