"""The generated regions of the documentation (README.md, docs/reference/*.md): find, compare,
rewrite.

A region is ``<!-- generated: KEY -->`` on a line of its own, the generated
text, and ``<!-- end generated -->``. Everything outside the regions is the
README's own prose and is never touched.
"""
from __future__ import annotations

import difflib
import re
from dataclasses import dataclass

BEGIN = '<!-- generated: {key} -->'
END = '<!-- end generated -->'
_REGION = re.compile(r'^<!-- generated: (?P<key>[^>]*?) -->\n(?P<body>.*?)^<!-- end generated -->$',
                     re.S | re.M)


@dataclass(frozen=True)
class Region:
    key: str
    body: str
    start: int
    end: int


def find_regions(text: str) -> list[Region]:
    """Every generated region of ``text`` in order; a key may appear once only."""
    regions = [Region(m['key'].strip(), m['body'], m.start('body'), m.end('body'))
               for m in _REGION.finditer(text)]
    seen = set()
    for r in regions:
        if r.key in seen:
            raise ValueError(f'README region {r.key!r} appears twice')
        seen.add(r.key)
    opened = len(re.findall(r'^<!-- generated: ', text, re.M))
    if opened != len(regions):
        raise ValueError(f'README has {opened} "<!-- generated: " markers but only {len(regions)} '
                         f'complete regions (each needs "{END}" on its own line)')
    return regions


def problems(text: str, generated: dict[str, str]) -> list[str]:
    """What disagrees between one document ``text`` holding every region and the ``generated``
    tables, one entry each: a missing region, then :func:`disagreements`."""
    found = {r.key for r in find_regions(text)}
    out = [f'README has no region "{BEGIN.format(key=key)}" for {key} '
           '(add the markers where the table belongs, then --write)'
           for key in generated if key not in found]
    return out + disagreements(text, generated)


def disagreements(text: str, generated: dict[str, str]) -> list[str]:
    """The regions of ``text`` that name nothing the code has, or whose body is not the
    generated table, one entry each."""
    out = []
    for region in find_regions(text):
        key = region.key
        if key not in generated:
            out.append(f'README region {key!r} names nothing the code has '
                       f'(known: {", ".join(sorted(generated))})')
            continue
        want = generated[key].rstrip('\n') + '\n'
        if region.body != want:
            diff = difflib.unified_diff(region.body.splitlines(), want.splitlines(),
                                        f'README.md [{key}]', f'code [{key}]', lineterm='', n=0)
            out.append(f'README region {key!r} disagrees with the code:\n' + '\n'.join(diff))
    return out


def rewrite(text: str, generated: dict[str, str]) -> str:
    """``text`` with every known region's body replaced by its generated table."""
    pieces, last = [], 0
    for region in find_regions(text):
        if region.key in generated:
            pieces.append(text[last:region.start])
            pieces.append(generated[region.key].rstrip('\n') + '\n')
            last = region.end
    pieces.append(text[last:])
    return ''.join(pieces)


def problems_across(texts: dict, generated: dict[str, str]) -> list[str]:
    """:func:`problems` over several documents (path -> text): every generated key stands in
    exactly one of them, and every region of each agrees with the code (:func:`disagreements`)."""
    where: dict[str, list[str]] = {}
    out = []
    for path, text in texts.items():
        regions = find_regions(text)
        for region in regions:
            where.setdefault(region.key, []).append(str(path))
        out += [f'{path}: {p}' for p in disagreements(text, generated)]
    for key in generated:
        if key not in where:
            out.append(f'no document has a region "{BEGIN.format(key=key)}" for {key} '
                       '(add the markers where the table belongs, then --write)')
        elif len(where[key]) > 1:
            out.append(f'region {key!r} appears in {len(where[key])} documents: {", ".join(where[key])}')
    return out
