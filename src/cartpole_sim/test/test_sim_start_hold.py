"""The simulator node holds its first sample until its readers are matched (``start_subscribers``).

Real time and lockstep; the graph and the probe are test_sim_node's.
"""
import importlib.util
import math
import time
from pathlib import Path

import pytest

_spec = importlib.util.spec_from_file_location(
    'sim_node_graph', Path(__file__).with_name('test_sim_node.py'))
_graph_module = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_graph_module)
graph = _graph_module.graph  # the fixture
stamp_ns = _graph_module.stamp_ns

pytestmark = pytest.mark.ros


@pytest.mark.parametrize('lockstep, startup_wait', [(False, True), (True, True), (True, False)])
def test_the_first_sample_is_held_until_the_readers_expected_are_matched(
        graph, spin_until, ros_context, lockstep, startup_wait):
    """``start_subscribers`` 2, one reader: no sample (in lockstep the timeout does not step
    past the held sample 0 either: the run monitor must know the sample it may answer); a
    second reader on both topics: the samples start at the start itself (hanging at rest)."""
    from rclpy.node import Node
    from sensor_msgs.msg import JointState

    sim, probe, executor = graph(lockstep=lockstep, start_subscribers=2, lockstep_timeout=0.01,
                                 lockstep_startup_wait=startup_wait)
    assert spin_until(executor, lambda: time.monotonic() - sim._held_since > 0.2, timeout=10.0)
    assert not probe.joints and not probe.truth and sim.runner.index == 0
    second = Node('second_reader', context=ros_context)
    for topic in ('/joint_states', '/cartpole/true_state'):
        second.create_subscription(JointState, topic, lambda m: None, 10)
    executor.add_node(second)
    try:
        assert spin_until(executor, lambda: len(probe.truth) >= (1 if lockstep else 3),
                          timeout=10.0)
    finally:
        executor.remove_node(second)
        second.destroy_node()
    assert not lockstep or stamp_ns(probe.truth[0].header.stamp) == 0  # sample 0, not later
    assert list(probe.truth[0].position) == pytest.approx([0.0, math.pi])
    assert list(probe.truth[0].velocity) == pytest.approx([0.0, 0.0])


def test_a_reader_that_never_comes_delays_the_start_by_at_most_the_hold(graph, spin_until,
                                                                         monkeypatch):
    from cartpole_sim import sim_node
    monkeypatch.setattr(sim_node, 'START_HOLD_S', 0.05)
    sim, probe, executor = graph(lockstep=False, start_subscribers=9)  # 2 readers of 9
    assert spin_until(executor, lambda: sim._startup_timer is None and sim.runner.index >= 4,
                      timeout=10.0)
