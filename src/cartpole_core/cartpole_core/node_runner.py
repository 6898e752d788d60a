"""``main()`` of every cartpole node: init, spin, destroy, shutdown, made safe for a clean stop.

:func:`run_node` points Fast DDS at the project's profiles (:mod:`cartpole_core.middleware`),
refuses a node whose role is taken in its namespace (:mod:`cartpole_core.domain_guard`),
applies the real-time hygiene after start-up (:mod:`cartpole_core.realtime`) and spins
until SIGINT or SIGTERM. The signals only note the request: the spin loop ends after the
callback in progress, so the context is still alive while the node shuts down and its
last words (the controller manager's zero force, the bridge's disarm) still go out. Bad
start-up parameters are reported on one line, exit 2. Beside it, the QoS every node
shares (:data:`PUBLISH_DEPTH`, :data:`PLANT_RESET_QOS`). It imports rclpy, never the
plant or the simulator node.

Why rclpy's own SIGINT handling is not used: (docs/architecture.md, "ROS interfaces").
"""
from __future__ import annotations

import signal
import sys
from typing import Callable

import rclpy
from rclpy.exceptions import InvalidParameterValueException, ParameterException
from rclpy.executors import Executor, ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions

from . import middleware, realtime
from .domain_guard import refuse_duplicate_node
from .roles import role_of_executable


class _StopRequest:
    """SIGINT/SIGTERM handler: remembers the signal; the spin loop acts on it."""

    def __init__(self) -> None:
        self.signum: int | None = None

    def __call__(self, signum, frame) -> None:  # noqa: ARG002 - signal handler
        if self.signum is None:
            self.signum = signum


def run_node(make_node: Callable[[], Node], args=None, *, name: str = '',
             make_executor: Callable[[], Executor] = SingleThreadedExecutor,
             on_interrupt: Callable[[Node, Executor], None] | None = None) -> None:
    """Create the node, spin it until SIGINT/SIGTERM, then destroy it and shut down.

    ``name`` is the installed executable: its role (:mod:`cartpole_core.roles`)
    decides the duplicate check and the real-time priority, whatever the node
    is called (``-r __node:=...``). ``on_interrupt(node, executor)`` runs after
    the signal while the context is still valid (e.g. the recorder drains its
    queues into the bag).
    """
    middleware.use_profiles()  # before the first participant: Fast DDS reads it then
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    stop = _StopRequest()
    previous = {sig: signal.signal(sig, stop) for sig in (signal.SIGINT, signal.SIGTERM)}
    node = None
    hygiene = None
    executor = make_executor()
    try:
        role = role_of_executable(name)
        refuse_duplicate_node(role)  # one graph a namespace (cartpole_core.domain_guard)
        node = make_node()
        executor.add_node(node)
        hygiene = realtime.node_hygiene(role, node.get_logger(),
                                        node.get_parameter('use_sim_time').value,
                                        name=node.get_name())
        while rclpy.ok() and stop.signum is None:
            executor.spin_once(timeout_sec=0.1)
            realtime.collect_when_idle()
        if stop.signum is not None:
            if hygiene is not None:
                hygiene.leave()  # shutting down is not the loop's work
            if on_interrupt is not None:
                on_interrupt(node, executor)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (ValueError, OSError, InvalidParameterValueException, ParameterException) as error:
        print(f'{name or "node"}: error: {error}', file=sys.stderr)
        raise SystemExit(2) from None
    finally:
        if hygiene is not None:
            hygiene.leave()
        if node is not None:
            node.destroy_node()
        executor.shutdown()
        rclpy.try_shutdown()
        for sig, handler in previous.items():
            signal.signal(sig, handler)


PLANT_RESET_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
"""QoS of ``/cartpole/plant_reset`` (publishers and subscribers): the last reset is kept
for late joiners, so a homing announced while the graph is still discovering itself
reaches the EKF and the controller manager."""

PUBLISH_DEPTH = 100
"""History depth of the 200 Hz publishers: a slow subscriber (the recorder on a
loaded machine) gets a burst late instead of losing it. Control-path
subscriptions keep their own small depth."""
