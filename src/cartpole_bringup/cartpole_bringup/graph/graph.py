"""The node graph of ``cartpole run``: one process (one executor) or one process a node.

The graph is ``sim`` (or ``hw_bridge``) + ``ekf`` + ``controller_manager``
(+ ``recorder``), wired by the topics of docs/architecture.md, plus a light
monitor node ``cartpole_run`` (:mod:`cartpole_bringup.graph.run_monitor`) that
watches the run: the time series for the summary, the run's duration
(simulated time in lockstep), the force commands.

- One process (default): the node classes are instantiated on one executor
  (as in ``examples_rclpy_executors/composed.py``); one DDS participant,
  the lowest latency.
- ``processes=True``: the installed executables, one process a node
  (:mod:`cartpole_bringup.graph.processes`).

**One graph per domain.** Before any node exists, the graph's node names are
claimed on the domain (:mod:`cartpole_sim.domain_guard`); a name taken
already refuses the start (:class:`~cartpole_sim.domain_guard.DuplicateNodeError`)
unless ``allow_duplicates``. A duplicate that shows up later is reported.

**A fault stops the run.** A node process that dies (or, in one process, a
callback that raises) is noticed within one spin of the monitor: the run
records the fault (``controller_manager died (SIGKILL)``) and stops.

**Stopping** (:meth:`Graph.stop`), orderly or after a fault: zero force
first, through whoever is still alive: after a fault the monitor's own zero
force command at once, then the controller manager's ``enabled:=false``
(and the zero force it then publishes); on the rig also the bridge's
``armed:=false`` (``U,0``, ``E,0``); on the simulator until a sample shows
the zero force applied. Then the
nodes stop one by one, the controller manager first (so that nothing it
watches goes stale while it still runs: no ``stale state`` fault for an
orderly stop), the plant, the EKF, and the recorder last, so that the bag
holds the zero force and is closed (in one process the plant goes first:
nothing spins between two nodes' ends there). A process gets SIGINT and time to shut
down properly (:data:`EXIT_TIMEOUT`, the recorder :data:`RECORDER_EXIT_TIMEOUT`)
before SIGTERM and, last, SIGKILL.

The parameters file (``--params``) is given to every node as
``--params-file`` (node sections and ``/**`` apply as in ROS); the explicit
options (scenario, controllers, ``lockstep``, ``use_sim_time``) override it.
"""
from __future__ import annotations

import importlib
import subprocess
import sys
import time
import traceback
from typing import Any, Callable

from rcl_interfaces.msg import ParameterType
from rcl_interfaces.srv import GetParameters, SetParameters
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.parameter import Parameter, parameter_value_to_python
from std_srvs.srv import Trigger

from cartpole_sim import realtime
from cartpole_sim.domain_guard import (ALLOW_PARAMETER, DuplicateNodeError, NodeClaim,
                                       claim_unique_names, domain_id, probe_node)

from ..analysis.analyze import FORCE, STATE, TRUE_STATE
from .spec import EXECUTORS, RECORDER_WINDOW, GraphSpec, make_executor  # noqa: F401
from .processes import (NODES, NodeStartError, describe_exit, executable,  # noqa: F401
                             node_command, ros_value_text, start_node_process, stop_node_process)
from .run_monitor import NODE_NAME as MONITOR_NAME
from .run_monitor import RunMonitor

STARTUP_TIMEOUT = 30.0
"""Wall seconds for the graph to come up (processes import rclpy and numpy first)."""
ZERO_FORCE_TIMEOUT = 2.0
"""Wall seconds to wait for the zero force command after disabling the controllers."""
LOOP_START_TIMEOUT = 10.0
"""Lockstep: wall seconds for the loop to answer its first sample before the remedy.

Longer than the discovery of one process by another (up to about 3 s: Fast DDS's
participant announcement period): until then the EKF's re-published estimate and the
manager's answer to it reach the simulator without a reset, and a reset (which starts
the run one period later) would make the run differ from the same run without one."""
LOOP_START_ATTEMPTS = 3
EXIT_TIMEOUT = 5.0
"""Wall seconds a child process gets after SIGINT (then SIGTERM, and SIGKILL 2 s later)."""
RECORDER_EXIT_TIMEOUT = 15.0
"""The recorder's SIGINT grace: it writes what it had received and closes the bag."""
CHECK_PERIOD = 0.01
"""Wall seconds between two looks at the child processes (a death is noticed this fast)."""
DUPLICATE_CHECK_PERIOD = 1.0
STOP_ORDER = ('controller_manager', 'sim', 'hw_bridge', 'ekf', 'recorder')
"""Processes: the manager first, so that nothing it watches goes stale while it runs."""
IN_PROCESS_STOP_ORDER = ('sim', 'hw_bridge', 'ekf', 'controller_manager', 'recorder')
"""One process: the plant first, before the manager's last zero force reaches it (the
executor would still run that callback of a destroyed node); nothing spins in between,
so nothing goes stale."""

