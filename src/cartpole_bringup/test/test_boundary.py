"""The boundary's own promises (issue 23): strict JSON, figure paths, damaged bags."""
from __future__ import annotations

import importlib.util
import json
from pathlib import Path

from cartpole_bringup import cli
from cartpole_bringup.boundary import figure_file, json_text

_spec = importlib.util.spec_from_file_location('bag_synth', Path(__file__).parents[2] / 'cartpole_analysis' / 'test' / 'bag_synth.py')
bag_synth = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bag_synth)


def test_json_has_no_nan_and_says_why_a_value_is_null():
    text = json_text({'mse_x': float('nan'), 'runs': [{'a': float('inf')}], 'ok': 1.5})
    data = json.loads(text)  # strict: NaN would not parse as JSON elsewhere
    assert ': NaN' not in text and 'Infinity' not in text
    assert data['mse_x'] is None and data['runs'][0]['a'] is None and data['ok'] == 1.5
    assert set(data['null_reasons']) == {'mse_x', 'runs[0].a'}


def test_a_figure_without_extension_is_a_png(tmp_path):
    assert figure_file(tmp_path / 'out', '--plot') == tmp_path / 'out.png'


def test_garbage_metadata_is_damaged_then_repaired(tmp_path, capsys):
    bag = tmp_path / 'bag'
    bag_synth.write_run(bag)
    (bag / 'metadata.yaml').write_text('rosbag2_bagfile_information: [garbage\n')
    assert cli.main(['bag', 'info', str(bag)]) == 1
    err = capsys.readouterr().err.strip()
    assert err.count('\n') == 0 and 'damaged' in err and f'cartpole bag repair {bag}' in err
    assert cli.main(['analyze', str(bag)]) == 2
    assert capsys.readouterr().err.strip() == f'cartpole analyze: error: {err.split(": ", 1)[1]}'
    assert cli.main(['bag', 'repair', str(bag), '--json']) == 0
    assert json.loads(capsys.readouterr().out)['action'] == 'metadata'
    assert (bag / 'metadata.yaml.damaged').is_file()
    assert cli.main(['bag', 'info', str(bag)]) == 0


def test_a_random_mcap_cannot_be_repaired_and_says_so(tmp_path, capsys):
    bag = tmp_path / 'bag'
    bag.mkdir()
    (bag / 'bag_0.mcap').write_bytes(b'not an mcap file at all')
    assert cli.main(['bag', 'repair', str(bag)]) == 1
    err = capsys.readouterr().err.strip()
    assert err.count('\n') == 0 and 'not an MCAP file' in err and 'can be recovered' in err
