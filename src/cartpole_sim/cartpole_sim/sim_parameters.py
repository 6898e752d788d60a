"""The parameters of the simulator node ``sim``: declared with their ranges, read into a scenario.

The start, the plant's uncertainties and the scenario's disturbances
(:mod:`cartpole_sim.scenario`) take effect at the next reset (``~/reset``); the
timeouts at once; ``lockstep`` and ``recorder_window`` are read-only
(docs/simulator.md, "The simulator node sim").
"""
from __future__ import annotations

import math
from pathlib import Path

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.node import Node

from cartpole_core.model import CartPoleParameters
from .plant import Scenario
from .scenario import DELAY_MAX, DROP_MAX, parse_push

SCENARIO_PARAMETERS = ('x0', 'theta0', 'x_dot0', 'theta_dot0', 'tip_mass', 'friction_scale',
                       'encoder_offset', 'noise', 'seed', 'plant_params_file',
                       'integration_step', 'cart_mass', 'delay', 'jitter', 'drop',
                       'force_noise', 'actuator_gain', 'actuator_tau', 'pushes')
"""Parameters that take effect at the next reset (service ``~/reset``)."""


def _float_range(low: float, high: float) -> list[FloatingPointRange]:
    return [FloatingPointRange(from_value=float(low), to_value=float(high), step=0.0)]


_START_PARAMETERS = (
    ('x0', 0.0, 'Initial cart position from the left end stop [m]; within the travel.',
     0.0, 10.0),
    ('theta0', math.pi, 'Initial pendulum angle [rad]; 0 upright, pi hanging.', -20.0, 20.0),
    ('x_dot0', 0.0, 'Initial cart velocity [m/s].', -5.0, 5.0),
    ('theta_dot0', 0.0, 'Initial pendulum angular velocity [rad/s].', -50.0, 50.0),
    ('tip_mass', 0.0, 'Tip mass of the plant [kg]; 0 keeps the nominal m_p (0.251 kg).',
     0.0, 10.0),
    ('friction_scale', 1.0, 'Multiplies every cart and pendulum friction coefficient.',
     0.0, 10.0),
    ('encoder_offset', 0.0, 'Pendulum angle minus pi when the encoders were reset [rad] '
     '(Appendix H); biases the measured angle.', -math.pi, math.pi),
)
"""The start and the plant's uncertainties: (name, default, description, low, high)."""

_DISTURBANCE_PARAMETERS = (
    ('cart_mass', 0.0, 'Equivalent cart mass of the plant [kg]; 0 keeps the nominal m_c '
     '(4.75 kg).', 0.0, 100.0),
    ('delay', 0.0, 'Sensor-to-actuator latency [s]: a command takes effect this long after '
     'the sample it was computed from (inside the hold).', 0.0, DELAY_MAX),
    ('jitter', 0.0, 'Extra latency per sample, uniform in [0, jitter] [s].', 0.0, DELAY_MAX),
    ('drop', 0.0, f'Probability in [0, {DROP_MAX:g}] that a sample is lost: not published on '
     '/joint_states (/cartpole/true_state and /clock still are); lockstep steps on at once '
     'with the held command.', 0.0, DROP_MAX),
    ('force_noise', 0.0, 'Std of Gaussian force noise on the cart [N], one draw per sample.',
     0.0, 100.0),
    ('actuator_gain', 1.0, 'Amplifier gain error: the current is this times the commanded '
     'one.', 0.0, 10.0),
    ('actuator_tau', 0.0, 'Time constant of an extra first-order amplifier lag [s]; 0 = none.',
     0.0, 1.0),
)
"""The scenario's disturbances (cartpole_sim.scenario): (name, default, description, low, high)."""


def load_plant_parameters(path: str) -> CartPoleParameters:
    """The nominal plant parameters: the thesis values, or a YAML file's."""
    if not path:
        return CartPoleParameters()
    if not Path(path).is_file():
        raise ValueError(f'plant_params_file {path!r} does not exist')
    try:
        return CartPoleParameters.from_yaml(path)
    except ValueError as error:
        raise ValueError(f'plant_params_file {path!r}: {error}') from error
    except Exception as error:  # unreadable or not YAML (yaml.YAMLError, OSError, ...)
        raise ValueError(f'plant_params_file {path!r} cannot be read: {error}') from error


