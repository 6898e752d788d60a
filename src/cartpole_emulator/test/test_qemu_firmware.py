"""The firmware compiled for the Cortex-M3, run in qemu-system-arm: its size and timing
against the Arduino Due's budget, fuzzed input, and its watchdog when the host dies.

The protocol itself is tested on both devices by the conformance suite
(test_emulator.py). Times here are the firmware's own (its ``micros()`` in the
``O`` lines of the plant channel), never the test's wall clock. Every test
skips, naming the Debian packages, where the ARM toolchain or QEMU is missing.
"""
from __future__ import annotations

import json
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import serial

from cartpole_hw import protocol as jp
from cartpole_hw.line_splitter import LineSplitter
from cartpole_emulator.qemu_board import firmware_dir
from cartpole_emulator.qemu_device import QemuDevice

REPORT = firmware_dir() / 'tools' / 'firmware_report.py'
DAC_ZERO = 1953


def run_report(image: Path, *options: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(REPORT), str(image), '--json', *options],
                          capture_output=True, text=True, timeout=300)


def test_the_firmware_fits_the_due_with_half_its_sram_to_spare(firmware_image):
    """``make -C firmware arm``'s check: flash and SRAM (static + the stack's high-water
    mark measured in the run) against the SAM3X8E, and the tick's work measured in QEMU."""
    result = run_report(firmware_image, '--samples', '300')
    assert result.returncode == 0, result.stdout + result.stderr
    f = json.loads(result.stdout)
    assert f['fits'] is True
    assert 0 < f['flash_bytes'] <= 512 * 1024
    assert f['sram_bytes'] == f['sram_static_bytes'] + f['stack_high_water_bytes']
    assert f['sram_bytes'] <= 48 * 1024
    # the run exercised the firmware: every sample, the refusals and the overlong lines
    assert f['samples'] >= 300 and f['refused'] > 0 and f['oversized'] > 0
    assert f['tx_dropped'] == 0
    # the stack was used (painted at reset, measured) and stayed inside its reservation
    assert 256 < f['stack_high_water_bytes'] < f['stack_reserved_bytes']
    # a sample's work is a small part of the Due's 420 000 cycles per 5 ms
    assert 500 < f['tick_instructions_max'] < 0.25 * f['due_cycles_per_tick']


def test_the_size_check_fails_when_the_firmware_would_not_fit(firmware_image):
    result = run_report(firmware_image, '--samples', '20', '--sram-budget', '2048')
    assert result.returncode == 1
    assert json.loads(result.stdout.splitlines()[-1])['fits'] is False
    assert 'would not fit the Arduino Due' in result.stderr


@pytest.fixture
def device(tmp_path, firmware_image):
    d = QemuDevice(link=str(tmp_path / 'emu'), image=str(firmware_image))
    d.start()
    try:
        yield d
    finally:
        d.stop()


def read_lines(port: serial.Serial, splitter: LineSplitter, until, timeout: float = 10.0):
    """Decoded device lines until ``until(messages)`` holds (or the timeout)."""
    messages = []
    deadline = time.monotonic() + timeout
    while not until(messages) and time.monotonic() < deadline:
        for line in splitter.feed(port.read(port.in_waiting or 1)):
            if not isinstance(line, jp.DecodeError):
                messages.append(jp.decode_line(line, 'device'))
    return messages


