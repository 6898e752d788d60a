"""Python ``logging`` of the ROS-free cores routed to the hosting node's logger.

The cores (the controller manager, the plugin registry, the plan cache, the
controllers) log with :mod:`logging` and import no rclpy. While a node hosts
them, :class:`RosLogHandler` (installed by the node adapter with
:func:`route_to_node`, removed with :meth:`RosLogHandler.remove` when the node
is destroyed) hands every record to the node's rclpy logger at the matching
severity: so a refused plugin or an exception in the control cycle shows on
the console, in ``/rosout`` and in rqt_console under the node's name, prefixed
with the Python logger's name. Without a node (scripts, tests) nothing
changes: Python's own handlers (or its last resort, stderr) print them.
"""
from __future__ import annotations

import logging

from rclpy.node import Node

class RosLogHandler(logging.Handler):
    """Forwards the records of some Python loggers to a node's rclpy logger."""

    def __init__(self, node: Node, logger_names: tuple[str, ...]) -> None:
        super().__init__()
        self._ros_logger = node.get_logger()
        self._loggers = [logging.getLogger(name) for name in logger_names]
        self._levels = [lg.level for lg in self._loggers]
        # rcutils' severities are Python's numbers (DEBUG 10 ... FATAL 50): pass what the
        # node logs, from its level at installation (e.g. --log-level).
        level = int(self._ros_logger.get_effective_level())
        for lg in self._loggers:
            lg.setLevel(level)
            lg.addHandler(self)

    def emit(self, record: logging.LogRecord) -> None:
        try:
            text = f'{record.name}: {record.getMessage()}'
            if record.exc_info:
                text += '\n' + logging.Formatter().formatException(record.exc_info)
            # One call site a severity: rclpy refuses a call site whose severity changes.
            ros, level = self._ros_logger, record.levelno
            if level >= logging.CRITICAL:
                ros.fatal(text)
            elif level >= logging.ERROR:
                ros.error(text)
            elif level >= logging.WARNING:
                ros.warning(text)
            elif level >= logging.INFO:
                ros.info(text)
            else:
                ros.debug(text)
        except Exception:  # a log line must never break the code that logs
            self.handleError(record)

    def remove(self) -> None:
        """Stop forwarding; the loggers' levels go back to what they were."""
        for lg, level in zip(self._loggers, self._levels):
            lg.removeHandler(self)
            lg.setLevel(level)


def route_to_node(node: Node, *logger_names: str) -> RosLogHandler:
    """Route the Python loggers ``logger_names`` (and their children) to ``node``'s logger."""
    return RosLogHandler(node, logger_names)
