"""What goes wrong while a graph runs: a second graph in its namespace, a node that dies or raises.

**One graph per namespace.** Before any node exists, the graph's roles are
claimed in its namespace of the domain (:mod:`cartpole_core.domain_guard`); a
role taken already refuses the start
(:class:`~cartpole_core.domain_guard.DuplicateNodeError`) unless
``allow_duplicates``. A duplicate that shows up later is reported.

**A fault stops the run.** A node process that dies (or, in one process, a
callback that raises) is noticed within one spin of the monitor
(:data:`CHECK_PERIOD`): the run records the fault
(``controller_manager died (SIGKILL)``) and stops.
"""
from __future__ import annotations

import sys
import time
import traceback
from typing import Callable

from cartpole_core.domain_guard import (NodeClaim, claim_graph, domain_id, probe_node,
                                       role_publishers)

from .processes import describe_exit
from .run_monitor import NODE_NAME as MONITOR_NAME

CHECK_PERIOD = 0.01
"""Wall seconds between two looks at the child processes (a death is noticed this fast)."""
DUPLICATE_CHECK_PERIOD = 1.0


class FaultWatch:
    """The domain claim and the faults of a :class:`cartpole_bringup.graph.graph.Graph`.

    Holds the run's ``fault`` (the first one; later ones while stopping are
    warnings), the stamp it came at, the exits of the node processes and which of
    them were asked to stop. Reads the graph's ``nodes`` and ``processes`` (its
    inventory) and the monitor.
    """

    def __init__(self, spec, context, nodes: dict, processes: dict,
                 report: Callable[[str], None], warn: Callable[[str], None]) -> None:
        self.spec = spec
        self.context = context
        self.nodes = nodes
        self.processes = processes
        self.report = report
        self.warn = warn
        self.monitor = None
        """The run monitor (set once it exists): its stamp, its view of the graph."""
        self.fault: str | None = None
        """Why the run stopped early: a node that died, a callback that raised."""
        self.fault_stamp_ns: int | None = None
        """Stamp of the latest state when the fault came."""
        self.stopping = False
        """Set when the stop begins: a fault after it is only a warning."""
        self.claim: NodeClaim | None = None
        self._exits: dict[str, int] = {}
        self._asked_to_stop: set[str] = set()
        self._duplicates_reported: set[str] = set()
        self._next_check = 0.0
        self._next_duplicate_check = time.monotonic() + DUPLICATE_CHECK_PERIOD

    # -- one graph per namespace -----------------------------------------------------------
    def claim_names(self) -> None:
        """Claim the graph's roles in its namespace (cartpole_core.domain_guard) before any node
        exists.

        One process holds every role for its life; with one process a node
        this one holds ``cartpole_run`` and each child claims its own role.
        """
        roles = [MONITOR_NAME] + self.spec.nodes
        probe = probe_node(self.context, self.spec.node_options().get('cli_args'))
        try:
            self.claim = claim_graph(probe, roles, namespace=self.spec.namespace,
                                     held=[MONITOR_NAME] if self.spec.processes else roles)
        finally:
            probe.destroy_node()

    def release_claim(self) -> None:
        if self.claim is not None:
            self.claim.release()
            self.claim = None

    def check_duplicates(self) -> None:
        """A second publisher of a role's own topic in the namespace: another graph there."""
        found = role_publishers(self.monitor, self.spec.nodes, self.spec.namespace)
        for topic, publishers in found.items():
            if len(publishers) > 1 and topic not in self._duplicates_reported:
                self._duplicates_reported.add(topic)
                text = (f'{topic} has a second publisher ({", ".join(publishers)}) in namespace '
                        f'{self.spec.namespace} on ROS_DOMAIN_ID={domain_id()}: another graph '
                        f'shares this namespace, and the two drive each other\'s nodes')
                self.warn(text)
                self.report(f'warning: {text}')

    # -- faults ---------------------------------------------------------------------------------
    def after_spin(self) -> None:
        """The periodic looks: node processes every :data:`CHECK_PERIOD`, duplicates every
        :data:`DUPLICATE_CHECK_PERIOD`."""
        now = time.monotonic()
        if self.processes and now >= self._next_check:
            self._next_check = now + CHECK_PERIOD
            self.check_processes()
        if now >= self._next_duplicate_check and not self.spec.allow_duplicates:
            self._next_duplicate_check = now + DUPLICATE_CHECK_PERIOD
            self.check_duplicates()

    def set_fault(self, reason: str) -> None:
        if self.stopping:
            self.warn(f'{reason} (while the graph was stopping)')
        elif self.fault is None:
            self.fault = reason
            self.fault_stamp_ns = self.monitor.last_stamp_ns
            self.report(f'fault: {reason}; stopping the graph (zero force first)')

    def expect_exit(self, name: str) -> None:
        """Node process ``name`` is being stopped: its exit is no fault."""
        self._asked_to_stop.add(name)

    def check_processes(self) -> None:
        for name, proc in self.processes.items():
            if name in self._exits:
                continue
            code = proc.poll()
            if code is None:
                continue
            self._exits[name] = code
            if name not in self._asked_to_stop:
                self.set_fault(f'{name} {describe_exit(code)}')

    def callback_failed(self, error: Exception) -> None:
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
        self.set_fault(f'{name} raised {type(error).__name__}: {error}')
