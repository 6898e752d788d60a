"""Host-side safety rules (BridgeCore) and the device logic the emulator runs, without ports."""
import math

import pytest

from cartpole_hw import protocol as jp
from cartpole_hw.bridge import E_OFF, E_ON, RESET, U_ZERO, BridgeConfig, BridgeCore
from cartpole_hw.device import DeviceLogic

import importlib.util
from pathlib import Path

_spec = importlib.util.spec_from_file_location('hw_vectors', Path(__file__).with_name('vectors.py'))
vectors = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(vectors)


def sample(seq, cart=0, pend=0, flags=0):
    return jp.encode(jp.Sample(seq, seq * 5000 % jp.UINT32, cart, pend, flags))[:-1]


def ready_core(t=0.0, version=1):
    """A connected, homed core (of a device speaking protocol ``version``)."""
    core = BridgeCore(BridgeConfig())
    core.on_connect(t)
    core.on_line(jp.encode(jp.Version(version, 'dev'))[:-1], t)
    ok, _, lines = core.home(t)
    assert ok and lines == [RESET, jp.encode(jp.Ping())]
    core.on_line(jp.encode(jp.Version(version, 'dev'))[:-1], t)
    assert core.homed
    return core


def setpoints(lines):
    return [jp.decode_line(line).value for line in lines if line.startswith(b'U,')]


def test_arming_is_refused_with_reasons_until_connected_answered_and_homed():
    core = BridgeCore()
    assert 'not connected' in core.arm(0.0)[1]
    core.on_connect(0.0)
    assert 'ping' in core.arm(0.0)[1]
    core.on_line(jp.encode(jp.Version(1, 'dev'))[:-1], 0.0)
    assert 'not homed' in core.arm(0.0)[1]
    core.on_line(jp.encode(jp.Version(3, 'future'))[:-1], 0.0)
    assert not core.link_ready and 'version 3' in core.last_error
    core.on_line(jp.encode(jp.Version(0, 'past'))[:-1], 0.0)
    assert not core.link_ready and 'version 0' in core.last_error


def test_disarmed_bridge_never_sends_a_nonzero_setpoint():
    core = ready_core()
    assert core.on_command(10.0, 0.01) == []
    out = core.on_line(sample(1, flags=jp.FLAG_ENABLED), 0.02)   # device enabled by someone
    for k in range(2, 20):
        out.write += core.on_line(sample(k, flags=jp.FLAG_ENABLED), 0.02 + k * 0.005).write
    assert E_OFF in out.write and set(setpoints(out.write)) == {0}
    assert core.counts.ignored_commands == 1


def test_homing_discards_samples_until_the_version_answer():
    core = ready_core()
    core.on_line(sample(1, cart=100), 0.0)
    core.home(0.01)
    assert core.on_line(sample(2, cart=100), 0.011).sample is None   # before R took effect
    core.on_line(jp.encode(jp.Version(1, 'dev'))[:-1], 0.012)
    s = core.on_line(sample(3, cart=5, pend=-500), 0.013).sample
    assert s.x == pytest.approx(5 * 0.769 / 8737) and s.theta == pytest.approx(math.pi / 2)


def test_host_watchdog_trips_after_command_timeout_and_disarms():
    core = ready_core()
    ok, _, lines = core.arm(0.0)
    assert ok and lines == [E_ON, U_ZERO]
    # before the first command: zero force fed every sample, no trip
    for k in range(1, 40):
        assert core.on_line(sample(k, flags=1), k * 0.005).write == [U_ZERO]
        assert core.on_tick(k * 0.005 + 0.001) == []
    assert core.armed and core.counts.watchdog_trips == 0
    core = ready_core()
    core.arm(0.0)
    t = 0.0
    for k in range(1, 5):
        t = k * 0.005
        core.on_line(sample(k, flags=1), t)
        assert setpoints(core.on_command(2.0, t, latency=0.001)) == [113]   # 56.744 * 2 N
    assert core.on_tick(t + 0.047) == []
    core.on_line(sample(5, flags=1), t + 0.047)
    lines = core.on_tick(t + 0.0485)       # the next tick (2 ms) would be past the 50 ms
    assert lines == [U_ZERO, E_OFF] and not core.armed and core.counts.watchdog_trips == 1
    assert 'host watchdog' in core.last_error
    assert core.on_command(2.0, t + 0.06) == []          # stays disarmed: explicit re-arm


