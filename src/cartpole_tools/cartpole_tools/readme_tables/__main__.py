"""``python -m cartpole_tools.readme_tables [--write | --check] [--doc PATH ...] [--src DIR]``.

The generated reference tables of the documentation (regions of README.md and
docs/reference/*.md) and every node's parameter file (``src/<package>/config/<node>.yaml``,
:mod:`.params_files`).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from cartpole_analysis.bags.writer import TOPICS
from . import params_files
from .cli_reference import cli_reference
from .introspect import describe_nodes
from .regions import problems_across, rewrite
from .render import MissingNote
from .tables import generate, load_plugins


def workspace_root() -> Path:
    """The workspace this package's source is in (symlink install), else the working directory."""
    here = Path(__file__).resolve()
    for parent in here.parents:
        if (parent / 'README.md').is_file() and (parent / 'src').is_dir():
            return parent
    return Path('.')


def default_documents(root: Path) -> list[Path]:
    """README.md and every page of docs/reference/: where the generated regions may stand."""
    return [root / 'README.md', *sorted((root / 'docs' / 'reference').glob('*.md'))]


def generated_tables() -> dict[str, str]:
    """Region key -> Markdown, for the installed nodes, plugins, bag topics and the CLI."""
    from cartpole_bringup.cli import build_parser
    tables = generate(describe_nodes(), load_plugins(), list(TOPICS))
    tables['cli'] = cli_reference(build_parser())
    return tables


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog='python -m cartpole_tools.readme_tables',
        description='Regenerate (--write) or check (--check) the reference tables (parameters, '
                    'plugins, topics, services, the cartpole command) from the code, in README.md '
                    "and docs/reference/*.md, and each node's default parameter file "
                    'src/<package>/config/<node>.yaml.')
    mode = parser.add_mutually_exclusive_group(required=True)
    mode.add_argument('--write', action='store_true', help='rewrite the generated regions')
    mode.add_argument('--check', action='store_true',
                      help='exit 1 and say what disagrees if a region is not what the code says')
    parser.add_argument('--doc', type=Path, action='append', default=None, metavar='PATH',
                        help='a Markdown file holding regions (repeatable; default: README.md '
                             'and docs/reference/*.md of the workspace)')
    parser.add_argument('--src', type=Path, default=None,
                        help="the packages' parent directory for the parameter files "
                             "(default: the workspace's src/)")
    args = parser.parse_args(argv)
    root = workspace_root()
    documents = args.doc or default_documents(root)
    src = args.src or root / 'src'
    texts = {path: path.read_text(encoding='utf-8') for path in documents}
    nodes = describe_nodes()
    files = params_files.expected(nodes.values(), src)
    try:
        generated = generated_tables()
    except MissingNote as exc:
        print(f'cannot generate the tables: {exc.args[0]}', file=sys.stderr)
        return 1
    if args.write:
        for path in params_files.write(files):
            print(f'{path}: written')
        try:
            new = {path: rewrite(text, generated) for path, text in texts.items()}
        except ValueError as exc:  # broken markers: write nothing
            print(exc, file=sys.stderr)
            return 1
        for path, text in new.items():
            if text != texts[path]:
                path.write_text(text, encoding='utf-8')
                print(f'{path}: regions rewritten')
        missing = problems_across(new, generated)
        for p in missing:
            print(p, file=sys.stderr)
        return 1 if missing else 0
    try:
        found = problems_across(texts, generated)
    except ValueError as exc:  # broken markers
        found = [str(exc)]
    stale = params_files.stale(files)
    for p in stale:
        print(p, file=sys.stderr)
    if stale:
        print(f'{len(stale)} parameter file(s) disagree with the code; run '
              'python -m cartpole_tools.readme_tables --write', file=sys.stderr)
    for p in found:
        print(p, file=sys.stderr)
    if found:
        print(f'{len(found)} generated region(s) disagree with the code; run '
              'python -m cartpole_tools.readme_tables --write', file=sys.stderr)
        return 1
    if stale:
        return 1
    print(f'{len(documents)} documents: every generated table matches the code, and every '
          'parameter file')
    return 0


if __name__ == '__main__':
    sys.exit(main())
