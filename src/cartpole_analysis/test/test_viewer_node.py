"""The `viewer` node on its own (`ros2 run cartpole_bringup viewer`): it takes the graph's topics.

A publisher node plays the graph's part (estimate, ground truth and controller status
with the same stamps, 200 Hz of stamps, the estimate after its sample's truth); a WebSocket client checks that the viewer
draws those values, has chosen the ground truth as the plant's state, and follows the
controller manager's x_ref from its parameter events.
"""
import importlib.util
import math
from pathlib import Path

import pytest

from cartpole_analysis.viewer.server import TOPICS
from cartpole_analysis.viewer.client import ViewerClient

_spec = importlib.util.spec_from_file_location('foxglove_support',
                                               Path(__file__).with_name('foxglove_support.py'))
foxglove_support = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(foxglove_support)

pytestmark = pytest.mark.ros


def test_standalone_viewer_draws_the_topics_it_subscribes(ros_context, spin_until):
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from sensor_msgs.msg import JointState

    from cartpole_analysis.viewer.node import ViewerNode

    viewer = ViewerNode(context=ros_context, parameter_overrides=[Parameter('port', value=0)])
    graph = Node('controller_manager', context=ros_context)  # its x_ref: parameter events
    graph.declare_parameter('x_ref', 0.3845)
    pubs = {topic: graph.create_publisher(JointState, topic, 100)
            for topic in ('/cartpole/state', '/cartpole/true_state')}
    status_pub = graph.create_publisher(DiagnosticArray, '/cartpole/controller_status', 100)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(viewer)
    executor.add_node(graph)
    client = None
    sent = {}
    try:
        assert spin_until(executor, lambda: viewer.plant_topic == '/cartpole/true_state', 10.0)
        client = ViewerClient(viewer.server.url, TOPICS.values())
        graph.set_parameters([Parameter('x_ref', value=0.5)])
        k = 0

        def joint_state(ns, x, theta):
            msg = JointState()
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(ns, 10**9)
            msg.name = ['cart', 'pendulum']
            msg.position, msg.velocity = [x, theta], [0.0, 0.0]
            return msg

        def publish_sample():
            # The graph's order: the truth of sample k now, the estimate (and the status)
            # of sample k-1, whose EKF step needed that sample's measurement first.
            nonlocal k
            ns = 1_700_000_000 * 10**9 + k * 5_000_000
            x, theta = 0.001 * k, math.pi - 0.01 * k
            pubs['/cartpole/true_state'].publish(joint_state(ns, x, theta))
            sent[ns] = (x, x + 2e-4, theta)
            if k > 0:
                ns_prev = ns - 5_000_000
                x_prev, _, theta_prev = sent[ns_prev]
                pubs['/cartpole/state'].publish(joint_state(ns_prev, x_prev + 2e-4, theta_prev))
                status = DiagnosticArray()
                status.header.stamp.sec, status.header.stamp.nanosec = divmod(ns_prev, 10**9)
                status.status = [DiagnosticStatus(
                    name='controller_manager', message='swingup',
                    values=[KeyValue(key='mode', value='swingup'),
                            KeyValue(key='event', value='')])]
                status_pub.publish(status)
            k += 1
        graph.create_timer(0.005, publish_sample)
        assert spin_until(executor, lambda: client.counts[TOPICS['scene']] >= 40, 30.0)
    finally:
        if client is not None:
            client.close()
        executor.shutdown()
        graph.destroy_node()
        viewer.destroy_node()
    schema = foxglove_support.Schema.from_advertised(client.channels[TOPICS['scene']])
    checked = 0
    for message in client.received(TOPICS['scene']):
        entities = {e['id']: e for e in
                    schema.decode('foxglove.SceneUpdate', message.payload)['entities']}
        x_true, x_est, theta = sent[message.log_time_ns]
        assert entities['estimate']['lines'][1]['points'][0]['x'] == pytest.approx(x_est)
        if 'plant' in entities:  # the truth of that stamp had arrived before its estimate
            assert entities['plant']['cubes'][0]['pose']['position']['x'] == \
                pytest.approx(x_true)
            checked += 1
        rig = entities['rig']
        mark_x = rig['lines'][0]['points'][0]['x']
        assert mark_x in (pytest.approx(0.3845), pytest.approx(0.5))
    assert checked >= 30
    # x* follows the manager's x_ref (0.3845 m at start, then set to 0.5 m).
    assert mark_x == pytest.approx(0.5)
