"""Starting a graph: its nodes in one process or one process a node, until the loop is wired.

The plant starts last (with processes: once the EKF, the controller manager
and the recorder subscribe); the rig's bridge, a managed node, is then
configured (and, with ``hw_arm``, activated once the loop answers:
:mod:`cartpole_bringup.graph.bridge_lifecycle`). The start waits for the first
state and, in lockstep, for the loop to answer its first sample
(:data:`LOOP_START_TIMEOUT`).
"""
from __future__ import annotations

import importlib
import time
from typing import Callable

from rclpy.parameter import Parameter
from rcl_interfaces.srv import SetParameters
from std_srvs.srv import Trigger

from cartpole_core import realtime
from cartpole_core.domain_guard import ALLOW_PARAMETER

from cartpole_analysis.analysis.analyze import FORCE, JOINTS, STATE, TRUE_STATE
from cartpole_core.namespaces import relative
from .processes import NODES, NodeStartError, describe_exit, node_command, start_node_process
from .spec import GraphSpec

STARTUP_TIMEOUT = 30.0
"""Wall seconds for the graph to come up (processes import rclpy and numpy first)."""
LOOP_START_TIMEOUT = 10.0
"""Lockstep: wall seconds for the loop to answer its first sample before the remedy.

Longer than the discovery of one process by another (up to about 3 s: Fast DDS's
participant announcement period): until then the EKF's re-published estimate and the
manager's answer to it reach the simulator without a reset, and a reset (which starts
the run one period later) would make the run differ from the same run without one."""
LOOP_START_ATTEMPTS = 3

class GraphError(RuntimeError):
    """The graph could not be started (a node failed, a timeout)."""


def command_line(spec: GraphSpec, name: str, extra: dict | None = None) -> list[str]:
    """The command starting node ``name`` of ``spec`` as a process (``extra``: more
    parameters)."""
    parameters = {**spec.node_parameters(name), **(extra or {})}
    if spec.allow_duplicates:
        parameters[ALLOW_PARAMETER] = True
    try:
        return node_command(name, parameters, log_level=spec.log_level,
                            params_file=spec.params_file, ros_arguments=spec.ros_arguments)
    except NodeStartError as error:
        raise GraphError(str(error)) from error


def plant_readers(spec: GraphSpec) -> dict[str, set[str]]:
    """``{topic: node names}``: the graph's nodes that read the plant's topics, each of which
    must be seen reading before the plant starts and the simulator's ``start_subscribers``
    is counted (a count of readers alone can be met while the recorder is still unseen:
    the bag would lack the run's first samples)."""
    readers = {JOINTS: {n for n in ('ekf', 'controller_manager', 'recorder') if n in spec.nodes}}
    if spec.plant == 'sim' and 'recorder' in spec.nodes:
        readers[TRUE_STATE] = {'recorder'}
    return readers