def noise(rng: random.Random, size: int) -> bytes:
    """Random bytes, overlong lines and valid lines with a byte changed, with no line in it
    the firmware could take as a command (each is checked with the codec)."""
    parts = []
    while sum(map(len, parts)) < size:
        kind = rng.random()
        if kind < 0.4:
            parts.append(bytes(rng.randrange(256) for _ in range(rng.randrange(1, 200))))
        elif kind < 0.6:
            parts.append(b'U,' + b'9' * rng.randrange(100, 3000) + b'\n')
        else:
            line = bytearray(jp.encode(rng.choice([jp.Setpoint(rng.randrange(-3000, 3000)),
                                                   jp.Enable(True), jp.Enable(False),
                                                   jp.ResetCounters(), jp.Ping()])))
            line[rng.randrange(len(line) - 1)] = rng.choice(b'0123456789,*EULRP\r\x00\xff')
            parts.append(bytes(line))
    segments = b''.join(parts).split(b'\n')
    safe = [b'#' if not isinstance(jp.decode_line(s + b'\n', 'host'), jp.DecodeError) else s
            for s in segments]
    return b'\n'.join(safe) + b'\n'


def test_fuzzed_input_never_crashes_hangs_or_moves_the_setpoint(device):
    """Line noise at full rate (as fast as the firmware's UART takes it): disabled, the
    output stays at zero current and the amplifier off; armed and fed with U,300 between
    the noise, the output is only ever 300 or zero (the watchdog, when the noise starved
    the U lines). The firmware keeps sampling throughout and answers afterwards."""
    rng = random.Random(22)
    disabled = [noise(rng, 8192) for _ in range(2)]    # made first: the device's thread
    armed = [noise(rng, 512) for _ in range(16)]        # shares this process
    port = serial.Serial(device.link, 115200, timeout=0.01, write_timeout=30)
    splitter = LineSplitter()
    port.write(jp.encode(jp.Stream(True)))
    first = read_lines(port, splitter, lambda m: any(isinstance(x, jp.Sample) for x in m))
    start_seq = next(x for x in first if isinstance(x, jp.Sample)).seq
    for chunk in disabled:                               # disabled: 2 x 8 KB of noise
        port.write(chunk)
        port.read(port.in_waiting)
    port.write(jp.encode(jp.Enable(True)) + jp.encode(jp.Setpoint(300)))
    for chunk in armed:                                  # armed: noise, then U,300
        port.write(chunk + jp.encode(jp.Setpoint(300)))
        port.read(port.in_waiting)
    port.write(jp.encode(jp.Enable(False)) + jp.encode(jp.Ping()))
    # the firmware takes the noise as fast as it can (a loaded machine runs QEMU slowly)
    messages = read_lines(port, splitter, lambda m: any(isinstance(x, jp.Version) for x in m),
                          timeout=60.0)
    assert any(isinstance(x, jp.Version) for x in messages), 'the firmware stopped answering'
    samples = [x for x in messages if isinstance(x, jp.Sample)]
    later = read_lines(port, splitter, lambda m: sum(isinstance(x, jp.Sample) for x in m) >= 3)
    later = [x for x in later if isinstance(x, jp.Sample)]
    assert later and later[-1].seq > start_seq + 10      # still sampling, never restarted
    both = samples + later
    assert all(b.seq > a.seq and b.t_us > a.t_us for a, b in zip(both, both[1:]))
    outputs = list(device.outputs)
    armed_at = next(i for i, (_, _, enabled, cause) in enumerate(outputs) if enabled)
    before, after = outputs[:armed_at], outputs[armed_at:]
    assert all(dac == DAC_ZERO and not enabled for _, dac, enabled, _ in before)
    assert {dac for _, dac, _, _ in after} <= {DAC_ZERO, DAC_ZERO + 300}
    assert sum(1 for _, dac, _, _ in after if dac == DAC_ZERO + 300) >= 10   # U,300 was taken
    # disarmed only by our closing E,0 (then our P)
    assert [cause for _, _, enabled, cause in after if not enabled] == ['E', 'P']
    last = device.statistics
    device.request_statistics()
    deadline = time.monotonic() + 5
    while device.statistics is last and time.monotonic() < deadline:
        time.sleep(0.05)
    stats = device.statistics
    assert stats is not last and stats.lines_in > 18, stats
    assert stats.refused > 50 and stats.oversized > 10, stats   # the noise was refused
    assert stats.stack_bytes < 4096, stats
    port.close()


