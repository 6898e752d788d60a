"""Split bags (no ROS): a new file every max_bag_duration or max_bag_size, as rosbag2 does.

Every reader takes the files together (rosbags, `cartpole bag info`, `cartpole analyze`,
the check and the repair), a kill between splits loses only the open file's last
flush period, and a closed file's index leaves memory (what bounds a long recording).
"""
from __future__ import annotations

import importlib.util
import json
import shutil
import tracemalloc
from pathlib import Path

import pytest
import yaml

from cartpole_analysis.analysis.analyze import analyze_bag
from cartpole_analysis.bags.check import damage
from cartpole_analysis.bags.repair import bag_files, needs_repair, repair_bag
from cartpole_analysis.bags.storage import FLUSH_PERIOD
from cartpole_analysis.bags.writer import BagWriter
from cartpole_bringup import cli

_spec = importlib.util.spec_from_file_location('bag_synth', Path(__file__).with_name('bag_synth.py'))
bag_synth = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bag_synth)

CUSTOM = {'x_ref': repr(bag_synth.X_REF), 'lockstep': 'true'}
EMPTY = b'\x00\x01\x00\x00\x00\x00\x00\x00\x00\x00\x00\x00'
"""A CDR std_msgs/Header-led message whose stamp bytes are patched by :func:`_at`."""


