"""``main()`` of every cartpole node: the STYLE.md pattern, made safe for a clean stop.

rclpy's own SIGINT handler shuts the context down under the spinning
executor: a callback in the middle of ``take_message`` then fails with an
RCLError instead of a clean exit, and ``destroy_node`` can no longer publish
(the controller manager's last zero force, the bridge's disarm). Here SIGINT
and SIGTERM raise KeyboardInterrupt in the spinning thread, the executor wakes
at least every 0.1 s to let it in, and the context is still alive while the
node shuts down. Bad start-up parameters are reported on one line, exit 2, and
so is a node whose name is taken on the domain already (:mod:`cartpole_sim.domain_guard`).
"""
from __future__ import annotations

import signal
import sys
from typing import Callable

import rclpy
from rclpy.exceptions import InvalidParameterValueException, ParameterException
from rclpy.executors import Executor, ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions

from .domain_guard import refuse_duplicate_node


def _raise_keyboard_interrupt(signum, frame):
    raise KeyboardInterrupt


def run_node(make_node: Callable[[], Node], args=None, *, name: str = '',
             make_executor: Callable[[], Executor] = SingleThreadedExecutor,
             on_interrupt: Callable[[Node, Executor], None] | None = None) -> None:
    """Create the node, spin it until SIGINT/SIGTERM, then destroy it and shut down.

    ``on_interrupt(node, executor)`` runs after the signal while the context
    is still valid (e.g. the recorder drains its queues into the bag).
    """
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    previous = {sig: signal.signal(sig, _raise_keyboard_interrupt)
                for sig in (signal.SIGINT, signal.SIGTERM)}
    node = None
    executor = make_executor()
    try:
        refuse_duplicate_node(make_node)  # one graph per domain (cartpole_sim.domain_guard)
        node = make_node()
        executor.add_node(node)
        try:
            while rclpy.ok():
                executor.spin_once(timeout_sec=0.1)
        except KeyboardInterrupt:
            for sig in previous:
                signal.signal(sig, signal.SIG_IGN)  # one signal is enough: finish cleanly
            if on_interrupt is not None:
                on_interrupt(node, executor)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (ValueError, OSError, InvalidParameterValueException, ParameterException) as error:
        print(f'{name or "node"}: error: {error}', file=sys.stderr)
        raise SystemExit(2) from None
    finally:
        if node is not None:
            node.destroy_node()
        executor.shutdown()
        rclpy.try_shutdown()
        for sig, handler in previous.items():
            signal.signal(sig, handler)


PUBLISH_DEPTH = 100
"""History depth of the 200 Hz publishers: a slow subscriber (the recorder on a
loaded machine) gets a burst late instead of losing it. Control-path
subscriptions keep their own small depth."""
