"""The live view's core (no ROS): a Foxglove WebSocket server and what it publishes.

Fed sample by sample -- by the ``viewer`` node from the graph's topics
(:mod:`cartpole_analysis.viewer.node`) or by ``cartpole offline --view``
straight from the offline loop (:mod:`cartpole_analysis.viewer.offline`) --
:class:`LiveView` publishes, through the ``foxglove-sdk`` server, the scene
(``/cartpole/view/scene``, foxglove.SceneUpdate), the state and the control
(``/cartpole/view/state``, ``/cartpole/view/control``, JSON) and the events
(``/cartpole/view/events``, foxglove.Log); docs/live_view.md lists their fields.

Every message's log time is the stamp of the sample it shows, so a client orders
and plots by the loop's own time (simulated in lockstep). Scene, state and control
are decimated by those stamps to at most ``max_rate`` (default and upper bound
60 Hz); events never are.
"""
from __future__ import annotations

import collections
import math
import threading
from dataclasses import dataclass
from typing import Any, Mapping

import foxglove
from foxglove.channels import LogChannel, SceneUpdateChannel
from foxglove.messages import Log, LogLevel, Timestamp
from foxglove.websocket import Capability, ServerListener

from cartpole_sim.geometry import RigGeometry
from cartpole_core.model import wrap_angle

from .scene import BodyState, RigScene, mode_key

DEFAULT_HOST = '127.0.0.1'
DEFAULT_PORT = 8765
MAX_RATE_HZ = 60.0
"""Upper bound (and default) of the rate of the scene, state and control channels."""
SUBPROTOCOL = 'foxglove.sdk.v1'
"""WebSocket subprotocol of the foxglove-sdk server (the Foxglove WebSocket protocol; the
server refuses the older name ``foxglove.websocket.v1`` with HTTP 400)."""

TOPICS = {
    'scene': '/cartpole/view/scene',
    'state': '/cartpole/view/state',
    'control': '/cartpole/view/control',
    'events': '/cartpole/view/events',
}
"""The advertised channels (see the module docstring)."""

MODE_CODES = {'idle': 0, 'swingup': 1, 'stabilizing': 2, 'fault': 3}
"""``mode_code`` of ``/cartpole/view/control``, for plots (-1: unknown)."""

_NUMBER = {'type': 'number'}
_STAMP = {'type': 'object', 'properties': {'sec': {'type': 'integer'},
                                           'nsec': {'type': 'integer'}}}
STATE_FIELDS = ('t', 'x', 'theta', 'theta_w', 'theta_w_deg', 'x_dot', 'theta_dot', 'x_meas',
                'theta_meas', 'x_true', 'theta_true', 'theta_w_true', 'theta_w_true_deg',
                'x_dot_true', 'theta_dot_true', 'x_ref', 'x_err')
CONTROL_NUMBERS = ('t', 'force', 'raw_force', 'feedforward', 'energy',
                   'energy_target', 'energy_error', 'mode_code', 'catch_count', 'fall_count')
CONTROL_STRINGS = ('mode', 'active', 'swingup', 'stabilizer')
STATE_SCHEMA = {'title': 'cartpole.view.State', 'type': 'object',
                'properties': {'timestamp': _STAMP, **{k: _NUMBER for k in STATE_FIELDS}}}
CONTROL_SCHEMA = {'title': 'cartpole.view.Control', 'type': 'object',
                  'properties': {'timestamp': _STAMP, 'enabled': {'type': 'boolean'},
                                 **{k: _NUMBER for k in CONTROL_NUMBERS},
                                 **{k: {'type': 'string'} for k in CONTROL_STRINGS}}}


def parse_address(text: str | None) -> tuple[str, int]:
    """``HOST:PORT``, ``HOST`` or ``PORT`` (``''``/None: the default 127.0.0.1:8765).

    Port 0 lets the system choose a free port (the server reports it).
    Raises ValueError with the reason on a bad address.
    """
    if not text:
        return DEFAULT_HOST, DEFAULT_PORT
    host, sep, port_text = text.rpartition(':')
    if not sep:
        host, port_text = (('', text) if text.isdigit() else (text, ''))
    host = host.strip('[]') or DEFAULT_HOST
    if not port_text:
        return host, DEFAULT_PORT
    try:
        port = int(port_text)
    except ValueError:
        raise ValueError(f'bad port {port_text!r} in {text!r} (HOST:PORT)') from None
    if not 0 <= port <= 65535:
        raise ValueError(f'port must be in [0, 65535], got {port}')
    return host, port


