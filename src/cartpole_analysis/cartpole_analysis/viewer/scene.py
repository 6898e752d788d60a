"""The 3D scene of the rig as ``foxglove.SceneUpdate`` messages (no ROS).

The rig is drawn at its true dimensions (:class:`cartpole_sim.geometry.RigGeometry`,
Table 2.1) in the URDF's root frame ``base_link`` (the rail): x along the rail from the
left end stop, z up, the pendulum in the plane y = 0, the tip mass at
``(x - l sin theta, 0, l cos theta)`` (4.5). One update holds four entities: ``rig`` (the
rail, both end stops and the x* mark), ``plant`` (cart, rod and tip mass of the plant's
own state, in the colour of the controller's mode, :data:`MODE_COLOURS`), ``estimate``
(the EKF's estimate drawn over it as an outline) and ``label`` (time, mode, active
controller). Every update repeats the static ``rig``, so a client that connects late sees
the whole scene with its first message.
What each channel shows: (docs/live_view.md, "The live view").
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from foxglove.messages import (
    Color, CubePrimitive, CylinderPrimitive, LinePrimitive, LinePrimitiveLineType, Point3, Pose,
    Quaternion, SceneEntity, SceneUpdate, SpherePrimitive, TextPrimitive, Timestamp, Vector3)

from cartpole_sim.geometry import RigGeometry
from cartpole_sim.urdf import ROOT_LINK

FRAME = ROOT_LINK
"""Frame of every entity (the URDF's root link)."""

MODE_COLOURS: dict[str, tuple[float, float, float]] = {
    'idle': (0.55, 0.55, 0.55),
    'swingup': (0.95, 0.55, 0.10),
    'stabilizing': (0.15, 0.65, 0.25),
    'fault': (0.85, 0.10, 0.10),
}
"""Colour (r, g, b) of the cart and the tip mass in each controller mode."""
NO_MODE_COLOUR = (0.20, 0.40, 0.75)
"""Colour before the first controller status (no controller manager heard yet)."""
ESTIMATE_COLOUR = (0.10, 0.75, 0.95)
RAIL_COLOUR = (0.55, 0.57, 0.60)
STOP_COLOUR = (0.25, 0.25, 0.28)
ROD_COLOUR = (0.75, 0.75, 0.75)
REFERENCE_COLOUR = (0.15, 0.65, 0.25)


def mode_key(mode: str | None) -> str:
    """The controller mode in the manager's spelling (``stabilising`` is ``stabilizing``,
    ``swing-up`` is ``swingup``)."""
    mode = (mode or '').strip().lower().replace('-', '').replace('_', '')
    return 'stabilizing' if mode.startswith('stabili') else mode


def mode_colour(mode: str | None) -> tuple[float, float, float]:
    """The colour of a controller mode (:data:`NO_MODE_COLOUR` if none or unknown)."""
    return MODE_COLOURS.get(mode_key(mode), NO_MODE_COLOUR)


@dataclass(frozen=True)
class BodyState:
    """Cart position x [m] and pendulum angle theta [rad] (0 upright) of one drawn body."""

    x: float
    theta: float


def _colour(rgb: tuple[float, float, float], alpha: float = 1.0) -> Color:
    return Color(r=rgb[0], g=rgb[1], b=rgb[2], a=alpha)


def _pose(x: float, y: float, z: float, theta: float = 0.0) -> Pose:
    """A pose at (x, y, z), turned by theta about -y (the pendulum joint's axis)."""
    half = 0.5 * theta
    return Pose(position=Vector3(x=x, y=y, z=z),
                orientation=Quaternion(x=0.0, y=-math.sin(half), z=0.0, w=math.cos(half)))


def _timestamp(stamp_ns: int) -> Timestamp:
    return Timestamp(int(stamp_ns // 1_000_000_000), int(stamp_ns % 1_000_000_000))


class RigScene:
    """Builds the scene updates of one rig.

    Parameters
    ----------
    geometry
        The rig's dimensions (travel, l, Table 2.1).
    x_ref
        x*, the cart reference [m] marked on the rail (settable: ``scene.x_ref = ...``).
    """

    def __init__(self, geometry: RigGeometry, x_ref: float) -> None:
        self.geometry = geometry
        self.x_ref = float(x_ref)

    # -- entities --------------------------------------------------------------------------
    def rig_entity(self, stamp_ns: int) -> SceneEntity:
        """Rail, end stops and the x* mark."""
        g = self.geometry
        left, right = g.rail_x_range
        rail = CubePrimitive(pose=_pose(0.5 * (left + right), g.cart_centre_y, g.rail_centre_z),
                             size=Vector3(x=right - left, y=g.rail_depth, z=g.rail_height),
                             color=_colour(RAIL_COLOUR))
        stop_size = Vector3(x=g.stop_width, y=g.rail_depth, z=g.rail_height + g.cart_height)
        stop_z = g.rail_centre_z + 0.5 * g.cart_height
        stops = [CubePrimitive(pose=_pose(cx, g.cart_centre_y, stop_z), size=stop_size,
                               color=_colour(STOP_COLOUR)) for cx in g.stop_centres_x]
        reach = g.pendulum_length + 0.5 * g.tip_height
        mark = LinePrimitive(type=LinePrimitiveLineType.LineStrip, pose=_pose(0.0, 0.0, 0.0),
                             thickness=2.0, scale_invariant=True,
                             points=[Point3(x=self.x_ref, y=g.axle_length, z=-reach),
                                     Point3(x=self.x_ref, y=g.axle_length, z=reach)],
                             color=_colour(REFERENCE_COLOUR, 0.6))
        text = TextPrimitive(pose=_pose(self.x_ref, g.axle_length, reach + 0.02), billboard=True,
                             font_size=14.0, scale_invariant=True,
                             color=_colour(REFERENCE_COLOUR), text='x*')
        return SceneEntity(timestamp=_timestamp(stamp_ns), frame_id=FRAME, id='rig',
                           cubes=[rail] + stops, lines=[mark], texts=[text])

    def plant_entity(self, stamp_ns: int, body: BodyState, mode: str | None) -> SceneEntity:
        """The cart, rod and tip mass at ``body``, coloured by ``mode``."""
        g = self.geometry
        colour = _colour(mode_colour(mode))
        cart = CubePrimitive(pose=_pose(body.x, g.cart_centre_y, 0.0),
                             size=Vector3(x=g.cart_width, y=g.cart_depth, z=g.cart_height),
                             color=colour)
        rod_x, rod_z = g.point_on_pendulum(body.x, body.theta, 0.5 * g.rod_length)
        rod = CylinderPrimitive(pose=_pose(rod_x, 0.0, rod_z, body.theta),
                                size=Vector3(x=g.rod_diameter, y=g.rod_diameter, z=g.rod_length),
                                bottom_scale=1.0, top_scale=1.0, color=_colour(ROD_COLOUR))
        tip_x, tip_z = g.tip_position(body.x, body.theta)
        tip = CylinderPrimitive(pose=_pose(tip_x, 0.0, tip_z, body.theta),
                                size=Vector3(x=g.tip_diameter, y=g.tip_diameter, z=g.tip_height),
                                bottom_scale=1.0, top_scale=1.0, color=colour)
        return SceneEntity(timestamp=_timestamp(stamp_ns), frame_id=FRAME, id='plant',
                           cubes=[cart], cylinders=[rod, tip])

    def estimate_entity(self, stamp_ns: int, body: BodyState) -> SceneEntity:
        """The estimate as an outline in front of the plant: cart, rod line, tip sphere."""
        g = self.geometry
        y = -0.5 * g.tip_diameter - 0.002  # just in front of the drawn pendulum
        half_w, half_h = 0.5 * g.cart_width, 0.5 * g.cart_height
        corners = [(-half_w, -half_h), (half_w, -half_h), (half_w, half_h), (-half_w, half_h)]
        colour = _colour(ESTIMATE_COLOUR, 0.9)
        outline = LinePrimitive(type=LinePrimitiveLineType.LineLoop, pose=_pose(0.0, 0.0, 0.0),
                                thickness=2.0, scale_invariant=True,
                                points=[Point3(x=body.x + cx, y=y, z=cz) for cx, cz in corners],
                                color=colour)
        tip_x, tip_z = g.tip_position(body.x, body.theta)
        rod = LinePrimitive(type=LinePrimitiveLineType.LineStrip, pose=_pose(0.0, 0.0, 0.0),
                            thickness=2.0, scale_invariant=True,
                            points=[Point3(x=body.x, y=y, z=0.0), Point3(x=tip_x, y=y, z=tip_z)],
                            color=colour)
        d = 1.2 * g.tip_diameter
        tip = SpherePrimitive(pose=_pose(tip_x, y, tip_z), size=Vector3(x=d, y=d, z=d),
                              color=_colour(ESTIMATE_COLOUR, 0.5))
        return SceneEntity(timestamp=_timestamp(stamp_ns), frame_id=FRAME, id='estimate',
                           lines=[outline, rod], spheres=[tip])

    def label_entity(self, stamp_ns: int, text: str) -> SceneEntity:
        g = self.geometry
        left, right = g.rail_x_range
        label = TextPrimitive(pose=_pose(0.5 * (left + right), g.axle_length,
                                         g.pendulum_length + 0.5 * g.tip_height + 0.08),
                              billboard=True, font_size=16.0, scale_invariant=True,
                              color=_colour((0.9, 0.9, 0.9)), text=text)
        return SceneEntity(timestamp=_timestamp(stamp_ns), frame_id=FRAME, id='label',
                           texts=[label])

    # -- one update --------------------------------------------------------------------------
    def update(self, stamp_ns: int, *, plant: BodyState | None, estimate: BodyState | None,
               mode: str | None, label: str = '') -> SceneUpdate:
        """The scene at ``stamp_ns``: the rig, the plant's and the estimated state, the label."""
        entities = [self.rig_entity(stamp_ns)]
        if plant is not None:
            entities.append(self.plant_entity(stamp_ns, plant, mode))
        if estimate is not None:
            entities.append(self.estimate_entity(stamp_ns, estimate))
        if label:
            entities.append(self.label_entity(stamp_ns, label))
        return SceneUpdate(entities=entities)
