"""Kill one node of a running ``cartpole run`` with SIGKILL and report what happened.

Usage (docs/bench/faults/measure.sh)::

    python killnode.py NODE OUTDIR [--after S] [-- <cartpole run options>]

NODE is ``sim``, ``ekf``, ``controller_manager``, ``recorder``, ``hw_bridge``
(a child of ``cartpole run --processes``) or ``run`` (the whole run). It is
killed once the graph's state topic has spanned S seconds of stamps. Prints
one JSON object: exit code, wall seconds from the kill to the run's exit, the
last state stamp seen before the kill, the kill's monotonic time, output tails.
"""
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

EXECUTABLES = {'sim': 'sim_node', 'ekf': 'ekf_node', 'controller_manager': 'controller_manager',
               'recorder': 'recorder', 'hw_bridge': 'hw_bridge', 'run': None}


def children(pid: int) -> list[int]:
    try:
        return [int(p) for p in Path(f'/proc/{pid}/task/{pid}/children').read_text().split()]
    except OSError:
        return []


def command_line(pid: int) -> str:
    try:
        return Path(f'/proc/{pid}/cmdline').read_bytes().replace(b'\0', b' ').decode()
    except OSError:
        return ''


def main() -> None:
    node, out = sys.argv[1], Path(sys.argv[2])
    rest, after = sys.argv[3:], 3.0
    if rest[:1] == ['--after']:
        after, rest = float(rest[1]), rest[2:]
    if rest[:1] == ['--']:
        rest = rest[1:]
    run_args = rest or ['--sim', '--processes', '--lockstep', '--duration', '20']
    out.mkdir(parents=True, exist_ok=True)

    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from sensor_msgs.msg import JointState

    context = Context()
    rclpy.init(context=context)
    probe = Node('_kill_probe', context=context)
    seen: list[float] = []
    topic = '/cartpole/true_state' if '--sim' in run_args else '/cartpole/state'
    probe.create_subscription(JointState, topic, lambda m: seen.append(
        m.header.stamp.sec + m.header.stamp.nanosec * 1e-9), 200)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(probe)
    proc = subprocess.Popen(['cartpole', 'run', *run_args, '--record', str(out), '--json'],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    start = time.monotonic()
    while (not seen or seen[-1] - seen[0] < after) and time.monotonic() - start < 120:
        executor.spin_once(timeout_sec=0.05)
    exe = EXECUTABLES[node]
    victim = proc.pid if exe is None else next(
        p for p in children(proc.pid) if f'/{exe} ' in command_line(p) + ' ')
    last_seen = seen[-1]
    os.kill(victim, signal.SIGKILL)
    killed = time.monotonic()
    try:
        stdout, stderr = proc.communicate(timeout=90)
    except subprocess.TimeoutExpired:
        proc.kill()
        stdout, stderr = proc.communicate()
    exited = time.monotonic() - killed
    probe.destroy_node()
    rclpy.try_shutdown(context=context)
    print(json.dumps({'kill_monotonic': killed, 'node': node, 'rc': proc.returncode,
                      'exit_after_kill_s': round(exited, 2), 'last_seen_stamp_s': last_seen,
                      'stdout_tail': stdout[-600:], 'stderr_tail': stderr[-1500:]}, indent=1))


if __name__ == '__main__':
    main()
