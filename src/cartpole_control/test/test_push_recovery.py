"""The physical limit for pushes (cartpole_control.push_recovery), on coarse grids.

The bounds of docs/robustness.md are computed on the fine grid (5 ms during and
after the push, 10 ms later, 3 s); these tests use a 10 ms / 50 ms grid over 2 s
so that each NLP builds and solves in about a second (the NLPs are built once,
``recovery_nlp``, and shared by the tests).
"""
import math

import numpy as np
import pytest

from cartpole_control import push_recovery as pr
from cartpole_core.model import CartPoleParameters, accelerations, torque_accelerations

P = CartPoleParameters()
COARSE = dict(horizon=2.0, push_step=0.01, step=0.05, fine_time=0.2)


def coarse(target: str, **changes) -> pr.PushRecoveryProblem:
    return pr.PushRecoveryProblem(P, target, **{**COARSE, **changes})


@pytest.fixture(scope='module')
def cart_fall_nlp():
    return pr.recovery_nlp(coarse('cart', max_angle=pr.FALL_ANGLE))


def test_push_widths_and_limits_are_the_grids():
    """The pushes are those of the robustness grid, the angle limit the fall detector's."""
    robustness = pytest.importorskip('cartpole_tools.bench.robustness')
    assert pr.PUSH_WIDTHS == {'cart': robustness.CART_PUSH_WIDTH,
                              'pendulum': robustness.PENDULUM_PUSH_WIDTH}
    from cartpole_control.manager_parameters import manager_parameter_specs
    specs = {s.name: s.default for s in manager_parameter_specs(P, P.sample_time)}
    assert math.degrees(pr.FALL_ANGLE) == pytest.approx(specs['fall.angle_deg'])
    assert pr.RAIL_GUARD_MARGIN == pytest.approx(specs['rail.margin'])


def test_grid_covers_the_push_and_the_horizon():
    problem = coarse('cart')
    h = problem.grid()
    assert h.sum() == pytest.approx(2.0)
    n = problem.pushed_intervals()
    assert h[:n].sum() == pytest.approx(problem.width)
    assert np.all(h <= 0.05 + 1e-12)
    with pytest.raises(ValueError):
        pr.PushRecoveryProblem(P, 'wheel')
    with pytest.raises(ValueError):
        pr.PushRecoveryProblem(P, 'cart', rail_margin=0.5)


def test_momentum_bound_is_the_stopping_distance_of_the_centre_of_mass():
    """At the closed-form bound, a point mass M = m_c + m_p pushed with P / w over w and
    braked with |F_min| + c_c,R from t = 0 stops exactly where the room ends
    (integrated numerically, independently of the formula)."""
    m = P.m_c + P.m_p
    brake = -P.force_min + P.c_c_right
    for margin, angle in ((0.0, None), (0.02, pr.FALL_ANGLE)):
        bound = pr.cart_push_momentum_bound(P, 0.1, margin, angle)
        dt, v, x, t = 1e-6, 0.0, 0.0, 0.0
        while True:
            a = ((bound / 0.1 if t < 0.1 else 0.0) - brake) / m
            if t > 0.1 and v + a * dt <= 0.0:
                break
            x += v * dt + 0.5 * a * dt * dt
            v += a * dt
            t += dt
        lean = 1.0 if angle is None else math.sin(angle)
        room = P.travel - margin - P.x_middle + P.m_p * P.l * lean / m
        assert x == pytest.approx(room, rel=1e-4)
    # Less room, a lower bound.
    assert (pr.cart_push_momentum_bound(P, 0.1, 0.02, pr.FALL_ANGLE)
            < pr.cart_push_momentum_bound(P, 0.1, 0.02)
            < pr.cart_push_momentum_bound(P, 0.1, 0.0))


def test_casadi_push_model_is_the_plants(cart_fall_nlp):
    """The push enters as the plant's: an extra force on the cart, M^-1 [0, tau] on theta."""
    f = pr.casadi_push_dynamics(P, friction=False)
    for state, force, torque in (((0.3, 0.4, 0.5, -2.0), 20.0, 0.0),
                                 ((0.5, -0.3, -0.4, 1.0), -10.0, 2.5)):
        got = np.array(f(state, force, torque)).ravel()
        a, b = accelerations(*state, force, P, friction=False)
        da, db = torque_accelerations(state[1], torque, P)
        np.testing.assert_allclose(got, [state[2], state[3], a + da, b + db], rtol=1e-12)


def replay(problem, recovery, until: float):
    """The solution's forces and the push, simulated at 0.5 ms on the plant's model."""
    n_push = problem.pushed_intervals()
    push = recovery.impulse / problem.width
    s = np.array([problem.start_x, 0.0, 0.0, 0.0])
    for k, h in enumerate(np.diff(recovery.times)):
        if recovery.times[k] >= until - 1e-9:
            return s, k
        force = recovery.forces[k] + (push if k < n_push and problem.target == 'cart' else 0.0)
        torque = push if k < n_push and problem.target == 'pendulum' else 0.0

        def d(y):
            a, b = accelerations(*y, force, P, friction=False)
            da, db = torque_accelerations(y[1], torque, P)
            return np.array([y[2], y[3], a + da, b + db])
        m = int(round(h / 5e-4))
        for _ in range(m):
            k1 = d(s)
            k2 = d(s + 2.5e-4 * k1)
            k3 = d(s + 2.5e-4 * k2)
            k4 = d(s + 5e-4 * k3)
            s = s + 5e-4 / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
    return s, len(recovery.forces)


