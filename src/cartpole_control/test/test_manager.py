"""ControllerManager: parameters and refusals, queued bumpless switching, feedforward,
saturation, catch/fall, faults, rail guard, and closed loops on the simulated plant."""
import math

import pytest

from cartpole_control.controller import (STABILIZER, SWINGUP, Controller, ControllerState,
                                         ParameterSpec)
from cartpole_control.feedforward import FrictionFeedforward
from cartpole_control.manager import (FAULT, IDLE, STABILIZING, SWINGUP_MODE, ControllerManager,
                                      ManagerOutput)
from cartpole_sim.model import CartPoleParameters, accelerations, wrap_angle
from cartpole_sim.plant import Plant, Scenario

P = CartPoleParameters()
TS = P.sample_time


# -- test plugins --------------------------------------------------------------------------
class Recording(Controller):
    """Returns the gain ``force``; records its lifecycle calls."""

    parameters = (ParameterSpec('force', 0.0, 'constant force [N]', low=-100.0, high=100.0),
                  ParameterSpec('limit', 100.0, 'refuse |force| above this', low=0.0, high=100.0))

    def __init__(self):
        super().__init__()
        self.calls = []
        self.hook = None

    def on_configure(self):
        if abs(self.gains['force']) > self.gains['limit']:
            raise ValueError(f"force {self.gains['force']} exceeds limit {self.gains['limit']}")

    def activate(self, state):
        super().activate(state)
        self.calls.append(('activate', state.t))

    def deactivate(self):
        super().deactivate()
        self.calls.append(('deactivate',))

    def update(self, state):
        self.calls.append(('update', state.t))
        if self.hook is not None:
            self.hook(state)
        return self.gains['force']


class Listening(Recording):
    """Records what the manager reports about its command (the anti-windup hook)."""

    kind, name = STABILIZER, 'listening'

    def command_applied(self, feedback):
        self.calls.append(('feedback', feedback))


class Deaf(Listening):
    kind, name = STABILIZER, 'deaf'

    def command_applied(self, feedback):
        raise RuntimeError('bad hook')


class PushA(Recording):
    kind, name = SWINGUP, 'push_a'


class PushB(Recording):
    kind, name = SWINGUP, 'push_b'


class HoldA(Recording):
    kind, name = STABILIZER, 'hold_a'


class HoldB(Recording):
    kind, name = STABILIZER, 'hold_b'


class Broken(Recording):
    kind, name = STABILIZER, 'broken'

    def update(self, state):
        raise RuntimeError('division by zero in the law')


REGISTRY = {SWINGUP: {'push_a': PushA, 'push_b': PushB},
            STABILIZER: {'hold_a': HoldA, 'hold_b': HoldB, 'broken': Broken,
                         'listening': Listening, 'deaf': Deaf}}


def make(**params):
    params.setdefault('stabilizer', 'hold_a')
    return ControllerManager(P, TS, registry=REGISTRY, **params)


def state(t=0.0, x=None, theta=math.pi, x_dot=0.0, theta_dot=0.0):
    return ControllerState(t, P.x_middle if x is None else x, theta, x_dot, theta_dot)


def upright(t=0.0, theta=0.05, **kw):
    return state(t, theta=theta, **kw)


def plugin(manager, kind):
    return manager.active_plugins()[kind]


# -- parameters ----------------------------------------------------------------------------
def test_parameter_specs_cover_manager_and_every_plugin():
    m = make()
    specs = m.parameter_specs()
    for name in ('swingup', 'stabilizer', 'enabled', 'x_ref', 'catch.energy_tolerance',
                 'catch.angle_deg', 'fall.angle_deg', 'feedforward.right', 'feedforward.left',
                 'feedforward.steepness', 'rail.margin', 'rail.max_brake_force', 'state_timeout'):
        assert name in specs
    for plugin_name in ('push_a', 'push_b', 'hold_a', 'hold_b', 'broken'):
        assert f'{plugin_name}.force' in specs and f'{plugin_name}.limit' in specs
    assert specs['swingup'].choices == ('push_a', 'push_b')
    values = m.get_parameters()
    assert values['catch.energy_tolerance'] == 0.05 and values['catch.angle_deg'] == 30.0
    assert values['feedforward.right'] == 3.3 and values['feedforward.left'] == 2.8
    assert values['x_ref'] == pytest.approx(P.travel / 2)
    assert values['enabled'] is True


