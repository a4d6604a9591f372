"""Joint drives: passive URDF damping (an exact flow) and PD servos, against references."""

from joint_space_reference import JointSpaceModel, urdf_path
import numpy as np
import pytest
from rigid_body_sim.core import rotation as so3
from rigid_body_sim.core import SpecError
from rigid_body_sim.scene import scene_from_dict, SceneError
from robot_helpers import arm7_free_fingers, inertial, joint, joint_accelerations, link, robot

SPLITTINGS = ['symplectic_euler', 'lie_poisson2', 'lie_poisson4']
I_AXLE = 0.5   # kg m², the wheel's moment about its axle


def wheel(tmp_path, damping=0.0, groups=None, integrator='lie_poisson2', dt=1e-3,
          rpy=(0.3, -0.2, 0.1)):
    """Build a wheel on a world axle through its centre of mass (no gravity torque)."""
    extra = f'<dynamics damping="{float(damping)!r}"/>' if damping else ''
    text = robot('w', link('world'),
                 link('wheel', inertial(2.0, (0, 0, 0), rpy, ixx=0.3, iyy=0.4,
                                        izz=0.6)),
                 joint('axle', 'continuous', 'world', 'wheel', xyz=(0, 0, 1), axis=(0, 0, 1),
                       extra=extra + '<limit effort="1e9" velocity="1e9"/>'))
    path = tmp_path / 'wheel.urdf'
    path.write_text(text)
    data = {'dt': dt, 'integrator': integrator, 'robots': [{'urdf': str(path)}]}
    if groups:
        data['command_groups'] = groups
    sim = scene_from_dict(data, str(tmp_path / 's.yaml')).simulation
    return sim


def axle_moment(sim):
    """Return the wheel's moment of inertia about the world z axle, ``zᵀ I z``."""
    R = so3.quat_to_matrix(sim.state.quat_principal_world[0])
    return float((R @ np.diag(sim.bodies.moments[0]) @ R.T)[2, 2])


@pytest.mark.parametrize('integrator', SPLITTINGS)
def test_joint_damping_is_an_exact_flow(tmp_path, integrator):
    # A wheel whose principal axis is its axle: the joint's flow is the motion itself.
    # d c dt = 20, far beyond any explicit method's stability.
    moment = axle_moment(wheel(tmp_path, rpy=(0, 0, 0)))
    d = 20.0 * moment / 1e-3
    sim = wheel(tmp_path, damping=d, integrator=integrator, rpy=(0, 0, 0))
    sim.set_joint_state({'axle': 0.0}, {'axle': 3.0})
    sim.step(3)
    # bound: the flow is exact and nothing else acts about the axle; what is left is the
    # rounding of exp and of three projections (1e-15 relative), with room: 1e-12.
    expected = 3.0 * np.exp(-d / moment * 3e-3)
    js = sim.joint_state()
    assert js.velocities[0] == pytest.approx(expected, rel=1e-12)
    # The effort read back is the damping torque now.
    assert js.efforts[0] == pytest.approx(-d * js.velocities[0], rel=1e-12)


def test_joint_damping_converges_on_a_skewed_wheel(tmp_path):
    # Principal axes off the axle: the joint's flow moves the wheel off its axle and the
    # projection brings it back, a splitting of order 2 (lie_poisson2).
    moment = axle_moment(wheel(tmp_path))
    d = 2.0 * moment
    errors = []
    for dt in (4e-3, 2e-3):
        sim = wheel(tmp_path, damping=d, dt=dt)
        sim.set_joint_state({'axle': 0.0}, {'axle': 3.0})
        sim.step(int(round(1.0 / dt)))
        errors.append(abs(sim.joint_state().velocities[0] - 3.0 * np.exp(-d / moment)))
    # bound: halving dt divides an order-2 error by 4, within a factor 1.25.
    assert 4.0 / 1.25 < errors[0] / errors[1] < 4.0 * 1.25
    # Stiff damping (d c dt = 200) stays stable and only slows the wheel.
    sim = wheel(tmp_path, damping=200.0 * moment / 1e-3)
    sim.set_joint_state({'axle': 0.0}, {'axle': 3.0})
    rates = []
    for _ in range(5):
        sim.step(2)
        rates.append(sim.joint_state().velocities[0])
    assert np.all(np.diff(np.abs(rates)) <= 0.0) and abs(rates[-1]) < 1e-6


