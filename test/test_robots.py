"""URDF robots in the core: conversion rules, joint coordinates, effort commands, bad input."""

import numpy as np
import pytest
from rigid_body_sim.core import rotation as so3
from rigid_body_sim.core import SpecError
from rigid_body_sim.core.robots import axis_angle_matrix, rpy_matrix
from rigid_body_sim.scene import load_scene, SceneError
from robot_helpers import (inertial, joint, joint_accelerations, link, robot,
                           robot_scene)
from scipy.spatial.transform import Rotation

# A generic inertia tensor (kg m², positive definite, triangle inequality holds).
TENSOR = {'ixx': 0.30, 'iyy': 0.20, 'izz': 0.25, 'ixy': 0.02, 'ixz': -0.03, 'iyz': 0.01}


def tensor_matrix(t=TENSOR):
    return np.array([[t['ixx'], t['ixy'], t['ixz']], [t['ixy'], t['iyy'], t['iyz']],
                     [t['ixz'], t['iyz'], t['izz']]])


def world_inertia(sim, body):
    """Return the inertia tensor of ``body`` about its centre of mass, in its body frame."""
    i = sim.bodies.index[body]
    V = sim.bodies.R_body_principal[i]
    return V @ np.diag(sim.bodies.moments[i]) @ V.T


def test_rpy_is_urdf_fixed_axis_roll_pitch_yaw(rng):
    # bound: two exact constructions of the same rotation agree to rounding (1e-15).
    for _ in range(5):
        rpy = rng.uniform(-3, 3, 3)
        np.testing.assert_allclose(rpy_matrix(rpy), Rotation.from_euler('xyz', rpy).as_matrix(),
                                   atol=1e-14)


def test_inertial_origin_and_full_tensor_are_honoured(tmp_path):
    xyz, rpy = (0.1, -0.2, 0.3), (0.4, -0.5, 0.6)
    sim = robot_scene(tmp_path, robot('r', link('a', inertial(2.0, xyz, rpy, **TENSOR)))
                      ).simulation
    i = sim.bodies.index['a']
    R = rpy_matrix(rpy)
    # bound: an eigendecomposition reassembled, relative 1e-14 of the 0.3 kg m² moments.
    np.testing.assert_allclose(world_inertia(sim, 'a'), R @ tensor_matrix() @ R.T, atol=1e-13)
    np.testing.assert_allclose(sim.bodies.com_body[i], xyz, atol=0)
    assert sim.bodies.mass[i] == 2.0


def test_fixed_joints_are_lumped_with_exact_inertia(tmp_path):
    # A body welded by a kept fixed joint carries the same momenta as the lumped body.
    parts = [link('a', inertial(1.5, (0.1, 0, 0.05), (0.2, 0, 0), **TENSOR)),
             link('b', inertial(0.7, (0, 0.2, 0), (0, 0.3, -0.1), ixx=0.02, iyy=0.03,
                                izz=0.04, ixy=0.001)),
             joint('weld', 'fixed', 'a', 'b', xyz=(0.3, -0.1, 0.2), rpy=(0.5, -0.4, 0.3))]
    text = robot('r', *parts)
    twist = {'base_pose': {'xyz': [0, 0, 1], 'rpy': [0.1, 0.2, 0.3]}}
    lumped = robot_scene(tmp_path, text, **twist).simulation
    kept = robot_scene(tmp_path, text, keep_fixed=['weld'], **twist).simulation
    assert lumped.bodies.names == ['a'] and kept.bodies.names == ['a', 'b']
    assert kept.constraint_names == ['weld']
    # Give both the same rigid motion: spin about an axis through a point.
    w, v0 = np.array([0.3, -1.1, 0.7]), np.array([0.2, 0.1, -0.4])
    for sim in (lumped, kept):
        p, q = sim.pose()
        v = v0 + np.cross(w, p - p[0])
        sim.state = sim.bodies.state_from_origins(0.0, p, q, v, np.tile(w, (len(p), 1)))
    dl, dk = lumped.diagnostics(), kept.diagnostics()
    assert lumped.bodies.mass.sum() == pytest.approx(kept.bodies.mass.sum(), rel=1e-15)
    # bound: sums of a few products of O(1) numbers: 1e-15 relative, with room: 1e-13.
    np.testing.assert_allclose(dl.linear_momentum_world, dk.linear_momentum_world, atol=1e-13)
    np.testing.assert_allclose(dl.angular_momentum_world, dk.angular_momentum_world,
                               atol=1e-13)
    assert dl.kinetic_energy.sum() == pytest.approx(dk.kinetic_energy.sum(), rel=1e-13)


