"""The encoders' noise, measured from the fourth differences of their samples."""
import math
import random

import pytest

from cartpole_control.encoder_noise import EncoderNoise

TS = 0.005


def swing(t):
    """A swing-up's motion, about: the cart shaken by 0.15 m, the pendulum swinging 2.5 rad."""
    return (0.38 + 0.15 * math.sin(2 * math.pi * 1.3 * t),
            math.pi - 2.5 * math.cos(2 * math.pi * 0.8 * t))


@pytest.mark.parametrize('sigma_x, sigma_theta', [(1e-4, 1.5e-3), (1.5e-3, 0.0225)])
def test_the_noise_of_a_swinging_cart_pole_is_measured_within_15_percent(sigma_x, sigma_theta):
    rng = random.Random(3)
    noise = EncoderNoise(TS)
    for k in range(1000):
        x, theta = swing(k * TS)
        noise.update(k * TS, x + rng.gauss(0.0, sigma_x), theta + rng.gauss(0.0, sigma_theta))
    var_x, var_theta = noise.variance
    assert math.sqrt(var_x) == pytest.approx(sigma_x, rel=0.15)
    assert math.sqrt(var_theta) == pytest.approx(sigma_theta, rel=0.15)


def test_a_smooth_motion_without_noise_reads_as_almost_none():
    noise = EncoderNoise(TS)
    for k in range(1000):
        noise.update(k * TS, *swing(k * TS))
    var_x, var_theta = noise.variance
    assert math.sqrt(var_x) < 2e-6 and math.sqrt(var_theta) < 2e-5


def bang_bang(noise, glitch=0.0):
    """A cart whose acceleration jumps by 40 m/s^2 every 50 ms (a bang-bang force), 0.1 mm of
    noise on its encoder, a sample lost every 97, and every 200th reading off by ``glitch``."""
    rng = random.Random(1)
    x = v = 0.0
    for k in range(2000):
        a = 20.0 if (k // 10) % 2 else -20.0
        x, v = x + v * TS + 0.5 * a * TS * TS, v + a * TS
        if k % 97 == 50:
            continue  # lost
        noise.update(k * TS, x + rng.gauss(0.0, 1e-4) + (glitch if k % 200 == 7 else 0.0), 0.0)
    return math.sqrt(noise.variance[0])


def test_steps_of_the_force_and_lost_samples_do_not_read_as_noise():
    """A lost sample starts the differences afresh (across the gap they read the cart's speed:
    20 % too much here)."""
    noise = EncoderNoise(TS)
    assert bang_bang(noise) == pytest.approx(1e-4, rel=0.1)
    assert noise.samples < 2000 - 4 * (2000 // 97)


def test_a_glitch_of_the_encoder_is_clipped():
    """A 5 mm misreading in 200 samples: counted at most 9 times the mean (unclipped it would
    read as 3.7 times the noise)."""
    assert bang_bang(EncoderNoise(TS), glitch=5e-3) < 1.3e-4
