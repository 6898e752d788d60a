"""The node graph of ``cartpole run``: one process (one executor) or one process a node.

The graph is ``sim`` (or ``hw_bridge``) + ``ekf`` + ``controller_manager``
(+ ``recorder``), wired by the topics of docs/architecture.md, plus a light
monitor node ``cartpole_run`` that watches the run: it keeps the time series
for the summary (:class:`cartpole_bringup.analyze.SeriesBuilder`), measures
the run's duration (simulated time in lockstep) and, at the end, switches the
controller manager off (``enabled:=false``) and waits for the zero force it
then publishes, disarms the hardware bridge, and only then stops the nodes,
plant first and recorder last, so the bag holds the zero force.

- One process (default): the node classes are instantiated on one
  :class:`~rclpy.executors.SingleThreadedExecutor` (as in
  ``examples_rclpy_executors/composed.py``); one DDS participant, the
  lowest latency.
- ``processes=True``: the installed executables
  ``install/<pkg>/lib/<pkg>/<exe>`` are started with ``--ros-args -p
  name:=value`` (and ``--params-file``), each in its own session so that a
  Ctrl-C reaches only ``cartpole run``, which then stops them in order
  (SIGINT, then SIGTERM and SIGKILL after a timeout). They also die with it
  (``PR_SET_PDEATHSIG``).

The parameters file (``--params``) is given to every node as
``--params-file`` (node sections and ``/**`` apply as in ROS); the explicit
options (scenario, controllers, ``lockstep``, ``use_sim_time``) override it.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import ParameterType
from rcl_interfaces.srv import GetParameters, SetParameters
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter, parameter_value_to_python
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger

from cartpole_sim import realtime

from .analyze import FORCE, HW_HEALTH, STATE, STATUS, TRUE_STATE, SeriesBuilder

NODES: dict[str, tuple[str, str, str, str]] = {
    'sim': ('cartpole_sim', 'sim_node', 'cartpole_sim.sim_node', 'SimNode'),
    'hw_bridge': ('cartpole_hw', 'hw_bridge', 'cartpole_hw.hw_node', 'HwBridgeNode'),
    'ekf': ('cartpole_estimation', 'ekf_node', 'cartpole_estimation.ekf_node', 'EkfNode'),
    'controller_manager': ('cartpole_control', 'controller_manager',
                           'cartpole_control.manager_node', 'ControllerManagerNode'),
    'recorder': ('cartpole_bringup', 'recorder', 'cartpole_bringup.record', 'RecorderNode'),
}
"""Node name -> (package, installed executable, module, class)."""

STARTUP_TIMEOUT = 30.0
"""Wall seconds for the graph to come up (processes import rclpy and numpy first)."""
ZERO_FORCE_TIMEOUT = 2.0
"""Wall seconds to wait for the zero force command after disabling the controllers."""
LOOP_START_TIMEOUT = 3.0
"""Lockstep: wall seconds for the loop to answer its first sample before the remedy."""
LOOP_START_ATTEMPTS = 3
EXIT_TIMEOUT = 5.0
"""Wall seconds a child process gets after SIGINT (then SIGTERM, then SIGKILL)."""


EXECUTORS = ('single', 'events')


def make_executor(kind: str, context):
    """The executor of the one-process graph (see :data:`EXECUTORS`)."""
    if kind == 'events':
        from rclpy.experimental import EventsExecutor
        return EventsExecutor(context=context)
    if kind == 'single':
        return SingleThreadedExecutor(context=context)
    raise ValueError(f'executor must be one of {EXECUTORS}, got {kind!r}')


class GraphError(RuntimeError):
    """The graph could not be started or driven (a node failed, a timeout)."""


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
        Simulator in lockstep; every node then uses sim time (``/clock``).
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

    def __post_init__(self) -> None:
        if self.plant not in ('sim', 'hw_bridge'):
            raise ValueError(f"plant must be 'sim' or 'hw_bridge', got {self.plant!r}")
        if self.lockstep and self.plant != 'sim':
            raise ValueError('lockstep needs the simulator')

    @property
    def nodes(self) -> list[str]:
        """Start order: recorder, ekf, controller manager, then the plant."""
        return (['recorder'] if self.record else []) + ['ekf', 'controller_manager', self.plant]

    def node_parameters(self, name: str) -> dict[str, Any]:
        """The explicit parameters of one node (incl. ``use_sim_time``, recorder output)."""
        out = dict(self.parameters.get(name, {}))
        if name == 'sim':
            out['lockstep'] = self.lockstep
        if name == 'recorder':
            out['output'] = str(self.record)
            out['custom_data'] = [f'{k}={v}' for k, v in self.custom_data.items()] or ['']
        if self.lockstep:
            out['use_sim_time'] = True
        return out


def ros_value_text(value: Any) -> str:
    """A parameter value as ``-p name:=value`` text (YAML)."""
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, (list, tuple)):
        return '[' + ', '.join(ros_value_text(v) for v in value) + ']'
    if isinstance(value, str):
        return "'" + value.replace("'", "''") + "'"
    return repr(value)


def executable(name: str) -> Path:
    """The installed executable of node ``name`` (``install/<pkg>/lib/<pkg>/<exe>``)."""
    from ament_index_python.packages import PackageNotFoundError, get_package_prefix
    package, exe = NODES[name][:2]
    try:
        path = Path(get_package_prefix(package)) / 'lib' / package / exe
    except PackageNotFoundError as error:
        raise GraphError(f'package {package} is not installed (run `make build`)') from error
    if not os.access(path, os.X_OK):
        raise GraphError(f'{path} is missing; run `make build`')
    return path


def command_line(spec: GraphSpec, name: str) -> list[str]:
    """The command starting node ``name`` as a process."""
    cmd = [str(executable(name)), '--ros-args', '--log-level', spec.log_level]
    if spec.params_file:
        cmd += ['--params-file', str(spec.params_file)]
    for key, value in spec.node_parameters(name).items():
        cmd += ['-p', f'{key}:={ros_value_text(value)}']
    return cmd


def _die_with_parent() -> None:  # pragma: no cover - runs in the child
    try:
        import ctypes
        ctypes.CDLL('libc.so.6', use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
    except OSError:
        pass


def _stamp_ns(stamp) -> int:
    return stamp.sec * 1_000_000_000 + stamp.nanosec


class RunMonitor(Node):
    """Watches a run (node ``cartpole_run``): series, sim time, forces.

    Parameters
    ----------
    state_topic
        The state it times the run by (``/cartpole/true_state`` on the
        simulator, ``/cartpole/state`` on the rig).
    collect
        Also subscribe the controller status (and the hw health) for the
        in-memory summary; not needed when a bag is recorded.
    """

    def __init__(self, state_topic: str = TRUE_STATE, collect: bool = True, **kwargs) -> None:
        super().__init__('cartpole_run', **kwargs)
        self.builder = SeriesBuilder()
        self.last_stamp_ns: int | None = None
        """Stamp of the latest state sample (simulated time in lockstep)."""
        self.forces = 0
        self.last_force: float | None = None
        self.zero_forces = 0
        qos = QoSProfile(depth=200, reliability=ReliabilityPolicy.RELIABLE)
        self.create_subscription(JointState, state_topic, self._state_cb(state_topic), qos)
        self.create_subscription(JointState, FORCE, self._on_force, qos)
        if collect:
            self.create_subscription(DiagnosticArray, STATUS, self._diag_cb(STATUS), qos)
            if state_topic == STATE:
                self.create_subscription(DiagnosticArray, HW_HEALTH, self._diag_cb(HW_HEALTH), qos)

    def _state_cb(self, topic: str) -> Callable[[JointState], None]:
        def callback(msg: JointState) -> None:
            stamp = _stamp_ns(msg.header.stamp)
            self.builder.joint_state(topic, stamp, msg.position, msg.velocity, msg.effort)
            if self.last_stamp_ns is None or stamp > self.last_stamp_ns:
                self.last_stamp_ns = stamp
        return callback

    def _on_force(self, msg: JointState) -> None:
        self.builder.joint_state(FORCE, _stamp_ns(msg.header.stamp), msg.position,
                                 msg.velocity, msg.effort)
        if len(msg.effort):
            self.forces += 1
            self.last_force = float(msg.effort[0])
            if self.last_force == 0.0:
                self.zero_forces += 1

    def _diag_cb(self, topic: str) -> Callable[[DiagnosticArray], None]:
        def callback(msg: DiagnosticArray) -> None:
            stamp = _stamp_ns(msg.header.stamp)
            for status in msg.status:
                values = {kv.key: kv.value for kv in status.values}
                if topic == STATUS:
                    self.builder.status(stamp, values)
                else:
                    self.builder.hw_health(stamp, values)
        return callback


class Graph:
    """A running node graph; use as a context manager (``close`` stops everything).

    Parameters
    ----------
    spec
        What to start.
    context
        An initialised rclpy context (its arguments carry ``--params-file``
        and the log level for the in-process nodes).
    should_stop
        Polled while waiting; True ends waits early (Ctrl-C).
    """

    def __init__(self, spec: GraphSpec, context, should_stop: Callable[[], bool] = lambda: False):
        self.spec = spec
        self.context = context
        self.should_stop = should_stop
        self.executor = make_executor(spec.executor, context)
        self.monitor = RunMonitor(state_topic=TRUE_STATE if spec.plant == 'sim' else STATE,
                                  collect=spec.record is None, context=context)
        self.executor.add_node(self.monitor)
        self.nodes: dict[str, Node] = {}
        self._clients: dict = {}
        self.processes: dict[str, subprocess.Popen] = {}
        self.wall_start: float | None = None
        self.stopped = False
        self.closed = False
        self.warnings: list[str] = []
        """Things that went other than planned while starting (reported at the end)."""
        self.realtime: realtime.LoopHygiene | None = None

    # -- start ---------------------------------------------------------------------------
    def start(self) -> None:
        """Start every node (plant last) and wait until the loop is wired."""
        if self.spec.processes:
            self._client(SetParameters, 'controller_manager', 'set_parameters')
            if self.spec.plant == 'hw_bridge':
                self._client(SetParameters, 'hw_bridge', 'set_parameters')
            self._start_processes()
        else:
            self._start_in_process()
            # The loop's real-time hygiene for this process (cartpole_sim.realtime), once
            # the executor has spun (its threads exist then and take the priority too).
            self.executor.spin_once(timeout_sec=0.0)
            try:
                self.realtime = realtime.enter_loop(
                    0 if self.spec.lockstep else None, what='cartpole run',
                    log=self.monitor.get_logger().info, warn=self.monitor.get_logger().warning)
            except ValueError as error:
                raise GraphError(str(error)) from None
        self.wall_start = time.monotonic()
        if not self.spin_until(lambda: self.monitor.last_stamp_ns is not None, STARTUP_TIMEOUT):
            if self.should_stop():
                return
            raise GraphError(f'no state arrived within {STARTUP_TIMEOUT:g} s; '
                             f'{self._process_report()}')
        if self.spec.lockstep:
            self._ensure_loop_started()
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
            if self.spin_until(moved, LOOP_START_TIMEOUT) or self.should_stop():
                return
            self.warnings.append('lockstep loop did not answer the first sample; '
                                 'reset the simulator (the run starts one period later)')
            client = self._client(Trigger, 'sim', 'reset')
            if self.spin_until(client.service_is_ready, 5.0):
                future = client.call_async(Trigger.Request())
                self.spin_until(future.done, 5.0)
            first = self.monitor.last_stamp_ns
        if not self.spin_until(moved, LOOP_START_TIMEOUT) and not self.should_stop():
            raise GraphError('the lockstep loop does not start; ' + self._process_report())

    def _start_in_process(self) -> None:
        import importlib
        for name in self.spec.nodes:
            package, _, module, cls = NODES[name]
            try:
                node_class = getattr(importlib.import_module(module), cls)
            except (ImportError, AttributeError) as error:
                raise GraphError(f'node {name} ({module}.{cls}) is not available: {error}') from error
            overrides = [Parameter(k, value=v) for k, v in self.spec.node_parameters(name).items()]
            try:
                node = node_class(context=self.context, parameter_overrides=overrides)
            except Exception as error:
                raise GraphError(f'node {name} did not start: {error}') from error
            self.nodes[name] = node
            self.executor.add_node(node)

    def _start_processes(self) -> None:
        env = dict(os.environ)
        for name in self.spec.nodes:
            if name == self.spec.plant:
                self._wait_for_subscribers()
            cmd = command_line(self.spec, name)
            self.processes[name] = subprocess.Popen(
                cmd, env=env, stdin=subprocess.DEVNULL, start_new_session=True,
                preexec_fn=_die_with_parent if sys.platform.startswith('linux') else None)

    def _wait_for_subscribers(self) -> None:
        """Processes: wait until EKF, controller manager (and recorder) are in the graph."""
        rec = 1 if self.spec.record else 0
        m = self.monitor

        def ready() -> bool:
            self._check_processes()
            return (m.count_subscribers('/joint_states') >= 1 + rec
                    and m.count_subscribers(STATE) >= 1 + rec
                    and m.count_publishers(FORCE) >= 1)
        if not self.spin_until(ready, STARTUP_TIMEOUT) and not self.should_stop():
            raise GraphError(f'the nodes did not come up within {STARTUP_TIMEOUT:g} s; '
                             f'{self._process_report()}')

    def _check_processes(self) -> None:
        for name, proc in self.processes.items():
            if proc.poll() is not None and not self.stopped:
                raise GraphError(f'node {name} exited with code {proc.returncode}')

    def _process_report(self) -> str:
        if not self.processes:
            return 'in-process nodes: ' + ', '.join(self.nodes)
        return ', '.join(f'{n}: {"running" if p.poll() is None else f"exit {p.returncode}"}'
                         for n, p in self.processes.items())

    # -- running -------------------------------------------------------------------------
    def spin_until(self, predicate: Callable[[], bool], timeout: float | None) -> bool:
        """Spin the executor until ``predicate()``; False on timeout or stop request."""
        deadline = None if timeout is None else time.monotonic() + timeout
        checks = 0
        while not predicate():
            if self.should_stop():
                return False
            if deadline is not None and time.monotonic() >= deadline:
                return False
            self.executor.spin_once(timeout_sec=0.05)
            checks += 1
            if self.processes and checks % 20 == 0:
                self._check_processes()
        return True

    def elapsed(self) -> float:
        """Run time so far [s]: simulated in lockstep, wall otherwise."""
        if self.spec.lockstep:
            stamp = self.monitor.last_stamp_ns
            return 0.0 if stamp is None else stamp * 1e-9
        return 0.0 if self.wall_start is None else time.monotonic() - self.wall_start

    def run_for(self, duration: float | None) -> None:
        """Spin until ``duration`` has elapsed (None: until ``should_stop``)."""
        if duration is None:
            self.spin_until(lambda: False, None)
        else:
            self.spin_until(lambda: self.elapsed() >= duration, None)

    # -- parameters ----------------------------------------------------------------------
    def _client(self, srv_type, node: str, service: str):
        """A service client of a graph node, kept for the whole run.

        Created early (at start), so that discovery of the response path is
        complete long before the stop needs it.
        """
        key = (node, service)
        if key not in self._clients:
            self._clients[key] = self.monitor.create_client(srv_type, f'/{node}/{service}')
        return self._clients[key]

    def set_parameters(self, node: str, values: dict[str, Any],
                       timeout: float = 5.0, attempts: int = 2) -> list[tuple[bool, str]]:
        """Set parameters of a graph node (in process, or through its service)."""
        params = [Parameter(k, value=v) for k, v in values.items()]
        if node in self.nodes:
            return [(r.successful, r.reason) for r in self.nodes[node].set_parameters(params)]
        client = self._client(SetParameters, node, 'set_parameters')
        if not self.spin_until(client.service_is_ready, timeout):
            return [(False, f'/{node}/set_parameters not available')] * len(params)
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
        client = self._client(GetParameters, node, 'get_parameters')
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

    # -- stop ----------------------------------------------------------------------------
    def stop(self) -> list[str]:
        """Zero force last, then stop the nodes (plant first, recorder last).

        Returns warnings (empty when everything went as planned).
        """
        if self.stopped:
            return []
        warnings: list[str] = []
        m = self.monitor
        zeros_before = m.zero_forces
        for (ok, reason) in self.set_parameters('controller_manager', {'enabled': False}, 6.0):
            if not ok:
                warnings.append(f'controller_manager enabled:=false refused: {reason}')
        if self.spec.plant == 'hw_bridge':
            for (ok, reason) in self.set_parameters('hw_bridge', {'armed': False}, 6.0):
                if not ok:
                    warnings.append(f'hw_bridge armed:=false refused: {reason}')
        if not self._wait(lambda: m.zero_forces > zeros_before, ZERO_FORCE_TIMEOUT):
            warnings.append('no zero force command seen after disabling the controller '
                            '(the plant watchdog zeroes the force)')
        self.stopped = True
        order = [self.spec.plant, 'ekf', 'controller_manager', 'recorder']
        if self.processes:
            for name in order:
                if name in self.processes:
                    warnings += self._stop_process(name)
        else:
            forces_seen = m.forces
            recorder = self.nodes.get('recorder')
            for name in order:
                node = self.nodes.pop(name, None)
                if node is None:
                    continue
                if name == 'recorder':
                    # Let the recorder take every command the monitor took, then close the bag.
                    self._wait(lambda: recorder.counts.get(FORCE, 0) >= forces_seen, 1.0)
                self.executor.remove_node(node)
                node.destroy_node()
        return warnings

    def _wait(self, predicate: Callable[[], bool], timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while not predicate():
            if time.monotonic() >= deadline:
                return False
            self.executor.spin_once(timeout_sec=0.02)
        return True

    def _stop_process(self, name: str) -> list[str]:
        proc = self.processes[name]
        if proc.poll() is not None:
            return [] if proc.returncode == 0 else [f'{name} had exited with code {proc.returncode}']
        for sig, grace in ((signal.SIGINT, EXIT_TIMEOUT), (signal.SIGTERM, 2.0),
                           (signal.SIGKILL, 2.0)):
            proc.send_signal(sig)
            try:
                # Keep the monitor spinning while a node shuts down (it may still publish).
                self._wait(lambda: proc.poll() is not None, grace)
                proc.wait(timeout=0.1)
            except subprocess.TimeoutExpired:
                continue
            if sig == signal.SIGINT:
                return [] if proc.returncode in (0, -signal.SIGINT) else \
                    [f'{name} exited with code {proc.returncode}']
            return [f'{name} did not stop on SIGINT; sent {sig.name}']
        return [f'{name} could not be stopped']

    def close(self) -> list[str]:
        """Stop (if not yet), destroy the monitor, make sure no child is left."""
        if self.closed:
            return []
        warnings: list[str] = list(self.warnings)
        try:
            warnings += self.stop()
        finally:
            self.closed = True
            for node in list(self.nodes.values()):
                node.destroy_node()
            self.nodes.clear()
            for name, proc in self.processes.items():
                if proc.poll() is None:
                    proc.kill()
                    proc.wait()
            self.monitor.destroy_node()
            self.executor.shutdown(timeout_sec=1.0)
            if self.realtime is not None:
                self.realtime.leave()
        return warnings

    def __enter__(self) -> 'Graph':
        return self

    def __exit__(self, *exc) -> None:
        self.close()
