"""Each node's installed parameter file is current, and rcl loads it onto the node.

The files come from :mod:`cartpole_tools.readme_tables.params_files`; the README
check (``python -m cartpole_tools.readme_tables --check``, test_readme_tables.py)
fails when one is stale. Here: what each file holds reaches its node through
``--ros-args --params-file`` as ``ros2 run`` passes it (the process's arguments,
rcl's YAML parser), typed as declared, in a namespace too.
"""
import math
import re
from pathlib import Path

import pytest
import yaml

from cartpole_tools.readme_tables import params_files
from cartpole_tools.readme_tables.introspect import NODES, NodeInfo, ParameterInfo, _build

CHANGED = {
    'sim': ('friction_scale', '1.25', 1.25),
    'ekf': ('r', '[0.02, 0.2]', [0.02, 0.2]),
    'controller_manager': ('stabilizer', '"smc"', 'smc'),
    'hw_bridge': ('baud', '57600', 57600),
    'recorder': ('queue_depth', '50', 50),
    'viewer': ('max_rate', '30.0', 30.0),
}
"""Per node: a parameter set to a value other than its default in a copy of its file."""


def _node_name(executable: str) -> str:
    return {'sim_node': 'sim', 'ekf_node': 'ekf', 'cartpole_recorder': 'recorder',
            'cartpole_viewer': 'viewer'}.get(executable, executable)


def _value(node, name: str):
    value = node.get_parameter(name).value
    value = value.tolist() if hasattr(value, 'tolist') else value
    return list(value) if isinstance(value, tuple) else value


def _installed(package: str, node: str) -> Path:
    from ament_index_python.packages import get_package_share_directory
    return Path(get_package_share_directory(package)) / 'config' / f'{node}.yaml'


def _same(a, b) -> bool:
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a):
        return math.isnan(b)
    return a == b


@pytest.mark.ros
@pytest.mark.parametrize('source', NODES, ids=[s.executable for s in NODES])
def test_installed_parameter_file_reaches_the_node(source, tmp_path):
    import rclpy
    from rclpy.context import Context

    name = _node_name(source.executable)
    installed = _installed(source.package, name)
    assert installed.is_file(), f'{installed} is not installed (setup.py data_files)'
    parameter, text, value = CHANGED[name]
    content = installed.read_text()
    edited, count = re.subn(rf'^    {re.escape(parameter)}: .*$', f'    {parameter}: {text}',
                            content, flags=re.M)
    assert count == 1
    path = tmp_path / f'{name}.yaml'
    path.write_text(edited)
    expected = yaml.safe_load(edited)[f'/**/{name}']['ros__parameters']

    context = Context()
    rclpy.init(args=['--ros-args', '--params-file', str(path), '-r', '__ns:=/rig2'],
               context=context)
    try:
        node = _build(source, context, {}, tmp_path / 'work')
        try:
            assert node.get_namespace() == '/rig2'
            declared = {n for n in node.list_parameters([], 0).names}
            assert set(expected) <= declared
            forced = source.overrides(tmp_path / 'work')  # e.g. the bridge's port: not a device
            for key, want in expected.items():
                if key not in forced:
                    assert _same(want, _value(node, key)), (key, want, _value(node, key))
            assert _value(node, parameter) == value
        finally:
            node.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)


def _info(default=0.05, description='how long'):
    return NodeInfo(node='demo', executable='demo_node', package='demo_pkg', endpoints=(),
                    parameters=(ParameterInfo('timeout', 'double', default, 0.0, 1.0, 0.0, False,
                                              description, ''),
                                ParameterInfo('lqg.q', 'double_array', [1e-05, 1e6], None, None,
                                              None, False, 'weights', ''),
                                ParameterInfo('port', 'string', '', None, None, None, True,
                                              'device', ''),
                                ParameterInfo('x_ref', 'double', math.nan, None, None, None,
                                              False, 'x*', ''),
                                ParameterInfo('depth', 'integer', 3, 1, 9, 1, False, 'n', '')))


def test_values_keep_their_type_in_yaml():
    text = params_files.render(_info())
    assert '/**/demo:\n  ros__parameters:\n' in text
    assert '    timeout: 0.05\n' in text
    assert '    lqg.q: [1.0e-05, 1000000.0]\n' in text   # doubles never look like integers
    assert '    port: ""\n' in text and '    x_ref: .nan\n' in text and '    depth: 3\n' in text
    assert '    # how long ([0.0, 1.0])\n' in text
    assert params_files.yaml_value(2.0, 'double') == '2.0'
    assert params_files.yaml_value(-math.inf, 'double') == '-.inf'
    assert params_files.yaml_value('true', 'string') == '"true"'    # a string, not a bool
    assert params_files.yaml_value([True, False], 'bool_array') == '[true, false]'


def test_check_names_a_stale_or_missing_file(tmp_path):
    files = params_files.expected([_info()], tmp_path)
    path, = files
    assert path == tmp_path / 'demo_pkg' / 'config' / 'demo.yaml'
    assert params_files.stale(files) == [f'{path}: missing']
    assert params_files.write(files) == [path]
    assert params_files.stale(files) == [] and params_files.write(files) == []
    changed = params_files.expected([_info(default=0.08)], tmp_path)
    assert params_files.stale(changed) == [f'{path}: differs from the declarations of its node']


def test_committed_files_are_the_installed_ones():
    """Every node has its file in src/<package>/config/ and the build installs that one."""
    src = Path(__file__).resolve().parents[2]
    for source in NODES:
        name = _node_name(source.executable)
        committed = src / source.package / 'config' / f'{name}.yaml'
        assert committed.read_text() == _installed(source.package, name).read_text()


def test_cartpole_params_reads_the_installed_file(tmp_path):
    """``cartpole run|offline --params FILE`` reads a copy of an installed file as rcl does."""
    from cartpole_bringup.boundary import ros_parameters
    text = _installed('cartpole_control', 'controller_manager').read_text()
    path = tmp_path / 'mine.yaml'
    path.write_text(text.replace('    stabilizer: "lqg"\n', '    stabilizer: "smc"\n'))
    found = ros_parameters(path, 'controller_manager')
    assert found == {k: tuple(v) if isinstance(v, list) else v for k, v in
                     yaml.safe_load(path.read_text())['/**/controller_manager']
                     ['ros__parameters'].items()}
    assert found['stabilizer'] == 'smc'
    assert ros_parameters(path, 'ekf') == {}


def test_the_installed_manager_file_is_a_params_file_offline_takes(tmp_path, capsys):
    # The file holds the node's own parameters (lockstep, lockstep_wait, stamp_tolerance):
    # the offline loop checks them against their ranges and does not hand them to the
    # manager, which has none of them (it refused 'lockstep' before).
    from cartpole_bringup import cli

    installed = Path(__file__).parents[2] / 'cartpole_control' / 'config' / 'controller_manager.yaml'
    assert cli.main(['offline', '--duration', '0.5', '--json', '--params', str(installed)]) == 0
    assert 'error' not in capsys.readouterr().err
    bad = tmp_path / 'manager.yaml'
    bad.write_text(installed.read_text().replace('lockstep_wait: 0.5', 'lockstep_wait: 20.0'))
    assert cli.main(['offline', '--duration', '0.5', '--params', str(bad)]) == 2
    err = capsys.readouterr().err
    assert 'controller_manager: lockstep_wait must be <= 10, got 20.0' in err
    assert len(err.strip().splitlines()) == 1
