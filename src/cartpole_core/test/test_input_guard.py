"""Foreign publishers are named by node; one DDS has not yet put a name to is not named."""
from types import SimpleNamespace

from cartpole_core.input_guard import InputGuard, UNKNOWN_NODE
from cartpole_core.message_checks import RigLimits


class _Node:
    """What the guard asks of its node: the publishers of a topic, a logger."""

    def __init__(self, publishers):
        self.publishers = publishers
        self.warnings = []

    def resolve_topic_name(self, topic):
        return '/' + topic

    def get_publishers_info_by_topic(self, name):
        return [SimpleNamespace(node_name=n, node_namespace='/') for n in self.publishers]

    def get_logger(self):
        return SimpleNamespace(warning=self.warnings.append)


def test_a_publisher_without_a_known_node_is_not_named_foreign_until_its_name_is_known():
    node = _Node(['sim', UNKNOWN_NODE])
    guard = InputGuard(node, RigLimits(), ['joint_states'])
    assert guard.foreign_publishers() == {}
    assert node.warnings == []
    node.publishers = ['sim', 'intruder']
    guard._looked_at = -1e9  # the next look is due
    assert guard.foreign_publishers() == {'joint_states': ['/intruder']}
    assert node.warnings == ['foreign publisher /intruder on /joint_states: not a node of the graph']