@dataclass(frozen=True)
class ControlSample:
    """One controller status (docs/architecture.md, ``/cartpole/controller_status``)."""

    mode: str
    swingup: str = ''
    stabilizer: str = ''
    enabled: bool = True
    energy: float = math.nan
    energy_error: float = math.nan
    raw_force: float = math.nan
    feedforward: float = math.nan
    force: float = math.nan
    catch_count: float = 0.0
    fall_count: float = 0.0
    event: str = ''

    @classmethod
    def from_status_values(cls, values: Mapping[str, str]) -> 'ControlSample':
        """From the KeyValues of the status (numbers as text); missing numbers are NaN."""
        def number(key: str) -> float:
            try:
                return float(values.get(key, 'nan'))
            except ValueError:
                return math.nan
        return cls(mode=values.get('mode', ''), swingup=values.get('swingup', ''),
                   stabilizer=values.get('stabilizer', ''),
                   enabled=values.get('enabled', 'true').strip().lower() == 'true',
                   energy=number('energy'), energy_error=number('energy_error'),
                   raw_force=number('raw_force'), feedforward=number('feedforward'),
                   force=number('force'), catch_count=number('catch_count'),
                   fall_count=number('fall_count'), event=values.get('event', ''))

    @property
    def active(self) -> str:
        """The plugin in charge: the swing-up, the stabiliser, or none (idle, fault)."""
        mode = mode_key(self.mode)
        if mode == 'swingup':
            return self.swingup
        if mode == 'stabilizing':
            return self.stabilizer
        return ''


class Decimator:
    """At most one sample per ``1 / max_rate`` of stamp time (see the module docstring).

    A stamp earlier than the last one shown is skipped (a repeated sample),
    unless it is more than a second earlier: then the run restarted and the
    decimator starts again.
    """

    def __init__(self, max_rate: float = MAX_RATE_HZ) -> None:
        if not (math.isfinite(max_rate) and 0.0 < max_rate <= MAX_RATE_HZ):
            raise ValueError(f'max_rate must be in (0, {MAX_RATE_HZ:g}] Hz, got {max_rate!r}')
        self.period_ns = int(math.ceil(1e9 / max_rate))
        self.last_ns: int | None = None

    def wanted(self, stamp_ns: int) -> bool:
        """Whether the sample at ``stamp_ns`` would be shown (nothing is counted)."""
        last = self.last_ns
        return last is None or stamp_ns - last >= self.period_ns \
            or stamp_ns < last - 1_000_000_000

    def due(self, stamp_ns: int) -> bool:
        """True when the sample at ``stamp_ns`` is to be shown (and it is then counted as shown)."""
        if not self.wanted(stamp_ns):
            return False
        self.last_ns = stamp_ns
        return True


class _SubscribedListener(ServerListener):
    """foxglove ServerListener: sets an event when a client subscribes to the scene."""

    def __init__(self, topic: str) -> None:
        self.topic = topic
        self.subscribed = threading.Event()

    def on_subscribe(self, client, channel) -> None:
        if channel.topic == self.topic:
            self.subscribed.set()


