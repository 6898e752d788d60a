"""One graph per ROS domain: a second node of the same name is refused, naming the domain.

A node executable (through cartpole_sim.node_runner.run_node) and `cartpole run`
refuse to start when a node of theirs is on the domain already, with a
message naming ROS_DOMAIN_ID and the fix; `-p allow_duplicates:=true` (or
`--allow-duplicates`) starts anyway.
"""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from cartpole_sim.child_process import interrupt
from cartpole_sim.domain_guard import (DuplicateNodeError, claim_node_names, domain_id,
                                       graph_duplicates)

pytestmark = pytest.mark.ros


def installed(package: str, exe: str) -> str:
    from ament_index_python.packages import get_package_prefix
    path = Path(get_package_prefix(package)) / 'lib' / package / exe
    assert os.access(path, os.X_OK), f'{path} not installed; run make build'
    return str(path)


def test_a_claimed_name_is_refused_with_the_holder_and_the_fix():
    first = claim_node_names(['cartpole_test_guard'])
    try:
        with pytest.raises(DuplicateNodeError) as refused:
            claim_node_names(['cartpole_test_guard'])
        text = str(refused.value)
        assert f'ROS_DOMAIN_ID={domain_id()}' in text and f'PID {os.getpid()}' in text
        assert 'export ROS_DOMAIN_ID=' in text and '--allow-duplicates' in text
    finally:
        first.release()
    claim_node_names(['cartpole_test_guard']).release()  # free again once released


def test_the_graph_look_sees_a_second_node_of_the_name(ros_context):
    from rclpy.node import Node
    sim = Node('sim', context=ros_context)
    other = Node('sim', namespace='/robot2', context=ros_context)
    probe = Node('_probe', context=ros_context)
    try:
        assert graph_duplicates(probe, ['sim', 'ekf'], wait=5.0) == ['sim']
        assert graph_duplicates(probe, ['sim'], wait=0.0, own='sim') == []  # only itself
        assert graph_duplicates(probe, ['ekf'], wait=0.0) == []
    finally:
        for node in (sim, other, probe):
            node.destroy_node()


def test_a_second_graph_on_the_domain_is_refused(ros_context, spin_until):
    """A sim_node runs: a second sim_node and `cartpole run` refuse; allow_duplicates starts."""
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
        second = subprocess.run([sim], capture_output=True, text=True, timeout=60)
        assert second.returncode == 2
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
