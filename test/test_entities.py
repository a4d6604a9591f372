"""
The entities of the ROS simulator interface (``rigid_body_sim/ros/entities.py``), ROS-free.

References: bounds against the shapes' surfaces sampled densely (a rotated cylinder's
and capsule's rims, a mesh hull's vertices exactly), a robot's bounds the union of its
links' shapes about its base link, and names kept unique.
"""

import math

import numpy as np

from rigid_body_sim.core import CollisionShape, Gravity, RigidBody, Simulation
from rigid_body_sim.core import rotation as so3
from rigid_body_sim.ros.entities import Entities, EntityError, OBJECT, ROBOT
from rigid_body_sim.scene import scene_from_dict

#: Rim samples: a sampled circle falls short of its true extreme by at most
#: r (1 − cos(π / N)) = 5e-11 r for N = 2e5: the tolerance below has room for it.
N = 200_000


def _quat(axis, angle):
    axis = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    return np.append(axis * math.sin(angle / 2), math.cos(angle / 2))


def _rim(centre, R, radius, half):
    """Points of a cylinder's two rims (shape axis z), world."""
    phi = np.linspace(0.0, 2 * math.pi, N, endpoint=False)
    circle = np.stack([radius * np.cos(phi), radius * np.sin(phi), np.zeros(N)], axis=1)
    return np.concatenate([(circle + [0, 0, z]) @ R.T + centre for z in (-half, half)])


def test_bounds_are_the_shapes_extremes_about_the_entity_frame():
    q_body = _quat((1, 2, 3), 0.7)
    q_cyl, q_cap = _quat((0, 1, 1), 0.4), _quat((1, 0, 0.3), 1.1)
    mesh = np.array([[0.5, 0.2, 0.0], [1.5, 0.2, 0.0], [0.5, 1.2, 0.0], [0.5, 0.2, 1.0],
                     [1.5, 1.2, 1.0]])
    body = RigidBody('b', 1.0, (0.1, 0.1, 0.1), position_world=(3.0, -1.0, 2.0),
                     orientation_xyzw=q_body)
    shapes = [CollisionShape('cylinder', 'b', radius=0.2, length=0.6,
                             position_body=(0.1, 0.0, 0.0), orientation_xyzw=q_cyl),
              CollisionShape('capsule', 'b', radius=0.1, length=0.4,
                             position_body=(-0.3, 0.2, 0.1), orientation_xyzw=q_cap),
              CollisionShape('mesh', 'b', mesh=mesh, position_body=(0.0, 0.0, -2.0))]
    sim = Simulation([body], [Gravity()], shapes=shapes)
    lower, upper = Entities(sim).bounds('b')
    # The same extremes, independently: sampled rims (cylinder), sampled rims grown by the
    # radius along each axis (capsule: its end spheres), the mesh's vertices; all in the
    # body frame (the entity's).
    R_cyl, R_cap = so3.quat_to_matrix(q_cyl), so3.quat_to_matrix(q_cap)
    points = [_rim(np.array([0.1, 0.0, 0.0]), R_cyl, 0.2, 0.3),
              mesh + [0.0, 0.0, -2.0]]
    ends = np.array([[0, 0, -0.2], [0, 0, 0.2]]) @ R_cap.T + [-0.3, 0.2, 0.1]
    points += [ends + 0.1 * e for e in np.vstack([np.eye(3), -np.eye(3)])]
    cloud = np.concatenate(points)
    np.testing.assert_allclose(upper, cloud.max(axis=0), rtol=0, atol=1e-9)
    np.testing.assert_allclose(lower, cloud.min(axis=0), rtol=0, atol=1e-9)
    assert Entities(Simulation([RigidBody('bare', 1.0, (0.1,) * 3)], [])).bounds('bare') is None


def test_a_robot_is_one_entity_bounded_by_its_links_and_a_body_keeps_its_name(tmp_path):
    urdf = tmp_path / 'r.urdf'
    inertial = ('<inertial><mass value="1"/><inertia ixx="0.1" iyy="0.1" izz="0.1" ixy="0" '
                'ixz="0" iyz="0"/></inertial>')
    urdf.write_text(
        f'<robot name="twin"><link name="base">{inertial}<collision><geometry><box '
        f'size="0.2 0.4 0.6"/></geometry></collision></link>'
        f'<link name="arm">{inertial}<collision><origin xyz="0 0 0.5"/><geometry><sphere '
        f'radius="0.1"/></geometry></collision></link>'
        f'<joint name="j" type="revolute"><parent link="base"/><child link="arm"/>'
        f'<origin xyz="1 0 0"/><axis xyz="0 0 1"/><limit lower="-1" upper="1" effort="1" '
        f'velocity="1"/></joint></robot>')
    scene = scene_from_dict({
        'dt': 1e-3, 'bodies': [{'name': 'twin', 'mass': 1.0, 'inertia': [0.1, 0.1, 0.1]}],
        'robots': [{'urdf': str(urdf), 'prefix': 'r_', 'collisions': True,
                    'base_pose': {'xyz': [0, 0, 5], 'rpy': [0, 0, 0.5]}}]},
        str(tmp_path / 's.yaml'))
    entities = Entities(scene.simulation)
    assert entities.names() == ['twin', 'twin_robot']
    assert entities.get('twin').category == OBJECT
    assert entities.get('twin_robot').category == ROBOT
    lower, upper = entities.bounds('twin_robot')
    # About the base link's frame: the box's half sizes, and the arm's sphere 1 m along x
    # and 0.5 m up: x to 1.1, z to 0.6.
    np.testing.assert_allclose(upper, [1.1, 0.2, 0.6], rtol=0, atol=1e-12)
    np.testing.assert_allclose(lower, [-0.1, -0.2, -0.3], rtol=0, atol=1e-12)
    position, quat = entities.state('twin_robot')[:2]
    np.testing.assert_allclose(position, [0, 0, 5], rtol=0, atol=1e-14)
    np.testing.assert_allclose(quat, [0, 0, math.sin(0.25), math.cos(0.25)], rtol=0,
                               atol=1e-15)


