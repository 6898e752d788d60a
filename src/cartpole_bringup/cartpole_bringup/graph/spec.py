"""What a graph is made of (:class:`GraphSpec`): its nodes, their parameters, its executor.

:class:`cartpole_bringup.graph.graph.Graph` starts what a spec describes, in one
process or one process a node.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rclpy.executors import SingleThreadedExecutor

from cartpole_core import namespaces

RECORDER_WINDOW = 10
"""Lockstep with a recorder: how many samples the simulator may be ahead of it (the
publishers keep 100, cartpole_core.node_runner.PUBLISH_DEPTH)."""


EXECUTORS = ('single', 'events')


def make_executor(kind: str, context):
    """The executor of the one-process graph (see :data:`EXECUTORS`)."""
    if kind == 'events':
        from rclpy.experimental import EventsExecutor
        return EventsExecutor(context=context)
    if kind == 'single':
        return SingleThreadedExecutor(context=context)
    raise ValueError(f'executor must be one of {EXECUTORS}, got {kind!r}')


@dataclass
class GraphSpec:
    """What to start.

    Attributes
    ----------
    plant
        ``'sim'`` or ``'hw_bridge'``.
    parameters
        Node name -> ROS parameters set explicitly (they override the file).
    params_file
        ROS 2 parameters YAML given to every node, or None.
    lockstep
        Simulator in lockstep; every node then uses sim time (``/clock``),
        and the EKF waits for the command of the previous sample.
    processes
        One OS process a node instead of one executor.
    record
        Directory of the bag to write (it must not exist), or None.
    custom_data
        Strings stored in the bag's ``custom_data``.
    log_level
        ROS log level of the nodes.
    executor
        One-process executor: ``'single'`` (rclpy's SingleThreadedExecutor) or
        ``'events'`` (rclpy.experimental's EventsExecutor, C++).
    allow_duplicates
        Start even when the graph's roles are taken in its namespace.
    namespace
        ROS namespace of every node (``/`` or ``/rig2``; :mod:`cartpole_core.namespaces`).
    hw_arm
        The rig: activate (arm) the bridge once the loop answers; else it stays
        inactive (streaming, disarmed).
    """

    plant: str
    parameters: dict[str, dict[str, Any]] = field(default_factory=dict)
    params_file: Path | None = None
    lockstep: bool = False
    processes: bool = False
    record: Path | None = None
    custom_data: dict[str, str] = field(default_factory=dict)
    log_level: str = 'warn'
    executor: str = 'events'
    allow_duplicates: bool = False
    namespace: str = namespaces.ROOT
    hw_arm: bool = False

    def __post_init__(self) -> None:
        self.namespace = namespaces.normalize(self.namespace)
        if self.plant not in ('sim', 'hw_bridge'):
            raise ValueError(f"plant must be 'sim' or 'hw_bridge', got {self.plant!r}")
        if self.lockstep and self.plant != 'sim':
            raise ValueError('lockstep needs the simulator')
        if self.hw_arm and self.plant != 'hw_bridge':
            raise ValueError('hw_arm needs the rig (plant hw_bridge)')

    @property
    def nodes(self) -> list[str]:
        """Start order: recorder, ekf, controller manager, then the plant."""
        return (['recorder'] if self.record else []) + ['ekf', 'controller_manager', self.plant]

    @property
    def ros_arguments(self) -> list[str]:
        """The ROS arguments of every node of the graph (its namespace, its ``/clock``)."""
        return namespaces.ros_arguments(self.namespace)

    def node_options(self) -> dict[str, Any]:
        """Keyword arguments of an ``rclpy.node.Node`` of the graph's process (its
        ``cli_args``: the namespace); none in the root namespace."""
        return {'cli_args': ['--ros-args', *self.ros_arguments]} if self.ros_arguments else {}

    def node_parameters(self, name: str) -> dict[str, Any]:
        """The explicit parameters of one node (incl. ``use_sim_time``, recorder output)."""
        out = dict(self.parameters.get(name, {}))
        if name == 'sim':
            out['lockstep'] = self.lockstep
        if name in ('ekf', 'controller_manager') and self.lockstep:
            out['lockstep'] = True
        if self.lockstep and name == 'sim':
            # The recorder, or without one the run monitor, paces the loop (complete series).
            out['recorder_window'] = RECORDER_WINDOW
        if name == 'recorder':
            out['lockstep'] = self.lockstep
            out['output'] = str(self.record)
            out['custom_data'] = [f'{k}={v}' for k, v in self.custom_data.items()] or ['']
        if self.lockstep:
            out['use_sim_time'] = True
        return out
