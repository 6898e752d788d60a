"""Control-cycle compute time under parameter changes (docs/architecture.md: "the cycle only swaps").

    python docs/bench/swaps/measure.py graph [--duration S]   # the real-time graph
    python docs/bench/swaps/measure.py direct                 # ControllerManager in-process

``graph``: starts ``cartpole run --sim --duration S`` (real time, one process,
default 70 s), waits for the first controller status, then makes the 20
changes of :data:`CHANGES` through the controller manager's
``set_parameters`` service (what ``ros2 param set`` calls), one every 3 s,
and prints one JSON object: the status's ``max_cycle_compute_s`` at the end
(the longest control cycle since start), the largest ``cycle_compute_s`` of
the cycles that applied a change (an event ``switch:...``, or the first
status after a gain change), the refused changes, and the load average.

``direct``: the same 20 changes on a :class:`ControllerManager` driven by the
simulated plant in this process (no ROS), each ``update`` timed with
``time.perf_counter``; works on any commit (the "before" figure of main,
where the status has no compute time). ``--blas-default`` unsets the
one-thread pinning of the numerical libraries first (the default BLAS
threading of an unpinned process).

Needs ``source env.sh`` and a free ROS_DOMAIN_ID (graph); wall-clock figures:
run it under ``flock /work/wt/rt.lock``.
"""
import json
import os
import sys

if '--blas-default' in sys.argv:  # before numpy loads anywhere
    for name in ('OMP_NUM_THREADS', 'OPENBLAS_NUM_THREADS', 'MKL_NUM_THREADS',
                 'BLIS_NUM_THREADS', 'VECLIB_MAXIMUM_THREADS', 'NUMEXPR_NUM_THREADS'):
        os.environ[name] = str(os.cpu_count() or 1)

import subprocess  # noqa: E402
import time  # noqa: E402

Q_THESIS = [100.0, 400.0, 100.0, 400.0]
Q_DEFAULT = [10.0, 10000.0, 10.0, 1.0, 400.0]
POLES_THESIS = [-1.0, 0.0, -4.0, 2.4, -4.0, -2.4]
POLES_DEFAULT = [-1.0, 0.0, -4.0, 2.4, -4.0, -2.4, -1.0, 0.0]
CHANGES = [
    {'lqg.r': 0.02}, {'lqg.q': Q_THESIS}, {'stabilizer': 'smc'}, {'smc.poles': POLES_THESIS},
    {'swingup': 'time_optimal'}, {'stabilizer': 'pid'}, {'swingup': 'pendulum_energy'},
    {'lqg.q': Q_DEFAULT}, {'stabilizer': 'lqg'}, {'swingup': 'time_optimal'},
    {'time_optimal.r': 0.03}, {'lqg.r': 0.01}, {'swingup': 'full_energy'},
    {'smc.poles': POLES_DEFAULT}, {'stabilizer': 'smc'}, {'swingup': 'time_optimal'},
    {'stabilizer': 'lqg'}, {'feedforward.steepness': 30.0}, {'swingup': 'energy_saturated'},
    {'swingup': 'pendulum_energy'},
]
"""20 changes: 10 switches (3 of them to time_optimal, 3 away from it) and 10 gain changes."""
PERIOD = 3.0


def load():
    return open('/proc/loadavg').read().split()[:3]


