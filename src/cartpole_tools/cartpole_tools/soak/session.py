"""A soak: the real-time graph run for a long time while a user's changes keep coming.

The graph is ``cartpole run --sim --processes --record`` (the default controllers,
:class:`cartpole_bringup.graph.graph.Graph`, one process a node). While it runs, every
``switch_every`` s the stabiliser is switched through the controller manager's
``set_parameters`` service (what ``ros2 param set`` calls), every ``restart_every`` s
the swing-up is restarted from hanging (the simulator's ``sim/reset`` service, what
``ros2 service call`` would do), and every ``sample_every`` s each process's resident
memory, open files and CPU time are read from /proc. The verdict (:func:`verdict`):
no fault, the pendulum up whenever it should be, the bag complete, memory growth after
``settle`` s at most :data:`MEMORY_LIMIT_MB_PER_H` (judged once at least
:data:`MIN_MEMORY_WINDOW_S` of samples follow ``settle``).
"""
from __future__ import annotations

import os
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable

from ..bench.procfs import cpu_seconds, open_files, rss_bytes
from .judge import UprightJudge, bag_verdict, memory_growth

MEMORY_LIMIT_MB_PER_H = 5.0
MIN_MEMORY_WINDOW_S = 600.0
"""Memory growth is judged only over at least this many seconds after ``settle``: over a
shorter window an allocator's step of a few MB extrapolates to tens of MB an hour."""
PROBE_PRIORITY = 10
"""SCHED_FIFO priority of this process: below the loop's (cartpole_core.realtime's 20)."""
COUNT_FROM_S = 2.0
"""Seconds after the start from which the bag is compared with what the probe saw."""
SOAK_PROCESS = 'cartpole soak'
"""This process: the graph's run monitor and the soak's probe (the instrument)."""


@dataclass
class SoakConfig:
    """What a soak does; times in wall seconds."""

    duration: float
    out: Path
    switch_every: float = 60.0
    restart_every: float = 600.0
    sample_every: float = 5.0
    settle: float = 300.0
    catch_timeout: float = 30.0
    stabilizers: tuple[str, ...] = ()
    """The stabilisers switched through in turn (empty: every registered one, the default
    first)."""


@dataclass
class ProcessSamples:
    """One process's /proc readings over the soak."""

    pid: int
    t_s: list[float] = field(default_factory=list)
    rss: list[int] = field(default_factory=list)
    fds: list[int] = field(default_factory=list)
    cpu_s: list[float] = field(default_factory=list)

    def take(self, now_s: float) -> None:
        rss, fds, cpu = rss_bytes(self.pid), open_files(self.pid), cpu_seconds(self.pid)
        if rss is None or fds is None or cpu is None:
            return  # gone: the graph reports the fault
        self.t_s.append(now_s)
        self.rss.append(rss)
        self.fds.append(fds)
        self.cpu_s.append(cpu)

    def summary(self, settle: float) -> dict:
        if not self.t_s:
            return {'pid': self.pid, 'samples': 0}
        span = self.t_s[-1] - self.t_s[0]
        after = [t for t in self.t_s if t >= settle]
        window = after[-1] - after[0] if len(after) > 1 else 0.0
        return {'pid': self.pid, 'samples': len(self.t_s),
                'rss_first_mb': self.rss[0] / 1e6, 'rss_last_mb': self.rss[-1] / 1e6,
                'rss_max_mb': max(self.rss) / 1e6,
                'growth_mb_per_h': memory_growth(self.t_s, self.rss, settle),
                'growth_window_s': window,
                'fds_first': self.fds[0], 'fds_last': self.fds[-1], 'fds_max': max(self.fds),
                'cpu_percent': 100.0 * (self.cpu_s[-1] - self.cpu_s[0]) / span if span else None}


def stabilizer_rotation(names: tuple[str, ...]) -> list[str]:
    """The stabilisers to switch through: ``names``, else every registered one, default first."""
    if names:
        return list(names)
    from cartpole_control.controller import STABILIZER
    from cartpole_control.manager import DEFAULT_CONTROLLERS
    from cartpole_control.registry import load_controllers

    default = DEFAULT_CONTROLLERS[STABILIZER]
    return [default] + sorted(n for n in load_controllers(STABILIZER) if n != default)