def test_defaults_with_the_installed_plugins():
    m = ControllerManager(P)
    values = m.get_parameters()
    assert values['swingup'] == 'pendulum_energy' and values['stabilizer'] == 'lqg'
    assert set(m.registered(SWINGUP)) >= {'pendulum_energy', 'full_energy', 'sign_based'}
    assert set(m.registered(STABILIZER)) >= {'pid', 'lqg', 'smc'}
    assert values['lqg.r'] == 0.01 and values['smc.poles'][0] == -1.0
    assert 'pendulum_energy.k_e' in m.parameter_specs()


def test_unknown_controller_is_refused_with_the_list_and_nothing_changes():
    m = make(stabilizer='hold_a')
    m.update(upright(0.0))
    before = m.get_parameters()
    result = m.set_parameters({'x_ref': 0.3, 'stabilizer': 'mpc'})
    assert not result.successful
    assert "'mpc'" in result.reason and "['broken', 'deaf', 'hold_a', 'hold_b', 'listening']" in result.reason
    assert m.get_parameters() == before
    out = m.update(upright(TS))
    assert out.stabilizer == 'hold_a' and out.event == ''


@pytest.mark.parametrize('changes, words', [
    ({'no_such': 1.0}, ['unknown parameter', 'no_such']),
    ({'catch.angle_deg': 120.0}, ['above its maximum']),
    ({'catch.angle_deg': 'thirty'}, ['must be a number']),
    ({'enabled': 1}, ['must be a bool']),
    ({'fall.angle_deg': 20.0}, ['fall angle', 'larger than the catch angle']),
    ({'hold_b.limit': 5.0, 'hold_b.force': 8.0}, ['hold_b', 'exceeds limit']),  # on_configure
    ({'hold_b.force': 10.0, 'x_ref': -1.0}, ['x_ref', 'below its minimum']),  # atomic
])
def test_bad_changes_are_refused_with_a_reason_and_change_nothing(changes, words):
    m = make()
    before = m.get_parameters()
    result = m.set_parameters(changes)
    assert not result.successful
    for word in words:
        assert word in result.reason
    assert m.get_parameters() == before
    assert plugin(m, STABILIZER).gains['force'] == 0.0


def test_refused_gain_keeps_the_old_one_in_the_running_plugin():
    m = make(stabilizer='hold_a', **{'hold_a.force': 2.0})
    assert m.update(upright(0.0)).raw_force == 2.0
    assert not m.set_parameters({'hold_a.limit': 1.0}).successful
    assert m.get_parameters()['hold_a.force'] == 2.0
    assert m.update(upright(TS)).raw_force == 2.0


def test_initial_parameters_are_validated():
    with pytest.raises(ValueError, match='unknown swingup controller'):
        make(swingup='bang_bang')
    with pytest.raises(ValueError, match='exceeds limit'):
        make(**{'hold_a.force': 60.0, 'hold_a.limit': 50.0})


def test_gains_of_inactive_plugins_can_be_set_and_are_used_on_switch():
    m = make(stabilizer='hold_a')
    assert m.set_parameters({'hold_b.force': 7.0}).successful
    m.update(upright(0.0))
    assert m.set_parameters({'stabilizer': 'hold_b'}).successful
    out = m.update(upright(TS))
    assert out.stabilizer == 'hold_b' and out.raw_force == 7.0


