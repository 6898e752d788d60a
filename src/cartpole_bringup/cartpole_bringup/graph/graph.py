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

**One graph per namespace.** Every node of the graph, the monitor included,
runs in the spec's namespace (``cartpole run --namespace rig2``:
:mod:`cartpole_core.namespaces`). Before any node exists, the graph's
roles are claimed in that namespace of the domain
(:mod:`cartpole_core.domain_guard`); a role taken already refuses the start
(:class:`~cartpole_core.domain_guard.DuplicateNodeError`) unless
``allow_duplicates``. A duplicate that shows up later is reported
(:mod:`cartpole_bringup.graph.faults`).

**A fault stops the run.** A node process that dies (or, in one process, a
callback that raises) is noticed within one spin of the monitor: the run
records the fault (``controller_manager died (SIGKILL)``) and stops
(:mod:`cartpole_bringup.graph.faults`).

**Stopping** (:meth:`Graph.stop`), orderly or after a fault: zero force
first, through whoever is still alive: after a fault the monitor's own zero
force command at once, then the controller manager's ``enabled:=false``
(and the zero force it then publishes); on the rig also the bridge's
lifecycle ``deactivate`` (``U,0``, ``E,0``), and its ``cleanup`` (port closed) before it
stops (:mod:`cartpole_bringup.graph.bridge_lifecycle`, which also configures and,
with ``--hw-arm``, activates it at the start); on the simulator until a sample shows
the zero force applied. Then the
nodes stop one by one, the controller manager first (so that nothing it
watches goes stale while it still runs: no ``stale state`` fault for an
orderly stop), the plant, the EKF, and the recorder last, so that the bag
holds the zero force and is closed (in one process the plant goes first:
nothing spins between two nodes' ends there). A process gets SIGINT and time to shut
down properly (:data:`~cartpole_bringup.graph.stop.EXIT_TIMEOUT`, the recorder
:data:`~cartpole_bringup.graph.stop.RECORDER_EXIT_TIMEOUT`) before SIGTERM and, last,
SIGKILL (:mod:`cartpole_bringup.graph.stop`). The start is :mod:`cartpole_bringup.graph.startup`,
the nodes' parameters :mod:`cartpole_bringup.graph.parameters`.

The parameters file (``--params``) is given to every node as
``--params-file`` (node sections and ``/**`` apply as in ROS); the explicit
options (scenario, controllers, ``lockstep``, ``use_sim_time``) override it.
"""
from __future__ import annotations

import subprocess
import sys
import time
from typing import Callable

from rclpy.executors import ExternalShutdownException
from rclpy.node import Node

from cartpole_core import realtime
from cartpole_core.child_process import reap
from cartpole_core.domain_guard import DuplicateNodeError

from cartpole_analysis.analysis.analyze import STATE, TRUE_STATE
from .bridge_lifecycle import BridgeLifecycle
from .faults import CHECK_PERIOD, DUPLICATE_CHECK_PERIOD, FaultWatch
from .parameters import NodeParameters
from .processes import NODES, executable, ros_value_text
from .run_monitor import RunMonitor
from .spec import GraphSpec, make_executor
from .startup import GraphError, GraphStartup, command_line
from .stop import StopSequence


def _report(text: str) -> None:
    print(f'cartpole run: {text}', file=sys.stderr, flush=True)


class Graph(GraphStartup, FaultWatch, StopSequence, NodeParameters, BridgeLifecycle):
    """A running node graph; use as a context manager (``close`` stops everything).

    Its concerns are rooms of their own: the start (:class:`GraphStartup`), the
    domain claim and faults (:class:`FaultWatch`), the stop sequence
    (:class:`StopSequence`), the nodes' parameters (:class:`NodeParameters`) and the
    rig bridge's lifecycle (:class:`BridgeLifecycle`);
    this class holds the state they share, the spin and the close.

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
        self.report = report
        self.nodes: dict[str, Node] = {}
        self._clients: dict = {}
        self._bridge = None
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
                                      collect=spec.record is None,
                                      progress=spec.lockstep and spec.record is None,
                                      context=context, **spec.node_options())
        except BaseException:
            self._release_claim()
            raise
        self.executor.add_node(self.monitor)

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
