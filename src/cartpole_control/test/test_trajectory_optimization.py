"""The minimum-time swing-up optimiser : model, bounds, cache, tracking gains."""
import dataclasses
import math

import numpy as np
import pytest

from cartpole_control import trajectory_optimization as to
from cartpole_control.tracking import tracking_gains
from cartpole_core.model import CartPoleParameters, accelerations, pendulum_energy

P = CartPoleParameters()


@pytest.mark.parametrize('state,force', [
    ((0.3, 2.0, 0.4, -3.0), 12.0), ((0.1, -0.7, -0.8, 5.0), -30.0), ((0.5, 4.0, 1.2, 0.5), 0.0)])
def test_casadi_model_is_the_plant_model(state, force):
    """The CasADi restatement of (4.18) equals cartpole_core.model.accelerations."""
    f0 = to.casadi_dynamics(P, friction=False)
    got = np.array(f0(state, force)).ravel()
    want = accelerations(*state, force, P, friction=False)
    np.testing.assert_allclose(got[2:], want, rtol=1e-12)
    np.testing.assert_allclose(got[:2], state[2:])
    # With friction: the smoothed Coulomb law matches the plant's away from zero speed.
    f1 = to.casadi_dynamics(P, friction=True)
    got = np.array(f1(state, force)).ravel()
    np.testing.assert_allclose(got[2:], accelerations(*state, force, P), rtol=1e-6)


BOUND_GUESSES = to.DEFAULT_GUESSES[:2]


@pytest.fixture(scope='module')
def bounds():
    """The three bounds at the thesis parameters (coarse multi-start, 70 intervals)."""
    return {case: to.solve_minimum_time(to.bound_problem(case, P), 70, guesses=BOUND_GUESSES)
            for case in to.BOUND_CASES}


@pytest.mark.slow  # the bounds fixture solves the optimisation (seconds of CPU)
@pytest.mark.parametrize('case', to.BOUND_CASES)
def test_optimiser_reproduces_the_reference_bounds_within_3_percent(bounds, case):
    traj = bounds[case]
    assert traj.success
    assert traj.final_time == pytest.approx(to.ISSUE_BOUNDS[case], rel=0.03)


@pytest.mark.slow  # the bounds fixture solves the optimisation (seconds of CPU)
@pytest.mark.parametrize('case', to.BOUND_CASES)
def test_bound_solutions_respect_limits_and_reach_the_region(bounds, case):
    traj = bounds[case]
    problem = to.bound_problem(case, P)
    assert np.all(traj.forces <= P.force_max + 1e-6) and np.all(traj.forces >= P.force_min - 1e-6)
    assert traj.states[:, 0].min() >= -1e-6 and traj.states[:, 0].max() <= P.travel + 1e-6
    np.testing.assert_allclose(traj.states[0], problem.start, atol=1e-9)
    end = traj.states[-1]
    assert abs(math.remainder(end[1], 2 * math.pi)) <= math.radians(10) + 1e-6
    if case == 'upright_at_rest':
        assert abs(end[2]) < 1e-6 and abs(end[3]) < 1e-6
    else:
        e = pendulum_energy(end[1], end[3], P)
        assert abs(e - P.upright_energy) <= 0.05 * P.upright_energy + 1e-6
    # Nearly full force all the time (bang-bang): most intervals at a limit.
    at_limit = np.mean((traj.forces > 0.97 * P.force_max) | (traj.forces < 0.97 * P.force_min))
    assert at_limit > 0.5
    # Independent check: the plan's forces replayed on the model with a 4x finer RK4
    # land where the plan says (up to the coarse grid's integration error).
    s = np.array(problem.start)
    f = to.casadi_step(to.casadi_dynamics(P), 8)
    for u in traj.forces:
        s = np.array(f(s, u, traj.dt)).ravel()
    np.testing.assert_allclose(s, end, atol=0.05)
    if case != 'upright_at_rest':
        assert to.in_region(s, problem, slack=1.1)


def test_problem_refuses_bad_input():
    with pytest.raises(ValueError, match='off the rail'):
        to.MinimumTimeProblem(P, (1.0, math.pi, 0.0, 0.0))
    with pytest.raises(ValueError, match='force_scale'):
        to.MinimumTimeProblem(P, (0.0, math.pi, 0.0, 0.0), force_scale=1.5)
    with pytest.raises(ValueError, match='4 finite'):
        to.MinimumTimeProblem(P, (0.0, math.nan, 0.0, 0.0))
    with pytest.raises(ValueError, match='n_intervals'):
        to.solve_minimum_time(to.bound_problem('middle', P), n_intervals=2)
    with pytest.raises(ValueError, match='unknown bound case'):
        to.bound_problem('top', P)


def test_key_depends_on_parameters_start_and_grid():
    a = to.bound_problem('left_stop', P)
    assert a.key(0.005) == to.bound_problem('left_stop', CartPoleParameters()).key(0.005)
    assert a.key(0.005) != a.key(None)
    assert a.key() != to.bound_problem('middle', P).key()
    assert a.key() != to.bound_problem('left_stop', P.replace(m_p=0.2)).key()
    assert a.key() != dataclasses.replace(a, force_scale=0.9).key()


def test_problem_round_trips_through_its_json_description():
    import json
    problem = dataclasses.replace(to.bound_problem('left_stop', P.replace(m_p=0.2)),
                                  region=to.CatchRegion(angle=0.1), terminal_cart_window=0.1,
                                  terminal_hold=0.15, force_scale=0.9)
    again = to.MinimumTimeProblem.from_dict(json.loads(json.dumps(problem.to_dict())))
    assert again == problem and again.key(0.005) == problem.key(0.005)


@pytest.mark.slow  # the bounds fixture solves the optimisation (seconds of CPU)
def test_tracking_gains_stabilise_the_linearised_error(bounds):
    """TV-LQR along a bound solution: a perturbed start converges to the plan on the model."""
    problem = to.bound_problem('middle', P)
    plan = bounds['middle']
    gains = tracking_gains(problem, plan, (300.0, 300.0, 10.0, 10.0), 0.02)
    assert gains.shape == (len(plan.forces), 4)
    step = to.casadi_step(to.casadi_dynamics(P), 2)
    s = np.array(problem.start) + np.array([0.02, 0.03, 0.0, 0.0])
    s_open = s.copy()
    for k, u in enumerate(plan.forces):
        s = np.array(step(s, u - gains[k] @ (s - plan.states[k]), plan.dt)).ravel()
        s_open = np.array(step(s_open, u, plan.dt)).ravel()
    err = np.abs(s - plan.states[-1])
    assert err[0] < 0.02 and err[1] < 0.05
    assert np.abs(s_open - plan.states[-1])[1] > 3 * err[1]