def test_missing_axis_is_x(tmp_path):
    text = robot('r', link('world'), link('a', inertial(1.0)),
                 joint('j', 'continuous', 'world', 'a', xyz=(0, 0, 1)))
    sim = robot_scene(tmp_path, text).simulation
    sim.set_joint_state({'j': 0.5})
    _, q = sim.pose('a')
    # bound: rotation built from the joint angle, rounding only.
    np.testing.assert_allclose(so3.quat_to_matrix(q), axis_angle_matrix(np.eye(3)[0], 0.5),
                               atol=1e-14)


@pytest.mark.parametrize('kind, rows, dof', [('revolute', 5, 1), ('continuous', 5, 1),
                                             ('prismatic', 5, 1), ('planar', 3, 3),
                                             ('fixed', 6, 0), ('floating', 0, 6)])
def test_joint_types_constrain_what_urdf_says(tmp_path, kind, rows, dof):
    text = robot('r', link('world'), link('base', inertial(2.0, **TENSOR)),
                 joint('j0', 'fixed', 'world', 'base', xyz=(0, 0, 1)),
                 link('a', inertial(1.0, (0.1, 0.2, 0), **TENSOR)),
                 joint('j', kind, 'base', 'a', xyz=(0.2, 0, 0), rpy=(0.3, 0, 0), axis=(0, 1, 1)))
    entry = {'keep_fixed': ['j']} if kind == 'fixed' else {}
    sim = robot_scene(tmp_path, text, **entry).simulation
    assert sim.bodies.names == ['a']
    m = sim.dynamics.solver.constraints.n_rows
    assert m == rows and 6 - m == dof
    assert sim.joint_names() == (['j'] if dof == 1 else [])


def test_planar_joint_keeps_the_body_in_its_plane(tmp_path):
    text = robot('r', link('world'), link('puck', inertial(1.0, (0.1, 0, 0), **TENSOR)),
                 joint('p', 'planar', 'world', 'puck', xyz=(0, 0, 0.5), axis=(0, 0, 1)))
    sim = robot_scene(tmp_path, text).simulation
    p0, q0 = sim.pose('puck')
    sim.state = sim.bodies.state_from_origins(0.0, p0[None], q0[None], np.array([[1, -2, 0.]]),
                                              np.array([[0, 0, 3.]]))
    sim.step(2000)
    p, q = sim.pose('puck')
    normal = so3.quat_to_matrix(q) @ np.array([0, 0, 1.0])
    # bound: the constraint solve holds Φ to its drift bound, well below 1e-9 here.
    assert abs(p[2] - 0.5) < 1e-9 and np.linalg.norm(normal - [0, 0, 1]) < 1e-9
    assert np.linalg.norm(p[:2] - p0[:2]) > 1.0     # it did slide


def test_world_link_or_fixed_base_welds_the_root(tmp_path):
    floating = robot('r', link('base', inertial(2.0, **TENSOR)), link('a', inertial(1.0)),
                     joint('j', 'continuous', 'base', 'a', axis=(0, 0, 1)))
    free = robot_scene(tmp_path, floating).simulation
    assert free.bodies.names == ['base', 'a']
    fixed = robot_scene(tmp_path, floating, fixed_base=True).simulation
    assert fixed.bodies.names == ['a']
    assert fixed.dynamics.solver.constraints.spec('j').body_b is None


