"""The EKF's encoder-offset state b (Appendix H): where it is learnt."""
import importlib.util
import math
from pathlib import Path

from cartpole_core.model import CartPoleParameters
from cartpole_estimation.ekf import EkfConfig, ExtendedKalmanFilter
from cartpole_sim.plant import Plant, Scenario

_spec = importlib.util.spec_from_file_location('test_ekf', Path(__file__).with_name('test_ekf.py'))
_ekf_tests = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_ekf_tests)
simulate, ALWAYS = _ekf_tests.simulate, _ekf_tests.ALWAYS


def test_the_offset_state_finds_an_encoder_reset_off_hanging():
    """Appendix H: the encoders zeroed with the pendulum 0.1 rad off hanging, then at rest.

    The model's gravity says a pendulum at rest hangs at pi: within half a
    second the filter has the offset to a few mrad and the angle it hands out
    is the pendulum's own; the thesis's filter keeps the encoder's error.
    """
    scenario = Scenario(x0=0.38, theta0=math.pi, encoder_offset=0.1)
    truth, _, estimates, _ = simulate(scenario, 2.0)
    assert abs(estimates[100].angle_offset - 0.1) < 0.005
    assert abs(estimates[-1].angle_offset - 0.1) < 0.002
    assert abs(estimates[-1].theta - truth[-1, 1]) < 0.002
    thesis = EkfConfig(q_diag=(1.0, 1.0, 50.0, 50.0), q_force=0.0, push_q_force=0.0,
                       angle_offset_p0=0.0)
    _, _, plain, _ = simulate(scenario, 2.0, config=thesis)
    assert plain[-1].angle_offset == 0.0
    assert abs(plain[-1].theta - truth[-1, 1]) > 0.09


def test_free_swing_without_offset_leaves_the_offset_near_zero():
    """No offset, a large free swing, never near an equilibrium at rest: b stays at its prior
    (``offset_gate_*``); corrected always, the midpoint prediction's model error is still
    too small to be taken for an offset (forward Euler's made it about 6 mrad)."""
    assert all(e.angle_offset == 0.0 for e in simulate()[2])
    estimates = simulate(config=ALWAYS)[2]
    assert max(abs(e.angle_offset) for e in estimates[200:]) < 0.002
    assert max(abs(e.angle_offset) for e in estimates[:40]) > 0.01  # it was corrected


def test_on_a_noisy_encoder_b_is_learnt_in_the_swing_too():
    """12 mrad of angle noise (8 x nominal), an offset of 30 mrad: the hanging start's 0.5 s
    leave b 32 mrad off and R_theta over 4 x its configured value (``noise_window``), which
    opens the gate (``offset_gate_noise``): a swing pumped at 25 N ends with b within
    10 mrad of the truth. With the gate alone b is kept where the start left it."""
    params = CartPoleParameters()

    def run(config):
        plant = Plant(params, Scenario(x0=0.38, theta0=math.pi, noise=True, seed=3,
                                       noise_std_pendulum=0.012, noise_std_cart=0.0008,
                                       encoder_offset=0.03))
        ekf = ExtendedKalmanFilter(params, config)
        u, offsets, factor = 0.0, [], 0.0
        for k in range(800):
            m = plant.measure()
            e = ekf.update(k * params.sample_time, m.x, m.theta, u)
            offsets.append(e.angle_offset)
            factor = ekf.measurement_noise_factors[1] if k == 99 else factor
            pump = math.copysign(25.0, e.theta_dot * math.cos(e.theta))
            u = 0.0 if k < 100 or abs(e.x - 0.38) > 0.25 else pump
            plant.step(u)
        return factor, offsets

    factor, offsets = run(EkfConfig())
    _, alone = run(EkfConfig(offset_gate_noise=math.inf))
    assert factor >= 4.0 and abs(offsets[99] - 0.03) > 0.02
    assert abs(offsets[-1] - 0.03) < 0.01 and len(set(offsets[100:])) > 100
    assert len(set(alone[100:])) == 1 and abs(alone[-1] - 0.03) > 0.02
