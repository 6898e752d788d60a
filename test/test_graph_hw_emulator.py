"""`cartpole run --hw` on the serial bridge, pointed at the device emulator on a real
pseudo-terminal: the whole graph swings up and balances through the Joint protocol
(SPEC section 4). Real time: the emulator paces itself by the wall clock like the firmware, and the
bridge's 50 ms host watchdog disarms on any stall of the control loop, so this test
runs the graph without the in-process recorder (recording is tested in lockstep).
It runs the defaults, what a user runs first: no --swingup, no --stabilizer (the
default LQG no longer chatters by tens of newtons, so it is the one tested here).
"""
import json
import os
import signal
import subprocess
import sys

import pytest

pytestmark = [pytest.mark.ros, pytest.mark.slow]


def test_cartpole_run_hw_against_the_emulator_succeeds(tmp_path):
    link = tmp_path / 'cartpole-emu'
    log = open(tmp_path / 'emulator.log', 'w')
    emulator = subprocess.Popen(
        [sys.executable, '-m', 'cartpole_bringup.cli', 'emulate', '--link', str(link)],
        stdout=subprocess.PIPE, stderr=log, text=True, start_new_session=True)
    try:
        first = emulator.stdout.readline()  # "port: /dev/pts/N  link: ..." once the pty exists
        assert 'port:' in first, (tmp_path / 'emulator.log').read_text()
        run = subprocess.run(
            [sys.executable, '-m', 'cartpole_bringup.cli', 'run', '--hw', '--port', str(link),
             '--hw-arm', '--duration', '17', '--json'],
            capture_output=True, text=True, timeout=240)
        assert run.returncode == 0, run.stderr[-3000:]
        lines = [line for line in run.stdout.splitlines() if line.startswith('{')]
        summary = json.loads(lines[-1])
        why = (summary, run.stderr[-2000:])  # e.g. a 'fault: stale state' of a stalled graph
        assert summary['catch_time_s'] is not None and summary['catch_time_s'] < 10.0, why
        assert summary['theta_amp_deg'] < 2.0, why
        assert summary['x_err_max_m'] <= 0.10, summary
        assert summary['end_stop_contact'] is False, summary
        assert summary['success'] is True, summary
        assert summary['stabilizer'] == 'lqg' and summary['swingup'] == 'pendulum_energy'
        assert summary['force_rms_n'] is not None and summary['force_p2p_n'] is not None
    finally:
        if emulator.poll() is None:
            os.killpg(emulator.pid, signal.SIGINT)
            try:
                emulator.wait(timeout=10)
            except subprocess.TimeoutExpired:
                os.killpg(emulator.pid, signal.SIGKILL)
                emulator.wait()
        log.close()