def test_a_world_link_robot_stands_at_base_pose(tmp_path):
    # The same arm (with a `world` link) at the origin and moved and turned about the
    # vertical: every pose is the base transform of the other's, and under gravity (along
    # the turning axis) the joints move the same.
    from joint_space_reference import urdf_path
    from rigid_body_sim.scene import scene_from_dict
    xyz, yaw = np.array([1.0, -2.0, 0.5]), 0.7

    def arm(**entry):
        data = {'dt': 1e-3, 'effects': {'gravity': {'g_world': [0.0, 0.0, -9.81]}},
                'robots': [dict(urdf=urdf_path('two_link_arm.urdf'),
                                initial_positions={'shoulder': 0.4, 'elbow': -0.3}, **entry)]}
        return scene_from_dict(data, str(tmp_path / 's.yaml')).simulation
    plain = arm()
    moved = arm(base_pose={'xyz': xyz.tolist(), 'rpy': [0.0, 0.0, yaw]})
    Rz = rpy_matrix([0.0, 0.0, yaw])
    p0, q0 = plain.pose()
    p1, q1 = moved.pose()
    # bound: one rotation and translation of O(1) m coordinates: a few ulps, 1e-14.
    np.testing.assert_allclose(p1, p0 @ Rz.T + xyz, atol=1e-14)
    np.testing.assert_allclose(so3.quat_to_matrix(q1), Rz @ so3.quat_to_matrix(q0), atol=1e-14)
    plain.run(0.3)
    moved.run(0.3)
    # bound: the two runs differ by the rounding of their coordinates (1e-16 of a few m)
    # carried through 300 steps of a mildly chaotic 2R arm: well below 1e-10.
    np.testing.assert_allclose(moved.joint_state().positions, plain.joint_state().positions,
                               atol=1e-10)
    assert abs(plain.joint_state().positions[0] - 0.4) > 0.01   # it did swing


def test_a_zero_effort_limit_is_no_limit_and_noted(tmp_path):
    text = robot('r', link('world'), link('a', inertial(1.0)),
                 joint('j', 'revolute', 'world', 'a', axis=(0, 0, 1),
                       extra='<limit effort="0" velocity="0" lower="-1" upper="1"/>'))
    scene = robot_scene(tmp_path, text)
    assert any('effort="0"> is read as no effort limit' in w for w in scene.warnings)
    sim = scene.simulation
    sim.set_joint_efforts({'j': 5.0})
    sim.step()
    assert sim.joint_state().efforts[0] == 5.0
    assert sim.joint_counters()['clamped_efforts'] == 0


def test_massless_link_on_a_moving_joint_is_named(tmp_path):
    text = robot('r', link('world'), link('ghost'),
                 joint('j', 'continuous', 'world', 'ghost', axis=(0, 0, 1)))
    with pytest.raises(SceneError, match=r"robots\[0\]\.links\.ghost\.inertial: link 'ghost'"
                                         r'.* has no mass'):
        robot_scene(tmp_path, text)


def test_unsupported_elements_are_named_in_one_warning(tmp_path):
    text = robot('r', link('a', inertial(1.0) + '<collision><geometry><sphere radius="1"/>'
                           '</geometry></collision>'),
                 '<gazebo reference="a"><mu1>0.5</mu1></gazebo>',
                 '<transmission name="t"><type>x</type></transmission>')
    scene = robot_scene(tmp_path, text)
    notes = [w for w in scene.warnings if 'not simulated' in w]
    assert len(notes) == 1
    for tag in ('<collision>', '<gazebo>', '<transmission>'):
        assert tag in notes[0]