def bag_counts(bag: Path, windows: dict[str, dict]) -> dict[str, int]:
    """Messages per topic of the bag with a stamp in that topic's window (first..last ns)."""
    from mcap.reader import make_reader

    from cartpole_analysis.bags.repair import bag_files
    from cartpole_analysis.bags.writer import cdr_stamp_ns

    counts = {topic: 0 for topic in windows}
    for path in bag_files(bag):
        with path.open('rb') as f:
            for _, channel, message in make_reader(f).iter_messages(topics=list(windows)):
                w = windows[channel.topic]
                if w['first_ns'] is not None and \
                        w['first_ns'] <= cdr_stamp_ns(message.data) <= w['last_ns']:
                    counts[channel.topic] += 1
    return counts


def run_soak(config: SoakConfig, should_stop: Callable[[], bool] = lambda: False,
             say: Callable[[str], None] = lambda text: None) -> dict:
    """Run the soak of ``config``; the results (see :func:`verdict`). Raises
    GraphError when the graph does not start."""
    import rclpy
    from rclpy.context import Context
    from rclpy.signals import SignalHandlerOptions

    from cartpole_analysis.bags.check import damage, read_metadata
    from cartpole_bringup.graph.graph import Graph, GraphSpec
    from cartpole_core import realtime
    from cartpole_core.middleware import keep_on_this_host

    from .probe import SoakProbe

    keep_on_this_host()
    rotation = stabilizer_rotation(config.stabilizers)
    config.out.mkdir(parents=True, exist_ok=True)
    bag = config.out / 'bag'
    spec = GraphSpec(plant='sim', processes=True, record=bag,
                     parameters={'controller_manager': {'stabilizer': rotation[0]}},
                     custom_data={'plant': 'sim', 'lockstep': 'false', 'command': 'cartpole soak'})
    judge = UprightJudge(catch_timeout=config.catch_timeout)
    context = Context()
    rclpy.init(args=['cartpole_soak', '--ros-args', '--log-level', 'warn'], context=context,
               signal_handler_options=SignalHandlerOptions.NO)
    events: list[dict] = []
    samples: dict[str, ProcessSamples] = {}
    graph = probe = hygiene = None
    elapsed = 0.0
    try:
        graph = Graph(spec, context, should_stop=should_stop, report=say)
        probe = SoakProbe(judge, time.monotonic(), context=context)
        graph.executor.add_node(probe)
        graph.start()
        # This process is the instrument: at a real-time priority below the loop's, so that
        # a loaded machine delays neither its counts nor its service calls and it never
        # preempts the loop it measures.
        hygiene = realtime.enter_loop(PROBE_PRIORITY, what='cartpole soak',
                                      log=lambda text: None, warn=say)
        probe.origin = time.monotonic()
        judge.restart(0.0, from_stamp_ns=0)
        graph.spin_until(lambda: probe.now_s() >= COUNT_FROM_S, None)
        probe.restart_counts()
        samples = {name: ProcessSamples(proc.pid) for name, proc in graph.processes.items()}
        samples[SOAK_PROCESS] = ProcessSamples(os.getpid())
        say(f'graph up ({", ".join(f"{n} pid {s.pid}" for n, s in samples.items())}); '
            f'soaking for {config.duration:g} s')
        next_switch, next_restart, next_sample = (config.switch_every, config.restart_every, 0.0)
        turn = 0
        while graph.fault is None and not should_stop():
            now = probe.now_s()
            if now >= config.duration:
                break
            if now >= next_sample:
                next_sample += config.sample_every
                for s in samples.values():
                    s.take(now)
            if now >= next_restart:
                next_restart += config.restart_every
                events.append(_restart(graph, probe, judge, now))
                say(f'{now:7.1f} s restart: {events[-1]["reply"]}')
            if now >= next_switch:
                next_switch += config.switch_every
                turn += 1
                events.append(_switch(graph, rotation[turn % len(rotation)], now))
                say(f'{now:7.1f} s stabilizer -> {events[-1]["value"]}: '
                    f'{"ok" if events[-1]["ok"] else events[-1]["reply"]}')
            wake = min(next_sample, next_switch, next_restart, config.duration)
            graph.spin_until(lambda: probe.now_s() >= wake, None)
            realtime.collect_when_idle()
        elapsed = probe.now_s()
        judge.ended = True
        for s in samples.values():
            s.take(elapsed)
    finally:
        judge.ended = True
        warnings = graph.close() if graph is not None else []
        if hygiene is not None:
            hygiene.leave()
        if probe is not None:
            probe.destroy_node()
        rclpy.try_shutdown(context=context)
    info, _ = read_metadata(bag)
    custom = (info or {}).get('custom_data') or {}
    missed = custom.get('recorder_missed')
    published = probe.published
    bag_figures = bag_verdict(published, bag_counts(bag, published), damage(bag),
                              None if missed is None else int(missed))
    # published before the recorder had discovered the publisher: reported, not judged
    # (the bag is compared with the probe from COUNT_FROM_S on)
    at_start = custom.get('recorder_missed_at_start')
    bag_figures['recorder_missed_at_start'] = None if at_start is None else int(at_start)
    return verdict(config, elapsed, graph.fault, warnings, events, judge, probe, samples,
                   bag_figures, bag)


