"""Device time on the host clock (cartpole_hw.device_clock), the bridge's stamps and seq gaps.

The pure tests feed the clock model r = c + (1 + e) tau + d with seeded latencies;
the last one runs the emulator on a real pty with USB latency jitter and a lossy
scenario, read by the bridge's serial link: the arrival times jitter by
milliseconds, the stamps' intervals stay Ts +/- 0.1 ms, the gaps are counted, and
an EKF fed the stamps counts the same missed samples.
"""
import random
import threading

import pytest

from cartpole_estimation.ekf import ExtendedKalmanFilter
from cartpole_hw import protocol as jp
from cartpole_hw.bridge import BridgeCore
from cartpole_hw.device_clock import DeviceClock, DeviceClockConfig
from cartpole_emulator.emulated_rig import Emulator, FaultConfig
from cartpole_hw.serial_link import SerialLink
from cartpole_core.model import CartPoleParameters
from cartpole_sim.plant import Scenario

TS = 0.005


def latencies(n, seed=1, jitter=0.004, spike=0.03, spike_p=0.01, floor=0.0008):
    """USB-like latencies: a floor, uniform jitter, rare long spikes; in order (a line is
    never received before the one sent before it)."""
    rng = random.Random(seed)
    out = []
    for k in range(n):
        d = floor + rng.uniform(0.0, jitter) + (spike if rng.random() < spike_p else 0.0)
        out.append(d)
    return out


def received(n, offset=123.4, drift=0.0, t_us0=0, seed=1, lost=()):
    """(t_us, receipt, true host time of the sample) of n samples (those in ``lost`` skipped)."""
    out, last_receipt = [], -1.0
    for k, d in enumerate(latencies(n, seed)):
        if k in lost:
            continue
        tau = k * TS
        host = offset + (1.0 + drift) * tau
        receipt = max(host + d, last_receipt)
        last_receipt = receipt
        out.append(((t_us0 + k * 5000) % jp.UINT32, receipt, host))
    return out


def stamps_of(samples, clock=None):
    clock = clock or DeviceClock()
    return [clock.stamp(t_us, r) for t_us, r, _ in samples], clock


def intervals(values):
    return [b - a for a, b in zip(values, values[1:])]


def test_stamps_keep_the_device_period_while_arrivals_jitter_by_milliseconds():
    samples = received(4000)
    stamps, clock = stamps_of(samples)
    arrivals = intervals([r for _, r, _ in samples])
    assert max(arrivals) - min(arrivals) > 0.004          # the premise: milliseconds of jitter
    assert all(abs(i - TS) <= 1e-4 for i in intervals(stamps))
    # Converged: each stamp is the sample's host time plus the smallest latency (0.8 ms
    # floor), however late the line arrived; spikes of 30 ms do not move it.
    errors = [s - host for s, (_, _, host) in zip(stamps, samples)][400:]
    assert max(errors) - min(errors) < 2e-4
    assert 0.0 <= min(errors) and max(errors) <= 0.0008 + 2e-4
    assert clock.steps == 1 and clock.resets == 0


def test_drift_is_estimated_and_followed():
    samples = received(12000, drift=80e-6)           # a crystal 80 ppm fast, 60 s
    stamps, clock = stamps_of(samples)
    assert clock.drift == pytest.approx(80e-6, abs=10e-6)
    assert all(abs(i - TS * (1 + 80e-6)) <= 1e-4 for i in intervals(stamps))
    errors = [s - host for s, (_, _, host) in zip(stamps, samples)][4000:]
    assert max(errors) - min(errors) < 2e-4


def test_t_us_wraps_without_a_jump():
    samples = received(2000, t_us0=jp.UINT32 - 3_000_000)     # wraps after 3 s
    assert any(b[0] < a[0] for a, b in zip(samples, samples[1:]))
    stamps, clock = stamps_of(samples)
    assert all(abs(i - TS) <= 1e-4 for i in intervals(stamps)) and clock.resets == 0


def test_lost_samples_keep_their_place_in_time():
    samples = received(600, lost={300, 301, 302})
    stamps, _ = stamps_of(samples)
    gaps = intervals(stamps)
    assert gaps[299] == pytest.approx(4 * TS, abs=1e-4)       # 3 lost: 4 periods
    assert all(abs(g - TS) <= 1e-4 for k, g in enumerate(gaps) if k != 299)


def test_a_device_restart_starts_the_mapping_again():
    clock = DeviceClock()
    first = [clock.stamp(k * 5000, 10.0 + k * TS + 0.001) for k in range(100)]
    again = clock.stamp(0, 10.0 + 100 * TS + 0.001)          # micros() from zero again
    assert clock.resets == 1 and again == pytest.approx(first[-1] + TS, abs=2e-4)


def test_config_refuses_nonsense():
    with pytest.raises(ValueError, match='max_slew'):
        DeviceClockConfig(max_slew=0.0)
    with pytest.raises(ValueError, match='two blocks'):
        DeviceClockConfig(block=1.0, window=1.5)


def test_bridge_counts_seq_gaps_and_stamps_them_as_the_ekf_counts_them():
    core = BridgeCore()
    core.on_connect(0.0)
    core.on_line(jp.encode(jp.Version(1, 'dev'))[:-1], 0.0)
    samples = []
    for k, (t_us, receipt, _) in enumerate(received(400, lost={100, 200, 201})):
        seq = t_us // 5000
        out = core.on_line(jp.encode(jp.Sample(seq, t_us, 0, 0, 0))[:-1], receipt)
        samples.append(out.sample)
    assert core.counts.seq_gaps == 2 and core.tracker.lost == 3
    assert [s.missed for s in samples if s.missed] == [1, 2]
    health = core.health()
    assert health['seq_gaps'] == '2' and health['lost_samples'] == '3'
    ekf = ExtendedKalmanFilter(CartPoleParameters())
    for s in samples:
        ekf.update(s.stamp, s.x, s.theta, 0.0)
    assert ekf.missed_samples_total == 3


@pytest.mark.slow
def test_emulator_usb_jitter_does_not_reach_the_stamps(tmp_path):
    """Real pty, real pyserial, the bridge's own link: 5 ms +/- 0.1 ms stamps, gaps counted."""
    scenario = Scenario(drop=0.03, seed=4)
    got, enough = [], threading.Event()

    def on_samples(samples):
        got.extend(samples)
        if len(got) >= 500:
            enough.set()

    with Emulator(scenario, link=str(tmp_path / 'emu'),
                  faults=FaultConfig(usb_jitter=0.004), seed=2) as em:
        core = BridgeCore()
        link = SerialLink(core, em.link, notify=on_samples)
        link.start()
        try:
            assert enough.wait(30.0), f'only {len(got)} samples'
        finally:
            link.stop()
    samples = got[:500]
    arrivals = intervals([s.receipt for s in samples])
    assert max(arrivals) - min(arrivals) > 0.002          # the premise: arrivals jitter by ms
    for a, b in zip(samples, samples[1:]):
        periods = (b.seq - a.seq) % jp.UINT32
        assert b.missed == periods - 1
        assert abs((b.stamp - a.stamp) - periods * TS) <= 1e-4, (a, b)
    gaps = sum(1 for s in samples[1:] if s.missed)
    assert gaps > 0 and core.counts.seq_gaps >= gaps
    assert core.health()['seq_gaps'] == str(core.counts.seq_gaps)