def test_rkmk4_refuses_damping_it_cannot_hold(tmp_path):
    moment = axle_moment(wheel(tmp_path))
    with pytest.raises(SceneError, match=r"joints\.axle\.dynamics\.damping: joint 'axle'.*> 1"):
        wheel(tmp_path, damping=4.0 * moment / 1e-3, integrator='rkmk4')
    sim = wheel(tmp_path, damping=0.5 * moment / 1e-3, integrator='rkmk4')
    sim.set_joint_state({'axle': 0.0}, {'axle': 3.0})
    # Held: the rate decays by RK4's factor at d c dt = 0.5 each step (0.607).
    factor = 1.0 - 0.5 + 0.5 ** 2 / 2.0 - 0.5 ** 3 / 6.0 + 0.5 ** 4 / 24.0
    sim.step(20)
    # bound: 20 steps' rounding of a rate that started at 3 rad/s, a few ulps of 3 (1e-15)
    # on 1.4e-4 rad/s: 1e-11 relative, 1e-9 with room.
    np.testing.assert_allclose(sim.joint_state().velocities[0], 3.0 * factor ** 20, rtol=1e-9)
    sim.step(80)
    # After 100 steps the factor leaves 6e-22 rad/s, below the rate's own rounding: the rate
    # is zero to a few ulps of the 3 rad/s it started from (1e-13: 150 ulps), of either sign.
    assert abs(sim.joint_state().velocities[0]) <= 1e-13


@pytest.mark.parametrize('seed', [4, 5])
def test_damped_arm_accelerations_are_the_joint_space_dynamics(seed, tmp_path):
    # arm7 damps joints 1, 2, 4, 6 and 7: q̈ = M⁻¹ (τ − h − D q̇), compiled and numpy paths
    # (the fingers apart: without their mimic, which test_mimic_joints.py covers).
    rng = np.random.default_rng(seed)
    reference = JointSpaceModel.from_urdf(open(urdf_path('arm7.urdf')).read())
    # (limits and friction off: the random states may lie beyond the limits, and the
    # reference has neither)
    sim = scene_from_dict({'dt': 1e-3, 'effects': {'gravity': {}},
                           'robots': [{'urdf': arm7_free_fingers(tmp_path), 'limits': False,
                                       'friction': False}]},
                          urdf_path('s.yaml')).simulation
    names = sim.joint_names()
    q = np.concatenate([rng.uniform(-2.5, 2.5, 7), rng.uniform(0.0, 0.04, 2)])
    qd = np.concatenate([3.0 * rng.normal(size=7), 0.1 * rng.normal(size=2)])
    sim.set_joint_state(dict(zip(names, q)), dict(zip(names, qd)))
    expected = reference.forward_dynamics(q, qd, -reference.damping * qd)
    assert np.count_nonzero(reference.damping) == 5
    # bound: as test_arm7_accelerations_are_the_joint_space_dynamics: 1e-10 relative.
    np.testing.assert_allclose(joint_accelerations(sim), expected,
                               atol=1e-10 * np.max(np.abs(expected)))
    np.testing.assert_allclose(sim.joint_state().efforts, -reference.damping * qd, rtol=1e-12)


def test_damping_only_removes_energy(tmp_path):
    sim = scene_from_dict({'dt': 1e-3, 'integrator': 'lie_poisson2',
                           'robots': [{'urdf': urdf_path('arm7.urdf')}]},
                          urdf_path('s.yaml')).simulation
    names = sim.joint_names()
    sim.set_joint_state({}, dict(zip(names, np.r_[np.linspace(-2, 2, 7), 0.0, 0.0])))
    energy = [sim.diagnostics().kinetic_energy.sum()]
    for _ in range(20):
        sim.step(25)
        energy.append(sim.diagnostics().kinetic_energy.sum())
    assert energy[-1] < 0.99 * energy[0]
    # bound: no gravity, no drive: the kinetic energy can only fall; the splitting's own
    # energy error is O(dt²) relative (1e-6 here), below each 25-step loss.
    assert np.all(np.diff(energy) < 0.0)


