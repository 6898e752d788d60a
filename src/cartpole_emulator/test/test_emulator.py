"""The device emulator over a real pseudo-terminal, spoken to with pyserial.

The protocol tests are one conformance suite over both devices (the ``device``
parameter): ``python``, the firmware's Python mirror (:class:`Emulator`), and
``qemu``, the firmware itself compiled for the Cortex-M3 and run in
qemu-system-arm (:class:`~cartpole_emulator.qemu_device.QemuDevice`), with the same
assertions, so the two can never drift apart. (The qemu cases skip, naming the
Debian packages, where the ARM toolchain and QEMU are not installed.)

Rates and intervals are measured with the device's own seq/t_us (simulated
device time), never asserted against the wall clock beyond a generous count.
"""
import os
import time

import pytest
import serial

from cartpole_hw import protocol as jp
from cartpole_hw.line_splitter import LineSplitter
from cartpole_emulator.emulated_rig import Emulator, FaultConfig
from cartpole_emulator.emulator import main
from cartpole_sim.plant import Scenario


class Client:
    """A minimal host: pyserial + splitter + decoder."""

    def __init__(self, path):
        self.port = serial.Serial(path, 115200, timeout=0.01)
        self.splitter = LineSplitter()
        self.messages = []
        self.errors = []

    def send(self, *messages):
        self.port.write(b''.join(jp.encode(m) for m in messages))

    def pump(self, until, timeout=5.0, every=None):
        """Read until ``until(self)`` holds; ``every()`` is called each read."""
        deadline = time.monotonic() + timeout
        while not until(self):
            if time.monotonic() > deadline:
                return False
            for line in self.splitter.feed(self.port.read(self.port.in_waiting or 1)):
                m = line if isinstance(line, jp.DecodeError) else jp.decode_line(line, 'device')
                (self.errors if isinstance(m, jp.DecodeError) else self.messages).append(m)
            if every:
                every()
        return True

    @property
    def samples(self):
        return [m for m in self.messages if isinstance(m, jp.Sample)]


DEVICES = ['python', 'qemu']


@pytest.fixture(params=DEVICES)
def make_device(request):
    """``make_device(scenario=None, **emulator_options)``: the device under test, not started."""
    if request.param == 'qemu':
        from cartpole_emulator.qemu_device import QemuDevice
        image = request.getfixturevalue('firmware_image')
        return lambda scenario=None, **kw: QemuDevice(scenario, image=str(image), **kw)
    return lambda scenario=None, **kw: Emulator(scenario, **kw)


@pytest.fixture
def emulator(tmp_path, make_device):
    em = make_device(link=str(tmp_path / 'emu'))
    em.start()
    try:
        yield em
    finally:
        em.stop()


def test_streams_5ms_samples_200_per_second_of_device_time(emulator):
    # The rate is read from the device's own clock and sequence numbers, never the
    # test's wall clock (a loaded machine delays the pty, not the device's stamps).
    c = Client(emulator.link)
    c.send(jp.Ping(), jp.Stream(True))
    assert c.pump(lambda c: len(c.samples) >= 200)
    s = c.samples
    assert any(isinstance(m, jp.Version) and m.version == jp.PROTOCOL_VERSION
               for m in c.messages)
    assert [b.seq - a.seq for a, b in zip(s, s[1:])] == [1] * (len(s) - 1)      # none lost
    assert {b.t_us - a.t_us for a, b in zip(s, s[1:])} == {5000}                # Ts = 5 ms
    per_second = (len(s) - 1) / ((s[-1].t_us - s[0].t_us) * 1e-6)
    assert per_second == pytest.approx(200.0, rel=1e-12)   # 200 Hz of device time
    assert s[0].flags == jp.FLAG_LIMIT_LEFT             # at the left stop, disabled
    assert (s[0].cart_ticks, s[0].pend_ticks) == (0, 0)


