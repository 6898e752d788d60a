"""Playing a pulse test for identification (thesis 4.3.2): the plan, its rehearsal, the player.

The player drives the simulator node (or the rig's bridge through its lifecycle)
with the planned force pulses; the recorded bag is then fitted as in
test_identify.py, at the same known "true" parameters.
"""
from __future__ import annotations

import json

import numpy as np
import pytest

from cartpole_bringup import cli
from cartpole_core.model import CartPoleParameters
from cartpole_tools.identification.bag_input import load_recording
from cartpole_tools.identification.fit import identify
from cartpole_tools.identification.recording import IdentificationError

TRUE = {'m_c': 4.2, 'c_c_right': 3.0, 'c_c_left': 2.8, 'c_p': 0.005, 'v_p': 0.001}
THESIS = CartPoleParameters()
FIT_STEP = 0.0025
CART_TICK = THESIS.cart_resolution


def _true_params() -> CartPoleParameters:
    return THESIS.replace(**TRUE)


# -- playing a pulse test ---------------------------------------------------------------------------
def test_pulse_plan_is_parsed_and_checked():
    from cartpole_tools.identification.pulse_plan import Pulse, parse_pulse_plan
    assert parse_pulse_plan('15:0.25, -9:0.2') == (Pulse(15.0, 0.25), Pulse(-9.0, 0.2))
    for bad, message in (('15', 'FORCE:LENGTH'), ('40:0.2', 'within'), ('0:0.2', 'non-zero'),
                         ('10:2', 'length'), ('', 'empty')):
        with pytest.raises(IdentificationError, match=message):
            parse_pulse_plan(bad)


def test_rehearsal_plays_the_plan_and_flags_unsafe_plans():
    from cartpole_tools.identification.pulse_plan import parse_pulse_plan
    from cartpole_tools.identification.pulse_player import rehearsal_warnings, rehearse
    rec, player = rehearse(parse_pulse_plan('15:0.25,-9:0.25'), THESIS)
    assert player.done and rehearsal_warnings(rec, player) == []
    # Zero for the 0.5 s lead-in, then 50 samples of 15 N, later 50 of -9 N.
    assert np.all(rec.force[:100] == 0.0) and np.sum(rec.force == 15.0) == 50
    assert np.sum(rec.force == -9.0) == 50
    k = int(np.flatnonzero(rec.force == -9.0)[0])
    assert np.ptp(rec.x[k - 200:k]) <= 2 * CART_TICK  # it waited for the cart to stand still
    assert 0.25 < rec.x.max() < 0.4
    # Too hard: the guard cuts the pulse near the far stop, the cart still coasts into it.
    rec, player = rehearse(parse_pulse_plan('30:0.5,-9:0.25'), THESIS)
    problems = rehearsal_warnings(rec, player)
    assert player.reason.startswith('rail guard: pulse 1')
    assert any('end stop' in p for p in problems)
    # The return pulse too strong: coasts back into the left stop zone.
    rec, player = rehearse(parse_pulse_plan('15:0.25,-12:0.25'), THESIS)
    assert any('within 0.1 m of a stop' in p for p in rehearsal_warnings(rec, player))


def test_rehearse_option_prints_the_prediction(capsys):
    assert cli.main(['identify', '--pulse-plan', '15:0.25,-9:0.25', '--rehearse', '--json']) == 0
    out = json.loads(capsys.readouterr().out)
    assert out['rehearsal']['problems'] == []
    assert out['rehearsal']['x_after_pulses'][0] == pytest.approx(0.32, abs=0.01)
    assert cli.main(['identify', '--pulse-plan', '15:0.25', '--rehearse', '--x0', '0.769']) == 1
    assert 'rail guard' in capsys.readouterr().out


@pytest.mark.ros
def test_pulse_plan_on_the_lockstep_simulator_records_a_bag_that_fits(tmp_path, ros_context):
    """Play, record, fit: the pulse player drives the simulator node, the bag gives m_c, c_c."""
    from rclpy.parameter import Parameter

    from cartpole_tools.identification.pulse_plan import parse_pulse_plan
    from cartpole_tools.identification.pulse_player import PulsePlayer
    from cartpole_tools.identification.node import play_pulse_plan
    from cartpole_sim.sim_node import SimNode

    truth = tmp_path / 'truth.yaml'
    _true_params().to_yaml(truth)
    sim = SimNode(context=ros_context, parameter_overrides=[
        Parameter('lockstep', value=True), Parameter('plant_params_file', value=str(truth))])
    player = PulsePlayer(parse_pulse_plan('15:0.25,-12:0.25'), THESIS, lead_in=0.3, settle=0.3)
    try:
        played = play_pulse_plan(player, context=ros_context, record=tmp_path / 'bag',
                                 extra_nodes=[sim], timeout=60.0, log=lambda line: None)
    finally:
        sim.destroy_node()
    assert played['guard'] is None and player.done
    rec = load_recording(tmp_path / 'bag')
    assert np.sum(rec.force == 15.0) == 50 and np.sum(rec.force == -12.0) == 50
    assert rec.x.max() == pytest.approx(0.43, abs=0.01)
    start = THESIS.replace(c_p=TRUE['c_p'], v_p=TRUE['v_p'])
    res = identify([rec], start, free=['m_c', 'c_c_right', 'c_c_left'], integration_step=FIT_STEP)
    for name in ('m_c', 'c_c_right', 'c_c_left'):
        assert res.values[name] == pytest.approx(TRUE[name], rel=0.01), name


