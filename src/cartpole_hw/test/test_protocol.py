"""Joint protocol codec (docs/rig.md, "The Joint protocol"): shared vectors, round trips,
fuzzing, conversions."""
import importlib.util
import math
from pathlib import Path

import pytest
from hypothesis import given, settings, strategies as st

from cartpole_hw import protocol as jp
from cartpole_hw.calibration import Calibration
from cartpole_hw.counters import CounterUnwrapper, SequenceTracker
from cartpole_hw.line_splitter import LineSplitter, iter_lines
from cartpole_core.model import CartPoleParameters, wrap_counter
from cartpole_sim.plant import Plant, Scenario

_spec = importlib.util.spec_from_file_location('hw_vectors', Path(__file__).with_name('vectors.py'))
vectors = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(vectors)


# -- shared vectors ------------------------------------------------------------------------------
@pytest.mark.parametrize('line,expected', vectors.load('decode'))
def test_decode_vectors(line, expected):
    raw = vectors.unescape(line)
    assert jp.canonical(jp.decode_line(raw)) == expected
    # the same with the terminator, LF or CRLF
    assert jp.canonical(jp.decode_line(raw + b'\n')) == expected
    if not raw.endswith(b'\r'):
        assert jp.canonical(jp.decode_line(raw + b'\r\n')) == expected


def test_vectors_cover_every_reason_and_type():
    expected = {e for _, e in vectors.load('decode')}
    for reason in jp.DECODE_REASONS:
        assert f'err:{reason}' in expected
    kinds = {e[0] for e in expected if not e.startswith('err:')}
    assert kinds == set('PERLUVS!')
    # both forms of version 2's longer lines
    bodies = [e for e in expected if not e.startswith('err:')]
    assert {e.count(',') for e in bodies if e[0] == 'U'} == {1, 2}
    assert {e.count(',') for e in bodies if e[0] == 'S'} == {5, 7}


@pytest.mark.parametrize('body,line', vectors.load('encode'))
def test_encode_vectors(body, line):
    decoded = jp.decode_line(line)
    assert not isinstance(decoded, jp.DecodeError)
    assert jp.encode(decoded) == line.encode() + b'\n'
    assert decoded.body() == body


@pytest.mark.parametrize('force,setpoint', vectors.load('setpoint'))
def test_setpoint_vectors(force, setpoint):
    assert Calibration().force_to_setpoint(float(force)) == int(setpoint)


@pytest.mark.parametrize('setpoint,dac', vectors.load('dac'))
def test_dac_vectors(setpoint, dac):
    assert Calibration().dac_value(int(setpoint)) == int(dac)


@pytest.mark.parametrize('body,hh', vectors.load('checksum'))
def test_checksum_vectors(body, hh):
    assert f'{jp.checksum(body):02X}' == hh


# -- round trips ---------------------------------------------------------------------------------
int16 = st.integers(jp.INT16_MIN, jp.INT16_MAX)
uint32 = st.integers(0, jp.UINT32 - 1)
text = st.text(st.characters(min_codepoint=0x20, max_codepoint=0x7E, blacklist_characters='*'),
               max_size=40)
messages = st.one_of(
    st.just(jp.Ping()), st.just(jp.ResetCounters()),
    st.builds(jp.Enable, st.booleans()), st.builds(jp.Stream, st.booleans()),
    st.builds(jp.Setpoint, int16), st.builds(jp.Setpoint, int16, uint32),
    st.builds(jp.Version, st.integers(0, 65535), text.filter(lambda s: s and ',' not in s)),
    st.builds(jp.Sample, uint32, uint32, int16, int16, st.integers(0, 15)),
    st.builds(jp.Sample, uint32, uint32, int16, int16, st.integers(0, 15), uint32, uint32),
    st.builds(jp.DeviceError, st.integers(0, 255), text),
)


@given(messages)
def test_round_trip_every_message(message):
    line = jp.encode(message)
    assert line.endswith(b'\n') and len(line) - 1 <= jp.MAX_LINE
    assert jp.decode_line(line) == message
    assert jp.decode_line(line.replace(b'\n', b'\r\n')) == message
    assert jp.decode_line(line.lower() if isinstance(message, jp.Ping) else line) == message \
        or isinstance(message, jp.Ping)


@given(messages, st.integers(0, 200), st.integers(0, 255))
def test_any_single_byte_corruption_is_refused_or_harmless(message, position, value):
    line = bytearray(jp.encode(message)[:-1])
    i = position % len(line)
    if value in (line[i], 0x0A):
        return
    original = bytes(line)
    line[i] = value
    result = jp.decode_line(bytes(line))
    # XOR catches every single-byte change, except a hex digit's case in the checksum
    if not isinstance(result, jp.DecodeError):
        assert result == jp.decode_line(original)
        assert bytes(line).upper() == original.upper()


