"""The installed URDF of the rig: it parses, its joints are /joint_states', its kinematics are the model's.

The forward kinematics are computed here from the URDF's own joint origins and axes
(homogeneous transforms, Rodrigues' rotation), independently of the code that wrote
it, and compared with the model's geometry (4.5): the tip mass at
(x - l sin theta, l cos theta), theta = 0 upright, pi hanging, positive theta left.
"""
import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from cartpole_sim.geometry import RigGeometry
from cartpole_core.model import CartPoleParameters
from cartpole_sim.urdf import rig_urdf


def installed_urdf() -> Path:
    from ament_index_python.packages import get_package_share_directory
    path = Path(get_package_share_directory('cartpole_sim')) / 'urdf' / 'cartpole.urdf'
    assert path.is_file(), f'{path} is not installed (make build)'
    return path


def _vec(text: str | None, default=(0.0, 0.0, 0.0)) -> np.ndarray:
    return np.array([float(v) for v in text.split()]) if text else np.array(default, float)


def _rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    k = axis / np.linalg.norm(axis)
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(angle) * kx + (1 - math.cos(angle)) * kx @ kx


def _rpy(rpy: np.ndarray) -> np.ndarray:
    r, p, y = rpy
    return (_rotation(np.array([0, 0, 1.0]), y) @ _rotation(np.array([0, 1.0, 0]), p)
            @ _rotation(np.array([1.0, 0, 0]), r))


