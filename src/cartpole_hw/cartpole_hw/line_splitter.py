"""The Joint protocol's byte stream cut into lines, with a bounded buffer.

A serial port delivers arbitrary chunks; :class:`LineSplitter` gives back
whole lines for :func:`cartpole_hw.protocol.decode_line` and turns a run of
bytes longer than a line into one ``oversized`` refusal instead of an
unbounded buffer (docs/rig.md, "The Joint protocol"). No ROS import.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Iterable

from .protocol import MAX_LINE, DecodeError

@dataclass
class LineSplitter:
    """Splits arbitrary byte chunks into lines, with a bounded buffer.

    :meth:`feed` returns complete lines (bytes, terminator and a trailing
    ``\\r`` stripped, empty lines skipped) and, for every run of more than
    :data:`MAX_LINE` bytes without a newline, one ``DecodeError('oversized')``:
    the bytes are dropped up to the next ``\\n``. The buffer never holds more
    than ``max_line + 1`` bytes.
    """

    max_line: int = MAX_LINE
    _buffer: bytearray = field(default_factory=bytearray)
    _discarding: bool = False

    def feed(self, chunk: bytes) -> list[bytes | DecodeError]:
        out: list[bytes | DecodeError] = []
        start = 0
        n = len(chunk)
        while start < n:
            nl = chunk.find(b'\n', start)
            end = n if nl < 0 else nl
            piece = chunk[start:end]
            if self._discarding:
                pass
            elif len(self._buffer) + len(piece) > self.max_line + 1:   # +1: a trailing \r
                out.append(DecodeError('oversized', bytes(self._buffer[:32]) + piece[:32]))
                self._buffer.clear()
                self._discarding = True
            else:
                self._buffer += piece
            if nl < 0:
                break
            # a terminator: emit the line (unless it was discarded)
            if not self._discarding:
                line = bytes(self._buffer)
                if line.endswith(b'\r'):
                    line = line[:-1]
                if len(line) > self.max_line:
                    out.append(DecodeError('oversized', line[:64]))
                elif line:
                    out.append(line)
            self._buffer.clear()
            self._discarding = False
            start = nl + 1
        return out

    @property
    def buffered(self) -> int:
        return len(self._buffer)

    def reset(self) -> None:
        self._buffer.clear()
        self._discarding = False



def iter_lines(chunks: Iterable[bytes]) -> Iterable[bytes | DecodeError]:
    """Convenience: split an iterable of chunks into lines with a :class:`LineSplitter`."""
    splitter = LineSplitter()
    for chunk in chunks:
        yield from splitter.feed(chunk)
