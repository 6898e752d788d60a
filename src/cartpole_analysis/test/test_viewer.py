"""The live view's core without ROS: a real foxglove-sdk server, a real WebSocket client.

An offline run (plant, EKF, controller manager) is fed to the viewer through the
observer of ``cartpole offline --view``; the client decodes what it receives with the
schemas the server advertises and checks it against the run itself: the drawn cart
and tip are where the state and the model's geometry (4.5) put them, the colour
follows the mode, the catch is an event at the manager's catch time, the plot
channels carry the same numbers, and no two messages are closer than 1/60 s of
stamp time.
"""
import importlib.util
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from cartpole_bringup.offline.closed_loop import run_closed_loop
from cartpole_analysis.viewer.server import (MAX_RATE_HZ, TOPICS, Decimator, LiveView, ViewerServer,
                                     parse_address)
from cartpole_analysis.viewer.client import ViewerClient
from cartpole_analysis.viewer.layout import foxglove_layout, layout_text
from cartpole_analysis.viewer.offline import RealTimePlayer
from cartpole_analysis.viewer.scene import MODE_COLOURS, NO_MODE_COLOUR
from cartpole_core.child_process import reap
from cartpole_sim.geometry import RigGeometry
from cartpole_core.model import CartPoleParameters

_spec = importlib.util.spec_from_file_location('foxglove_support',
                                               Path(__file__).with_name('foxglove_support.py'))
foxglove_support = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(foxglove_support)
Schema = foxglove_support.Schema

REPO = Path(__file__).resolve().parents[3]


@pytest.mark.parametrize('text, expected', [
    (None, ('127.0.0.1', 8765)), ('', ('127.0.0.1', 8765)), ('0.0.0.0:9000', ('0.0.0.0', 9000)),
    ('9001', ('127.0.0.1', 9001)), ('localhost', ('localhost', 8765)), (':0', ('127.0.0.1', 0)),
    ('[::1]:8765', ('::1', 8765))])
def test_addresses(text, expected):
    assert parse_address(text) == expected


@pytest.mark.parametrize('text', ['host:99999', 'host:port', '127.0.0.1:-1'])
def test_bad_addresses_are_refused(text):
    with pytest.raises(ValueError, match='port'):
        parse_address(text)


def test_decimation_is_by_stamps_and_at_most_60_hz():
    decimator = Decimator()
    stamps = [k * 5_000_000 for k in range(2000)]  # 10 s of 200 Hz samples
    shown = [s for s in stamps if decimator.due(s)]
    gaps = np.diff(shown)
    assert gaps.min() >= 1e9 / MAX_RATE_HZ
    assert len(shown) == 500  # every fourth sample: 50 Hz
    assert not decimator.due(shown[-1])            # a repeated sample is not shown twice
    assert decimator.due(0)                        # a restarted run (stamps back to 0) is
    with pytest.raises(ValueError, match='max_rate'):
        Decimator(120.0)


class FakeClock:
    """The wall clock of the real-time player, advanced by its own sleeps."""

    def __init__(self):
        self.now = 100.0
        self.sleeps = []

    def __call__(self):
        return self.now

    def sleep(self, seconds):
        self.sleeps.append(seconds)
        self.now += seconds


@pytest.fixture(scope='module')
def served_run():
    """A 7 s offline run (caught at about 2.8 s) played at 4x to a server, and what a client got."""
    server = ViewerServer(port=0)
    params = CartPoleParameters()
    view = LiveView(server, RigGeometry.from_parameters(params), params.x_middle)
    client = ViewerClient(server.url, TOPICS.values())
    clock = FakeClock()
    player = RealTimePlayer(view, speed=4.0, clock=clock, sleep=clock.sleep)
    truth, estimates = {}, {}

    def observer(meas, est, out, state):
        stamp = int(round(meas.t * 1e9))
        truth[stamp], estimates[stamp] = tuple(state), (est.x, est.theta)
        player(meas, est, out, state)
    run = run_closed_loop(params, duration=7.0, observer=observer)
    shown = view.shown
    assert client.wait_for(lambda c: c.counts[TOPICS['scene']] >= shown
                           and c.counts[TOPICS['control']] >= shown - 1, 20.0)
    client.close()
    server.stop()
    return dict(client=client, run=run, truth=truth, estimates=estimates, clock=clock,
                shown=shown, params=params)


