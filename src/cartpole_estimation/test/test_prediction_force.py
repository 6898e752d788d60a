"""The force the EKF node predicts an interval with: acting force, command, or the held command."""
import pytest

from cartpole_estimation.ekf_config import EkfConfig
from cartpole_estimation.prediction_force import REMEMBERED, PredictionForce


def test_the_acting_force_then_the_matched_command_then_the_held_one_until_its_timeout():
    forces = PredictionForce('acting', command_timeout=0.05)
    assert forces.for_interval(None, None) == 0.0            # nothing yet
    forces.command((0, 0), 8.0, newest_sample_t=0.0)
    assert forces.ready((0, 0))                              # no acting force seen yet
    forces.acting((0, 0), 6.0)
    assert forces.for_interval((0, 0), 0.0) == 6.0
    forces.command((0, 5_000_000), 9.0, newest_sample_t=0.005)
    assert not forces.ready((0, 5_000_000))                 # its acting force is due
    assert forces.for_interval((0, 5_000_000), 0.005) == 9.0  # the matched command
    # a sample no command answers: the latest one held, zero once older than the timeout
    assert forces.for_interval((0, 10_000_000), 0.010) == 9.0
    assert forces.for_interval((0, 60_000_000), 0.060) == 0.0
    forces.clear()
    assert forces.for_interval((0, 0), 0.0) == 0.0


def test_with_command_the_acting_force_is_not_used_nor_waited_for():
    forces = PredictionForce('command')
    forces.command((0, 0), 8.0, 0.0)
    forces.acting((0, 0), 6.0)
    forces.command((0, 5_000_000), 9.0, 0.005)
    assert forces.ready((0, 5_000_000))
    assert forces.for_interval((0, 0), 0.0) == 8.0


def test_only_the_newest_are_remembered():
    forces = PredictionForce()
    for k in range(REMEMBERED + 1):
        forces.acting((k, 0), float(k))
        forces.command((k, 0), float(k), float(k))
    assert forces.for_interval((0, 0), 100.0) == 0.0        # forgotten, the held one too old
    assert forces.for_interval((REMEMBERED, 0), float(REMEMBERED)) == REMEMBERED


@pytest.mark.parametrize('make', [lambda: PredictionForce('applied'),
                                  lambda: EkfConfig(force_input='applied')])
def test_a_force_input_that_is_neither_is_refused(make):
    with pytest.raises(ValueError, match='force_input must be one of'):
        make()
