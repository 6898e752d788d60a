"""The parameters of ``hw_bridge``: declared with their ranges, read into a BridgeConfig.

The calibration (signs, ticks, travel, setpoint per newton, DAC zero) and the
port are read-only: they are taken once, at construction; the timeouts can
change while the node runs (docs/rig.md, "Starting the bridge").
"""
from __future__ import annotations

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.node import Node

from .bridge_records import BridgeConfig
from .calibration import Calibration

CALIBRATION = ('cart_sign', 'pendulum_sign', 'force_sign', 'cart_ticks_over_travel', 'travel',
               'pendulum_ticks_per_rev', 'setpoint_per_newton', 'dac_zero')
"""The calibration's parameters (:class:`~cartpole_hw.calibration.Calibration`'s fields)."""


def _fp(lo: float, hi: float) -> list[FloatingPointRange]:
    return [FloatingPointRange(from_value=float(lo), to_value=float(hi), step=0.0)]


def _ir(lo: int, hi: int, step: int = 1) -> list[IntegerRange]:
    return [IntegerRange(from_value=lo, to_value=hi, step=step)]


def declare_bridge_parameters(node: Node) -> None:
    """Declare every parameter of ``hw_bridge`` on ``node``."""
    cal = Calibration()
    ro = dict(read_only=True)
    node.declare_parameter('port', '/dev/ttyACM0', ParameterDescriptor(
        description='serial device of the Arduino Due (or the emulator link, e.g. '
                    '/tmp/cartpole-emu); opened by configure, re-opened after a '
                    'disconnect while inactive', **ro))
    node.declare_parameter('baud', 115200, ParameterDescriptor(
        description='baud rate (8N1)', integer_range=_ir(1200, 4_000_000), **ro))
    for name, meaning in (('cart_sign', 'a growing cart count means the cart moves right'),
                          ('pendulum_sign', 'a growing pendulum count means theta grows'),
                          ('force_sign', 'a positive setpoint pushes the cart right')):
        node.declare_parameter(name, getattr(cal, name), ParameterDescriptor(
            description=f'+1 if {meaning}, else -1', integer_range=_ir(-1, 1, 2), **ro))
    for name, meaning, lo, hi in (
            ('cart_ticks_over_travel', 'cart ticks over the travel (2.4)', 1, 1e6),
            ('travel', 'cart travel between the end stops [m] (section 2.3)', 0.01, 10.0),
            ('pendulum_ticks_per_rev', 'pendulum ticks per revolution (2.3)', 1, 1e6),
            ('setpoint_per_newton', 'DAC setpoint per newton, 1/0.017623 (A.3)', 1.0, 1000.0)):
        node.declare_parameter(name, getattr(cal, name), ParameterDescriptor(
            description=meaning, floating_point_range=_fp(lo, hi), **ro))
    node.declare_parameter('dac_zero', cal.dac_zero, ParameterDescriptor(
        description='DAC value of zero current (Appendix A)', integer_range=_ir(0, 4095), **ro))
    node.declare_parameter('command_timeout', 0.05, ParameterDescriptor(
        description='host watchdog: longest gap between fresh force commands while '
                    'active [s]; a trip sends U,0 and E,0 and ends in on_error',
        floating_point_range=_fp(0.005, 1.0)))
    node.declare_parameter('sample_timeout', 0.05, ParameterDescriptor(
        description='longest gap between valid samples while active before the fault [s]',
        floating_point_range=_fp(0.01, 1.0)))
    node.declare_parameter('reconnect_period', 0.5, ParameterDescriptor(
        description='period of the attempts to re-open a vanished port while inactive [s]',
        floating_point_range=_fp(0.05, 10.0)))
    node.declare_parameter('health_period', 0.2, ParameterDescriptor(
        description='period of /cartpole/hw/health [s]', floating_point_range=_fp(0.02, 10.0),
        **ro))
    node.declare_parameter('home_on_start', False, ParameterDescriptor(
        description='reset the encoders (R) at the first configure, once the device '
                    'answers; the cart must be at the left stop and the pendulum hanging '
                    'still', **ro))


def bridge_config(node: Node) -> tuple[BridgeConfig, str]:
    """The bridge's configuration and port from the declared parameters; ValueError (with
    the reason) when they do not make a calibration or name no port."""
    p = {name: node.get_parameter(name).value for name in CALIBRATION}
    p['cart_ticks_over_travel'] = float(p['cart_ticks_over_travel'])
    p['pendulum_ticks_per_rev'] = float(p['pendulum_ticks_per_rev'])
    try:
        config = BridgeConfig(calibration=Calibration(**p),
                              command_timeout=node.get_parameter('command_timeout').value,
                              sample_timeout=node.get_parameter('sample_timeout').value)
    except ValueError as exc:
        raise ValueError(f'hw_bridge: bad calibration parameters: {exc}') from exc
    port = node.get_parameter('port').value
    if not isinstance(port, str) or not port.strip():
        raise ValueError('hw_bridge: parameter port must name a serial device')
    return config, port
