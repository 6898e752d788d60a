"""(docs/bench/faults, see measure.sh) Device side after a kill: the host lines and the output after the kill time."""
import json, sys
emu = json.load(open(sys.argv[1])); t = open(sys.argv[2]).read(); kill = json.loads(t[t.index('{\n'):])['kill_monotonic']
tl = emu['timeline']
before = [e for e in tl if e[0] <= kill and e[1] == 'U']
last_u = before[-1] if before else None
after = [(round((e[0] - kill) * 1e3, 1), e[1], e[2]) for e in tl if kill < e[0] <= kill + 0.3]
zero = next((e for e in tl if e[0] > kill and e[1] == 'output' and e[2] == 'zero'), None)
print('   last U before the kill:', last_u[2] if last_u else None, '%.1f ms before' % ((kill - last_u[0]) * 1e3) if last_u else '')
print('   device output zero %.1f ms after the last U (%.1f ms after the kill)' % ((zero[0] - last_u[0]) * 1e3, (zero[0] - kill) * 1e3) if zero and last_u else '   output zero: not seen (already zero?)')
print('   after the kill [ms, kind, value]:', after[:10])
