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
import traceback

from cartpole_core.domain_guard import (NodeClaim, claim_graph, domain_id, probe_node,
                                       role_publishers)

from .processes import describe_exit
from .run_monitor import NODE_NAME as MONITOR_NAME

CHECK_PERIOD = 0.01
"""Wall seconds between two looks at the child processes (a death is noticed this fast)."""
DUPLICATE_CHECK_PERIOD = 1.0


class FaultWatch:
    """The domain claim and the fault bookkeeping of :class:`cartpole_bringup.graph.graph.Graph` (a mixin).

    Uses the graph's ``spec``, ``context``, ``monitor``, ``nodes``,
    ``processes``, ``report``, ``warnings``, ``fault``, ``_claim``,
    ``_stopping``, ``_exits`` and ``_asked_to_stop``.
    """

    # -- one graph per namespace -----------------------------------------------------------
    def _claim_names(self) -> NodeClaim:
        """Claim the graph's roles in its namespace (cartpole_core.domain_guard) before any node
        exists.

        One process holds every role for its life; with one process a node
        this one holds ``cartpole_run`` and each child claims its own role.
        """
        roles = [MONITOR_NAME] + self.spec.nodes
        probe = probe_node(self.context, self.spec.node_options().get('cli_args'))
        try:
            return claim_graph(probe, roles, namespace=self.spec.namespace,
                               held=[MONITOR_NAME] if self.spec.processes else roles)
        finally:
            probe.destroy_node()

    def _release_claim(self) -> None:
        if self._claim is not None:
            self._claim.release()
            self._claim = None

    def _check_duplicates(self) -> None:
        """A second publisher of a role's own topic in the namespace: another graph there."""
        found = role_publishers(self.monitor, self.spec.nodes, self.spec.namespace)
        for topic, publishers in found.items():
            if len(publishers) > 1 and topic not in self._duplicates_reported:
                self._duplicates_reported.add(topic)
                text = (f'{topic} has a second publisher ({", ".join(publishers)}) in namespace '
                        f'{self.spec.namespace} on ROS_DOMAIN_ID={domain_id()}: another graph '
                        f'shares this namespace, and the two drive each other\'s nodes')
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
