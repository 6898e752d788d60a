"""R matched to the encoders' scatter near an equilibrium (cartpole_estimation.measurement_noise)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from cartpole_core.model import CartPoleParameters
from cartpole_estimation.ekf import ExtendedKalmanFilter
from cartpole_estimation.ekf_config import EkfConfig
from cartpole_estimation.measurement_noise import MeasurementNoise

TS = 0.005
R = (0.01, 0.1)
SCALE = 0.1 / 3.0e-6  # EkfConfig's R_theta over noise_variance_theta


def _noise(window=1.0, limit=1000.0):
    return MeasurementNoise(R, SCALE, window, limit, TS)


def _feed(noise, n, sigma_x, sigma_theta, seed=0, near=True, every=1):
    rng = np.random.default_rng(seed)
    for k in range(n):
        if k % every:
            continue
        noise.update(k * TS, rng.normal(0.4, sigma_x), math.pi + rng.normal(0.0, sigma_theta),
                     near)
    return noise.factors


def test_the_scatter_of_a_noisy_encoder_raises_r_to_its_variance():
    """15 mrad and 1.5 mm of white noise: R_theta 75 x, R_x 7.5 x the thesis's (the
    variances over the 3e-6 rad^2 and 3e-7 m^2 R stands for), within 25 % after 4 s (over
    20 seeds the estimate scatters by 12 %)."""
    fx, ft = _feed(_noise(), 800, 1.5e-3, 15e-3)
    assert fx == pytest.approx(7.5, rel=0.25) and ft == pytest.approx(75.0, rel=0.25)


def test_the_first_samples_already_set_r():
    """The mean runs over the samples so far until the window fills: 40 samples (0.2 s)
    of 15 mrad put R_theta within a factor 2 of its value (an exponential mean from the
    floor would be at a sixth of it)."""
    _, ft = _feed(_noise(), 42, 1.5e-3, 15e-3)
    assert 75.0 / 2.0 < ft < 75.0 * 2.0


def test_the_thesis_s_noise_keeps_the_configured_r():
    """1.5 mrad and 0.1 mm (the simulator's nominal noise): R stays r_diag, the floor."""
    assert _feed(_noise(), 2000, 1.0e-4, 1.5e-3) == (1.0, 1.0)


def test_away_from_an_equilibrium_nothing_is_counted():
    noise = _noise()
    assert _feed(noise, 400, 1.5e-3, 15e-3, near=False) == (1.0, 1.0)
    assert noise.samples == 0


def test_lost_samples_break_the_second_difference():
    """Every other sample lost: no two neighbours Ts apart, nothing counted (a second
    difference over 2 Ts would count the motion four times over)."""
    noise = _noise()
    assert _feed(noise, 400, 1.5e-3, 15e-3, every=2) == (1.0, 1.0)
    assert noise.samples == 0


def test_window_zero_keeps_r_fixed_and_the_limit_caps_it():
    assert _feed(_noise(window=0.0), 400, 1.5e-3, 15e-3) == (1.0, 1.0)
    fx, ft = _feed(_noise(limit=20.0), 800, 1.5e-3, 15e-3)
    assert ft == 20.0 and fx == pytest.approx(7.5, rel=0.25)


def test_the_filter_uses_it_and_its_rate_stops_following_the_noise():
    """The EKF at rest, hanging, 15 mrad of noise: R_theta follows (75 x within 20 %), and
    over the second second theta_dot's estimate scatters by less than half of what it
    does with R fixed (0.006 against 0.030 rad/s rms)."""
    def run(config):
        ekf = ExtendedKalmanFilter(CartPoleParameters(), config)
        rng = np.random.default_rng(3)
        rates = []
        for k in range(400):
            e = ekf.update(k * TS, rng.normal(0.0, 1.0e-3), math.pi + rng.normal(0.0, 15e-3),
                           0.0)
            rates.append(e.theta_dot)
        return ekf, float(np.sqrt(np.mean(np.square(rates[200:]))))

    ekf, rate = run(EkfConfig())
    fixed, rate_fixed = run(EkfConfig(noise_window=0.0))
    assert ekf.measurement_noise_factors[1] == pytest.approx(75.0, rel=0.2)
    assert fixed.measurement_noise_factors == (1.0, 1.0)
    assert rate < 0.5 * rate_fixed


@pytest.mark.parametrize('bad', [{'noise_window': -1.0}, {'noise_window': math.nan},
                                 {'noise_variance_theta': 0.0}, {'noise_limit': 0.5},
                                 {'noise_limit': math.inf}])
def test_bad_noise_settings_are_refused(bad):
    name = next(iter(bad))
    with pytest.raises(ValueError, match=name):
        EkfConfig(**bad)
