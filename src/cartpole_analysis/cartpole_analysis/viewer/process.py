"""The ``viewer`` node in its own process, for ``cartpole run --view`` (and its benchmark).

Starts the installed executable (``install/cartpole_bringup/lib/cartpole_bringup/viewer``)
with ``--ros-args -p host:=... -p port:=...``, waits for its ``viewer:
serving ws://HOST:PORT`` line (so a port in use is an error before the graph
starts, and port 0 reports the port chosen), then forwards whatever else the
viewer prints. Its own process: the viewer's Python work (parsing 800
messages a second, building scenes, the WebSocket server) never competes
with the control loop for the interpreter, and the viewer gives itself the
lowest CPU priority (:func:`cartpole_analysis.viewer.node.lower_priority`).
It dies with its parent (``PR_SET_PDEATHSIG``) and stops on SIGINT like
every node.
"""
from __future__ import annotations

import os
import queue
import re
import signal
import subprocess
import sys
import threading
from pathlib import Path

from cartpole_core.child_process import interrupt

SERVING = re.compile(r'viewer: serving (ws://\S+)')
START_TIMEOUT = 30.0
"""Wall seconds for the viewer to import, bind and report."""
STOP_TIMEOUT = 5.0


def viewer_executable() -> Path:
    from ament_index_python.packages import get_package_prefix
    path = Path(get_package_prefix('cartpole_analysis')) / 'lib' / 'cartpole_analysis' / 'cartpole_viewer'
    if not os.access(path, os.X_OK):
        raise RuntimeError(f'{path} is missing; run `make build`')
    return path


class ViewerProcess:
    """The viewer executable, started by :meth:`start`, stopped by :meth:`stop`.

    Parameters
    ----------
    host, port
        Where the server binds (port 0: any free port).
    parameters
        Further ROS parameters of the node (``plant_params_file``, ``x_ref``,
        ``max_rate``).
    log_level
        ROS log level of the node.
    ros_arguments
        Further ROS arguments (the graph's namespace: ``-r __ns:=/rig2``).
    """

    def __init__(self, host: str, port: int, parameters: dict | None = None,
                 log_level: str = 'warn', ros_arguments: list[str] | None = None) -> None:
        self.command = [str(viewer_executable()), '--ros-args', '--log-level', log_level,
                        *(ros_arguments or []), '-p', f'host:={host}', '-p', f'port:={int(port)}']
        for key, value in (parameters or {}).items():
            text = ('true' if value else 'false') if isinstance(value, bool) else str(value)
            self.command += ['-p', f'{key}:={text}']
        self.process: subprocess.Popen | None = None
        self.url: str | None = None
        self._lines: queue.Queue = queue.Queue()

    def start(self, timeout: float = START_TIMEOUT) -> str:
        """Start it and wait for its address; returns ``ws://HOST:PORT``.

        Raises RuntimeError with the viewer's own words when it exits or
        stays silent.
        """
        from cartpole_core.child_process import die_with_parent  # as the graph's node processes

        self.process = subprocess.Popen(
            self.command, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE, text=True, start_new_session=True,
            preexec_fn=die_with_parent if sys.platform.startswith('linux') else None)
        threading.Thread(target=self._read, daemon=True).start()
        said: list[str] = []
        while True:
            try:
                line = self._lines.get(timeout=timeout)
            except queue.Empty:
                self.stop()
                raise RuntimeError(f'the viewer did not start within {timeout:g} s') from None
            if line is None:
                self.process.wait()
                raise RuntimeError(f'the viewer exited with code {self.process.returncode}: '
                                   + ' '.join(s.strip() for s in said)[-500:])
            match = SERVING.search(line)
            if match:
                self.url = match.group(1)
                return self.url
            said.append(line)

    def _read(self) -> None:
        """Hand the lines to :meth:`start` until the address, then forward them to stderr."""
        assert self.process is not None and self.process.stderr is not None
        started = False
        for line in self.process.stderr:
            if started:
                sys.stderr.write(line)
                continue
            self._lines.put(line)
            started = SERVING.search(line) is not None
        self._lines.put(None)

    def stop(self) -> str | None:
        """SIGINT, then SIGKILL after a timeout; returns a warning, or None if it stopped cleanly."""
        proc = self.process
        if proc is None or proc.poll() is not None:
            return None if proc is None or proc.returncode in (0, -signal.SIGINT) else \
                f'viewer had exited with code {proc.returncode}'
        if not interrupt(proc, STOP_TIMEOUT, drain=False):  # a thread reads its stdout
            return 'viewer did not stop on SIGINT; killed'
        return None if proc.returncode in (0, -signal.SIGINT) else \
            f'viewer exited with code {proc.returncode}'


class GraphViewer:
    """The view of ``cartpole run --view``: the viewer process and its tap in the graph.

    :meth:`start` starts the viewer process reading a feed socket;
    :meth:`attach` adds the ``viewer_tap`` node (:mod:`cartpole_analysis.viewer.tap`)
    to the graph's executor; :meth:`close` removes the tap, stops the viewer and
    the socket's directory goes.

    The viewer keeps wall time even in lockstep (no ``use_sim_time``): it orders
    and decimates by the messages' stamps, its own timers only poll the graph.
    """

    def __init__(self, address: str | None, *, plant_params: Path | None = None,
                 log_level: str = 'warn', ros_arguments: list[str] | None = None) -> None:
        import tempfile

        from .server import parse_address

        host, port = parse_address(address)
        self._directory = tempfile.TemporaryDirectory(prefix='cartpole-view-')
        self.feed = str(Path(self._directory.name) / 'feed.sock')
        parameters: dict = {'feed': self.feed}
        if plant_params is not None:
            parameters['plant_params_file'] = str(Path(plant_params).resolve())
        self.process = ViewerProcess(host, port, parameters, log_level=log_level,
                                     ros_arguments=ros_arguments)
        self.tap = None
        self._executor = None

    @property
    def url(self) -> str | None:
        return self.process.url

    def start(self) -> str:
        return self.process.start()

    def attach(self, executor, context, plant_topic: str, **node_options) -> None:
        """Tap the graph: the ``viewer_tap`` node on the graph's executor (``node_options``:
        its ``cli_args``, the graph's namespace)."""
        from .tap import ViewerTapNode
        self.tap = ViewerTapNode(self.feed, plant_topic=plant_topic, context=context,
                                 **node_options)
        self._executor = executor
        executor.add_node(self.tap)

    def close(self) -> list[str]:
        """Remove the tap, stop the viewer; returns warnings."""
        warnings = []
        if self.tap is not None:
            try:
                self._executor.remove_node(self.tap)
            except Exception:  # the executor may be shut down already
                pass
            self.tap.destroy_node()
            self.tap = None
        warning = self.process.stop()
        if warning:
            warnings.append(warning)
        self._directory.cleanup()
        return warnings


def start_viewer(address: str | None, *, plant_params: Path | None = None,
                 log_level: str = 'warn', ros_arguments: list[str] | None = None) -> GraphViewer:
    """The view of ``cartpole run --view [HOST:PORT]``, its viewer process started (in the
    graph's namespace with ``ros_arguments``); RuntimeError if it cannot start."""
    viewer = GraphViewer(address, plant_params=plant_params, log_level=log_level,
                         ros_arguments=ros_arguments)
    try:
        viewer.start()
    except RuntimeError:
        viewer.close()
        raise
    return viewer
