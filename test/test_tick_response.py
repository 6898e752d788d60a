"""One pendulum encoder tick's effect on the force command (docs/controllers.md, "lqg"), with the
thesis's settings, the earlier default, the robust gain and today's precise one: the thesis's
filter and feedforward turn it into more than 10 N at once, the defaults into about 1 N; the
precise gain's heavier angle weight costs a larger peak, still a third of the thesis's."""
from cartpole_analysis.analysis.tick_response import THESIS_SETTINGS, tick_response


def test_one_tick_moves_the_default_command_by_a_tenth_of_what_the_thesis_settings_did():
    thesis, before, robust, default = (tick_response(*v) for v in THESIS_SETTINGS.values())
    for old in (thesis, before):
        assert abs(old.first_n) > 10.0 and old.feedforward_n > 3.0   # (6.12) flips sign
        assert old.theta_dot_step > 0.015                            # 0.021 rad/s per tick
    assert abs(robust.first_n) < 2.0 and robust.peak_n < 3.0
    assert robust.peak_n < 0.25 * min(thesis.peak_n, before.peak_n)
    assert abs(default.first_n) < 2.0 and robust.peak_n < default.peak_n < 4.5
    assert default.peak_n < 0.35 * min(thesis.peak_n, before.peak_n)
    assert robust.theta_dot_step < 0.005 and default.theta_dot_step < 0.005