def direct():
    from cartpole_control.manager import ControllerManager
    from cartpole_control.controller import ControllerState
    from cartpole_core.model import CartPoleParameters
    from cartpole_sim.plant import Plant, Scenario
    params = CartPoleParameters()
    manager = ControllerManager(params, params.sample_time)
    plant = Plant(params, Scenario())
    ts = params.sample_time
    per_change, cycles, longest, longest_at, force = [], [], 0.0, None, 0.0
    steps_between = int(PERIOD / ts)
    for k in range(steps_between * (len(CHANGES) + 1)):
        if k % steps_between == 0 and 0 < k // steps_between <= len(CHANGES):
            change = CHANGES[k // steps_between - 1]
            started = time.perf_counter()
            result = manager.set_parameters(change)
            outside = time.perf_counter() - started
            if not result.successful:
                raise SystemExit(f'refused {change}: {result.reason}')
            pending = change
        else:
            pending = None
        x = plant.state  # the true state stands in for the estimate
        state = ControllerState(plant.t, x[0], x[1], x[2], x[3])
        started = time.perf_counter()
        out = manager.update(state)
        compute = time.perf_counter() - started
        if compute > longest:
            longest, longest_at = compute, {'t': plant.t, 'mode': out.mode, 'event': out.event,
                                            'swingup_law': out.swingup_law}
        cycles.append(compute)
        if pending is not None:
            per_change.append({'change': pending, 'cycle_s': compute, 'set_s': outside,
                               'event': out.event})
        force = out.force
        plant.step(force)
    cycles.sort()
    return {'mode': 'direct', 'max_cycle_s': longest, 'max_cycle_at': longest_at,
            'p999_cycle_s': cycles[int(0.999 * len(cycles))], 'cycles': len(cycles),
            'max_change_cycle_s': max(c['cycle_s'] for c in per_change),
            'changes': per_change, 'load': load(),
            'blas': os.environ.get('OPENBLAS_NUM_THREADS')}


def graph(duration):
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from rcl_interfaces.srv import SetParameters
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter
    run = subprocess.Popen(['cartpole', 'run', '--sim', '--duration', str(duration)],
                           stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    context = Context()
    rclpy.init(context=context)
    node = rclpy.create_node('swap_bench', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    statuses = []
    node.create_subscription(DiagnosticArray, '/cartpole/controller_status',
                             lambda msg: statuses.append(
                                 {kv.key: kv.value for kv in msg.status[0].values}), 1000)
    client = node.create_client(SetParameters, '/controller_manager/set_parameters')
    refused, marks = [], []
    try:
        deadline = time.monotonic() + 60.0
        while not statuses and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.1)
        if not statuses:
            raise SystemExit('no controller status within 60 s')
        for change in CHANGES:
            until = time.monotonic() + PERIOD
            while time.monotonic() < until:
                executor.spin_once(timeout_sec=0.05)
            request = SetParameters.Request(parameters=[
                Parameter(k, value=v).to_parameter_msg() for k, v in change.items()])
            marks.append(len(statuses))
            future = client.call_async(request)
            executor.spin_until_future_complete(future, timeout_sec=10.0)
            answer = future.result()
            if answer is None or not all(r.successful for r in answer.results):
                refused.append({'change': change, 'reason': answer and [
                    r.reason for r in answer.results]})
        until = time.monotonic() + 1.0
        while time.monotonic() < until:
            executor.spin_once(timeout_sec=0.05)
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
        run.send_signal(2)
        tail = run.communicate(timeout=60)[0]
    change_cycles = []
    for mark in marks:  # the first cycles after each request: the swap is among them
        window = statuses[mark:mark + 10]
        if window:
            change_cycles.append(max(float(s['cycle_compute_s']) for s in window))
    last = statuses[-1]
    top = sorted(range(len(statuses)), key=lambda i: -float(statuses[i]['cycle_compute_s']))[:5]
    longest_cycles = [{'cycle_s': float(statuses[i]['cycle_compute_s']),
                       'state_stamp': float(statuses[i]['state_stamp']),
                       'mode': statuses[i]['mode'], 'event': statuses[i]['event'],
                       'after_change': next((k for k, m in reversed(list(enumerate(marks)))
                                             if m <= i), None)} for i in top]
    return {'mode': 'graph', 'max_cycle_compute_s': float(last['max_cycle_compute_s']),
            'longest_cycle_gap_s': float(last['longest_cycle_gap_s']),
            'longest_cycle_gap_before_changes_s': float(
                statuses[marks[0] - 1]['longest_cycle_gap_s']),
            'max_cycle_compute_before_changes_s': float(
                statuses[marks[0] - 1]['max_cycle_compute_s']),
            'longest_cycles': longest_cycles,
            'max_change_cycle_s': max(change_cycles), 'change_cycles_s': change_cycles,
            'statuses': len(statuses), 'refused': refused,
            'switch_events': [s['event'] for s in statuses if 'switch' in s['event']],
            'load': load(), 'run_tail': tail.strip().splitlines()[-3:]}


def main():
    if len(sys.argv) > 1 and sys.argv[1] == 'graph':
        duration = float(sys.argv[sys.argv.index('--duration') + 1]) \
            if '--duration' in sys.argv else 70.0
        print(json.dumps(graph(duration)))
    else:
        print(json.dumps(direct()))


if __name__ == '__main__':
    main()
