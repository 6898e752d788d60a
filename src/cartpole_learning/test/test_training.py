"""The trainer (training extra): the numpy forward pass is the trainer's own, and a short run."""
import numpy as np
import pytest

torch = pytest.importorskip('torch', reason='the training extra (requirements-train.txt) is '
                                            'not installed')
pytest.importorskip('stable_baselines3', reason='the training extra (requirements-train.txt) '
                                                'is not installed')

from cartpole_learning import policy_file  # noqa: E402
from cartpole_learning.observation import OBSERVATION_SIZE  # noqa: E402
from cartpole_learning.training import TrainConfig, actor_layers, build_actor, \
    sequential_layers, train  # noqa: E402


def _check_numpy_against_torch(weights, biases, actor, tmp_path, rng):
    mean = rng.normal(size=OBSERVATION_SIZE)
    var = rng.uniform(0.1, 3.0, size=OBSERVATION_SIZE)
    policy_file.save(str(tmp_path / 'p.npz'), mean, var, 10.0, 1e-8, weights, biases, 34.2, {})
    policy = policy_file.load(str(tmp_path / 'p.npz'))
    obs = rng.normal(scale=3.0, size=(500, OBSERVATION_SIZE)).astype(np.float32)
    normalised = np.clip((obs - mean) / np.sqrt(var + 1e-8), -10.0, 10.0)
    with torch.no_grad():
        expected = np.clip(actor(torch.as_tensor(normalised, dtype=torch.float32)).numpy()[:, 0],
                           -1.0, 1.0)
    got = np.array([policy.action(o) for o in obs])
    assert np.max(np.abs(got - expected)) <= 1e-5


def test_numpy_forward_pass_matches_the_imitation_actor(tmp_path):
    torch.manual_seed(0)
    actor = build_actor((64, 64), OBSERVATION_SIZE)
    _check_numpy_against_torch(*sequential_layers(actor), actor, tmp_path,
                               np.random.default_rng(0))


def test_numpy_forward_pass_matches_stable_baselines3s_ppo_actor(tmp_path):
    from stable_baselines3 import PPO

    from cartpole_learning.env import SwingUpEnv
    env = SwingUpEnv(duration=0.1)
    try:
        model = PPO('MlpPolicy', env, n_steps=16, batch_size=16, seed=1, device='cpu',
                    policy_kwargs=dict(activation_fn=torch.nn.Tanh))
        with torch.no_grad():  # weights away from their initial scale
            for p in model.policy.parameters():
                p.add_(0.3 * torch.randn_like(p))

        def actor(x):
            return model.policy.action_net(model.policy.mlp_extractor.forward_actor(x))
        _check_numpy_against_torch(*actor_layers(model), actor, tmp_path,
                                   np.random.default_rng(1))
    finally:
        env.close()


@pytest.mark.slow
def test_a_short_training_run_writes_a_policy_the_plugin_loads(tmp_path):
    config = TrainConfig(seed=3, rounds=2, episodes=2, epochs=2, workers=1, duration=0.5,
                         ppo_steps=64, envs=1, n_steps=32, batch_size=32)
    out = tmp_path / 'p.npz'
    provenance = train(config, str(out), log=lambda s: None)
    policy = policy_file.load(str(out))
    assert policy.provenance['seed'] == 3 and provenance['steps'] >= 64
    assert [r['round'] for r in policy.provenance['rounds']] == [0, 1]
    assert policy.provenance['ppo']['steps'] >= 64
    assert policy.provenance['ranges']['delay'] == [0.0, 0.025]
    assert np.isfinite(policy.force(np.zeros(OBSERVATION_SIZE, np.float32)))