# -- queued, bumpless switching -----------------------------------------------------------------
def test_changes_are_applied_between_updates_not_in_the_middle():
    m = make(stabilizer='hold_a', **{'hold_a.force': 1.0})
    m.update(upright(0.0))
    running = plugin(m, STABILIZER)
    results = []

    def mid_cycle(_state):  # a request arriving while update() runs
        results.append(m.set_parameters({'hold_a.force': 5.0, 'stabilizer': 'hold_b'}))
        running.hook = None
    running.hook = mid_cycle
    out = m.update(upright(TS))
    assert results[0].successful
    assert out.raw_force == 1.0 and out.stabilizer == 'hold_a' and out.event == ''
    assert m.get_parameters()['stabilizer'] == 'hold_b'  # accepted, queued
    out = m.update(upright(2 * TS))
    assert out.stabilizer == 'hold_b' and out.event == 'switch:stabilizer=hold_b'
    assert out.mode == STABILIZING


def test_switching_the_stabiliser_while_stabilising_is_bumpless():
    m = make(stabilizer='hold_a')
    m.update(upright(0.0))
    old = plugin(m, STABILIZER)
    assert m.set_parameters({'stabilizer': 'hold_b'}).successful
    m.update(upright(TS))
    new = plugin(m, STABILIZER)
    assert isinstance(new, HoldB) and new.active and not old.active
    assert old.calls[-1] == ('deactivate',)
    assert new.calls[:2] == [('activate', TS), ('update', TS)]  # activated from this state


def test_switching_the_swingup_while_swinging_takes_effect_next_cycle():
    m = make(swingup='push_a', **{'push_a.force': 1.0, 'push_b.force': -1.0})
    assert m.update(state(0.0)).raw_force == 1.0
    assert m.set_parameters({'swingup': 'push_b'}).successful
    out = m.update(state(TS))
    assert (out.mode, out.swingup, out.raw_force) == (SWINGUP_MODE, 'push_b', -1.0)
    assert out.event == 'switch:swingup=push_b'


def test_switching_the_inactive_kind_does_not_activate_it():
    m = make(swingup='push_a')
    m.update(state(0.0))
    assert m.set_parameters({'stabilizer': 'hold_b'}).successful
    out = m.update(state(TS))
    assert out.mode == SWINGUP_MODE and out.stabilizer == 'hold_b'
    assert not plugin(m, STABILIZER).active and plugin(m, SWINGUP).active


def test_gain_change_reconfigures_the_running_plugin_without_reactivation():
    m = make(swingup='push_a')
    m.update(state(0.0))
    live = plugin(m, SWINGUP)
    assert m.set_parameters({'push_a.force': 3.0}).successful
    assert m.update(state(TS)).raw_force == 3.0
    assert plugin(m, SWINGUP) is live and [c for c in live.calls if c[0] == 'activate'] == [
        ('activate', 0.0)]


# -- feedforward (6.12) and saturation ---------------------------------------------------------
@pytest.mark.parametrize('x_dot, u, expected', [
    (0.0, 1.0, 3.3), (0.5, 1.0, 3.3), (0.5, -1.0, -3.3), (-0.5, 1.0, 2.8), (-0.5, -1.0, -2.8),
    (0.0, 0.0, 0.0), (0.2, 0.01, 3.3 * math.tanh(0.2))])
def test_feedforward_signs_and_magnitudes(x_dot, u, expected):
    assert FrictionFeedforward(3.3, 2.8, 20.0)(x_dot, u) == pytest.approx(expected, abs=1e-9)


def test_manager_adds_feedforward_to_the_raw_force():
    m = make(swingup='push_a', **{'push_a.force': -2.0, 'feedforward.steepness': 50.0})
    out = m.update(state(0.0, x_dot=-0.3))
    assert out.raw_force == -2.0
    assert out.feedforward == pytest.approx(-2.8)
    assert out.force == pytest.approx(-4.8)
    m.set_parameters({'feedforward.left': 1.0})
    out = m.update(state(TS, x_dot=-0.3))
    assert out.force == pytest.approx(-3.0)