def _transform(rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    t = np.eye(4)
    t[:3, :3], t[:3, 3] = rotation, translation
    return t


class Urdf:
    def __init__(self, text: str) -> None:
        self.root = ET.fromstring(text)
        self.joints = {j.get('name'): j for j in self.root.findall('joint')}
        self.links = {link.get('name') for link in self.root.findall('link')}

    def chain(self, link: str) -> list:
        """Joints from the root to ``link``."""
        by_child = {j.find('child').get('link'): j for j in self.joints.values()}
        out = []
        while link in by_child:
            joint = by_child[link]
            out.append(joint)
            link = joint.find('parent').get('link')
        return out[::-1]

    def link_pose(self, link: str, q: dict[str, float]) -> np.ndarray:
        """Pose of ``link`` in the root link's frame for joint positions ``q``."""
        pose = np.eye(4)
        for joint in self.chain(link):
            origin = joint.find('origin')
            pose = pose @ _transform(_rpy(_vec(origin.get('rpy'))), _vec(origin.get('xyz')))
            kind = joint.get('type')
            if kind == 'fixed':
                continue
            axis = _vec(joint.find('axis').get('xyz'), (1.0, 0.0, 0.0))
            value = q[joint.get('name')]
            if kind == 'prismatic':
                pose = pose @ _transform(np.eye(3), axis / np.linalg.norm(axis) * value)
            else:
                pose = pose @ _transform(_rotation(axis, value), np.zeros(3))
        return pose


@pytest.fixture(scope='module')
def urdf():
    return Urdf(installed_urdf().read_text())


def test_installed_urdf_is_the_generated_one():
    assert installed_urdf().read_text() == rig_urdf()


def test_joints_are_the_two_of_joint_states_with_the_travel_as_limits(urdf):
    params = CartPoleParameters()
    movable = {n: j for n, j in urdf.joints.items() if j.get('type') != 'fixed'}
    assert set(movable) == {'cart', 'pendulum'}
    cart = movable['cart']
    assert cart.get('type') == 'prismatic'
    limit = cart.find('limit')
    assert float(limit.get('lower')) == 0.0
    assert float(limit.get('upper')) == pytest.approx(params.travel)
    # The pendulum turns freely (theta is not wrapped on /joint_states): URDF's unlimited
    # revolute joint.
    assert movable['pendulum'].get('type') == 'continuous'
    assert urdf.links == {'base_link', 'cart', 'pendulum', 'tip_mass'}
    children = {j.find('child').get('link') for j in urdf.joints.values()}
    assert urdf.links - children == {'base_link'}  # the root, as REP 105 names it
    assert [j.get('name') for j in urdf.chain('tip_mass')] == ['cart', 'pendulum', 'tip']


@pytest.mark.parametrize('x, theta', [(0.0, math.pi), (0.3845, 0.0), (0.769, 0.5),
                                      (0.2, -1.2), (0.6, 2.0 * math.pi + 0.3), (0.1, math.pi / 2)])
def test_forward_kinematics_put_the_tip_where_the_model_does(urdf, x, theta):
    l = CartPoleParameters().l
    tip = urdf.link_pose('tip_mass', {'cart': x, 'pendulum': theta})[:3, 3]
    np.testing.assert_allclose(tip, [x - l * math.sin(theta), 0.0, l * math.cos(theta)],
                               atol=1e-9)
    joint = urdf.link_pose('pendulum', {'cart': x, 'pendulum': theta})[:3, 3]
    np.testing.assert_allclose(joint, [x, 0.0, 0.0], atol=1e-12)


def test_hanging_upright_and_leaning_left_as_on_joint_states(urdf):
    l = CartPoleParameters().l
    def tip(theta):
        return urdf.link_pose('tip_mass', {'cart': 0.3, 'pendulum': theta})[:3, 3]
    assert tip(math.pi)[2] == pytest.approx(-l)        # pi hanging
    assert tip(0.0)[2] == pytest.approx(l)             # 0 upright
    assert tip(0.1)[0] < 0.3                           # positive theta leans left (-x)


def test_visuals_have_the_dimensions_of_table_2_1(urdf):
    g = RigGeometry()
    shapes = {link.get('name'): [v.find('geometry')[0] for v in link.findall('visual')]
              for link in urdf.root.findall('link')}
    rod, = shapes['pendulum']
    assert float(rod.get('radius')) == pytest.approx(0.005)  # d_rod 1 cm
    tip, = shapes['tip_mass']
    assert float(tip.get('length')) == pytest.approx(0.104)   # h_mass
    assert float(tip.get('radius')) == pytest.approx(0.00975)  # d_mass 1.95 cm
    rail = shapes['base_link'][0]
    assert _vec(rail.get('size'))[0] == pytest.approx(0.889)   # l_rail
    cart, = shapes['cart']
    assert _vec(cart.get('size'))[0] == pytest.approx(0.889 - 0.769) == pytest.approx(g.cart_width)


def test_urdf_of_other_plant_parameters_follows_them():
    params = CartPoleParameters().replace(l=0.5, travel=0.6)
    other = Urdf(rig_urdf(params))
    tip = other.link_pose('tip_mass', {'cart': 0.1, 'pendulum': 0.4})[:3, 3]
    np.testing.assert_allclose(tip, [0.1 - 0.5 * math.sin(0.4), 0.0, 0.5 * math.cos(0.4)],
                               atol=1e-9)
    assert float(other.joints['cart'].find('limit').get('upper')) == pytest.approx(0.6)


@pytest.mark.ros
def test_joint_names_match_a_published_joint_states_message(urdf, ros_context, spin_until):
    """The simulator's own /joint_states names every movable joint of the URDF, in order."""
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from sensor_msgs.msg import JointState

    from cartpole_sim.sim_node import SimNode

    sim = SimNode(context=ros_context, parameter_overrides=[Parameter('lockstep', value=True)])
    probe = Node('urdf_probe', context=ros_context)
    names = []
    probe.create_subscription(JointState, '/joint_states', lambda m: names.append(list(m.name)),
                              10)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(sim)
    executor.add_node(probe)
    try:
        assert spin_until(executor, lambda: names, 20.0), 'no /joint_states'
    finally:
        executor.shutdown()
        probe.destroy_node()
        sim.destroy_node()
    movable = [n for n, j in urdf.joints.items() if j.get('type') != 'fixed']
    assert names[0] == movable == ['cart', 'pendulum']
