"""What a node of the graph is (its role), whatever it is called and wherever it runs (no ROS).

A node can be renamed (``-r __node:=plant``) and moved (``-r __ns:=/rig2``);
its role stays what its executable is. The duplicate guard
(:mod:`cartpole_core.domain_guard`) and the real-time priority
(:mod:`cartpole_core.realtime`) go by the role, so a renamed node keeps both:

- a node process knows its role from its executable (:data:`ROLE_OF_EXECUTABLE`,
  the ``name`` each ``main()`` gives :func:`cartpole_core.node_runner.run_node`);
- ``cartpole run`` knows the roles of the nodes it starts;
- on the DDS graph, a role is seen by what it publishes (:data:`ROLE_TOPICS`,
  relative to the graph's namespace), the node that publishes it being the
  one found.
"""
from __future__ import annotations

ROLE_OF_EXECUTABLE: dict[str, str] = {
    'sim_node': 'sim',
    'hw_bridge': 'hw_bridge',
    'ekf_node': 'ekf',
    'controller_manager': 'controller_manager',
    'recorder': 'recorder',
}
"""Installed executable -> the role of the node it runs (its default node name)."""

LOOP_ROLES = frozenset({'sim', 'hw_bridge', 'ekf', 'controller_manager'})
"""The roles in the control loop (they take the real-time priority)."""

ROLE_TOPICS: dict[str, str] = {
    'sim': 'joint_states',
    'hw_bridge': 'joint_states',
    'ekf': 'cartpole/state',
    'controller_manager': 'cartpole/controller_status',
}
"""Role -> the topic (relative) that only a node of that role publishes in a graph: the
plant's samples, the estimate, the controller status. The recorder and the run monitor
publish nothing of their own; only the machine-local claim sees them."""


def role_of_executable(executable: str) -> str | None:
    """The role of an installed executable's node, None for a node outside the graph."""
    return ROLE_OF_EXECUTABLE.get(executable)


def topic_in_namespace(topic: str, namespace: str) -> str:
    """The absolute name of a relative ``topic`` in ``namespace`` (``/`` or ``/rig1``)."""
    return namespace.rstrip('/') + '/' + topic.lstrip('/')
