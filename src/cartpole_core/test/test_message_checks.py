"""The input checks without DDS: every kind of bad message a foreign node can send is refused
with its reason, and every message the rig (or the simulator) produces is taken."""
import math
from types import SimpleNamespace

import pytest

from cartpole_core.message_checks import (COMMAND, REASONS, SAMPLE, STATE, TRUTH, InputJudge,
                                          RigLimits, judge, judge_stamp)
from cartpole_core.model import CartPoleParameters

S = 1_000_000_000
NOW = 1_796_000_000 * S      # a wall clock


def msg(stamp_ns=NOW, name=('cart', 'pendulum'), position=(0.4, math.pi), velocity=(),
        effort=()):
    sec, nanosec = divmod(stamp_ns, S)
    return SimpleNamespace(header=SimpleNamespace(stamp=SimpleNamespace(sec=sec, nanosec=nanosec)),
                           name=list(name), position=list(position), velocity=list(velocity),
                           effort=list(effort))


LIMITS = RigLimits()
GOOD = {
    SAMPLE: msg(),
    STATE: msg(position=(0.4, 0.01), velocity=(0.3, -2.0)),
    TRUTH: msg(position=(0.0, 0.01), velocity=(0.0, 0.0), effort=(3.0, -12.0)),
    COMMAND: msg(name=('cart',), position=(), effort=(34.0,)),
}


@pytest.mark.parametrize('kind', sorted(GOOD))
def test_what_the_rig_produces_is_taken(kind):
    assert judge(GOOD[kind], kind, NOW, LIMITS) is None


@pytest.mark.parametrize('kind,bad,reason', [
    (SAMPLE, msg(position=(math.nan, math.pi)), 'non_finite'),
    (SAMPLE, msg(position=(0.4, math.inf)), 'non_finite'),
    (SAMPLE, msg(position=(1e308, math.pi)), 'cart_range'),
    (SAMPLE, msg(position=(0.4, 1e308)), 'pendulum_range'),
    (SAMPLE, msg(position=(-0.9, math.pi)), 'cart_range'),
    (SAMPLE, msg(name=('cart', 'pole')), 'joint_names'),
    (SAMPLE, msg(name=()), 'joint_names'),
    (SAMPLE, msg(name=('cart', 'pendulum', 'wheel'), position=(0.4, 0.0, 0.0)), 'joint_names'),
    (SAMPLE, msg(position=(0.4,)), 'array_length'),
    (SAMPLE, msg(velocity=(1.0,)), 'array_length'),
    (SAMPLE, msg(stamp_ns=0), 'zero_stamp'),
    (SAMPLE, msg(stamp_ns=NOW - 60 * S), 'stamp_far'),
    (SAMPLE, msg(stamp_ns=NOW + 60 * S), 'stamp_far'),
    (STATE, msg(position=(0.4, 0.0)), 'array_length'),               # no velocities
    (STATE, msg(position=(0.4, 0.0), velocity=(0.0, math.nan)), 'non_finite'),
    (STATE, msg(position=(0.4, 0.0), velocity=(50.0, 0.0)), 'velocity_range'),
    (STATE, msg(position=(0.4, 0.0), velocity=(0.0, 1e308)), 'velocity_range'),
    (COMMAND, msg(name=('cart',), position=(), effort=(math.nan,)), 'non_finite'),
    (COMMAND, msg(name=('cart',), position=(), effort=(-math.inf,)), 'non_finite'),
    (COMMAND, msg(name=('cart',), position=(), effort=(1e308,)), 'effort_range'),
    (COMMAND, msg(name=('cart',), position=(), effort=(40.0,)), 'effort_range'),
    (COMMAND, msg(name=(), position=(), effort=(1.0,)), 'joint_names'),
    (COMMAND, msg(name=('pendulum',), position=(), effort=(1.0,)), 'joint_names'),
    (COMMAND, msg(name=('cart',), position=(), effort=()), 'array_length'),
    (COMMAND, msg(name=('cart',), position=(), effort=(1.0, 2.0)), 'array_length'),
    (TRUTH, msg(position=(0.0, 0.0), velocity=(0.0,)), 'array_length'),
])
def test_every_kind_of_bad_message_is_refused_with_its_reason(kind, bad, reason):
    assert reason in REASONS
    assert judge(bad, kind, NOW, LIMITS) == reason


def test_the_limits_are_the_rig_s_own():
    p = CartPoleParameters()
    limits = RigLimits.from_parameters(p)
    assert limits.force_max == pytest.approx(34.2, abs=0.05)       # +11 A (Appendix C)
    assert limits.force_min == pytest.approx(-37.4, abs=0.05)      # -12 A
    assert limits.cart_range == pytest.approx((-0.819, 0.819))
    command = msg(name=('cart',), position=(), effort=(-37.3,))
    assert judge(command, COMMAND, NOW, limits) is None
    assert judge(msg(name=('cart',), position=(), effort=(34.3,)), COMMAND, NOW,
                 limits) == 'effort_range'
    longer = RigLimits.from_parameters(p.replace(travel=1.5))
    assert judge(msg(position=(1.2, 0.0)), SAMPLE, NOW, longer) is None
    assert judge(msg(position=(1.2, 0.0)), SAMPLE, NOW, limits) == 'cart_range'
    with pytest.raises(ValueError, match='stamp_tolerance'):
        RigLimits(stamp_tolerance=math.nan)


def test_stamps_against_a_simulated_clock_and_without_a_clock():
    # lockstep on simulated time: sample 0 is stamped 0 while the clock reads about 0
    assert judge_stamp(0, 5_000_000, LIMITS) is None
    assert judge_stamp(0, NOW, LIMITS) == 'zero_stamp'
    # no /clock yet (the clock reads 0): nothing to judge the stamp against
    assert judge_stamp(NOW, 0, LIMITS) is None
    # stamp_tolerance 0 turns the stamp checks off
    assert judge_stamp(0, NOW, RigLimits(stamp_tolerance=0.0)) is None
    assert judge_stamp(NOW - 9 * S, NOW, LIMITS) is None           # a stalled process
    assert judge_stamp(NOW - 11 * S, NOW, LIMITS) == 'stamp_far'    # a replayed bag


def test_the_judge_counts_by_topic_and_reason_and_tells_once():
    j = InputJudge(LIMITS)
    assert j.first_news() is None
    assert j.accept(GOOD[SAMPLE], SAMPLE, 'joint_states', NOW)
    assert not j.accept(msg(stamp_ns=0), SAMPLE, 'joint_states', NOW)
    news = j.first_news()
    assert 'joint_states' in news and 'zero_stamp' in news
    for _ in range(3):
        assert not j.accept(msg(name=('cart',), position=(), effort=(math.nan,)), COMMAND,
                            'cartpole/force_command', NOW)
    assert j.first_news() is None                                   # said once
    assert j.refused == 4
    assert j.counts[('cartpole/force_command', 'non_finite')] == 3
    values = j.values()
    assert values['refused_inputs'] == 4
    assert values['refused_inputs.zero_stamp'] == 1
    assert values['refused_inputs.non_finite'] == 3
    assert values['refused_inputs.last'] == 'non_finite on cartpole/force_command'
    assert 'refused_inputs.cart_range' not in values
    assert not j.accept_stamps([0], 'cartpole/plant_reset', NOW)
    assert j.accept_stamps([NOW, NOW - S], 'cartpole/command_applied', NOW)
    assert j.refused == 5
