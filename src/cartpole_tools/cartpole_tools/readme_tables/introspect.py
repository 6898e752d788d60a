"""What each installed node declares: parameters with descriptors, topics, services.

Each node is built in-process in its own rclpy context (never spun: nothing is
published or opened beyond what its constructor does) and destroyed after.
The hardware bridge gets a port that does not exist (a managed node, it stays
unconfigured and opens nothing); the recorder an output directory inside a
temporary directory.
"""
from __future__ import annotations

import importlib
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

INTERNAL_PARAMETERS = frozenset({'use_sim_time', 'start_type_description_service'})
"""Parameters every rclpy node declares by itself (not ours to document)."""

INTERNAL_TOPICS = frozenset({'/rosout', '/parameter_events'})

INTERNAL_SERVICE_SUFFIXES = ('/describe_parameters', '/get_parameter_types', '/get_parameters',
                             '/get_type_description', '/list_parameters', '/set_parameters',
                             '/set_parameters_atomically', '/get_available_states',
                             '/get_available_transitions', '/get_transition_graph')
"""rclpy's own parameter and type-description services of every node, and the descriptive
lifecycle services of a managed node (its ``change_state`` and ``get_state`` are documented)."""


@dataclass(frozen=True)
class ParameterInfo:
    """One declared parameter as ``ros2 param describe`` shows it."""

    name: str
    type_name: str
    default: Any
    low: float | None
    high: float | None
    step: float | None
    read_only: bool
    description: str
    additional_constraints: str


@dataclass(frozen=True)
class Endpoint:
    """A topic or service of a node: ``kind`` is ``publishes``, ``subscribes`` or ``service``."""

    kind: str
    name: str
    type_name: str
    condition: str = ''
    """Empty, or the parameter overrides under which alone the node creates it."""


@dataclass(frozen=True)
class NodeInfo:
    """Everything the README tables say about one node."""

    node: str
    executable: str
    package: str
    parameters: tuple[ParameterInfo, ...]
    endpoints: tuple[Endpoint, ...]


@dataclass(frozen=True)
class NodeSource:
    """How to build one installed node: its package, executable and class."""

    package: str
    executable: str
    module: str
    cls: str
    overrides: Callable[[Path], dict[str, Any]] = lambda tmp: {}
    variants: tuple[dict[str, Any], ...] = ()
    """Further parameter overrides that make the node create more endpoints (e.g. lockstep)."""


NODES: tuple[NodeSource, ...] = (
    NodeSource('cartpole_sim', 'sim_node', 'cartpole_sim.sim_node', 'SimNode',
               variants=({'lockstep': True, 'recorder_window': 10},)),
    NodeSource('cartpole_estimation', 'ekf_node', 'cartpole_estimation.ekf_node', 'EkfNode'),
    NodeSource('cartpole_control', 'controller_manager', 'cartpole_control.manager_node',
               'ControllerManagerNode'),
    NodeSource('cartpole_hw', 'hw_bridge', 'cartpole_hw.hw_node', 'HwBridgeNode',
               lambda tmp: {'port': str(tmp / 'no-such-port')}),
    NodeSource('cartpole_bringup', 'cartpole_recorder', 'cartpole_bringup.graph.recorder', 'RecorderNode',
               lambda tmp: {'output': str(tmp / 'bag')}, variants=({'lockstep': True},)),
    NodeSource('cartpole_analysis', 'cartpole_viewer', 'cartpole_analysis.viewer.node', 'ViewerNode',
               lambda tmp: {'port': 0}),
)
"""Every installed executable that is a ROS node (``cartpole`` and ``emulator`` are not)."""

_OVERRIDE_DEFAULTS = {'hw_bridge': {'port': '/dev/ttyACM0'}, 'recorder': {'output': ''},
                      'viewer': {'port': 8765}}
"""The declared defaults of the parameters :data:`NODES` overrides to build the node."""


def _type_name(type_id: int) -> str:
    from rcl_interfaces.msg import ParameterType
    names = {getattr(ParameterType, n): n[len('PARAMETER_'):].lower()
             for n in dir(ParameterType) if n.startswith('PARAMETER_')}
    return names.get(type_id, str(type_id))


def _python(value: Any) -> Any:
    if hasattr(value, 'tolist'):
        value = value.tolist()
    return list(value) if isinstance(value, (list, tuple)) else value


