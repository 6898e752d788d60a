"""(docs/bench/faults, see measure.sh) From a killed run's bag: zero-force delay (stamps) and gaps in the samples."""
import sys, glob, json
import numpy as np
from pathlib import Path
from rosbags.highlevel import AnyReader
from cartpole_bringup.cdr_parse import parse_joint_state
bag = Path(glob.glob(sys.argv[1] + '/*/bag')[0])
truth, forces = [], []
with AnyReader([bag]) as r:
    counts = {c.topic: c.msgcount for c in r.connections}
    for c, t, raw in r.messages():
        if c.topic == '/cartpole/true_state':
            s, n, p, v, e = parse_joint_state(raw); truth.append((s, e[0]))
        elif c.topic == '/cartpole/force_command':
            s, n, p, v, e = parse_joint_state(raw); forces.append((s, e[0]))
truth = sorted(set(truth)); forces = sorted(forces)
ts = np.array([s for s, _ in truth]); gaps = np.diff(ts) * 1e-9
nonzero = [s for s, f in forces if f != 0.0]
last_cmd = nonzero[-1] if nonzero else None
zero_after = [s for s, f in truth if last_cmd is not None and s > last_cmd and abs(f) < 1e-3]
summary = json.loads((bag.parent / 'summary.json').read_text())
print(json.dumps({'fault': summary.get('fault'), 'counts': counts,
                  'last_nonzero_command_s': None if last_cmd is None else last_cmd * 1e-9,
                  'first_zero_force_sample_s': zero_after[0] * 1e-9 if zero_after else None,
                  'zero_force_delay_ms': (zero_after[0] - last_cmd) * 1e-6 if zero_after else None,
                  'truth_span_s': [ts[0] * 1e-9, ts[-1] * 1e-9], 'max_sample_gap_ms': gaps.max() * 1e3,
                  'gaps_over_6ms': int((gaps > 0.006).sum())}))
