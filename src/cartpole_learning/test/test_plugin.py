"""The ``policy`` plugin: registered in both roles, numpy inference, fallbacks counted."""
import math

import numpy as np
import pytest

from cartpole_control.controller import STABILIZER, SWINGUP, ControlContext, ControllerState
from cartpole_control.manager import ControllerManager
from cartpole_control.registry import load_controllers
from cartpole_core.model import CartPoleParameters
from cartpole_learning import policy_file
from cartpole_learning.observation import OBSERVATION_SIZE
from cartpole_learning.plugin import SHIPPED_POLICY, PolicyStabilizer, PolicySwingUp

P = CartPoleParameters()


def _context(real_time=True):
    return ControlContext(plant=P, x_ref=P.x_middle, sample_time=P.sample_time,
                          real_time=real_time)


def _upright(t=0.0):
    return ControllerState(t, P.x_middle, 0.02, 0.0, 0.1)


def _write(path, bias=0.0, nan=False):
    rng = np.random.default_rng(0)
    w = [rng.normal(size=(4, OBSERVATION_SIZE)) * 0.1, rng.normal(size=(1, 4)) * 0.1]
    b = [np.zeros(4), np.array([bias])]
    policy_file.save(str(path), np.zeros(OBSERVATION_SIZE), np.ones(OBSERVATION_SIZE), 10.0,
                     1e-8, w, b, 34.2, {'seed': 0})
    if nan:  # a file that loads but whose output is not finite (an inf bias through clip)
        data = dict(np.load(path))
        data['bias_1'] = np.array([np.inf])
        np.savez(path, **data)


def test_registered_as_swingup_and_stabilizer_under_one_name():
    assert load_controllers(SWINGUP)['policy'] is PolicySwingUp
    assert load_controllers(STABILIZER)['policy'] is PolicyStabilizer
    manager = ControllerManager(P, swingup='policy', stabilizer='policy')
    values = manager.get_parameters()
    assert (values['swingup'], values['stabilizer']) == ('policy', 'policy')
    assert values['policy.file'] == ''


def test_the_shipped_policy_runs_in_numpy():
    plugin = PolicyStabilizer()
    plugin.configure({}, _context())
    plugin.activate(_upright())
    force = plugin.update(_upright())
    assert math.isfinite(force) and abs(force) <= P.force_max
    assert plugin.policy.path == SHIPPED_POLICY
    assert plugin.status_values()['policy_fallbacks'] == 0


def test_a_missing_file_falls_back_to_the_laws_and_is_counted(tmp_path):
    for cls, law in ((PolicySwingUp, 'pendulum_energy'), (PolicyStabilizer, 'lqg')):
        plugin = cls()
        plugin.configure({'file': str(tmp_path / 'missing.npz')}, _context())
        assert 'no policy file' in plugin.load_error
        plugin.activate(_upright())
        assert plugin.law == f'policy:fallback({law})'
        expected = plugin.fallback_class()
        expected.configure({}, _context())
        expected.activate(_upright())
        assert plugin.update(_upright(0.005)) == expected.update(_upright(0.005))
        assert plugin.status_values()['policy_fallbacks'] == 1


def test_a_non_finite_output_falls_back_for_the_rest_of_the_activation(tmp_path):
    _write(tmp_path / 'nan.npz', nan=True)
    plugin = PolicyStabilizer()
    with pytest.raises(policy_file.PolicyFileError):  # refused on load, so the file ...
        policy_file.load(str(tmp_path / 'nan.npz'))
    _write(tmp_path / 'ok.npz')
    plugin.configure({'file': str(tmp_path / 'ok.npz')}, _context())
    plugin.activate(_upright())
    assert plugin.update(_upright()) != 0.0
    # ... is made to give NaN at run time: the forward pass of a corrupted network.
    plugin.policy.biases[-1][0] = np.nan
    force = plugin.update(_upright(0.005))
    assert math.isfinite(force)
    assert plugin.law == 'policy:fallback(lqg)'
    assert plugin.status_values()['policy_fallbacks'] == 1
    plugin.deactivate()
    plugin.policy.biases[-1][0] = 0.0
    plugin.activate(_upright())
    assert plugin.law == 'policy'


def test_overruns_in_a_row_fall_back_and_each_is_counted(tmp_path):
    _write(tmp_path / 'ok.npz')
    plugin = PolicySwingUp()
    plugin.configure({'file': str(tmp_path / 'ok.npz'), 'max_overruns': 3}, _context())
    plugin.activate(_upright())
    budget = plugin.gains['max_inference_us']
    # No inference of this interpreter takes less than 1 ns; make the budget unreachable.
    plugin.gains['max_inference_us'] = 1e-3
    plugin.update(_upright(0.005))
    plugin.update(_upright(0.010))
    assert plugin.law == 'policy'  # late twice: still the policy's force
    plugin.gains['max_inference_us'] = budget
    plugin.update(_upright(0.015))  # in time: the count in a row starts again
    plugin.gains['max_inference_us'] = 1e-3
    for k in range(2):
        plugin.update(_upright(0.02 + 0.005 * k))
    assert plugin.law == 'policy' and plugin.status_values()['policy_overruns'] == 4
    plugin.update(_upright(0.03))  # the third in a row
    assert plugin.law == 'policy:fallback(pendulum_energy)'
    assert plugin.status_values()['policy_fallbacks'] == 1
    assert 'overrun: 3 inferences in a row' in plugin.fallback_reason
    # A batch run waits for every cycle: no overrun there, and the run stays deterministic.
    batch = PolicySwingUp()
    batch.configure({'file': str(tmp_path / 'ok.npz'), 'max_overruns': 1},
                    _context(real_time=False))
    batch.activate(_upright())
    batch.gains['max_inference_us'] = 1e-3
    batch.update(_upright())
    assert batch.law == 'policy' and batch.status_values()['policy_fallbacks'] == 0
    assert batch.status_values()['policy_overruns'] == 0


def test_a_preempted_inference_is_no_overrun(tmp_path):
    """5 ms of wall time in which the thread does no work (the loop preempted) is the
    loop's cycle gap, not the network's overrun: the policy stays in charge."""
    import time
    from types import SimpleNamespace
    _write(tmp_path / 'ok.npz')
    plugin = PolicyStabilizer()
    plugin.configure({'file': str(tmp_path / 'ok.npz'), 'max_overruns': 1}, _context())
    plugin.activate(_upright())
    network = plugin.policy.force

    def preempted(obs):
        time.sleep(0.005)  # stands for the scheduler running another process
        return network(obs)
    plugin.policy = SimpleNamespace(force=preempted)
    plugin.update(_upright(0.005))
    assert plugin.law == 'policy' and plugin.status_values()['policy_fallbacks'] == 0
    assert plugin.inference_us < 2000.0 and plugin.status_values()['policy_overruns'] == 0


def test_a_scratch_validation_reads_no_file(tmp_path):
    import dataclasses
    plugin = PolicySwingUp()
    plugin.configure({'file': str(tmp_path / 'missing.npz')},
                     dataclasses.replace(_context(), validation_only=True))
    assert plugin.policy is None and plugin.load_error == ''
