"""No half-built node: a node of ours that refuses its parameters at construction leaves
no publisher, subscription or service of it in the process (graph introspection from a
probe node in the same context, which sees the process's own entities at once).

rclpy (Jazzy) itself leaves one thing of any destroyed node in the graph: its
``~/get_type_description`` service (a plain ``rclpy.node.Node`` created and destroyed
shows it too); the tests hold the refused node to that floor."""
import pytest

pytestmark = pytest.mark.ros


def _entities(probe, name: str) -> dict[str, list[str]]:
    """The publishers, subscriptions and services of the nodes called ``name``."""
    found: dict[str, list[str]] = {'publishers': [], 'subscriptions': [], 'services': []}
    for topic, _ in probe.get_topic_names_and_types():
        for kind, infos in (('publishers', probe.get_publishers_info_by_topic(topic)),
                            ('subscriptions', probe.get_subscriptions_info_by_topic(topic))):
            found[kind] += [topic for info in infos if info.node_name == name]
    found['services'] = [service for service, _ in probe.get_service_names_and_types()
                         if service.startswith(f'/{name}/')]
    return found


def _floor(context, probe, name: str) -> dict[str, list[str]]:
    """What a plain rclpy node called ``name`` leaves after destroy_node (rclpy's own)."""
    from rclpy.node import Node
    Node(name, context=context).destroy_node()
    floor = _entities(probe, name)
    assert floor == {'publishers': [], 'subscriptions': [],
                     'services': [f'/{name}/get_type_description']}, floor
    return floor


def _refused(kind: str):
    """(node name, the node class, good overrides, refused overrides, the refusal's words)."""
    from rclpy.parameter import Parameter
    if kind == 'ekf':
        from cartpole_estimation.ekf_node import EkfNode
        return 'ekf', EkfNode, [], [Parameter('q', value=[1.0, 2.0])], 'q needs 4'
    if kind == 'controller_manager':
        from cartpole_control.manager_node import ControllerManagerNode
        return ('controller_manager', ControllerManagerNode, [],
                [Parameter('catch.angle_deg', value=50.0)], 'fall angle')
    if kind == 'sim':
        from cartpole_sim.sim_node import SimNode
        return 'sim', SimNode, [], [Parameter('x0', value=0.9)], 'outside the travel'
    if kind == 'hw_bridge':
        from cartpole_hw.hw_node import HwBridgeNode
        return 'hw_bridge', HwBridgeNode, [], [Parameter('port', value=' ')], 'port'
    from cartpole_analysis.viewer.node import ViewerNode
    return ('viewer', ViewerNode, None, [Parameter('plant_params_file', value='/no/such.yaml')],
            'such')


@pytest.mark.parametrize('kind', ['ekf', 'controller_manager', 'sim', 'hw_bridge', 'viewer'])
def test_a_refused_node_leaves_nothing_in_the_graph(ros_context, kind):
    from rclpy.node import Node

    name, cls, good, bad, words = _refused(kind)
    probe = Node('_refusal_probe', context=ros_context)
    try:
        if good is not None:   # the probe sees a node that was built: the check can fail
            node = cls(context=ros_context, parameter_overrides=good)
            try:
                seen = _entities(probe, name)
                assert seen['publishers'] and seen['services'], seen
            finally:
                node.destroy_node()
        # The refusal's traceback (kept, as a caller that reports it keeps it) holds the
        # half-built node alive: only its own destruction takes it out of the graph.
        with pytest.raises(Exception, match=words) as refusal:
            cls(context=ros_context, parameter_overrides=bad)
        assert name not in probe.get_node_names()
        assert _entities(probe, name) == _floor(ros_context, probe, name)
        assert refusal.traceback
    finally:
        probe.destroy_node()
