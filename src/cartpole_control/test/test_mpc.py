"""The mpc stabiliser: the unconstrained MPC is the terminal LQR, the rail constraint keeps the
cart where the LQR leaves it, the QP is built once per configure, a failed solve falls back."""
import functools
import math

import numpy as np
import pytest

from cartpole_control.controller import ControlContext, ControllerState
from cartpole_control.controllers.lqg import augmented_model
from cartpole_control.controllers.mpc import MpcStabilizer
from cartpole_control.manager import ControllerManager
from cartpole_control.mpc_qp import CondensedQp, discretise
from cartpole_core.model import CartPoleParameters, linearise_upright

P = CartPoleParameters()
CONTEXT = ControlContext(plant=P, x_ref=P.x_middle, sample_time=P.sample_time)


def configured(**gains):
    plugin = MpcStabilizer()
    plugin.configure(gains, CONTEXT)
    return plugin


def z_of(plugin, state):
    return np.array([state.x - CONTEXT.x_ref, state.theta_w, state.x_dot, state.theta_dot,
                     plugin.integral])


@pytest.mark.parametrize('solver', ['daqp', 'casadi_qpoases'])
def test_without_an_active_constraint_the_mpc_is_the_terminal_lqr(solver):
    plugin = configured(solver=solver, budget_us=1e6)  # the first qpOASES call is slow
    start = ControllerState(0.0, P.x_middle, 0.0, 0.0, 0.0)
    plugin.activate(start)
    rng = np.random.default_rng(4)
    for k in range(1, 9):
        dx, th, dxd, thd = rng.normal(size=4) * [0.01, 0.003, 0.02, 0.02]
        state = ControllerState(k * P.sample_time, P.x_middle + dx, th, dxd, thd)
        u = plugin.update(state)
        lqr = -float(plugin.gain @ z_of(plugin, state))
        assert abs(u) < 20.0 and abs(u - lqr) < 1e-6, (k, u, lqr)
    assert plugin.status_values()['mpc_fallbacks'] == 0


def test_the_terminal_lqr_is_the_discrete_lqi_of_the_same_weights():
    plugin = configured()
    a, b = augmented_model(*linearise_upright(P))
    a_d, b_d = discretise(a, b, P.sample_time)
    k = plugin.gain[np.newaxis]
    # stable, and close to the continuous LQI's gain of the same weights (sampled at 5 ms)
    assert np.max(np.abs(np.linalg.eigvals(a_d - b_d @ k))) < 1.0
    from cartpole_control.controllers.lqg import LqgStabilizer
    lqi = LqgStabilizer()
    lqi.configure({}, CONTEXT)
    continuous = np.append(lqi.gain, lqi.integral_gain)
    np.testing.assert_allclose(plugin.gain, continuous, rtol=0.15)


def _linear_run(law, z0, steps=600):
    """The discretised linear model closed with ``law(z) -> u``, forces saturated as the
    manager saturates the raw force (feedforward left out)."""
    a, b = augmented_model(*linearise_upright(P))
    a_d, b_d = discretise(a, b, P.sample_time)
    z = np.array(z0, dtype=float)
    out = [z.copy()]
    for _ in range(steps):
        u = min(max(law(z), P.force_min), P.force_max)
        z = a_d @ z + b_d[:, 0] * u
        out.append(z.copy())
    return np.array(out)


def test_the_mpc_keeps_the_cart_inside_the_guard_boundary_where_the_lqr_leaves_it():
    """On the discretised linear model: the cart at rest 25 cm right of x*, the pendulum 2.9 deg
    right of upright and falling right at 0.3 rad/s. To catch it the terminal LQR (the same
    weights, unconstrained, the force saturated) runs the cart 1.4 cm past the rail guard's
    limiter boundary (travel - margin - reserve = 0.699 m); the MPC stays within 3 mm of it,
    the pendulum up, and then brings the cart back to x* (it does not stay parked there)."""
    plugin = configured(budget_us=1e6)  # a solve slowed by a busy machine is not replaced
    qp = plugin.qp                       # by the LQR's force: the run is reproducible
    high = P.travel - CONTEXT.rail_margin - CONTEXT.rail_reserve - CONTEXT.x_ref
    z0 = [0.25, -0.05, 0.0, -0.3, 0.0]
    lqr = _linear_run(lambda z: -float(plugin.gain @ z), z0)
    mpc = _linear_run(lambda z: qp.solve(z, P.force_min, P.force_max).force, z0, steps=1600)
    assert lqr[:, 0].max() > high + 0.01
    assert mpc[:, 0].max() <= high + 0.003
    assert np.abs(mpc[:, 1]).max() < math.radians(8.0)
    assert abs(mpc[-1, 0]) < 0.02                                  # back at x* after 8 s


