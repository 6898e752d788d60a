"""The device's side of a kill: the last ``U`` before it, the output going to zero after it.

Usage: ``python hw_after_kill.py EMU.json KILLNODE.out`` (the outputs of
test/emulator_probe.py and killnode.py; both use the machine's monotonic clock).
"""
import json
import sys


def main() -> None:
    timeline = json.load(open(sys.argv[1]))['timeline']
    text = open(sys.argv[2]).read()
    kill = json.loads(text[text.index('{\n'):])['kill_monotonic']
    before = [e for e in timeline if e[0] <= kill and e[1] == 'U']
    last_u = before[-1] if before else None
    zero = next((e for e in timeline if e[0] > kill and e[1:] == ['output', 'zero']), None)
    if last_u:
        print(f'   last U before the kill: {last_u[2]}, {(kill - last_u[0]) * 1e3:.1f} ms before')
    if zero and last_u:
        print(f'   device output zero {(zero[0] - last_u[0]) * 1e3:.1f} ms after the last U '
              f'({(zero[0] - kill) * 1e3:.1f} ms after the kill)')
    else:
        print('   output zero: not seen after the kill (it was zero already)')
    after = [(round((e[0] - kill) * 1e3, 1), e[1], e[2]) for e in timeline
             if kill < e[0] <= kill + 0.3]
    print('   after the kill [ms, kind, value]:', after[:10])


if __name__ == '__main__':
    main()
