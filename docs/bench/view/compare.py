"""Which part of the live view costs the loop its tail latency (docs/benchmarks.md, the live view).

    python docs/bench/view/compare.py [ROUNDS] [SECONDS]

ROUNDS (default 2) rounds of four real-time runs of SECONDS (default 20) each,
measured by ``cartpole bench loop``'s probe and statistics
(:func:`cartpole_tools.bench.loop._measure`), one after the other so that
they see about the same machine:

- ``alone``: ``cartpole run --sim``;
- ``view``: ``cartpole run --sim --view`` (the ``viewer_tap`` node in the
  graph's process, the samples over a local socket to the viewer process) and
  a Foxglove WebSocket client (``python -m cartpole_analysis.viewer.client``)
  subscribed to every channel, at normal priority;
- ``view_idle_client``: the same with the client at ``SCHED_IDLE`` (what the
  viewer costs without the client's own CPU);
- ``standalone``: ``cartpole run --sim`` next to the standalone ``viewer``
  executable (a remote DDS reader of ``/cartpole/state``,
  ``/cartpole/true_state`` and ``/cartpole/controller_status``) and the client.

One JSON line a run, with the load average. Needs ``source env.sh`` and a free
ROS_DOMAIN_ID; real time: run it under ``flock /work/wt/rt.lock``.
"""
import json
import os
import sys

import cartpole_tools.bench.loop_probe as bench_loop
from cartpole_tools.bench.loop_view import COMMAND_TOPIC, SAMPLE_TOPIC, _free_port
from cartpole_analysis.viewer.process import viewer_executable

KINDS = ('alone', 'view', 'view_idle_client', 'standalone')
_normal_client = bench_loop.start_viewer_client


def _idle_client(url):
    client = _normal_client(url)
    os.sched_setscheduler(client.pid, os.SCHED_IDLE, os.sched_param(0))
    return client


def run(kind: str, seconds: float) -> dict:
    port = _free_port()
    url = f'ws://127.0.0.1:{port}'
    bench_loop.start_viewer_client = _idle_client if kind == 'view_idle_client' \
        else _normal_client
    graph = bench_loop._graph_cmds('single', seconds, 'events')
    if kind == 'alone':
        return bench_loop._measure(graph, SAMPLE_TOPIC, COMMAND_TOPIC, seconds,
                                   ['cartpole run'])
    if kind == 'standalone':
        viewer = [str(viewer_executable()), '--ros-args', '--log-level', 'warn',
                  '-p', 'host:=127.0.0.1', '-p', f'port:={port}']
        return bench_loop._measure(graph + [viewer], SAMPLE_TOPIC, COMMAND_TOPIC, seconds,
                                   ['cartpole run', 'viewer'], viewer_url=url)
    return bench_loop._measure(bench_loop._graph_cmds('single', seconds, 'events', port),
                               SAMPLE_TOPIC, COMMAND_TOPIC, seconds, ['cartpole run'],
                               viewer_url=url)


def main() -> int:
    rounds = int(sys.argv[1]) if len(sys.argv) > 1 else 2
    seconds = float(sys.argv[2]) if len(sys.argv) > 2 else 20.0
    for k in range(rounds):
        for kind in KINDS:
            r = run(kind, seconds)
            print(json.dumps({'round': k + 1, 'kind': kind, 'load': os.getloadavg(),
                              'p50_ms': r['p50_ms'], 'p99_ms': r['p99_ms'], 'max_ms': r['max_ms'],
                              'missed': r['missed_cycles'], 'cpu': r['cpu_percent'],
                              'scenes': r.get('viewer_messages', {}).get('/cartpole/view/scene')}),
                  flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
