"""`cartpole run --sim` in real time (no --lockstep), the first thing a user runs.

(The real-time run with a recorder is test_viewer_live.py's: it records and serves a viewer.)

The verdict must be the plant's: the cart starts resting against the left
stop, where round-off leaves its position at about -1e-22 m before the first
command; that is not an end-stop contact (docs/reference/summary.md, "The run summary": `end_stop_contact`).
"""
import json
import signal
import subprocess
import sys
import time

import pytest

pytestmark = [pytest.mark.ros, pytest.mark.slow]


def test_real_time_sim_run_with_disturbances_still_succeeds():
    # The scenario's disturbances reach the real-time simulator node: 4 ms of delay with
    # 2 ms of jitter on top of the graph's own latency, 5 % lost samples and a 0.5 N s push
    # on the balancing cart at 8 s, 1 s before the verdict's window (the last 3 s of 12: the
    # window starts at 9 s, as the default 10 s window of a 19 s run); the default pair
    # still ends balanced.
    run = subprocess.run(
        [sys.executable, '-m', 'cartpole_bringup.cli', 'run', '--sim', '--duration', '12',
         '--window', '3', '--delay', '0.004', '--jitter', '0.002', '--drop', '0.05', '--push', '8:cart:5:0.1',
         '--json'],
        capture_output=True, text=True, timeout=180)
    assert run.returncode == 0, run.stderr[-3000:]
    summary = json.loads(run.stdout.strip().splitlines()[-1])
    assert summary['catch_time_s'] is not None and summary['catch_time_s'] < 10.0, summary
    assert summary['end_stop_contact'] is False, summary
    assert summary['success'] is True, summary
    assert summary['falls_after_catch'] == 0, summary  # counted on the graph too, not null
    assert summary['recorder_missed'] is None, summary  # no bag, nothing counted


def test_the_real_time_graph_keeps_the_pendulum_after_the_grids_6_ns_cart_push():
    # The robustness grid's 6 N s level (60 N for 0.1 s) on the balancing cart at 6 s, with
    # encoder noise: the ekf node's push Q (its parameter push_q_force) shows the push to the
    # manager within 20-25 ms, which keeps it; with q_force alone 9 of 12 offline seeds of
    # this run were kept. The verdict's window is the last 3 s of 14, 5 s after the push.
    run = subprocess.run(
        [sys.executable, '-m', 'cartpole_bringup.cli', 'run', '--sim', '--noise', '--seed', '0',
         '--duration', '14', '--window', '3', '--push', '6:cart:60:0.1', '--json'],
        capture_output=True, text=True, timeout=180)
    assert run.returncode == 0, run.stderr[-3000:]
    summary = json.loads(run.stdout.strip().splitlines()[-1])
    assert summary['catch_time_s'] is not None and summary['catch_time_s'] < 6.0, summary
    assert summary['falls_after_catch'] == 0 and summary['end_stop_contact'] is False, summary
    assert summary['success'] is True, summary


def test_a_real_time_run_stalled_again_and_again_still_succeeds():
    """A loaded host deschedules the one process (sim, EKF and controller manager): here
    SIGSTOP for 40 ms every 0.3 s, catch transient included, for the whole run. The
    plant runs on its own sample clock through the stalls and the manager counts only
    its running time as silence, so the run is caught and balanced as without them.

    With the default controllers. energy_saturated's swing-up sends the cart back
    towards the stop it started near at up to 1.5-1.7 m/s, along the rail guard's
    braking envelope; a stall that load stretches to 60 ms there holds its 20-37 N
    for 12 samples, more than the limiter's 5 cm reserve allows for, and the guard
    trips (3 of 6 such runs beside three busy processes: the guard doing its work).
    The default swing-up peaks at 1.15-1.17 m/s (8 of 8 under the same load)."""
    run = subprocess.Popen(
        [sys.executable, '-m', 'cartpole_bringup.cli', 'run', '--sim', '--duration', '9',
         '--window', '3', '--json'],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    stalls = 0
    try:
        while run.poll() is None:
            time.sleep(0.3)       # the stimulus: the process runs 0.3 s, then stalls
            run.send_signal(signal.SIGSTOP)
            time.sleep(0.04)
            run.send_signal(signal.SIGCONT)
            stalls += 1
    except ProcessLookupError:
        pass
    finally:
        if run.poll() is None:
            run.send_signal(signal.SIGCONT)
    out, err = run.communicate(timeout=180)
    assert run.returncode == 0, err[-3000:]
    summary = json.loads(out.strip().splitlines()[-1])
    assert stalls >= 30 and summary['longest_cycle_gap_s'] >= 0.04, (stalls, summary)
    assert summary['fault'] is None, (summary, err[-3000:])
    assert [c['kind'] for c in summary['controllers']] == ['swingup', 'stabilizer'], summary
    assert summary['success'] is True and summary['end_stop_contact'] is False, summary
