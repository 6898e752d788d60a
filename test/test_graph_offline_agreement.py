"""A bag recorded from `cartpole run --lockstep` agrees with `cartpole offline` on the same scenario.

In lockstep the graph runs the very objects of the offline loop (plant,
sampling and quantisation, EKF, controller manager) in the same order, so
the two runs should be the same trajectory. Tolerances:

- catch time within 2 samples (10 ms): the only intended difference is
  message passing, which changes no number; 2 samples leave room for the
  start-up (the simulator re-publishes sample 0 until the loop answers);
- amplitude and cart error over the last 10 s within 0.1 deg / 5 mm and a
  factor 2 on the MSEs: after the catch small differences are amplified by
  the chattering stabiliser, but the balancing quality must be the same;
- success and end-stop contact identical.
"""
from __future__ import annotations

import json
import subprocess

import pytest

pytestmark = [pytest.mark.ros, pytest.mark.slow]

DURATION = '20'


def _cartpole(*args, timeout=120):
    import importlib.util
    from pathlib import Path
    spec = importlib.util.spec_from_file_location(
        'graph_processes', Path(__file__).with_name('test_graph_processes.py'))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    code, out, err = module.run(list(args), timeout)
    assert code == 0, err
    return json.loads(out.strip().splitlines()[-1])


def test_lockstep_bag_agrees_with_offline(tmp_path):
    scenario = ['--theta0', '3.1', '--stabilizer', 'smc']
    offline = _cartpole('offline', '--duration', DURATION, '--json', *scenario)
    online = _cartpole('run', '--sim', '--lockstep', '--duration', DURATION,
                       '--record', str(tmp_path), '--json', *scenario)
    analysed = _cartpole('analyze', online['bag'], '--json')
    for key in ('catch_time_s', 'success', 'end_stop_contact', 'theta_amp_deg'):
        assert analysed[key] == online[key]
    assert offline['catch_time_s'] is not None
    assert analysed['catch_time_s'] == pytest.approx(offline['catch_time_s'], abs=0.0101)
    assert analysed['upright_time_s'] == pytest.approx(offline['upright_time_s'], abs=0.0101)
    assert analysed['theta_amp_deg'] == pytest.approx(offline['theta_amp_deg'], abs=0.1)
    assert analysed['x_err_max_m'] == pytest.approx(offline['x_err_max_m'], abs=0.005)
    for key in ('mse_x', 'mse_theta'):
        assert 0.5 <= analysed[key] / offline[key] <= 2.0, key
    assert analysed['success'] == offline['success']
    assert analysed['end_stop_contact'] == offline['end_stop_contact']
