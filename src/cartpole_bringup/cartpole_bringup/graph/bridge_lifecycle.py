"""The rig's bridge in a graph: its lifecycle driven through its services, as ``ros2 lifecycle set``.

``hw_bridge`` is a managed node (:mod:`cartpole_hw.hw_node`): it starts unconfigured,
whether in this process or its own. The graph **configures** it once the other nodes are
up (port open, samples streaming disarmed) and fails to start with the reason if it
cannot; with ``hw_arm`` (``cartpole run --hw-arm``) it **activates** it (arms) once the
controller manager answers (twice :data:`WARM_COMMANDS` force commands, the bridge's
warm-loop rule), asking again for up to :data:`ACTIVATE_TIMEOUT` s while the bridge
refuses; at the stop it **deactivates** it with the zero force and **cleans it up** (port
closed). It watches ``hw_bridge/transition_event`` (relative, like the services): the
bridge going to ``errorprocessing`` (a fault while armed) is the run's fault, with the
bridge's ``last_error``, and stops the run.
The bridge's states and transitions: (docs/rig.md, "The lifecycle").
"""
from __future__ import annotations

from typing import Callable

from lifecycle_msgs.msg import TransitionEvent

from cartpole_hw.lifecycle_client import LifecycleClient

BRIDGE = 'hw_bridge'
CONFIGURE_TIMEOUT = 15.0
"""Wall seconds for the bridge to appear and configure (its handshake takes up to 3 s)."""
WARM_COMMANDS = 20
"""Force commands the run waits for before activating: the bridge's warm-loop rule
(:class:`cartpole_hw.bridge.BridgeConfig` ``warm_commands``)."""
ACTIVATE_TIMEOUT = 10.0
"""Wall seconds the run keeps asking the bridge to activate while it refuses."""
ACTIVATE_RETRY = 0.2
"""Wall seconds between two activation requests."""
TRANSITION_TIMEOUT = 6.0
"""Wall seconds for a transition at the stop."""


class BridgeLifecycle:
    """The bridge's transitions for a :class:`cartpole_bringup.graph.graph.Graph`.

    Its lifecycle client and the transition subscription live on the run
    ``monitor``; ``spin_until`` waits while the graph spins, ``alive(name)``
    tells whether a node still runs, ``set_fault(reason)`` reports the bridge's
    fault and ``stopping()`` is true once the run should end (Ctrl-C, a fault).
    """

    def __init__(self, spec, monitor, spin_until: Callable, alive: Callable[[str], bool],
                 set_fault: Callable[[str], None], stopping: Callable[[], bool]) -> None:
        self.spec = spec
        self.monitor = monitor
        self.spin_until = spin_until
        self.alive = alive
        self.set_fault = set_fault
        self.stopping = stopping
        self._client: LifecycleClient | None = None

    def client(self) -> LifecycleClient:
        """The lifecycle client of the bridge, created early (discovery of its responses)."""
        if self._client is None:
            self._client = LifecycleClient(self.monitor, BRIDGE, self.spin_until)
            self.monitor.create_subscription(TransitionEvent, f'{BRIDGE}/transition_event',
                                             self._on_transition, 10)
        return self._client

    def _on_transition(self, event: TransitionEvent) -> None:
        if event.goal_state.label == 'errorprocessing':
            reported = self.monitor.builder.first_fault() or ''   # from /cartpole/hw/health
            why = reported if reported.startswith(f'{BRIDGE}:') else \
                f'{BRIDGE}: fault while armed (its log says why)'
            self.set_fault(f'{why}; zero force, disarmed, port closed (on_error)')

    def configure(self) -> str:
        """Configure the bridge: '' when done, else why not."""
        ok, reason = self.client().change('configure', CONFIGURE_TIMEOUT)
        return '' if ok else f'{BRIDGE} configure: {reason}'

    def activate(self) -> str:
        """Arm the bridge once the controller answers: '' when done, else why not."""
        m = self.monitor
        first = m.forces
        # twice the bridge's count: the monitor sees a command before the bridge does
        if not self.spin_until(lambda: m.forces >= first + 2 * WARM_COMMANDS, ACTIVATE_TIMEOUT):
            return f'{BRIDGE} activate: the controller manager does not answer the samples'
        ok, reason = self.client().change_retrying(
            'activate', int(ACTIVATE_TIMEOUT / ACTIVATE_RETRY), ACTIVATE_RETRY,
            TRANSITION_TIMEOUT, give_up=self.stopping)
        if ok:
            return ''
        return f'{BRIDGE} activate: {reason}' if self.stopping() else \
            f'{BRIDGE} activate: {reason} for {ACTIVATE_TIMEOUT:g} s'

    def to(self, transition: str, state: str) -> list[str]:
        """At the stop: ``transition`` if the bridge is in ``state``; warnings."""
        if self.spec.plant != BRIDGE or not self.alive(BRIDGE):
            return []
        client = self.client()
        if client.state(TRANSITION_TIMEOUT) != state:
            return []
        ok, reason = client.change(transition, TRANSITION_TIMEOUT)
        return [] if ok else [f'{BRIDGE} {transition}: {reason}']