@pytest.mark.parametrize('target,impulse', [('cart', 4.0), ('pendulum', 0.03)])
def test_a_push_well_below_the_bound_is_recovered_on_the_plant_model(target, impulse):
    """Feasible; the solution's forces replayed on cartpole_core.model (frictionless, so the
    same equations) follow its states; the recovery stays on the rail and ends upright at
    rest; a pendulum pushed towards increasing theta (leaning left) makes the cart go left."""
    problem = coarse(target, max_angle=pr.FALL_ANGLE, friction=False)
    nlp = pr.recovery_nlp(problem)
    r, _ = nlp.elastic(impulse)
    assert r.feasible, r.status
    s = r.states
    assert s[:, 0].min() >= -1e-6 and s[:, 0].max() <= P.travel + 1e-6
    assert np.abs(s[:, 1]).max() <= pr.FALL_ANGLE + 1e-6
    np.testing.assert_allclose(s[-1, 1:], 0.0, atol=1e-6)
    assert min(P.force_min, r.forces.min()) >= P.force_min - 1e-6
    assert r.forces.max() <= P.force_max + 1e-6
    simulated, k = replay(problem, r, 0.6)  # open loop: unstable, so a short stretch
    np.testing.assert_allclose(simulated, s[k], atol=2e-3)
    if target == 'pendulum':
        assert s[:, 0].min() < problem.start_x - 0.05


def test_a_push_well_above_the_bound_is_not(cart_fall_nlp):
    """12 N s on the cart cannot be recovered without a fall (the bound is 7.8 N s); 17 N s
    not at all, being above the momentum bound (15 N s): the slack stays positive."""
    r, _ = cart_fall_nlp.elastic(12.0)
    assert not r.feasible and r.violation > 0.05
    free = pr.recovery_nlp(coarse('cart'))
    assert pr.cart_push_momentum_bound(P) < 17.0
    r, _ = free.elastic(17.0, 'brake')  # the start that finds the bound without a limit
    assert not r.feasible


def test_bound_with_the_fall_limit_is_below_the_bound_without_and_the_momentum_bound():
    """The cart bounds on the coarse grid (5 %): with |theta| <= 45 deg <= without (the
    pendulum let go and swung up again) <= the closed-form momentum bound; and the rail
    guard's margin lowers the bound."""
    fall = pr.largest_push(coarse('cart', max_angle=pr.FALL_ANGLE), rel_tol=0.05,
                           starts=((0.5, 'rest'),), retry_from_rest=False)
    free = pr.largest_push(coarse('cart'), rel_tol=0.05, starts=((0.6, 'brake'),),
                           retry_from_rest=False)
    momentum = pr.cart_push_momentum_bound(P)
    assert 6.5 < fall.impulse < 9.0
    assert fall.impulse <= free.impulse <= momentum
    assert free.impulse > 0.85 * momentum  # letting the pendulum go uses nearly all the rail
    assert fall.recovery.feasible and free.recovery.feasible
    assert fall.infeasible <= 1.05 * fall.impulse * (1 + 1e-6)
    assert np.abs(fall.recovery.states[:, 1]).max() <= pr.FALL_ANGLE + 1e-6


def test_behind_the_rail_guard_a_controller_that_reacts_late_keeps_the_envelope_and_recovers_less():
    """With ``guard`` every node's stopping position, by the rail guard's own model, stays
    inside its limiter's boundary (margin + reserve = 0.07 m); with ``reaction`` the force is
    zero until then. A 0.04 N m s pendulum push is recovered that way (30 ms late); 0.065,
    which the 0.02 m margin alone allows (bound 0.0629 on the fine grid; without the
    reaction and the envelope), is not."""
    from cartpole_control.rail_guard import RailGuard
    problem = coarse('pendulum', max_angle=pr.FALL_ANGLE, rail_margin=pr.RAIL_GUARD_MARGIN,
                     guard=True, reaction=0.03)
    nlp = pr.recovery_nlp(problem)
    r, _ = nlp.elastic(0.04)
    assert r.feasible, r.status
    blind = r.times[:-1] < 0.03 - 1e-9
    assert blind.sum() == 3 and np.all(r.forces[blind] == 0.0) and r.forces[3] < -10.0
    guard = RailGuard(P, margin=pr.RAIL_GUARD_MARGIN, limit_reserve=pr.GUARD_RESERVE)
    stops = [guard.stopping_position(x, v, w, 0.0) for x, _, v, w in r.states[1:]]
    inner = pr.RAIL_GUARD_MARGIN + pr.GUARD_RESERVE
    assert min(stops) >= inner - 1e-5 and max(stops) <= P.travel - inner + 1e-5
    assert min(stops) < inner + 0.005  # the envelope binds: the recovery uses it all
    late, _ = nlp.elastic(0.065)
    assert not late.feasible and late.violation > 0.05
