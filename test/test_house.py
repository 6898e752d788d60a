"""The workspace's shape: no import circle, dependencies pointing one way, files a reader can hold.

Reads every module of every workspace package with ``ast``, counting the imports
inside functions as well as the ones at the top (a circle hidden in a function is
still a circle: the two modules cannot be understood or tested apart). Tests are
left out of the module graph: they may import anything below or beside them.

The layer order is the one the packages are built in: ``cartpole_core`` below
``cartpole_sim``, ``cartpole_hw``, ``cartpole_estimation`` and ``cartpole_control``
(three of which never import the simulator), then ``cartpole_emulator``,
``cartpole_analysis``, ``cartpole_bringup`` and ``cartpole_tools``.
"""
import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / 'src'

LAYER = {
    'cartpole_core': 0,
    'cartpole_sim': 1, 'cartpole_hw': 1, 'cartpole_estimation': 1, 'cartpole_control': 1,
    'cartpole_emulator': 2,
    'cartpole_analysis': 3,
    'cartpole_bringup': 4,
    'cartpole_tools': 5, 'cartpole_learning': 5,
}
"""Package -> its layer; a package imports only packages of a lower layer (and itself)."""

NEVER = {('cartpole_hw', 'cartpole_sim'), ('cartpole_estimation', 'cartpole_sim'),
         ('cartpole_control', 'cartpole_sim')}
"""(importer, imported) pairs refused although the layers would allow them."""

KNOWN_CIRCLES: list[list[str]] = []
"""Circles that other work in progress breaks; the merge that breaks one removes it here."""

MAX_LINES = 500

TOO_LONG_KNOWN: set[str] = set()
"""Files over the limit that other work in progress splits; the merge that splits one
removes it here. A listed file that is no longer too long fails the test too, so the
list only shrinks."""

MAX_DOCSTRING_LINES = 20



def _modules() -> dict[str, Path]:
    """Dotted module name -> file, for every non-test module of every workspace package."""
    found = {}
    for package in sorted(p for p in SRC.iterdir() if p.name in LAYER):
        for path in sorted((package / package.name).rglob('*.py')):
            parts = list(path.relative_to(package).with_suffix('').parts)
            if parts[-1] == '__init__':
                parts.pop()
            found['.'.join(parts)] = path
    return found


def _imports(name: str, path: Path, modules: dict[str, Path]) -> set[str]:
    """Workspace modules ``name`` imports anywhere in its file (relative imports resolved)."""
    is_package = path.name == '__init__.py'
    here = name.split('.') if is_package else name.split('.')[:-1]
    targets = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            targets.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = here[:len(here) - node.level + 1]
                module = '.'.join(base + ([node.module] if node.module else []))
            else:
                module = node.module or ''
            targets.add(module)
            targets.update(f'{module}.{alias.name}' for alias in node.names)
    resolved = set()
    for target in targets:
        # The longest prefix that is a workspace module (``from a.b import func`` -> a.b).
        parts = target.split('.')
        while parts and '.'.join(parts) not in modules:
            parts.pop()
        if parts and '.'.join(parts) != name:
            resolved.add('.'.join(parts))
    return resolved


def _graph() -> dict[str, set[str]]:
    modules = _modules()
    return {name: _imports(name, path, modules) for name, path in modules.items()}


def _parents(name: str) -> set[str]:
    """A module's enclosing packages: importing ``a.b.c`` runs ``a`` and ``a.b`` first, but
    that is Python's doing, not an edge a reader follows, so packages are not edges."""
    parts = name.split('.')
    return {'.'.join(parts[:i]) for i in range(1, len(parts))}


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan)."""
    index, low, stack, on_stack, found = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph.get(v, ()):
            if w in _parents(v):
                continue
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_no_import_circle_even_inside_functions():
    found = _cycles(_graph())
    assert [c for c in found if c not in KNOWN_CIRCLES] == []
    assert [c for c in KNOWN_CIRCLES if c not in found] == [], 'broken: remove from KNOWN_CIRCLES'



def test_the_checker_finds_a_circle_hidden_in_a_function(tmp_path):
    graph = {'p.a': {'p.b'}, 'p.b': set(), 'p.c': {'p.d'}, 'p.d': {'p.e'}, 'p.e': {'p.c'}}
    assert _cycles(graph) == [['p.c', 'p.d', 'p.e']]
    modules = {'p': Path('p/__init__.py'), 'p.a': Path('p/a.py'), 'p.b': Path('p/b.py')}
    source = 'def f():\n    from .b import g\n    return g\n'
    path = tmp_path / 'a.py'
    path.write_text(source)
    assert _imports('p.a', path, modules) == {'p.b'}


def test_dependencies_point_down_the_layers():
    wrong = []
    for name, targets in _graph().items():
        mine = name.split('.')[0]
        for target in targets:
            theirs = target.split('.')[0]
            if theirs != mine and (LAYER[theirs] >= LAYER[mine] or (mine, theirs) in NEVER):
                wrong.append(f'{name} imports {target}')
    assert sorted(wrong) == []


def _python_files():
    for top in (SRC, ROOT / 'test'):
        yield from (p for p in top.rglob('*.py') if 'build' not in p.relative_to(ROOT).parts)


def test_no_file_over_500_lines():
    lengths = {str(p.relative_to(ROOT)): len(p.read_text().splitlines()) for p in _python_files()}
    too_long = {name for name, n in lengths.items() if n > MAX_LINES}
    assert sorted(f'{n}: {lengths[n]} lines' for n in too_long - TOO_LONG_KNOWN) == []
    assert sorted(TOO_LONG_KNOWN - too_long) == [], 'split: remove from TOO_LONG_KNOWN'


def _docstring_lines(path: Path) -> int:
    """Lines of a module's docstring as written (0 without one)."""
    text = ast.get_docstring(ast.parse(path.read_text(), str(path)), clean=False)
    return len(text.split('\n')) if text is not None else 0


def test_no_module_docstring_over_20_lines():
    """What and why in a page a reader can hold; the design notes live in docs/."""
    lengths = {str(p.relative_to(ROOT)): _docstring_lines(p) for p in _python_files()
               if p.is_relative_to(SRC) and 'test' not in p.relative_to(SRC).parts}
    too_long = {name for name, n in lengths.items() if n > MAX_DOCSTRING_LINES}
    assert sorted(f'{n}: {lengths[n]} lines' for n in too_long) == []


def test_the_docstring_count_sees_a_long_one(tmp_path):
    path = tmp_path / 'm.py'
    path.write_text('"""What.\n' + 'why\n' * 19 + '"""\nX = 1\n')
    assert _docstring_lines(path) == 21
    path.write_text('X = 1\n"""Not a docstring."""\n')
    assert _docstring_lines(path) == 0


def test_every_package_is_in_the_layer_order():
    assert sorted(p.parent.name for p in SRC.glob('*/package.xml')) == sorted(LAYER)