def test_direction_filter():
    assert jp.decode_line(b'P*50', direction='device').reason == 'unknown_type'
    assert jp.decode_line(jp.encode(jp.Sample(1, 2, 3, 4, 5)), direction='host').reason == 'unknown_type'
    assert jp.decode_line(b'P*50', direction='host') == jp.Ping()


def test_encode_refuses_what_the_wire_cannot_carry():
    with pytest.raises(ValueError):
        jp.encode(jp.Sample(0, 0, 40000, 0, 0))
    with pytest.raises(ValueError):
        jp.encode(jp.Sample(0, 0, 0, 0, 16))
    with pytest.raises(ValueError):
        jp.encode(jp.Setpoint(1 << 20))
    with pytest.raises(ValueError):
        jp.encode(jp.DeviceError(1, 'star * in text'))
    with pytest.raises(ValueError):
        jp.encode(jp.Version(1, 'comma,name'))


# -- fuzzing ---------------------------------------------------------------------------------------
@settings(max_examples=400)
@given(st.binary(max_size=200))
def test_decoder_never_raises(data):
    result = jp.decode_line(data)
    if isinstance(result, jp.DecodeError):
        assert result.reason in jp.DECODE_REASONS
    else:
        assert jp.decode_line(jp.encode(result)) == result


@settings(max_examples=300)
@given(st.lists(st.binary(max_size=300), max_size=30))
def test_splitter_is_bounded_and_never_raises(chunks):
    splitter = LineSplitter()
    for chunk in chunks:
        for item in splitter.feed(chunk):
            if isinstance(item, jp.DecodeError):
                assert item.reason == 'oversized'
            else:
                assert b'\n' not in item and 0 < len(item) <= jp.MAX_LINE
        assert splitter.buffered <= jp.MAX_LINE + 1


@given(st.lists(messages, min_size=1, max_size=20), st.lists(st.integers(1, 50), min_size=1))
def test_splitter_reassembles_lines_across_any_chunking(msgs, cuts):
    stream = b''.join(jp.encode(m).replace(b'\n', b'\r\n') if i % 2 else jp.encode(m)
                      for i, m in enumerate(msgs))
    chunks, i, k = [], 0, 0
    while i < len(stream):
        n = cuts[k % len(cuts)]
        chunks.append(stream[i:i + n])
        i += n
        k += 1
    decoded = [jp.decode_line(line) for line in iter_lines(chunks)]
    assert decoded == msgs


def test_splitter_drops_oversized_garbage_and_recovers():
    splitter = LineSplitter()
    good = jp.encode(jp.Sample(7, 35000, 1, 2, 1))
    out = splitter.feed(b'x' * 1000)
    out += splitter.feed(b'y' * 5000 + b'\n' + good)
    assert [type(o) for o in out] == [jp.DecodeError, bytes]
    assert out[0].reason == 'oversized'
    assert jp.decode_line(out[1]) == jp.Sample(7, 35000, 1, 2, 1)


# -- sequence tracking -----------------------------------------------------------------------------
def test_sequence_tracker_counts_gaps_across_the_uint32_wrap():
    t = SequenceTracker()
    for seq in (jp.UINT32 - 3, jp.UINT32 - 2, 1, 2, 2, 5):
        t.update(seq)
    # lost: UINT32-1, 0 (2) and 3, 4 (2); one duplicate
    assert (t.lost, t.duplicates, t.restarts) == (4, 1, 0)
    assert t.update(0) == -1 and t.restarts == 1   # backwards: device restarted
    assert t.update(1) == 0 and t.lost == 4


# -- conversions (2.3), (2.4), (A.3) ------------------------------------------------------------
def test_calibration_matches_the_thesis_resolutions():
    cal = Calibration.from_parameters(CartPoleParameters())
    assert cal.cart_resolution == pytest.approx(88.016e-6, rel=1e-4)          # (2.4)
    assert cal.pendulum_resolution == pytest.approx(math.pi * 1e-3)           # (2.3)
    assert cal.cart_position(8737) == pytest.approx(0.769)
    assert cal.pendulum_angle(0) == pytest.approx(math.pi)                   # hanging after reset
    assert cal.pendulum_angle(1000) == pytest.approx(2 * math.pi)
    assert cal.setpoint_to_force(1) == pytest.approx(0.017623, rel=1e-4)      # (A.3)
    assert (cal.setpoint_min, cal.setpoint_max) == (-1953, 2142)
    # +11 A (34.2 N) fits in the DAC range, -12 A (-37.4 N) does not: the DAC's
    # offset 1953 limits the leftward force to -1953 / 56.744 = -34.4 N
    p = CartPoleParameters()
    assert 0 < cal.force_to_setpoint(p.force_max) < cal.setpoint_max
    assert cal.force_to_setpoint(p.force_min) == cal.setpoint_min
    assert cal.setpoint_to_force(cal.setpoint_min) == pytest.approx(-34.42, abs=0.01)


