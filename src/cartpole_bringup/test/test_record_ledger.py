"""The recorder's ledger (cartpole_bringup.graph.record_ledger): lockstep progress, repeats, misses."""
from __future__ import annotations

from cartpole_bringup.graph.record_ledger import (CLOCK, FORCE, JOINT_STATES, STATE, STATUS,
                                            TRUE_STATE, RecordLedger)

TS = 5_000_000
ALL = (JOINT_STATES, TRUE_STATE, CLOCK, STATE, FORCE, STATUS, '/cartpole/ekf/health')


def one_sample(ledger, k, skip=()):
    for topic in (TRUE_STATE, CLOCK, JOINT_STATES, STATE, FORCE, STATUS):
        if topic not in skip:
            ledger.take(topic, k * TS)


def test_progress_is_the_oldest_newest_stamp_and_needs_every_sample_topic():
    ledger = RecordLedger(ALL)
    assert ledger.topics == (JOINT_STATES, TRUE_STATE, CLOCK, STATE, FORCE, STATUS)
    assert ledger.take('/cartpole/ekf/health', 0)   # not a sample topic: not booked
    one_sample(ledger, 0, skip=(STATUS,))
    assert ledger.progress_ns() is None               # no status yet
    ledger.take(STATUS, 0)
    assert ledger.progress_ns() == 0
    one_sample(ledger, 1, skip=(FORCE, STATUS))       # the manager has not answered sample 1
    assert ledger.progress_ns() == 0
    ledger.take(FORCE, TS)
    ledger.take(STATUS, TS)
    assert ledger.progress_ns() == TS


def test_lockstep_repeats_are_skipped_and_real_time_repeats_are_kept():
    lockstep = RecordLedger(ALL, skip_repeats=True)
    assert lockstep.take(TRUE_STATE, 0) and not lockstep.take(TRUE_STATE, 0)
    assert lockstep.repeats == 1
    assert lockstep.take(TRUE_STATE, TS)
    real_time = RecordLedger(ALL)
    assert real_time.take(FORCE, 0) and real_time.take(FORCE, 0)  # the stop's last zero force


def test_missed_messages_are_counted_by_stamp_from_what_implies_them():
    ledger = RecordLedger(ALL, horizon_ns=50 * TS)
    for k in range(400):
        if k == 100:
            one_sample(ledger, k, skip=(STATE,))              # estimate missed: 1
        elif k == 200:
            one_sample(ledger, k, skip=(JOINT_STATES, TRUE_STATE))  # sample and truth: 2
        elif k == 300:
            one_sample(ledger, k, skip=(FORCE, STATUS, STATE))  # the EKF dropped it: not a miss
        else:
            one_sample(ledger, k)
    assert ledger.missed == 3        # settled once 50 samples older than the newest
    ledger.take(FORCE, 400 * TS)     # the newest stamp: its estimate may be on its way
    ledger.take(STATUS, 401 * TS)
    ledger.take(STATE, 401 * TS)
    assert ledger.finish() == 3 + 1  # status 401 implies its force command


def test_a_topic_nobody_publishes_is_not_missed():
    """On the rig no ground truth is published, although the recorder subscribes it."""
    ledger = RecordLedger(ALL, horizon_ns=0)
    for k in range(100):
        ledger.take(JOINT_STATES, k * TS)
        ledger.take(STATE, k * TS)
    assert ledger.finish() == 0


def test_messages_before_their_publisher_was_discovered_are_counted_apart():
    """A real-time recorder in its own process finds the estimate's publisher before the
    plant's: the first samples the estimates imply are missed at the start, not later."""
    ledger = RecordLedger(ALL, horizon_ns=0)
    for k in range(100):
        one_sample(ledger, k, skip=(JOINT_STATES, TRUE_STATE, CLOCK) if k < 30 else ())
    one_sample(ledger, 100, skip=(JOINT_STATES,))          # a sample lost later: a miss
    one_sample(ledger, 101)
    assert ledger.finish() == 1
    assert ledger.missed_at_start == 30                    # 30 estimates imply their sample