def test_several_robots_need_their_own_names(tmp_path):
    text = robot('r', link('world'), link('a', inertial(1.0)),
                 joint('j', 'continuous', 'world', 'a', axis=(0, 0, 1)))
    (tmp_path / 'r.urdf').write_text(text)
    data = {'dt': 1e-3, 'robots': [{'urdf': 'r.urdf', 'name': 'one'},
                                   {'urdf': 'r.urdf', 'name': 'two'}]}
    from rigid_body_sim.scene import scene_from_dict
    with pytest.raises(SceneError, match=r"robots\[1\]: body 'a' of robot 'two' has the name "
                                         r"of a link of robot 'one'.*prefix"):
        scene_from_dict(data, str(tmp_path / 's.yaml'))
    data['robots'][1]['prefix'] = 'two/'
    sim = scene_from_dict(data, str(tmp_path / 's.yaml')).simulation
    assert sim.bodies.names == ['a', 'two/a'] and sim.joint_names() == ['j', 'two/j']


def test_xacro_arguments_expand(tmp_path):
    (tmp_path / 'r.urdf.xacro').write_text(
        '<?xml version="1.0"?><robot name="x" xmlns:xacro="http://www.ros.org/wiki/xacro">'
        '<xacro:arg name="p" default="left_"/><xacro:property name="m" value="1.5"/>'
        '<link name="world"/><link name="$(arg p)a">' + inertial('${m}') + '</link>'
        '<joint name="$(arg p)j" type="continuous"><parent link="world"/>'
        '<child link="$(arg p)a"/><axis xyz="0 0 1"/></joint></robot>')
    data = {'dt': 1e-3, 'robots': [{'urdf': 'r.urdf.xacro', 'xacro_args': {'p': 'right_'}}]}
    from rigid_body_sim.scene import scene_from_dict
    sim = scene_from_dict(data, str(tmp_path / 's.yaml')).simulation
    assert sim.joint_names() == ['right_j'] and sim.bodies.mass[0] == 1.5


def test_a_urdf_is_a_scene(tmp_path):
    path = tmp_path / 'pendulum.urdf'
    path.write_text(robot('p', link('world'), link('bob', inertial(1.0, (0, 0, -1))),
                          joint('hinge', 'continuous', 'world', 'bob', axis=(0, 1, 0))))
    scene = load_scene(path)
    assert scene.name == 'pendulum'
    sim = scene.simulation
    sim.set_joint_state({'hinge': 0.1})
    sim.step(10)
    assert sim.joint_state().velocities[0] < 0.0   # gravity swings it back


@pytest.mark.parametrize('text, match', [
    ('<robot name="r"><link name="a"></robot>', r'robot\.urdf:1: not well-formed XML'),
    ('<robot name="r">\n<link name="a"/>\n<joint name="j" type="hinge"><parent link="a"/>'
     '<child link="b"/></joint><link name="b"/></robot>',
     r'robot\.urdf:3: .*Invalid joint type: hinge'),
    ('<robot name="r"><link name="a"/><joint name="j" type="revolute"><parent link="a"/>'
     '<child link="b"/></joint><link name="b"/></robot>', r'needs a <limit>'),
    ('<robot name="r"><link name="a"/><joint name="j" type="fixed"><parent link="a"/>'
     '<child link="c"/></joint><link name="b"/></robot>', r"unknown link 'c'"),
    ('<robot name="r"><link name="a">' + inertial(-1.0) + '</link></robot>',
     r"link 'a': inertial.mass must be >= 0"),
    ('<robot name="r"><link name="a">' + inertial(1.0, ixx=1.0, iyy=0.1, izz=0.1) +
     '</link></robot>', r'robots\[0\]\.links\.a\.inertia: violates the triangle inequality'),
])
def test_malformed_urdf_is_refused_with_where(tmp_path, text, match):
    with pytest.raises(SceneError, match=match):
        robot_scene(tmp_path, text)


def test_missing_urdf_file_and_xacro_error(tmp_path):
    from rigid_body_sim.scene import scene_from_dict
    with pytest.raises(SceneError, match=r'robots\[0\]\.urdf: .*nope\.urdf: no such file'):
        scene_from_dict({'dt': 1e-3, 'robots': [{'urdf': 'nope.urdf'}]},
                        str(tmp_path / 's.yaml'))
    (tmp_path / 'bad.xacro').write_text('<robot xmlns:xacro="http://www.ros.org/wiki/xacro" '
                                        'name="b"><link name="${undefined}"/></robot>')
    with pytest.raises(SceneError, match=r'bad\.xacro: xacro failed'):
        scene_from_dict({'dt': 1e-3, 'robots': [{'urdf': 'bad.xacro'}]},
                        str(tmp_path / 's.yaml'))


