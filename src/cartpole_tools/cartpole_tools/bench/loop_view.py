"""The live view's cost to the loop, for ``cartpole bench loop --view ROUNDS``.

A viewer that slows the loop would show in the loop's tail latency, and the
tail latency on a shared machine moves with the machine's load from one
minute to the next. So the cost is measured as alternating pairs of runs on
about the same machine state: the graph alone (``cartpole run --sim``), then
the graph with its live view (``cartpole run --sim --view``: the ``viewer``
process fed by the ``viewer_tap`` node) and a Foxglove WebSocket client
subscribed to every viewer channel (``python -m cartpole_analysis.viewer.client``,
its own process), the load a user watching the run puts on it. The median of
the pairs' p99 ratios is the viewer's cost; the same probe as
:mod:`cartpole_tools.bench.loop_probe` measures both.
"""
from __future__ import annotations

import socket
from typing import Any

import numpy as np

from .loop_probe import WARMUP_S, graph_cmds, graph_labels, measure

SAMPLE_TOPIC = '/joint_states'
COMMAND_TOPIC = '/cartpole/force_command'


def _free_port() -> int:
    """A TCP port that is free now (for the viewer of the run to bind)."""
    with socket.socket() as sock:
        sock.bind(('127.0.0.1', 0))
        return sock.getsockname()[1]


def view_rounds(mode: str, executor: str, duration: float, rounds: int,
                warmup: float = WARMUP_S) -> dict[str, Any]:
    """``rounds`` pairs (alone, with the view) of ``duration`` s each; returns
    ``view_rounds`` (a list of ``{graph, graph_view, p99_ratio}``) and their median
    ``p99_ratio_view`` (None when no pair has both p99s)."""
    out = []
    for _ in range(rounds):
        alone = measure(graph_cmds(mode, duration, executor), SAMPLE_TOPIC, COMMAND_TOPIC,
                         duration, graph_labels(mode), warmup)
        port = _free_port()
        viewed = measure(graph_cmds(mode, duration, executor, port), SAMPLE_TOPIC,
                          COMMAND_TOPIC, duration, graph_labels(mode), warmup,
                          viewer_url=f'ws://127.0.0.1:{port}')
        out.append({'graph': alone, 'graph_view': viewed,
                    'p99_ratio': (viewed['p99_ms'] / alone['p99_ms'])
                    if viewed['p99_ms'] and alone['p99_ms'] else None})
    ratios = [r['p99_ratio'] for r in out if r['p99_ratio'] is not None]
    return {'view_rounds': out,
            'p99_ratio_view': float(np.median(ratios)) if ratios else None}


def _cpu(stats: dict[str, Any], name: str) -> str:
    value = stats['cpu_percent'].get(name)
    return '-' if value is None else f'{value:.0f}'


def markdown(results: dict[str, Any], runs: list[tuple[str, str]], duration: float) -> str:
    """The pairs as a markdown table (after :func:`cartpole_tools.bench.loop`'s)."""
    md = [f"\nThe viewer's cost: alternating pairs of {duration:g} s runs, the graph alone, "
          'then the graph with `--view` (the viewer in its own process at idle priority, fed '
          'by the `viewer_tap` node) and a Foxglove WebSocket client subscribed to every '
          'viewer channel.\n',
          '| mode | executor | round | p99 alone [ms] | p99 with viewer [ms] | ratio '
          '| p50 alone / with [ms] | missed cycles alone / with '
          '| CPU of cartpole run alone / with [%] | CPU of the viewer [%] | scenes received |',
          '|' + '---|' * 11]
    for mode, ex in runs:
        r = results[mode][ex]
        if not r.get('view_rounds'):
            continue
        graph = graph_labels(mode)[0]
        for k, pair in enumerate(r['view_rounds'], 1):
            a, v = pair['graph'], pair['graph_view']
            ratio = '-' if pair['p99_ratio'] is None else f'{pair["p99_ratio"]:.2f}'
            scenes = v.get('viewer_messages', {}).get('/cartpole/view/scene', 0)
            md.append(f'| {mode} | {ex} | {k} | {a["p99_ms"]:.3f} | {v["p99_ms"]:.3f} | {ratio} '
                      f'| {a["p50_ms"]:.3f} / {v["p50_ms"]:.3f} '
                      f'| {a["missed_cycles"]} / {v["missed_cycles"]} '
                      f'| {_cpu(a, graph)} / {_cpu(v, graph)} | {_cpu(v, "viewer")} | {scenes} |')
        ratio = r['p99_ratio_view']
        md.append(f'| {mode} | {ex} | median ratio | | | '
                  f'{"-" if ratio is None else f"{ratio:.2f}"} | | | | | |')
    return '\n'.join(md) + '\n'
