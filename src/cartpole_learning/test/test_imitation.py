"""DAgger's teacher and what it records: the laws by name, the estimate's features."""
import numpy as np
import pytest

from cartpole_control.controllers.lqg import LqgStabilizer
from cartpole_control.controllers.pendulum_energy import PendulumEnergySwingUp
from cartpole_core.model import CartPoleParameters
from cartpole_learning.imitation import TEACHER, TeacherLoop, teacher_classes
from cartpole_learning.observation import OBSERVATION_NAMES
from cartpole_sim.scenario import Scenario


def test_the_default_teacher_is_the_fastest_robust_pair_and_the_commands_default():
    import argparse

    from cartpole_control.controllers.time_optimal import TimeOptimalSwingUp
    from cartpole_learning.commands.train import add_arguments
    assert TEACHER == ('time_optimal', 'lqg')
    assert teacher_classes() == {'swingup': TimeOptimalSwingUp, 'stabilizer': LqgStabilizer}
    assert teacher_classes(('pendulum_energy', 'lqg'))['swingup'] is PendulumEnergySwingUp
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    assert parser.parse_args([]).teacher == ':'.join(TEACHER)


@pytest.mark.parametrize('teacher, message', [
    (('foo', 'lqg'), "swingup 'foo': expected one of"),
    (('pendulum_energy', 'policy'), "stabilizer 'policy': expected one of"),
])
def test_an_unknown_teacher_or_a_learned_one_is_refused(teacher, message):
    with pytest.raises(ValueError, match=message):
        teacher_classes(teacher)


def test_the_teacher_labels_what_it_does_and_the_features_carry_the_plant_estimate():
    """A 40 ms dead time the manager measures shows in the observation the teacher labels."""
    loop = TeacherLoop(CartPoleParameters(), ('pendulum_energy', 'lqg'))
    try:
        loop.begin(student_acts=False)
        loop._episode(Scenario(delay=0.04, seed=0), 800)  # 4 s from hanging
        assert loop.receive()[:2] == ('end', 'time')
    finally:
        loop.close()
    obs, labels = np.array(loop.observations), np.array(loop.labels)
    assert len(obs) == len(labels) == 801
    assert np.max(np.abs(labels)) > 0.3  # the energy law pumps
    dead_time = obs[:, OBSERVATION_NAMES.index('dead_time')]
    assert dead_time[0] < 0.01 and 0.035 < dead_time[-1] < 0.05  # learned during the swing-up
    stabiliser = loop._teachers['stabilizer']   # the shipped policy's teacher: one, robust gain
    assert stabiliser.gains['q'] == (10.0, 10000.0, 10.0, 1.0, 400.0)
    assert np.array_equal(stabiliser.gain, stabiliser.robust_gain)


@pytest.mark.slow
def test_a_planning_teacher_has_its_plan_before_the_first_episode(tmp_path, monkeypatch):
    """``time_optimal`` teaches from its minimum-time plan: :func:`prepare_teacher` solves it
    into an empty plan cache first (else every episode's teacher would swing up with its
    fall-back while a background solve ran), and the episode's teacher tracks it."""
    from cartpole_learning.imitation import prepare_teacher

    monkeypatch.setenv('CARTPOLE_CACHE_DIR', str(tmp_path))
    said = []
    prepare_teacher(CartPoleParameters(), ('time_optimal', 'lqg'), said.append)
    assert any('plan from x = 0.00 m: T = ' in text for text in said), said
    loop = TeacherLoop(CartPoleParameters(), ('time_optimal', 'lqg'))
    try:
        loop.begin(student_acts=False)
        loop._episode(Scenario(seed=0), 300)  # 1.5 s from hanging at the left stop
        assert loop.receive()[:2] == ('end', 'time')
    finally:
        loop.close()
    swingup = loop._teachers['swingup']
    assert swingup.law == 'time_optimal:plan'
    assert (swingup.gains['abort_x'], swingup.gains['abort_theta']) == (0.3, 1.5)  # DAgger's
    assert np.max(np.abs(loop.labels)) > 0.8  # the plan's full-force strokes
