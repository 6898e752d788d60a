"""Bags that survive kills (no ROS): the writer's flush rule, `cartpole bag repair`, `bag info`.

A kill is what is on disk while the writer is still open: the MCAP file
without summary and footer, no metadata.yaml (optionally cut in the middle
of a record). The repaired bag must read back with rosbags and `cartpole
analyze`, keep the run's custom_data, and miss at most the flush period.
"""
from __future__ import annotations

import importlib.util
import json
import shutil
from pathlib import Path

import pytest
import yaml

from cartpole_bringup import cli
from cartpole_analysis.bags.writer import BagWriter, bag_custom_data
from cartpole_analysis.bags.repair import needs_repair, repair_bag
from cartpole_analysis.bags.storage import FLUSH_PERIOD

_spec = importlib.util.spec_from_file_location('bag_synth', Path(__file__).with_name('bag_synth.py'))
bag_synth = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bag_synth)

CUSTOM = {'x_ref': repr(bag_synth.X_REF), 'lockstep': 'true', 'swingup': 'pendulum_energy'}


def _record_and_kill(tmp_path: Path, seconds: float) -> tuple[Path, int]:
    """Record `seconds` of a run at 100 Hz; return a copy of the bag as a kill leaves it."""
    ts = bag_synth._types()
    t, x, theta, x_dot, theta_dot, force = bag_synth.trajectory()
    live = tmp_path / 'live' / 'bag'
    writer = BagWriter(live, custom_data=CUSTOM)
    n = int(round(seconds / bag_synth.TS))
    for k in range(n):
        state = ([x[k], theta[k]], [x_dot[k], theta_dot[k]])
        writer.write('/cartpole/true_state',
                     bag_synth.joint_state(ts, t[k], *state, effort=[force[k], 0.0]), 0)
        writer.write('/cartpole/force_command',
                     bag_synth.joint_state(ts, t[k], [], [], [force[k]], names=('cart',)), 0)
    killed = tmp_path / 'killed' / 'bag'
    shutil.copytree(live, killed)  # what is on disk now, with the writer still open
    writer.close()
    return killed, n


def _read(bag: Path) -> dict[str, list[int]]:
    return bag_synth.read_log_times(bag)


def test_a_killed_recording_is_repaired_and_loses_at_most_the_flush_period(tmp_path):
    killed, n = _record_and_kill(tmp_path, 6.0)
    assert not (killed / 'metadata.yaml').exists() and needs_repair(killed)
    result = repair_bag(killed)
    assert result.action == 'recovered' and result.damaged_copy.is_file()
    stamps = _read(killed)
    last = (n - 1) * bag_synth.TS
    for topic in ('/cartpole/true_state', '/cartpole/force_command'):
        got = stamps[topic]
        assert got == sorted(got) and got[0] == 0  # from the start, in order, no gap
        assert last - got[-1] * 1e-9 <= FLUSH_PERIOD + 1e-9, topic
        assert len(got) == round(got[-1] * 1e-9 / bag_synth.TS) + 1
    assert result.counts == {t: len(v) for t, v in stamps.items()}
    assert bag_custom_data(killed) == CUSTOM  # the run description survived the kill
    info = yaml.safe_load((killed / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert info['version'] == 9 and info['storage_identifier'] == 'mcap'
    assert info['message_count'] == result.message_count
    assert not needs_repair(killed)
    assert repair_bag(killed).action == 'intact'  # a second repair changes nothing


def test_a_record_cut_in_the_middle_is_dropped_and_the_rest_recovered(tmp_path):
    killed, _ = _record_and_kill(tmp_path, 3.0)
    whole = len(_read_repaired_copy(killed, tmp_path / 'whole')['/cartpole/true_state'])
    mcap = killed / 'bag_0.mcap'
    data = mcap.read_bytes()
    mcap.write_bytes(data[:len(data) // 2 + 7])  # the kill came in the middle of a chunk
    result = repair_bag(killed)
    assert result.action == 'recovered' and result.dropped_bytes > 0
    got = _read(killed)['/cartpole/true_state']
    assert 0 < len(got) < whole


def _read_repaired_copy(bag: Path, where: Path) -> dict[str, list[int]]:
    copy = where / 'bag'
    shutil.copytree(bag, copy)
    repair_bag(copy)
    return _read(copy)


def test_a_lost_metadata_yaml_is_rebuilt_from_the_file(tmp_path):
    bag = tmp_path / 'run' / 'bag'
    bag_synth.write_run(bag, custom_data=CUSTOM)
    before = yaml.safe_load((bag / 'metadata.yaml').read_text())
    (bag / 'metadata.yaml').unlink()
    result = repair_bag(bag)
    assert result.action == 'metadata' and result.damaged_copy is None
    after = yaml.safe_load((bag / 'metadata.yaml').read_text())
    assert after == before


def test_cartpole_bag_repair_and_info_and_analyze(tmp_path, capsys):
    killed, _ = _record_and_kill(tmp_path, 12.0)
    assert cli.main(['analyze', str(killed)]) == 2
    assert 'cartpole bag repair' in capsys.readouterr().err
    assert cli.main(['bag', 'repair', str(killed), '--json']) == 0
    report = json.loads(capsys.readouterr().out)
    assert report['action'] == 'recovered' and report['messages'] > 0
    assert cli.main(['bag', 'info', str(killed), '--json']) == 0
    info = json.loads(capsys.readouterr().out)
    assert info['needs_repair'] is False and info['custom_data'] == CUSTOM
    assert set(info['topics']) == {'/cartpole/true_state', '/cartpole/force_command'}
    assert cli.main(['analyze', str(killed), '--json']) == 0
    assert json.loads(capsys.readouterr().out)['catch_time_s'] is None  # no status recorded
    assert cli.main(['bag', 'repair', str(tmp_path / 'nothing')]) == 2


def test_the_writer_finishes_a_chunk_once_it_is_a_flush_period_old(tmp_path):
    """Wall-clock rule: nothing of the open chunk is in the file before the period, all after."""
    from cartpole_analysis.bags.storage import McapBagFile, TopicInfo
    now = [0.0]
    path = tmp_path / 'x.mcap'
    f = McapBagFile(path, flush_period=0.5, clock=lambda: now[0])
    f.add_topic(TopicInfo('/a', 'std_msgs/msg/Empty'), b'')
    size = path.stat().st_size
    f.write('/a', 0, b'\x00\x01\x00\x00', 0)
    now[0] = 0.4
    f.write('/a', 1, b'\x00\x01\x00\x00', 0)
    assert not f.flush_if_due() and path.stat().st_size == size  # still in the open chunk
    now[0] = 0.5
    assert f.flush_if_due()  # idle: the chunk is written though nothing new arrived
    assert path.stat().st_size > size
    f.abort()