def test_a_bounds_filter_selects_the_entities_whose_box_meets_the_region():
    # A unit cube turned 45° about z (its box: the cube itself, its frame's axes), a
    # bare point body, and queries placed just inside and just outside each, by the
    # closed-form distances: the turned cube reaches √2/2 along x, its faces 0.5 out.
    turn = _quat((0, 0, 1), math.pi / 4)
    sim = Simulation([RigidBody('cube', 1.0, (0.1,) * 3, orientation_xyzw=turn),
                      RigidBody('dot', 1.0, (0.1,) * 3, position_world=(5.0, 0.0, 0.0))],
                     [], shapes=[CollisionShape('box', 'cube', size=(1.0, 1.0, 1.0))])
    ent = Entities(sim)
    names = ['cube', 'dot']
    reach, eps = math.sqrt(0.5), 1e-6
    # Spheres: the corner at (√2/2, 0, 0); the dot by its origin.
    assert ent.overlapping(names, 'sphere', [(reach + 0.1 + eps, 0, 0), (0.1, 0, 0)]) == []
    assert ent.overlapping(names, 'sphere', [(reach + 0.1 - eps, 0, 0), (0.1, 0, 0)]) == \
        ['cube']
    assert ent.overlapping(names, 'sphere', [(5.0, 0.0, 0.3), (0.3, 0, 0)]) == ['dot']
    # A box (world axes) beside the corner; then one over the dot and the cube's top.
    assert ent.overlapping(names, 'box', [(reach + eps, -1, -1), (2, 1, 1)]) == []
    assert ent.overlapping(names, 'box', [(reach - eps, -1, -1), (2, 1, 1)]) == ['cube']
    assert ent.overlapping(names, 'box', [(6, 1, 0.5), (-1, -1, 0.0)]) == names
    # A hull: a triangle in the plane x + y = c; the cube's face x' = 0.5 is that plane
    # for c = 0.5 √2 (its rotated normal (1, 1, 0) / √2).

    def triangle(c):
        return [(c / 2 + 3, c / 2 - 3, -3), (c / 2 - 3, c / 2 + 3, -3), (c / 2, c / 2, 3)]
    assert ent.overlapping(names, 'hull', triangle(reach + 1e-5)) == []
    assert ent.overlapping(names, 'hull', triangle(reach - 1e-5)) == ['cube']
    for kind, points in (('sphere', [(0, 0, 0), (-1, 0, 0)]), ('box', [(0, 0, 0)]),
                         ('hull', [(0, 0, 0), (1, 0, 0)]),
                         ('sphere', [(math.nan, 0, 0), (1, 0, 0)])):
        try:
            ent.overlapping(names, kind, points)
        except EntityError as exc:
            assert exc.code == 'OPERATION_FAILED' and 'filters.bounds' in str(exc)
        else:
            raise AssertionError(f'{kind} {points} accepted')


def test_a_state_set_in_a_moving_frame_is_what_that_frame_observes():
    # The reference spins (2 rad/s about z) and moves (1 m/s along x); a cube is set at
    # p, at rest in its axes but for v and ω relative. Read back from the world state
    # alone: the cube's position in the frame's axes is p, its change over one short
    # free step (no forces, isotropic bodies) is v to O(h), and its angular velocity
    # relative to the frame, in its axes, is ω.
    h = 1e-7
    sim = Simulation([RigidBody('cube', 1.0, (0.1,) * 3),
                      RigidBody('ref', 1.0, (0.1,) * 3, position_world=(1.0, 2.0, 3.0),
                                orientation_xyzw=_quat((1, 1, 0), 0.4),
                                linear_velocity_world=(1.0, 0.0, 0.0),
                                angular_velocity_body=(0.0, 0.0, 2.0))], [], dt=h)
    ent = Entities(sim)
    p, v, w = np.array([1.0, -0.5, 0.2]), np.array([0.0, 0.5, 0.1]), np.array([0.3, 0, 0])
    q = _quat((0, 1, 0), 0.3)
    ent.set_state('cube', p, q, v, w, frame='ref')

    def relative():
        pc, qc = sim.pose('cube')
        pr, qr = sim.pose('ref')
        R = so3.quat_to_matrix(qr)
        return R.T @ (pc - pr), R.T @ so3.quat_to_matrix(qc), R.T @ (
            sim.twist('cube')[1] - sim.twist('ref')[1])
    r0, R0, w0 = relative()
    np.testing.assert_allclose(r0, p, rtol=0, atol=1e-14)
    np.testing.assert_allclose(R0, so3.quat_to_matrix(q), rtol=0, atol=1e-14)
    np.testing.assert_allclose(w0, w, rtol=0, atol=1e-14)
    sim.step()
    # (the finite difference's error: h times the relative acceleration, ~ |ω|² |p| + 2|ω||v|)
    np.testing.assert_allclose((relative()[0] - r0) / h, v, rtol=0, atol=10 * h)
    for frame in ('cube', 'nowhere'):
        try:
            ent.set_state('cube', p, q, v, w, frame=frame)
        except EntityError as exc:
            assert exc.code == 'OPERATION_FAILED' and repr(frame) in str(exc)
        else:
            raise AssertionError(frame)
