"""``python -m cartpole_bringup.readme_tables [--write | --check] [--readme PATH]``."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .regions import problems, rewrite
from .render import MissingNote
from .tables import generate_all


def default_readme() -> Path:
    """README.md of the workspace this package's source is in (symlink install), else ./README.md."""
    here = Path(__file__).resolve()
    for parent in here.parents:
        if (parent / 'README.md').is_file() and (parent / 'src').is_dir():
            return parent / 'README.md'
    return Path('README.md')


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog='python -m cartpole_bringup.readme_tables',
        description="Regenerate (--write) or check (--check) the README's parameter, plugin and "
                    'topic tables from the nodes, the plugin registry and the bag topic list.')
    mode = parser.add_mutually_exclusive_group(required=True)
    mode.add_argument('--write', action='store_true', help='rewrite the generated regions')
    mode.add_argument('--check', action='store_true',
                      help='exit 1 and say what disagrees if a region is not what the code says')
    parser.add_argument('--readme', type=Path, default=None, help='default: the workspace README.md')
    args = parser.parse_args(argv)
    readme = args.readme or default_readme()
    text = readme.read_text(encoding='utf-8')
    try:
        generated = generate_all()
    except MissingNote as exc:
        print(f'{readme}: cannot generate the tables: {exc.args[0]}', file=sys.stderr)
        return 1
    if args.write:
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
    for p in found:
        print(p, file=sys.stderr)
    if found:
        print(f'{readme}: {len(found)} generated region(s) disagree with the code; run '
              'python -m cartpole_bringup.readme_tables --write', file=sys.stderr)
        return 1
    print(f'{readme}: every generated table matches the code')
    return 0


if __name__ == '__main__':
    sys.exit(main())
