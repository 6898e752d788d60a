"""The policy file: what it stores, what it refuses, and the numpy forward pass."""
import json
import math
import zipfile

import numpy as np
import pytest

from cartpole_learning import policy_file
from cartpole_learning.observation import OBSERVATION_NAMES, OBSERVATION_SIZE, Observer, \
    observation

N = OBSERVATION_SIZE


def _layers(rng, arch=(8, 8)):
    weights, biases, width = [], [], N
    for hidden in (*arch, 1):
        weights.append(rng.normal(size=(hidden, width)))
        biases.append(rng.normal(size=hidden))
        width = hidden
    return weights, biases


def _write(path, rng, **changes):
    weights, biases = _layers(rng)
    args = dict(obs_mean=rng.normal(size=N), obs_var=rng.uniform(0.5, 2.0, size=N),
                obs_clip=10.0, obs_epsilon=1e-8, weights=weights, biases=biases,
                action_scale=34.2, provenance={'seed': 3, 'command': 'cartpole train'})
    args.update(changes)
    policy_file.save(str(path), **args)
    return args


def test_round_trip_and_forward_pass_match_a_direct_computation(tmp_path):
    rng = np.random.default_rng(0)
    args = _write(tmp_path / 'p.npz', rng)
    policy = policy_file.load(str(tmp_path / 'p.npz'))
    assert policy.provenance == {'seed': 3, 'command': 'cartpole train'}
    for _ in range(20):
        obs = rng.normal(size=N).astype(np.float32)
        h = np.clip((obs - args['obs_mean']) / np.sqrt(args['obs_var'] + 1e-8), -10, 10)
        h = np.tanh(args['weights'][0] @ h + args['biases'][0])
        h = np.tanh(args['weights'][1] @ h + args['biases'][1])
        a = float(np.clip(args['weights'][2] @ h + args['biases'][2], -1, 1)[0])
        assert policy.force(obs) == pytest.approx(34.2 * a, abs=1e-12)


def test_the_action_is_clipped_to_the_amplifier_scale(tmp_path):
    rng = np.random.default_rng(1)
    weights, biases = _layers(rng)
    biases[-1] = np.array([50.0])  # a huge output
    _write(tmp_path / 'p.npz', rng, weights=weights, biases=biases)
    policy = policy_file.load(str(tmp_path / 'p.npz'))
    assert policy.force(np.zeros(N, np.float32)) == 34.2


@pytest.mark.parametrize('change, message', [
    (dict(obs_mean=np.zeros(N + 1)), 'normalisation of shape'),
    (dict(obs_var=np.full(N, np.nan)), 'non-finite'),
    (dict(action_scale=0.0), 'action_scale'),
])
def test_a_file_that_does_not_fit_is_refused_with_the_reason(tmp_path, change, message):
    _write(tmp_path / 'p.npz', np.random.default_rng(2), **change)
    with pytest.raises(policy_file.PolicyFileError, match=message):
        policy_file.load(str(tmp_path / 'p.npz'))


def test_wrong_layer_shapes_and_outputs_are_refused(tmp_path):
    rng = np.random.default_rng(3)
    weights, biases = _layers(rng)
    weights[1] = rng.normal(size=(8, 5))
    _write(tmp_path / 'a.npz', rng, weights=weights, biases=biases)
    with pytest.raises(policy_file.PolicyFileError, match='layer 1'):
        policy_file.load(str(tmp_path / 'a.npz'))
    weights, biases = _layers(rng)
    weights[2], biases[2] = rng.normal(size=(2, 8)), rng.normal(size=2)
    _write(tmp_path / 'b.npz', rng, weights=weights, biases=biases)
    with pytest.raises(policy_file.PolicyFileError, match='expected 1'):
        policy_file.load(str(tmp_path / 'b.npz'))


