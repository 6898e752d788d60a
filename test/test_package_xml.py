"""Every package.xml declares what its package imports, under the key rosdep resolves.

`rosdep install --from-paths src --ignore-src` installs what the package.xml files
name and nothing else, so a module imported but not declared is an install that
fails at run time. This test reads every Python file of every package (``ast``:
``import`` and ``from ... import`` anywhere in the file, including the ones inside
functions), maps each top-level module to its dependency key and compares with the
package.xml:

- outside ``test/``: ``depend`` or ``exec_depend`` (``setup.py``: ``buildtool_depend``);
- in ``test/``: those, or ``test_depend``;
- and the other way round: a declared key that no file of the package uses is stale.

Keys: a ROS package is its own key (checked against the ament index, so a typo or
an unknown module is not taken for one); a workspace package too; the Python
libraries by :data:`ROSDEP_KEYS`, the keys of rosdep's ``python.yaml`` in
ros/rosdistro. A library without a rosdep key (:data:`PIP_ONLY`) is named in a
comment of the package.xml and pinned in requirements.txt, which the README's apt
route installs with pip.
"""
import ast
import re
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / 'src'
PACKAGES = sorted(p.parent for p in [*SRC.glob('*/package.xml'),
                                     *(ROOT / 'docs' / 'examples').glob('*/package.xml')])
"""The workspace's packages and the example of a third-party plugin package."""

ROSDEP_KEYS = {
    'numpy': 'python3-numpy',
    'scipy': 'python3-scipy',
    'yaml': 'python3-yaml',
    'serial': 'python3-serial',
    'matplotlib': 'python3-matplotlib',
    'PIL': 'python3-pil',
    'websockets': 'python3-websockets',
    'setuptools': 'python3-setuptools',
    'pytest': 'python3-pytest',
    'hypothesis': 'python3-hypothesis',
    'casadi': 'casadi-pip',
    'rosbags': 'python3-rosbags-pip',
}
"""Imported module -> its key in rosdep's python.yaml (ros/rosdistro)."""

PIP_ONLY = {
    'daqp': 'daqp',
    'osqp': 'osqp',
    'mcap': 'mcap',
    'foxglove': 'foxglove-sdk',
    'distributed': 'distributed',
    'gymnasium': 'gymnasium',
    'stable_baselines3': 'stable-baselines3',
    'torch': 'torch',
}
"""Imported module -> its PyPI distribution, for libraries rosdep has no key for."""

IMPLIED = {
    'rclpy.lifecycle': 'lifecycle_msgs',
}
"""Imports that use another package's interfaces at run time (rclpy's lifecycle node
serves and calls lifecycle_msgs services)."""

_MESSAGE_TYPE = re.compile(r'^([a-z][a-z0-9_]*)/(?:msg|srv|action)/[A-Z]\w*$')
_PIP_COMMENT = re.compile(r'no rosdep key.*?:(.*?)-->', re.S)


def _ament_packages():
    from ament_index_python.packages import get_packages_with_prefixes
    return set(get_packages_with_prefixes())


def _is_test(package: Path, path: Path) -> bool:
    return path.relative_to(package).parts[0] == 'test'


def imports(path: Path) -> set[str]:
    """Dotted module names a file imports (absolute imports only) and the packages of
    the ``pkg/msg/Type`` strings it names (types it imports by name at run time)."""
    tree = ast.parse(path.read_text(encoding='utf-8'), str(path))
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found.add(node.module)
            found.update(f'{node.module}.{alias.name}' for alias in node.names)
        elif isinstance(node, ast.Constant) and isinstance(node.value, str):
            match = _MESSAGE_TYPE.match(node.value)
            if match:
                found.add(match.group(1))
    return found


def keys_of(modules: set[str], local: set[str], ament: set[str]) -> tuple[set[str], list[str]]:
    """The dependency keys of dotted module names, and the modules no key is known for.

    ``local``: modules of the directory itself (a test's helper modules)."""
    keys, unknown = set(), []
    for module in modules:
        for prefix, key in IMPLIED.items():
            if module == prefix or module.startswith(prefix + '.'):
                keys.add(key)
        top = module.split('.')[0]
        if top in sys.stdlib_module_names or top in local:
            continue
        if top in ROSDEP_KEYS:
            keys.add(ROSDEP_KEYS[top])
        elif top in PIP_ONLY:
            keys.add('pip:' + PIP_ONLY[top])
        elif top in ament:
            keys.add(top)
        else:
            unknown.append(module)
    return keys, sorted(set(unknown))


def declared(package: Path) -> dict[str, set[str]]:
    """Keys of a package.xml by role: run, test, build; ``pip:<name>`` for the libraries
    its comments name as having no rosdep key."""
    text = (package / 'package.xml').read_text(encoding='utf-8')
    root = ET.fromstring(text)
    tags = {tag: {e.text.strip() for e in root.findall(tag)}
            for tag in ('depend', 'exec_depend', 'test_depend', 'buildtool_depend',
                        'build_depend')}
    pip = set()
    for body in _PIP_COMMENT.findall(text):
        pip.update('pip:' + name for name in re.findall(r'[A-Za-z0-9][A-Za-z0-9_.\-]*', body))
    run = tags['depend'] | tags['exec_depend']
    return {'run': run, 'pip': pip, 'test': tags['test_depend'],
            'build': tags['buildtool_depend'] | tags['build_depend'] | tags['depend']}