def test_a_line_completed_across_a_deadline_comes_before_it(device):
    """Armed, tagged U lines back to back, as fast as the firmware's UART takes them, so a
    line is in flight at nearly every deadline. QEMU's clock is the host's, which runs on
    while the host runs something else: a line the loop took before a deadline may
    complete, by micros(), after it. Stamped so, the deadline's S line would report the
    command as written after the sample, and the watchdog would take the U as 2^32 us old
    (device fault 16 while U lines arrive every 5 ms). Every report must say the command in
    force was written before its sample. (Whether the watchdog trips here depends on how
    the host runs QEMU and this process, so it is not asserted.)"""
    port = serial.Serial(device.link, 115200, timeout=0.002, write_timeout=0)
    splitter = LineSplitter()
    port.write(jp.encode(jp.Stream(True)) + jp.encode(jp.Enable(True)))
    samples, pending = [], b''
    deadline = time.monotonic() + 30.0
    while len(samples) < 200 and time.monotonic() < deadline:
        if not pending:   # tagged with the last sample's seq; the pty takes what it can
            pending = b''.join(jp.encode(jp.Setpoint(0, samples[-1].seq if samples else 0))
                               for _ in range(20))
        pending = pending[port.write(pending) or 0:]
        for line in splitter.feed(port.read(port.in_waiting or 1)):
            message = jp.decode_line(line, 'device')
            if isinstance(message, jp.Sample):
                samples.append(message)
    port.close()
    reports = [s for s in samples if s.age_us is not None]
    assert len(samples) >= 200 and len(reports) >= 190, (len(samples), len(reports))
    after = [s for s in reports if s.age_us >= 2 ** 31]   # age_us = t_us - written, mod 2^32
    assert after == [], (len(after), after[:3])


HOST = r'''
import sys, serial
from cartpole_hw import protocol as jp
from cartpole_hw.line_splitter import LineSplitter
port = serial.Serial(sys.argv[1], 115200, timeout=0.01)
splitter = LineSplitter()
port.write(jp.encode(jp.Stream(True)) + jp.encode(jp.Enable(True)))
answered = 0
while True:
    for line in splitter.feed(port.read(port.in_waiting or 1)):
        message = jp.decode_line(line, 'device')
        if isinstance(message, jp.Sample):
            port.write(jp.encode(jp.Setpoint(300, message.seq)))
            answered += 1
            if answered == 100:
                print('armed', flush=True)
'''


def test_killing_the_host_while_armed_zeroes_the_output_within_50ms_of_device_time(device):
    """A host process arms the device and answers every sample with U,300, then is
    SIGKILLed: the firmware's watchdog writes zero current at the first 5 ms deadline
    more than 45 ms after the last U it handled (so within 50 ms), by its own clock, and
    nothing drives the cart after that."""
    host = subprocess.Popen([sys.executable, '-c', HOST, device.link], stdout=subprocess.PIPE,
                            text=True)
    try:
        assert host.stdout.readline().strip() == 'armed'
    finally:
        host.send_signal(signal.SIGKILL)
        host.wait()
        host.stdout.close()
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline:
        outputs = list(device.outputs)   # the zero output, and the T of its deadline
        if outputs[-1][1] == DAC_ZERO and outputs[-1][2] and device.deadlines[-1] >= outputs[-1][0]:
            break
        time.sleep(0.05)
    last_u = max(i for i, o in enumerate(outputs) if o[3] == 'U')
    assert outputs[last_u][1] == DAC_ZERO + 300
    zero = outputs[last_u + 1]
    assert zero[1:] == (DAC_ZERO, True, 'A'), outputs[last_u:]   # the watchdog, still enabled
    assert zero[0] in device.deadlines                # written at a deadline, with its time
    assert 45_000 < zero[0] - outputs[last_u][0] <= 50_000, (zero, outputs[last_u])
    assert outputs[last_u + 1:] == [zero]             # and zero ever since