@pytest.mark.parametrize('raw, expected', [(100.0, P.force_max), (-100.0, P.force_min),
                                           (20.0, 20.0 + 3.3)])
def test_force_is_saturated_to_the_amplifier(raw, expected):
    m = make(swingup='push_a', **{'push_a.force': raw})
    out = m.update(state(0.0))
    assert out.force == pytest.approx(expected)
    assert P.force_max == pytest.approx(34.246, abs=1e-3)
    assert P.force_min == pytest.approx(-37.360, abs=1e-3)


def test_model_accelerations_under_the_last_force_reach_the_plugin():
    m = make(swingup='push_a', **{'push_a.force': 4.0})
    seen = []
    m.update(state(0.0))
    plugin(m, SWINGUP).hook = seen.append
    s = state(TS, theta=2.5, x_dot=0.2, theta_dot=1.0)
    last = m.update(state(0.0)).force
    m.update(s)
    expected = accelerations(s.x, s.theta, s.x_dot, s.theta_dot, last, P)
    assert (seen[-1].x_ddot, seen[-1].theta_ddot) == pytest.approx(expected)


# -- catch trigger and fall detector ----------------------------------------------------------------
def orbit_rate(theta):
    """theta_dot on the heteroclinic orbit (6.10): E_p = E*."""
    return -math.sqrt(2 * P.g / P.l * (1 - math.cos(theta)))


def test_catch_fires_exactly_on_the_conditions():
    m = make()
    t = 0.0
    for deg in (60.0, 31.0):  # energy right, angle not yet
        theta = math.radians(deg)
        out = m.update(state(t, theta=theta, theta_dot=orbit_rate(theta)))
        assert out.mode == SWINGUP_MODE and out.catch_count == 0
        t += TS
    theta = math.radians(20.0)
    out = m.update(state(t, theta=theta, theta_dot=orbit_rate(theta) * 2.0))  # energy 9 % high
    assert out.mode == SWINGUP_MODE and abs(out.energy_error) > 0.05 * P.upright_energy
    t += TS
    theta = math.radians(29.0)
    out = m.update(state(t, theta=theta, theta_dot=orbit_rate(theta)))
    assert (out.mode, out.event, out.catch_count, out.catch_time) == (STABILIZING, 'catch', 1, t)
    assert out.energy_error == pytest.approx(0.0, abs=1e-9)
    assert out.raw_force == plugin(m, STABILIZER).gains['force']
    assert not plugin(m, SWINGUP).active and plugin(m, STABILIZER).active


def test_catch_is_latched_until_a_fall_then_rearmed():
    m = make()
    out = m.update(upright(0.0, theta=0.1))
    assert out.mode == STABILIZING
    # Energy far off and 40 deg: still stabilising (one-shot, hysteresis up to 45 deg).
    out = m.update(upright(TS, theta=math.radians(40.0), theta_dot=3.0))
    assert out.mode == STABILIZING and out.event == ''
    out = m.update(upright(2 * TS, theta=math.radians(-46.0)))
    assert (out.mode, out.event, out.fall_count) == (SWINGUP_MODE, 'fall', 1)
    assert plugin(m, SWINGUP).active and not plugin(m, STABILIZER).active
    out = m.update(upright(3 * TS, theta=0.0))
    assert (out.mode, out.catch_count, out.catch_time) == (STABILIZING, 2, 0.0)


def test_catch_thresholds_are_parameters():
    m = make(**{'catch.angle_deg': 10.0, 'fall.angle_deg': 20.0})
    assert m.update(upright(0.0, theta=math.radians(15.0),
                            theta_dot=orbit_rate(math.radians(15.0)))).mode == SWINGUP_MODE
    assert m.update(upright(TS, theta=math.radians(9.0),
                            theta_dot=orbit_rate(math.radians(9.0)))).mode == STABILIZING
    assert m.update(upright(2 * TS, theta=math.radians(21.0))).event == 'fall'


