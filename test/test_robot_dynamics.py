"""
URDF robots against independent joint-space references.

The simulator runs robots in maximal coordinates (a body per link group, joints as
multiplier constraints); ``joint_space_reference`` computes ``M(q) q̈ + h(q, q̇) = τ`` in
joint space from the same files with its own parser (RNEA and CRBA), and the two-link
arm also has a closed form written from its Lagrangian.
"""

from joint_space_reference import (JointSpaceModel, two_link_closed_form, TWO_LINK_PARAMS,
                                   urdf_path, xacro_arm_params)
import numpy as np
import pytest
from rigid_body_sim.core import rotation as so3
from rigid_body_sim.scene import scene_from_dict
from robot_helpers import arm7_free_fingers, joint_accelerations
from scipy.integrate import solve_ivp


def robot_sim(file, dt=1e-3, integrator='lie_poisson2', gravity=True, **entry):
    data = {'dt': dt, 'integrator': integrator,
            'robots': [dict(urdf=urdf_path(file), **entry)]}
    if gravity:
        data['effects'] = {'gravity': {'g_world': [0.0, 0.0, -9.81]}}
    return scene_from_dict(data, urdf_path('scene.yaml')).simulation


Q0, QD0 = np.array([1.0, -0.5]), np.array([0.3, 0.2])


def two_link_reference(T):
    """q, q̇ of the closed-form 2R arm at T by DOP853 (rtol = atol = 1e-13)."""
    M, h = two_link_closed_form(TWO_LINK_PARAMS)

    def rhs(t, y):
        return np.concatenate([y[2:], np.linalg.solve(M(y[:2]), -h(y[:2], y[2:]))])
    sol = solve_ivp(rhs, (0.0, T), np.concatenate([Q0, QD0]), method='DOP853', rtol=1e-13,
                    atol=1e-13)
    return sol.y[:2, -1], sol.y[2:, -1]


def run_two_link(file, integrator, dt, T):
    sim = robot_sim(file, dt, integrator)
    sim.set_joint_state({'shoulder': Q0[0], 'elbow': Q0[1]},
                        {'shoulder': QD0[0], 'elbow': QD0[1]})
    sim.step(int(round(T / dt)))
    return sim


@pytest.mark.parametrize('integrator, order, dts', [
    ('symplectic_euler', 1, (1e-3, 5e-4)),
    ('lie_poisson2', 2, (2e-3, 1e-3)),
    ('lie_poisson4', 4, (2e-3, 1e-3)),
])
def test_two_link_arm_converges_to_its_closed_form(integrator, order, dts):
    T = 1.0
    q_ref, _ = two_link_reference(T)
    errors = [np.max(np.abs(run_two_link('two_link_arm.urdf', integrator, dt, T)
                            .joint_state().positions - q_ref)) for dt in dts]
    ratio = errors[0] / errors[1]
    # bound: halving dt divides the global error of an order-p method by 2^p, up to the
    # next term of its expansion: within a factor 1.25 at these step sizes (measured
    # 2.03, 4.00 and 16.0).
    assert 2 ** order / 1.25 < ratio < 2 ** order * 1.25
    # bound: the DOP853 reference is good to 1e-11, far below every error measured here
    # (the finest: 1.5e-8 for lie_poisson4), so the errors are the method's own.
    assert errors[1] > 1e-10


def test_rotated_frames_give_the_same_motion():
    # The same robot with every link, joint and inertial frame rotated: same joint motion.
    T = 0.5
    plain = run_two_link('two_link_arm.urdf', 'lie_poisson4', 1e-3, T).joint_state()
    rotated = run_two_link('two_link_arm_rotated.urdf', 'lie_poisson4', 1e-3, T).joint_state()
    # bound: both runs integrate identical principal-frame bodies whose inputs differ by
    # the rounding of the rotated frames (1e-15); 500 steps of a mildly chaotic double
    # pendulum amplify that well below 1e-11.
    np.testing.assert_allclose(rotated.positions, plain.positions, atol=1e-11)
    np.testing.assert_allclose(rotated.velocities, plain.velocities, atol=1e-10)


