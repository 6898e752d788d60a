"""The documentation site builds from docs/ with warnings as errors (what `make docs` runs), and
its pages are there: the five tutorials, the generated reference, the API from the docstrings."""
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

pytestmark = pytest.mark.slow


def test_the_site_builds_without_a_warning(tmp_path):
    out = tmp_path / 'html'
    result = subprocess.run([sys.executable, '-m', 'sphinx', '-W', '--keep-going', '-q', '-b', 'html',
                             str(ROOT / 'docs'), str(out), '-d', str(tmp_path / 'doctrees')],
                            capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr[-4000:]
    for page in ('index', 'tutorials/first-run', 'tutorials/switch-controllers',
                 'tutorials/record-and-analyse', 'tutorials/write-a-plugin',
                 'tutorials/connect-your-rig', 'reference/cli', 'reference/parameters',
                 'reference/nodes', 'reference/summary', 'reference/api/cartpole_control'):
        assert (out / f'{page}.html').is_file(), page
    api = (out / 'reference' / 'api' / 'cartpole_core.html').read_text(encoding='utf-8')
    assert 'CartPoleParameters' in api and '(4.34)' in api   # the model, cited by its equation
    parameters = (out / 'reference' / 'parameters.html').read_text(encoding='utf-8')
    assert 'lqg.q' in parameters and 'state_timeout' in parameters