def test_setpoint_reaches_the_amplifier_and_moves_the_cart_right(emulator):
    c = Client(emulator.link)
    c.send(jp.Stream(True), jp.Enable(True))
    c.pump(lambda c: len(c.samples) >= 2)
    # U,600 at every read (a test process stalled for 45 ms lets the watchdog of the QEMU
    # device, which runs on, zero the current until the next U: so "until", not "after N")
    assert c.pump(lambda c: c.samples[-1].cart_ticks > 100 and not c.samples[-1].watchdog_tripped,
                  every=lambda: c.send(jp.Setpoint(600)))
    moved = c.samples[-1]
    assert moved.enabled                                # 600 / 56.744 = 10.6 N > friction
    assert emulator.device.dac_value() == 1953 + 600
    # and left with a negative setpoint: the cart comes back
    assert c.pump(lambda c: c.samples[-1].cart_ticks < moved.cart_ticks,
                  every=lambda: c.send(jp.Setpoint(-600)))


def test_device_watchdog_trips_within_50ms_of_the_last_setpoint(emulator):
    c = Client(emulator.link)
    c.send(jp.Stream(True), jp.Enable(True), jp.Setpoint(300))
    assert c.pump(lambda c: any(s.watchdog_tripped for s in c.samples))
    first = next(s for s in c.samples if s.watchdog_tripped)
    # By device time: the U's arrival (as the device stamped it) to the first sample
    # showing the trip, from which the current is zero.
    assert 45_000 < first.t_us - emulator.device.last_u_us <= 50_000
    assert any(isinstance(m, jp.DeviceError) and m.code == 16 for m in c.messages)
    assert emulator.device.output_setpoint() == 0
    c.send(jp.Setpoint(10))
    n = len(c.samples)
    assert c.pump(lambda c: len(c.samples) > n + 2)
    assert not c.samples[-1].watchdog_tripped             # cleared by the next U


@pytest.mark.parametrize('before_period', [0.0, 0.0012, 0.0049])
def test_setpoint_between_periods_is_zeroed_within_50ms_of_its_arrival(before_period):
    """The emulator core in device time (no pty, no clock): a U that arrives
    ``before_period`` s before a period is stamped then, and the first period with
    zero current starts at most 50 ms after it."""
    em = Emulator(Scenario(x0=0.3))
    em.feed(jp.encode(jp.Enable(True)), em.t_us)
    for _ in range(3):
        em.sample_period()
    arrival = em.device_time_us(before_period)
    assert arrival == em.t_us - round(before_period * 1e6)
    em.feed(jp.encode(jp.Setpoint(600)), arrival)
    driving = 0.0
    while not em.device.watchdog_tripped:
        driving = em.plant.force
        em.sample_period()
    zero_from = (em.t_us - 5000) % jp.UINT32      # the period that tripped starts here
    em.sample_period()                            # the plant runs (lazily) through it
    assert driving == pytest.approx(600 / 56.744, rel=0.01)      # driven until then
    assert em.plant.force == pytest.approx(0.0, abs=1e-6)        # zero from then on
    assert 45_000 < zero_from - arrival <= 50_000


def test_reset_rezeroes_and_malformed_commands_are_answered(emulator):
    emulator.plant.state[0] = 0.2                        # cart in the middle somewhere
    c = Client(emulator.link)
    c.send(jp.Stream(True))
    c.pump(lambda c: len(c.samples) >= 2)
    assert c.samples[-1].cart_ticks == round(0.2 / (0.769 / 8737))
    c.port.write(b'U,5*00\nE,1*58\n' + jp.encode(jp.ResetCounters()))
    assert c.pump(lambda c: sum(isinstance(m, jp.DeviceError) for m in c.messages) >= 2)
    codes = [m.code for m in c.messages if isinstance(m, jp.DeviceError)]
    assert codes[:2] == [1, 9]                           # bad checksum; R refused while enabled
    c.send(jp.Enable(False), jp.ResetCounters(), jp.Ping())
    assert c.pump(lambda c: isinstance(c.messages[-1], jp.Sample) and
                  any(isinstance(m, jp.Version) for m in c.messages))
    n = len(c.messages)
    c.pump(lambda c: len(c.messages) > n + 2)
    assert abs(c.samples[-1].cart_ticks) <= 1           # re-zeroed where the cart stands


