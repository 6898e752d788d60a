"""The repository stands alone: every document it cites is in it, and it carries its license.

- No file cites the product specification or the style guide the project was built from
  (they are not part of the repository, so a reader cannot open them): the words checked
  are built below so that this file does not match itself.
- A reference in the form ``docs/rig.md, "The Joint protocol"`` (code and comments cite
  the documentation so) names a file of the repository and the start of one of its headings.
- LICENSE (Apache-2.0) is at the root and, the same text, in each package, which installs
  it to its share/ directory and says Apache-2.0 in its package.xml.
"""
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SKIP_DIRS = {'.git', '.venv', 'build', 'install', 'log', 'runs', '__pycache__', '.hypothesis',
             '.pytest_cache'}
CITATION = re.compile(r'\b' + 'SP' + r'EC\b|\b' + 'STY' + r'LE\.md')
REFERENCE = re.compile(r'\b((?:docs/)?[\w./-]+\.md), "([^"]+)"')
_HEADING = re.compile(r'^#{1,6} +(.*?) *#*$')
PACKAGES = sorted(p.parent for p in [*(ROOT / 'src').glob('*/package.xml'),
                                     *(ROOT / 'docs' / 'examples').glob('*/package.xml')])


def text_files(root: Path = ROOT):
    """(relative path, text) of every text file of the repository outside build output."""
    for path in sorted(root.rglob('*')):
        rel = path.relative_to(root)
        if not path.is_file() or SKIP_DIRS & set(rel.parts):
            continue
        data = path.read_bytes()
        if b'\0' in data[:8192]:
            continue
        try:
            yield rel.as_posix(), data.decode('utf-8')
        except UnicodeDecodeError:
            continue


def citations(files) -> list[str]:
    return [f'{rel}:{n}: {line.strip()}' for rel, text in files
            for n, line in enumerate(text.splitlines(), 1) if CITATION.search(line)]


def headings(path: Path) -> list[str]:
    fence, out = False, []
    for line in path.read_text(encoding='utf-8').splitlines():
        if line.lstrip().startswith('```'):
            fence = not fence
        elif not fence and (m := _HEADING.match(line)):
            out.append(m.group(1).replace('`', ''))
    return out


def broken_references(files, root: Path = ROOT) -> list[str]:
    out = []
    for rel, text in files:
        for n, line in enumerate(text.splitlines(), 1):
            for m in REFERENCE.finditer(line):
                target, section = root / m.group(1), m.group(2).replace('`', '')
                if not target.is_file():
                    out.append(f'{rel}:{n}: {m.group(1)}: no such file')
                elif not any(h.startswith(section) for h in headings(target)):
                    out.append(f'{rel}:{n}: {m.group(1)} has no heading "{section}..."')
    return out


def test_no_file_cites_a_document_outside_the_repository():
    assert citations(text_files()) == []


def test_every_cited_section_exists():
    assert broken_references(text_files()) == []


def test_the_checks_notice_a_citation_and_a_broken_reference(tmp_path):
    (tmp_path / 'docs').mkdir()
    (tmp_path / 'docs' / 'rig.md').write_text('# Rig\n\n## The `Joint` protocol\n```\n# x\n```\n')
    (tmp_path / 'a.py').write_text(
        '"""Codec (docs/rig.md, "The Joint protocol").\n'
        'Rules (docs/rig' '.md, "The watchdog"); see docs/gone' '.md, "Anything".\n'
        f'As {"SP" + "EC"} section 4 says; {"STY" + "LE"}.md too."""\n'
        'SPEC_POLES = ParameterSpec = SPECS = 1\n')
    files = list(text_files(tmp_path))
    assert citations(files) == [f'a.py:3: As {"SP" + "EC"} section 4 says; '
                                f'{"STY" + "LE"}.md too."""']
    assert broken_references(files, tmp_path) == [
        'a.py:2: docs/rig.md has no heading "The watchdog..."',
        'a.py:2: docs/gone.md: no such file']


def test_license_at_the_root_and_in_each_package():
    text = (ROOT / 'LICENSE').read_text()
    assert text.lstrip().startswith('Apache License') and 'Version 2.0, January 2004' in text
    assert 'END OF TERMS AND CONDITIONS' in text
    for package in PACKAGES:
        assert (package / 'LICENSE').read_text() == text, package.name
        assert ET.parse(package / 'package.xml').getroot().findtext('license') == 'Apache-2.0'
        assert "['package.xml', 'LICENSE']" in (package / 'setup.py').read_text(), package.name


@pytest.mark.parametrize('package', [p.name for p in PACKAGES if p.parent.name == 'src'])
def test_license_is_installed(package):
    from ament_index_python.packages import get_package_share_directory
    installed = Path(get_package_share_directory(package)) / 'LICENSE'
    assert installed.read_text() == (ROOT / 'LICENSE').read_text()
