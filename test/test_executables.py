"""Every installed executable starts from install/<pkg>/lib/<pkg>/ (where `ros2 run` looks) and
stops cleanly on SIGINT: exit code 0, no traceback.

A node counts as started when the test process sees it in the ROS graph (real DDS
discovery between processes), not after a sleep.
"""
import os
import signal
import subprocess
from pathlib import Path

import pytest
from ament_index_python.packages import get_package_prefix

from cartpole_core.child_process import reap

pytestmark = pytest.mark.ros

NODES = [
    ('cartpole_sim', 'sim_node', [], 'sim'),
    ('cartpole_estimation', 'ekf_node', [], 'ekf'),
    ('cartpole_control', 'controller_manager', [], 'controller_manager'),
    ('cartpole_hw', 'hw_bridge', ['-p', 'port:=/dev/null/no-such-port'], 'hw_bridge'),
    ('cartpole_bringup', 'cartpole_recorder', ['-p', 'output:={tmp}/bag'], 'recorder'),
    ('cartpole_analysis', 'cartpole_viewer', ['-p', 'port:=0'], 'viewer'),
]


def executable(package, name):
    path = Path(get_package_prefix(package)) / 'lib' / package / name
    assert path.is_file() and os.access(path, os.X_OK), f'{path} is not an installed executable'
    return path


@pytest.mark.parametrize('package,name,ros_args,node_name', NODES, ids=[n[1] for n in NODES])
def test_node_executable_starts_and_stops_on_sigint(package, name, ros_args, node_name,
                                                    ros_context, spin_until, tmp_path):
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    args = [a.format(tmp=tmp_path) for a in ros_args]
    cmd = [str(executable(package, name))] + (['--ros-args'] + args if args else [])
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    observer = rclpy.create_node('executable_observer', context=ros_context)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(observer)
    try:
        seen = spin_until(executor, lambda: node_name in observer.get_node_names()
                          or proc.poll() is not None, timeout=60.0)
        assert seen and proc.poll() is None, \
            f'{name} did not appear in the graph; exit {proc.poll()}'
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=30)
        assert proc.returncode == 0, f'{name} exited {proc.returncode}: {err[-2000:]}'
        assert 'Traceback' not in err, err[-2000:]
    finally:
        reap(proc)
        executor.shutdown()
        observer.destroy_node()


@pytest.mark.parametrize('argv', [['--help'], ['offline', '--help'], ['run', '--help'],
                                  ['analyze', '--help'], ['bench', '--help'], ['bound', '--help'],
                                  ['identify', '--help'], ['emulate', '--help']])
def test_cartpole_command_answers(argv):
    out = subprocess.run([str(executable('cartpole_bringup', 'cartpole'))] + argv,
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert 'usage' in out.stdout.lower()
