"""Cart-pendulum model of the thesis: parameters, dynamics, energies, linearisation.

State ``x = [x, theta, x_dot, theta_dot]`` (4.34): cart position [m] from the
left end stop, pendulum angle [rad] from upright (theta = pi hanging), and
their rates. The pendulum centre of mass sits at ``(x - l sin theta, l cos
theta)`` (4.5), so a positive theta leans the pendulum towards negative x.
Input ``u = F`` [N], the force on the cart.

This module has no ROS import; the simulator, the EKF and the controllers all
use it.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np

STATE_NAMES = ('x', 'theta', 'x_dot', 'theta_dot')


def wrap_counter(ticks: int, bits: int = 16) -> int:
    """A count as a ``bits``-wide two's complement counter shows it (the HCTL-2021's, section 2.3)."""
    half = 1 << (bits - 1)
    return ((ticks + half) % (1 << bits)) - half


class EncoderResolution:
    """The encoder resolutions (2.3), (2.4) of anything that has the encoder figures.

    A mixin of :class:`CartPoleParameters` and of the hardware bridge's
    ``cartpole_hw.protocol.Calibration``, which both carry ``travel``,
    ``cart_ticks_over_travel`` and ``pendulum_ticks_per_rev``: one formula
    for the simulated encoders and the rig's.
    """

    __slots__ = ()
    travel: float
    cart_ticks_over_travel: float
    pendulum_ticks_per_rev: float

    @property
    def cart_resolution(self) -> float:
        """min dx, metres per cart tick (2.4): 0.769 m / 8737 = 88.016e-6 m."""
        return self.travel / self.cart_ticks_over_travel

    @property
    def pendulum_resolution(self) -> float:
        """min dtheta, radians per pendulum tick (2.3): 2 pi / 2000 = pi * 1e-3 rad."""
        return 2.0 * math.pi / self.pendulum_ticks_per_rev


@dataclass(frozen=True)
class CartPoleParameters(EncoderResolution):
    """Physical parameters of the rig (Table 2.1, Table 4.1 "new", Appendix A/C).

    Every field is in SI units. The defaults are the thesis values
    (docs/simulator.md, "Plant parameters"). Instances are immutable; use :meth:`replace` or
    :meth:`with_scenario` for variants.
    """

    m_p: float = 0.251
    """Tip mass [kg] (Table 2.1)."""
    l: float = 0.3345
    """Joint to centre of the tip mass [m] (Table 2.1)."""
    m_c: float = 4.75
    """Equivalent cart mass incl. transmission [kg] (Table 4.1, new)."""
    c_c_right: float = 3.4
    """Cart Coulomb friction moving right, x_dot >= 0 [N] (Table 4.1, (4.27))."""
    c_c_left: float = 2.45
    """Cart Coulomb friction moving left, x_dot < 0 [N] (Table 4.1, (4.27))."""
    v_c: float = 0.0
    """Cart viscous friction [N s/m]; about zero on the rig (section 4.3.1)."""
    c_p: float = 0.0038
    """Pendulum Coulomb friction torque [N m] (Table 4.1)."""
    v_p: float = 0.00067
    """Pendulum viscous friction [N m s/rad] (Table 4.1)."""
    g: float = 9.81
    """Gravitational acceleration [m/s^2]."""
    friction_steepness_cart: float = 1000.0
    """k of tanh(k x_dot) in (4.20) [s/m]: tanh reaches 0.76 at 1 mm/s."""
    friction_steepness_pendulum: float = 1000.0
    """k of tanh(k theta_dot) in (4.21) [s/rad]."""
    travel: float = 0.769
    """Cart travel between the end stops, l_rail - w_cart [m] (section 2.3)."""
    end_stop_stiffness: float = 1.0e6
    """Spring constant of the end stops [N/m] (section 4.5: stiff spring-damper)."""
    end_stop_damping: float = 1.0e3
    """Damping of the end stops [N s/m]; only pushes, never pulls."""
    force_per_ampere: float = 3.1133
    """k_t / r, force on the cart per motor ampere [N/A] (2.1), Appendix C."""
    current_max: float = 11.0
    """Positive current saturation of the amplifier [A] (Appendix C)."""
    current_min: float = -12.0
    """Negative current saturation of the amplifier [A] (Appendix C)."""
    actuator_gain: float = 1.065e4
    """Numerator of the current loop H(s) = b / (s + a) [1/s] (4.4)."""
    actuator_pole: float = 1.058e4
    """a of the current loop H(s) = b / (s + a) [1/s] (4.4)."""
    pendulum_ticks_per_rev: int = 2000
    """Pendulum encoder resolution [ticks/rev] (2.3)."""
    cart_ticks_over_travel: int = 8737
    """Cart encoder ticks over the whole travel (2.4)."""
    counter_bits: int = 16
    """Width of the HCTL-2021 up/down counters; they wrap (section 2.3)."""
    sample_time: float = 0.005
    """Ts, the control and sampling period [s] (section 9.2)."""

    def __post_init__(self) -> None:
        positive = ('m_p', 'l', 'm_c', 'g', 'friction_steepness_cart',
                    'friction_steepness_pendulum', 'travel', 'end_stop_stiffness',
                    'force_per_ampere', 'current_max', 'actuator_gain', 'actuator_pole',
                    'pendulum_ticks_per_rev', 'cart_ticks_over_travel', 'counter_bits',
                    'sample_time')
        non_negative = ('c_c_right', 'c_c_left', 'v_c', 'c_p', 'v_p', 'end_stop_damping')
        for name in positive:
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f'{name} must be a finite number > 0, got {value!r}')
        for name in non_negative:
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise ValueError(f'{name} must be a finite number >= 0, got {value!r}')
        if not (math.isfinite(self.current_min) and self.current_min < 0):
            raise ValueError(f'current_min must be a finite number < 0, got {self.current_min!r}')

    # -- derived quantities -------------------------------------------------
    @property
    def force_max(self) -> float:
        """Largest force to the right the amplifier can give [N] (34.2 N)."""
        return self.current_max * self.force_per_ampere

    @property
    def force_min(self) -> float:
        """Largest force to the left, a negative number [N] (-37.4 N)."""
        return self.current_min * self.force_per_ampere

    @property
    def upright_energy(self) -> float:
        """E*, the pendulum energy (7.3) at rest upright: 2 m_p g l [J]."""
        return 2.0 * self.m_p * self.g * self.l

    @property
    def x_middle(self) -> float:
        """The middle of the travel, the default reference x* [m]."""
        return 0.5 * self.travel

    # -- variants and persistence -------------------------------------------
    def replace(self, **changes: Any) -> 'CartPoleParameters':
        """Return a copy with ``changes`` applied (validated again)."""
        return dataclasses.replace(self, **changes)

    def with_scenario(self, tip_mass: float | None = None,
                      friction_scale: float = 1.0) -> 'CartPoleParameters':
        """Return the parameters of a robustness scenario (section 10.3).

        ``tip_mass`` replaces m_p; ``friction_scale`` multiplies every friction
        coefficient of the cart and the pendulum.
        """
        changes: dict[str, float] = {}
        if tip_mass is not None:
            changes['m_p'] = float(tip_mass)
        if friction_scale != 1.0:
            for name in ('c_c_right', 'c_c_left', 'v_c', 'c_p', 'v_p'):
                changes[name] = getattr(self, name) * friction_scale
        return self.replace(**changes) if changes else self

    def to_dict(self) -> dict[str, float]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> 'CartPoleParameters':
        """Build from a mapping; unknown keys are refused with their names."""
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - names)
        if unknown:
            raise ValueError(f'unknown plant parameter(s) {unknown}; known: {sorted(names)}')
        kinds = {f.name: f.type for f in dataclasses.fields(cls)}
        values: dict[str, Any] = {}
        for key, value in data.items():
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise ValueError(f'plant parameter {key} must be a number, got {value!r}')
            values[key] = int(value) if kinds[key] == 'int' else float(value)
        return cls(**values)

    def to_yaml(self, path: str | Path) -> None:
        import yaml
        Path(path).write_text(yaml.safe_dump({'cartpole_plant': self.to_dict()}, sort_keys=False))

    @classmethod
    def from_yaml(cls, path: str | Path) -> 'CartPoleParameters':
        """Load from a YAML file written by :meth:`to_yaml` (or a flat mapping)."""
        import yaml
        data = yaml.safe_load(Path(path).read_text()) or {}
        if isinstance(data, dict) and 'cartpole_plant' in data:
            data = data['cartpole_plant']
        if not isinstance(data, dict):
            raise ValueError(f'{path}: expected a mapping of plant parameters')
        return cls.from_dict(data)


# -- friction (4.20)-(4.33) --------------------------------------------------
def cart_friction(x_dot: float, p: CartPoleParameters) -> float:
    """B_c(x_dot) = c_c(x_dot) tanh(k x_dot) + v_c x_dot, (4.20) with (4.27).

    The Coulomb level depends on the direction: c_c,R for x_dot >= 0, c_c,L
    otherwise (4.27).
    """
    c_c = p.c_c_right if x_dot >= 0.0 else p.c_c_left
    return c_c * math.tanh(p.friction_steepness_cart * x_dot) + p.v_c * x_dot


def pendulum_friction(theta_dot: float, p: CartPoleParameters) -> float:
    """B_p(theta_dot) = c_p tanh(k theta_dot) + v_p theta_dot, (4.21)/(4.30)."""
    return p.c_p * math.tanh(p.friction_steepness_pendulum * theta_dot) + p.v_p * theta_dot


# -- dynamics (4.17), (4.18), (4.34)-(4.40) --------------------------------------
def accelerations(x: float, theta: float, x_dot: float, theta_dot: float,
                  force: float, p: CartPoleParameters,
                  friction: bool = True) -> tuple[float, float]:
    """(x_ddot, theta_ddot) = M(theta)^-1 ([F, 0] - B - C - G), (4.18).

    ``force`` is every external force on the cart (actuator plus end stops).
    With ``friction=False`` B is left out. Scalar maths for speed; the
    closed form inverse of the 2x2 M(theta) gives (4.34)-(4.38).
    """
    s = math.sin(theta)
    c = math.cos(theta)
    m_p, l, m_c = p.m_p, p.l, p.m_c
    if friction:
        # cart_friction and pendulum_friction, inlined: this is the innermost
        # function of every simulation (test_model checks they agree).
        b_c = ((p.c_c_right if x_dot >= 0.0 else p.c_c_left)
               * math.tanh(p.friction_steepness_cart * x_dot) + p.v_c * x_dot)
        b_p = p.c_p * math.tanh(p.friction_steepness_pendulum * theta_dot) + p.v_p * theta_dot
    else:
        b_c = b_p = 0.0
    # Generalised forces minus C and G, (4.17).
    q1 = force - b_c - m_p * l * s * theta_dot * theta_dot
    q2 = -b_p + m_p * p.g * l * s
    # M = [[m_c + m_p, -m_p l c], [-m_p l c, m_p l^2]]; det = m_p l^2 (m_c + m_p s^2).
    det = m_p * l * l * (m_c + m_p * s * s)
    x_ddot = (m_p * l * l * q1 + m_p * l * c * q2) / det
    theta_ddot = (m_p * l * c * q1 + (m_c + m_p) * q2) / det
    return x_ddot, theta_ddot


def acceleration_function(p: CartPoleParameters):
    """A fast ``acc(x, theta, x_dot, theta_dot, force) -> (x_ddot, theta_ddot)`` for ``p``.

    The same arithmetic as :func:`accelerations` (4.18) in the same order, so the
    same numbers to the last bit, with the parameter products computed once:
    simulators and filters call it thousands of times a simulated second.
    """
    m_p, l, m_c, g = p.m_p, p.l, p.m_c, p.g
    c_r, c_l, k_c, v_c = p.c_c_right, p.c_c_left, p.friction_steepness_cart, p.v_c
    c_p, k_p, v_p = p.c_p, p.friction_steepness_pendulum, p.v_p
    m_p_l = m_p * l
    m_p_l_l = m_p * l * l
    m_p_g_l = m_p * g * l
    m_c_m_p = m_c + m_p
    sin, cos, tanh = math.sin, math.cos, math.tanh

    def acc(x: float, theta: float, x_dot: float, theta_dot: float,
            force: float) -> tuple[float, float]:
        s = sin(theta)
        c = cos(theta)
        b_c = (c_r if x_dot >= 0.0 else c_l) * tanh(k_c * x_dot) + v_c * x_dot
        b_p = c_p * tanh(k_p * theta_dot) + v_p * theta_dot
        q1 = force - b_c - m_p_l * s * theta_dot * theta_dot
        q2 = -b_p + m_p_g_l * s
        det = m_p_l_l * (m_c + m_p * s * s)
        return ((m_p_l_l * q1 + m_p_l * c * q2) / det,
                (m_p_l * c * q1 + m_c_m_p * q2) / det)

    return acc


def torque_accelerations(theta: float, torque: float,
                         p: CartPoleParameters) -> tuple[float, float]:
    """(x_ddot, theta_ddot) added by a torque on the pendulum [N m], M(theta)^-1 [0, torque].

    A torque about the joint is a generalised force on theta in (4.17); by
    the linearity of (4.18) in the generalised forces it adds the second
    column of M(theta)^-1 times the torque, with det M = m_p l^2 (m_c + m_p
    sin^2 theta), the same closed form as :func:`accelerations`.
    """
    s = math.sin(theta)
    c = math.cos(theta)
    m_p, l = p.m_p, p.l
    det = m_p * l * l * (p.m_c + m_p * s * s)
    return m_p * l * c * torque / det, (p.m_c + m_p) * torque / det


def dynamics(t: float, x: np.ndarray, u: float, params: CartPoleParameters) -> np.ndarray:
    """x_dot = f(x) + g(x) u, (4.34)/(4.40), in python-control's signature.

    ``x`` has shape (4,), ``u`` is the force on the cart [N]. ``t`` is unused
    (the model is time invariant) and kept for the common signature.
    """
    x_ddot, theta_ddot = accelerations(float(x[0]), float(x[1]), float(x[2]), float(x[3]),
                                       float(u), params)
    return np.array([x[2], x[3], x_ddot, theta_ddot])


def drift(x: np.ndarray, params: CartPoleParameters) -> np.ndarray:
    """f(x) of (4.40): the state derivative with zero force."""
    return dynamics(0.0, x, 0.0, params)


def input_gain(x: np.ndarray, params: CartPoleParameters) -> np.ndarray:
    """g(x) of (4.34)/(4.40): [0, 0, 1/(m_c + m_p sin^2), cos/(l (m_c + m_p sin^2))]."""
    s = math.sin(float(x[1]))
    c = math.cos(float(x[1]))
    d = params.m_c + params.m_p * s * s
    return np.array([0.0, 0.0, 1.0 / d, c / (params.l * d)])


def force_for_acceleration(x_ddot: float, theta: float, theta_dot: float,
                           theta_ddot: float, params: CartPoleParameters) -> float:
    """Cart acceleration to force, (7.10).

    F = (m_c + m_p) x_ddot - m_p l cos(theta) theta_ddot + m_p l sin(theta) theta_dot^2.
    """
    m_p, l = params.m_p, params.l
    return ((params.m_c + m_p) * x_ddot - m_p * l * math.cos(theta) * theta_ddot
            + m_p * l * math.sin(theta) * theta_dot * theta_dot)


# -- energies (7.3), (7.11) ---------------------------------------------------------
def pendulum_energy(theta: float, theta_dot: float, params: CartPoleParameters) -> float:
    """E_p = 1/2 J theta_dot^2 + m_p g l (cos theta + 1), J = m_p l^2, (7.3).

    Zero hanging at rest; E* = 2 m_p g l upright at rest.
    """
    j = params.m_p * params.l * params.l
    return 0.5 * j * theta_dot * theta_dot + params.m_p * params.g * params.l * (math.cos(theta) + 1.0)


def system_energy(x: np.ndarray, params: CartPoleParameters) -> float:
    """E = 1/2 q_dot^T M(theta) q_dot + m_p g l (cos theta + 1), (7.11)."""
    theta, x_dot, theta_dot = float(x[1]), float(x[2]), float(x[3])
    m_p, l = params.m_p, params.l
    return (0.5 * (params.m_c + m_p) * x_dot * x_dot + 0.5 * m_p * l * l * theta_dot * theta_dot
            - m_p * l * math.cos(theta) * x_dot * theta_dot
            + m_p * params.g * l * (math.cos(theta) + 1.0))


# -- linearisation (8.13), (8.14) ---------------------------------------------------
def linearise_upright(params: CartPoleParameters) -> tuple[np.ndarray, np.ndarray]:
    """(A, B) of the model about upright rest, (8.13)/(8.14).

    Coulomb friction is left out (it is not differentiable at rest); the
    viscous pendulum term is kept. Note the thesis's (8.13) prints
    A44 = -(m_c + m_p) v_p / (l^2 m_p); the derivative of (4.38) has a further
    1/m_c, which is used here.
    """
    m_p, l, m_c, g, v_p = params.m_p, params.l, params.m_c, params.g, params.v_p
    a = np.array([
        [0.0, 0.0, 1.0, 0.0],
        [0.0, 0.0, 0.0, 1.0],
        [0.0, m_p * g / m_c, -params.v_c / m_c, -v_p / (l * m_c)],
        [0.0, (m_c + m_p) * g / (l * m_c), -params.v_c / (l * m_c),
         -(m_c + m_p) * v_p / (l * l * m_p * m_c)],
    ])
    b = np.array([[0.0], [0.0], [1.0 / m_c], [1.0 / (l * m_c)]])
    return a, b


def wrap_angle(theta: float) -> float:
    """theta_w, the angle wrapped to (-pi, pi]."""
    w = math.fmod(theta + math.pi, 2.0 * math.pi)
    if w <= 0.0:
        w += 2.0 * math.pi
    return w - math.pi