@pytest.mark.ros
def test_pulse_player_refuses_without_samples_or_with_an_unsafe_plan(tmp_path, ros_context):
    from rclpy.parameter import Parameter

    from cartpole_tools.identification.pulse_plan import parse_pulse_plan
    from cartpole_tools.identification.pulse_player import PulsePlayer
    from cartpole_tools.identification.node import play_pulse_plan
    from cartpole_sim.sim_node import SimNode

    player = PulsePlayer(parse_pulse_plan('15:0.25'), THESIS)
    with pytest.raises(RuntimeError, match='no /joint_states sample'):
        play_pulse_plan(player, context=ros_context, sample_wait=0.3, log=lambda line: None)
    sim = SimNode(context=ros_context, parameter_overrides=[Parameter('lockstep', value=True),
                                                            Parameter('x0', value=0.7)])
    seen = []
    try:
        with pytest.raises(RuntimeError, match='refused.*too close'):
            play_pulse_plan(player, context=ros_context, extra_nodes=[sim],
                            check=lambda x, theta: seen.append(x) or ['too close'],
                            log=lambda line: None)
        # The check saw the simulator's cart; no command was answered, the sim never stepped.
        assert seen == [pytest.approx(0.7, abs=2 * CART_TICK)]
        assert sim._runner.index == 0 and not player.done
    finally:
        sim.destroy_node()


@pytest.mark.ros
def test_pulse_plan_on_the_emulated_rig_activates_the_bridge_and_deactivates_it(tmp_path,
                                                                                ros_context,
                                                                                spin_until):
    """``cartpole identify --pulse-plan --arm`` on the rig: the bridge (configured,
    streaming, disarmed) is armed through its lifecycle (activate after zero-force
    answers), the pulse reaches the device's DAC, and the bridge ends inactive: zero,
    disabled, still streaming. Without --arm nothing reaches the device."""
    import threading

    from rclpy.lifecycle import TransitionCallbackReturn
    from rclpy.parameter import Parameter

    from cartpole_tools.identification.node import play_pulse_plan
    from cartpole_tools.identification.pulse_plan import parse_pulse_plan
    from cartpole_tools.identification.pulse_player import PulsePlayer
    from cartpole_emulator.emulator import Emulator
    from cartpole_hw.hw_node import HwBridgeNode

    em = Emulator(link=str(tmp_path / 'emu'))
    em.device.watchdog_us = 300_000     # one process (and GIL) with the executor, under load
    em.start()
    bridge = HwBridgeNode(context=ros_context, parameter_overrides=[
        Parameter('port', value=em.link), Parameter('home_on_start', value=True),
        Parameter('command_timeout', value=0.3), Parameter('sample_timeout', value=0.3)])
    setpoints, disabled = [], threading.Event()

    def sample_period():   # the emulator's thread: the output in force each period
        setpoints.append((em.device.enabled, em.device.output_setpoint()))
        if setpoints[-1] == (False, 0) and (True, round(6 * 56.744)) in setpoints:
            disabled.set()
        step()

    step, em.sample_period = em.sample_period, sample_period
    try:
        assert bridge.trigger_configure() == TransitionCallbackReturn.SUCCESS   # streaming
        unarmed = PulsePlayer(parse_pulse_plan('6:0.1'), THESIS, lead_in=0.1, settle=0.1)
        play_pulse_plan(unarmed, context=ros_context, extra_nodes=[bridge], timeout=30.0,
                        log=lambda line: None)
        assert unarmed.done and {out for _, out in setpoints} == {0}   # never armed
        player = PulsePlayer(parse_pulse_plan('6:0.1'), THESIS, lead_in=0.1, settle=0.1)
        lines = []
        played = play_pulse_plan(player, context=ros_context, extra_nodes=[bridge], arm=True,
                                 timeout=30.0, log=lines.append)
        assert played['guard'] is None and player.done
        assert (True, round(6 * 56.744)) in setpoints                  # the pulse acted
        assert 'hw bridge armed (lifecycle state active)' in lines
        assert 'hw bridge disarmed (inactive)' in lines
        assert bridge._state_machine.current_state[1] == 'inactive'
        assert disabled.wait(5.0), setpoints[-5:]                    # zero and disabled after
    finally:
        bridge.destroy_node()
        em.stop()
