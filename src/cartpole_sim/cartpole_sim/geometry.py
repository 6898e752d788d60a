"""The rig as it is drawn: dimensions of Table 2.1 and the frame they are placed in.

One geometry behind every picture of the rig: the URDF (:mod:`cartpole_sim.urdf`), the
live Foxglove scene (:mod:`cartpole_analysis.viewer.scene`) and the animations made from
bags (:mod:`cartpole_analysis.analysis.animation`). No ROS import: plain numbers.

The rail frame (``rail``): origin at the pendulum joint when the cart is at the left end
stop (x = 0), x along the rail to the right, z up, y into the rig. The joint is at
``(x, 0, 0)``, the centre of the tip mass at ``(x - l sin theta, 0, l cos theta)`` (4.5):
a rotation by theta about -y. Dimensions from Table 2.1; l and the travel from
:class:`~cartpole_core.model.CartPoleParameters`, the cart width ``l_rail - travel``
(section 2.3). Sizes the thesis does not give (``cart_height``, ``rail_depth``, ...) are
drawing sizes, named as such. Where Table 2.1 contradicts itself and which value is
drawn: (docs/live_view.md, "The rig's geometry").
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from cartpole_core.model import CartPoleParameters

RAIL_LENGTH = 0.889
"""l_rail [m] (Table 2.1)."""
ROD_DIAMETER = 0.01
"""d_rod [m] (Table 2.1)."""
TIP_HEIGHT = 0.104
"""h_mass [m], length of the cylindrical tip mass along the rod (Table 2.1)."""
TIP_DIAMETER = 0.0195
"""d_mass [m] (Table 2.1)."""


@dataclass(frozen=True)
class RigGeometry:
    """Dimensions of the rig in the rail frame (see the module docstring) [m].

    Build it with :meth:`from_parameters` so that the pendulum length and
    the travel are the model's.
    """

    travel: float = CartPoleParameters.travel
    """Cart travel between the end stops (section 2.3)."""
    pendulum_length: float = CartPoleParameters.l
    """l, joint to the centre of the tip mass (Table 2.1)."""
    rail_length: float = RAIL_LENGTH
    rod_diameter: float = ROD_DIAMETER
    tip_height: float = TIP_HEIGHT
    tip_diameter: float = TIP_DIAMETER
    cart_height: float = 0.06
    """Drawing size: the cart's height (not in the thesis)."""
    cart_depth: float = 0.10
    """Drawing size: the cart's depth along y (not in the thesis)."""
    axle_length: float = 0.02
    """Drawing size: from the pendulum's plane (y = 0) to the cart's front face."""
    rail_height: float = 0.02
    """Drawing size: the rail's height."""
    rail_depth: float = 0.04
    """Drawing size: the rail's depth along y."""
    stop_width: float = 0.02
    """Drawing size: the end stops' width along x."""

    def __post_init__(self) -> None:
        for name in ('travel', 'pendulum_length', 'rail_length', 'rod_diameter', 'tip_height',
                     'tip_diameter', 'cart_height', 'cart_depth', 'axle_length', 'rail_height',
                     'rail_depth', 'stop_width'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f'{name} must be a finite number > 0, got {value!r}')
        if self.rail_length <= self.travel:
            raise ValueError(f'rail_length {self.rail_length} m must exceed the travel '
                             f'{self.travel} m (the cart is l_rail - travel wide)')
        if self.tip_height >= 2 * self.pendulum_length:
            raise ValueError('tip_height must be less than twice the pendulum length')

    @classmethod
    def from_parameters(cls, params: CartPoleParameters | None = None,
                        **drawing: float) -> 'RigGeometry':
        """The geometry of a rig with the model's travel and pendulum length."""
        params = params or CartPoleParameters()
        return cls(travel=params.travel, pendulum_length=params.l, **drawing)

    # -- derived dimensions ----------------------------------------------------------------
    @property
    def cart_width(self) -> float:
        """w_cart = l_rail - travel (section 2.3): 0.12 m."""
        return self.rail_length - self.travel

    @property
    def rod_length(self) -> float:
        """From the joint to the tip mass: l - h_mass / 2."""
        return self.pendulum_length - 0.5 * self.tip_height

    @property
    def cart_centre_y(self) -> float:
        """y of the cart's centre: behind the pendulum's plane by the axle."""
        return self.axle_length + 0.5 * self.cart_depth

    @property
    def rail_centre_z(self) -> float:
        """z of the rail's centre: under the cart."""
        return -0.5 * self.cart_height - 0.5 * self.rail_height

    @property
    def rail_x_range(self) -> tuple[float, float]:
        """x of the rail's two ends (where the cart's sides meet the end stops)."""
        half = 0.5 * self.cart_width
        return -half, self.travel + half

    @property
    def stop_centres_x(self) -> tuple[float, float]:
        """x of the centres of the left and right end stops (just outside the rail's ends)."""
        left, right = self.rail_x_range
        half = 0.5 * self.stop_width
        return left - half, right + half

    # -- kinematics (4.5) ----------------------------------------------------------------------
    def tip_position(self, x: float, theta: float) -> tuple[float, float]:
        """(x, z) of the centre of the tip mass in the rail frame (4.5)."""
        return x - self.pendulum_length * math.sin(theta), self.pendulum_length * math.cos(theta)

    def point_on_pendulum(self, x: float, theta: float, distance: float) -> tuple[float, float]:
        """(x, z) of the point ``distance`` from the joint along the rod."""
        return x - distance * math.sin(theta), distance * math.cos(theta)
