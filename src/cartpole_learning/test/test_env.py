"""cartpole/SwingUp-v0: gymnasium's checks, what the agent sees, how an episode ends."""
import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import cartpole_learning.env  # noqa: F401 (registers the id)
from cartpole_learning.env import ENV_ID, SwingUpEnv
from cartpole_learning.observation import OBSERVATION_NAMES
from cartpole_learning.ranges import draw
from cartpole_sim.scenario_ranges import RangeTable


@pytest.fixture
def env():
    e = SwingUpEnv(duration=1.0)
    yield e
    e.close()


def test_registered_and_passes_gymnasiums_env_checker():
    made = gym.make(ENV_ID)
    try:
        check_env(made.unwrapped, skip_render_check=True)
        assert made.unwrapped.observation_space.shape == (len(OBSERVATION_NAMES),) == (15,)
    finally:
        made.close()


def test_same_seed_same_episode(env):
    def episode(seed):
        obs, _ = env.reset(seed=seed)
        out = [obs]
        for k in range(100):
            obs, *_ = env.step(np.array([0.3 * np.sin(k / 10)], np.float32))
            out.append(obs)
        return np.array(out)
    assert np.array_equal(episode(7), episode(7))
    assert not np.array_equal(episode(7), episode(8))


def test_the_observation_is_the_estimate_not_the_true_state():
    e = SwingUpEnv(table={'encoder_offset': (0.05, 0.05), 'force_noise': (0.0, 0.0)},
                   upright_start=0.0, duration=1.0)
    try:
        obs, info = e.reset(seed=1)
        assert info['scenario'].encoder_offset == 0.05
        # Hanging at rest 0.05 rad off at the left stop, encoders reset there: the
        # estimate starts from the measured pi (the EKF has not yet found the offset),
        # the true angle is pi + 0.05.
        true_theta = e._loop._plant.state[1]
        assert true_theta == pytest.approx(np.pi + 0.05, abs=1e-3)
        assert abs(obs[1] - np.sin(true_theta)) > 0.03
        assert obs[0] == pytest.approx(-e.x_ref, abs=1e-3)
    finally:
        e.close()


def test_a_fall_after_the_catch_ends_the_episode_with_the_penalty():
    e = SwingUpEnv(upright_start=1.0, duration=2.0)
    try:
        e.reset(seed=3)
        assert e._kind == 'stabilizer'  # caught in the first cycle
        for _ in range(e.steps):
            obs, reward, terminated, truncated, info = e.step(np.array([1.0], np.float32))
            if terminated or truncated:
                break
        assert terminated and not truncated
        assert info['end'] in ('fall', 'fault:rail guard')
        assert reward < -e.failure_penalty / 2
    finally:
        e.close()


def test_the_rail_guard_keeps_a_full_push_off_the_stop(env):
    env.reset(seed=5)
    for _ in range(env.steps):
        obs, reward, terminated, truncated, info = env.step(np.array([1.0], np.float32))
        if terminated or truncated:
            break
    assert info.get('end') != 'impact'
    assert not env._loop._plant.impacts


def test_an_episode_is_truncated_after_its_duration(env):
    env.reset(seed=4)
    for k in range(env.steps + 1):
        _, _, terminated, truncated, _ = env.step(np.zeros(1, np.float32))
        assert not terminated
        if truncated:
            break
    assert truncated
    # Lost samples never reach the plugin: the episode's 1 s may take fewer cycles.
    assert k + 1 <= env.steps + 1
    assert env._loop._plant.t == pytest.approx(1.0 + env.nominal.sample_time)


def test_episodes_draw_from_the_combined_table_with_the_push_inside_the_episode():
    rng = np.random.default_rng(0)
    table = RangeTable()
    pushes = 0
    for _ in range(60):
        s = draw(table, rng, 0.3845, 0.0, (2.5, 5.0))
        assert 0.7 <= s.actuator_gain <= 1.3 and 0.0 <= s.delay <= 0.025 and s.noise
        assert (s.x0, s.theta0 - s.encoder_offset) == (0.0, pytest.approx(np.pi))
        for push in s.pushes:
            assert 2.5 <= push.t <= 5.0
            pushes += 1
    assert 25 <= pushes <= 55  # two runs in three
    s = draw(table, np.random.default_rng(1), 0.3845, 1.0)
    assert abs(s.x0 - 0.3845) <= 0.1 and abs(s.theta0) <= 0.25
    with pytest.raises(ValueError, match='unknown'):
        SwingUpEnv(table={'gravity': (1, 2)})


def test_vectorised_with_gymnasium():
    envs = gym.make_vec(ENV_ID, num_envs=2, vectorization_mode='sync', duration=0.2)
    try:
        obs, _ = envs.reset(seed=0)
        assert obs.shape == (2, len(OBSERVATION_NAMES))
        obs, reward, terminated, truncated, _ = envs.step(np.zeros((2, 1), np.float32))
        assert reward.shape == (2,)
    finally:
        envs.close()
