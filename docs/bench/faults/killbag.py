"""The bag of a run with a killed node: the fault, zero-force delay from stamps, gaps.

Usage: ``python killbag.py OUTDIR`` (the run directory parent given to killnode.py).
Zero-force delay: from the last non-zero ``/cartpole/force_command`` to the first
``/cartpole/true_state`` sample whose actuator force (``effort[0]``) is below 1 mN.
"""
import json
import sys
from pathlib import Path

import numpy as np
from rosbags.highlevel import AnyReader

from cartpole_analysis.bags.cdr_parse import parse_joint_state


def main() -> None:
    (bag,) = Path(sys.argv[1]).glob('*/bag')
    truth, forces = set(), []
    with AnyReader([bag]) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
        for c, _, raw in reader.messages():
            if c.topic in ('/cartpole/true_state', '/cartpole/force_command'):
                stamp, _, _, _, effort = parse_joint_state(raw)
                (truth.add if c.topic == '/cartpole/true_state' else forces.append)(
                    (stamp, float(effort[0])))
    truth, forces = sorted(truth), sorted(forces)
    stamps = np.array([s for s, _ in truth])
    gaps = np.diff(stamps) * 1e-9
    nonzero = [s for s, f in forces if f != 0.0]
    last = nonzero[-1] if nonzero else None
    zero = [s for s, f in truth if last is not None and s > last and abs(f) < 1e-3]
    summary = json.loads((bag.parent / 'summary.json').read_text())
    print(json.dumps({
        'fault': summary.get('fault'), 'counts': counts,
        'last_nonzero_command_s': None if last is None else last * 1e-9,
        'first_zero_force_sample_s': zero[0] * 1e-9 if zero else None,
        'zero_force_delay_ms': (zero[0] - last) * 1e-6 if zero else None,
        'truth_span_s': [stamps[0] * 1e-9, stamps[-1] * 1e-9],
        'max_sample_gap_ms': gaps.max() * 1e3, 'gaps_over_6ms': int((gaps > 0.006).sum())}))


if __name__ == '__main__':
    main()
