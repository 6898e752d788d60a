"""Stalls under load (docs/benchmarks.md): hardware start-ups and stale-state faults with CPU burners.

    python docs/bench/stalls/measure.py hw N [--processes] [--burners K] [--stabilizer NAME]
    python docs/bench/stalls/measure.py sim SECONDS [--burners K]         # one long run

Starts K (default 2) CPU-bound processes (``while True: pass``, normal priority),
then either N times: ``cartpole emulate`` and ``cartpole run --hw --hw-arm
--duration 6`` (the default controllers unless ``--stabilizer NAME``) (one process, or ``--processes``), watching
``/cartpole/hw/health``: a start-up succeeds when the bridge arms and no fault
disarms it before the run's own stop; or one ``cartpole run --sim --duration
SECONDS`` counting ``fault: stale state``. One JSON line per trial, with the
load average. Needs `source env.sh` and a free ROS_DOMAIN_ID; it measures wall
clock behaviour, so nothing else real-time should run meanwhile.
"""
import json
import os
import re
import signal
import subprocess
import sys
import threading
import time

HERE = os.environ.get('STALLS_OUT', '/tmp/cartpole-stalls')


def burners(k):
    return [subprocess.Popen([sys.executable, '-c', 'while True: pass']) for _ in range(k)]


def stop(procs):
    """The burners hold no state: kill them."""
    for p in procs:
        p.kill()
        p.wait()


def load():
    return open('/proc/loadavg').read().split()[:3]


class HealthWatch:
    """Listens to /cartpole/hw/health: when armed, first fault."""

    def __init__(self):
        import rclpy
        from rclpy.context import Context
        from diagnostic_msgs.msg import DiagnosticArray
        self.rclpy = rclpy
        self.context = Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node('i11b_watch', context=self.context)
        self.events = []
        self.t0 = time.monotonic()
        self.armed_at = None
        self.fault = None
        self.node.create_subscription(DiagnosticArray, '/cartpole/hw/health', self._cb, 10)
        self.gaps = {}
        self.node.create_subscription(DiagnosticArray, '/cartpole/controller_status', self._status, 100)
        self.node.create_subscription(DiagnosticArray, '/cartpole/ekf/health', self._ekf, 10)
        from rclpy.executors import SingleThreadedExecutor
        self.ex = SingleThreadedExecutor(context=self.context)
        self.ex.add_node(self.node)
        self.stop_flag = False
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self):
        while not self.stop_flag:
            self.ex.spin_once(timeout_sec=0.1)

    def _status(self, msg):
        for s in msg.status:
            for kv in s.values:
                if kv.key == 'longest_cycle_gap_s':
                    self.gaps['manager'] = round(float(kv.value), 3)

    def _ekf(self, msg):
        for s in msg.status:
            for kv in s.values:
                if kv.key == 'longest_cycle_gap_s':
                    self.gaps['ekf'] = round(float(kv.value), 3)

    def _cb(self, msg):
        for s in msg.status:
            v = {kv.key: kv.value for kv in s.values}
            if 'longest_cycle_gap_s' in v and self.fault is None:
                self.gaps['hw'] = round(float(v['longest_cycle_gap_s']), 3)
            t = time.monotonic() - self.t0
            if v.get('armed') == 'true' and self.armed_at is None:
                self.armed_at = t
            if v.get('faults', '0') != '0' and self.fault is None:
                self.fault = (round(t, 2), v.get('last_error'), v.get('armed'))

    def close(self):
        self.stop_flag = True
        self.thread.join()
        self.ex.shutdown()
        self.node.destroy_node()
        self.rclpy.try_shutdown(context=self.context)


def hw_trial(i, processes, duration):
    link = f'{HERE}/emu{i}'
    emu = subprocess.Popen(['cartpole', 'emulate', '--link', link], stdout=subprocess.PIPE,
                           stderr=subprocess.STDOUT, text=True, start_new_session=True)
    first = emu.stdout.readline()
    assert 'port:' in first, first
    watch = HealthWatch()
    cmd = ['cartpole', 'run', '--hw', '--port', link, '--hw-arm', '--duration', str(duration),
           '--json', '--log-level', 'info'] + (['--processes'] if processes else []) + \
        (['--stabilizer', sys.argv[sys.argv.index('--stabilizer') + 1]]
         if '--stabilizer' in sys.argv else [])
    t0 = time.monotonic()
    run = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    wall = time.monotonic() - t0
    watch.close()
    os.killpg(emu.pid, signal.SIGINT)
    out, _ = emu.communicate(timeout=10)
    try:
        summary = json.loads(run.stdout.strip().splitlines()[-1])
    except (IndexError, json.JSONDecodeError):
        summary = {}
    with open(f'{HERE}/hw_{"p" if processes else "o"}_{i}.err', 'w') as f:
        f.write(run.stderr)
    fault = watch.fault
    # a fault after the run's own stop (disarm) does not count: the run lasts `duration` s
    ok = watch.armed_at is not None and (fault is None or fault[0] > watch.armed_at + duration)
    return dict(trial=i, ok=ok, armed_at=watch.armed_at, fault=fault, rc=run.returncode,
                catch=summary.get('catch_time_s'), success=summary.get('success'),
                gap=summary.get('longest_cycle_gap_s'), gaps=watch.gaps, wall=round(wall, 1),
                emulator=out.strip().splitlines()[-1:])


def sim_run(seconds, processes):
    cmd = ['cartpole', 'run', '--sim', '--duration', str(seconds), '--json', '--log-level', 'info'] + \
        (['--processes'] if processes else [])
    run = subprocess.run(cmd, capture_output=True, text=True, timeout=seconds + 300)
    with open(f'{HERE}/sim_{seconds}.err', 'w') as f:
        f.write(run.stderr)
    stale = len(re.findall(r'fault: stale state', run.stderr))
    faults = re.findall(r'fault: [^;\n]*', run.stderr)
    try:
        summary = json.loads(run.stdout.strip().splitlines()[-1])
    except (IndexError, json.JSONDecodeError):
        summary = {}
    return dict(stale_faults=stale, faults=faults[:10], rc=run.returncode,
                summary={k: summary.get(k) for k in ('catch_time_s', 'success', 'theta_amp_deg',
                                                     'x_err_max_m', 'longest_cycle_gap_s', 'fault')})


def main():
    os.makedirs(HERE, exist_ok=True)
    what = sys.argv[1]
    n = int(sys.argv[2])
    processes = '--processes' in sys.argv
    k = int(sys.argv[sys.argv.index('--burners') + 1]) if '--burners' in sys.argv else 2
    duration = 6
    hot = burners(k)
    time.sleep(1.0)
    results = []
    try:
        print('load before', load(), flush=True)
        if what == 'hw':
            for i in range(n):
                r = hw_trial(i, processes, duration)
                r['load'] = load()
                print(json.dumps(r), flush=True)
                results.append(r)
            print('ok', sum(r['ok'] for r in results), 'of', n, flush=True)
        else:
            r = sim_run(n, processes)
            r['load'] = load()
            print(json.dumps(r), flush=True)
    finally:
        stop(hot)


if __name__ == '__main__':
    main()