def test_disconnect_makes_the_port_vanish_and_come_back_at_the_link(tmp_path, make_device):
    link = tmp_path / 'emu'
    with make_device(link=str(link), faults=FaultConfig(corrupt=0.0)) as em:
        c = Client(str(link))
        c.send(jp.Stream(True))
        c.pump(lambda c: len(c.samples) >= 2)
        old = os.path.realpath(link)   # noqa: F841 (the new pty may reuse the number)
        em.disconnect(0.3)
        with pytest.raises(serial.SerialException):
            deadline = time.monotonic() + 3
            while time.monotonic() < deadline:
                c.port.read(100)
        deadline = time.monotonic() + 3
        while not link.exists() and time.monotonic() < deadline:
            time.sleep(0.01)
        assert link.exists() and em.disconnect_count == 1
        c2 = Client(str(link))
        n = len(c.samples)
        assert c2.pump(lambda c2: len(c2.samples) >= 3)   # still streaming: device kept power
        assert c2.samples[0].seq > c.samples[n - 1].seq + 10
        c.port.close()
        c2.port.close()
        del old


def test_corruption_is_always_detected(tmp_path, make_device):
    with make_device(link=str(tmp_path / 'emu'), faults=FaultConfig(corrupt=0.5), seed=3) as em:
        c = Client(em.link)
        c.send(jp.Stream(True))
        assert c.pump(lambda c: len(c.samples) + len(c.errors) >= 200)
        assert len(c.errors) > 50
        s = c.samples
        # every accepted sample is genuine: seq increasing, t_us = 5 ms x seq
        assert all(b.seq > a.seq for a, b in zip(s, s[1:]))
        assert all((b.t_us - a.t_us) == 5000 * (b.seq - a.seq) for a, b in zip(s, s[1:]))


def test_command_line_refuses_bad_options(capsys):
    with pytest.raises(SystemExit):
        main(['--drop', '2'])
    assert 'probability' in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(['--stall', 'x'])


def test_scenario_drop_loses_exactly_the_seeded_samples(tmp_path, make_device):
    # The scenario's drop loses samples on the link: their seq is skipped, so the host sees
    # the gap; which ones is fixed by the seed (one draw per 5 ms period of the device).
    from cartpole_sim.plant import Plant, Scenario

    scenario = Scenario(drop=0.25, seed=6)
    with make_device(scenario, link=str(tmp_path / 'emu')) as em:
        c = Client(em.link)
        c.send(jp.Stream(True))
        assert c.pump(lambda c: len(c.samples) >= 150)
    seqs = [s.seq for s in c.samples]
    reference = Plant(em.params, scenario)
    lost = [reference.sample_lost() for _ in range(seqs[-1] + 1)]
    expected = [k for k in range(seqs[0], seqs[-1] + 1) if not lost[k]]
    assert seqs == expected
    assert len(expected) < seqs[-1] - seqs[0] + 1  # some were lost


def test_command_line_takes_the_scenario_options():
    from cartpole_emulator.emulator import build_parser
    from cartpole_sim.plant import Push
    from cartpole_sim.scenario_options import scenario_from_args

    args = build_parser().parse_args([
        '--delay', '0.01', '--jitter', '0.002', '--drop', '0.1', '--force-noise', '0.5',
        '--actuator-gain', '0.7', '--actuator-tau', '0.004', '--cart-mass', '5.5',
        '--tip-mass', '0.2', '--encoder-offset', '0.05', '--push', '12:cart:10:0.1',
        '--noise', '--seed', '3', '--drop-lines', '0.2'])
    scenario = scenario_from_args(args)
    assert (scenario.delay, scenario.jitter, scenario.drop, scenario.force_noise,
            scenario.actuator_gain, scenario.actuator_tau, scenario.cart_mass,
            scenario.tip_mass, scenario.encoder_offset, scenario.noise, scenario.seed) == \
        (0.01, 0.002, 0.1, 0.5, 0.7, 0.004, 5.5, 0.2, 0.05, True, 3)
    assert scenario.pushes == (Push(12.0, 'cart', 10.0, 0.1),)
    assert args.drop_lines == 0.2


def test_command_line_refuses_a_bad_scenario(capsys):
    assert main(['--delay', '0.5']) == 2
    assert '--delay must be <= 0.04' in capsys.readouterr().err