@pytest.mark.parametrize('phase', [0.0, 0.0003, 0.0011, 0.0019])
@pytest.mark.parametrize('jitter', [0.0, 0.0004])
def test_host_watchdog_zero_force_within_50_ms_of_the_last_command(phase, jitter):
    """The 50 ms watchdog in simulated time: commands every 5 ms (arrival jitter), the link ticking
    every ``tick_period`` at some phase; after the last command, U,0 goes out at the
    last tick inside the 50 ms, not one tick later (nor earlier than needed)."""
    cfg = BridgeConfig(sample_timeout=10.0)                 # samples are not this test's
    core = ready_core()
    core.config = cfg
    core.arm(0.0)
    last = 0.0
    for k in range(1, 21):
        last = k * 0.005 + (jitter if k % 2 else 0.0)
        core.on_command(2.0, last, latency=0.001)
    t = 0.1 + phase
    while t <= last:
        t += cfg.tick_period
    while True:
        lines = core.on_tick(t)
        if lines:
            break
        t += cfg.tick_period
    assert lines[:2] == [U_ZERO, E_OFF] and core.counts.watchdog_trips == 1
    assert cfg.command_timeout - cfg.tick_period < t - last <= cfg.command_timeout


@pytest.mark.parametrize('elapsed_us,trips', vectors.load('watchdog'))
@pytest.mark.parametrize('t0', [1000, jp.UINT32 - 256])
def test_device_watchdog_shared_vectors(elapsed_us, trips, t0):
    """The same vectors as the firmware's C++ test: a tick ``elapsed_us`` after the last U."""
    d = DeviceLogic()
    d.handle_line(jp.encode(jp.Enable(True)), t0)
    d.handle_line(jp.encode(jp.Setpoint(100)), t0)
    d.tick((t0 + int(elapsed_us)) % jp.UINT32, False, False)
    assert d.watchdog_tripped == (trips == '1')
    assert (d.output_setpoint() == 0) == (trips == '1')


def test_absurd_sequence_jump_is_a_bad_sample_not_lost_samples():
    core = ready_core()
    for k in range(1, 11):
        assert core.on_line(sample(k), k * 0.005).sample is not None
    # a checksummed line whose seq jumped by a million (a garble the XOR did not catch)
    out = core.on_line(sample(10 + 1_000_000), 0.055)
    assert out.sample is None and out.write == []
    assert (core.counts.bad_samples, core.tracker.lost, core.counts.samples) == (1, 0, 10)
    assert core.on_line(sample(11), 0.056).sample is not None        # the stream goes on
    # a real gap: 30 samples lost over 155 ms is accepted and counted as lost
    assert core.on_line(sample(42), 0.056 + 0.155).sample is not None
    h = core.health()
    assert (h['lost_samples'], h['bad_samples'], h['sequence_resyncs']) == ('30', '1', '0')
    # a device whose count really moved: three consecutive samples resynchronise
    outs = [core.on_line(sample(5_000_000 + i), 0.22 + 0.005 * i) for i in range(4)]
    assert [o.sample is not None for o in outs] == [False, False, True, True]
    h = core.health()
    assert (h['lost_samples'], h['bad_samples'], h['sequence_resyncs']) == ('30', '3', '1')


def test_activate_waits_for_a_warm_loop():
    """The lifecycle's activate: refused (with the count) while the loop still works off a
    backlog (stale commands) or nobody answers, granted after 20 fresh commands in a row;
    ``arm`` itself is immediate."""
    core = ready_core()
    ok, reason, lines = core.activate(0.0)
    assert not ok and not lines and '0 of 20' in reason and 'never' in reason
    t = 0.0
    for k in range(1, 60):
        t = k * 0.005
        core.on_line(sample(k), t)
        core.on_command(1.0, t + 0.001, latency=0.08 if k < 30 else 0.002)   # backlog, then live
        assert E_ON not in core.on_tick(t + 0.002)          # nothing arms by itself
        ok, reason, lines = core.activate(t + 0.002)
        if ok:
            break
        assert E_ON not in lines and not core.armed
    assert core.armed and k == 29 + core.config.warm_commands
    assert lines == [E_ON, U_ZERO]
    # a warm run gone cold (no command for longer than command_timeout): refused again
    cold = ready_core()
    for k in range(1, 25):
        cold.on_line(sample(k), k * 0.005)
        cold.on_command(1.0, k * 0.005 + 0.001, latency=0.002)
    ok, reason, _ = cold.activate(24 * 0.005 + 0.2)
    assert not ok and '24 of 20' in reason and 'ms ago' in reason
    other = ready_core()
    assert other.arm(0.0)[0]                                     # arm itself: at once


def test_stale_and_nonfinite_commands_are_not_fresh():
    core = ready_core()
    core.arm(0.0)
    assert core.on_command(math.nan, 0.001) == []
    assert core.on_command(1.0, 0.001, latency=0.2) == []
    counts = core.counts
    assert (counts.bad_commands, counts.stale_commands, core.commands_live) == (1, 1, False)


@pytest.mark.parametrize('event', ['sample_timeout', 'device_watchdog', 'limit', 'device_fault',
                                   'disconnect', 'restart'])
