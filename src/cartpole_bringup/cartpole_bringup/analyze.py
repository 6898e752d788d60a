"""Run analysis from recorded bags (no ROS): time series, the SPEC 5 summary, plots.

:class:`SeriesBuilder` turns the graph's messages (from a bag here, or live in
``cartpole run``) into a :class:`~cartpole_bringup.plots.RunSeries` and the
summary of :func:`cartpole_bringup.metrics.summarize` -- the very function
``cartpole offline`` uses, so both report the same numbers for the same
trajectory.

What is taken from where:

- states: the ground truth ``/cartpole/true_state`` when present (simulator),
  else the estimate ``/cartpole/state`` (hardware);
- time: the messages' ``header.stamp``; t = 0 is simulated time zero when the
  run was in lockstep (``/clock`` recorded, or ``lockstep=true`` in the bag's
  custom_data), else the first sample;
- catch time: the first ``/cartpole/controller_status`` whose ``event`` has
  ``catch`` (events are ';'-separated) or whose ``mode`` is the stabilising one, at its ``state_stamp``
  (the sample the switch was computed from) or else its header stamp;
- end-stop contact: the plant's own contact state (simulator): a non-zero
  end-stop force in ``effort[1]`` of ``/cartpole/true_state``, or (bags
  written before it was published) the true position past a stop by more
  than the plant's tolerance;
  on hardware, a limit flag ``limit_left`` / ``limit_right`` of
  ``/cartpole/hw/health`` closing after it was seen open (the cart starts on
  the left switch); with neither, the estimate outside [0, travel];
- x*: ``--x-ref``, else ``x_ref`` of the bag's custom_data, else the middle of
  the travel.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

from cartpole_sim.model import CartPoleParameters

from . import metrics
from .bag import bag_custom_data
from .plots import RunSeries

TRUE_STATE = '/cartpole/true_state'
STATE = '/cartpole/state'
FORCE = '/cartpole/force_command'
STATUS = '/cartpole/controller_status'
HW_HEALTH = '/cartpole/hw/health'
JOINTS = '/joint_states'
CLOCK = '/clock'

CATCH_EVENT = 'catch'
HW_LIMIT_KEYS = ('limit_left', 'limit_right')
"""Keys of the limit-switch flags in the hw bridge's health status."""


def is_stabilising(mode: str) -> bool:
    """The controller status mode of the stabiliser (``stabilising``/``stabilizing``)."""
    return mode.strip().lower().startswith('stabili')


def _truthy(text: str) -> bool:
    text = text.strip().lower()
    if text in ('true', 'yes', 'on'):
        return True
    try:
        return float(text) != 0.0
    except ValueError:
        return False