# -- joint coordinates -----------------------------------------------------------------------

def chain(tmp_path, **entry):
    """Build a fixed-base chain: a revolute, a prismatic and a continuous joint, skewed."""
    text = robot(
        'chain', link('world'),
        link('l1', inertial(1.0, (0.2, 0.05, 0), (0.1, 0.2, 0.3), **TENSOR)),
        link('l2', inertial(0.8, (0.0, 0.1, 0.2), (0.3, 0, 0.1), **TENSOR)),
        link('l3', inertial(0.6, (0.1, 0.0, 0.1), (0, 0.4, 0), **TENSOR)),
        joint('q1', 'revolute', 'world', 'l1', xyz=(0, 0, 1), rpy=(0.2, -0.1, 0.3),
              axis=(0, 0.6, 0.8)),
        joint('q2', 'prismatic', 'l1', 'l2', xyz=(0.4, 0, 0), rpy=(0, 0.5, 0), axis=(1, 0, 0)),
        joint('q3', 'continuous', 'l2', 'l3', xyz=(0, 0.3, 0.1), rpy=(-0.4, 0, 0.2),
              axis=(0.3, -0.4, 0.5)))
    return robot_scene(tmp_path, text, **entry).simulation


def test_set_joint_state_round_trips(tmp_path, rng):
    sim = chain(tmp_path)
    for _ in range(3):
        q = {'q1': rng.uniform(-3, 3), 'q2': rng.uniform(-0.5, 0.5), 'q3': rng.uniform(-20, 20)}
        qd = {k: rng.normal() for k in q}
        sim.set_joint_state(q, qd)
        js = sim.joint_state()
        # bound: forward kinematics and back, rounding of O(10) angles: 1e-12.
        np.testing.assert_allclose(js.positions, list(q.values()), atol=1e-12)
        np.testing.assert_allclose(js.velocities, list(qd.values()), atol=1e-12)
        assert max(sim.constraint_violation().values()) < 1e-12


def test_initial_positions_and_velocities(tmp_path):
    sim = chain(tmp_path, initial_positions={'q1': 0.3, 'q3': -7.0},
                initial_velocities={'q2': 0.25})
    js = sim.joint_state()
    # bound: rounding of the forward kinematics at load.
    np.testing.assert_allclose(js.positions, [0.3, 0.0, -7.0 + 2 * np.pi], atol=1e-12)
    np.testing.assert_allclose(js.velocities, [0.0, 0.25, 0.0], atol=1e-12)


def test_continuous_joints_count_turns(tmp_path):
    # A wheel symmetric about its axle, no gravity: it spins at a constant rate.
    text = robot('w', link('world'), link('wheel', inertial(1.0, ixx=0.5, iyy=0.5, izz=1.0)),
                 joint('axle', 'continuous', 'world', 'wheel', axis=(0, 0, 1)))
    sim = robot_scene(tmp_path, text).simulation
    sim.set_joint_state({'axle': 0.0}, {'axle': 30.0})
    sim.step(2000)
    # bound: a symmetric body's spin is integrated exactly; angle = rate t to rounding of
    # 2000 steps (2000 · 60 rad · 1e-16).
    assert sim.joint_state().positions[0] == pytest.approx(60.0, abs=1e-10)


# -- efforts ---------------------------------------------------------------------------------