# -- faults, stale state, idle, restart ---------------------------------------------------------------
def test_stale_state_commands_zero_and_faults_until_restart():
    m = make(swingup='push_a', **{'push_a.force': 5.0})
    assert m.update(state(0.0)).force > 5.0
    out = m.stale(0.06)
    assert (out.force, out.mode, out.fault_reason, out.event) == (
        0.0, FAULT, 'stale state', 'fault:stale state')
    out = m.update(state(0.065))
    assert (out.force, out.mode, out.event) == (0.0, FAULT, '')
    answer = m.restart()
    assert answer.successful and answer.reason == (
        'fault (stale state) cleared; swing-up restarts at the next control cycle')
    out = m.update(state(0.07))
    assert (out.mode, out.event, out.fault_reason) == (SWINGUP_MODE, 'restart', '')
    assert out.force > 5.0


@pytest.mark.parametrize('bad', [dict(x=math.nan), dict(theta_dot=math.inf),
                                 dict(x_dot=-math.inf)])
def test_non_finite_state_faults_with_zero_force(bad):
    m = make(swingup='push_a', **{'push_a.force': 5.0})
    m.update(state(0.0))
    out = m.update(state(TS, **bad))
    assert (out.force, out.mode, out.fault_reason) == (0.0, FAULT, 'non-finite state')
    assert not plugin(m, SWINGUP).active


def test_a_plugin_that_raises_faults_with_zero_force():
    m = make(stabilizer='broken')
    out = m.update(upright(0.0))
    assert out.force == 0.0 and out.mode == FAULT
    assert 'broken failed' in out.fault_reason and 'division by zero' in out.fault_reason


def _feedback(manager):
    return [c[1] for c in plugin(manager, STABILIZER).calls if c[0] == 'feedback']


@pytest.mark.parametrize('force, limited', [(3.0, 0), (80.0, 1), (-80.0, -1)])
def test_the_plugin_hears_whether_its_force_was_cut_by_the_saturation(force, limited):
    m = make(stabilizer='listening', **{'listening.force': force})
    out = m.update(upright(0.0))
    assert out.mode == STABILIZING
    (fb,) = _feedback(m)
    assert (fb.raw, fb.force, fb.limited, fb.held) == (force, out.force, limited, False)
    assert fb.force == out.raw_force + out.feedforward if limited == 0 else abs(fb.force) < 38.0


def test_the_plugin_hears_the_rail_guard_withhold_a_push_into_the_stop():
    """At rest at the left stop and upright: a push left is withheld (limited from below)."""
    m = make(stabilizer='listening', **{'listening.force': -5.0})
    out = m.update(upright(0.0, x=0.0))
    assert out.force == 0.0 and m.guard_status == 'limited'
    (fb,) = _feedback(m)
    assert fb.limited == -1 and not fb.held and fb.force == 0.0


def test_a_plugin_without_the_hook_still_runs_and_one_that_raises_in_it_faults():
    m = make(stabilizer='hold_a', **{'hold_a.force': 2.0})     # the base class's hook: no-op
    assert m.update(upright(0.0)).mode == STABILIZING
    m = make(stabilizer='deaf', **{'deaf.force': 2.0})
    out = m.update(upright(0.0))
    assert out.mode == FAULT and out.force == 0.0 and 'bad hook' in out.fault_reason