@pytest.mark.parametrize('seed', [1, 2, 3])
def test_arm7_accelerations_are_the_joint_space_dynamics(seed, tmp_path):
    # q̈ of the maximal-coordinate solve (the step's multipliers) = M⁻¹ (τ − D q̇ − h) (the
    # URDF's joint damping D), with the fixed hand lumped into link7 and the fingers on
    # prismatic joints, here without their mimic (the reference's full model; the mimic
    # is test_mimic_joints.py's).
    rng = np.random.default_rng(seed)
    reference = JointSpaceModel.from_urdf(open(urdf_path('arm7.urdf')).read())
    # The random states may lie beyond the URDF's limits, and the reference has neither
    # limits nor friction: both are off here (test_joint_limits.py has them).
    sim = robot_sim(arm7_free_fingers(tmp_path), limits=False, friction=False)
    names = sim.joint_names()
    assert names == reference.joint_names
    q = np.concatenate([rng.uniform(-2.5, 2.5, 7), rng.uniform(0.0, 0.04, 2)])
    qd = np.concatenate([rng.normal(size=7), 0.1 * rng.normal(size=2)])
    limit = np.array([reference.limits[name].effort for name in names])
    tau = rng.uniform(-0.5, 0.5, 9) * limit      # within the limits: nothing is clamped
    sim.set_joint_state(dict(zip(names, q)), dict(zip(names, qd)))
    sim.set_joint_efforts(dict(zip(names, tau)))
    js = sim.joint_state()
    np.testing.assert_allclose(js.positions, q, atol=1e-12)
    expected = reference.forward_dynamics(q, qd, tau - reference.damping * qd)
    # bound: two solves of a 9-coordinate system (condition ~1e4 from the 0.1 kg fingers)
    # in double precision: 1e-16 · 1e4 · |q̈| ≈ 1e-12 |q̈| (measured 3e-14 |q̈|); 1e-10
    # relative leaves room for another CPU's last bits.
    scale = np.max(np.abs(expected))
    np.testing.assert_allclose(joint_accelerations(sim), expected, atol=1e-10 * scale)
    # The effort read back: the command that acted (none yet, then τ: no limit reached)
    # and the damping torque now.
    np.testing.assert_allclose(sim.joint_state().efforts, -reference.damping * qd,
                               rtol=1e-12)
    sim.step()
    js = sim.joint_state()
    np.testing.assert_allclose(js.efforts, tau - reference.damping * js.velocities,
                               rtol=1e-12, atol=1e-12)
    assert sim.joint_counters()['clamped_efforts'] == 0


def test_xacro_arm_is_its_two_link_closed_form(rng):
    length = 0.55
    sim = robot_sim('xacro_arm.urdf.xacro', xacro_args={'prefix': 'left_',
                                                        'link_length': str(length)})
    names = sim.joint_names()
    assert names == ['left_joint1', 'left_joint2']
    M, h = two_link_closed_form(xacro_arm_params(length))
    for _ in range(3):
        q, qd = rng.uniform(-2, 2, 2), rng.normal(size=2)
        sim.set_joint_state(dict(zip(names, q)), dict(zip(names, qd)))
        # bound: one 2x2 solve and the maximal-coordinate solve, rounding of O(100) terms.
        np.testing.assert_allclose(joint_accelerations(sim),
                                   np.linalg.solve(M(q), -h(q, qd)), atol=1e-11)


def test_planar_and_floating_joints_load_and_move():
    sim = robot_sim('floating_planar.urdf', gravity=False)
    assert sim.bodies.names == ['puck', 'drone', 'rotor']
    assert sim.joint_names() == ['rotor_joint']
    p0, q0 = sim.pose('drone')
    np.testing.assert_allclose(p0, [0.5, -0.3, 1.0], atol=1e-15)
    # Spinning the rotor by a joint command moves the drone's orientation the other way
    # (internal torque), not its position, and keeps the rotor on its axle.
    sim.set_joint_efforts({'rotor_joint': 0.01})
    sim.step(500)
    p1, q1 = sim.pose('drone')
    d = sim.diagnostics()
    # bound: no external wrench: the momenta stay zero to rounding of 500 steps.
    np.testing.assert_allclose(d.linear_momentum_world, 0.0, atol=1e-13)
    np.testing.assert_allclose(d.angular_momentum_world, 0.0, atol=1e-13)
    assert sim.joint_state().velocities[0] > 0.1
    turn = so3.quat_to_matrix(q1) @ so3.quat_to_matrix(q0).T
    assert np.arccos(np.clip((np.trace(turn) - 1) / 2, -1, 1)) > 1e-3
    assert max(sim.constraint_violation().values()) < 1e-9
