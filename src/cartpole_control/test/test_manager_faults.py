"""ControllerManager: faults, stale state, idle and restart, what a plugin hears of its
command (saturation, rail guard), the feedforward each kind gets."""
import math

import pytest

from cartpole_control.controller import STABILIZER, SWINGUP
from cartpole_control.feedforward import FrictionFeedforward
from cartpole_control.manager import (FAULT, IDLE, STABILIZING, SWINGUP_MODE, ControllerManager,
                                      ManagerOutput)
from manager_test_support import TS, make, plugin, state, upright


# -- faults, stale state, idle, restart -----------------------------------------------------------
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


def test_between_cycles_only_the_configured_stabiliser_works_ahead_and_only_in_swing_up(caplog):
    """The MPC builds its catch QP so; a standby that raises loses nothing: logged, no fault."""
    m = make(swingup='push_a')
    m.update(state(0.0))
    stabilizer = plugin(m, STABILIZER)
    stabilizer.standby_error = RuntimeError('bad standby')
    m.between_cycles()
    assert stabilizer.calls == [('standby',)] and 'failed in standby' in caplog.text
    out = m.update(upright(TS))
    assert (out.mode, out.event) == (STABILIZING, 'catch')
    m.between_cycles()  # stabilising: nothing ahead
    assert stabilizer.calls.count(('standby',)) == 1
    assert ('standby',) not in plugin(m, SWINGUP).calls


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
    # caught at the stop by the thesis's trigger (the region would wait for room on the rail)
    m = make(stabilizer='listening', **{'listening.force': -5.0, 'catch.region': False})
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
