"""The window of evenly spaced encoder samples both on-line estimates weigh."""
import pytest

from cartpole_control.position_window import MAX_FILLED, PositionWindow

TS = 0.005


def test_a_lost_sample_is_filled_in_on_the_line_between_its_neighbours():
    w = PositionWindow(TS, half_window=2, every=1)
    for k in (0, 1, 2, 4):                      # sample 3 lost
        w.push(k * TS, 0.1 * k, 3.0 - k)
    assert w.t == pytest.approx([0.0, 0.005, 0.010, 0.015, 0.020])
    assert w.x == pytest.approx([0.0, 0.1, 0.2, 0.3, 0.4])
    assert w.theta == pytest.approx([3.0, 2.0, 1.0, 0.0, -1.0])
    assert w.step == pytest.approx(TS)


def test_a_window_due_at_a_filled_in_sample_is_reported_at_the_next_real_one():
    w = PositionWindow(TS, half_window=2, every=5)
    due = [w.push(k * TS, 0.0, 0.0) for k in (0, 1, 2, 3)]
    assert not any(due)
    assert w.push(5 * TS, 0.0, 0.0)             # sample 4 (due) lost, filled in


def test_a_longer_gap_or_time_going_back_starts_afresh():
    w = PositionWindow(TS, half_window=2, every=1)
    for k in range(5):
        w.push(k * TS, 0.0, 0.0)
    w.push((4 + MAX_FILLED + 2) * TS, 0.0, 0.0)  # MAX_FILLED + 1 lost in a row
    assert len(w.t) == 1
    w.push(w.t[-1] - TS, 0.0, 0.0)              # time went back
    assert len(w.t) == 1