def test_stabilisers_get_the_velocity_band_feedforward_swingups_the_thesis_one():
    ff = FrictionFeedforward(3.3, 2.8, 20.0, 0.01)
    assert ff.stabilizing(0.02, -1.0) == pytest.approx(3.3)     # moving right: along x_dot
    assert ff.stabilizing(-0.02, 1.0) == pytest.approx(-2.8)
    assert ff.stabilizing(0.0, 1.0) == pytest.approx(3.3 * math.tanh(20.0))  # at rest: (6.12)
    assert ff.stabilizing(0.005, -1.0) == pytest.approx(3.3 * (0.5 - 0.5 * math.tanh(20.0)))
    assert ff(0.02, -1.0) == pytest.approx(-3.3 * math.tanh(20.0))            # (6.12)
    assert FrictionFeedforward(3.3, 2.8, 20.0, 0.0).stabilizing(0.02, -1.0) == ff(0.02, -1.0)
    m = make(stabilizer='listening', swingup='push_a', **{'listening.force': -1.0,
                                                          'push_a.force': -1.0,
                                                          'feedforward.velocity_band': 0.01})
    swing = m.update(state(0.0, x_dot=0.05))
    assert swing.mode == SWINGUP_MODE and swing.feedforward == pytest.approx(-3.3 * math.tanh(20))
    held = m.update(upright(TS, x_dot=0.05))
    assert held.mode == STABILIZING and held.feedforward == pytest.approx(3.3)


def test_disable_gives_idle_and_zero_force_enable_restarts_swingup():
    m = make(swingup='push_a', **{'push_a.force': 5.0})
    m.update(state(0.0))
    assert m.set_parameters({'enabled': False}).successful
    out = m.update(state(TS))
    assert (out.mode, out.force, out.enabled) == (IDLE, 0.0, False)
    assert not plugin(m, SWINGUP).active
    m.set_parameters({'enabled': True})
    out = m.update(state(2 * TS))
    assert (out.mode, out.event, out.enabled) == (SWINGUP_MODE, 'restart', True)
    assert out.force > 5.0


def test_starts_idle_when_disabled_and_restart_keeps_it_idle():
    m = make(enabled=False)
    assert m.update(state(0.0)).mode == IDLE
    answer = m.restart()
    assert not answer.successful and 'nothing to restart' in answer.reason
    assert 'disabled' in answer.reason and 'fault' not in answer.reason
    out = m.update(state(TS))
    assert (out.mode, out.event) == (IDLE, '')


def test_restart_answers_truthfully_in_every_mode():
    m = make(swingup='push_a', **{'push_a.force': 5.0})
    m.update(state(0.0))
    running = m.restart()                                  # swing-up: nothing to do
    assert not running.successful and running.reason.startswith('already running (swingup)')
    assert m.update(state(TS)).event == ''
    m.set_parameters({'enabled': False})                   # being disabled, not yet applied
    assert 'being disabled' in m.restart().reason
    assert m.update(state(2 * TS)).mode == IDLE
    idle = m.restart()                                     # disabled: no fault to clear
    assert not idle.successful and 'fault' not in idle.reason
    assert m.update(state(3 * TS)).event == ''             # and no restart happens
    m.set_parameters({'enabled': True})
    assert m.update(state(4 * TS)).event == 'restart'      # enabling restarts, as documented
    m.stale(5 * TS)
    m.set_parameters({'enabled': False})                   # a fault, then disabled
    disabled_fault = m.restart()
    assert disabled_fault.successful and disabled_fault.reason.startswith(
        'fault (stale state) cleared; control is disabled')
    out = m.update(state(6 * TS))
    assert (out.mode, out.fault_reason) == (IDLE, '')


def test_reset_clears_counters():
    m = make()
    m.update(upright(0.0))
    m.update(upright(TS, theta=1.0))
    m.reset()
    out = m.update(state(2 * TS))
    assert (out.catch_count, out.fall_count, out.catch_time, out.mode) == (
        0, 0, None, SWINGUP_MODE)


def test_output_is_frozen():
    out = make().update(state(0.0))
    assert isinstance(out, ManagerOutput)
    with pytest.raises(Exception):
        out.force = 1.0