def test_channels_are_advertised_with_their_schemas(served_run):
    channels = served_run['client'].channels
    assert set(channels) == set(TOPICS.values())
    assert channels[TOPICS['scene']]['schemaName'] == 'foxglove.SceneUpdate'
    assert channels[TOPICS['scene']]['encoding'] == 'protobuf'
    assert channels[TOPICS['events']]['schemaName'] == 'foxglove.Log'
    for key in ('state', 'control'):
        assert channels[TOPICS[key]]['encoding'] == 'json'


def test_scene_draws_the_state_at_the_model_geometry(served_run):
    client, truth, estimates = served_run['client'], served_run['truth'], served_run['estimates']
    schema = Schema.from_advertised(client.channels[TOPICS['scene']])
    scenes = client.received(TOPICS['scene'])
    l = served_run['params'].l
    assert len(scenes) == served_run['shown'] >= 7.0 * 50
    stamps = [m.log_time_ns for m in scenes]
    assert stamps[0] == 0 and np.diff(stamps).min() >= 1e9 / MAX_RATE_HZ
    for message in scenes:
        update = schema.decode('foxglove.SceneUpdate', message.payload)
        entities = {e['id']: e for e in update['entities']}
        assert set(entities) == {'rig', 'plant', 'estimate', 'label'}
        plant, estimate = entities['plant'], entities['estimate']
        stamp = message.log_time_ns
        assert plant['timestamp']['seconds'] * 10**9 + plant['timestamp']['nanos'] == stamp
        x, theta = truth[stamp][:2]
        cart = plant['cubes'][0]['pose']['position']
        assert cart['x'] == pytest.approx(x, abs=1e-12)
        tip = plant['cylinders'][1]['pose']['position']
        assert (tip['x'], tip['z']) == pytest.approx((x - l * math.sin(theta),
                                                      l * math.cos(theta)), abs=1e-9)
        x_est, theta_est = estimates[stamp]
        rod_start, rod_end = estimate['lines'][1]['points']
        assert rod_start['x'] == pytest.approx(x_est, abs=1e-12)
        assert (rod_end['x'], rod_end['z']) == pytest.approx(
            (x_est - l * math.sin(theta_est), l * math.cos(theta_est)), abs=1e-9)


def test_colour_follows_the_mode_and_the_catch_is_an_event(served_run):
    client, run = served_run['client'], served_run['run']
    schema = Schema.from_advertised(client.channels[TOPICS['scene']])
    catch_ns = int(round(run.catch_time * 1e9))
    colours = {}
    for message in client.received(TOPICS['scene']):
        plant = next(e for e in schema.decode('foxglove.SceneUpdate', message.payload)['entities']
                     if e['id'] == 'plant')
        c = plant['cubes'][0]['color']
        colours[message.log_time_ns] = (c['r'], c['g'], c['b'])
    swingup = pytest.approx(MODE_COLOURS['swingup'])
    stabilizing = pytest.approx(MODE_COLOURS['stabilizing'])
    # The scene of a sample is drawn before its own status arrives (as on the graph): the
    # first has no mode yet, each later one the mode of the status before it.
    assert colours[0] == pytest.approx(NO_MODE_COLOUR)
    assert all(c == swingup for s, c in colours.items() if 0 < s <= catch_ns)
    assert all(c == stabilizing for s, c in colours.items() if s > catch_ns + 10_000_000)
    events = Schema.from_advertised(client.channels[TOPICS['events']])
    logs = [(m.log_time_ns, events.decode('foxglove.Log', m.payload))
            for m in client.received(TOPICS['events'])]
    catches = [(stamp, log) for stamp, log in logs if log['message'].startswith('catch')]
    assert len(catches) == 1 and catches[0][0] == catch_ns