def _at(seconds: float) -> bytes:
    ns = int(round(seconds * 1e9))
    return EMPTY[:4] + (ns // 10**9).to_bytes(4, 'little') + (ns % 10**9).to_bytes(4, 'little')


def _read(bag: Path) -> dict[str, list[int]]:
    return bag_synth.read_log_times(bag)


def test_a_split_bag_lists_every_file_and_reads_as_one(tmp_path, capsys):
    bag = tmp_path / 'run' / 'bag'
    bag_synth.write_run(bag, custom_data=CUSTOM, max_bag_duration=6.0)  # 20 s of run
    whole = tmp_path / 'whole' / 'bag'
    bag_synth.write_run(whole, custom_data=CUSTOM, max_bag_duration=0.0)
    names = [p.name for p in bag_files(bag)]
    assert names == ['bag_0.mcap', 'bag_1.mcap', 'bag_2.mcap', 'bag_3.mcap']
    assert [p.name for p in bag_files(whole)] == ['bag_0.mcap']
    info = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert info['relative_file_paths'] == names
    assert [f['path'] for f in info['files']] == names
    assert sum(f['message_count'] for f in info['files']) == info['message_count']
    spans = [(f['starting_time']['nanoseconds_since_epoch'], f['duration']['nanoseconds'])
             for f in info['files']]
    assert all(d <= 6e9 for _, d in spans)  # no file spans more than max_bag_duration
    assert [s for s, _ in spans] == sorted(s for s, _ in spans)
    assert info['custom_data'] == CUSTOM and damage(bag) is None
    assert _read(bag) == _read(whole)  # every message once, in order, across the files
    assert analyze_bag(bag).summary == analyze_bag(whole).summary
    assert cli.main(['bag', 'info', str(bag), '--json']) == 0
    facts = json.loads(capsys.readouterr().out)
    assert facts['files'] == names and facts['messages'] == info['message_count']
    assert repair_bag(bag).action == 'intact'


def test_a_bag_is_split_by_size(tmp_path):
    with BagWriter(tmp_path / 'bag', {'/clock': 'rosgraph_msgs/msg/Clock'},
                   max_bag_duration=0.0, max_bag_size=20_000) as bag:
        for k in range(4000):
            bag.write('/clock', _at(k * 0.005), 0)
    sizes = [p.stat().st_size for p in bag_files(tmp_path / 'bag')]
    assert len(sizes) >= 3
    assert all(20_000 <= s <= 30_000 for s in sizes[:-1])  # split at the first chunk past it
    assert sum(len(v) for v in _read(tmp_path / 'bag').values()) == 4000


def test_a_kill_after_splits_loses_only_the_open_file_s_flush_period(tmp_path):
    ts = bag_synth._types()
    t, x, theta, x_dot, theta_dot, force = bag_synth.trajectory()
    live = tmp_path / 'live' / 'bag'
    writer = BagWriter(live, custom_data=CUSTOM, max_bag_duration=4.0)
    n = int(round(10.0 / bag_synth.TS))
    for k in range(n):
        writer.write('/cartpole/true_state', bag_synth.joint_state(
            ts, t[k], [x[k], theta[k]], [x_dot[k], theta_dot[k]], [force[k], 0.0]), 0)
    killed = tmp_path / 'killed' / 'bag'
    shutil.copytree(live, killed)  # what is on disk with the writer open in its third file
    writer.close()
    meta = yaml.safe_load((killed / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert meta['relative_file_paths'] == ['bag_0.mcap', 'bag_1.mcap', 'bag_2.mcap']
    assert 'bag_2.mcap is truncated' in damage(killed) and needs_repair(killed)
    result = repair_bag(killed)
    assert result.action == 'recovered' and [p.name for p in result.damaged_copies] == [
        'bag_2.mcap.damaged']
    got = _read(killed)['/cartpole/true_state']
    assert got == [round(k * bag_synth.TS * 1e9) for k in range(len(got))]  # no gap
    assert (n - 1) * bag_synth.TS - got[-1] * 1e-9 <= FLUSH_PERIOD + 1e-9
    assert damage(killed) is None and not needs_repair(killed)
    assert yaml.safe_load((killed / 'metadata.yaml').read_text())[
        'rosbag2_bagfile_information']['custom_data'] == CUSTOM


def test_a_lost_metadata_yaml_of_a_split_bag_is_rebuilt_in_file_order(tmp_path):
    bag = tmp_path / 'bag'
    with BagWriter(bag, {'/clock': 'rosgraph_msgs/msg/Clock'}, max_bag_duration=1.0) as w:
        for k in range(2400):  # 12 s: 12 files, so that bag_10 sorts after bag_9
            w.write('/clock', _at(k * 0.005), 0)
    before = yaml.safe_load((bag / 'metadata.yaml').read_text())
    (bag / 'metadata.yaml').unlink()
    assert repair_bag(bag).action == 'metadata'
    assert yaml.safe_load((bag / 'metadata.yaml').read_text()) == before


@pytest.mark.parametrize('bad', [float('nan'), -1.0])
def test_a_bad_split_is_refused(tmp_path, bad):
    with pytest.raises(ValueError, match='max_bag_duration and max_bag_size must be >= 0'):
        BagWriter(tmp_path / 'bag', max_bag_duration=bad)
    assert not (tmp_path / 'bag').exists()


def _index_memory(tmp_path: Path, max_bag_duration: float) -> int:
    """Heap growth [bytes] in the mcap writer of writing 3000 chunks (0.5 s of log time apart).

    Counted where the mcap writer allocates (its chunk and message indexes), so that the
    one-time caches a new file fills elsewhere (yaml, package metadata) do not count."""
    with BagWriter(tmp_path / f'bag_{max_bag_duration:g}', {'/clock': 'rosgraph_msgs/msg/Clock'},
                   max_bag_duration=max_bag_duration) as bag:
        bag.write('/clock', _at(0.0), 0)
        tracemalloc.start(4)
        try:
            before = tracemalloc.take_snapshot()
            for k in range(1, 3001):
                bag.write('/clock', _at(k * FLUSH_PERIOD), 0)  # each one finishes a chunk
            after = tracemalloc.take_snapshot()
        finally:
            tracemalloc.stop()
    in_mcap = [tracemalloc.Filter(True, '*/mcap/writer.py', all_frames=True)]
    return sum(d.size_diff for d in after.filter_traces(in_mcap).compare_to(
        before.filter_traces(in_mcap), 'filename'))


def test_a_closed_file_s_index_leaves_memory(tmp_path):
    unsplit = _index_memory(tmp_path, 0.0)
    split = _index_memory(tmp_path, 60.0)  # 120 chunks a file
    assert unsplit > 500_000         # ~0.26 kB of index a chunk of one topic, until the close
    assert split < unsplit / 10
