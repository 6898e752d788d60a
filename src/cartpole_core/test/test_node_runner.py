"""``run_node``: a stop signal never interrupts a callback (a KeyboardInterrupt raised inside
``take_message`` becomes pybind11's "Unable to convert call argument" and kills the node
with a traceback)."""
import subprocess
import sys
import textwrap

import pytest

pytestmark = pytest.mark.ros

CHILD = textwrap.dedent('''
    import os, signal, sys
    from rclpy.node import Node
    from sensor_msgs.msg import JointState
    from cartpole_core.node_runner import run_node

    class Busy(Node):
        """Receives its own 200 Hz messages; the 20th callback signals the process and
        then keeps working, as a callback that is half-way through a message would."""

        def __init__(self):
            super().__init__('busy')
            self.pub = self.create_publisher(JointState, 'busy', 10)
            self.create_subscription(JointState, 'busy', self.on_msg, 10)
            self.create_timer(0.005, lambda: self.pub.publish(JointState(name=['cart'])))
            self.count = 0

        def on_msg(self, msg):
            self.count += 1
            if self.count == 20:
                os.kill(os.getpid(), signal.{sig})
                total = 0
                for i in range(200000):       # bytecodes to run the handler in
                    total += i
                print('callback finished', flush=True)

        def destroy_node(self):
            print('destroyed after', self.count, flush=True)
            super().destroy_node()

    run_node(Busy, name='busy')
    print('clean exit', flush=True)
''')


@pytest.mark.parametrize('sig', ['SIGINT', 'SIGTERM'])
def test_a_stop_signal_lets_the_callback_finish_then_shuts_down_cleanly(sig):
    result = subprocess.run([sys.executable, '-c', CHILD.replace('{sig}', sig)],
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr[-2000:]
    # Fast DDS logs to stdout too (e.g. a shared-memory port still locked by a killed
    # process elsewhere on the machine); the child's own lines are what matter.
    lines = [line for line in result.stdout.splitlines() if 'RTPS_' not in line]
    assert lines[0] == 'callback finished'
    assert lines[1].startswith('destroyed after') and lines[-1] == 'clean exit'
    assert 'Traceback' not in result.stderr and 'KeyboardInterrupt' not in result.stderr


SIMULATOR_MODULES = ('cartpole_sim.plant', 'cartpole_sim.sim_node', 'cartpole_sim.sim_runner',
                     'cartpole_sim.scenario', 'cartpole_sim.disturbance')


@pytest.mark.parametrize('node_module', ['cartpole_estimation.ekf_node',
                                         'cartpole_control.manager_node',
                                         'cartpole_hw.hw_node', 'cartpole_bringup.graph.recorder'])
def test_the_nodes_above_the_simulator_load_none_of_its_code(node_module):
    # The runner and the shared QoS come from cartpole_core.node_runner, the model from
    # cartpole_core.model; neither pulls in the plant or the simulator node.
    probe = (f'import sys, {node_module}; '
             f'print(sorted(m for m in sys.modules if m in {SIMULATOR_MODULES!r}))')
    result = subprocess.run([sys.executable, '-c', probe], capture_output=True, text=True,
                            timeout=60)
    assert result.returncode == 0, result.stderr[-2000:]
    assert result.stdout.strip().splitlines()[-1] == '[]'
    assert 'cartpole_core.node_runner' in subprocess.run(
        [sys.executable, '-c', f'import sys, {node_module}; print(list(sys.modules))'],
        capture_output=True, text=True, timeout=60).stdout
