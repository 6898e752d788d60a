"""The mpc solve-time benchmark: it counts the MPC's cycles after the catch, and by default
starts each cycle on the 5 ms sample clock as the controller manager does."""
from cartpole_tools.bench import mpc_solve


def test_the_cycles_are_paced_on_the_sample_clock_unless_flat_out(monkeypatch):
    clock = {'now': 0.0}
    waits = []

    def perf_counter():  # each reading 0.5 ms later: a cycle takes a few ms of the 5
        clock['now'] += 0.0005
        return clock['now']

    def sleep(seconds):
        waits.append(seconds)
        clock['now'] += seconds
    monkeypatch.setattr(mpc_solve.time, 'perf_counter', perf_counter)
    monkeypatch.setattr(mpc_solve.time, 'sleep', sleep)
    paced = mpc_solve.solve_times({'mpc.budget_us': 1e6}, duration=3.2, pushes=())
    assert paced['paced'] and len(waits) > 500
    assert all(0.0 < w <= 0.005 for w in waits)
    assert paced['cycles'] > 0 and paced['balanced'] and paced['fallbacks'] == 0
    assert 'paced' in mpc_solve.table([{'solver': 'daqp', 'horizon': 200, **paced}])


def test_flat_out_never_sleeps(monkeypatch):
    monkeypatch.setattr(mpc_solve.time, 'sleep', lambda s: (_ for _ in ()).throw(AssertionError))
    result = mpc_solve.solve_times({'mpc.budget_us': 1e6}, duration=3.2, pushes=(), paced=False)
    assert not result['paced'] and result['cycles'] > 0
    assert 'flat out' in mpc_solve.table([{'solver': 'daqp', 'horizon': 200, **result}])