@dataclass
class SeriesBuilder:
    """Accumulates the messages of one run; :meth:`build` makes the series.

    Feed it with :meth:`joint_state` (any JointState topic), :meth:`status`
    (controller status key/values) and :meth:`hw_health`.
    """

    states: dict[str, list[tuple[int, float, float, float, float]]] = field(
        default_factory=lambda: {TRUE_STATE: [], STATE: []})
    forces: list[tuple[int, float]] = field(default_factory=list)
    catch_ns: int | None = None
    controllers: dict[str, str] = field(default_factory=dict)
    """swingup / stabilizer names from the last status."""
    limit_flag: bool = False
    truth_contact: bool = False
    """A ``/cartpole/true_state`` sample carried a non-zero end-stop force."""
    hw_health_seen: bool = False
    status_count: int = 0
    _limit_open: dict[str, bool] = field(default_factory=dict)

    def joint_state(self, topic: str, stamp_ns: int, position: Sequence[float],
                    velocity: Sequence[float], effort: Sequence[float]) -> None:
        if topic in self.states and len(position) >= 2 and len(velocity) >= 2:
            self.states[topic].append((stamp_ns, float(position[0]), float(position[1]),
                                       float(velocity[0]), float(velocity[1])))
            if topic == TRUE_STATE and len(effort) >= 2 and effort[1] != 0.0:
                self.truth_contact = True
        elif topic == FORCE and len(effort) >= 1:
            self.forces.append((stamp_ns, float(effort[0])))

    def status(self, stamp_ns: int, values: Mapping[str, str]) -> None:
        self.status_count += 1
        for key in ('swingup', 'stabilizer'):
            if values.get(key):
                self.controllers[key] = values[key]
        if self.catch_ns is not None:
            return
        events = values.get('event', '').split(';')
        if CATCH_EVENT in events or is_stabilising(values.get('mode', '')):
            self.catch_ns = _stamp_value_ns(values.get('state_stamp'), stamp_ns)

    def hw_health(self, stamp_ns: int, values: Mapping[str, str]) -> None:
        """Limit switches: a flag closing after it was seen open is a contact.

        The cart starts at the left stop (SPEC 1a), where the left switch may
        be closed; that is the starting position, not a contact.
        """
        self.hw_health_seen = True
        for key in HW_LIMIT_KEYS:
            if key not in values:
                continue
            closed = _truthy(values[key])
            if closed and self._limit_open.get(key, False):
                self.limit_flag = True
            if not closed:
                self._limit_open[key] = True

    @property
    def source(self) -> str | None:
        """The state topic the series is built from (truth first), None if none."""
        for topic in (TRUE_STATE, STATE):
            if self.states[topic]:
                return topic
        return None

    def build(self, *, params: CartPoleParameters, x_ref: float, lockstep: bool,
              label: str = '') -> tuple[RunSeries, bool]:
        """The run's series and its end-stop contact flag.

        Raises ValueError when no state was recorded.
        """
        source = self.source
        if source is None:
            raise ValueError(f'no {TRUE_STATE} or {STATE} messages: nothing to analyse')
        rows = np.array(sorted(self.states[source]), dtype=float)
        # A sample delivered twice (lockstep re-publishes sample 0 until the loop answers).
        rows = rows[np.concatenate(([True], np.diff(rows[:, 0]) > 0))]
        t0 = 0.0 if lockstep else rows[0, 0]
        t = (rows[:, 0] - t0) * 1e-9
        forces = np.array(sorted(self.forces), dtype=float).reshape(-1, 2)
        catch = None if self.catch_ns is None else (self.catch_ns - t0) * 1e-9
        series = RunSeries.from_states(t, rows[:, 1:], forces[:, 1], params=params, x_ref=x_ref,
                                       catch_time=catch, t_force=(forces[:, 0] - t0) * 1e-9,
                                       label=label)
        if source == TRUE_STATE:
            contact = self.truth_contact or metrics.end_stop_touched(series.x, params.travel)
        elif self.hw_health_seen:
            contact = self.limit_flag
        else:
            contact = metrics.end_stop_touched(series.x, params.travel)
        return series, contact


def _stamp_value_ns(text: str | None, fallback_ns: int) -> int:
    """A ``state_stamp`` value (seconds as a float, or ``sec.nanosec``) in ns."""
    if text:
        try:
            return int(round(float(text) * 1e9))
        except ValueError:
            pass
    return fallback_ns


def _stamp_ns(stamp) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def parse_joint_state(data: bytes | memoryview) -> tuple[int, list[str], np.ndarray, np.ndarray,
                                                         np.ndarray]:
    """(stamp [ns], name, position, velocity, effort) of a CDR sensor_msgs/JointState.

    A direct reader of the XCDR1 layout (4-byte encapsulation header, then
    fields aligned to their size relative to the payload start), about ten
    times faster than a generic deserialiser on long bags.
    """
    buf = memoryview(data)
    little = bool(buf[1] & 1)
    order = '<' if little else '>'
    base = 4
    pos = 0

    def align(n: int) -> None:
        nonlocal pos
        pos += (-pos) % n

    def u32() -> int:
        nonlocal pos
        align(4)
        (v,) = struct.unpack_from(order + 'I', buf, base + pos)
        pos += 4
        return v

    def string() -> str:
        nonlocal pos
        n = u32()
        text = bytes(buf[base + pos:base + pos + max(n - 1, 0)]).decode('utf-8')
        pos += n
        return text

    def doubles() -> np.ndarray:
        nonlocal pos
        n = u32()
        if n:
            align(8)
        arr = np.frombuffer(buf, dtype=order + 'f8', count=n, offset=base + pos)
        pos += 8 * n
        return arr

    sec, nanosec = struct.unpack_from(order + 'iI', buf, base)
    pos = 8
    string()  # frame_id
    names = [string() for _ in range(u32())]
    position, velocity, effort = doubles(), doubles(), doubles()
    return sec * 1_000_000_000 + nanosec, names, position, velocity, effort