def declare_sim_parameters(node: Node) -> None:
    """Declare every parameter of ``sim`` on ``node``."""
    declare = node.declare_parameter
    declare('lockstep', False, ParameterDescriptor(
        description='Lockstep: advance one Ts per force command echoing the sample stamp, '
                    'publish /clock; false: real time on a wall timer.', read_only=True))
    declare('lockstep_startup_wait', True, ParameterDescriptor(
        description='Lockstep: until the first matching command, re-publish sample 0 every '
                    '0.1 s wall and do not apply lockstep_timeout.', read_only=True))
    declare('recorder_window', 0, ParameterDescriptor(
        description='Lockstep: step past sample k only once the recorder holds every sample '
                    'topic up to sample k - recorder_window; 0 = do not wait for a recorder.',
        read_only=True, integer_range=[IntegerRange(from_value=0, to_value=90, step=1)]))
    declare('start_subscribers', 0, ParameterDescriptor(
        description='Hold the first sample until joint_states and cartpole/true_state '
                    'each have this many matched subscriptions (at most 5 s wall, then start '
                    'and warn), so a recorder has the run from its start and, in lockstep, '
                    'the run monitor knows the samples; 0 = start at once.',
        read_only=True, integer_range=[IntegerRange(from_value=0, to_value=64, step=1)]))
    declare('lockstep_timeout', 1.0, ParameterDescriptor(
        description='Lockstep: wall seconds to wait for the awaited command before stepping '
                    'with the held one [s]; takes effect at once.',
        floating_point_range=_float_range(0.001, 3600.0)))
    declare('command_timeout', 0.05, ParameterDescriptor(
        description='Watchdog: zero force when no command arrived for this much simulated '
                    'time [s]; takes effect at once.',
        floating_point_range=_float_range(0.0, 10.0)))
    _declare_ranged(node, _START_PARAMETERS)
    declare('noise', False, ParameterDescriptor(
        description='Add Gaussian measurement noise before quantisation.'))
    declare('seed', 0, ParameterDescriptor(
        description='Seed of the measurement noise.',
        integer_range=[IntegerRange(from_value=0, to_value=2**31 - 1, step=1)]))
    _declare_disturbances(node)
    declare('plant_params_file', '', ParameterDescriptor(
        description="YAML of CartPoleParameters (must exist and have the node's "
                    "sample_time); '' = the thesis values."))
    declare('integration_step', 0.001, ParameterDescriptor(
        description='RK4 step of the plant [s]; at most the sample time.',
        floating_point_range=_float_range(1e-5, 0.005)))

def _declare_ranged(node: Node, table) -> None:
    """Declare the float parameters of ``table``: (name, default, description, low, high)."""
    for name, default, description, low, high in table:
        node.declare_parameter(name, default, ParameterDescriptor(
            description=description, floating_point_range=_float_range(low, high)))

def _declare_disturbances(node: Node) -> None:
    """The scenario's disturbances (cartpole_sim.scenario), at the next reset like the rest."""
    declare = node.declare_parameter
    _declare_ranged(node, _DISTURBANCE_PARAMETERS)
    declare('pushes', '', ParameterDescriptor(
        description="Pushes 'T:TARGET:AMPLITUDE:WIDTH' separated by commas or spaces, "
                    "TARGET cart [N] or pendulum [N m]; '' = none."))

def scenario_from(values: dict) -> tuple[CartPoleParameters, Scenario]:
    """Nominal parameters and scenario from parameter values; ValueError if invalid."""
    params = load_plant_parameters(values['plant_params_file'])
    x0 = float(values['x0'])
    if not 0.0 <= x0 <= params.travel:
        raise ValueError(f'x0 = {x0:g} m is outside the travel [0, {params.travel:g}] m')
    tip_mass = float(values['tip_mass'])
    if not (tip_mass >= 0.0 and math.isfinite(tip_mass)):
        raise ValueError(f'tip_mass must be 0 (nominal) or a positive mass, got {tip_mass!r}')
    step = float(values['integration_step'])
    if not 0.0 < step <= params.sample_time:
        raise ValueError(f'integration_step = {step:g} s must be in (0, sample_time = '
                         f'{params.sample_time:g} s]')
    scenario = Scenario(
        x0=x0, theta0=float(values['theta0']), x_dot0=float(values['x_dot0']),
        theta_dot0=float(values['theta_dot0']),
        tip_mass=tip_mass if tip_mass > 0.0 else None,
        friction_scale=float(values['friction_scale']),
        encoder_offset=float(values['encoder_offset']),
        noise=bool(values['noise']), seed=int(values['seed']),
        cart_mass=float(values['cart_mass']) or None, delay=float(values['delay']),
        jitter=float(values['jitter']), drop=float(values['drop']),
        force_noise=float(values['force_noise']),
        actuator_gain=float(values['actuator_gain']),
        actuator_tau=float(values['actuator_tau']),
        pushes=tuple(parse_push(text) for text in
                     str(values['pushes']).replace(',', ' ').split()))
    scenario.plant_parameters(params)  # validates the scenario's plant (e.g. masses)
    return params, scenario
