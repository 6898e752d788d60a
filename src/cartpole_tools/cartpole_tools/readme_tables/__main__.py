"""``python -m cartpole_tools.readme_tables [--write | --check] [--readme PATH] [--src DIR]``.

The README's generated tables and every node's parameter file
(``src/<package>/config/<node>.yaml``, :mod:`.params_files`).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from cartpole_analysis.bags.writer import TOPICS
from . import params_files
from .introspect import describe_nodes
from .regions import problems, rewrite
from .render import MissingNote
from .tables import generate, load_plugins


def default_readme() -> Path:
    """README.md of the workspace this package's source is in (symlink install), else ./README.md."""
    here = Path(__file__).resolve()
    for parent in here.parents:
        if (parent / 'README.md').is_file() and (parent / 'src').is_dir():
            return parent / 'README.md'
    return Path('README.md')


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog='python -m cartpole_tools.readme_tables',
        description="Regenerate (--write) or check (--check) the README's parameter, plugin and "
                    'topic tables from the nodes, the plugin registry and the bag topic list, '
                    "and each node's default parameter file src/<package>/config/<node>.yaml.")
    mode = parser.add_mutually_exclusive_group(required=True)
    mode.add_argument('--write', action='store_true', help='rewrite the generated regions')
    mode.add_argument('--check', action='store_true',
                      help='exit 1 and say what disagrees if a region is not what the code says')
    parser.add_argument('--readme', type=Path, default=None, help='default: the workspace README.md')
    parser.add_argument('--src', type=Path, default=None,
                        help="the packages' parent directory for the parameter files "
                             "(default: the workspace's src/)")
    args = parser.parse_args(argv)
    readme = args.readme or default_readme()
    src = args.src or default_readme().parent / 'src'
    text = readme.read_text(encoding='utf-8')
    nodes = describe_nodes()
    files = params_files.expected(nodes.values(), src)
    try:
        generated = generate(nodes, load_plugins(), list(TOPICS))
    except MissingNote as exc:
        print(f'{readme}: cannot generate the tables: {exc.args[0]}', file=sys.stderr)
        return 1
    if args.write:
        for path in params_files.write(files):
            print(f'{path}: written')
        try:
            new = rewrite(text, generated)
        except ValueError as exc:  # broken markers: write nothing
            print(f'{readme}: {exc}', file=sys.stderr)
            return 1
        missing = problems(new, generated)
        if new != text:
            readme.write_text(new, encoding='utf-8')
            print(f'{readme}: regions rewritten')
        for p in missing:
            print(p, file=sys.stderr)
        return 1 if missing else 0
    try:
        found = problems(text, generated)
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
        print(f'{readme}: {len(found)} generated region(s) disagree with the code; run '
              'python -m cartpole_tools.readme_tables --write', file=sys.stderr)
        return 1
    if stale:
        return 1
    print(f'{readme}: every generated table matches the code, and every parameter file')
    return 0


if __name__ == '__main__':
    sys.exit(main())
