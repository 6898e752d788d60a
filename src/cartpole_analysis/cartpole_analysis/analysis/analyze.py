"""Run analysis from recorded bags (no ROS): time series, the run summary, plots.

:class:`SeriesBuilder` turns the graph's messages (from a bag here, or live in
``cartpole run``) into a :class:`~cartpole_analysis.analysis.plots.RunSeries` and the
summary of :func:`cartpole_analysis.analysis.metrics.summarize` -- the very function
``cartpole offline`` uses, so both report the same numbers for the same
trajectory. What each summary key is taken from (ground truth or estimate, the
stamps, the catch, end-stop contact, the end of the run, the fault, the loop's
figures) is the table of docs/running.md, "`cartpole analyze`".
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

from cartpole_control.manager import LOOP_FIGURES, STATUS_KEYS
from cartpole_core.model import CartPoleParameters

from . import metrics
from ..bags.writer import bag_custom_data
from cartpole_core.namespaces import bag_namespace, graph_topic
from ..bags.cdr_parse import parse_diagnostic_array, parse_joint_state  # noqa: F401 (re-exported)
from .plots import RunSeries
from .timeline import ControllerTimeline

TRUE_STATE = '/cartpole/true_state'
STATE = '/cartpole/state'
FORCE = '/cartpole/force_command'
STATUS = '/cartpole/controller_status'
HW_HEALTH = '/cartpole/hw/health'
JOINTS = '/joint_states'
CLOCK = '/clock'

CATCH_EVENT = 'catch'
TABLE_EXTRA_KEYS = ('fault', 'longest_cycle_gap_s', 'recorder_missed')
"""Summary keys the comparison table shows besides the success measures
(docs/reference/summary.md, "The run summary")."""
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
    swingup_law: str | None = None
    """The status's ``swingup_law`` at the first catch (until then the latest)."""
    limit_flag: bool = False
    truth_contact: bool = False
    """A ``/cartpole/true_state`` sample carried a non-zero end-stop force."""
    hw_health_seen: bool = False
    status_count: int = 0
    t0_ns: int = 0
    """The stamp of t = 0 of the last :meth:`build` [ns]: 0 in lockstep, else the start of
    control (the first status with a controller running), else the first sample."""
    timeline: ControllerTimeline = field(default_factory=ControllerTimeline)
    """The active controller cycle by cycle (stamps in ns)."""
    faults: list[tuple[int, str]] = field(default_factory=list)
    """(stamp [ns], reason) of each fault the manager or the bridge reported."""
    events: list[tuple[int, str]] = field(default_factory=list)
    """(stamp [ns], ``'event;event'``) of each status that reported events."""
    cycle_gaps: list[tuple[int, float]] = field(default_factory=list)
    """(stamp [ns], longest_cycle_gap_s) whenever the reported value grew."""
    figures: list[tuple[int, dict[str, float]]] = field(default_factory=list)
    """(stamp [ns], {key: value}): the loop figures and the plugin's own of each status."""
    _limit_open: dict[str, bool] = field(default_factory=dict)
    _hw_faults: int = 0

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
        cycle_ns = _stamp_value_ns(values.get('state_stamp'), stamp_ns)
        mode = values.get('mode', '')
        self.timeline.update(cycle_ns, mode, values.get('swingup', ''),
                             values.get('stabilizer', ''))
        event = values.get('event', '')
        events = event.split(';') if event else []
        if event:
            self.events.append((cycle_ns, event))
        for e in events:
            if e.startswith('fault:'):
                self.faults.append((cycle_ns, e[len('fault:'):]))
        gap = _float_or_none(values.get('longest_cycle_gap_s'))
        if gap is not None and (not self.cycle_gaps or gap > self.cycle_gaps[-1][1]):
            self.cycle_gaps.append((cycle_ns, gap))
        figures = {}
        for key, text in values.items():
            if key in LOOP_FIGURES or key not in STATUS_KEYS:
                value = _float_or_none(text)
                if value is not None:
                    figures[key] = value
        if figures:
            self.figures.append((cycle_ns, figures))
        if self.catch_ns is None and values.get('swingup_law'):
            self.swingup_law = values['swingup_law']
        if self.catch_ns is None and (CATCH_EVENT in events or is_stabilising(mode)):
            self.catch_ns = cycle_ns

    def hw_health(self, stamp_ns: int, values: Mapping[str, str]) -> None:
        """Limit switches: a flag closing after it was seen open is a contact.

        The cart starts at the left stop (README.md, "Two commands"), where the left switch may
        be closed; that is the starting position, not a contact.
        """
        self.hw_health_seen = True
        faults = _float_or_none(values.get('faults'))
        if faults is not None and faults > self._hw_faults:
            self._hw_faults = int(faults)
            self.faults.append((stamp_ns, f'hw_bridge: {values.get("last_error") or "fault"}'))
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
              label: str = '', end_ns: int | None = None) -> tuple[RunSeries, bool]:
        """The run's series (up to ``end_ns``, the stamp where the run ended) and its contact flag.

        Raises ValueError when no state was recorded.
        """
        source = self.source
        if source is None:
            raise ValueError(f'no {TRUE_STATE} or {STATE} messages: nothing to analyse')
        # Stamps stay integers (ns) until the origin is subtracted: float64 cannot hold
        # an epoch in ns exactly.
        rows = sorted(r for r in self.states[source] if end_ns is None or r[0] <= end_ns)
        if not rows:
            raise ValueError(f'no state up to the end of the run: nothing to analyse')
        stamps = np.array([r[0] for r in rows], dtype=np.int64)
        keep = np.concatenate(([True], np.diff(stamps) > 0))  # a sample delivered twice
        # t = 0: lockstep, sample 0 (the plant waits for the loop); real time, the start of
        # control. The plant may run before the controller manager's first cycle, and with
        # one process a node a subscription may match seconds late, so the first recorded
        # sample is no start (it made catch times of --processes runs -0.05 to 5.4 s for
        # one swing-up of 2.8 s); the first sample is the origin only without any status.
        started = self.timeline.first_start
        t0 = 0 if lockstep else int(stamps[0] if started is None else started)
        self.t0_ns = t0
        t = (stamps[keep] - t0) * 1e-9
        states = np.array([r[1:] for r in rows], dtype=float).reshape(-1, 4)[keep]
        forces = sorted(f for f in self.forces if end_ns is None or f[0] <= end_ns)
        t_force = (np.array([f[0] for f in forces], dtype=np.int64) - t0) * 1e-9
        catch = None if self.catch_ns is None or (end_ns is not None and self.catch_ns > end_ns) \
            else (self.catch_ns - t0) * 1e-9
        spans = self.timeline.spans(origin=t0, scale=1e-9, end=end_ns)
        series = RunSeries.from_states(t, states, [f[1] for f in forces], params=params,
                                       x_ref=x_ref, catch_time=catch, t_force=t_force,
                                       label=label, controllers=spans)
        if source == TRUE_STATE:
            contact = self.truth_contact or metrics.end_stop_touched(series.x, params.travel)
        elif self.hw_health_seen:
            contact = self.limit_flag
        else:
            contact = metrics.end_stop_touched(series.x, params.travel)
        return series, contact

    def first_fault(self, end_ns: int | None = None) -> str | None:
        """The first fault reported up to ``end_ns``, None if none."""
        faults = sorted(f for f in self.faults if end_ns is None or f[0] <= end_ns)
        return faults[0][1] if faults else None

    def falls_after_catch(self, end_ns: int | None = None) -> int | None:
        """How many ``fall`` events came after the first catch, up to ``end_ns``; None
        without any status (a bag without the manager's cannot tell)."""
        if not self.status_count:
            return None
        return metrics.falls_after_catch(
            (e for e in self.events if end_ns is None or e[0] <= end_ns), self.catch_ns)

    def longest_cycle_gap(self, end_ns: int | None = None) -> float | None:
        """The largest ``longest_cycle_gap_s`` reported up to ``end_ns`` (None if never)."""
        gaps = [g for ns, g in self.cycle_gaps if end_ns is None or ns <= end_ns]
        return max(gaps) if gaps else None

    def last_figures(self, end_ns: int | None = None) -> dict[str, float]:
        """The loop and plugin figures of the last status up to ``end_ns`` ({} if none)."""
        last: dict[str, float] = {}
        for ns, figures in self.figures:
            if end_ns is None or ns <= end_ns:
                last.update(figures)
        return last

    def summarize(self, *, params: CartPoleParameters, x_ref: float, lockstep: bool,
                  label: str = '', end_ns: int | None = None, fault: str | None = None,
                  window: float = metrics.WINDOW_S) -> tuple[RunSeries, dict[str, Any]]:
        """The series and the run summary (docs/reference/summary.md, "The run summary"); ``fault``
        overrides the reported one; ``window`` [s] is the final window it scores."""
        series, contact = self.build(params=params, x_ref=x_ref, lockstep=lockstep, label=label,
                                     end_ns=end_ns)
        summary = metrics.summarize(series.t, series.x, series.theta, x_ref=x_ref,
                                    catch_time=series.catch_time, end_stop_contact=contact,
                                    fault=fault or self.first_fault(end_ns),
                                    controllers=series.controllers,
                                    longest_cycle_gap_s=self.longest_cycle_gap(end_ns),
                                    swingup_law=self.swingup_law,
                                    force=series.force, t_force=series.t_force,
                                    falls_after_catch=self.falls_after_catch(end_ns),
                                    window=window)
        summary.update(self.last_figures(end_ns))
        return series, summary