def test_every_fault_zeroes_force_and_disarms(event):
    core = ready_core()
    core.arm(0.0)
    core.on_line(sample(10, flags=1), 0.001)
    core.on_command(5.0, 0.002)
    if event == 'sample_timeout':
        lines = core.on_tick(0.06)
    elif event == 'device_watchdog':
        lines = core.on_line(sample(11, flags=jp.FLAG_ENABLED | jp.FLAG_WATCHDOG), 0.004).write
    elif event == 'limit':
        lines = core.on_line(sample(11, flags=jp.FLAG_ENABLED | jp.FLAG_LIMIT_RIGHT), 0.004).write
    elif event == 'device_fault':
        lines = core.on_line(jp.encode(jp.DeviceError(17, 'limit right'))[:-1], 0.004).write
    elif event == 'disconnect':
        core.on_disconnect(0.004, 'gone')
        lines = [U_ZERO, E_OFF]            # nothing can be sent; on reconnect U,0 E,0 go first
        assert core.on_connect(0.5)[:2] == [U_ZERO, E_OFF] and core.counts.reconnects == 1
    else:
        lines = core.on_line(sample(0, flags=1), 0.004).write
        assert not core.homed and 're-home' in core.last_error
    assert lines[:2] == [U_ZERO, E_OFF]
    assert not core.armed and core.last_error


def test_limit_switch_inhibits_force_towards_it_only():
    core = ready_core()
    core.on_line(sample(1, flags=jp.FLAG_LIMIT_LEFT), 0.0)   # homed at the left stop
    assert core.arm(0.001)[0]
    core.on_line(sample(2, flags=jp.FLAG_LIMIT_LEFT | 1), 0.005)
    assert core.armed                                    # closed before arming: no crash
    assert setpoints(core.on_command(-3.0, 0.006)) == [0]
    assert setpoints(core.on_command(3.0, 0.007)) == [170]
    assert core.counts.limit_inhibits == 1


def test_bad_lines_are_counted_by_reason_and_lost_samples_by_seq():
    core = ready_core()
    for line in (b'S,1,2,3,4,5*00', b'S,1,2,3,4,5', b'P*50', b'S,1,2,99999,4,5*' + b'%02X' % jp.checksum('S,1,2,99999,4,5')):
        core.on_line(line, 0.0)
    core.on_line(jp.DecodeError('oversized'), 0.0)
    core.on_line(sample(1), 0.0)
    core.on_line(sample(4), 0.0)
    h = core.health()
    assert (h['bad_lines'], h['bad_lines.bad_checksum'], h['bad_lines.missing_checksum'],
            h['bad_lines.unknown_type'], h['bad_lines.out_of_range'], h['bad_lines.oversized']) \
        == ('5', '1', '1', '1', '1', '1')
    assert h['lost_samples'] == '2' and h['samples'] == '2'


# -- the latency report (protocol version 2) ------------------------------------------------
def test_a_version_2_device_gets_tagged_setpoints_a_version_1_device_untagged_ones():
    for version, expected in ((2, jp.Setpoint(113, 7)), (1, jp.Setpoint(113))):
        core = ready_core(version=version)
        assert core.tags_commands == (version == 2)
        core.arm(0.0)
        core.on_line(sample(7, flags=1), 0.005)
        lines = core.on_command(2.0, 0.006, latency=0.001, tag=7)
        assert [jp.decode_line(line) for line in lines] == [expected]
        # a command that answers no sample of the bridge goes untagged
        assert jp.decode_line(core.on_command(2.0, 0.007, latency=0.001)[0]) == jp.Setpoint(113)
        # the zeros of a disarm are untagged
        assert core.disarm() == [U_ZERO, E_OFF]


def test_a_reported_command_is_passed_on_once_with_its_time_on_the_samples_clock():
    core = ready_core(version=2)
    core.arm(0.0)
    t0 = 1000.0                                  # the host clock; receipt = device time + t0
    stamps = {}
    reported = []
    for k in range(1, 12):
        back_age = (2, 10_000 - 1300 - 2000 * (k >= 8)) if k >= 4 else (None, None)
        # from sample 4 on: the command answering sample k - 2 took effect 1.3 ms (from 8 on
        # 3.3 ms) after it, i.e. reported 2 samples later with age 10 - 1.3 ms
        line = jp.encode(jp.Sample(k, k * 5000, 0, 0, 1, *back_age))[:-1]
        s = core.on_line(line, t0 + k * 0.005 + 0.0004).sample
        stamps[k] = s.stamp
        if s.applied is not None:
            reported.append((k, s.applied))
    assert [k for k, _ in reported] == list(range(4, 12))      # a new command each sample
    for k, applied in reported:
        assert applied.seq == k - 2
        latency = 0.0013 + 0.002 * (k >= 8)
        assert applied.stamp - stamps[k - 2] == pytest.approx(latency, abs=1e-9)
        assert applied.latency == pytest.approx(latency, abs=1e-12)
    # the same command reported again is not passed on again; the report ending is quiet
    again = core.on_line(jp.encode(jp.Sample(12, 60_000, 0, 0, 1, 3, 13_300))[:-1], t0 + 0.0604)
    assert again.sample.applied is None
    quiet = core.on_line(jp.encode(jp.Sample(13, 65_000, 0, 0, 1))[:-1], t0 + 0.0654)
    assert quiet.sample.applied is None
    h = core.health()
    assert h['actuation_reports'] == '8' and float(h['actuation_latency_s']) == pytest.approx(0.0033)