def test_plot_channels_carry_the_run(served_run):
    client, run, params = served_run['client'], served_run['run'], served_run['params']
    states = {m.log_time_ns: json.loads(m.payload) for m in client.received(TOPICS['state'])}
    controls = {m.log_time_ns: json.loads(m.payload) for m in client.received(TOPICS['control'])}
    assert set(controls) <= set(states) and len(controls) >= len(states) - 1
    index = {int(round(t * 1e9)): k for k, t in enumerate(run.t)}
    for stamp, state in states.items():
        k = index[stamp]
        assert state['x'] == run.x_est[k] and state['x_true'] == run.x[k]
        assert state['theta_w_true_deg'] == pytest.approx(
            math.degrees(math.remainder(run.theta[k], 2 * math.pi)), abs=1e-9)
        assert state['x_ref'] == params.x_middle
    for stamp, control in controls.items():
        k = index[stamp]
        assert control['force'] == run.force[k]
        # E* of the pendulum the manager estimates (adaptive_target): within 1 % of the nominal
        assert control['energy_target'] == pytest.approx(params.upright_energy, rel=1e-2)
        assert control['mode'] == run.mode[k]
        assert control['active'] == ('lqg' if run.mode[k] == 'stabilizing' else 'pendulum_energy')


def test_real_time_player_paces_by_simulated_time(served_run):
    clock = served_run['clock']
    # 7 simulated seconds at 4x: 1.75 s of (fake) wall time, reached by waiting only.
    assert clock.now - 100.0 == pytest.approx(7.0 / 4.0, abs=1e-6)
    assert min(clock.sleeps) > 0


def test_layout_file_is_the_generated_one_and_uses_advertised_fields():
    from cartpole_analysis.viewer.server import CONTROL_SCHEMA, STATE_SCHEMA
    assert (REPO / 'src' / 'cartpole_analysis' / 'config' / 'foxglove_layout.json').read_text() \
        == layout_text()
    layout = foxglove_layout()
    fields = {TOPICS['state']: set(STATE_SCHEMA['properties']),
              TOPICS['control']: set(CONTROL_SCHEMA['properties'])}
    paths = [p['value'] for config in layout['configById'].values()
             for p in config.get('paths', [])]
    assert len(paths) >= 12
    for path in paths:
        topic, _, field = path.rpartition('.')
        assert field in fields[topic], path
    assert set(layout['configById']['3D!rig']['topics']) == {TOPICS['scene']}
    assert layout['configById']['RosOut!events']['topicToRender'] == TOPICS['events']


@pytest.mark.slow
def test_cartpole_offline_view_serves_a_client(tmp_path):
    """`cartpole offline --view`: waits for a client, plays, prints the summary, exits."""
    proc = subprocess.Popen([sys.executable, '-m', 'cartpole_bringup.cli', 'offline', '--view',
                             '127.0.0.1:0', '--duration', '2', '--speed', '4', '--json'],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        url = foxglove_support.read_view_url(proc.stderr)
        assert url, 'no address printed'
        client = ViewerClient(url, [TOPICS['scene'], TOPICS['state']])
        out, err = proc.communicate(timeout=60)
        client.close()
    finally:
        reap(proc)
    assert proc.returncode == 0, err
    summary = json.loads(out.strip().splitlines()[-1])
    assert summary['catch_time_s'] is None  # 2 s: still swinging up
    stamps = [m.log_time_ns for m in client.received(TOPICS['scene'])]
    # It waited for the client: the first sample it shows is the run's first.
    assert stamps[0] == 0 and stamps[-1] == 2_000_000_000 and len(stamps) == 101
