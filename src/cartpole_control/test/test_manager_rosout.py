"""The cores' Python logs reach /rosout while the controller manager node hosts them: a
plugin the registry skips and a refused ``ros2 param set`` (through the parameter
service) are seen on /rosout under the node's name; the routing ends with the node."""
import importlib
import logging
import sys

import pytest
from manager_test_support import fake_distribution

pytestmark = pytest.mark.ros

BROKEN = 'raise ImportError("needs a library that is not installed")\n'


def test_a_refused_plugin_is_seen_on_rosout(ros_context, spin_until, tmp_path, monkeypatch):
    from rcl_interfaces.msg import Log
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from rclpy.parameter_client import AsyncParameterClient
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    from cartpole_control.manager_node import ControllerManagerNode
    from cartpole_core.ros_logging import RosLogHandler

    site = tmp_path / 'site'
    fake_distribution(site, 'fake-broken', '0.1', 'fake_broken', BROKEN,
                      [('broken', 'fake_broken:Broken')])
    monkeypatch.setattr(sys, 'path', [str(site)] + sys.path)
    importlib.invalidate_caches()

    probe = Node('rosout_probe', context=ros_context)
    logs = []
    probe.create_subscription(Log, '/rosout', logs.append, QoSProfile(
        depth=1000, reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL))
    node = ControllerManagerNode(context=ros_context)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(probe)
    executor.add_node(node)

    def logged(level, *words):
        return [log.msg for log in logs if log.name == 'controller_manager'
                and log.level == level and all(w in log.msg for w in words)]

    try:
        assert spin_until(executor, lambda: logged(
            Log.WARN, 'cartpole_control.registry', 'skipping controller plugin broken',
            'ImportError', 'not installed'), 10.0), [log.msg for log in logs]
        client = AsyncParameterClient(probe, 'controller_manager')
        assert spin_until(executor, client.services_are_ready, 10.0)
        future = client.set_parameters([Parameter('stabilizer', value='no_such_plugin')])
        assert spin_until(executor, future.done, 10.0)
        (result,) = future.result().results
        assert not result.successful and 'no_such_plugin' in result.reason
        assert spin_until(executor, lambda: logged(
            Log.WARN, 'parameter change refused', 'no_such_plugin'), 10.0)
    finally:
        executor.shutdown()
        node.destroy_node()
        probe.destroy_node()
    library = logging.getLogger('cartpole_control')
    assert not [h for h in library.handlers if isinstance(h, RosLogHandler)]
