"""``spin_until``: spin an executor until a predicate holds, or a timeout passes.

The one helper for code that waits on a ROS graph (the pulse player's
start-up, the tests' fixture): it waits on the executor, where work arrives
as events, never on a bare sleep; the timeout only bounds a wait that fails.
It lives in the bottom package for the reason :mod:`cartpole_core.node_runner`
gives (every package may import it without a cycle) and imports nothing of
the simulator.
"""
from __future__ import annotations

import time
from typing import Callable

SPIN_PERIOD = 0.1
"""Longest single ``spin_once`` [s]: how late a predicate made true without an event is seen."""


def spin_until(executor, predicate: Callable[[], bool], timeout: float) -> bool:
    """Spin ``executor`` until ``predicate()``; False if ``timeout`` seconds pass first."""
    deadline = time.monotonic() + timeout
    while not predicate():
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            return False
        executor.spin_once(timeout_sec=min(SPIN_PERIOD, remaining))
    return True
