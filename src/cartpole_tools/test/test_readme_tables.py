"""The generated reference tables agree with the code, and the check notices when they do not."""
import os
import subprocess
import sys
from pathlib import Path

import pytest

from cartpole_tools.readme_tables.introspect import Endpoint, NodeInfo, ParameterInfo
from cartpole_tools.readme_tables.regions import find_regions, problems, problems_across, rewrite
from cartpole_tools.readme_tables.render import MissingNote
from cartpole_tools.readme_tables.tables import generate

ROOT = Path(__file__).resolve().parents[3]
REFERENCE = ROOT / 'docs' / 'reference'


def _parameter(name, default, low=None, high=None, read_only=False):
    type_name = {bool: 'bool', int: 'integer', float: 'double', str: 'string'}[type(default)]
    return ParameterInfo(name=name, type_name=type_name, default=default, low=low, high=high,
                         step=0.0 if low is not None else None, read_only=read_only,
                         description=f'what {name} does', additional_constraints='')


class _FakeStabilizer:
    """A stabiliser law for the test (its first docstring line is the table's 'law')."""


def _nodes(state_timeout=0.05, extra_topic=None):
    manager = NodeInfo(
        node='controller_manager', executable='controller_manager', package='cartpole_control',
        parameters=(_parameter('state_timeout', state_timeout, 0.006, 10.0),
                    _parameter('sample_time', 0.005, 1e-4, 0.1, read_only=True),
                    _parameter('fake.gain', 2.0, 0.0, 5.0)),
        endpoints=(Endpoint('publishes', '/cartpole/force_command', 'sensor_msgs/msg/JointState'),
                   Endpoint('subscribes', '/cartpole/state', 'sensor_msgs/msg/JointState'),
                   Endpoint('service', '/controller_manager/restart_swingup',
                            'std_srvs/srv/Trigger')))
    ekf_endpoints = [Endpoint('publishes', '/cartpole/state', 'sensor_msgs/msg/JointState')]
    if extra_topic:
        ekf_endpoints.append(Endpoint('publishes', extra_topic, 'std_msgs/msg/Header'))
    ekf = NodeInfo(node='ekf', executable='ekf_node', package='cartpole_estimation',
                   parameters=(_parameter('health_period', 0.1, 0.01, 10.0),),
                   endpoints=tuple(ekf_endpoints))
    return {'controller_manager': manager, 'ekf': ekf}


def _generate(**kwargs):
    return generate(_nodes(**kwargs), {'stabilizer': {'fake': _FakeStabilizer}},
                    ['/cartpole/state', '/cartpole/force_command'])


def _readme(generated):
    """A README with prose around an (empty) region for every generated table."""
    parts = ['# Title', '', 'Prose that must survive.', '']
    for key in generated:
        parts += [f'## {key}', '', f'<!-- generated: {key} -->', '<!-- end generated -->', '',
                  'More prose.', '']
    return rewrite('\n'.join(parts), generated)


def test_write_then_check_agrees_and_keeps_the_prose():
    generated = _generate()
    text = _readme(generated)
    assert problems(text, generated) == []
    assert text.count('More prose.') == len(generated) and 'Prose that must survive.' in text
    assert rewrite(text, generated) == text  # rewriting is idempotent
    table = {r.key: r.body for r in find_regions(text)}['parameters controller_manager']
    assert '| `state_timeout` | double | `0.05` | [0.006, 10.0] |' in table
    assert '[0.0001, 0.1]; read-only' in table
    assert 'fake.gain' not in table  # a plugin's gains go to the plugins' section
    plugins = {r.key: r.body for r in find_regions(text)}['plugin-parameters']
    assert '### `fake` (stabilizer)' in plugins
    assert '| `fake.gain` | double | `2.0` | [0.0, 5.0] |' in plugins