def floating_arm(tmp_path):
    text = robot(
        'f', link('base', inertial(3.0, (0.0, 0.1, 0.0), (0.2, 0.1, 0), **TENSOR)),
        link('l1', inertial(1.0, (0.2, 0.05, 0), (0.1, 0.2, 0.3), **TENSOR)),
        link('l2', inertial(0.8, (0.0, 0.1, 0.2), (0.3, 0, 0.1), **TENSOR)),
        joint('q1', 'revolute', 'base', 'l1', xyz=(0.1, 0, 0.2), rpy=(0.2, -0.1, 0.3),
              axis=(0, 0.6, 0.8)),
        joint('q2', 'prismatic', 'l1', 'l2', xyz=(0.4, 0, 0), rpy=(0, 0.5, 0), axis=(1, 0, 0)))
    return robot_scene(tmp_path, text, dt=1e-3).simulation


def test_efforts_are_internal_and_do_their_work(tmp_path):
    sim = floating_arm(tmp_path)
    d0 = sim.diagnostics()
    q0 = sim.joint_state().positions
    tau = np.array([0.8, -1.5])
    sim.set_joint_efforts({'q1': tau[0], 'q2': tau[1]})
    sim.step(500)
    d1 = sim.diagnostics()
    js = sim.joint_state()
    # Equal and opposite pairs: no net force or torque on the robot. bound: rounding of
    # 500 steps of O(1) momenta (5e-14), with room for the constraint drift terms: 1e-11.
    np.testing.assert_allclose(d1.linear_momentum_world, d0.linear_momentum_world, atol=1e-11)
    np.testing.assert_allclose(d1.angular_momentum_world, d0.angular_momentum_world,
                               atol=1e-11)
    # Work done by constant efforts: E(t) − E(0) = τ · (q(t) − q(0)).
    work = tau @ (js.positions - q0)
    gain = d1.kinetic_energy.sum() - d0.kinetic_energy.sum()
    assert abs(work) > 0.05
    # bound: a second-order method's energy error, O(dt²) relative: 1e-5 at dt = 1e-3 (it
    # measures 1e-7 here).
    assert gain == pytest.approx(work, rel=1e-5)
    np.testing.assert_array_equal(js.efforts, tau)


def test_efforts_drive_the_equations_of_motion(tmp_path, rng):
    # q̈ read from the step's multipliers: increasing the effort of one joint changes
    # the accelerations by M⁻¹ e_i Δτ, so the change is linear in Δτ.
    sim = chain(tmp_path)
    sim.set_joint_state({'q1': 0.4, 'q2': 0.1, 'q3': 1.0}, {'q1': 0.3, 'q2': -0.2, 'q3': 2.0})
    base = joint_accelerations(sim)
    sim.set_joint_efforts({'q2': 1.0})
    one = joint_accelerations(sim) - base
    sim.set_joint_efforts({'q2': 3.0})
    three = joint_accelerations(sim) - base
    assert np.linalg.norm(one) > 0.1
    # bound: the solve is linear in the applied wrench; rounding of O(10) terms: 1e-11.
    np.testing.assert_allclose(three, 3.0 * one, atol=1e-11)


def test_effort_limits_clamp_and_count(tmp_path):
    text = robot('r', link('world'), link('a', inertial(1.0)),
                 joint('j', 'revolute', 'world', 'a', axis=(0, 0, 1),
                       extra='<limit effort="2" velocity="1" lower="-100" upper="100"/>'))
    sim = robot_scene(tmp_path, text).simulation
    sim.set_joint_efforts({'j': 5.0})
    sim.step()
    assert sim.joint_state().efforts[0] == 2.0
    sim.set_joint_efforts({'j': -1.0})
    sim.step()
    assert sim.joint_state().efforts[0] == -1.0
    assert sim.joint_counters()['clamped_efforts'] == 1
    sim.set_joint_efforts({'j': 2.0})
    sim.step(2000)      # 2 N m on 0.1 kg m²: 20 rad/s², past 1 rad/s within 0.05 s
    assert sim.joint_counters()['velocity_limit_excursions'] > 1900


def test_effort_for_a_duration_expires(tmp_path):
    sim = floating_arm(tmp_path)
    sim.set_joint_efforts({'q1': 1.0}, duration=0.01)
    sim.step(10)
    assert sim.joint_state().efforts[0] == 1.0
    sim.step(1)
    assert sim.joint_state().efforts[0] == 0.0
    rate = sim.joint_state().velocities[0]
    sim.step(5)
    # bound: no effort now; the free motion changes the rate only through the coupling
    # of two bodies rotating slowly (rate² dt terms, 1e-6 here).
    assert sim.joint_state().velocities[0] == pytest.approx(rate, abs=1e-4)


