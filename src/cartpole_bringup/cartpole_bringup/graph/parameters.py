"""The parameters of a graph's nodes: in process directly, across processes by their services."""
from __future__ import annotations

from typing import Any, Callable

from rcl_interfaces.msg import ParameterType
from rcl_interfaces.srv import GetParameters, SetParameters
from rclpy.parameter import Parameter, parameter_value_to_python


class NodeParameters:
    """Set and get parameters of the nodes of a :class:`cartpole_bringup.graph.graph.Graph`.

    ``nodes`` are the graph's in-process nodes (set directly); the others are
    reached through their services by clients of ``client_node`` (the run
    monitor), kept for the run; ``spin_until(predicate, timeout)`` waits
    while the graph spins.
    """

    def __init__(self, nodes: dict, client_node, spin_until: Callable) -> None:
        self.nodes = nodes
        self.client_node = client_node
        self.spin_until = spin_until
        self._clients: dict = {}

    def client(self, srv_type, node: str, service: str):
        """A service client of a graph node, kept for the whole run.

        Created early (at start), so that discovery of the response path is
        complete long before the stop needs it. The name is relative: the
        node of the graph's namespace.
        """
        key = (node, service)
        if key not in self._clients:
            self._clients[key] = self.client_node.create_client(srv_type, f'{node}/{service}')
        return self._clients[key]

    def set_parameters(self, node: str, values: dict[str, Any],
                       timeout: float = 5.0, attempts: int = 2) -> list[tuple[bool, str]]:
        """Set parameters of a graph node (in process, or through its service)."""
        params = [Parameter(k, value=v) for k, v in values.items()]
        if node in self.nodes:
            return [(r.successful, r.reason) for r in self.nodes[node].set_parameters(params)]
        client = self.client(SetParameters, node, 'set_parameters')
        if not self.spin_until(client.service_is_ready, timeout):
            return [(False, f'{client.service_name} not available')] * len(params)
        request = SetParameters.Request(parameters=[p.to_parameter_msg() for p in params])
        for _ in range(attempts):  # a response can be lost while discovery completes
            future = client.call_async(request)
            if self.spin_until(future.done, timeout / attempts) and future.result() is not None:
                return [(r.successful, r.reason) for r in future.result().results]
            client.remove_pending_request(future)
        return [(False, 'no answer')] * len(params)

    def get_parameter(self, node: str, name: str, timeout: float = 5.0) -> Any:
        """A parameter value of a graph node, None if it cannot be read."""
        if node in self.nodes:
            node_obj = self.nodes[node]
            return node_obj.get_parameter(name).value if node_obj.has_parameter(name) else None
        client = self.client(GetParameters, node, 'get_parameters')
        if not self.spin_until(client.service_is_ready, timeout):
            return None
        future = client.call_async(GetParameters.Request(names=[name]))
        if not self.spin_until(future.done, timeout) or future.result() is None:
            client.remove_pending_request(future)
            return None
        values = future.result().values
        if not values or values[0].type == ParameterType.PARAMETER_NOT_SET:
            return None
        return parameter_value_to_python(values[0])
