"""The template third-party plugin (docs/examples/cartpole_pole_placement), as a lab uses it.

It is built and installed with colcon into a temporary prefix, as a package of
the lab's own workspace, and used from a process that has sourced that
prefix's ``local_setup.bash`` on top of this workspace: the registry finds it
through its entry point, the controller manager lists it and its gains,
switches to it by the ``stabilizer`` parameter, and it balances the pendulum
in the offline closed loop (plant, quantised encoders, EKF, manager). Its own
tests pass against the installed package.
"""
import json
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow

EXAMPLE = Path(__file__).resolve().parents[1] / 'docs' / 'examples' / 'cartpole_pole_placement'

USE = textwrap.dedent('''
    import json, math
    from cartpole_bringup.offline.closed_loop import run_closed_loop
    from cartpole_control.controller import STABILIZER, ControllerState
    from cartpole_control.manager import ControllerManager
    from cartpole_control.registry import load_controllers
    from cartpole_core.model import CartPoleParameters

    p = CartPoleParameters()
    found = load_controllers(STABILIZER)
    manager = ControllerManager(p)
    specs = manager.parameter_specs()
    # Stabilising with lqg, then switched by the parameter (what ros2 param set calls).
    upright = ControllerState(0.0, p.x_middle + 0.01, 0.02, 0.0, 0.0)
    first = manager.update(upright)
    refused = manager.set_parameters({'pole_placement.poles': [-2.0, -2.0, -12.0, -16.0]})
    switched = manager.set_parameters({'stabilizer': 'pole_placement'})
    later = ControllerState(p.sample_time, p.x_middle + 0.01, 0.02, 0.0, 0.0)
    out = manager.update(later)
    gain = manager.active_plugins()[STABILIZER].gain
    law = -(gain[0] * 0.01 + gain[1] * 0.02)
    run = run_closed_loop(p, duration=20.0, manager_parameters={'stabilizer': 'pole_placement'})
    print(json.dumps({
        'module': found['pole_placement'].__module__ if 'pole_placement' in found else None,
        'choices': list(specs['stabilizer'].choices), 'has_poles': 'pole_placement.poles' in specs,
        'first': [first.mode, first.stabilizer], 'refused': refused.successful,
        'refusal': refused.reason, 'switched': switched.successful,
        'after': [out.mode, out.stabilizer, out.event, out.raw_force, law],
        'summary': run.summary, 'x_min': float(run.x.min()), 'x_max': float(run.x.max()),
        'theta_end': [float(math.remainder(th, 2 * math.pi)) for th in run.theta[-400:]],
    }))
''')


def test_the_example_plugin_builds_installs_is_found_switched_to_and_balances(tmp_path):
    colcon = shutil.which('colcon')
    assert colcon, 'colcon is on the PATH of the workspace environment (env.sh)'
    source = tmp_path / 'src' / EXAMPLE.name
    shutil.copytree(EXAMPLE, source, ignore=shutil.ignore_patterns('build', '*.egg-info',
                                                                  '__pycache__'))
    build = subprocess.run(
        [colcon, '--log-base', str(tmp_path / 'log'), 'build', '--base-paths', str(tmp_path / 'src'),
         '--build-base', str(tmp_path / 'build'), '--install-base', str(tmp_path / 'install'),
         '--event-handlers', 'console_cohesion-', 'summary-', 'status-'],
        cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert build.returncode == 0, build.stdout[-3000:] + build.stderr[-3000:]
    setup = tmp_path / 'install' / 'local_setup.bash'
    assert setup.is_file()

    def in_prefix(command):
        return subprocess.run(['bash', '-c', f'source {setup} && {command}'], cwd=tmp_path,
                              capture_output=True, text=True, timeout=600,
                              env={**os.environ, 'PYTHONDONTWRITEBYTECODE': '1'})

    own = in_prefix(f'{sys.executable} -m pytest -q -p no:cacheprovider {source / "test"}')
    assert own.returncode == 0 and '3 passed' in own.stdout, own.stdout[-3000:] + own.stderr

    script = tmp_path / 'use_the_plugin.py'
    script.write_text(USE)
    used = in_prefix(f'{sys.executable} {script}')
    assert used.returncode == 0, used.stderr[-3000:]
    r = json.loads(used.stdout.strip().splitlines()[-1])
    installed = tmp_path / 'install' / 'cartpole_pole_placement'
    assert r['module'] == 'cartpole_pole_placement.pole_placement'
    import cartpole_control  # noqa: F401 - the module this process sees is not the example's
    assert 'cartpole_pole_placement' not in sys.modules and installed.is_dir()
    assert {'lqg', 'pid', 'smc', 'pole_placement'} <= set(r['choices']) and r['has_poles']
    assert r['first'] == ['stabilizing', 'lqg']
    assert not r['refused'] and 'distinct' in r['refusal']
    assert r['switched']
    mode, stabilizer, event, raw_force, law = r['after']
    assert (mode, stabilizer, event) == ('stabilizing', 'pole_placement',
                                         'switch:stabilizer=pole_placement')
    assert raw_force == pytest.approx(law, rel=1e-12)
    s = r['summary']
    assert s['success'] and s['catch_time_s'] is not None and not s['end_stop_contact']
    assert -1e-6 <= r['x_min'] and r['x_max'] <= 0.769 + 1e-6   # never into a stop (it starts at 0)
    assert max(abs(th) for th in r['theta_end']) < 0.05   # the last 2 s: upright within 3 deg