def test_calibration_defaults_are_the_plant_parameters_encoder_figures():
    default, p = Calibration(), CartPoleParameters()
    assert default == Calibration.from_parameters(p)
    assert (default.cart_ticks_over_travel, default.travel, default.pendulum_ticks_per_rev,
            default.counter_bits) == (8737.0, 0.769, 2000.0, 16)     # thesis section 2.3
    assert isinstance(default.cart_ticks_over_travel, float)            # the bridge's doubles
    assert (default.cart_resolution, default.pendulum_resolution) == (p.cart_resolution,
                                                                      p.pendulum_resolution)
    rig = Calibration.from_parameters(p.replace(cart_ticks_over_travel=9000, travel=0.8))
    assert rig.cart_resolution == pytest.approx(0.8 / 9000)


def test_calibration_signs_and_refusals():
    cal = Calibration(cart_sign=-1, pendulum_sign=-1, force_sign=-1)
    assert cal.cart_position(100) < 0
    assert cal.pendulum_angle(500) == pytest.approx(math.pi / 2)
    assert cal.force_to_setpoint(10.0) == -567
    assert cal.force_to_setpoint(math.nan) == 0
    for bad in (dict(cart_sign=0), dict(travel=-1.0), dict(dac_zero=5000),
                dict(setpoint_per_newton=math.inf)):
        with pytest.raises(ValueError):
            Calibration(**bad)


def test_unwrapper_rebuilds_count_across_wraps_synthetic():
    unwrapper = CounterUnwrapper()
    counts = list(range(0, 200_000, 997)) + list(range(200_000, -150_000, -1499))
    rebuilt = [unwrapper.update(wrap_counter(c)) for c in counts]
    assert rebuilt == counts
    unwrapper.reset()
    assert unwrapper.update(wrap_counter(70_000)) == wrap_counter(70_000)


def test_the_plants_positions_are_what_the_unwrapper_rebuilds_from_its_wrapping_counters():
    # ~35 rad/s for 4 s is ~20 revolutions = 40,000 ticks > 32,767: the raw counter wraps.
    p = CartPoleParameters(c_c_right=0.0, c_c_left=0.0, c_p=0.0, v_p=0.0)
    plant = Plant(p, Scenario(x0=p.x_middle, theta_dot0=40.0,
                              x_dot0=-p.m_p * p.l * 40.0 / (p.m_c + p.m_p)))
    cal = Calibration.from_parameters(p)
    cart, pend = CounterUnwrapper(16), CounterUnwrapper(16)
    for _ in range(800):
        m = plant.measure()
        assert m.x == cal.cart_position(cart.update(m.cart_ticks))
        assert m.theta == cal.pendulum_angle(pend.update(m.pendulum_ticks))
        plant.step(0.0)
    assert pend.update(m.pendulum_ticks) > 32767   # it did wrap


def test_unwrapping_the_16_bit_counters_across_many_revolutions():
    cal = Calibration()
    unwrap = CounterUnwrapper(16)
    counts = (0, 20000, 32767, 35536, 60536, 85536, 60000, 40000)   # many revolutions
    raw = [wrap_counter(c) for c in counts]
    assert raw == [0, 20000, 32767, -30000, -5000, 20000, -5536, -25536]
    angles = [cal.pendulum_angle(unwrap.update(r)) for r in raw]
    assert angles == pytest.approx([math.pi + c * cal.pendulum_resolution for c in counts])


def test_version_2_fields_round_trip_and_give_the_applied_command():
    s = jp.Sample(3, 2000, 0, 0, 1, 5, 4000)        # across both wraps
    assert (s.applied_seq, s.applied_t_us) == (jp.UINT32 - 2, jp.UINT32 - 2000)
    assert jp.decode_line(jp.encode(s)) == s
    plain = jp.Sample(3, 2000, 0, 0, 1)
    assert plain.applied_seq is None and plain.applied_t_us is None
    assert jp.encode(plain) == jp.frame('S,3,2000,0,0,1')      # the version-1 form
    with pytest.raises(ValueError):
        jp.encode(jp.Sample(3, 2000, 0, 0, 1, 5, None))     # both or neither
    with pytest.raises(ValueError):
        jp.encode(jp.Setpoint(1, -1))
    assert jp.decode_line(jp.encode(jp.Setpoint(-5, 12))) == jp.Setpoint(-5, 12)
    # the longest version-2 sample line fits the line limit with room to spare
    longest = jp.encode(jp.Sample(jp.UINT32 - 1, jp.UINT32 - 1, -32768, -32768, 15,
                                  jp.UINT32 - 1, jp.UINT32 - 1))
    assert len(longest) - 1 <= jp.MAX_LINE - 30