def servo_wheel(tmp_path, kp, kd, interface='position', dt=1e-3, integrator='lie_poisson2'):
    return wheel(tmp_path, groups=[{'name': 'g', 'joints': ['axle'], 'interface': interface,
                                    'kp': kp, 'kd': kd}], integrator=integrator, dt=dt)


def oscillator(q0, target, kp, kd, moment, t):
    """q(t) of I q̈ = kp (target − q) − kd q̇, q(0) = q0, q̇(0) = 0 (underdamped)."""
    wn, zeta = np.sqrt(kp / moment), kd / (2.0 * np.sqrt(kp * moment))
    wd = wn * np.sqrt(1.0 - zeta ** 2)
    e0 = q0 - target
    decay = np.exp(-zeta * wn * t)
    return target + e0 * decay * (np.cos(wd * t) + zeta * wn / wd * np.sin(wd * t))


@pytest.mark.parametrize('integrator, order', [('lie_poisson2', 2), ('lie_poisson4', 4)])
def test_position_servo_is_a_damped_oscillator(tmp_path, integrator, order):
    # The spring in the kicks, the rate term an exact flow: each splitting keeps its order.
    kp, kd = 40.0, 2.0
    moment = axle_moment(wheel(tmp_path))
    errors = []
    for dt in (4e-3, 2e-3):
        sim = servo_wheel(tmp_path, kp, kd, dt=dt, integrator=integrator)
        sim.command_joints({'axle': 0.8})
        sim.step(int(round(1.0 / dt)))
        errors.append(abs(sim.joint_state().positions[0]
                          - oscillator(0.0, 0.8, kp, kd, moment, 1.0)))
    # bound: an order-p method's global error falls by 2^p when dt halves, within 1.25.
    assert 2 ** order / 1.25 < errors[0] / errors[1] < 2 ** order * 1.25
    assert errors[1] < 1e-3


def test_velocity_servo_reaches_its_speed(tmp_path):
    kd = 2.0
    moment = axle_moment(wheel(tmp_path))
    sim = servo_wheel(tmp_path, 0.0, kd, interface='velocity')
    sim.command_joints({'axle': 5.0})
    sim.step(1000)
    # bound: first-order lag v* (1 − exp(−kd t / I)), integrated to O(dt²) (1e-6 here).
    assert sim.joint_state().velocities[0] == pytest.approx(
        5.0 * (1.0 - np.exp(-kd / moment)), abs=1e-4)
    js = sim.joint_state()
    assert js.efforts[0] == pytest.approx(kd * (5.0 - js.velocities[0]), rel=1e-12)


def test_servo_holds_a_robot_against_gravity():
    # A position-servoed arm7 settles where kp (q* − q) = g(q): its effort is the torque
    # gravity takes, which the joint-space reference computes independently.
    names = [f'joint{i}' for i in range(1, 8)]
    groups = [{'name': 'arm', 'joints': names, 'interface': 'position', 'kp': 400.0,
               'kd': 20.0},
              {'name': 'hand', 'joints': ['finger_joint1', 'finger_joint2'],
               'interface': 'position', 'kp': 100.0, 'kd': 5.0}]
    # (friction off: it would hold the arm anywhere within ±F of that balance)
    sim = scene_from_dict({'dt': 1e-3, 'effects': {'gravity': {}}, 'command_groups': groups,
                           'robots': [{'urdf': urdf_path('arm7.urdf'), 'friction': False}]},
                          urdf_path('s.yaml')).simulation
    target = np.array([0.3, -0.5, 0.2, -1.5, 0.1, 1.2, 0.4])
    sim.command_joints(dict(zip(names + ['finger_joint1', 'finger_joint2'],
                                np.r_[target, 0.02, 0.02])))
    sim.step(6000)
    js = sim.joint_state()
    reference = JointSpaceModel.from_urdf(open(urdf_path('arm7.urdf')).read())
    gravity = reference.bias(js.positions, np.zeros(9))
    assert np.max(np.abs(js.velocities)) < 1e-6
    # bound: at rest the servo balances gravity; a rate below 1e-6 rad/s times kd leaves
    # at most 2e-5 N m of imbalance, and the joint damping a further d q̇ (3e-7).
    np.testing.assert_allclose(js.efforts[:7], gravity[:7], atol=1e-4)
    np.testing.assert_allclose(400.0 * (target - js.positions[:7]), gravity[:7], atol=1e-4)


