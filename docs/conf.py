"""Sphinx configuration of the documentation site (`make docs`: docs/ -> build/docs/html).

MyST Markdown pages; the API reference comes from the packages' docstrings (autodoc, which
imports them: run from a shell with `source env.sh`). Warnings are errors (`make docs` passes -W).
"""
from __future__ import annotations

project = 'cartpole'
author = 'cartpole maintainers'
copyright = '2026, cartpole maintainers'

extensions = [
    'myst_parser',
    'sphinx.ext.autodoc',
    'sphinx.ext.napoleon',
    'sphinx.ext.mathjax',
]
source_suffix = {'.md': 'markdown'}
root_doc = 'index'
exclude_patterns = ['bench/**', 'examples/**', '_build', 'Thumbs.db', '.DS_Store']
myst_enable_extensions = ['colon_fence', 'dollarmath', 'deflist']
myst_heading_anchors = 4
# Pages link to the sources (../src/...) for the reader on GitHub; on the site those links are
# plain links to files outside the site, which MyST may not resolve: not a warning.
suppress_warnings = ['myst.xref_missing', 'myst.header', 'ref.python']

autodoc_default_options = {'members': True, 'undoc-members': False, 'show-inheritance': False}
autodoc_member_order = 'bysource'
autodoc_typehints = 'description'
napoleon_numpy_docstring = True
napoleon_google_docstring = False

html_theme = 'furo'
html_title = 'cartpole: swing-up and stabilisation on ROS 2 Jazzy'


import re  # noqa: E402

_BARS = re.compile(r'(?<!\\)\|')


def _escape_bars(app, what, name, obj, options, lines):
    """The docstrings write |x| for an absolute value, the thesis's notation, not an RST
    substitution: escape the bars, except on the rows of a grid table."""
    for i, line in enumerate(lines):
        row = line.strip()
        if row.startswith('+') or (row.startswith('|') and row.endswith('|') and row.count('|') > 2):
            continue
        if '|' in line:
            lines[i] = _BARS.sub(r'\\|', line)


def setup(app):
    app.connect('autodoc-process-docstring', _escape_bars)


# --- The API reference: one page a package, every module of it, from the docstrings. ---
# Written at configuration time into reference/api/ (not committed), so a module that is added,
# split or renamed is in the reference without an edit here.
import pathlib  # noqa: E402

_DOCS = pathlib.Path(__file__).resolve().parent
_SRC = _DOCS.parent / 'src'
API_PACKAGES = {
    'cartpole_core': 'the plant model and the node plumbing every layer shares',
    'cartpole_sim': 'the simulated rig',
    'cartpole_estimation': 'the Extended Kalman Filter',
    'cartpole_control': 'the controller manager, the catch trigger and the controller plugins',
    'cartpole_hw': 'the Joint protocol and the serial bridge',
}


def _modules(package: str) -> list[str]:
    root = _SRC / package
    names = []
    for path in sorted((root / package).rglob('*.py')):
        parts = path.relative_to(root).with_suffix('').parts
        if parts[-1] == '__init__':
            parts = parts[:-1]
        if any(p.startswith('_') for p in parts):
            continue
        names.append('.'.join(parts))
    return names


def _write_api_pages() -> None:
    out = _DOCS / 'reference' / 'api'
    out.mkdir(parents=True, exist_ok=True)
    index = ['# API reference', '',
             'The ROS-free cores and their node adapters, from the docstrings. Every law names',
             'the thesis equation it implements.', '', '```{toctree}', ':maxdepth: 1', '']
    for package, what in API_PACKAGES.items():
        index.append(package)
        lines = [f'# {package}', '', f'{what.capitalize()}.', '']
        for module in _modules(package):
            lines += [f'## `{module}`', '', '```{eval-rst}', f'.. automodule:: {module}', '```', '']
        text = '\n'.join(lines)
        page = out / f'{package}.md'
        if not page.exists() or page.read_text() != text:
            page.write_text(text)
    index += ['```', '']
    text = '\n'.join(index)
    if not (out / 'index.md').exists() or (out / 'index.md').read_text() != text:
        (out / 'index.md').write_text(text)


_write_api_pages()
