"""(docs/bench/faults, see measure.sh) Kill one node of a running `cartpole run` and report what happened.

usage: python killnode.py NODE OUTDIR [--after S] [-- cartpole run args...]
"""
import json, os, signal, subprocess, sys, time
from pathlib import Path

node, out = sys.argv[1], Path(sys.argv[2])
after = 3.0
rest = sys.argv[3:]
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

ctx = Context(); rclpy.init(context=ctx)
probe = Node('kill_probe', context=ctx)
seen = []
topic = '/cartpole/true_state' if '--sim' in run_args else '/cartpole/state'
probe.create_subscription(JointState, topic, lambda m: seen.append(m.header.stamp.sec + m.header.stamp.nanosec * 1e-9), 200)
ex = SingleThreadedExecutor(context=ctx); ex.add_node(probe)
cmd = ['cartpole', 'run', *run_args, '--record', str(out), '--json']
proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)

def children(pid):
    try:
        return [int(p) for p in Path(f'/proc/{pid}/task/{pid}/children').read_text().split()]
    except OSError:
        return []

def cmdline(pid):
    try:
        return Path(f'/proc/{pid}/cmdline').read_bytes().replace(b'\0', b' ').decode()
    except OSError:
        return ''

t_start = time.monotonic()
while (not seen or seen[-1] - seen[0] < after) and time.monotonic() - t_start < 120:
    ex.spin_once(timeout_sec=0.05)
exe = {'sim': 'sim_node', 'ekf': 'ekf_node', 'controller_manager': 'controller_manager',
       'recorder': 'recorder', 'hw_bridge': 'hw_bridge', 'run': None}[node]
if exe is None:
    victim = proc.pid
else:
    victim = next(p for p in children(proc.pid) if f'/{exe} ' in cmdline(p) + ' ')
last_seen = seen[-1]
os.kill(victim, signal.SIGKILL)
t_kill = time.monotonic()
kill_monotonic = t_kill
try:
    stdout, stderr = proc.communicate(timeout=90)
except subprocess.TimeoutExpired:
    proc.kill(); stdout, stderr = proc.communicate()
t_exit = time.monotonic() - t_kill
probe.destroy_node(); rclpy.try_shutdown(context=ctx)
print(json.dumps({'kill_monotonic': kill_monotonic, 'node': node, 'rc': proc.returncode, 'exit_after_kill_s': round(t_exit, 2),
                  'last_seen_stamp_s': last_seen, 'stdout_tail': stdout[-600:], 'stderr_tail': stderr[-1500:]}, indent=1))