def test_missing_garbled_and_foreign_files_are_refused(tmp_path):
    with pytest.raises(policy_file.PolicyFileError, match='no policy file'):
        policy_file.load(str(tmp_path / 'none.npz'))
    (tmp_path / 'text.npz').write_text('not a zip')
    with pytest.raises(policy_file.PolicyFileError, match='not a policy file'):
        policy_file.load(str(tmp_path / 'text.npz'))
    np.savez(tmp_path / 'obj.npz', format=np.array(policy_file.FORMAT),
             obs_mean=np.array([{'a': 1}], dtype=object))  # needs pickle: never loaded
    with pytest.raises(policy_file.PolicyFileError):
        policy_file.load(str(tmp_path / 'obj.npz'))
    rng = np.random.default_rng(4)
    _write(tmp_path / 'p.npz', rng)
    with zipfile.ZipFile(tmp_path / 'p.npz') as z:
        arrays = {n[:-4]: np.load(z.open(n)) for n in z.namelist()}
    arrays['observation_names'] = np.array(list(reversed(OBSERVATION_NAMES)))
    np.savez(tmp_path / 'order.npz', **arrays)
    with pytest.raises(policy_file.PolicyFileError, match='observation'):
        policy_file.load(str(tmp_path / 'order.npz'))


def test_observation_is_continuous_over_the_top_and_flags_the_role():
    a = observation(0.1, math.pi - 1e-9, 0.2, 3.0, 1.0, False)
    b = observation(0.1, -math.pi + 1e-9, 0.2, 3.0, 1.0, True)
    assert np.allclose(a[:6], b[:6], atol=1e-6)
    assert (a[6], b[6]) == (0.0, 1.0)
    assert observation(5.0, 0.0, 0.0, 0.0, 0.0, False)[0] == 2.0  # clipped to the space


def test_the_observation_reads_the_plant_estimate_and_keeps_the_stabilisers_integral():
    from types import SimpleNamespace

    from cartpole_control.controller import CommandFeedback, ControllerState
    estimate = SimpleNamespace(natural_frequency=SimpleNamespace(omega_sq=30.0, nominal=25.0),
                               dead_time=0.02, disturbance=-3.0)
    context = SimpleNamespace(x_ref=0.385, plant_estimate=estimate, sample_time=0.005)
    observer = Observer()
    observer.reset(0.0)
    seen = [observer.observe(ControllerState(0.005 * k, 0.485, 0.1, 0.2, 0.3, 0.4), context,
                             True).copy() for k in range(1, 4)]
    names = list(OBSERVATION_NAMES)
    assert seen[0][names.index('omega_sq_error')] == pytest.approx(0.2)
    assert seen[0][names.index('disturbance')] == -3.0
    assert seen[0][names.index('upright_theta')] == pytest.approx(0.1)
    # int (x - x*) dt over two steps of 5 ms (the first step from the reset's stamp)
    assert seen[2][names.index('upright_x_integral')] == pytest.approx(0.1 * 0.015)
    # the third increment pushed a command cut from below further down: taken back
    observer.feedback(CommandFeedback(raw=-40.0, force=-37.0, limited=-1))
    held = observer.observe(ControllerState(0.02, 0.485, 0.1, 0.2, 0.3, 0.4), context, True)
    assert held[names.index('upright_x_integral')] == pytest.approx(0.1 * 0.015)
    observer.feedback(CommandFeedback(raw=-4.0, force=-4.0, limited=0))  # passed: kept
    assert observer.observe(ControllerState(0.025, 0.485, 0.1, 0.2, 0.3, 0.4), context, True)[
        names.index('upright_x_integral')] == pytest.approx(0.1 * 0.02)
    swinging = Observer().observe(ControllerState(0.0, 0.485, 3.0, 0.2, 0.3, 0.4),
                                  SimpleNamespace(x_ref=0.385, plant_estimate=None,
                                                  sample_time=0.005), False)
    assert list(swinging[6:]) == [0.0] * 9  # outside a manager and in the swing-up role

def test_the_shipped_policy_loads_and_records_its_provenance():
    from cartpole_learning.plugin import SHIPPED_POLICY
    policy = policy_file.load(SHIPPED_POLICY)
    for key in ('command', 'seed', 'steps', 'wall_time_s', 'commit', 'ranges'):
        assert key in policy.provenance, key
    assert json.dumps(policy.provenance)
