"""Real-time runs whose process is stalled again and again, as a loaded host stalls it.

    python docs/bench/realtime/stalled_runs.py N STOP_S PERIOD_S -- CARTPOLE_RUN_ARGS...

Starts ``cartpole run --sim --json CARTPOLE_RUN_ARGS`` (one process: simulator,
EKF and controller manager stall together, as they do when the machine
deschedules the process) N times, each with a fresh plan cache, and from 2.5 s
after its start until 8 s later stops it with SIGSTOP for STOP_S every PERIOD_S
(SIGCONT after each). Prints one JSON line per run: the summary's verdict
figures, the controllers that ran, and the number of stalls.
"""
import json
import os
import signal
import subprocess
import sys
import tempfile
import time

KEYS = ('success', 'catch_time_s', 'theta_amp_deg', 'x_err_max_m', 'fault',
        'end_stop_contact', 'longest_cycle_gap_s', 'swingup_law')


def stalled_run(stop: float, period: float, argv: list[str]) -> dict:
    env = dict(os.environ, CARTPOLE_CACHE_DIR=tempfile.mkdtemp(prefix='stalled_'))
    run = subprocess.Popen(['cartpole', 'run', '--sim', '--json', *argv], env=env,
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    stalls = 0
    time.sleep(2.5)
    until = time.monotonic() + 8.0
    try:
        while time.monotonic() < until and run.poll() is None:
            time.sleep(period)
            run.send_signal(signal.SIGSTOP)
            time.sleep(stop)
            run.send_signal(signal.SIGCONT)
            stalls += 1
    finally:
        if run.poll() is None:
            run.send_signal(signal.SIGCONT)
    out, err = run.communicate(timeout=600)
    try:
        summary = json.loads(out.strip().splitlines()[-1])
    except (IndexError, ValueError):
        return {'error': err[-2000:], 'stalls': stalls}
    return {**{k: summary.get(k) for k in KEYS},
            'controllers': len(summary.get('controllers') or []), 'stalls': stalls}


def main() -> int:
    n, stop, period = int(sys.argv[1]), float(sys.argv[2]), float(sys.argv[3])
    argv = sys.argv[4:]
    if argv[:1] == ['--']:
        argv = argv[1:]
    for _ in range(n):
        print(json.dumps(stalled_run(stop, period, argv)), flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