def _switch(graph, name: str, now: float) -> dict:
    results = graph.set_parameters('controller_manager', {'stabilizer': name}, timeout=5.0)
    ok = all(r[0] for r in results)
    return {'t_s': round(now, 3), 'what': 'stabilizer', 'value': name, 'ok': ok,
            'reply': '; '.join(r[1] for r in results if r[1])}


def _restart(graph, probe, judge: UprightJudge, now: float) -> dict:
    from std_srvs.srv import Trigger

    judge.restart(now)
    client = probe.reset_client
    if not graph.spin_until(client.service_is_ready, 5.0):
        return {'t_s': round(now, 3), 'what': 'restart', 'ok': False,
                'reply': f'{client.service_name} not available'}
    future = client.call_async(Trigger.Request())
    if not graph.spin_until(future.done, 5.0) or future.result() is None:
        client.remove_pending_request(future)
        return {'t_s': round(now, 3), 'what': 'restart', 'ok': False, 'reply': 'no answer'}
    return {'t_s': round(now, 3), 'what': 'restart', 'ok': bool(future.result().success),
            'reply': future.result().message}


def verdict(config: SoakConfig, elapsed: float, fault: str | None, warnings: list[str],
            events: list[dict], judge: UprightJudge, probe, samples: dict[str, ProcessSamples],
            bag: dict, bag_path: Path) -> dict:
    """Everything measured, and ``ok``: no fault, up, the bag complete, memory within bounds."""
    processes = {name: s.summary(config.settle) for name, s in samples.items()}
    growth = {name: p.get('growth_mb_per_h') for name, p in processes.items()}
    judged = all(p.get('growth_window_s', 0.0) >= MIN_MEMORY_WINDOW_S for p in processes.values())
    memory_ok = (all(g is not None and g <= MEMORY_LIMIT_MB_PER_H for g in growth.values())
                 if judged and processes else None)
    refused = [e for e in events if not e['ok']]
    faults = ([fault] if fault else []) + [f'{e["what"]} {e.get("value", "")} refused: '
                                           f'{e["reply"]}' for e in refused]
    if probe.modes.get('fault'):
        faults.append(f'controller manager in fault for {probe.modes["fault"]} cycles')
    faults += [f'/diagnostics ERROR x{n}: {k}' for k, n in probe.diagnostic_errors.items()]
    up = judge.verdict(elapsed)
    complete = elapsed >= config.duration - 1.0
    ok = (complete and not faults and up['up_ok'] and bag['bag_ok']
          and memory_ok is not False)
    return {'ok': ok, 'config': {k: str(v) if isinstance(v, Path) else v
                                 for k, v in asdict(config).items()},
            'elapsed_s': elapsed, 'ran_to_the_end': complete, 'faults': faults,
            'warnings': warnings, 'switches': sum(e['what'] == 'stabilizer' for e in events),
            'restarts': sum(e['what'] == 'restart' for e in events), 'events': events,
            **up, **bag, 'bag': str(bag_path), 'memory_ok': memory_ok,
            'memory_limit_mb_per_h': MEMORY_LIMIT_MB_PER_H, 'processes': processes,
            'longest_sample_gap_s': probe.longest_sample_gap_s,
            'longest_cycle_gap_s': probe.manager_longest_cycle_gap_s,
            'controller_modes': probe.modes, 'load_average': list(os.getloadavg())}