# -- closed loops on the simulated plant (true state as the estimate) --------------------------
def run(manager, plant, seconds, on_step=None):
    outs = []
    for k in range(int(round(seconds / TS))):
        if on_step is not None:
            on_step(k, plant)
        s = plant.true_state()
        out = manager.update(ControllerState(plant.t, *s))
        outs.append(out)
        plant.step(out.force)
    return outs


def test_rail_guard_overrides_a_controller_pushing_into_the_stop():
    m = make(swingup='push_a', **{'push_a.force': 100.0})
    plant = Plant(P, Scenario(x0=P.x_middle))
    outs = run(m, plant, 1.5)
    assert not plant.end_stop_contact
    assert outs[-1].mode == FAULT and outs[-1].fault_reason == 'rail guard'
    assert outs[-1].force == 0.0
    assert sum(o.event == 'fault:rail guard' for o in outs) == 1
    assert abs(plant.true_state()[2]) < 0.05
    assert min(o.force for o in outs) < -25.0  # it braked, not just zeroed
    # Restart re-arms: back to the (still pushing) swing-up, now at rest near the stop.
    m.set_parameters({'push_a.force': -2.0})
    m.restart()
    out = m.update(ControllerState(plant.t, *plant.true_state()))
    assert out.mode == SWINGUP_MODE and out.force < 0.0


def test_rail_guard_at_the_left_stop_at_rest_lets_the_swingup_start():
    """Default start (x = 0, at rest): no trip; pushing into the stop withheld, out allowed."""
    m = make(swingup='push_a', **{'push_a.force': -5.0})
    plant = Plant(P, Scenario())
    outs = run(m, plant, 0.2)
    assert all(o.force == 0.0 and o.mode == SWINGUP_MODE for o in outs)
    m.set_parameters({'push_a.force': 2.0})
    outs = run(m, plant, 0.5)
    assert outs[-1].mode == SWINGUP_MODE and plant.true_state()[0] > 0.03


def test_without_feedforward_the_swingup_never_leaves_the_left_stop():
    """SPEC section 7: the first centring push (~1.9 N) is below the 3.4 N Coulomb friction."""
    for steepness, moves in ((0.0, False), (20.0, True)):
        m = ControllerManager(P, **{'feedforward.steepness': steepness})
        plant = Plant(P, Scenario())
        outs = run(m, plant, 1.0)
        assert 1.5 < outs[0].raw_force < 2.5
        assert bool(plant.true_state()[0] > 0.01) is moves


def test_swingup_catch_and_switching_stabilisers_keeps_the_pendulum_up():
    m = ControllerManager(P)  # pendulum_energy + lqg
    plant = Plant(P, Scenario())
    outs = run(m, plant, 7.0)
    assert outs[-1].mode == STABILIZING and outs[-1].catch_count == 1
    assert 3.0 < outs[-1].catch_time < 7.0
    for name in ('smc', 'pid', 'lqg'):
        assert m.set_parameters({'stabilizer': name}).successful
        angles = []
        outs = run(m, plant, 2.5, lambda k, pl: angles.append(abs(wrap_angle(pl.state[1]))))
        assert outs[0].event == f'switch:stabilizer={name}' and outs[0].stabilizer == name
        assert all(o.mode == STABILIZING for o in outs)
        assert max(angles) < math.radians(3.0), name
    assert outs[-1].fall_count == 0 and not plant.end_stop_contact
    assert abs(plant.true_state()[0] - P.x_middle) < 0.1


def test_switching_the_swingup_while_swinging_keeps_swinging():
    m = ControllerManager(P, swingup='pendulum_energy')
    plant = Plant(P, Scenario(x0=P.x_middle))
    outs = run(m, plant, 2.0)
    assert outs[-1].mode == SWINGUP_MODE
    energy_before = max(o.energy for o in outs)
    assert m.set_parameters({'swingup': 'sign_based'}).successful
    outs = run(m, plant, 10.0)
    assert outs[0].event == 'switch:swingup=sign_based'
    assert max(o.energy for o in outs) > energy_before
    assert outs[-1].catch_count >= 1 and outs[-1].mode == STABILIZING
    assert not plant.end_stop_contact


