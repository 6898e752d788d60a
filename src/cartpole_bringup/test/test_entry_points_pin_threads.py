"""Every executable of the workspace pins the numerical libraries to one thread before numpy
loads (cartpole_core.realtime.pin_numerical_threads, run by each package's __init__): a BLAS
thread pool competing with the loop on a small machine turned a 0.6 ms Riccati solve into
16 ms (docs/benchmarks.md, loop latency)."""
import os
import subprocess
import sys
import textwrap
from importlib.metadata import entry_points

import pytest

from cartpole_core import realtime

PACKAGES = ('cartpole_analysis', 'cartpole_bringup', 'cartpole_control', 'cartpole_core',
            'cartpole_emulator', 'cartpole_estimation', 'cartpole_hw', 'cartpole_sim', 'cartpole_tools')
SCRIPTS = sorted({(ep.name, ep.value.split(':')[0]) for ep in entry_points(group='console_scripts')
                  if ep.value.split('.')[0] in PACKAGES})


def test_every_package_has_its_executables_listed():
    modules = {module for _, module in SCRIPTS}
    assert {'cartpole_bringup.cli', 'cartpole_control.manager_node',
            'cartpole_estimation.ekf_node', 'cartpole_hw.hw_node', 'cartpole_emulator.emulator',
            'cartpole_sim.sim_node', 'cartpole_analysis.viewer.node',
            'cartpole_bringup.graph.recorder'} <= modules


def test_no_generic_name_on_the_path():
    """The nodes keep their ``ros2 run`` names; every other executable is ``cartpole*``."""
    node_names = {'sim_node', 'ekf_node', 'controller_manager', 'hw_bridge'}
    generic = [name for name, _ in SCRIPTS if name not in node_names and not name.startswith('cartpole')]
    assert not generic


def threads_after_import(module, **env_update):
    """(OPENBLAS_NUM_THREADS, OMP_NUM_THREADS, thread count) after importing ``module`` as its
    console script does (package first), then numpy and a BLAS call."""
    env = {k: v for k, v in os.environ.items() if k not in realtime.NUMERICAL_THREAD_VARIABLES}
    env.update(env_update)
    code = textwrap.dedent(f'''
        import os, importlib
        importlib.import_module({module!r})
        import numpy as np
        a = np.random.default_rng(0).standard_normal((300, 300))
        a @ a                                   # a BLAS call that would start the pool
        print(os.environ['OPENBLAS_NUM_THREADS'], os.environ['OMP_NUM_THREADS'],
              len(os.listdir('/proc/self/task')))
    ''')
    result = subprocess.run([sys.executable, '-c', code], env=env, capture_output=True,
                            text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    blas, omp, threads = result.stdout.split()[-3:]
    return blas, omp, int(threads)


@pytest.mark.parametrize('name, module', SCRIPTS)
def test_an_executable_pins_blas_before_numpy_loads(name, module):
    assert threads_after_import(module)[:2] == ('1', '1'), name


@pytest.mark.skipif((os.cpu_count() or 1) < 2, reason='one core: no BLAS pool to start')
def test_the_pinning_is_what_keeps_the_blas_pool_away():
    """The check above can fail: unpinned, the same import and call start OpenBLAS's pool."""
    module = 'cartpole_control.manager_node'
    cores = str(os.cpu_count())
    pinned = threads_after_import(module)[2]
    unpinned = threads_after_import(module, OPENBLAS_NUM_THREADS=cores, OMP_NUM_THREADS=cores)
    assert unpinned[:2] == (cores, cores) and unpinned[2] > pinned
