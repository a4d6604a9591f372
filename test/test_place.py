"""
``Simulation.place``: bodies moved as one rigid whole between steps (a teleport).

The standard simulator interface's ``set_entity_state`` sets an entity's pose and twist
this way (a robot: all its links, about its base). References: the pose and twist asked
for, exactly (to rounding); the other bodies' states unchanged bit for bit; a robot's
joint coordinates unchanged and its joints at rest; the motion afterwards the closed
form from the new state; refusals that name the field and change nothing.
"""

import math
from pathlib import Path

import numpy as np
import pytest

from rigid_body_sim.core import CollisionShape, Constraint, Gravity, RigidBody, Simulation, \
    SpecError
from rigid_body_sim.core import rotation as so3
from rigid_body_sim.scene import scene_from_dict

G = 9.81
URDF = Path(__file__).parent / 'urdf' / 'quadruped.urdf'


def _two_bodies():
    bodies = [RigidBody('a', 2.0, (0.1, 0.2, 0.3), com_body=(0.1, -0.05, 0.02),
                        position_world=(1.0, 2.0, 3.0), orientation_xyzw=(0.0, 0.0, 0.6, 0.8),
                        angular_velocity_body=(0.5, -1.0, 2.0)),
              RigidBody('b', 1.0, (0.1, 0.1, 0.1), position_world=(0.0, 0.0, 1.0),
                        linear_velocity_world=(0.3, 0.0, 0.0))]
    return Simulation(bodies, [Gravity()], integrator='lie_poisson2', dt=1e-3)


def test_a_body_is_placed_exactly_and_falls_from_there_the_others_untouched():
    sim = _two_bodies()
    sim.step(10)
    other = [part[1].copy() for part in sim.state.parts]
    q = np.array([0.1, -0.2, 0.3, 0.9]) / math.sqrt(0.95)
    sim.place(['a'], 'a', (5.0, 6.0, 7.0), q, (1.0, -2.0, 0.5), (0.0, 0.0, 0.0))
    position, orientation = sim.pose('a')
    velocity, omega = sim.twist('a')
    np.testing.assert_allclose(position, [5.0, 6.0, 7.0], rtol=0, atol=1e-14)
    assert abs(abs(float(np.dot(orientation, q))) - 1.0) <= 1e-15
    np.testing.assert_allclose(velocity, [1.0, -2.0, 0.5], rtol=0, atol=1e-14)
    np.testing.assert_allclose(omega, 0.0, rtol=0, atol=1e-15)
    for part, before in zip(sim.state.parts, other):
        assert np.array_equal(part[1], before)   # bit for bit
    # From there, free fall (no spin): p + v t − g t²/2 over 0.5 s, to rounding.
    sim.step(500)
    t = 0.5
    expected = np.array([5.0 + t, 6.0 - 2.0 * t, 7.0 + 0.5 * t - 0.5 * G * t * t])
    np.testing.assert_allclose(sim.pose('a')[0], expected, rtol=0, atol=1e-12)


def test_a_spinning_placement_moves_the_origin_with_its_twist():
    sim = _two_bodies()
    omega = np.array([0.0, 0.0, 3.0])
    sim.place(['a'], 'a', (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0), (0.0, 0.0, 0.0), omega)
    velocity, w = sim.twist('a')
    np.testing.assert_allclose(w, omega, rtol=0, atol=1e-15)
    np.testing.assert_allclose(velocity, 0.0, rtol=0, atol=1e-15)   # the origin's, not the COM's


def _quadruped():
    scene = scene_from_dict({
        'dt': 1e-3, 'effects': {'gravity': {'g_world': [0.0, 0.0, -G]}},
        'robots': [{'urdf': str(URDF), 'base_pose': {'xyz': [0.0, 0.0, 1.0]},
                    'initial_positions': {'lf_hip': 0.4, 'rf_knee': -0.7}}]}, str(URDF))
    return scene.simulation


def test_a_robot_is_placed_rigidly_its_joints_kept_and_at_rest():
    sim = _quadruped()
    sim.set_joint_state({}, {'lf_hip': 1.0, 'rh_knee': -2.0})
    sim.step(50)   # (falling, legs swinging)
    names = [b.name for b in sim.robots[0].bodies]
    base = names[0]
    joints = sim.joint_state()
    assert np.max(np.abs(joints.velocities)) > 0.5
    pos0, quat0 = sim.pose()
    turn = so3.quat_to_matrix(np.array([0.0, 0.0, math.sin(0.6), math.cos(0.6)]))
    target = so3.matrix_to_quat(turn @ so3.quat_to_matrix(quat0[0]))
    v, w = np.array([0.2, 0.0, -0.1]), np.array([0.0, 0.5, 1.0])
    sim.place(names, base, (3.0, -1.0, 2.0), target, v, w)
    after = sim.joint_state()
    np.testing.assert_allclose(after.positions, joints.positions, rtol=0, atol=1e-12)
    np.testing.assert_allclose(after.velocities, 0.0, rtol=0, atol=1e-12)
    pos, quat = sim.pose()
    vel, omega = sim.twist()
    # Every link keeps its pose relative to the base, turned with it; the whole moves with
    # the base origin's twist (each origin at v + ω × r).
    for i in range(len(names)):
        r = pos[i] - pos[0]
        np.testing.assert_allclose(r, turn @ (pos0[i] - pos0[0]), rtol=0, atol=1e-12)
        np.testing.assert_allclose(vel[i], v + np.cross(w, r), rtol=0, atol=1e-12)
        np.testing.assert_allclose(omega[i], w, rtol=0, atol=1e-14)
    np.testing.assert_allclose(pos[0], [3.0, -1.0, 2.0], rtol=0, atol=1e-14)
    assert max(sim.constraint_violation().values()) <= 1e-12