def test_closed_loop_through_the_ekf_catches_and_switches_without_losing_the_pendulum():
    """The architecture's cycle: quantised measurement -> EKF -> manager -> plant (ZOH)."""
    ekf_module = pytest.importorskip('cartpole_estimation.ekf')
    ekf = ekf_module.ExtendedKalmanFilter(P)
    m = ControllerManager(P)
    plant = Plant(P, Scenario(theta0=math.pi + 0.03))
    force, angles, outs = 0.0, [], []
    switches = {9.0: 'smc', 11.0: 'pid', 13.0: 'lqg'}
    for k in range(int(15.0 / TS)):
        t = k * TS
        if round(t, 6) in switches:
            assert m.set_parameters({'stabilizer': switches[round(t, 6)]}).successful
        meas = plant.measure()
        est = ekf.update(meas.t, meas.x, meas.theta, force)
        out = m.update(ControllerState(est.t, est.x, est.theta, est.x_dot, est.theta_dot))
        outs.append(out)
        force = out.force
        plant.step(force)
        if t > 8.0:
            angles.append(abs(wrap_angle(plant.state[1])))
    assert outs[-1].catch_time is not None and outs[-1].catch_time < 8.0
    assert [o.event for o in outs if o.event.startswith('switch')] == [
        'switch:stabilizer=smc', 'switch:stabilizer=pid', 'switch:stabilizer=lqg']
    assert outs[-1].mode == STABILIZING and outs[-1].fall_count == 0
    assert max(angles) < math.radians(3.0)
    assert not plant.end_stop_contact


# -- the per-cycle fast paths give the same cycle ------------------------------------------------
def test_update_values_gives_the_same_cycle_as_update():
    """The offline loop's entry (the estimate as numbers) and update(ControllerState) agree
    to the bit, through swing-up, catch and stabilisation."""
    a, b = ControllerManager(P), ControllerManager(P)
    plant = Plant(P, Scenario())
    for _ in range(int(7.0 / TS)):
        x, theta, x_dot, theta_dot = plant.state
        out_a = a.update(ControllerState(plant.t, x, theta, x_dot, theta_dot))
        out_b = b.update_values(plant.t, x, theta, x_dot, theta_dot)
        assert out_a == out_b
        plant.step(out_a.force)
    assert out_a.mode == STABILIZING and out_a.catch_count == 1


def test_states_and_outputs_built_directly_equal_the_dataclass_constructors():
    from cartpole_control.manager import _controller_state, _manager_output
    values = (1.0, 0.3, 3.0, 0.1, -0.2, 0.5, -0.6)
    s = _controller_state(*values)
    assert type(s) is ControllerState and s == ControllerState(*values)
    assert hash(s) == hash(ControllerState(*values)) and s.theta_w == wrap_angle(3.0)
    names = list(ManagerOutput.__dataclass_fields__)
    values = (0.1, 2.0, 'stabilizing', 'pendulum_energy', 'lqg', True, 1.5, 0.1, 1.9, 0.1,
              'catch', 1, 0, 0.1, '', 'pendulum_energy')
    assert len(names) == len(values)
    out = _manager_output(*values)
    assert type(out) is ManagerOutput and out == ManagerOutput(*values)
    assert [getattr(out, n) for n in names] == list(values)
    for obj in (s, out):
        with pytest.raises(Exception):
            obj.t = 5.0  # still frozen
    from cartpole_control.controller import CommandFeedback
    from cartpole_control.manager import _command_feedback
    fb = _command_feedback(40.0, 34.25, 1, False)
    assert type(fb) is CommandFeedback and fb == CommandFeedback(40.0, 34.25, 1, False)
    assert fb.blocks(0.1) and not fb.blocks(-0.1) and not fb.blocks(0.0)
    with pytest.raises(Exception):
        fb.force = 0.0