def _float_or_none(text: str | None) -> float | None:
    try:
        return float(text) if text not in (None, '') else None
    except ValueError:
        return None


def _stamp_value_ns(text: str | None, fallback_ns: int) -> int:
    """A ``state_stamp`` value (seconds as a float, or ``sec.nanosec``) in ns."""
    if text:
        try:
            return int(round(float(text) * 1e9))
        except ValueError:
            pass
    return fallback_ns


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
    t0_ns: int = 0
    """The stamp [ns] of the series' t = 0 (0 in lockstep, else the first state sample)."""


def root_topics(reader, custom: Mapping[str, str]) -> dict[str, str]:
    """A rosbags reader's topics -> their root-namespace names: a bag recorded in a
    namespace (``/rig2/joint_states``) reads as one of the root (``/joint_states``);
    :mod:`cartpole_core.namespaces`."""
    names = [c.topic for c in reader.connections]
    namespace = bag_namespace(custom, names)
    return {name: graph_topic(name, namespace) for name in names}


def read_bag(path: str | Path) -> tuple[SeriesBuilder, dict[str, int]]:
    """Feed every relevant message of a bag into a :class:`SeriesBuilder`.

    Topics by their root-namespace names (:func:`root_topics`).
    """
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    path = Path(path)
    if not (path / 'metadata.yaml').is_file() and not path.is_file():
        raise FileNotFoundError(f'{path} is not a rosbag2 bag (no metadata.yaml); if its '
                                f'recording was cut short, run `cartpole bag repair {path}`')
    builder = SeriesBuilder()
    wanted = {TRUE_STATE, STATE, FORCE, STATUS, HW_HEALTH}
    with AnyReader([path], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        root = root_topics(reader, bag_custom_data(path))
        topics: dict[str, int] = {}
        for c in reader.connections:
            topics[root[c.topic]] = topics.get(root[c.topic], 0) + c.msgcount
        connections = [c for c in reader.connections if root[c.topic] in wanted]
        for connection, _, raw in reader.messages(connections=connections):
            topic = root[connection.topic]
            if connection.msgtype == 'diagnostic_msgs/msg/DiagnosticArray':
                stamp, statuses = parse_diagnostic_array(raw)
                for _, values in statuses:
                    if topic == STATUS:
                        builder.status(stamp, values)
                    else:
                        builder.hw_health(stamp, values)
            elif connection.msgtype == 'sensor_msgs/msg/JointState':
                stamp, _, position, velocity, effort = parse_joint_state(raw)
                builder.joint_state(topic, stamp, position, velocity, effort)
    return builder, topics


def run_end_ns(custom: Mapping[str, str]) -> int | None:
    """The stamp [ns] where the recorded run ended (custom_data ``run_end_ns``), None if unknown."""
    try:
        return int(custom['run_end_ns'])
    except (KeyError, ValueError):
        return None


def analyze_bag(path: str | Path, *, x_ref: float | None = None,
                params: CartPoleParameters | None = None, label: str = '',
                window: float | None = None) -> BagAnalysis:
    """Series and run summary of one recorded run.

    Parameters
    ----------
    path
        The bag directory (``metadata.yaml`` and the MCAP file).
    x_ref
        x* [m]; default: the bag's custom_data ``x_ref``, else mid-travel.
    params
        Nominal plant parameters (travel for the end-stop test, l, g, E*).
    window
        The final window the summary scores [s]; default: the bag's custom_data
        ``window_s`` (``cartpole run --window``), else :data:`metrics.WINDOW_S`.
    """
    path = Path(path)
    params = params or CartPoleParameters()
    custom = bag_custom_data(path)
    if x_ref is None:
        x_ref = float(custom['x_ref']) if 'x_ref' in custom else params.x_middle
    if window is None:
        window = _float_or_none(custom.get('window_s')) or metrics.WINDOW_S
    builder, topics = read_bag(path)
    lockstep = CLOCK in topics or custom.get('lockstep', '').lower() == 'true'
    series, summary = builder.summarize(params=params, x_ref=x_ref, lockstep=lockstep,
                                        label=label or run_label(path),
                                        end_ns=run_end_ns(custom),
                                        fault=custom.get('fault') or None, window=window)
    summary['recorder_missed'] = recorder_missed(custom)
    return BagAnalysis(path=path, series=series, summary=summary, source=builder.source,
                       topics=topics, controllers=dict(builder.controllers),
                       t0_ns=builder.t0_ns)


def recorder_missed(custom: Mapping[str, str]) -> int | None:
    """Messages the recorder missed (custom_data ``recorder_missed``); None if not counted."""
    try:
        return int(custom['recorder_missed'])
    except (KeyError, ValueError):
        return None


def run_label(path: Path) -> str:
    """A short name of a bag: its directory name, or its parent's for ``.../bag``."""
    path = Path(path).resolve()
    return path.parent.name if path.name == 'bag' else path.name


def comparison_table(analyses: Iterable[BagAnalysis]) -> list[str]:
    """Rows of a side-by-side table: one row a summary key, one column a bag."""
    analyses = list(analyses)
    labels = [a.series.label for a in analyses]
    keys = metrics.SUMMARY_KEYS + TABLE_EXTRA_KEYS
    key_width = max(len(k) for k in keys)
    widths = [max(len(label), 10) for label in labels]

    def cell(value) -> str:
        if isinstance(value, bool) or value is None:
            return 'null' if value is None else str(value)
        if isinstance(value, float):
            return f'{value:.4g}'
        return str(value)

    rows = [' '.join([f'{"":<{key_width}}'] + [f'{lb:>{w}}' for lb, w in zip(labels, widths)])]
    for key in keys:
        cells = [f'{cell(a.summary.get(key)):>{w}}' for a, w in zip(analyses, widths)]
        rows.append(' '.join([f'{key:<{key_width}}'] + cells))
    return rows
