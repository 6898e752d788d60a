"""Stopping a child process the way a user stops a node: SIGINT, a wait, then SIGKILL.

Every node's ``main`` (:func:`cartpole_core.node_runner.run_node`) ends cleanly
on SIGINT; a child that does not within the grace is killed, so that no test
or tool leaves a process behind. The graph's own stop, which escalates through
SIGTERM and reports, is :func:`cartpole_bringup.graph.processes.stop_node_process`.
This module imports nothing of the simulator (see :mod:`cartpole_core.node_runner`
for why shared helpers live in the bottom package).
"""
from __future__ import annotations

import signal
import subprocess


def interrupt(proc: subprocess.Popen, grace: float, *, drain: bool = True) -> bool:
    """SIGINT ``proc`` (if it runs) and wait ``grace`` seconds for it to end, else SIGKILL.

    ``drain``: read its pipes while waiting (``communicate``), so that a child
    blocked on a full pipe can end; False when another thread reads them.
    Returns True if it ended within the grace (its exit code is
    ``proc.returncode``), False if it had to be killed.
    """
    wait = proc.communicate if drain else proc.wait
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
    try:
        wait(timeout=grace)
        return True
    except subprocess.TimeoutExpired:
        proc.kill()
        wait()
        return False


def reap(proc: subprocess.Popen, *, drain: bool = True) -> None:
    """Kill ``proc`` if it still runs and collect it: the ``finally`` of whoever started it,
    so that no child outlives a failed test or tool.

    ``drain``: collect with ``communicate`` (its pipes read); False: ``wait``.
    """
    if proc.poll() is None:
        proc.kill()
        (proc.communicate if drain else proc.wait)()


def child_running(pid: int, executable: str) -> int:
    """PID of the child process of ``pid`` whose command line runs ``executable`` (by name:
    ``controller_manager``, ``cartpole_recorder``, ...), for a test or tool that signals one node of
    ``cartpole run --processes``; LookupError if there is none (Linux /proc)."""
    from pathlib import Path
    for child in Path(f'/proc/{pid}/task/{pid}/children').read_text().split():
        try:
            argv = Path(f'/proc/{child}/cmdline').read_bytes().split(b'\0')
        except OSError:  # ended meanwhile
            continue
        if any(Path(arg.decode(errors='replace')).name == executable for arg in argv):
            return int(child)
    raise LookupError(f'no {executable} process under {pid}')

def die_with_parent() -> None:  # pragma: no cover - runs in the child
    """In the child before exec: SIGTERM when the parent dies (Linux PR_SET_PDEATHSIG)."""
    try:
        import ctypes
        ctypes.CDLL('libc.so.6', use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
    except OSError:
        pass