def _depends_on(package: str, other: str, graph: dict[str, set[str]]) -> bool:
    """``package`` (transitively) depends on ``other`` through run-time dependencies."""
    seen, todo = set(), [package]
    while todo:
        name = todo.pop()
        for dep in graph.get(name, ()):
            if dep == other:
                return True
            if dep not in seen:
                seen.add(dep)
                todo.append(dep)
    return False


def problems(package: Path, ament: set[str], workspace: dict[str, dict[str, set[str]]]) -> list[str]:
    """What the package.xml of ``package`` does not declare, or declares for nothing."""
    name = package.name
    have = workspace[name]
    graph = {n: d['run'] & set(workspace) for n, d in workspace.items()}
    ament = ament | set(workspace)
    found = []
    missing: dict[str, list[str]] = {}
    used = {'run': set(), 'test': set(), 'build': set()}
    for path in sorted(package.rglob('*.py')):
        role = ('test' if _is_test(package, path)
                else 'build' if path.relative_to(package) == Path('setup.py') else 'run')
        local = {p.stem for p in path.parent.glob('*.py')} if role == 'test' else set()
        keys, unknown = keys_of(imports(path), local, ament)
        keys.discard(name)
        where = str(path.relative_to(package))
        for module in unknown:
            found.append(f'{name}/{where}: imports {module}, neither a ROS package nor in '
                         'ROSDEP_KEYS or PIP_ONLY of test/test_package_xml.py: find its rosdep key')
        used[role] |= keys
        for key in keys:
            if key.startswith('pip:'):
                ok = key in have['pip']
                want = f'a comment "no rosdep key ...: {key[4:]}"'
            elif role == 'run':
                ok, want = key in have['run'], f'<exec_depend>{key}</exec_depend>'
            elif role == 'build':
                ok, want = key in have['build'], f'<buildtool_depend>{key}</buildtool_depend>'
            else:
                ok = key in have['run'] | have['test']
                want = f'<test_depend>{key}</test_depend>'
                if not ok and key in workspace and _depends_on(key, name, graph):
                    ok = True  # a test_depend would be a cycle colcon refuses; built anyway
            if not ok:
                missing.setdefault(want, []).append(where)
    for want, files in sorted(missing.items()):
        more = f' and {len(files) - 2} more' if len(files) > 2 else ''
        found.append(f'{name}/package.xml lacks {want}: used by {", ".join(files[:2])}{more}')
    for key in sorted(have['run'] - used['run']):
        found.append(f'{name}/package.xml: <exec_depend>{key}</exec_depend> but no module '
                     'of the package outside test/ uses it')
    for key in sorted(have['test'] - used['test']):
        found.append(f'{name}/package.xml: <test_depend>{key}</test_depend> but no test uses it')
    for key in sorted(have['pip'] - used['run'] - used['test']):
        found.append(f'{name}/package.xml: names {key[4:]} as a pip dependency but nothing '
                     'imports it')
    return found


def _workspace():
    return {p.name: declared(p) for p in PACKAGES}


@pytest.mark.parametrize('package', PACKAGES, ids=lambda p: p.name)
def test_package_xml_declares_exactly_what_the_package_imports(package):
    assert problems(package, _ament_packages(), _workspace()) == []


def test_every_pip_only_library_is_pinned_in_requirements():
    pinned = {re.split(r'[=<>\[ ]', line, maxsplit=1)[0].lower()
              for name in ('requirements.txt', 'requirements-train.txt')
              for line in (ROOT / name).read_text().splitlines()
              if line.strip() and not line.startswith('#')}
    assert sorted((set(PIP_ONLY.values()) | {'casadi', 'rosbags'}) - pinned) == []


def test_the_keys_are_rosdep_keys():
    """Each key of ROSDEP_KEYS is spelled as rosdep's python.yaml spells them (the ones with a
    ``-pip`` suffix install with pip, the others with apt)."""
    for module, key in ROSDEP_KEYS.items():
        assert re.fullmatch(r'python3-[a-z0-9-]+|[a-z0-9]+-pip', key), (module, key)
    assert not set(ROSDEP_KEYS) & set(PIP_ONLY)


def test_a_removed_dependency_is_named(tmp_path):
    """The check notices an import the package.xml lost, a test-only import declared as
    nothing, and a declaration nothing uses."""
    import shutil
    package = tmp_path / 'cartpole_core'
    shutil.copytree(SRC / 'cartpole_core', package,
                    ignore=shutil.ignore_patterns('__pycache__', '*.urdf'))
    xml = package / 'package.xml'
    text = xml.read_text()
    text = text.replace('  <exec_depend>python3-yaml</exec_depend>\n', '')
    text = text.replace('  <test_depend>python3-pytest</test_depend>\n',
                        '  <test_depend>python3-pytest</test_depend>\n'
                        '  <test_depend>python3-hypothesis</test_depend>\n')
    xml.write_text(text)
    (package / 'cartpole_core' / 'uses_pandas.py').write_text('import pandas\n')
    workspace = _workspace()
    workspace['cartpole_core'] = declared(package)
    found = problems(package, _ament_packages(), workspace)
    assert sorted(found) == [
        'cartpole_core/cartpole_core/uses_pandas.py: imports pandas, neither a ROS package nor in '
        'ROSDEP_KEYS or PIP_ONLY of test/test_package_xml.py: find its rosdep key',
        'cartpole_core/package.xml lacks <exec_depend>python3-yaml</exec_depend>: used by '
        'cartpole_core/model.py',
        'cartpole_core/package.xml: <test_depend>python3-hypothesis</test_depend> but no test '
        'uses it'], found
