"""`cartpole run`: options -> node parameters, process command lines, refusals, Ctrl-C."""
from __future__ import annotations

import datetime as dt
import json
import math
import os
import signal
import subprocess
from pathlib import Path

import pytest

from cartpole_core.child_process import reap

from cartpole_bringup import cli
from cartpole_bringup.commands import run as run_cmd


def parse(*argv):
    return cli.build_parser().parse_args(['run', *argv])


def test_options_become_node_parameters():
    args = parse('--sim', '--lockstep', '--tip-mass', '0.2', '--x0', '0.1', '--theta0', '3.0',
                 '--noise', '--seed', '7', '--swingup', 'full_energy', '--stabilizer', 'smc')
    p = run_cmd.node_parameters(args)
    assert p['sim'] == {'x0': 0.1, 'theta0': 3.0, 'friction_scale': 1.0, 'encoder_offset': 0.0,
                        'noise': True, 'seed': 7, 'tip_mass': 0.2}
    assert p['controller_manager'] == {'swingup': 'full_energy', 'stabilizer': 'smc'}
    assert 'hw_bridge' not in p
    hw = run_cmd.node_parameters(parse('--hw', '--port', '/dev/ttyACM1'))
    assert hw['hw_bridge'] == {'port': '/dev/ttyACM1'}  # armed is no parameter: the lifecycle's
    armed = run_cmd.node_parameters(parse('--hw', '--port', 'X', '--hw-arm'))['hw_bridge']
    assert armed == {'port': 'X', 'home_on_start': True}


def test_disturbance_options_become_sim_parameters():
    args = parse('--sim', '--lockstep', '--delay', '0.0075', '--jitter', '0.002', '--drop', '0.1',
                 '--force-noise', '0.5', '--actuator-gain', '0.8', '--actuator-tau', '0.003',
                 '--cart-mass', '5.2', '--push', '12:cart:10:0.1', '--push', '15:pendulum:-0.3:0.02')
    sim = run_cmd.node_parameters(args)['sim']
    assert {k: sim[k] for k in ('delay', 'jitter', 'drop', 'force_noise', 'actuator_gain',
                                'actuator_tau', 'cart_mass')} == {
        'delay': 0.0075, 'jitter': 0.002, 'drop': 0.1, 'force_noise': 0.5,
        'actuator_gain': 0.8, 'actuator_tau': 0.003, 'cart_mass': 5.2}
    from cartpole_sim.plant import Push, parse_push
    assert [parse_push(t) for t in sim['pushes'].split()] == [
        Push(12.0, 'cart', 10.0, 0.1), Push(15.0, 'pendulum', -0.3, 0.02)]


def test_graph_spec_and_process_command_lines(tmp_path):
    from cartpole_bringup.graph.graph import GraphSpec, command_line, ros_value_text

    spec = GraphSpec(plant='sim', lockstep=True, processes=True, record=tmp_path / 'bag',
                     params_file=tmp_path / 'p.yaml', custom_data={'x_ref': '0.3845'},
                     parameters={'sim': {'theta0': 3.0, 'noise': True},
                                 'controller_manager': {'stabilizer': 'pid'}})
    assert spec.nodes == ['recorder', 'ekf', 'controller_manager', 'sim']  # plant last
    cmd = command_line(spec, 'sim')
    assert cmd[0].endswith('/lib/cartpole_sim/sim_node') and os.access(cmd[0], os.X_OK)
    assert cmd[1:] == ['--ros-args', '--log-level', 'warn', '--params-file',
                       str(tmp_path / 'p.yaml'), '-p', 'theta0:=3.0', '-p', 'noise:=true',
                       '-p', 'lockstep:=true', '-p', 'recorder_window:=10',
                       '-p', 'use_sim_time:=true']  # lockstep with a recorder: it waits for it
    rec = command_line(spec, 'recorder')
    assert 'lockstep:=true' in rec  # the recorder reports its progress
    assert f'output:={ros_value_text(str(tmp_path / "bag"))}' in rec
    assert "custom_data:=['x_ref=0.3845']" in rec
    assert ros_value_text("it's") == "'it''s'"
    with pytest.raises(ValueError, match='lockstep needs the simulator'):
        GraphSpec(plant='hw_bridge', lockstep=True)
    with pytest.raises(ValueError, match='hw_arm needs the rig'):
        GraphSpec(plant='sim', hw_arm=True)


