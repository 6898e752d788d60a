"""(docs/bench/faults, see measure.sh) Run the emulator in this process and log when the device last got a U and when its output went to zero.

usage: python emu_probe.py LINK SECONDS OUT.json
"""
import json, sys, time
from cartpole_hw.emulator import Emulator
link, seconds, out = sys.argv[1], float(sys.argv[2]), sys.argv[3]
emu = Emulator(link=link)
log = []  # (t, kind, value)
handle = emu.device.handle_line
def handle_line(line, now_us):
    if line[:2] in (b'U,', b'E,'):
        log.append((time.monotonic(), line[:1].decode(), line.split(b'*')[0].decode()))
    return handle(line, now_us)
emu.device.handle_line = handle_line
step = emu.sample_period
def sample_period():
    step()
    log.append((time.monotonic(), 'S', emu.device.output_setpoint() if emu.device.enabled else 'off'))
emu.sample_period = sample_period
emu.start()
print('port', emu.port, flush=True)
time.sleep(seconds)
emu.stop()
# last U with a non-zero setpoint, then the first period whose output is zero
last_u = max((t for t, k, v in log if k == 'U' and v != 'U,0'), default=None)
zero = next((t for t, k, v in log if k == 'S' and last_u and t > last_u and v in (0, 'off')), None)
lines_after = [(round(t - last_u, 4), k, v) for t, k, v in log if last_u and last_u - 0.01 <= t <= last_u + 0.12 and k != 'S']
changes = []
prev = None
for t, k, v in log:
    if k == 'S':
        zero = v in (0, 'off')
        if zero != prev:
            changes.append((t, 'output', 'zero' if zero else 'nonzero')); prev = zero
    else:
        changes.append((t, k, v))
json.dump({'timeline': changes, 'last_nonzero_U': last_u, 'first_zero_output_period': zero,
           'delay_ms': None if zero is None or last_u is None else (zero - last_u) * 1e3,
           'host_lines_around': lines_after}, open(out, 'w'), indent=1)
