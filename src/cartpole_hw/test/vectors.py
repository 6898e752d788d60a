"""Reader of the shared protocol vectors (also read by the firmware's C++ test)."""
from __future__ import annotations

from pathlib import Path

VECTORS = Path(__file__).resolve().parents[3] / 'firmware' / 'test_vectors' / 'protocol_vectors.txt'


def unescape(text: str) -> bytes:
    out = bytearray()
    i = 0
    while i < len(text):
        c = text[i]
        if c == '\\' and i + 1 < len(text):
            n = text[i + 1]
            if n == 'x':
                out.append(int(text[i + 2:i + 4], 16))
                i += 4
                continue
            out += {'r': b'\r', 'n': b'\n', '\\': b'\\'}[n]
            i += 2
            continue
        out += c.encode('ascii')
        i += 1
    return bytes(out)


def load(kind: str) -> list[tuple[str, str]]:
    rows = []
    for raw in VECTORS.read_text().splitlines():
        if not raw or raw.startswith('#'):
            continue
        fields = raw.split('|')
        assert len(fields) == 3, f'bad vector line {raw!r}'
        if fields[0] == kind:
            rows.append((fields[1], fields[2]))
    return rows