@pytest.mark.parametrize('delay', [0.0, 0.02])
def test_a_tagged_setpoint_acts_from_its_arrival_plus_the_delay_and_is_reported(delay):
    """The emulator core in device time: a tagged U arriving 1.3 ms after the sample it
    answers drives the plant from then (plus the scenario's delay), and the S lines say
    so (protocol version 2: ``back``, ``age_us``), as the firmware reports its DAC write."""
    em = Emulator(Scenario(x0=0.3, delay=delay))
    sent = []
    em._send = sent.append
    em.feed(jp.encode(jp.Stream(True)) + jp.encode(jp.Enable(True)), em.t_us)
    for _ in range(12):
        em.sample_period()
        answered = em.device.seq - 1
        em.feed(jp.encode(jp.Setpoint(300, answered)), (em.t_us - 5000 + 1300) % jp.UINT32)
    samples = [m for m in map(jp.decode_line, sent) if isinstance(m, jp.Sample)]
    latency_us = 1300 + round(delay * 1e6)
    reported = [s for s in samples if s.applied_seq is not None]
    assert reported, samples
    # the first report comes with the first sample after the first command acted
    assert reported[0].t_us == (latency_us // 5000 + 1) * 5000
    for s in reported:
        assert (s.applied_t_us - s.applied_seq * 5000) % jp.UINT32 == latency_us
        assert s.back * 5000 - s.age_us == latency_us
    assert [s.t_us for s in samples if s.applied_seq is None] == \
        [t for t in range(0, reported[0].t_us, 5000)]
    # the emulator's own record: sample time and application of every tagged command
    assert {(applied - sampled) % jp.UINT32 for _, sampled, applied in em.applied} == {latency_us}
    assert em.plant.force == pytest.approx(300 / 56.744, rel=0.02)


def test_an_untagged_setpoint_ends_the_report():
    em = Emulator(Scenario(x0=0.3))
    sent = []
    em._send = sent.append
    em.feed(jp.encode(jp.Stream(True)) + jp.encode(jp.Enable(True)), em.t_us)
    em.sample_period()
    em.feed(jp.encode(jp.Setpoint(300, 0)), (em.t_us - 4000) % jp.UINT32)
    em.sample_period()
    em.feed(jp.encode(jp.Setpoint(0)), (em.t_us - 4000) % jp.UINT32)
    em.sample_period()
    s = [m for m in map(jp.decode_line, sent) if isinstance(m, jp.Sample)]
    assert [(m.applied_seq, m.applied_t_us) for m in s] == [(None, None), (0, 1000), (None, None)]


@pytest.mark.parametrize('argv,words', [
    (['--duration', 'nan'], '--duration: must be a finite number'),
    (['--duration', 'inf'], '--duration: must be a finite number'),
    (['--duration', '1e9'], '(0, 3600] s'),
    (['--duration', '0'], '(0, 3600] s'),
    (['--limit-margin', '1'], '[0, 0.1] m'),
    (['--usb-jitter', '5'], '[0, 1] s'),
    (['--stall', '1:1e9'], '(0, 60000] ms'),
    (['--disconnect', '1e9:1'], 'AT in [0, 3600] s'),
    (['--drop-lines', 'nan'], '--drop-lines: must be a finite number'),
    (['--name', 'a*b'], '--name: must be 1 to 80'),
    (['--image', '/no/such.elf'], 'no such file'),
    (['--link', '/no/such/dir/emu'], 'does not exist'),
    (['--params', '/no/such.yaml'], 'no such file'),
    (['--params', 'NOT_YAML'], 'not a CartPoleParameters YAML'),
    (['--x0', 'nan'], '--x0'),
    (['--no-such-option'], 'unrecognized arguments'),
])
def test_every_option_is_refused_in_one_line(argv, words, tmp_path, capsys):
    """``cartpole emulate`` refuses like every ``cartpole`` command: one line, exit 2, the
    bound in the message; options that size the work are bounded (nothing runs for ever)."""
    if 'NOT_YAML' in argv:
        garbled = tmp_path / 'garbled.yaml'
        garbled.write_text('m_c: [1, 2\n')
        argv = [str(garbled) if a == 'NOT_YAML' else a for a in argv]
    try:
        code = main(argv)
    except SystemExit as exit_:
        code = exit_.code
    err = capsys.readouterr().err
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith('cartpole emulate: error: '), err
    assert words in lines[0], lines[0]
    assert 'Traceback' not in err
