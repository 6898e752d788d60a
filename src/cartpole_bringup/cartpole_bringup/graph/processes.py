"""The graph's nodes as OS processes (``cartpole run --processes``): command lines, exits.

Each node is its installed executable ``install/<pkg>/lib/<pkg>/<exe>`` with
``--ros-args -p name:=value`` (and ``--params-file``), started in its own
session so that a Ctrl-C reaches only ``cartpole run``, and dying with it
(``PR_SET_PDEATHSIG``). :func:`describe_exit` words a child's exit status the
way the run summary's ``fault`` reports it (``controller_manager died
(SIGKILL)``).
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

from cartpole_core.child_process import die_with_parent

NODES: dict[str, tuple[str, str, str, str]] = {
    'sim': ('cartpole_sim', 'sim_node', 'cartpole_sim.sim_node', 'SimNode'),
    'hw_bridge': ('cartpole_hw', 'hw_bridge', 'cartpole_hw.hw_node', 'HwBridgeNode'),
    'ekf': ('cartpole_estimation', 'ekf_node', 'cartpole_estimation.ekf_node', 'EkfNode'),
    'controller_manager': ('cartpole_control', 'controller_manager',
                           'cartpole_control.manager_node', 'ControllerManagerNode'),
    'recorder': ('cartpole_bringup', 'cartpole_recorder', 'cartpole_bringup.graph.recorder', 'RecorderNode'),
}
"""Node name -> (package, installed executable, module, class)."""


class NodeStartError(RuntimeError):
    """A node executable is missing."""


def ros_value_text(value: Any) -> str:
    """A parameter value as ``-p name:=value`` text (YAML)."""
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, (list, tuple)):
        return '[' + ', '.join(ros_value_text(v) for v in value) + ']'
    if isinstance(value, str):
        return "'" + value.replace("'", "''") + "'"
    return repr(value)


def executable(name: str) -> Path:
    """The installed executable of node ``name`` (``install/<pkg>/lib/<pkg>/<exe>``)."""
    from ament_index_python.packages import PackageNotFoundError, get_package_prefix
    package, exe = NODES[name][:2]
    try:
        path = Path(get_package_prefix(package)) / 'lib' / package / exe
    except PackageNotFoundError as error:
        raise NodeStartError(f'package {package} is not installed (run `make build`)') from error
    if not os.access(path, os.X_OK):
        raise NodeStartError(f'{path} is missing; run `make build`')
    return path


def node_command(name: str, parameters: Mapping[str, Any], *, log_level: str,
                 params_file: Path | None, ros_arguments: Sequence[str] = ()) -> list[str]:
    """The command starting node ``name`` as a process with these explicit parameters
    (and ``ros_arguments``: remappings such as the namespace)."""
    cmd = [str(executable(name)), '--ros-args', '--log-level', log_level, *ros_arguments]
    if params_file:
        cmd += ['--params-file', str(params_file)]
    for key, value in parameters.items():
        cmd += ['-p', f'{key}:={ros_value_text(value)}']
    return cmd



def start_node_process(cmd: Sequence[str]) -> subprocess.Popen:
    """Start one node process in its own session, dying with this process."""
    return subprocess.Popen(
        list(cmd), env=dict(os.environ), stdin=subprocess.DEVNULL, start_new_session=True,
        preexec_fn=die_with_parent if sys.platform.startswith('linux') else None)


def stop_node_process(proc: subprocess.Popen, name: str,
                      wait: Callable[[Callable[[], bool], float], bool], grace: float) -> list[str]:
    """SIGINT and ``grace`` seconds to shut down properly, then SIGTERM, and SIGKILL 2 s later.

    ``wait(predicate, timeout)`` waits while doing the caller's work (spinning
    its executor). Returns warnings (empty when the node stopped on SIGINT).
    """
    for sig, timeout in ((signal.SIGINT, grace), (signal.SIGTERM, 2.0), (signal.SIGKILL, 2.0)):
        proc.send_signal(sig)
        try:
            wait(lambda: proc.poll() is not None, timeout)
            proc.wait(timeout=0.1)
        except subprocess.TimeoutExpired:
            continue
        if sig == signal.SIGINT:
            return [] if proc.returncode in (0, -signal.SIGINT) else \
                [f'{name} {describe_exit(proc.returncode)} on SIGINT']
        return [f'{name} did not stop on SIGINT; sent {sig.name}']
    return [f'{name} could not be stopped']


def describe_exit(returncode: int) -> str:
    """``died (SIGKILL)``, ``exited with code 2``, ``exited`` (code 0)."""
    if returncode < 0:
        try:
            return f'died ({signal.Signals(-returncode).name})'
        except ValueError:
            return f'died (signal {-returncode})'
    return 'exited' if returncode == 0 else f'exited with code {returncode}'