@pytest.mark.parametrize('call, match', [
    (lambda s: s.set_joint_efforts({'q1': float('nan')}), r'efforts\.q1: .*finite'),
    (lambda s: s.set_joint_efforts({'nope': 1.0}), r"efforts\.nope: unknown joint 'nope'"),
    (lambda s: s.set_joint_efforts([1.0]), r'efforts: expected a mapping'),
    (lambda s: s.set_joint_efforts({'q1': 1.0}, duration=-1), r'duration'),
    (lambda s: s.set_joint_state({'q1': float('inf')}), r'positions\.q1'),
    (lambda s: s.set_joint_state({'q1': 0.1}, {'zz': 1.0}), r'velocities\.zz: unknown joint'),
    (lambda s: s.joint_state(['q1', 'x']), r"names\[1\]: unknown joint 'x'"),
])
def test_bad_joint_input_changes_nothing(tmp_path, call, match):
    sim = floating_arm(tmp_path)
    sim.set_joint_efforts({'q2': 0.5})
    sim.step()
    before = sim.state.y.copy()
    efforts = sim.joint_state().efforts.copy()
    with pytest.raises(SpecError, match=match):
        call(sim)
    np.testing.assert_array_equal(sim.state.y, before)
    sim.step()
    np.testing.assert_array_equal(sim.joint_state().efforts, efforts)


def test_the_description_is_prefixed_as_the_simulation_names_things(tmp_path):
    from rigid_body_sim.urdf import parse_urdf, prefixed_xml
    text = robot('r', link('world'), link('a', inertial(1.0)), link('b', inertial(0.5)),
                 joint('j1', 'revolute', 'world', 'a', axis=(0, 0, 1)),
                 joint('j2', 'revolute', 'a', 'b', axis=(0, 1, 0),
                       extra='<limit effort="1" velocity="1" lower="-1" upper="1"/>'
                             '<mimic joint="j1" multiplier="2"/>'),
                 '<gazebo reference="b"><mu1>0.5</mu1></gazebo>')
    parsed = parse_urdf(prefixed_xml(text, 'left_'), 'r.urdf')
    assert [lk.name for lk in parsed.links] == ['world', 'left_a', 'left_b']
    assert [(j.name, j.parent, j.child) for j in parsed.joints] == [
        ('left_j1', 'world', 'left_a'), ('left_j2', 'left_a', 'left_b')]
    assert parsed.joints[1].mimic[0] == 'left_j1'
    assert 'reference="left_b"' in parsed.xml
    sim = robot_scene(tmp_path, text, prefix='left_').simulation
    assert sim.joint_names() == ['left_j1', 'left_j2']
    assert 'left_j2_mimic' in sim.constraint_names
    assert prefixed_xml(text, '') == text


def test_a_material_named_only_takes_its_definitions_colour():
    from rigid_body_sim.urdf import parse_urdf
    shape = '<geometry><box size="1 1 1"/></geometry>'
    text = robot('r', '<material name="blue"><color rgba="0 0 0.8 1"/></material>',
                 link('a', f'<visual>{shape}<material name="blue"/></visual>'
                      f'<visual>{shape}<material name="red"><color rgba="1 0 0 1"/>'
                      f'</material></visual>'),
                 link('b', f'<visual>{shape}<material name="red"/></visual>'
                      f'<visual>{shape}<material name="none"/></visual>'),
                 joint('j', 'fixed', 'a', 'b'))
    rgba = [v.rgba for v in parse_urdf(text, 'r.urdf').visuals]
    assert rgba == [(0.0, 0.0, 0.8, 1.0), (1.0, 0.0, 0.0, 1.0), (1.0, 0.0, 0.0, 1.0), None]
