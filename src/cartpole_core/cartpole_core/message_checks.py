"""What the rig can produce: every JointState-like message judged where it enters a node.

A node of someone else's on the same ROS domain (a stray ``ros2 topic pub``,
a recorder replaying a bag) can publish on the graph's topics. Each
subscriber of ours judges what it takes with :func:`judge` against the rig's
limits (:class:`RigLimits`): finite numbers, the expected joint names and
array lengths, positions within the rail and the encoders' range, velocities
the plant can reach, an effort within the amplifier's range, a stamp that is
not zero and not far from the node's clock. What fails is dropped (the loop
goes on as after a lost sample) and counted by reason in an
:class:`InputJudge`. The messages are duck-typed (``header.stamp``, ``name``,
``position``, ``velocity``, ``effort``), so this module has no ROS import and
is tested without DDS. The ROS wiring is :mod:`cartpole_core.input_guard`;
the limits and the diagnostics keys: docs/troubleshooting.md ("Messages from
outside the graph").
"""
from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass

from .model import CartPoleParameters

STAMP_TOLERANCE_RANGE = (0.0, 86400.0)
"""[s] The range of every node's ``stamp_tolerance`` parameter (0: stamps not judged)."""

CART, PENDULUM = 'cart', 'pendulum'

SAMPLE, STATE, TRUTH, COMMAND = 'sample', 'state', 'truth', 'command'
"""The kinds of message: an encoders' sample (``joint_states``), an estimate
(``cartpole/state``), the simulator's ground truth (``cartpole/true_state``), a
force command (``cartpole/force_command``)."""

REASONS = ('non_finite', 'joint_names', 'array_length', 'cart_range', 'pendulum_range',
           'velocity_range', 'effort_range', 'zero_stamp', 'stamp_far', 'undecodable')
"""Every reason a message is refused, in the order they are checked (``undecodable``:
bytes a node that takes serialized messages could not read)."""

_FIELDS = {  # kind -> the joints, and which arrays must have one value per joint
    SAMPLE: ((CART, PENDULUM), ('position',)),
    STATE: ((CART, PENDULUM), ('position', 'velocity')),
    TRUTH: ((CART, PENDULUM), ('position', 'velocity')),
    COMMAND: ((CART,), ('effort',)),
}


@dataclass(frozen=True)
class RigLimits:
    """What the rig can produce; the defaults are the thesis rig's (:class:`CartPoleParameters`)."""

    travel: float = CartPoleParameters.travel
    """Cart travel between the end stops [m] (section 2.3)."""
    cart_margin: float = 0.05
    """Beyond the travel on either side [m]: end-stop compression and the EKF's overshoot."""
    pendulum_turns: float = 1000.0
    """Revolutions of the pendulum either way from where its encoder was reset."""
    cart_speed: float = 10.0
    """Largest cart speed [m/s] (the amplifier's 37 N over the 0.77 m rail reach about 3.5)."""
    pendulum_speed: float = 200.0
    """Largest pendulum speed [rad/s] (a fall from upright reaches about 15)."""
    force_min: float = CartPoleParameters().force_min
    """The amplifier's largest force to the left [N] (Appendix C, -37.4 N)."""
    force_max: float = CartPoleParameters().force_max
    """The amplifier's largest force to the right [N] (Appendix C, +34.2 N)."""
    stamp_tolerance: float = 10.0
    """Largest distance between a stamp and the node's clock [s]; 0 turns the stamp
    checks off (synthetic stamps in tests, tools that replay old data)."""

    def __post_init__(self) -> None:
        for name in ('travel', 'cart_margin', 'pendulum_turns', 'cart_speed', 'pendulum_speed',
                     'stamp_tolerance'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f'{name} must be a finite number >= 0, got {value!r}')
        if not (math.isfinite(self.force_min) and math.isfinite(self.force_max)
                and self.force_min < 0 < self.force_max):
            raise ValueError(f'force range [{self.force_min!r}, {self.force_max!r}] must '
                             'contain 0')

    @classmethod
    def from_parameters(cls, params: CartPoleParameters, **changes) -> 'RigLimits':
        """The limits of the rig ``params`` describe (travel, amplifier), with ``changes``."""
        base = dict(travel=params.travel, force_min=params.force_min,
                    force_max=params.force_max)
        base.update(changes)
        return cls(**base)

    @property
    def cart_range(self) -> tuple[float, float]:
        """x [m]: the rail, or up to a travel to the left of the power-on position (an
        encoder not homed yet counts from wherever the cart was), plus the margin."""
        return -self.travel - self.cart_margin, self.travel + self.cart_margin

    @property
    def pendulum_range(self) -> float:
        """Largest |theta| [rad]."""
        return 2.0 * math.pi * self.pendulum_turns


def _finite(values) -> bool:
    return all(math.isfinite(v) for v in values)