@dataclass
class BagAnalysis:
    """The analysis of one bag."""

    path: Path
    series: RunSeries
    summary: dict[str, Any]
    source: str
    """State topic used (ground truth or estimate)."""
    topics: dict[str, int]
    """Messages per topic in the bag."""
    controllers: dict[str, str]


def read_bag(path: str | Path) -> tuple[SeriesBuilder, dict[str, int]]:
    """Feed every relevant message of a bag into a :class:`SeriesBuilder`."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    path = Path(path)
    if not (path / 'metadata.yaml').is_file() and not path.is_file():
        raise FileNotFoundError(f'{path} is not a rosbag2 bag (no metadata.yaml); if its '
                                f'recording was cut short, run `cartpole bag repair {path}`')
    builder = SeriesBuilder()
    wanted = {TRUE_STATE, STATE, FORCE, STATUS, HW_HEALTH}
    last_status = None
    with AnyReader([path], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        topics = {c.topic: c.msgcount for c in reader.connections}
        connections = [c for c in reader.connections if c.topic in wanted]
        for connection, _, raw in reader.messages(connections=connections):
            if connection.topic in (STATUS, HW_HEALTH):
                if connection.topic == STATUS and builder.catch_ns is not None:
                    last_status = (connection, raw)  # only the controller names are left
                    continue
                _feed_diagnostics(builder, connection.topic,
                                  reader.deserialize(raw, connection.msgtype))
            elif connection.msgtype == 'sensor_msgs/msg/JointState':
                stamp, _, position, velocity, effort = parse_joint_state(raw)
                builder.joint_state(connection.topic, stamp, position, velocity, effort)
        if last_status is not None:
            _feed_diagnostics(builder, STATUS,
                              reader.deserialize(last_status[1], last_status[0].msgtype))
    return builder, topics


def _feed_diagnostics(builder: SeriesBuilder, topic: str, msg) -> None:
    stamp = _stamp_ns(msg.header.stamp)
    for status in msg.status:
        values = {kv.key: kv.value for kv in status.values}
        if topic == STATUS:
            builder.status(stamp, values)
        else:
            builder.hw_health(stamp, values)


def analyze_bag(path: str | Path, *, x_ref: float | None = None,
                params: CartPoleParameters | None = None, label: str = '') -> BagAnalysis:
    """Series and SPEC 5 summary of one recorded run.

    Parameters
    ----------
    path
        The bag directory (``metadata.yaml`` and the MCAP file).
    x_ref
        x* [m]; default: the bag's custom_data ``x_ref``, else mid-travel.
    params
        Nominal plant parameters (travel for the end-stop test, l, g, E*).
    """
    path = Path(path)
    params = params or CartPoleParameters()
    custom = bag_custom_data(path)
    if x_ref is None:
        x_ref = float(custom['x_ref']) if 'x_ref' in custom else params.x_middle
    builder, topics = read_bag(path)
    lockstep = CLOCK in topics or custom.get('lockstep', '').lower() == 'true'
    series, contact = builder.build(params=params, x_ref=x_ref, lockstep=lockstep,
                                    label=label or run_label(path))
    summary = metrics.summarize(series.t, series.x, series.theta, x_ref=x_ref,
                                catch_time=series.catch_time, end_stop_contact=contact)
    return BagAnalysis(path=path, series=series, summary=summary, source=builder.source,
                       topics=topics, controllers=dict(builder.controllers))


def run_label(path: Path) -> str:
    """A short name of a bag: its directory name, or its parent's for ``.../bag``."""
    path = Path(path).resolve()
    return path.parent.name if path.name == 'bag' else path.name


def comparison_table(analyses: Iterable[BagAnalysis]) -> list[str]:
    """Rows of a side-by-side table: one row a summary key, one column a bag."""
    analyses = list(analyses)
    labels = [a.series.label for a in analyses]
    key_width = max(len(k) for k in metrics.SUMMARY_KEYS)
    widths = [max(len(label), 10) for label in labels]

    def cell(value) -> str:
        if isinstance(value, bool) or value is None:
            return 'null' if value is None else str(value)
        if isinstance(value, float):
            return f'{value:.4g}'
        return str(value)

    rows = [' '.join([f'{"":<{key_width}}'] + [f'{lb:>{w}}' for lb, w in zip(labels, widths)])]
    for key in metrics.SUMMARY_KEYS:
        cells = [f'{cell(a.summary.get(key)):>{w}}' for a, w in zip(analyses, widths)]
        rows.append(' '.join([f'{key:<{key_width}}'] + cells))
    return rows
