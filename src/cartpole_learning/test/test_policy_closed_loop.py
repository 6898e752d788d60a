"""The shipped policy in the offline closed loop: hanging to balancing, and the hand-over to lqg."""
import pytest

from cartpole_bringup.offline.closed_loop import run_closed_loop
from cartpole_sim.scenario import Scenario

pytestmark = pytest.mark.slow


@pytest.mark.parametrize('stabilizer', ['policy', 'lqg'])
def test_the_shipped_policy_swings_up_and_the_stabiliser_holds(stabilizer):
    run = run_closed_loop(scenario=Scenario(noise=True, seed=0), duration=30.0,
                          manager_parameters={'swingup': 'policy', 'stabilizer': stabilizer})
    s = run.summary
    assert s['success'], s
    assert s['catch_time_s'] <= 1.745  # 1.5 x the minimum-time bound; its teacher's plan 1.54 s
    assert s['falls_after_catch'] == 0 and not s['impacts']
    assert s.get('policy_fallbacks', 0) == 0
    assert s['theta_amp_deg'] < 1.0
    assert [c['name'] for c in s['controllers']][:2] == ['policy', stabilizer]


def test_a_missing_policy_file_still_swings_up_with_the_laws(tmp_path):
    run = run_closed_loop(scenario=Scenario(noise=True, seed=0), duration=30.0,
                          manager_parameters={'swingup': 'policy', 'stabilizer': 'policy',
                                              'policy.file': str(tmp_path / 'missing.npz')})
    s = run.summary
    assert s['success'], s
    assert s['policy_fallbacks'] == 1  # the stabiliser's (the swing-up's status is not reported)
    assert s['swingup_law'] == 'policy:fallback(pendulum_energy)'