def test_the_simulator_starts_only_once_every_reader_of_its_topics_is_seen(monkeypatch):
    """Two readers of /joint_states (the EKF, the manager) met the old count while the
    recorder was unseen: the simulator then started, and the bag lost the run's first
    samples. Now it waits for each reader by name, and ``start_subscribers`` counts them."""
    from types import SimpleNamespace

    from cartpole_analysis.analysis.analyze import FORCE, JOINTS, STATE, TRUE_STATE
    from cartpole_bringup.graph import startup

    spec = startup.GraphSpec(plant='sim', processes=True, record=Path('bag'))
    seen = {JOINTS: ['ekf', 'controller_manager', 'soak_probe'], TRUE_STATE: ['soak_probe'],
            STATE: ['controller_manager', 'recorder'], FORCE: ['sim', 'monitor']}

    class Monitor:
        def get_subscriptions_info_by_topic(self, topic):
            return [SimpleNamespace(node_name=n) for n in seen['/' + topic]]

        def count_subscribers(self, topic):
            return len(seen['/' + topic])

        def count_publishers(self, topic):
            return len(seen['/' + topic])

    polls = []

    def spin_until(ready, timeout):
        for _ in range(3):
            polls.append(ready())
            if polls[-1]:
                return True
            seen[JOINTS].append('recorder')  # discovered a moment later
            seen[TRUE_STATE].append('recorder')
        return False

    started = {}
    monkeypatch.setattr(startup, 'start_node_process',
                        lambda command: started.setdefault(Path(command[0]).name, command))
    graph = startup.GraphStartup(spec, None, None, Monitor(), {}, {}, None, None, None,
                                 spin_until, lambda: False, print)
    graph._start_processes()
    assert polls == [False, True]
    assert any('start_subscribers:=2' in part for part in started['sim_node'])


def test_run_directory_is_named_by_time_and_controllers(tmp_path):
    now = dt.datetime(2025, 3, 4, 5, 6, 7, tzinfo=dt.timezone.utc)
    names = {'swingup': 'pendulum_energy', 'stabilizer': 'lqg'}
    first = run_cmd.run_directory(tmp_path, names, now)
    assert first == tmp_path / '20250304T050607Z_pendulum_energy_lqg'
    first.mkdir()
    assert run_cmd.run_directory(tmp_path, names, now).name == '20250304T050607Z_pendulum_energy_lqg_2'


@pytest.mark.parametrize('argv, reason', [
    (['--hw'], '--hw needs --port'),
    (['--sim', '--port', '/dev/x'], 'are for --hw'),
    (['--hw', '--port', 'X', '--lockstep'], '--lockstep needs --sim'),
    (['--sim', '--duration', '0'], '--duration must be > 0'),
    (['--sim', '--plots'], '--plots without DIR needs --record'),
    (['--sim', '--x0', '0.9'], 'outside the travel'),
    (['--sim', '--tip-mass', '-1'], '--tip-mass must be > 0'),
    (['--sim', '--domain-id', '300'], '--domain-id must be in'),
    (['--sim', '--view', 'localhost:70000'], '--view: port must be in'),
    (['--sim', '--realtime', 'fast'], "--realtime: CARTPOLE_REALTIME='fast': expected on, off"),
    (['--sim', '--realtime', '60'], 'SCHED_FIFO priority 1..49'),
    (['--sim', '--duration', '5', '--window', '6'], '--window must be <= 5 s'),
    (['--sim', '--window', '0'], '--window must be > 0 s'),
    (['--sim', '--window', 'nan'], '--window must be a finite number'),
])
def test_bad_options_are_refused_before_anything_starts(argv, reason, capsys, tmp_path):
    try:
        code = cli.main(['run', *argv])
    except SystemExit as exc:  # options.scenario_from_args exits with the reason
        code, err = 2, str(exc)
    else:
        err = capsys.readouterr().err
    assert code == 2 and reason in err


def cartpole_exe() -> str:
    from ament_index_python.packages import get_package_prefix
    path = Path(get_package_prefix('cartpole_bringup')) / 'lib' / 'cartpole_bringup' / 'cartpole'
    assert os.access(path, os.X_OK), f'{path} missing; run make build'
    return str(path)


