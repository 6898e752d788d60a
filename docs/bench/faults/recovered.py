"""How much of a killed bag the mcap stream reader recovers (before `cartpole bag repair`).

Usage: ``python recovered.py OUTDIR LAST_SEEN_STAMP_S``: the last message's log
time against the last sample seen live before the kill.
"""
import sys
from pathlib import Path

from mcap.records import Message
from mcap.stream_reader import StreamReader


def main() -> None:
    (path,) = Path(sys.argv[1]).glob('*/bag/*.mcap')
    last_seen = float(sys.argv[2])
    first = last = None
    count = 0
    try:
        with path.open('rb') as f:
            for record in StreamReader(f).records:
                if isinstance(record, Message):
                    count += 1
                    t = record.log_time * 1e-9
                    first = t if first is None else min(first, t)
                    last = t if last is None else max(last, t)
    except Exception as error:  # the kill cut the file: the stream ends in a record
        print('stream ends:', type(error).__name__, error)
    print(f'{path}: {count} messages, {first} .. {last}; last seen live {last_seen}; '
          f'lost {last_seen - last:.2f} s of {last_seen - first:.2f} s')


if __name__ == '__main__':
    main()
