"""Stopping a graph (:meth:`StopSequence.stop`): zero force first, then the nodes in order.

Zero force through whoever is still alive: after a fault the run monitor's
own zero force command at once, then the controller manager's
``enabled:=false`` (and the zero force it then publishes); on the rig also the
bridge's lifecycle ``deactivate`` (``U,0``, ``E,0``); on the simulator until a
sample shows the zero force applied. Then the nodes stop one by one (the
bridge after its ``cleanup``: streaming off, port closed)
(:data:`STOP_ORDER`, :data:`IN_PROCESS_STOP_ORDER`), the recorder last, so
that the bag holds the zero force and is closed. A process gets SIGINT and
time to shut down (:data:`EXIT_TIMEOUT`, the recorder
:data:`RECORDER_EXIT_TIMEOUT`) before SIGTERM and, last, SIGKILL
(:func:`cartpole_bringup.graph.processes.stop_node_process`).
"""
from __future__ import annotations

import time
from typing import Callable

from cartpole_analysis.analysis.analyze import FORCE
from .processes import stop_node_process

ZERO_FORCE_TIMEOUT = 2.0
"""Wall seconds to wait for the zero force command after disabling the controllers."""
ZERO_FORCE_APPLIED_TIMEOUT = 2.0
"""Wall seconds to wait for a simulator sample with the zero force applied, in real time."""
LOCKSTEP_ZERO_FORCE_APPLIED_TIMEOUT = 10.0
"""The same in lockstep, where the simulator steps only as fast as the recorder takes
its samples (``recorder_window``): on a loaded machine that can be seconds behind."""
EXIT_TIMEOUT = 5.0
"""Wall seconds a child process gets after SIGINT (then SIGTERM, and SIGKILL 2 s later)."""
RECORDER_EXIT_TIMEOUT = 15.0
"""The recorder's SIGINT grace: it writes what it had received and closes the bag."""
STOP_ORDER = ('controller_manager', 'sim', 'hw_bridge', 'ekf', 'recorder')
"""Processes: the manager first, so that nothing it watches goes stale while it runs."""
IN_PROCESS_STOP_ORDER = ('sim', 'hw_bridge', 'ekf', 'controller_manager', 'recorder')
"""One process: the plant first, before the manager's last zero force reaches it (the
executor would still run that callback of a destroyed node); nothing spins in between,
so nothing goes stale."""

class StopSequence:
    """The stop of a :class:`cartpole_bringup.graph.graph.Graph`: once, whatever went before.

    Works on the graph's inventory (``nodes``, ``processes``, ``executor``,
    ``monitor``) through its parts (``faults``, ``parameters``, ``bridge``);
    ``alive(name)`` tells whether a node still runs, ``spin_once(timeout)`` spins
    the graph. Holds whether it ran and the stamp where it began.
    """

    def __init__(self, spec, executor, monitor, nodes: dict, processes: dict, faults,
                 parameters, bridge, alive: Callable[[str], bool],
                 spin_once: Callable[[float], None]) -> None:
        self.spec = spec
        self.executor = executor
        self.monitor = monitor
        self.nodes = nodes
        self.processes = processes
        self.faults = faults
        self.parameters = parameters
        self.bridge = bridge
        self.alive = alive
        self.spin_once = spin_once
        self.stopped = False
        self.stamp_ns: int | None = None
        """Stamp of the latest state when the stop began (the fault's, after a fault)."""

    def stop(self) -> list[str]:
        """Zero force first, then stop the nodes in order (see the module docstring).

        Returns warnings (empty when everything went as planned). Waits here
        are not cut short by Ctrl-C or the fault: the stop always completes.
        """
        if self.stopped:
            return []
        self.faults.stopping = True
        if self.stamp_ns is None:
            fault_stamp = self.faults.fault_stamp_ns
            self.stamp_ns = fault_stamp if fault_stamp is not None else self.monitor.last_stamp_ns
        warnings = self._command_zero_force()
        self.stopped = True
        if self.processes:
            for name in STOP_ORDER:
                if name in self.processes:
                    if name == 'hw_bridge':
                        warnings += self.bridge.to('cleanup', 'inactive')
                    warnings += self._stop_process(name)
        else:
            warnings += self.bridge.to('cleanup', 'inactive')
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
        plant_alive = self.alive(self.spec.plant)
        if plant_alive and (self.faults.fault is not None or not self.alive('controller_manager')):
            m.publish_zero_force(sample_stamp=self.spec.lockstep)
        if self.alive('controller_manager'):
            for ok, reason in self.parameters.set_parameters('controller_manager',
                                                             {'enabled': False}, 6.0):
                if not ok:
                    warnings.append(f'controller_manager enabled:=false refused: {reason}')
        if not plant_alive:
            return warnings
        warnings += self.bridge.to('deactivate', 'active')
        if not self.wait(lambda: m.zero_forces > zeros_before, ZERO_FORCE_TIMEOUT):
            warnings.append('no zero force command seen after disabling the controller '
                            '(the plant watchdog zeroes the force)')
        elif self.spec.plant == 'sim':
            timeout = LOCKSTEP_ZERO_FORCE_APPLIED_TIMEOUT if self.spec.lockstep \
                else ZERO_FORCE_APPLIED_TIMEOUT
            if not self.wait(lambda: m.zero_force_samples > applied_before, timeout):
                warnings.append(f'no simulator sample with the zero force applied within '
                                f'{timeout:g} s; stopping the simulator without one')
        return warnings

    def _destroy_in_order(self, order: list[str]) -> None:
        """Destroy the in-process nodes in ``order`` with nothing spinning in between.

        The recorder first takes every command the monitor took (the executor
        spins for it while every node is alive); then the nodes go one after
        the other without spinning: a spin after a node's destruction would
        still dispatch its queued callbacks (the events executor does), whose
        publishers are gone.
        """
        recorder = self.nodes.get('recorder')
        if recorder is not None:
            forces_seen = self.monitor.forces
            self.wait(lambda: recorder.counts.get(FORCE, 0) >= forces_seen, 1.0)
        for name in order:
            node = self.nodes.pop(name, None)
            if node is None:
                continue
            self.executor.remove_node(node)
            node.destroy_node()

    def wait(self, predicate: Callable[[], bool], timeout: float) -> bool:
        """Spin until ``predicate()`` or ``timeout`` [s]; not cut short by Ctrl-C or a fault."""
        deadline = time.monotonic() + timeout
        while not predicate():
            if time.monotonic() >= deadline:
                return False
            self.spin_once(0.02)
        return True

    def _stop_process(self, name: str) -> list[str]:
        self.faults.expect_exit(name)
        if self.processes[name].poll() is not None:
            return []  # it had died: that is the fault, reported already
        # Keep the monitor spinning while a node shuts down (it may still publish).
        return stop_node_process(self.processes[name], name, self.wait,
                                 RECORDER_EXIT_TIMEOUT if name == 'recorder' else EXIT_TIMEOUT)
