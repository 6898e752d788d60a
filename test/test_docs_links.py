"""The README stays the front door, and no link of it or of docs/ leads nowhere.

The README says what this is, the two commands and the first five tasks, with links: at most
250 lines, 25 KB, no line over 160 characters. The manual is docs/ (built as a site). Every relative link of README.md and docs/*.md must
name a file that exists and, with a ``#fragment``, a heading of that file (GitHub's anchors).
"""
import re
from collections import Counter
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / 'README.md'
PAGES = [README] + sorted(p for p in (ROOT / 'docs').rglob('*.md')
                          if 'api' not in p.relative_to(ROOT / 'docs').parts)
"""Every page a reader reaches (the generated API pages excepted)."""
README_MAX_LINES = 250
README_MAX_BYTES = 25_000
README_MAX_LINE = 160

_LINK = re.compile(r'(?<!\\)\[([^\]]*)\]\(([^)\s]+)\)')
_HEADING = re.compile(r'^(#{1,6}) +(.*?) *#*$')


def _prose(text):
    """The lines of a Markdown text outside code fences."""
    fence = False
    for line in text.splitlines():
        if line.lstrip().startswith('```'):
            fence = not fence
            continue
        if not fence:
            yield line


def _slug(heading):
    """GitHub's anchor of a heading: lower case, punctuation dropped, spaces to hyphens."""
    text = heading.replace('`', '').replace('*', '')                     # code, emphasis marks
    text = re.sub(r'\[([^\]]*)\]\([^)]*\)', r'\1', text)                  # link text only
    text = re.sub(r'[^\w\- ]', '', text.strip().lower())
    return text.replace(' ', '-')


def anchors(path):
    """Every anchor a Markdown file's headings define (duplicates get -1, -2, ... as on GitHub)."""
    seen = Counter()
    found = set()
    for line in _prose(path.read_text(encoding='utf-8')):
        match = _HEADING.match(line)
        if not match:
            continue
        slug = _slug(match.group(2))
        found.add(slug if not seen[slug] else f'{slug}-{seen[slug]}')
        seen[slug] += 1
    return found


def links(path):
    """The relative links of a Markdown file: (line number, target)."""
    text = path.read_text(encoding='utf-8')
    fence = False
    for number, line in enumerate(text.splitlines(), 1):
        if line.lstrip().startswith('```'):
            fence = not fence
            continue
        if fence:
            continue
        line = re.sub(r'`[^`]*`', '', line)   # link syntax inside inline code is not a link
        for match in _LINK.finditer(line):
            target = match.group(2)
            if not re.match(r'^[a-z][a-z0-9+.-]*:', target):   # http:, https:, mailto:
                yield number, target


def broken_links(path):
    """What is wrong with each relative link of a Markdown file, as readable lines."""
    problems = []
    for number, target in links(path):
        file_part, _, fragment = target.partition('#')
        destination = (path.parent / file_part).resolve() if file_part else path
        where = f'{path.relative_to(ROOT)}:{number}: {target}'
        if not destination.exists():
            problems.append(f'{where}: no such file')
        elif fragment and destination.suffix == '.md' and fragment not in anchors(destination):
            problems.append(f'{where}: no heading with this anchor in {destination.name}')
    return problems


def test_readme_fits_on_a_few_screens():
    text = README.read_text(encoding='utf-8')
    lines = text.count('\n')
    assert lines <= README_MAX_LINES, (
        f'README.md has {lines} lines (at most {README_MAX_LINES}): move how-to, reference and '
        'measurements to docs/ and link them')
    assert len(text.encode('utf-8')) <= README_MAX_BYTES
    long = [n for n, line in enumerate(text.splitlines(), 1) if len(line) > README_MAX_LINE]
    assert long == [], f'README.md lines over {README_MAX_LINE} characters: {long}'


def test_readme_reaches_the_five_tasks_and_cites_the_thesis():
    text = README.read_text(encoding='utf-8')
    for task in ('tutorials/first-run.md', 'tutorials/switch-controllers.md',
                 'tutorials/record-and-analyse.md', 'tutorials/write-a-plugin.md',
                 'tutorials/connect-your-rig.md'):
        assert f'(docs/{task})' in text, task
    for words in ('Swing Up and Stabilisation of an Inverted Pendulum on a Cart using Nonlinear',
                  'CA10-1030', 'Control and Automation', 'Department of Electronic Systems',
                  'Aalborg'):
        assert words in ' '.join(text.split()), words


@pytest.mark.parametrize('page', PAGES, ids=lambda page: str(page.relative_to(ROOT)))
def test_every_relative_link_leads_somewhere(page):
    assert broken_links(page) == []


def test_the_link_check_notices_a_broken_file_and_anchor(tmp_path):
    (tmp_path / 'docs').mkdir()
    (tmp_path / 'docs' / 'page.md').write_text('# A page\n\n## The `sim` node, in full\n')
    page = tmp_path / 'README.md'
    page.write_text('[ok](docs/page.md#the-sim-node-in-full) [top](#title)\n# Title\n'
                    '[gone](docs/missing.md) [bad](docs/page.md#no-such-heading)\n'
                    '```\n[in code](docs/ignored.md)\n```\n[web](https://example.org/x)\n')
    global ROOT
    saved, ROOT = ROOT, tmp_path
    try:
        problems = broken_links(page)
    finally:
        ROOT = saved
    assert problems == ['README.md:3: docs/missing.md: no such file',
                        'README.md:3: docs/page.md#no-such-heading: no heading with this anchor '
                        'in page.md']
