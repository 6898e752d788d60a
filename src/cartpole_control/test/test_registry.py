"""The registry's skip paths, with fake distributions on ``sys.path``.

Each fake is a real installed distribution as ``importlib.metadata`` sees one
(a ``*.dist-info`` directory with ``METADATA`` and ``entry_points.txt``) next
to its module: what ``pip install`` of a third-party plugin leaves behind.
"""
import importlib
import logging
import sys

import pytest
from manager_test_support import fake_distribution

from cartpole_control import registry
from cartpole_control.controller import STABILIZER, SWINGUP

GOOD = '''
from cartpole_control.controller import STABILIZER, Controller

class {cls}(Controller):
    kind, name = STABILIZER, {name!r}
    {extra}
    def update(self, state):
        return 0.0
'''


@pytest.fixture
def site(tmp_path, monkeypatch):
    """A function that installs a fake distribution into its own directory on sys.path."""
    added = []
    monkeypatch.setattr(sys, 'path', list(sys.path))  # restored after the test

    def install(dist, version, module, source, entry_points):
        root = tmp_path / dist
        fake_distribution(root, dist, version, module, source, entry_points)
        sys.path.insert(len(added), str(root))  # after the fakes before it, before the rest
        added.append(module)
        importlib.invalidate_caches()

    yield install
    for module in added:
        sys.modules.pop(module, None)


def load(caplog):
    with caplog.at_level(logging.WARNING, logger=registry.__name__):
        return registry.load_controllers(STABILIZER)


def the_warning(caplog):
    """The one record logged, a warning; its message."""
    [record] = caplog.records
    assert record.levelno == logging.WARNING
    return record.getMessage()


def stabilizer(site, dist, version, cls, name):
    """Install a good stabiliser class ``cls`` named ``name`` in module ``<dist>`` (underscored)."""
    module = dist.replace('-', '_')
    site(dist, version, module, GOOD.format(cls=cls, name=name, extra=''),
         [(name, f'{module}:{cls}')])


def test_a_good_third_party_plugin_is_found_next_to_the_installed_ones(site, caplog):
    stabilizer(site, 'fake-good', '1.0', 'Mine', 'mine')
    found = load(caplog)
    assert found['mine'].__module__ == 'fake_good'
    assert {'lqg', 'pid', 'smc'} <= set(found) and not caplog.records


@pytest.mark.parametrize('case, source, value, reason', [
    ('broken import', 'import no_such_module_anywhere\n', 'fake_bad:Mine',
     "ModuleNotFoundError: No module named 'no_such_module_anywhere'"),
    ('missing class', 'X = 1\n', 'fake_bad:Mine', "has no attribute 'Mine'"),
    ('not a controller', 'class Mine:\n    name = "mine"\n', 'fake_bad:Mine',
     'fake_bad:Mine is not a Controller subclass'),
    ('wrong API version', GOOD.format(cls='Mine', name='mine', extra='api_version = 1'),
     'fake_bad:Mine', 'written for controller API 1, this is 2'),
    ('wrong kind', GOOD.format(cls='Mine', name='mine', extra=f'kind = {SWINGUP!r}'),
     'fake_bad:Mine', "declared kind 'swingup' in group 'cartpole_control.stabilizer'"),
    ('entry point name is not the class name', GOOD.format(cls='Mine', name='other', extra=''),
     'fake_bad:Mine', "entry point name 'mine' is not the class's name 'other'"),
    ('overrides activate', GOOD.format(cls='Mine', name='mine',
                                       extra='def activate(self, state):\n        pass\n'),
     'fake_bad:Mine', 'TypeError: fake_bad.Mine overrides activate(); override on_activate()'),
])
def test_an_unusable_plugin_is_skipped_with_a_warning_naming_it_and_its_distribution(
        site, caplog, case, source, value, reason):
    site('fake-bad', '0.3', 'fake_bad', source, [('mine', value)])
    found = load(caplog)
    assert 'mine' not in found, case
    assert {'lqg', 'pid', 'smc'} <= set(found)  # the installed ones are unaffected
    message = the_warning(caplog)
    assert message.startswith(f'skipping controller plugin mine ({value}) from fake-bad 0.3: ')
    assert reason in message, message


def test_a_duplicate_name_uses_the_first_on_the_path_and_the_warning_names_both(site, caplog):
    stabilizer(site, 'fake-twin-a', '1.0', 'TwinA', 'twin')
    stabilizer(site, 'fake-twin-b', '2.5', 'TwinB', 'twin')
    assert load(caplog)['twin'].__module__ == 'fake_twin_a'
    message = the_warning(caplog)
    assert 'skipping controller plugin twin (fake_twin_b:TwinB) from fake-twin-b 2.5' in message
    assert 'taken by TwinA from fake-twin-a 1.0, which is used' in message
    assert 'fake_twin_b' not in sys.modules  # the loser is not even imported


def test_a_duplicate_of_an_installed_name_names_both_distributions(site, caplog):
    # The fake comes first on sys.path, so it is the one used; the installed pid is skipped.
    stabilizer(site, 'fake-pid', '9.9', 'OtherPid', 'pid')
    assert load(caplog)['pid'].__qualname__ == 'OtherPid'
    message = the_warning(caplog)
    assert 'skipping controller plugin pid (cartpole_control.controllers.pid:PidStabilizer) ' \
           'from cartpole' in message
    assert 'taken by OtherPid from fake-pid 9.9' in message