@functools.lru_cache(maxsize=None)
def _after_a_6_ns_cart_push(stabilizer):
    """Per seed 0-11: (recovered, end-stop contact) after a 6 N s cart push at 12 s (0.1 s at
    60 N, the robustness grid's level); recovered: the pendulum still up 4 s later, no fault,
    no end-stop contact. The MPC's budget is off, so that no solve falls back because the
    machine is busy: the runs are reproducible."""
    from cartpole_bringup.offline.closed_loop import run_closed_loop
    from cartpole_sim.plant import Push, Scenario

    out = []
    parameters = {'stabilizer': stabilizer, 'mpc.budget_us': 1e6}
    for seed in range(12):
        run = run_closed_loop(P, Scenario(noise=True, seed=seed,
                                          pushes=(Push(12.0, 'cart', 60.0, 0.1),)),
                              duration=16.0, manager_parameters=parameters,
                              stop_on_failure=True)
        catch = run.catch_time
        falls = [t for t, e in run.events if e == 'fall' and catch is not None and t > catch]
        faults = [e for _, e in run.events if e.startswith('fault:')]
        out.append((catch is not None and not falls and not faults and not run.end_stop_contact,
                    run.end_stop_contact))
    return tuple(out)


@pytest.mark.slow
def test_after_a_6_ns_cart_push_the_mpc_never_drives_the_cart_into_an_end_stop():
    """Safety first, whether the pendulum is kept or not (it is in 3 of 12 seeds, as with
    lqg: docs/robustness.md): the rail constraint and the guard keep the cart off the stops."""
    runs = _after_a_6_ns_cart_push('mpc')
    assert not any(contact for _, contact in runs)
    assert 0 < sum(recovered for recovered, _ in runs) < len(runs)  # the level is marginal


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason='the 6 N s cart push is recovered in 3 of 12 seeds only: '
                   'it is 90 % of what a controller that sees the push after 20 ms can recover '
                   'behind the rail guard (6.66 N s, docs/robustness.md, "Behind the rail '
                   'guard, reacting to what the encoders show")')
def test_the_mpc_recovers_from_a_6_ns_cart_push():
    assert all(recovered for recovered, _ in _after_a_6_ns_cart_push('mpc'))


def test_the_qp_is_built_once_per_configure_and_never_in_update():
    before = CondensedQp.constructions
    plugin = configured()
    assert CondensedQp.constructions == before + 1
    plugin.activate(ControllerState(0.0, P.x_middle, 0.02, 0.0, 0.0))
    for k in range(200):
        plugin.update(ControllerState(k * P.sample_time, P.x_middle + 0.001 * k, 0.02, 0.3, 0.0))
    plugin.deactivate()
    plugin.activate(ControllerState(2.0, P.x_middle, 0.0, 0.0, 0.0))
    plugin.update(ControllerState(2.005, P.x_middle, 0.0, 0.0, 0.0))
    assert CondensedQp.constructions == before + 1
    plugin.configure({'horizon': 40}, CONTEXT)
    assert CondensedQp.constructions == before + 2


def test_a_failed_solve_applies_the_terminal_lqr_and_is_counted():
    plugin = configured()
    state = ControllerState(0.0, P.x_middle + 0.01, 0.02, 0.1, -0.1)
    plugin.activate(state)
    plugin.qp.backend.solve = lambda: (math.nan, False, 'injected failure')
    u = plugin.update(state)
    assert u == pytest.approx(-float(plugin.gain @ z_of(plugin, state)), abs=1e-9)
    assert plugin.status_values() == {'mpc_solve_us': pytest.approx(plugin.solve_us),
                                      'mpc_fallbacks': 1}

    def raises():
        raise RuntimeError('solver crashed')
    plugin.qp.backend.solve = raises
    u = plugin.update(ControllerState(0.005, P.x_middle + 0.01, 0.02, 0.1, -0.1))
    assert math.isfinite(u) and plugin.status_values()['mpc_fallbacks'] == 2


def test_bad_gains_are_refused_with_the_reason():
    with pytest.raises(ValueError, match='integral weight'):
        configured(q=(10.0, 10000.0, 10.0, 1.0, 0.0))
    with pytest.raises(ValueError, match='block'):
        configured(horizon=4, block=5)
    with pytest.raises(ValueError, match='solver'):
        configured(solver='gurobi')


def test_the_manager_switches_lqg_to_mpc_bumplessly_and_the_integrator_starts_at_zero():
    manager = ControllerManager(P, sample_time=P.sample_time, real_time=False)
    out = manager.update_values(0.0, P.x_middle, 0.02, 0.0, 0.0)
    assert out.mode == 'stabilizing' and out.stabilizer == 'lqg'
    assert manager.set_parameters({'stabilizer': 'mpc'}).successful
    out = manager.update_values(0.005, P.x_middle, 0.02, 0.0, 0.0)
    mpc = manager.active_plugins()['stabilizer']
    assert out.stabilizer == 'mpc' and 'switch:stabilizer=mpc' in out.event
    assert mpc.active and mpc.integral == 0.0
    assert out.raw_force == pytest.approx(-mpc.gain[1] * 0.02, abs=1e-6)