def judge(msg, kind: str, now_ns: int, limits: RigLimits) -> str | None:
    """The reason (one of :data:`REASONS`) ``msg`` cannot come from the rig, or None.

    ``msg`` is JointState-like; ``kind`` one of :data:`SAMPLE`, :data:`STATE`,
    :data:`TRUTH`, :data:`COMMAND`; ``now_ns`` the node's clock [ns] (0: the node
    has no time yet, a simulated clock before its first ``/clock``: stamps are not
    judged then).
    """
    joints, arrays = _FIELDS[kind]
    names = list(msg.name)
    if sorted(names) != sorted(joints):
        return 'joint_names'
    columns = {}
    for field in ('position', 'velocity', 'effort'):
        values = msg.__getattribute__(field)
        if field in arrays and len(values) != len(names):
            return 'array_length'
        if field not in arrays and len(values) not in (0, len(names)):
            return 'array_length'
        try:
            columns[field] = [float(v) for v in values]
        except (TypeError, ValueError):
            return 'non_finite'
    if not all(_finite(values) for values in columns.values()):
        return 'non_finite'
    at = {name: i for i, name in enumerate(names)}
    position, velocity, effort = columns['position'], columns['velocity'], columns['effort']
    if position:
        low, high = limits.cart_range
        if CART in at and not low <= position[at[CART]] <= high:
            return 'cart_range'
        if PENDULUM in at and abs(position[at[PENDULUM]]) > limits.pendulum_range:
            return 'pendulum_range'
    if velocity and (abs(velocity[at[CART]]) > limits.cart_speed
                     or (PENDULUM in at and abs(velocity[at[PENDULUM]]) > limits.pendulum_speed)):
        return 'velocity_range'
    if kind == COMMAND and not limits.force_min - 1e-9 <= effort[at[CART]] <= \
            limits.force_max + 1e-9:
        return 'effort_range'
    return judge_stamp(msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec,
                       now_ns, limits)


def judge_stamp(stamp_ns: int, now_ns: int, limits: RigLimits) -> str | None:
    """``zero_stamp`` or ``stamp_far`` when the stamp cannot be one of the rig's now, else None.

    A zero stamp is refused unless the node's clock itself is near zero (a lockstep
    simulation's sample 0, on simulated time); nothing is judged while the clock
    reads 0 or with ``stamp_tolerance`` 0."""
    tolerance_ns = limits.stamp_tolerance * 1e9
    if tolerance_ns <= 0 or now_ns == 0:
        return None
    if stamp_ns == 0 and abs(now_ns) > tolerance_ns:
        return 'zero_stamp'
    if abs(stamp_ns - now_ns) > tolerance_ns:
        return 'stamp_far'
    return None


class InputJudge:
    """Judges a node's inputs and counts what it refused, by topic and reason."""

    def __init__(self, limits: RigLimits | None = None) -> None:
        self.limits = limits or RigLimits()
        self.counts: Counter[tuple[str, str]] = Counter()
        """Refused messages by (topic, reason)."""
        self.last = ''
        """The latest refusal: ``<reason> on <topic>``."""
        self._told = False

    @property
    def refused(self) -> int:
        """Messages refused since start."""
        return sum(self.counts.values())

    def accept(self, msg, kind: str, topic: str, now_ns: int) -> bool:
        """True if ``msg`` may be taken; else it is counted (see :meth:`first_news`)."""
        reason = judge(msg, kind, now_ns, self.limits)
        if reason is None:
            return True
        self.counts[(topic, reason)] += 1
        self.last = f'{reason} on {topic}'
        return False

    def accept_stamps(self, stamps_ns, topic: str, now_ns: int) -> bool:
        """True if every stamp of a message of no joints (a Header, a TimeReference) may
        be the rig's now (:func:`judge_stamp`); else it is counted."""
        for stamp_ns in stamps_ns:
            reason = judge_stamp(stamp_ns, now_ns, self.limits)
            if reason is not None:
                self.count(topic, reason)
                return False
        return True

    def count(self, topic: str, reason: str) -> None:
        """Count a refusal the node decided itself (a message of no known kind)."""
        self.counts[(topic, reason)] += 1
        self.last = f'{reason} on {topic}'

    def first_news(self) -> str | None:
        """The sentence to log, once: the first refusal (None before it and after it)."""
        if self._told or not self.counts:
            return None
        self._told = True
        return (f'dropped a message on {self.last.split(" on ")[1]} that the rig cannot '
                f'produce ({self.last.split(" on ")[0]}); further ones are counted on '
                f'/diagnostics (refused_inputs)')

    def values(self) -> dict[str, object]:
        """Health values: ``refused_inputs``, ``refused_inputs.<reason>`` (each reason seen),
        ``refused_inputs.last``."""
        out: dict[str, object] = {'refused_inputs': self.refused}
        by_reason: Counter[str] = Counter()
        for (_, reason), n in self.counts.items():
            by_reason[reason] += n
        for reason in REASONS:
            if by_reason[reason]:
                out[f'refused_inputs.{reason}'] = by_reason[reason]
        if self.last:
            out['refused_inputs.last'] = self.last
        return out
