"""ControllerManager: parameters and refusals, queued bumpless switching, feedforward,
saturation, catch trigger and fall detector."""
import math

import pytest

from cartpole_control.controller import STABILIZER, SWINGUP, Controller
from cartpole_control.feedforward import FrictionFeedforward
from cartpole_control.manager import STABILIZING, SWINGUP_MODE, ControllerManager
from cartpole_core.model import accelerations
from manager_test_support import P, TS, HoldA, HoldB, Recording, make, plugin, state, upright


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


def built_and_configured():
    return Recording.built, Recording.configured


def test_gain_change_and_switch_are_built_when_set_and_only_swapped_in_the_cycle():
    """The cycle only swaps: the instance is constructed and configured by the parameter
    check (once: the set takes the checked one), none in update; the run goes on."""
    m = make(swingup='push_a')
    m.update(state(0.0))
    m.update(state(TS))
    live = plugin(m, SWINGUP)
    before = built_and_configured()
    assert m.check_parameters({'push_a.force': 3.0}).successful
    checked = built_and_configured()
    assert checked == (before[0] + 1, before[1] + 1)
    assert m.set_parameters({'push_a.force': 3.0}).successful
    assert built_and_configured() == checked          # no second copy for the set
    out = m.update(state(2 * TS))
    assert built_and_configured() == checked          # nothing built in the cycle
    new = plugin(m, SWINGUP)
    assert out.raw_force == 3.0 and new is not live and new.active and not live.active
    assert new.steps == 3                             # took over the run (2 updates + this one)
    assert live.calls[-1] == ('deactivate',)

    assert m.set_parameters({'swingup': 'push_b', 'push_b.force': -2.0}).successful
    switched = built_and_configured()
    assert switched == (checked[0] + 1, checked[1] + 1)
    out = m.update(state(3 * TS))
    assert built_and_configured() == switched
    assert out.event == 'switch:swingup=push_b' and out.raw_force == -2.0
    assert plugin(m, SWINGUP).calls[:2] == [('activate', 3 * TS), ('update', 3 * TS)]


def test_a_check_of_other_changes_is_not_taken_for_the_set():
    m = make(swingup='push_a')
    assert m.check_parameters({'push_a.force': 3.0}).successful
    assert m.set_parameters({'push_a.force': 4.0}).successful
    assert m.update(state(0.0)).raw_force == 4.0
    assert m.check_parameters({'push_a.force': 5.0}).successful
    assert m.set_parameters({'push_a.limit': 50.0}).successful   # another change came between
    assert m.set_parameters({'push_a.force': 5.0}).successful
    m.update(state(TS))
    assert plugin(m, SWINGUP).gains == {'force': 5.0, 'limit': 50.0}


def test_changes_queued_before_one_cycle_are_applied_together():
    m = make(swingup='push_a')
    m.update(state(0.0))
    assert m.set_parameters({'stabilizer': 'hold_b'}).successful
    assert m.set_parameters({'push_a.force': 2.0}).successful
    assert m.set_parameters({'hold_b.force': 1.5}).successful
    out = m.update(state(TS))
    assert out.stabilizer == 'hold_b' and out.raw_force == 2.0 and out.event == \
        'switch:stabilizer=hold_b'
    assert plugin(m, STABILIZER).gains['force'] == 1.5 and not plugin(m, STABILIZER).active


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
    # the thesis's loop (no prediction): the plugin sees the estimate itself
    m = make(swingup='push_a', **{'push_a.force': 4.0, 'predict.horizon': 0.0})
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
    m = make(**{'predict.horizon': 0.0})  # (6.4) on the estimate itself
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


class Forgetful(Controller):
    """Hooks that do their own work and never call ``super()``: the contract needs none."""

    kind, name = STABILIZER, 'forgetful'

    def __init__(self):
        super().__init__()
        self.started = self.stopped = 0

    def on_activate(self, state):
        self.started += 1

    def on_deactivate(self):
        self.stopped += 1

    def update(self, state):
        return 0.0


class ForgetfulSwingUp(Forgetful):
    kind, name = SWINGUP, 'forgetful_swingup'


def test_hooks_without_super_keep_the_managers_bookkeeping_through_catch_fall_and_switch():
    registry = {SWINGUP: {'forgetful_swingup': ForgetfulSwingUp},
                STABILIZER: {'forgetful': Forgetful, 'hold_a': HoldA}}
    m = ControllerManager(P, TS, registry=registry, swingup='forgetful_swingup',
                          stabilizer='forgetful', **{'rail.actuator_dead_time': 0.0})
    m.update(state(0.0))
    swing, stab = plugin(m, SWINGUP), plugin(m, STABILIZER)
    assert swing.active and not stab.active and swing.started == 1
    out = m.update(upright(TS, theta=0.1))                       # catch
    assert out.mode == STABILIZING
    assert stab.active and not swing.active and (swing.stopped, stab.started) == (1, 1)
    out = m.update(upright(2 * TS, theta=math.radians(-46.0)))   # fall
    assert out.mode == SWINGUP_MODE and swing.active and not stab.active
    assert (swing.started, stab.stopped) == (2, 1)
    m.update(upright(3 * TS, theta=0.0))                         # caught again, then switched
    assert m.set_parameters({'stabilizer': 'hold_a'}).successful
    out = m.update(upright(4 * TS, theta=0.0))
    assert out.stabilizer == 'hold_a' and plugin(m, STABILIZER).active
    assert not stab.active and stab.stopped == 2
    m.reset()
    assert not plugin(m, STABILIZER).active and not swing.active


def test_a_plugin_that_overrides_activate_or_deactivate_is_refused_at_definition():
    for method in ('activate', 'deactivate'):
        with pytest.raises(TypeError, match=f'overrides {method}.*on_{method}'):
            type('Overrides', (Controller,), {method: lambda self, *a: None,
                                              'update': lambda self, s: 0.0})


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