class ViewerServer:
    """A foxglove-sdk WebSocket server with the channels of :data:`TOPICS`.

    Raises RuntimeError (from the SDK) when the address cannot be bound.
    Each server has its own ``foxglove.Context``, so several can run in one
    process (tests) without sharing channels.
    """

    def __init__(self, host: str = DEFAULT_HOST, port: int = DEFAULT_PORT,
                 name: str = 'cartpole') -> None:
        self.context = foxglove.Context()
        self.listener = _SubscribedListener(TOPICS['scene'])
        self.scene = SceneUpdateChannel(TOPICS['scene'], context=self.context)
        self.state = foxglove.Channel(TOPICS['state'], schema=STATE_SCHEMA, context=self.context)
        self.control = foxglove.Channel(TOPICS['control'], schema=CONTROL_SCHEMA,
                                        context=self.context)
        self.events = LogChannel(TOPICS['events'], context=self.context)
        self._server = foxglove.start_server(name=name, host=host, port=port,
                                             capabilities=[Capability.Time],
                                             server_listener=self.listener,
                                             context=self.context)
        self.host = host
        self.port = self._server.port

    @property
    def url(self) -> str:
        return f'ws://{self.host}:{self.port}'

    def wait_for_client(self, timeout: float | None = None) -> bool:
        """Block until a client subscribes to the scene; False on timeout."""
        return self.listener.subscribed.wait(timeout)

    def broadcast_time(self, stamp_ns: int) -> None:
        self._server.broadcast_time(int(stamp_ns))

    def stop(self) -> None:
        self._server.stop()


