"""Test plugins and helpers shared by the ControllerManager tests (test_manager*.py), and the
swing-up gains of the thesis that the closed-loop tests pin (``THESIS_INTEGRAL``)."""
import math
import textwrap

from cartpole_control.controller import STABILIZER, SWINGUP, Controller, ControllerState, \
    ParameterSpec
from cartpole_control.manager import ControllerManager
from cartpole_core.model import CartPoleParameters

P = CartPoleParameters()
TS = P.sample_time

THESIS_INTEGRAL = {'pendulum_energy.i_band': 1000.0, 'pendulum_energy.k_i': 0.02}
"""Manager parameters for the energy integral of (7.32) as the thesis has it (integrating at
every energy, k_i 0.02): the swing-up the closed-loop tests that pin it were found with."""


# -- test plugins --------------------------------------------------------------------------
class Recording(Controller):
    """Returns the gain ``force``; records its lifecycle calls."""

    parameters = (ParameterSpec('force', 0.0, 'constant force [N]', low=-100.0, high=100.0),
                  ParameterSpec('limit', 100.0, 'refuse |force| above this', low=0.0, high=100.0))

    running_state = ('steps',)
    built = 0
    """Instances of any test plugin constructed (class-wide)."""
    configured = 0
    """on_configure calls of any test plugin (class-wide)."""

    def __init__(self):
        super().__init__()
        Recording.built += 1
        self.calls = []
        self.hook = None
        self.standby_error = None
        self.steps = 0
        """Updates since activation: the running state a take-over hands on."""

    def on_configure(self):
        Recording.configured += 1
        if abs(self.gains['force']) > self.gains['limit']:
            raise ValueError(f"force {self.gains['force']} exceeds limit {self.gains['limit']}")

    def on_activate(self, state):
        self.steps = 0
        self.calls.append(('activate', state.t))

    def on_deactivate(self):
        self.calls.append(('deactivate',))

    def standby(self):
        self.calls.append(('standby',))
        if self.standby_error is not None:
            raise self.standby_error

    def update(self, state):
        self.calls.append(('update', state.t))
        self.steps += 1
        if self.hook is not None:
            self.hook(state)
        return self.gains['force']


class Listening(Recording):
    """Records what the manager reports about its command (the anti-windup hook)."""

    kind, name = STABILIZER, 'listening'

    def command_applied(self, feedback):
        self.calls.append(('feedback', feedback))


class Deaf(Listening):
    kind, name = STABILIZER, 'deaf'

    def command_applied(self, feedback):
        raise RuntimeError('bad hook')


class PushA(Recording):
    kind, name = SWINGUP, 'push_a'


class PushB(Recording):
    kind, name = SWINGUP, 'push_b'


class HoldA(Recording):
    kind, name = STABILIZER, 'hold_a'


class HoldB(Recording):
    kind, name = STABILIZER, 'hold_b'


class Broken(Recording):
    kind, name = STABILIZER, 'broken'

    def update(self, state):
        raise RuntimeError('division by zero in the law')


REGISTRY = {SWINGUP: {'push_a': PushA, 'push_b': PushB},
            STABILIZER: {'hold_a': HoldA, 'hold_b': HoldB, 'broken': Broken,
                         'listening': Listening, 'deaf': Deaf}}


def make(**params):
    params.setdefault('stabilizer', 'hold_a')
    # No plant here reports the actuator's motion, so its dead time is never measured: no
    # prior for it either (the guard's envelope and the catch region as on a known actuator).
    params.setdefault('rail.actuator_dead_time', 0.0)
    return ControllerManager(P, TS, registry=REGISTRY, **params)


def state(t=0.0, x=None, theta=math.pi, x_dot=0.0, theta_dot=0.0):
    return ControllerState(t, P.x_middle if x is None else x, theta, x_dot, theta_dot)


def upright(t=0.0, theta=0.05, **kw):
    return state(t, theta=theta, **kw)


def plugin(manager, kind):
    return manager.active_plugins()[kind]


# -- fake installed plugin distributions ------------------------------------------------------
def fake_distribution(root, dist, version, module, source, entry_points):
    """Install the distribution ``dist`` with one module and its entry points under ``root``."""
    root.mkdir(parents=True, exist_ok=True)
    (root / f'{module}.py').write_text(textwrap.dedent(source))
    info = root / f"{dist.replace('-', '_')}-{version}.dist-info"  # as pip names it
    info.mkdir()
    (info / 'METADATA').write_text(f'Metadata-Version: 2.1\nName: {dist}\nVersion: {version}\n')
    lines = ''.join(f'{name} = {value}\n' for name, value in entry_points)
    (info / 'entry_points.txt').write_text(f'[cartpole_control.stabilizer]\n{lines}')
