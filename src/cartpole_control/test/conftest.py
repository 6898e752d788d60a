"""Makes this folder's helper modules (``manager_test_support``) importable by its tests.

pytest runs with ``--import-mode=importlib`` (pytest.ini), which does not put a
test's folder on ``sys.path``; the helpers are one module, imported once, so the
ControllerManager test files share its test plugins.
"""
import sys
from pathlib import Path

_HERE = str(Path(__file__).resolve().parent)
if _HERE not in sys.path:
    sys.path.insert(0, _HERE)
