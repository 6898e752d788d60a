"""The rig's bridge in a graph: its lifecycle driven through its services, as ``ros2 lifecycle set``.

``hw_bridge`` is a managed node (:mod:`cartpole_hw.hw_node`): it starts
unconfigured, whether in this process or its own. The graph

- **configures** it once the other nodes are up (port open, handshake,
  samples streaming disarmed: the EKF and the controller manager run on
  them) and fails to start with the reason if it cannot;
- with ``hw_arm`` (``cartpole run --hw-arm``), once the first state arrived,
  waits until the controller manager answers (twice :data:`WARM_COMMANDS` force
  commands, the bridge's warm-loop rule) and **activates** it (arms), asking
  again for up to :data:`ACTIVATE_TIMEOUT` s while the bridge refuses (a loop
  still working off its start-up backlog);
- at the stop **deactivates** it (``U,0``, ``E,0``) with the zero force, and
  **cleans it up** (port closed) before the node stops;
- watches ``hw_bridge/transition_event`` (relative: the graph's namespace, as the
  lifecycle services): the bridge going to
  ``errorprocessing`` (a fault while armed: it zeroed, disarmed and closed
  the port) is the run's fault (``hw_bridge: <its last_error>; ...``, the
  reason from ``/cartpole/hw/health`` when the monitor has it), and stops the run.
"""
from __future__ import annotations

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
    """The bridge's transitions for :class:`cartpole_bringup.graph.graph.Graph` (a mixin).

    Uses the graph's ``spec``, ``monitor``, ``fault``, ``should_stop``,
    ``spin_until``, ``_alive``, ``_set_fault`` and ``_bridge`` (None at first).
    """

    def _bridge_client(self) -> LifecycleClient:
        """The lifecycle client of the bridge, created early (discovery of its responses)."""
        if self._bridge is None:
            self._bridge = LifecycleClient(self.monitor, BRIDGE, self.spin_until)
            self.monitor.create_subscription(TransitionEvent, f'{BRIDGE}/transition_event',
                                             self._on_bridge_transition, 10)
        return self._bridge

    def _on_bridge_transition(self, event: TransitionEvent) -> None:
        if event.goal_state.label == 'errorprocessing':
            reported = self.monitor.builder.first_fault() or ''   # from /cartpole/hw/health
            why = reported if reported.startswith(f'{BRIDGE}:') else \
                f'{BRIDGE}: fault while armed (its log says why)'
            self._set_fault(f'{why}; zero force, disarmed, port closed (on_error)')

    def _configure_bridge(self) -> str:
        """Configure the bridge: '' when done, else why not."""
        ok, reason = self._bridge_client().change('configure', CONFIGURE_TIMEOUT)
        return '' if ok else f'{BRIDGE} configure: {reason}'

    def _activate_bridge(self) -> str:
        """Arm the bridge once the controller answers: '' when done, else why not."""
        m = self.monitor
        first = m.forces
        # twice the bridge's count: the monitor sees a command before the bridge does
        if not self.spin_until(lambda: m.forces >= first + 2 * WARM_COMMANDS, ACTIVATE_TIMEOUT):
            return f'{BRIDGE} activate: the controller manager does not answer the samples'
        stopping = lambda: self.should_stop() or self.fault is not None  # noqa: E731
        ok, reason = self._bridge_client().change_retrying(
            'activate', int(ACTIVATE_TIMEOUT / ACTIVATE_RETRY), ACTIVATE_RETRY,
            TRANSITION_TIMEOUT, give_up=stopping)
        if ok:
            return ''
        return f'{BRIDGE} activate: {reason}' if stopping() else \
            f'{BRIDGE} activate: {reason} for {ACTIVATE_TIMEOUT:g} s'

    def _bridge_to(self, transition: str, state: str) -> list[str]:
        """At the stop: ``transition`` if the bridge is in ``state``; warnings."""
        if self.spec.plant != BRIDGE or not self._alive(BRIDGE):
            return []
        client = self._bridge_client()
        if client.state(TRANSITION_TIMEOUT) != state:
            return []
        ok, reason = client.change(transition, TRANSITION_TIMEOUT)
        return [] if ok else [f'{BRIDGE} {transition}: {reason}']