class GraphStartup:
    """The start of a :class:`cartpole_bringup.graph.graph.Graph`.

    Fills the graph's inventory (``nodes`` in this process, or ``processes``)
    on its ``executor``, watched by its ``monitor``; uses its parts
    (``parameters``' clients, the ``bridge``, the ``faults``). Holds this
    process's real-time hygiene (one process) once the loop runs here.
    """

    def __init__(self, spec, context, executor, monitor, nodes: dict, processes: dict,
                 parameters, bridge, faults, spin_until: Callable,
                 should_stop: Callable[[], bool], warn: Callable[[str], None]) -> None:
        self.spec = spec
        self.context = context
        self.executor = executor
        self.monitor = monitor
        self.nodes = nodes
        self.processes = processes
        self.parameters = parameters
        self.bridge = bridge
        self.faults = faults
        self.spin_until = spin_until
        self.should_stop = should_stop
        self.warn = warn
        self.realtime: realtime.LoopHygiene | None = None
        self.wall_start: float | None = None
        """Wall time the run began: when the loop is wired (set again once it answers)."""

    def _ending(self) -> bool:
        return self.should_stop() or self.faults.fault is not None

    def start(self) -> None:
        """Start every node (plant last) and wait until the loop is wired."""
        rig = self.spec.plant == 'hw_bridge'
        if rig:
            self.bridge.client()
        if self.spec.processes:
            self.parameters.client(SetParameters, 'controller_manager', 'set_parameters')
            self._start_processes()
        else:
            self._start_in_process()
            # The loop's real-time hygiene for this process (cartpole_core.realtime), once
            # the executor has spun (its threads exist then and take the priority too).
            self.executor.spin_once(timeout_sec=0.0)
            try:
                self.realtime = realtime.enter_loop(
                    0 if self.spec.lockstep else None, what='cartpole run',
                    log=self.monitor.get_logger().info, warn=self.monitor.get_logger().warning)
            except ValueError as error:
                raise GraphError(str(error)) from None
        if rig:   # a managed node: samples flow once it is configured
            reason = self.bridge.configure()
            if reason and not self._ending():
                raise GraphError(f'{reason}; {self._process_report()}')
        self.wall_start = time.monotonic()
        if not self.spin_until(lambda: self.monitor.last_stamp_ns is not None, STARTUP_TIMEOUT):
            # Ctrl-C, or a node died once the plant had started (under load the monitor's
            # subscription can match seconds after the plant began to publish): the run
            # stops and its summary reports the fault, as for a death later on.
            if self._ending():
                return
            raise GraphError(f'no state arrived within {STARTUP_TIMEOUT:g} s; '
                             f'{self._process_report()}')
        if self.spec.lockstep:
            self._ensure_loop_started()
        if rig and self.spec.hw_arm:   # arm once the loop answers (cartpole run --hw-arm)
            reason = self.bridge.activate()
            if reason and not self._ending():
                raise GraphError(reason)
        self.wall_start = time.monotonic()

    def _ensure_loop_started(self) -> None:
        """Lockstep: make sure the loop got past its first sample.

        The simulator re-publishes its first sample until the answering force
        command arrives. With one process a node, that first command can be
        published before the simulator's subscription is matched and be lost;
        the EKF then ignores the repeated sample (same stamp) and the loop
        would wait forever. The remedy is the simulator's ``~/reset``: the
        initial state again, as a new sample one period later.
        """
        first = self.monitor.last_stamp_ns
        moved = lambda: self.monitor.last_stamp_ns > first  # noqa: E731
        for _ in range(LOOP_START_ATTEMPTS):
            if self.spin_until(moved, LOOP_START_TIMEOUT) or self._ending():
                return
            self.warn('lockstep loop did not answer the first sample; '
                      'reset the simulator (the run starts one period later)')
            client = self.parameters.client(Trigger, 'sim', 'reset')
            if self.spin_until(client.service_is_ready, 5.0):
                future = client.call_async(Trigger.Request())
                self.spin_until(future.done, 5.0)
            first = self.monitor.last_stamp_ns
        if not self.spin_until(moved, LOOP_START_TIMEOUT) and not self._ending():
            raise GraphError('the lockstep loop does not start; ' + self._process_report())

    def _start_in_process(self) -> None:
        for name in self.spec.nodes:
            package, _, module, cls = NODES[name]
            try:
                node_class = getattr(importlib.import_module(module), cls)
            except (ImportError, AttributeError) as error:
                raise GraphError(f'node {name} ({module}.{cls}) is not available: {error}') from error
            overrides = [Parameter(k, value=v) for k, v in self.spec.node_parameters(name).items()]
            try:
                node = node_class(context=self.context, parameter_overrides=overrides,
                                  **self.spec.node_options())
            except Exception as error:
                raise GraphError(f'node {name} did not start: {error}') from error
            self.nodes[name] = node
            self.executor.add_node(node)

    def _start_processes(self) -> None:
        for name in self.spec.nodes:
            extra = {}
            if name == self.spec.plant:
                self._wait_for_subscribers()
                if name == 'sim':
                    # the readers seen here, matched before the first sample (a reader
                    # discovering the new simulator late would miss the run's start; in
                    # lockstep this node, which answers a dead manager's samples with zero)
                    m = self.monitor
                    extra['start_subscribers'] = min(
                        m.count_subscribers(relative(JOINTS)),
                        m.count_subscribers(relative(TRUE_STATE)))
            self.processes[name] = start_node_process(command_line(self.spec, name, extra))

    def _wait_for_subscribers(self) -> None:
        """Processes: wait until EKF, controller manager (and recorder) are in the graph."""
        rec = 1 if self.spec.record else 0
        m = self.monitor
        wanted = plant_readers(self.spec)

        def ready() -> bool:
            # The monitor itself publishes on FORCE too (its zero force in a fault).
            return (all(names <= {i.node_name for i in
                                  m.get_subscriptions_info_by_topic(relative(topic))}
                        for topic, names in wanted.items())
                    and m.count_subscribers(relative(STATE)) >= 1 + rec
                    and m.count_publishers(relative(FORCE)) >= 2)
        if not self.spin_until(ready, STARTUP_TIMEOUT) and not self.should_stop():
            raise GraphError(self.faults.fault or f'the nodes did not come up within '
                                           f'{STARTUP_TIMEOUT:g} s; {self._process_report()}')

    def _process_report(self) -> str:
        if not self.processes:
            return 'in-process nodes: ' + ', '.join(self.nodes)
        return ', '.join(f'{n}: {"running" if p.poll() is None else describe_exit(p.returncode)}'
                         for n, p in self.processes.items())
