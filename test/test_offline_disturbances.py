"""The offline closed loop under the scenario's disturbances: lost samples are gaps the EKF
bridges and the summary reports, and a disturbed run is reproduced bit for bit by its seed."""
import json
import subprocess
import sys

import pytest

from cartpole_bringup.offline.closed_loop import run_closed_loop
from cartpole_sim.plant import Push, Scenario

pytestmark = pytest.mark.slow

DISTURBED = dict(noise=True, delay=0.0063, jitter=0.002, drop=0.05, force_noise=0.3,
                 actuator_gain=0.9, actuator_tau=0.002, cart_mass=5.0,
                 pushes=(Push(12.0, 'cart', 5.0, 0.1),))


def test_lost_samples_are_gaps_the_ekf_reports_and_the_summary_counts():
    run = run_closed_loop(scenario=Scenario(noise=True, drop=0.1, seed=3), duration=20.0)
    assert run.summary['success']
    lost = run.summary['lost_samples']
    assert lost == run.lost_samples and 300 < lost < 500  # 10 % of 4001 samples
    # Every lost sample between two delivered ones is a gap the EKF bridged and reported.
    lost_at = set(run.lost_at)
    delivered = [t for t in run.t if t not in lost_at]
    inside = [t for t in run.lost_at if delivered[0] < t < delivered[-1]]
    assert len(run.lost_at) == lost and len(inside) >= lost - 3
    assert run.summary['ekf_missed_samples'] == len(inside)
    assert 'lost_samples' not in run_closed_loop(duration=1.0).summary


def test_a_disturbed_run_is_reproduced_bit_for_bit_by_its_seed():
    a = run_closed_loop(scenario=Scenario(seed=11, **DISTURBED), duration=14.0)
    b = run_closed_loop(scenario=Scenario(seed=11, **DISTURBED), duration=14.0)
    c = run_closed_loop(scenario=Scenario(seed=12, **DISTURBED), duration=14.0)
    for name in ('x', 'theta', 'x_est', 'theta_dot_est', 'force'):
        assert (getattr(a, name) == getattr(b, name)).all(), name
    assert a.summary == b.summary and a.events == b.events
    assert not (a.force == c.force).all()
    assert a.catch_time is not None


def test_cartpole_offline_takes_the_disturbance_options():
    out = subprocess.run([sys.executable, '-m', 'cartpole_bringup.cli', 'offline', '--json',
                          '--duration', '20', '--noise', '--drop', '0.1', '--delay', '0.005',
                          '--jitter', '0.001', '--push', '12:cart:5:0.1', '--cart-mass', '5',
                          '--actuator-gain', '0.9'],
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    summary = json.loads(out.stdout)
    assert summary['success'] and summary['lost_samples'] > 0
    bad = subprocess.run([sys.executable, '-m', 'cartpole_bringup.cli', 'offline',
                          '--actuator-tau', '-1'], capture_output=True, text=True, timeout=300)
    assert bad.returncode != 0 and '--actuator-tau must be >= 0' in bad.stderr
    assert 'Traceback' not in bad.stderr


def test_stop_on_failure_ends_a_failed_run_early_with_the_same_trajectory():
    # A cart half as heavy as the model: the swing-up drives it into the rail guard's fault
    # (the guard without its limiter, which would bend the cart back instead).
    scenario = Scenario(noise=True, cart_mass=2.0)
    trip = {'rail.limit': False}
    full = run_closed_loop(scenario=scenario, duration=20.0, manager_parameters=trip)
    short = run_closed_loop(scenario=scenario, duration=20.0, stop_on_failure=True,
                            manager_parameters=trip)
    assert not full.summary['success']
    faults = [e for _, e in full.events if e.startswith('fault:')]
    assert faults == ['fault:rail guard'], faults      # that fault, once, and no other
    assert full.catch_time is None and not full.end_stop_contact   # stopped before the stop
    stop = short.summary['stopped_at_s']
    assert short.summary['success'] is False and stop < 15.0 and short.t[-1] == stop
    n = len(short.t)
    assert (short.x == full.x[:n]).all() and (short.force == full.force[:n]).all()
    assert 'stopped_at_s' not in run_closed_loop(duration=8.0, stop_on_failure=True).summary