def _stamp_json(stamp_ns: int) -> dict[str, int]:
    return {'sec': int(stamp_ns // 1_000_000_000), 'nsec': int(stamp_ns % 1_000_000_000)}


def _finite(mapping: dict[str, Any]) -> dict[str, Any]:
    """Drop the numbers that are NaN or infinite (JSON has none; a plot shows a gap)."""
    return {k: v for k, v in mapping.items()
            if not (isinstance(v, float) and not math.isfinite(v))}


class LiveView:
    """Turns the loop's samples into the viewer's messages (see the module docstring).

    Feed it with :meth:`measurement` (``/joint_states``), :meth:`truth`
    (``/cartpole/true_state``), :meth:`estimate` (``/cartpole/state``: this
    one draws the scene) and :meth:`status` (``/cartpole/controller_status``:
    mode, energies and the force command the manager published with the same
    stamp on ``/cartpole/force_command``); stamps in ns.

    Parameters
    ----------
    server
        Where to publish (:class:`ViewerServer`).
    geometry
        The rig drawn.
    x_ref
        x* [m]; change it with :meth:`set_x_ref`.
    max_rate
        Upper bound of the rate of the decimated channels [Hz], at most 60.
    """

    HISTORY = 16
    """Samples kept per input to match a stamp (the truth arrives around the estimate)."""

    def __init__(self, server: ViewerServer, geometry: RigGeometry, x_ref: float,
                 max_rate: float = MAX_RATE_HZ) -> None:
        self.server = server
        self.scene = RigScene(geometry, x_ref)
        self.decimator = Decimator(max_rate)
        self._truth: dict[int, tuple[float, float, float, float]] = {}
        self._measured: dict[int, tuple[float, float]] = {}
        self._shown: collections.deque[int] = collections.deque(maxlen=self.HISTORY)
        self._start_ns: int | None = None
        self.control = ControlSample(mode='')
        """The latest controller status."""
        self.shown = 0
        """Scene updates published."""

    @property
    def x_ref(self) -> float:
        return self.scene.x_ref

    def set_x_ref(self, x_ref: float) -> None:
        if math.isfinite(x_ref):
            self.scene.x_ref = float(x_ref)

    # -- inputs ----------------------------------------------------------------------------
    def wanted(self, stamp_ns: int) -> bool:
        """Whether the sample at ``stamp_ns`` will be drawn (when its estimate comes): a
        feeder may skip decoding the measurement and truth of the other samples."""
        return self.decimator.wanted(stamp_ns)

    @staticmethod
    def _keep(buffer: dict, stamp_ns: int, value) -> None:
        buffer[stamp_ns] = value
        if len(buffer) > LiveView.HISTORY:
            del buffer[min(buffer)]

    def was_shown(self, stamp_ns: int) -> bool:
        """Whether the sample at ``stamp_ns`` was drawn (its status is then plotted)."""
        return stamp_ns in self._shown

    def measurement(self, stamp_ns: int, x: float, theta: float) -> None:
        self._keep(self._measured, stamp_ns, (float(x), float(theta)))

    def truth(self, stamp_ns: int, x: float, theta: float, x_dot: float, theta_dot: float) -> None:
        self._keep(self._truth, stamp_ns, (float(x), float(theta), float(x_dot), float(theta_dot)))

    def _time(self, stamp_ns: int) -> float:
        if self._start_ns is None or stamp_ns < self._start_ns - 1_000_000_000:
            self._start_ns = stamp_ns
        return (stamp_ns - self._start_ns) * 1e-9

    def estimate(self, stamp_ns: int, x: float, theta: float, x_dot: float,
                 theta_dot: float) -> bool:
        """The estimate of the sample at ``stamp_ns``; draws it when due. True if shown."""
        if not self.decimator.due(stamp_ns):
            return False
        self._shown.append(stamp_ns)
        t = self._time(stamp_ns)
        state: dict[str, Any] = {
            'timestamp': _stamp_json(stamp_ns), 't': t, 'x': x, 'theta': theta,
            'theta_w': wrap_angle(theta), 'theta_w_deg': math.degrees(wrap_angle(theta)),
            'x_dot': x_dot, 'theta_dot': theta_dot, 'x_ref': self.x_ref, 'x_err': x - self.x_ref}
        plant = None
        measured = self._measured.get(stamp_ns)
        if measured is not None:
            state['x_meas'], state['theta_meas'] = measured
            plant = BodyState(*measured)
        truth = self._truth.get(stamp_ns)
        if truth is not None:
            theta_w_true = wrap_angle(truth[1])
            state.update(x_true=truth[0], theta_true=truth[1], theta_w_true=theta_w_true,
                         theta_w_true_deg=math.degrees(theta_w_true), x_dot_true=truth[2],
                         theta_dot_true=truth[3])
            plant = BodyState(truth[0], truth[1])
        if self.server.scene.has_sinks():  # nobody watching: no scene to build
            mode = self.control.mode or None
            active = self.control.active
            label = f't = {t:6.2f} s   {mode or "no controller status"}' + (
                f' ({active})' if active else '')
            update = self.scene.update(stamp_ns, plant=plant, estimate=BodyState(x, theta),
                                       mode=mode, label=label)
            self.server.scene.log(update, log_time=stamp_ns)
        self.server.state.log(_finite(state), log_time=stamp_ns)
        self.server.broadcast_time(stamp_ns)
        self.shown += 1
        return True

    def status(self, stamp_ns: int, control: ControlSample) -> None:
        """A controller status for the sample at ``stamp_ns`` (its header stamp)."""
        self.control = control
        if control.event:
            self._log_events(stamp_ns, control)
        if not self.was_shown(stamp_ns):
            return
        energy_target = control.energy + control.energy_error  # E* - E_p + E_p
        message = {
            'timestamp': _stamp_json(stamp_ns), 't': self._time(stamp_ns),
            'force': control.force,
            'raw_force': control.raw_force, 'feedforward': control.feedforward,
            'energy': control.energy, 'energy_target': energy_target,
            'energy_error': control.energy_error, 'mode': control.mode,
            'mode_code': float(MODE_CODES.get(mode_key(control.mode), -1)),
            'active': control.active, 'swingup': control.swingup,
            'stabilizer': control.stabilizer, 'enabled': control.enabled,
            'catch_count': control.catch_count, 'fall_count': control.fall_count}
        self.server.control.log(_finite(message), log_time=stamp_ns)

    def _log_events(self, stamp_ns: int, control: ControlSample) -> None:
        t = self._time(stamp_ns)
        for event in filter(None, control.event.split(';')):
            if event.startswith('fault'):
                level = LogLevel.Error
            elif event == 'fall':
                level = LogLevel.Warning
            else:
                level = LogLevel.Info
            text = f'{event} at t = {t:.3f} s (mode {control.mode}, {control.active or "-"})'
            self.server.events.log(Log(timestamp=Timestamp(int(stamp_ns // 1_000_000_000),
                                                           int(stamp_ns % 1_000_000_000)),
                                       level=level, message=text, name='controller_manager'),
                                   log_time=stamp_ns)