@pytest.mark.parametrize('bodies, reference, kwargs, field, words', [
    (['a'], 'a', {'position': (0.0, 0.0, math.nan)}, 'position', 'finite'),
    (['a'], 'a', {'orientation_xyzw': (0.0, 0.0, 0.0, 0.0)}, 'orientation_xyzw', 'rotation'),
    (['a'], 'a', {'linear_velocity_world': (1.0, 2.0)}, 'linear_velocity_world', '3 numbers'),
    (['nobody'], 'nobody', {}, 'bodies', 'unknown body'),
    (['a'], 'b', {}, 'reference', 'not one of'),
    (['b'], 'b', {}, 'bodies', "'hinge'"),
    (['b', 'c'], 'b', {}, 'bodies', "'pin'"),
])
def test_a_placement_refused_names_its_field_and_changes_nothing(bodies, reference, kwargs,
                                                                 field, words):
    sim = Simulation([RigidBody('a', 1.0, (0.1,) * 3, position_world=(0, 0, 2)),
                      RigidBody('b', 1.0, (0.1,) * 3, position_world=(1, 0, 0)),
                      RigidBody('c', 1.0, (0.1,) * 3, position_world=(3, 0, 0))],
                     [Gravity()], constraints=[
                         Constraint('hinge', 'hinge', 'b', 'c', anchor_world=(2, 0, 0),
                                    axis_world=(0, 0, 1)),
                         Constraint('pin', 'ball', 'c', None, anchor_world=(3, 0, 1))])
    sim.step(3)
    before = sim.state.y.copy()
    args = {'position': (0.0, 0.0, 0.0), 'orientation_xyzw': (0.0, 0.0, 0.0, 1.0), **kwargs}
    with pytest.raises(SpecError) as err:
        sim.place(bodies, reference, **args)
    assert err.value.field == field and words in str(err.value)
    assert np.array_equal(sim.state.y, before)


def test_accelerations_are_the_closed_forms_free_and_on_a_hinge():
    # Free: Euler's equations I ω̇ = −ω × I ω in the body frame (inertia diag(0.1, 0.2,
    # 0.3)), and the origin at r from the centre: g + α × r + ω × (ω × r).
    sim = _two_bodies()
    acc, alpha = sim.accelerations()
    w_body = sim.twist('a', frame='body')[1]
    inertia = np.array([0.1, 0.2, 0.3])
    R = so3.quat_to_matrix(sim.pose('a')[1])
    expected_alpha = R @ (-np.cross(w_body, inertia * w_body) / inertia)
    w = R @ w_body
    r = sim.pose('a')[0] - sim.state.pos_com_world[0]
    np.testing.assert_allclose(alpha[0], expected_alpha, rtol=0, atol=1e-14)
    np.testing.assert_allclose(acc[1], [0.0, 0.0, -G], rtol=0, atol=1e-14)
    np.testing.assert_allclose(acc[0], [0.0, 0.0, -G] + np.cross(expected_alpha, r)
                               + np.cross(w, np.cross(w, r)), rtol=0, atol=1e-13)
    # A uniform sphere of radius ρ on a hinge at distance L
    # from its centre, released at rest at angle θ: θ̈ = −m g L sin θ / (I + m L²), and its
    # origin (the centre) accelerates at θ̈ L tangentially.
    m, rho, L, theta = 2.0, 0.1, 0.5, 0.7
    inertia = 0.4 * m * rho * rho
    centre = (L * math.sin(theta), 0.0, -L * math.cos(theta))
    sim = Simulation([RigidBody('s', m, (inertia,) * 3, position_world=centre)], [Gravity()],
                     constraints=[Constraint('hinge', 'hinge', 's', None,
                                             anchor_world=(0.0, 0.0, 0.0),
                                             axis_world=(0.0, 1.0, 0.0))])
    acc, alpha = sim.accelerations()
    theta_dd = -m * G * L * math.sin(theta) / (inertia + m * L * L)
    # x = L sin θ, z = −L cos θ: a turn about +y decreases θ, so α_y = −θ̈.
    np.testing.assert_allclose(alpha[0], [0.0, -theta_dd, 0.0], rtol=1e-12, atol=1e-14)
    tangent = np.array([math.cos(theta), 0.0, math.sin(theta)])
    np.testing.assert_allclose(acc[0], theta_dd * L * tangent, rtol=1e-12, atol=1e-13)


def test_accelerations_of_a_box_resting_on_the_ground_are_zero_both_paths():
    # The ground's forces as the last step held them carry the weight: a = 0 to rounding
    # (the compiled steps keep them in their record; the Python path in the effect).
    for compiled in (True, False):
        sim = Simulation([RigidBody('box', 2.0, (0.1, 0.1, 0.1), position_world=(0, 0, 0.1))],
                         [Gravity()], integrator='rkmk4',
                         shapes=[CollisionShape('plane', None, friction=0.5),
                                 CollisionShape('box', 'box', size=(0.2, 0.2, 0.2))])
        sim.contact.compiled = compiled
        sim.step(20)
        acc, alpha = sim.accelerations()
        np.testing.assert_allclose(acc, 0.0, rtol=0, atol=1e-12)
        np.testing.assert_allclose(alpha, 0.0, rtol=0, atol=1e-12)
        # Lifted off the ground by a teleport, it falls freely: the forces no longer apply.
        sim.place(['box'], 'box', (0.0, 0.0, 1.0), (0.0, 0.0, 0.0, 1.0))
        np.testing.assert_allclose(sim.accelerations()[0], [[0.0, 0.0, -G]], rtol=0,
                                   atol=1e-14)