def test_the_device_clock_maps_a_reported_time_like_a_sample_time():
    from cartpole_hw.device_clock import DeviceClock
    clock = DeviceClock()
    assert clock.stamp_of(0) is None
    for k in range(400):                         # 2 s, a drifting device clock (+50 ppm)
        t_us = (jp.UINT32 - 1_000_000 + k * 5000) % jp.UINT32     # across the wrap
        stamp = clock.stamp(t_us, 50.0 + k * 0.005 * (1 + 50e-6) + 0.0002 * (k % 3))
    assert clock.stamp_of(t_us) == pytest.approx(stamp, abs=1e-12)
    ahead = clock.stamp((t_us + 5000) % jp.UINT32, 50.0 + 400 * 0.005 * (1 + 50e-6))
    # a time between two samples: on the line through both stamps (to the slew per sample)
    between = clock.stamp_of((t_us + 2000) % jp.UINT32)
    assert between == pytest.approx(stamp + 0.4 * (ahead - stamp), abs=2e-5)
    assert clock.stamp_of((t_us - 3000) % jp.UINT32) < stamp


@pytest.mark.parametrize('events,expected', vectors.load('report'))
def test_device_latency_report_shared_vectors(events, expected):
    """The same vectors as the firmware's C++ test: the latency report of protocol 2."""
    d = DeviceLogic()
    got = []
    for event in events.split():
        what, at = event.split('@')
        now = int(at)
        if what == 'W':
            d.output_written(now)
        elif what == 'S':
            d.tick(now, False, False)
            got.append(jp.canonical(jp.decode_line(d.sample_line(now, 0, 0))))
        else:
            replies, _ = d.handle_line(jp.frame(what), now)
            assert replies == []
    assert ';'.join(got) == expected


def test_device_reports_a_delayed_command_only_if_it_is_still_the_current_run():
    # The emulator's path: the plant says when a tagged command acted (after its delay).
    d = DeviceLogic()
    d.handle_line(jp.encode(jp.Enable(True)), 0)
    d.handle_line(jp.encode(jp.Setpoint(50, 3)), 1000)
    assert d.take_pending() == 3 and d.take_pending() is None
    d.command_applied(3, 21000)
    assert (d.applied_tag, d.applied_us) == (3, 21000)
    d.handle_line(jp.encode(jp.Setpoint(50, 4)), 6000)
    d.handle_line(jp.encode(jp.Setpoint(0)), 7000)             # a disarm's zero: report ends
    d.command_applied(4, 26000)                                # 4 acts late: not reported
    assert d.applied_tag is None
    d.handle_line(jp.encode(jp.Setpoint(50, 9)), 30000)
    d.command_applied(4, 31000)                                # older than this run: ignored
    assert d.applied_tag is None
    d.command_applied(9, 50000)
    assert d.applied_tag == 9


# -- the device logic (mirror of joint_protocol.cpp, run by the emulator) ---------------------
def test_device_watchdog_enable_and_reset_rules():
    d = DeviceLogic()
    d.handle_line(b'E,1*58', 0)
    d.handle_line(b'U,500*4C', 1000)
    assert d.output_setpoint() == 500 and d.dac_value() == 2453
    assert d.tick(1000 + 45_000, False, False) == []       # the next tick is still in time
    assert d.tick(1000 + 50_000, False, False) == [jp.encode(jp.DeviceError(16, 'watchdog'))]
    assert d.output_setpoint() == 0 and d.flags() == jp.FLAG_ENABLED | jp.FLAG_WATCHDOG
    replies, reset = d.handle_line(b'R*52', 60_000)
    assert not reset and jp.decode_line(replies[0]).code == 9
    d.handle_line(b'E,0*59', 70_000)
    assert d.dac_value() == 1953 and d.handle_line(b'R*52', 80_000) == ([], True)
    assert jp.decode_line(d.handle_line(b'U,1.5*00', 0)[0][0]).code == 1