def _parameter(node, name: str, defaults: dict[str, Any]) -> ParameterInfo:
    d = node.describe_parameter(name)
    low = high = step = None
    if d.floating_point_range:
        r = d.floating_point_range[0]
        low, high, step = r.from_value, r.to_value, r.step
    elif d.integer_range:
        r = d.integer_range[0]
        low, high, step = r.from_value, r.to_value, r.step
    value = defaults[name] if name in defaults else _python(node.get_parameter(name).value)
    return ParameterInfo(name=name, type_name=_type_name(d.type), default=value, low=low,
                         high=high, step=step, read_only=bool(d.read_only),
                         description=d.description, additional_constraints=d.additional_constraints)


def _type_string(cls) -> str:
    module = cls.__module__.split('.')
    return f'{module[0]}/{module[1]}/{cls.__name__}' if len(module) > 1 else cls.__name__


def _service_name(node, name: str) -> str:
    return f'/{node.get_name()}/{name[2:]}' if name.startswith('~/') else name


def _endpoints(node) -> set[Endpoint]:
    found = set()
    for pub in node.publishers:
        if pub.topic_name not in INTERNAL_TOPICS:
            found.add(Endpoint('publishes', pub.topic_name, _type_string(pub.msg_type)))
    for sub in node.subscriptions:
        if sub.topic_name not in INTERNAL_TOPICS:
            found.add(Endpoint('subscribes', sub.topic_name, _type_string(sub.msg_type)))
    for srv in node.services:
        if not srv.srv_name.endswith(INTERNAL_SERVICE_SUFFIXES):
            found.add(Endpoint('service', _service_name(node, srv.srv_name),
                               _type_string(srv.srv_type)))
    return found


def _sorted(endpoints) -> tuple[Endpoint, ...]:
    order = {'publishes': 0, 'subscribes': 1, 'service': 2}
    return tuple(sorted(endpoints, key=lambda e: (order[e.kind], e.name)))


def _build(source: NodeSource, context, extra: dict[str, Any], workdir: Path):
    from rclpy.parameter import Parameter

    cls = getattr(importlib.import_module(source.module), source.cls)
    workdir.mkdir(parents=True)
    overrides = {**source.overrides(workdir), **extra}
    return cls(context=context,
               parameter_overrides=[Parameter(k, value=v) for k, v in overrides.items()])


def describe_node(source: NodeSource, context, workdir: Path) -> NodeInfo:
    """Build ``source``'s node in ``context`` (and each variant), read its declarations, destroy it.

    ``workdir`` is an empty scratch directory (the recorder's bag goes there).
    """
    node = _build(source, context, {}, workdir / 'default')
    try:
        name = node.get_name()
        defaults = _OVERRIDE_DEFAULTS.get(name, {})
        names = [n for n in node.list_parameters([], 0).names if n not in INTERNAL_PARAMETERS]
        parameters = tuple(_parameter(node, n, defaults) for n in names)
        endpoints = _endpoints(node)
    finally:
        node.destroy_node()
    for i, variant in enumerate(source.variants):
        node = _build(source, context, variant, workdir / f'variant{i}')
        try:
            condition = ', '.join(f'`{k}:={str(v).lower()}`' for k, v in variant.items())
            for extra in _endpoints(node) - endpoints:
                endpoints.add(Endpoint(extra.kind, extra.name, extra.type_name, condition))
        finally:
            node.destroy_node()
    return NodeInfo(node=name, executable=source.executable, package=source.package,
                    parameters=parameters, endpoints=_sorted(endpoints))


def describe_nodes(sources: tuple[NodeSource, ...] = NODES) -> dict[str, NodeInfo]:
    """Every node of ``sources`` by node name, each built in a fresh private context.

    Discovery is kept on this host (``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``)
    unless the caller chose otherwise; nothing is spun, so no other graph is touched.
    """
    import rclpy
    from rclpy.context import Context

    from cartpole_core.middleware import keep_on_this_host
    keep_on_this_host()
    found = {}
    with tempfile.TemporaryDirectory(prefix='cartpole-readme-') as tmp:
        for source in sources:
            context = Context()
            rclpy.init(context=context)
            try:
                info = describe_node(source, context, Path(tmp) / source.executable)
            finally:
                rclpy.try_shutdown(context=context)
            found[info.node] = info
    return found
