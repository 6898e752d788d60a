"""Drive a managed node's transitions the way ``ros2 lifecycle set`` does.

``ros2 lifecycle set /hw_bridge activate`` asks the node for its available
transitions (``~/get_available_transitions``), picks the one labelled
``activate`` and calls ``~/change_state`` with it (lifecycle_msgs/srv/ChangeState);
``ros2 lifecycle get`` calls ``~/get_state``. :class:`LifecycleClient` does the
same from a node of the caller's (``cartpole run --hw``, ``cartpole identify
--arm``, the tests), waiting by spinning the caller's executor.
"""
from __future__ import annotations

from typing import Callable

from lifecycle_msgs.srv import ChangeState, GetAvailableTransitions, GetState
from rclpy.node import Node

DONE = {'configure': 'inactive', 'activate': 'active', 'deactivate': 'inactive',
        'cleanup': 'unconfigured', 'shutdown': 'finalized'}
"""The primary state a successful transition ends in (the transitions' descriptions name the
transition state in between, e.g. ``configuring``)."""

SpinUntil = Callable[[Callable[[], bool], float], bool]
"""``spin_until(predicate, timeout) -> bool``: spin the caller's executor until it holds."""


class LifecycleClient:
    """The lifecycle services of node ``target``, called from ``node``: ``/hw_bridge``, or
    relative, ``hw_bridge``: the one in ``node``'s namespace."""

    def __init__(self, node: Node, target: str, spin_until: SpinUntil) -> None:
        self.target = target
        self.spin_until = spin_until
        self._get_state = node.create_client(GetState, f'{self.target}/get_state')
        self._transitions = node.create_client(GetAvailableTransitions,
                                               f'{self.target}/get_available_transitions')
        self._change = node.create_client(ChangeState, f'{self.target}/change_state')

    def _call(self, client, request, timeout: float):
        """The response, or None (service absent, no answer within ``timeout`` s)."""
        if not self.spin_until(client.service_is_ready, timeout):
            return None
        future = client.call_async(request)
        if not self.spin_until(future.done, timeout):
            client.remove_pending_request(future)
            return None
        return future.result()

    def state(self, timeout: float = 5.0) -> str | None:
        """The current state's label (``unconfigured``, ``inactive``, ``active``,
        ``finalized``, ...), None if the node does not answer."""
        for _ in range(2):   # a response can be lost while discovery completes
            response = self._call(self._get_state, GetState.Request(), timeout / 2)
            if response is not None:
                return response.current_state.label
        return None

    def change(self, label: str, timeout: float = 10.0) -> tuple[bool, str]:
        """Trigger the transition ``label`` (``configure``, ``activate``, ...): (done, why not).

        A response lost on the way (the client's reader not yet matched by the
        node's writer, early after the start) is made good by asking the state: the
        transition's goal state means done, its start state a second request."""
        response = None
        for _ in range(2):
            response = self._call(self._transitions, GetAvailableTransitions.Request(),
                                  timeout / 2)
            if response is not None:
                break
        if response is None:
            return False, f'{self.target} does not answer (is it running?)'
        available = [t for t in response.available_transitions]
        match = next((t for t in available if t.transition.label == label), None)
        if match is None:
            return False, (f'{self.target}: no transition {label!r} from its current state '
                           f'(available: {", ".join(t.transition.label for t in available) or "none"})')
        request = ChangeState.Request(transition=match.transition)
        for _ in range(2):
            response = self._call(self._change, request, timeout)
            if response is not None:
                if not response.success:
                    return False, f'{self.target} refused {label} (its log says why)'
                return True, ''
            state = self.state(timeout)
            if state == DONE.get(label, match.goal_state.label):
                return True, ''
            if state != match.start_state.label:
                return False, f'{self.target} did not answer {label}; now {state}'
        return False, f'{self.target}/change_state gave no answer within {timeout:g} s'

    def change_retrying(self, label: str, attempts: int, retry: float, timeout: float,
                        give_up: Callable[[], bool] = lambda: False) -> tuple[bool, str]:
        """:meth:`change` ``label``, asked again ``retry`` s after each refusal, at most
        ``attempts`` times (a bridge refusing to activate while the loop is not warm yet);
        stops asking early once ``give_up()`` holds. (done, the last reason)."""
        reason = ''
        for _ in range(attempts):
            ok, reason = self.change(label, timeout)
            if ok or give_up():
                return ok, reason
            self.spin_until(lambda: False, retry)
        return False, reason

    def destroy(self, node: Node) -> None:
        for client in (self._get_state, self._transitions, self._change):
            node.destroy_client(client)