def test_servo_effort_is_clamped_to_the_limit(tmp_path):
    text = robot('r', link('world'), link('a', inertial(1.0, ixx=0.1, iyy=0.1, izz=0.1)),
                 joint('j', 'revolute', 'world', 'a', axis=(0, 0, 1),
                       extra='<limit effort="0.5" velocity="10" lower="-3" upper="3"/>'))
    path = tmp_path / 'robot.urdf'
    path.write_text(text)
    sim = scene_from_dict({'dt': 1e-3, 'robots': [{'urdf': str(path)}],
                           'command_groups': [{'name': 'g', 'joints': ['j'],
                                               'interface': 'position', 'kp': 50.0,
                                               'kd': 1.0}]},
                          str(tmp_path / 's.yaml')).simulation
    sim.command_joints({'j': 2.0})
    sim.step(100)
    js = sim.joint_state()
    assert js.efforts[0] == 0.5
    # bound: constant 0.5 N m on 0.1 kg m² for 0.1 s: q = 1/2 (5 rad/s²) t² = 0.025 rad,
    # integrated exactly by the splitting up to rounding.
    assert js.positions[0] == pytest.approx(0.025, rel=1e-9)


def test_unstable_gains_are_refused_with_the_bound(tmp_path):
    moment = axle_moment(wheel(tmp_path))
    kp = 2.0 * moment / 1e-6           # ω dt = sqrt(2): past the bound of 1
    with pytest.raises(SceneError, match=r"command_groups\.g: joint 'axle': kp .* > 1"):
        servo_wheel(tmp_path, kp, 0.0)
    sim = servo_wheel(tmp_path, 0.5 * moment / 1e-6, 0.0)
    with pytest.raises(SpecError, match=r'> 1'):
        sim.set_step(dt=2e-3)
    assert sim.dt == 1e-3
    # The same question without the change (the node asks it before a parameter changes).
    with pytest.raises(SpecError, match=r'> 1'):
        sim.check_step(dt=2e-3)
    assert sim.check_step(dt=0.5e-3)[0] == 0.5e-3 and sim.dt == 1e-3


@pytest.mark.parametrize('group, match', [
    ({'name': 'g', 'joints': ['axle'], 'interface': 'torque'}, r'interface: must be'),
    ({'name': 'g', 'joints': ['axle'], 'interface': 'position', 'mode': 'exact', 'kp': 1.0},
     r'kp: an exact drive has no gains'),
    ({'name': 'g', 'joints': ['axle'], 'interface': 'effort', 'mode': 'exact'},
     r"mode: 'exact' drives exist for the position and velocity interfaces .*nothing to "
     r'hold'),
    ({'name': 'g', 'joints': ['axle'], 'interface': 'velocity', 'mode': 'exact', 'kd': 1.0},
     r'kd: an exact drive has no gains'),
    ({'name': 'g', 'joints': ['axle'], 'interface': 'position'}, r'kp: a position servo'),
    ({'name': 'g', 'joints': ['nope'], 'interface': 'effort'},
     r"joints\[0\]: unknown joint 'nope'"),
    ({'name': 'g', 'joints': 'axle'}, r'joints: expected a non-empty list'),
])
def test_bad_command_groups_are_named(tmp_path, group, match):
    with pytest.raises(SceneError, match=r'command_groups\[0\]\.' + match):
        wheel(tmp_path, groups=[group])


def test_bad_commands_change_nothing(tmp_path):
    sim = servo_wheel(tmp_path, 10.0, 1.0)
    sim.command_joints({'axle': 0.3})
    sim.step(10)
    before = sim.state.y.copy()
    for bad, match in (({'axle': float('nan')}, r'values\.axle'),
                       ({'x': 1.0}, r'values\.x: unknown joint'), ([1.0], r'expected a mapping')):
        with pytest.raises(SpecError, match=match):
            sim.command_joints(bad)
    np.testing.assert_array_equal(sim.state.y, before)
    assert sim.drives.q_target[0] == 0.3
