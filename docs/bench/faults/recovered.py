"""(docs/bench/faults, see measure.sh) How much of a killed bag the mcap stream reader recovers: last message log time vs the last sample seen live."""
import sys, glob
from mcap.stream_reader import StreamReader
from mcap.records import Message
path = glob.glob(sys.argv[1] + '/*/bag/*.mcap')[0]
last_seen = float(sys.argv[2])
first = last = None; n = 0
try:
    with open(path, 'rb') as f:
        for rec in StreamReader(f, skip_magic=False).records:
            if isinstance(rec, Message):
                n += 1
                t = rec.log_time * 1e-9
                first = t if first is None else min(first, t); last = t if last is None else max(last, t)
except Exception as e:
    print('stream ends:', type(e).__name__, e)
print(f'{path}: {n} messages, {first} .. {last}; last seen live {last_seen}; lost {last_seen - last:.2f} s of {last_seen - first:.2f} s')