def test_check_names_a_changed_default_in_the_readme():
    generated = _generate()
    text = _readme(generated)
    edited = text.replace('| `state_timeout` | double | `0.05` |',
                          '| `state_timeout` | double | `0.08` |')
    assert edited != text
    found = problems(edited, generated)
    assert len(found) == 1
    assert "'parameters controller_manager' disagrees" in found[0]
    assert '-| `state_timeout` | double | `0.08`' in found[0]
    assert '+| `state_timeout` | double | `0.05`' in found[0]


def test_check_names_a_changed_default_in_the_code():
    text = _readme(_generate())
    found = problems(text, _generate(state_timeout=0.1))
    assert len(found) == 1 and 'parameters controller_manager' in found[0]
    assert '`0.1`' in found[0]


def test_check_names_missing_and_unknown_regions():
    generated = _generate()
    text = _readme(generated)
    without = text.replace('<!-- generated: parameters ekf -->', '<!-- generated: parameters kf -->')
    found = problems(without, generated)
    assert any('no region "<!-- generated: parameters ekf -->"' in p for p in found)
    assert any("'parameters kf' names nothing" in p for p in found)
    with pytest.raises(ValueError, match='complete regions'):
        find_regions(text.replace('<!-- end generated -->', '', 1))


def test_a_topic_without_a_note_is_refused():
    with pytest.raises(MissingNote, match='/cartpole/new_topic'):
        _generate(extra_topic='/cartpole/new_topic')


def test_the_status_note_names_every_status_key():
    """A status key added to the manager without documenting it fails the generation."""
    from cartpole_tools.readme_tables import notes
    from cartpole_control.manager_node import STATUS_KEYS

    note = notes.ENDPOINT_NOTES[('controller_manager', '/cartpole/controller_status')]
    assert all(f'`{k}`' in note for k in STATUS_KEYS)


def test_every_region_stands_in_one_document_only():
    generated = _generate()
    text = _readme(generated)
    first, second = Path('a.md'), Path('b.md')
    assert problems_across({first: text}, generated) == []
    found = problems_across({first: text, second: text}, generated)
    assert len(found) == len(generated) and all('appears in 2 documents' in p for p in found)
    found = problems_across({first: text.replace('<!-- generated: topics -->', '<!-- generated: x -->')},
                            generated)
    assert any('no document has a region "<!-- generated: topics -->"' in p for p in found)
    assert any("'x' names nothing" in p for p in found)


def _check(*documents: Path):
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    doc_args = [a for d in documents for a in ('--doc', str(d))]
    return subprocess.run([sys.executable, '-m', 'cartpole_tools.readme_tables', '--check',
                           *doc_args], capture_output=True, text=True, timeout=120, env=env)


@pytest.mark.ros
def test_reference_tables_match_the_code(tmp_path):
    """The installed nodes, plugins, bag topics and the cartpole command are what the generated
    tables of docs/reference/ say.

    On failure: ``python -m cartpole_tools.readme_tables --write`` and commit docs/reference/.
    """
    pages = sorted(REFERENCE.glob('*.md'))
    result = _check(ROOT / 'README.md', *pages)
    assert result.returncode == 0, result.stderr[-4000:]
    text = '\n'.join(p.read_text(encoding='utf-8') for p in pages)
    for key in ('parameters controller_manager', 'parameters sim', 'parameters ekf',
                'parameters hw_bridge', 'parameters recorder', 'plugins', 'topics',
                'plugin-parameters', 'cli'):
        assert f'<!-- generated: {key} -->' in text
    assert '### `time_optimal` (swingup)' in text and '### `cartpole run`' in text
    # the check notices one changed default in the manager's table
    parameters = REFERENCE / 'parameters.md'
    edited = parameters.read_text(encoding='utf-8').replace(
        '| `state_timeout` | double | `0.05` |', '| `state_timeout` | double | `0.5` |')
    copy = tmp_path / 'parameters.md'
    copy.write_text(edited, encoding='utf-8')
    result = _check(ROOT / 'README.md', *[copy if p == parameters else p for p in pages])
    assert result.returncode == 1
    assert "'parameters controller_manager' disagrees" in result.stderr
    assert '`0.5`' in result.stderr
