"""An MCAP file's framing: where its whole records end and whether it has its footer.

Read by the length fields of the records alone, so a file cut short by a killed
recorder is measured without a parser that would refuse it: :mod:`.check` asks
whether a bag is whole, :mod:`.repair` copies the whole records of one that is not.
"""
from __future__ import annotations

import struct
from pathlib import Path

MAGIC = b'\x89MCAP0\r\n'
_OP_FOOTER = 0x02
_RECORD_HEADER = struct.Struct('<BQ')


class RepairError(RuntimeError):
    """The bag cannot be repaired (no MCAP file, not an MCAP file, ...); the message says why."""


def complete_prefix(path: Path) -> tuple[int, bool]:
    """(length of the part made of whole records, whether it ends with the footer and magic)."""
    size = path.stat().st_size
    with path.open('rb') as f:
        if f.read(len(MAGIC)) != MAGIC:
            raise RepairError(f'{path} is not an MCAP file (it does not start with the MCAP '
                              'magic); nothing in it can be recovered'
                              if size else f'{path} is empty; nothing in it can be recovered')
        pos = len(MAGIC)
        while pos + _RECORD_HEADER.size <= size:
            f.seek(pos)
            opcode, length = _RECORD_HEADER.unpack(f.read(_RECORD_HEADER.size))
            end = pos + _RECORD_HEADER.size + length
            if end > size:
                break
            pos = end
            if opcode == _OP_FOOTER:
                f.seek(pos)
                return pos, f.read(len(MAGIC)) == MAGIC
    return pos, False