class GraphError(RuntimeError):
    """The graph could not be started (a node failed, a timeout)."""


def command_line(spec: GraphSpec, name: str) -> list[str]:
    """The command starting node ``name`` of ``spec`` as a process."""
    parameters = spec.node_parameters(name)
    if spec.allow_duplicates:
        parameters[ALLOW_PARAMETER] = True
    try:
        return node_command(name, parameters, log_level=spec.log_level,
                            params_file=spec.params_file)
    except NodeStartError as error:
        raise GraphError(str(error)) from error


def _report(text: str) -> None:
    print(f'cartpole run: {text}', file=sys.stderr, flush=True)


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
    report
        Called with a line of text when something goes wrong during the run
        (a fault, a duplicate node); default: stderr.

    Raises DuplicateNodeError when a node name of the graph is taken on the domain.
    """

    def __init__(self, spec: GraphSpec, context, should_stop: Callable[[], bool] = lambda: False,
                 report: Callable[[str], None] = _report):
        self.spec = spec
        self.context = context
        self.should_stop = should_stop
        self.report = report
        self.nodes: dict[str, Node] = {}
        self._clients: dict = {}
        self.processes: dict[str, subprocess.Popen] = {}
        self.wall_start: float | None = None
        self.stopped = False
        self.closed = False
        self.warnings: list[str] = []
        """Things that went other than planned (reported at the end)."""
        self.fault: str | None = None
        """Why the run stopped early: a node that died, a callback that raised."""
        self.stop_stamp_ns: int | None = None
        """Stamp of the latest state when the stop began (where the run's summary ends)."""
        self._stopping = False
        self._asked_to_stop: set[str] = set()
        self._exits: dict[str, int] = {}
        self._next_check = 0.0
        self._next_duplicate_check = time.monotonic() + DUPLICATE_CHECK_PERIOD
        self._duplicates_reported: set[str] = set()
        self.realtime: realtime.LoopHygiene | None = None
        self._claim = None if spec.allow_duplicates else self._claim_names()
        try:
            self.executor = make_executor(spec.executor, context)
            self.monitor = RunMonitor(state_topic=TRUE_STATE if spec.plant == 'sim' else STATE,
                                      collect=spec.record is None, context=context)
        except BaseException:
            self._release_claim()
            raise
        self.executor.add_node(self.monitor)

    # -- one graph per domain -------------------------------------------------------------
    def _claim_names(self) -> NodeClaim:
        """Claim the graph's names on the domain (cartpole_sim.domain_guard) before any node exists.

        One process holds every name for its life; with one process a node
        this one holds ``cartpole_run`` and each child claims its own name.
        """
        names = [MONITOR_NAME] + self.spec.nodes
        probe = probe_node(self.context)
        try:
            return claim_unique_names(probe, names,
                                      held=[MONITOR_NAME] if self.spec.processes else names)
        finally:
            probe.destroy_node()

    def _release_claim(self) -> None:
        if self._claim is not None:
            self._claim.release()
            self._claim = None

    def _check_duplicates(self) -> None:
        names = [MONITOR_NAME] + self.spec.nodes
        for name in self.monitor.duplicated_names(names):
            if name not in self._duplicates_reported:
                self._duplicates_reported.add(name)
                text = (f'a second node /{name} appeared on ROS_DOMAIN_ID={domain_id()}: another '
                        f'graph shares this domain, and the two drive each other\'s nodes')
                self.warnings.append(text)
                self.report(f'warning: {text}')

    # -- faults ---------------------------------------------------------------------------------
    def _set_fault(self, reason: str) -> None:
        if self._stopping:
            self.warnings.append(f'{reason} (while the graph was stopping)')
        elif self.fault is None:
            self.fault = reason
            self.stop_stamp_ns = self.monitor.last_stamp_ns
            self.report(f'fault: {reason}; stopping the graph (zero force first)')

    def _check_processes(self) -> None:
        for name, proc in self.processes.items():
            if name in self._exits:
                continue
            code = proc.poll()
            if code is None:
                continue
            self._exits[name] = code
            if name not in self._asked_to_stop:
                self._set_fault(f'{name} {describe_exit(code)}')

    def _callback_failed(self, error: Exception) -> None:
        """A callback of an in-process node raised: that node's fault, the traceback on stderr."""
        name = 'a callback'
        tb = error.__traceback__
        while tb is not None:
            owner = tb.tb_frame.f_locals.get('self')
            for node_name, node in self.nodes.items():
                if owner is node:
                    name = node_name
            tb = tb.tb_next
        print(''.join(traceback.format_exception(error)), file=sys.stderr, end='', flush=True)
        self._set_fault(f'{name} raised {type(error).__name__}: {error}')

    def _alive(self, name: str) -> bool:
        if name in self.nodes:
            return True
        proc = self.processes.get(name)
        return proc is not None and proc.poll() is None

    # -- start -----------------------------------------------------------------------------------
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
            raise GraphError(self.fault or f'no state arrived within {STARTUP_TIMEOUT:g} s; '
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
            if self.spin_until(moved, LOOP_START_TIMEOUT) or self.should_stop() or self.fault:
                return
            self.warnings.append('lockstep loop did not answer the first sample; '
                                 'reset the simulator (the run starts one period later)')
            client = self._client(Trigger, 'sim', 'reset')
            if self.spin_until(client.service_is_ready, 5.0):
                future = client.call_async(Trigger.Request())
                self.spin_until(future.done, 5.0)
            first = self.monitor.last_stamp_ns
        if not self.spin_until(moved, LOOP_START_TIMEOUT) and not self.should_stop():
            raise GraphError(self.fault or 'the lockstep loop does not start; '
                                           + self._process_report())

    def _start_in_process(self) -> None:
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
        for name in self.spec.nodes:
            if name == self.spec.plant:
                self._wait_for_subscribers()
            self.processes[name] = start_node_process(command_line(self.spec, name))

    def _wait_for_subscribers(self) -> None:
        """Processes: wait until EKF, controller manager (and recorder) are in the graph."""
        rec = 1 if self.spec.record else 0
        m = self.monitor

        def ready() -> bool:
            # The monitor itself publishes on FORCE too (its zero force in a fault).
            return (m.count_subscribers('/joint_states') >= 1 + rec
                    and m.count_subscribers(STATE) >= 1 + rec
                    and m.count_publishers(FORCE) >= 2)
        if not self.spin_until(ready, STARTUP_TIMEOUT) and not self.should_stop():
            raise GraphError(self.fault or f'the nodes did not come up within '
                                           f'{STARTUP_TIMEOUT:g} s; {self._process_report()}')

    def _process_report(self) -> str:
        if not self.processes:
            return 'in-process nodes: ' + ', '.join(self.nodes)
        return ', '.join(f'{n}: {"running" if p.poll() is None else describe_exit(p.returncode)}'
                         for n, p in self.processes.items())

    # -- running -------------------------------------------------------------------------
    def _spin_once(self, timeout: float) -> None:
        try:
            self.executor.spin_once(timeout_sec=timeout)
        except ExternalShutdownException:
            raise
        except Exception as error:  # a callback of an in-process node raised
            self._callback_failed(error)
        now = time.monotonic()
        if self.processes and now >= self._next_check:
            self._next_check = now + CHECK_PERIOD
            self._check_processes()
        if now >= self._next_duplicate_check and not self.spec.allow_duplicates:
            self._next_duplicate_check = now + DUPLICATE_CHECK_PERIOD
            self._check_duplicates()

    def spin_until(self, predicate: Callable[[], bool], timeout: float | None) -> bool:
        """Spin until ``predicate()``; False on timeout, and (until the stop) on Ctrl-C or a fault."""
        deadline = None if timeout is None else time.monotonic() + timeout
        while not predicate():
            if not self._stopping and (self.should_stop() or self.fault is not None):
                return False
            if deadline is not None and time.monotonic() >= deadline:
                return False
            self._spin_once(0.05)
        return True

    def elapsed(self) -> float:
        """Run time so far [s]: simulated in lockstep, wall otherwise."""
        if self.spec.lockstep:
            stamp = self.monitor.last_stamp_ns
            return 0.0 if stamp is None else stamp * 1e-9
        return 0.0 if self.wall_start is None else time.monotonic() - self.wall_start

    def run_for(self, duration: float | None) -> None:
        """Spin until ``duration`` has elapsed (None: until ``should_stop``) or a fault."""
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
        """Zero force first, then stop the nodes in order (see the module docstring).

        Returns warnings (empty when everything went as planned). Waits here
        are not cut short by Ctrl-C or the fault: the stop always completes.
        """
        if self.stopped:
            return []
        self._stopping = True
        if self.stop_stamp_ns is None:
            self.stop_stamp_ns = self.monitor.last_stamp_ns
        warnings = self._command_zero_force()
        self.stopped = True
        if self.processes:
            for name in STOP_ORDER:
                if name in self.processes:
                    warnings += self._stop_process(name)
        else:
            self._destroy_in_order([n for n in IN_PROCESS_STOP_ORDER if n in self.nodes])
        return warnings

    def _command_zero_force(self) -> list[str]:
        """Zero force through whoever is alive; returns warnings.

        After a fault the monitor commands zero at once too (the manager may be
        dead, or alive without states to run its next cycle on). On the
        simulator the stop waits until a sample shows the zero force applied.
        """
        warnings: list[str] = []
        m = self.monitor
        zeros_before, applied_before = m.zero_forces, m.zero_force_samples
        plant_alive = self._alive(self.spec.plant)
        if plant_alive and (self.fault is not None or not self._alive('controller_manager')):
            m.publish_zero_force(sample_stamp=self.spec.lockstep)
        if self._alive('controller_manager'):
            for ok, reason in self.set_parameters('controller_manager', {'enabled': False}, 6.0):
                if not ok:
                    warnings.append(f'controller_manager enabled:=false refused: {reason}')
        if self.spec.plant == 'hw_bridge' and plant_alive:
            for ok, reason in self.set_parameters('hw_bridge', {'armed': False}, 6.0):
                if not ok:
                    warnings.append(f'hw_bridge armed:=false refused: {reason}')
        if not plant_alive:
            return warnings
        if not self._wait(lambda: m.zero_forces > zeros_before, ZERO_FORCE_TIMEOUT):
            warnings.append('no zero force command seen after disabling the controller '
                            '(the plant watchdog zeroes the force)')
        elif self.spec.plant == 'sim':
            self._wait(lambda: m.zero_force_samples > applied_before, ZERO_FORCE_TIMEOUT)
        return warnings

    def _destroy_in_order(self, order: list[str]) -> None:
        forces_seen = self.monitor.forces
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

    def _wait(self, predicate: Callable[[], bool], timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while not predicate():
            if time.monotonic() >= deadline:
                return False
            self._spin_once(0.02)
        return True

    def _stop_process(self, name: str) -> list[str]:
        self._asked_to_stop.add(name)
        if self.processes[name].poll() is not None:
            return []  # it had died: that is the fault, reported already
        # Keep the monitor spinning while a node shuts down (it may still publish).
        return stop_node_process(self.processes[name], name, self._wait,
                                 RECORDER_EXIT_TIMEOUT if name == 'recorder' else EXIT_TIMEOUT)

    def close(self) -> list[str]:
        """Stop (if not yet), destroy the monitor, make sure no child is left; all warnings."""
        if self.closed:
            return []
        try:
            self.warnings += self.stop()
        finally:
            self.closed = True
            for node in list(self.nodes.values()):
                node.destroy_node()
            self.nodes.clear()
            for proc in self.processes.values():
                if proc.poll() is None:  # only when the stop itself failed
                    proc.kill()
                    proc.wait()
            self.monitor.destroy_node()
            self.executor.shutdown(timeout_sec=1.0)
            if self.realtime is not None:
                self.realtime.leave()
            self._release_claim()
        return list(self.warnings)

    def __enter__(self) -> 'Graph':
        return self

    def __exit__(self, *exc) -> None:
        self.close()


__all__ = ['Graph', 'GraphError', 'GraphSpec', 'DuplicateNodeError', 'command_line',
           'executable', 'ros_value_text', 'make_executor', 'NODES']
