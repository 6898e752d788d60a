"""`cartpole analyze BAG --animate FILE`: the animation of a recorded bag.

The bag is the known synthetic run of ``bag_synth`` (20 s; theta falls linearly from
pi, hanging, to 0, upright, over 6 s, then wobbles by 0.01 rad; the catch at 5 s).
The GIF is read back with Pillow: its frame count and playing time follow from the
run's length, the frame rate and the speed, and the first and last frames show the
pendulum hanging and upright -- the tip mass's colour at the pixel where the
geometry (4.5) puts the tip, and background where it would be the other way up.
"""
import importlib.util
import json
import math
import shutil
from pathlib import Path

import pytest
from PIL import Image

from cartpole_bringup import cli
from cartpole_analysis.analysis.animation import Viewport, frame_times, gif_durations
from cartpole_analysis.viewer.scene import MODE_COLOURS
from cartpole_sim.geometry import RigGeometry
from cartpole_core.model import CartPoleParameters

_spec = importlib.util.spec_from_file_location('bag_synth', Path(__file__).with_name('bag_synth.py'))
bag_synth = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bag_synth)


@pytest.fixture(scope='module')
def known_bag(tmp_path_factory):
    path = tmp_path_factory.mktemp('anim') / 'bag'
    bag_synth.write_run(path, custom_data={'x_ref': repr(bag_synth.X_REF), 'lockstep': 'true'})
    return path


def animate(bag, out, *extra, capsys):
    code = cli.main(['analyze', str(bag), '--animate', str(out), '--json', *extra])
    captured = capsys.readouterr()
    return code, captured


def rgb(mode):
    return tuple(int(255 * c) for c in MODE_COLOURS[mode])


def test_gif_has_the_frames_the_duration_and_the_pendulum_where_the_geometry_says(
        known_bag, tmp_path, capsys):
    out = tmp_path / 'run.gif'
    code, captured = animate(known_bag, out, capsys=capsys)
    assert code == 0, captured.err
    info = json.loads(captured.out)['animation']
    frames = int(bag_synth.DURATION * 25) + 1  # a frame every 40 ms from 0 to 20 s
    assert info['frames'] == frames
    with Image.open(out) as gif:
        assert gif.n_frames == frames
        durations = []
        for k in range(gif.n_frames):
            gif.seek(k)
            durations.append(gif.info['duration'])
        assert sum(durations) == frames * 40
        gif.seek(0)
        first = gif.convert('RGB')
        gif.seek(75)  # t = 3 s
        middle = gif.convert('RGB')
        gif.seek(gif.n_frames - 1)
        last = gif.convert('RGB')
    assert info['size_px'] == list(first.size)
    assert out.stat().st_size < 2_000_000

    geometry = RigGeometry.from_parameters(CartPoleParameters())
    view = Viewport.for_rig(geometry, first.size[0])
    l = geometry.pendulum_length
    t, x, theta = bag_synth.trajectory()[:3]

    def pixel(image, px, pz):
        # 3 px right of the point: still on the 9 px wide tip mass, off the 1 px x* line
        # (the synthetic cart sits at x*).
        col, row = view.to_pixel(px, pz)
        return image.getpixel((round(col) + 3, round(row)))
    white = (255, 255, 255)
    # First frame, t = 0: hanging (theta = pi), tip at (x0, -l), in the swing-up colour.
    assert pixel(first, x[0], -l) == rgb('swingup')
    assert pixel(first, x[0], l) == white
    # Last frame, t = 20 s: upright (theta ~ 0), tip at (x - l sin theta, l cos theta), stabilising.
    tip = (x[-1] - l * math.sin(theta[-1]), l * math.cos(theta[-1]))
    assert pixel(last, *tip) == rgb('stabilizing')
    assert pixel(last, x[-1], -l) == white
    # t = 3 s: theta = pi/2, horizontal, leaning left (positive theta): tip at (x - l, 0).
    k = 300
    assert theta[k] == pytest.approx(math.pi / 2)
    col, row = view.to_pixel(x[k] - l, 0.0)
    assert middle.getpixel((round(col), round(row))) == rgb('swingup')
    col, row = view.to_pixel(x[k] + l, 0.0)
    assert middle.getpixel((round(col), round(row))) == white


def test_speed_shortens_the_animation(known_bag, tmp_path, capsys):
    out = tmp_path / 'fast.gif'
    code, captured = animate(known_bag, out, '--speed', '2', '--fps', '20', capsys=capsys)
    assert code == 0, captured.err
    info = json.loads(captured.out)['animation']
    assert info['frames'] == int(bag_synth.DURATION * 20 / 2) + 1
    assert info['duration_s'] == pytest.approx(info['frames'] / 20.0)


def test_frame_clock():
    assert frame_times(0.0, 1.0, 25, 1.0).tolist() == pytest.approx([k * 0.04 for k in range(26)])
    # 30 fps does not fit GIF's 10 ms steps: the durations alternate so the total keeps time.
    durations = gif_durations(300, 30.0)
    assert set(durations) == {30, 40} and sum(durations) == 10_000


@pytest.mark.parametrize('argv, reason', [
    (['--animate', 'x.avi'], 'must be one of'),
    (['--animate', 'x.gif', '--speed', '0'], '--speed must be >= 0.1'),
])
def test_bad_animation_options_are_refused(known_bag, tmp_path, capsys, argv, reason):
    argv = [a if not a.startswith('x.') else str(tmp_path / a) for a in argv]
    code = cli.main(['analyze', str(known_bag), *argv])
    assert code == 2 and reason in capsys.readouterr().err
    assert not list(tmp_path.iterdir())


def test_several_bags_are_refused(known_bag, tmp_path, capsys):
    code = cli.main(['analyze', str(known_bag), str(known_bag), '--animate', str(tmp_path / 'a.gif')])
    assert code == 2 and 'one bag' in capsys.readouterr().err


@pytest.mark.skipif(shutil.which('ffmpeg') is not None, reason='ffmpeg is installed')
def test_mp4_without_ffmpeg_says_so(known_bag, tmp_path, capsys):
    code = cli.main(['analyze', str(known_bag), '--animate', str(tmp_path / 'run.mp4')])
    assert code == 2 and 'ffmpeg' in capsys.readouterr().err
