"""The node graph of ``cartpole run``: one process (one executor) or one process a node.

The graph is ``sim`` (or ``hw_bridge``) + ``ekf`` + ``controller_manager``
(+ ``recorder``), wired by the topics of docs/architecture.md, plus the run
monitor ``cartpole_run`` (:mod:`.run_monitor`). In one process the node classes
share one executor (as ``examples_rclpy_executors/composed.py``); with
``processes=True`` each node is its installed executable (:mod:`.processes`).

:class:`Graph` holds the nodes and its parts, each with its own state: the start
(:mod:`.startup`), the domain claim and the faults (:mod:`.faults`), the
parameters (:mod:`.parameters`), the rig bridge's lifecycle
(:mod:`.bridge_lifecycle`) and the stop, zero force first (:mod:`.stop`).
docs/running.md, "`cartpole run`", says what a user sees of each.
"""
from __future__ import annotations

import subprocess
import sys
import time
from typing import Any, Callable

from rclpy.executors import ExternalShutdownException
from rclpy.node import Node

from cartpole_core.child_process import reap
from cartpole_core.domain_guard import DuplicateNodeError

from cartpole_analysis.analysis.analyze import STATE, TRUE_STATE
from .bridge_lifecycle import BridgeLifecycle
from .faults import FaultWatch
from .parameters import NodeParameters
from .processes import NODES, executable, ros_value_text
from .run_monitor import RunMonitor
from .spec import GraphSpec, make_executor
from .startup import GraphError, GraphStartup, command_line
from .stop import StopSequence


def _report(text: str) -> None:
    print(f'cartpole run: {text}', file=sys.stderr, flush=True)


class Graph:
    """A running node graph; use as a context manager (``close`` stops everything).

    It holds its inventory (``nodes`` in this process, ``processes`` of the
    nodes in their own, the ``executor`` and the run ``monitor``) and its parts,
    each with its own state: ``faults`` (:class:`FaultWatch`: the domain claim,
    the run's fault), ``parameters`` (:class:`NodeParameters`), ``bridge``
    (:class:`BridgeLifecycle`), ``startup`` (:class:`GraphStartup`) and
    ``stopper`` (:class:`StopSequence`). Itself it does the spin and the close.

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

    Raises DuplicateNodeError when a role of the graph is taken in its namespace.
    """

    def __init__(self, spec: GraphSpec, context, should_stop: Callable[[], bool] = lambda: False,
                 report: Callable[[str], None] = _report):
        self.spec = spec
        self.context = context
        self.should_stop = should_stop
        self.nodes: dict[str, Node] = {}
        self.processes: dict[str, subprocess.Popen] = {}
        self.closed = False
        self.warnings: list[str] = []
        """Things that went other than planned (reported at the end)."""
        self.faults = FaultWatch(spec, context, self.nodes, self.processes, report,
                                 self.warnings.append)
        if not spec.allow_duplicates:
            self.faults.claim_names()
        try:
            self.executor = make_executor(spec.executor, context)
            self.monitor = RunMonitor(state_topic=TRUE_STATE if spec.plant == 'sim' else STATE,
                                      collect=spec.record is None,
                                      progress=spec.lockstep and spec.record is None,
                                      context=context, **spec.node_options())
        except BaseException:
            self.faults.release_claim()
            raise
        self.executor.add_node(self.monitor)
        self.faults.monitor = self.monitor
        self.parameters = NodeParameters(self.nodes, self.monitor, self.spin_until)
        self.bridge = BridgeLifecycle(spec, self.monitor, self.spin_until, self._alive,
                                      self.faults.set_fault, self._ending)
        self.startup = GraphStartup(spec, context, self.executor, self.monitor, self.nodes,
                                    self.processes, self.parameters, self.bridge, self.faults,
                                    self.spin_until, should_stop, self.warnings.append)
        self.stopper = StopSequence(spec, self.executor, self.monitor, self.nodes,
                                    self.processes, self.faults, self.parameters, self.bridge,
                                    self._alive, self._spin_once)

    @property
    def fault(self) -> str | None:
        """Why the run stopped early: a node that died, a callback that raised."""
        return self.faults.fault

    @property
    def stop_stamp_ns(self) -> int | None:
        """Stamp of the latest state when the stop (or the fault) began: where the summary ends."""
        if self.stopper.stamp_ns is not None:
            return self.stopper.stamp_ns
        return self.faults.fault_stamp_ns

    @property
    def stopped(self) -> bool:
        return self.stopper.stopped

    def start(self) -> None:
        """Start every node (plant last) and wait until the loop is wired (:class:`GraphStartup`)."""
        self.startup.start()

    def stop(self) -> list[str]:
        """Zero force first, then the nodes in order (:class:`StopSequence`); warnings."""
        return self.stopper.stop()

    def set_parameters(self, node: str, values: dict[str, Any], timeout: float = 5.0,
                       attempts: int = 2) -> list[tuple[bool, str]]:
        """Set parameters of a graph node (in process, or through its service)."""
        return self.parameters.set_parameters(node, values, timeout, attempts)

    def get_parameter(self, node: str, name: str, timeout: float = 5.0) -> Any:
        """A parameter value of a graph node, None if it cannot be read."""
        return self.parameters.get_parameter(node, name, timeout)

    # -- running -------------------------------------------------------------------------
    def _ending(self) -> bool:
        return self.should_stop() or self.faults.fault is not None

    def _alive(self, name: str) -> bool:
        if name in self.nodes:
            return True
        proc = self.processes.get(name)
        return proc is not None and proc.poll() is None

    def _spin_once(self, timeout: float) -> None:
        try:
            self.executor.spin_once(timeout_sec=timeout)
        except ExternalShutdownException:
            raise
        except Exception as error:  # a callback of an in-process node raised
            self.faults.callback_failed(error)
        self.faults.after_spin()

    def spin_until(self, predicate: Callable[[], bool], timeout: float | None) -> bool:
        """Spin until ``predicate()``; False on timeout, and (until the stop) on Ctrl-C or a fault."""
        deadline = None if timeout is None else time.monotonic() + timeout
        while not predicate():
            if not self.faults.stopping and self._ending():
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
        start = self.startup.wall_start
        return 0.0 if start is None else time.monotonic() - start

    def run_for(self, duration: float | None) -> None:
        """Spin until ``duration`` has elapsed (None: until ``should_stop``) or a fault."""
        if duration is None:
            self.spin_until(lambda: False, None)
        else:
            self.spin_until(lambda: self.elapsed() >= duration, None)

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
                reap(proc, drain=False)  # only when the stop itself failed
            self.monitor.destroy_node()
            self.executor.shutdown(timeout_sec=1.0)
            if self.startup.realtime is not None:
                self.startup.realtime.leave()
            self.faults.release_claim()
        return list(self.warnings)

    def __enter__(self) -> 'Graph':
        return self

    def __exit__(self, *exc) -> None:
        self.close()


__all__ = ['Graph', 'GraphError', 'GraphSpec', 'DuplicateNodeError', 'command_line',
           'executable', 'ros_value_text', 'make_executor', 'NODES']
