"""The emulated rig in its own process, logging what the device received and its output.

Usage: ``python test/emulator_probe.py LINK SECONDS OUT.json [DELAY [WATCHDOG]]``. Opens
the emulator on a pseudo-terminal linked at LINK (with the scenario's command delay
DELAY seconds, default 0, and the device watchdog WATCHDOG seconds, default the
firmware's 0.05) and prints ``port <pty>``; runs until SECONDS have
passed or SIGINT/SIGTERM arrives, then writes the timeline (monotonic time, the
``U``/``E`` lines received, the changes of the output between zero and non-zero)
and ``applied``, the device's record of its last 1000 tagged commands
(``[tag, t_us of the sample it answers, t_us it took effect]``, protocol version
2), to OUT.json. Used by test_graph_hw_emulator.py and docs/bench/faults
(hw_after_kill.py reads the timeline).
"""
import json
import signal
import sys
import threading
import time

from cartpole_emulator.emulator import Emulator
from cartpole_sim.plant import Scenario


def main() -> None:
    link, seconds, out = sys.argv[1], float(sys.argv[2]), sys.argv[3]
    delay = float(sys.argv[4]) if len(sys.argv) > 4 else 0.0
    emulator = Emulator(Scenario(delay=delay), link=link)
    if len(sys.argv) > 5:
        emulator.device.watchdog_us = round(float(sys.argv[5]) * 1e6)
    timeline = []
    handle, step = emulator.device.handle_line, emulator.sample_period
    zero_before = [None]

    def handle_line(line, now_us):
        if line[:2] in (b'U,', b'E,'):
            timeline.append((time.monotonic(), line[:1].decode(), line.split(b'*')[0].decode()))
        return handle(line, now_us)

    def sample_period():
        step()
        zero = not emulator.device.enabled or emulator.device.output_setpoint() == 0
        if zero != zero_before[0]:
            timeline.append((time.monotonic(), 'output', 'zero' if zero else 'nonzero'))
            zero_before[0] = zero

    done = threading.Event()
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda *_: done.set())
    emulator.device.handle_line = handle_line
    emulator.sample_period = sample_period
    emulator.start()
    print('port', emulator.port, flush=True)
    done.wait(seconds)
    emulator.stop()
    with open(out, 'w') as f:
        json.dump({'timeline': timeline, 'applied': list(emulator.applied)}, f)


if __name__ == '__main__':
    main()