@pytest.mark.ros
def test_installed_cartpole_run_stops_cleanly_on_sigint(ros_context, spin_until, tmp_path):
    """Ctrl-C: zero force last, bag closed, summary printed, exit 0."""
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from sensor_msgs.msg import JointState

    node = Node('run_probe', context=ros_context)
    truth = []
    node.create_subscription(JointState, '/cartpole/true_state', truth.append, 10)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    # full_energy catches at about 6.9 s (the default swing-up at 2.8 s): the probe's own
    # discovery may take seconds under load, and the run must still end before any catch.
    proc = subprocess.Popen([cartpole_exe(), 'run', '--sim', '--swingup', 'full_energy',
                             '--record', str(tmp_path), '--json'],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        # Real time: wait for 0.5 s of samples, then Ctrl-C.
        assert spin_until(executor, lambda: len(truth) >= 100, 60.0), 'graph did not run'
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=30)
    finally:
        reap(proc)
        node.destroy_node()
    assert proc.returncode == 0, err
    result = json.loads([line for line in out.splitlines() if line.startswith('{')][-1])
    assert result['lockstep'] is False and result['elapsed_s'] > 0.4
    assert result['catch_time_s'] is None and result['success'] is False  # far too short
    bag = Path(result['bag'])
    assert (bag / 'metadata.yaml').is_file()
    from rosbags.highlevel import AnyReader
    with AnyReader([bag]) as reader:
        conns = [c for c in reader.connections if c.topic == '/cartpole/force_command']
        forces = [reader.deserialize(raw, c.msgtype).effort[0]
                  for c, _, raw in reader.messages(connections=conns)]
    assert len(forces) >= 50 and forces[-1] == 0.0
    assert any(abs(f) > 0.0 for f in forces), 'the swing-up never pushed'
    assert not math.isnan(result['x_err_max_m'])


@pytest.mark.ros
def test_lockstep_start_recovers_when_the_first_command_is_lost(ros_context):
    """The race of one process a node, made deterministic in one process.

    The EKF answers the simulator's first sample before any controller
    exists, so that answer is lost. The EKF re-publishes its estimate for the
    simulator's repeated sample (and, failing that, the graph resets the
    simulator); either way the loop must then run.
    """
    from rclpy.parameter import Parameter

    from cartpole_bringup.graph.graph import Graph, GraphSpec
    from cartpole_control.manager_node import ControllerManagerNode
    from cartpole_estimation.ekf_node import EkfNode
    from cartpole_sim.sim_node import SimNode

    class LateController(Graph):
        def _start_in_process(self):
            sim_time = [Parameter('use_sim_time', value=True)]
            ekf = EkfNode(context=self.context, parameter_overrides=sim_time)
            self.nodes['ekf'] = ekf
            self.executor.add_node(ekf)
            sim = SimNode(context=self.context,
                          parameter_overrides=sim_time + [Parameter('lockstep', value=True)])
            self.nodes['sim'] = sim
            self.executor.add_node(sim)
            assert self.spin_until(lambda: ekf.counts.samples >= 1, 10.0), 'EKF did not answer sample 0'
            manager = ControllerManagerNode(context=self.context, parameter_overrides=sim_time)
            self.nodes['controller_manager'] = manager
            self.executor.add_node(manager)

    graph = LateController(GraphSpec(plant='sim', lockstep=True), ros_context)
    try:
        graph.start()
        graph.run_for(0.5)
        assert graph.elapsed() >= 0.5
        assert graph.nodes['sim'].runner.index >= 100
    finally:
        warnings = graph.close()
    assert not [w for w in warnings if 'zero force' in w]


def test_a_run_whose_scored_window_starts_before_the_catch_is_said_to_be_too_short():
    """A real-time run with the graph in processes starts its plant 2-3 s late: with
    `--duration 15` the last 10 s began before the catch at 3.05 s and the swing-up read as
    a fall (theta amplitude 179 deg). The verdict stays; the run says why it says little."""
    spans = [{'kind': 'swingup', 'name': 'pendulum_energy', 'start_s': 0.0, 'end_s': 3.05},
             {'kind': 'stabilizer', 'name': 'lqg', 'start_s': 3.05, 'end_s': 12.52}]
    summary = {'catch_time_s': 3.05, 'controllers': spans}
    warning = run_cmd.window_warning(summary, 10.0)
    assert warning is not None and 'from 2.52 s' in warning and 'catch at 3.05 s' in warning
    assert run_cmd.window_warning(summary, 9.0) is None
    assert run_cmd.window_warning({'catch_time_s': None, 'controllers': spans}, 10.0) is None
    assert run_cmd.window_warning(None, 10.0) is None
