"""
Effort-limited exact drives: the drive's row bounded by the URDF effort, ``|f| ≤ E``.

While the row would need more than ``E`` the drive is saturated: no row, a constant
effort ``σE``; it engages again where the row's law ``r = Φ̇ + ωΦ = 0`` holds (a
located event), without an impulse. References: the closed form of a wheel under a
constant torque and then on the law's exponential (no gravity, one coordinate), the
joint-space forward dynamics of ``joint_space_reference`` (CRBA/RNEA, its own parser)
for a pendulum falling against its saturated drive, and the joint-space mass matrix
for the impulse a command's projection needs (every joint driven: ``μ = M(q) r``).
"""

from joint_space_reference import JointSpaceModel
import numpy as np
import pytest
from rigid_body_sim.core.complementarity import solve_direct
from rigid_body_sim.core.limits import FORCE_TOLERANCE, RATE_TOLERANCE
from rigid_body_sim.scene import scene_from_dict, SceneError
from robot_helpers import inertial, joint, link, robot
from scipy.integrate import solve_ivp
from test_exact_drives import G, LENGTH, MASS
from test_exact_velocity_drives import ARM

I_AXLE = 0.6       # kg m²
EFFORT = 2.0       # N m


def build(tmp_path, text, interface, joints, time_constant=0.05, integrator='lie_poisson2',
          gravity=False, **entry):
    """Load one URDF robot whose ``joints`` are exact drives of ``interface``."""
    path = tmp_path / 'robot.urdf'
    path.write_text(text)
    data = {'dt': 1e-3, 'integrator': integrator, 'constraint_time_constant': time_constant,
            'robots': [dict(urdf=str(path), **entry)],
            'command_groups': [{'name': 'g', 'joints': list(joints), 'interface': interface,
                                'mode': 'exact'}]}
    if gravity:
        data['effects'] = {'gravity': {'g_world': [0.0, 0.0, -G]}}
    return scene_from_dict(data, str(tmp_path / 'scene.yaml')).simulation


def wheel_urdf(effort=EFFORT):
    """Return a wheel on a world axle (z) through its centre of mass, moment I_AXLE."""
    return robot('w', link('world'),
                 link('wheel', inertial(2.0, ixx=0.3, iyy=0.4, izz=I_AXLE)),
                 joint('axle', 'continuous', 'world', 'wheel', xyz=(0, 0, 1), axis=(0, 0, 1),
                       extra=f'<limit effort="{effort!r}" velocity="1e9"/>'))


@pytest.mark.parametrize('integrator', ['lie_poisson2', 'lie_poisson4', 'rkmk4'])
def test_a_wheel_asked_for_a_speed_lags_at_its_effort_then_catches_up(tmp_path, integrator):
    # v* = 3 rad/s from rest needs an impulse: the drive saturates at once and the wheel
    # turns at a = E/I, q = a t²/2, its target c = v* t running ahead. The law r = q̇ − v*
    # + ω (q − v* t) reaches 0 at the root t_e of ω a t²/2 + (a − ω v*) t − v* = 0;
    # there the row engages and holds r = 0: q = v* t + Φ_e exp(−ω (t − t_e)), which needs
    # I ω² |Φ_e| = 0.69 N m < E (ω = 1/s), so it stays engaged.
    v, omega = 3.0, 1.0
    sim = build(tmp_path, wheel_urdf(), 'velocity', ['axle'], time_constant=1.0 / omega,
                integrator=integrator)
    sim.command_joints({'axle': v})
    assert sim.drive_saturation()['saturated'] == {'axle': 1}
    a = EFFORT / I_AXLE
    t_e = max(np.roots([0.5 * omega * a, a - omega * v, -v]))
    phi_e = 0.5 * a * t_e**2 - v * t_e
    worst_q = worst_f = 0.0
    for _ in range(3000):
        sim.step()
        t = sim.time
        js = sim.joint_state()
        if t <= t_e:
            q, f = 0.5 * a * t * t, EFFORT
            reaction = sim.reactions()['axle_drive']['wheel']
            np.testing.assert_allclose(reaction.torque_com_world, [0.0, 0.0, EFFORT],
                                       atol=1e-12)
        else:
            q = v * t + phi_e * np.exp(-omega * (t - t_e))
            f = I_AXLE * omega**2 * phi_e * np.exp(-omega * (t - t_e))
        worst_q = max(worst_q, abs(js.positions[0] - q))
        worst_f = max(worst_f, abs(js.efforts[0] - f))
    assert sim.drive_saturation()['counters'] == {'saturations': 1, 'engagements': 1}
    # bound: the engagement is located to r within RATE_TOLERANCE, so the law's
    # exponential starts off by at most that rate over ω (1e-9 rad), and the
    # constant-torque arc is exact in these methods (rounding 1e-13); rkmk4's drift
    # (1e-11, test_exact_velocity_drives) with it.
    assert worst_q < RATE_TOLERANCE / omega + 1e-11
    # bound: the effort is E exactly while saturated; engaged, I ω² Φ of the row, off
    # by I ω² times the position bound (6e-10 N m) and ω times the rate tolerance.
    assert worst_f < I_AXLE * omega**2 * (RATE_TOLERANCE / omega + 1e-11) + 1e-9


def test_a_target_jump_is_closed_at_full_effort_never_more(tmp_path):
    # A jump of 0.3 rad with E = 2 N m: the projection's impulse I ω Δ = 3.6 N m s is far
    # beyond E dt, so the drive saturates at once; it then closes the jump in arcs of
    # ±E (each change located where the law holds), engages for good and holds the
    # target. The torque each step applies, I Δq̇ / dt, never exceeds E.
    sim = build(tmp_path, wheel_urdf(), 'position', ['axle'])
    sim.command_joints({'axle': 0.3})
    assert sim.drive_saturation()['saturated'] == {'axle': 1}
    rate, worst = 0.0, 0.0
    for _ in range(4000):
        sim.step()
        js = sim.joint_state()
        worst = max(worst, abs(I_AXLE * (js.velocities[0] - rate) / sim.dt))
        rate = js.velocities[0]
        # bound: an engaged row's force may pass E by FORCE_TOLERANCE of it before its
        # release is located.
        assert abs(js.efforts[0]) <= EFFORT * (1.0 + FORCE_TOLERANCE)
    # bound: that, and the rounding of the momentum difference (1e-16 of I q̇ / dt, q̇ <
    # 1 rad/s: 1e-13 of E).
    assert worst <= EFFORT * (1.0 + FORCE_TOLERANCE + 1e-12)
    assert sim.drive_saturation()['saturated'] == {}
    assert sim.drive_saturation()['counters']['saturations'] >= 2
    # Engaged since the last arc: Φ decays as exp(−ω t) (ω = 20/s): at rounding now.
    assert abs(js.positions[0] - 0.3) < 1e-12


def test_a_pendulum_beyond_its_effort_falls_with_the_effort_at_the_limit(tmp_path):
    # The bob of test_exact_drives held level by a position drive whose effort (3 N m) is
    # below its weight's torque (m g L = 5.9 N m): the first step finds the row's force
    # past E at its start, so the drive saturates there (a located event at t = 0) and
    # the bob falls under gravity and +E: M(q) q̈ + h(q, q̇) = E, integrated to 1e-12.
    effort = 3.0
    text = robot('p', link('world'),
                 link('rod', inertial(MASS, (LENGTH, 0, 0), (0.2, -0.1, 0.3), ixx=0.01,
                                      iyy=0.02, izz=0.015)),
                 joint('pivot', 'continuous', 'world', 'rod', xyz=(0, 0, 1), axis=(0, 1, 0),
                       extra=f'<limit effort="{effort!r}" velocity="1e9"/>'))
    sim = build(tmp_path, text, 'position', ['pivot'], gravity=True, integrator='lie_poisson4')
    reference = JointSpaceModel.from_urdf(text)
    hold = reference.inverse_dynamics([0.0], [0.0], [0.0])[0]   # what holding it takes
    assert abs(hold) > effort
    sign = 1.0 if hold > 0.0 else -1.0

    def rhs(_, y):
        return [y[1], reference.forward_dynamics(y[:1], y[1:], [sign * effort])[0]]

    times = 0.001 * np.arange(1, 201)
    ref = solve_ivp(rhs, (0.0, times[-1]), [0.0, 0.0], method='DOP853', t_eval=times,
                    rtol=1e-12, atol=1e-14)
    worst = 0.0
    for k in range(200):
        sim.step()
        js = sim.joint_state()
        assert sim.drive_saturation()['saturated'] == {'pivot': int(sign)}
        assert js.efforts[0] == sign * effort
        worst = max(worst, abs(js.positions[0] - ref.y[0, k]))
    assert sim.drive_saturation()['counters'] == {'saturations': 1, 'engagements': 0}
    # bound: lie_poisson4's error, C h⁴ t with |q̈| ~ 7 rad/s² (1e-11 at dt 1e-3 over
    # 0.2 s; its own measured constant is smaller), and the reference's 1e-12.
    assert 0.05 < abs(ref.y[0, -1])          # it fell
    assert worst < 1e-10


def test_a_commands_impulse_is_the_joint_space_mass_times_its_rate_jump(tmp_path):
    # Every joint of the 3-link arm driven: a command's velocity projection moves each q̇
    # by −r, so the impulse it needs is M(q) r, with r the laws' residuals after the
    # command (q̇ − v* for velocity drives from where they are).
    text = ARM.replace('effort="1e6"', 'effort="1e3"')
    sim = build(tmp_path, text, 'velocity', ['j1', 'j2', 'j3'], gravity=True)
    names = sim.joint_names()
    q = np.array([0.2, 0.5, -0.4])
    sim.set_joint_state(dict(zip(names, q)))
    v = np.array([0.7, -1.3, 2.1])
    sim.command_joints(dict(zip(names, v)))   # each impulse below E dt = 1 N m s: engaged
    assert sim.drive_saturation()['saturated'] == {}
    state = sim.state
    mu = sim.events._impulses([0, 1, 2], state)     # from each child side's momentum
    expected = JointSpaceModel.from_urdf(text).mass_matrix(q) @ (0.0 - v)
    # bound: the projections' rounding, 1e-13 of the impulses (< 1 N m s).
    np.testing.assert_allclose(mu, expected, atol=1e-12)
    # The probes (one projection per drive, for mechanisms that are not trees) agree.
    solver = sim.dynamics.solver
    vel, om = solver.project_velocities(state)
    probed = sim.events._probe_impulses([0, 1, 2], state, vel, om, vel - state.vel_com_world,
                                        om - state.ang_vel_principal)
    np.testing.assert_allclose(probed, expected, atol=1e-12)
    # A larger command saturates the joints whose impulse exceeds E dt, towards it.
    sim.command_joints({'j1': 400.0})
    assert sim.drive_saturation()['saturated'] == {'j1': 1}


def test_reset_and_a_state_set_engage_the_drives_and_unlimited_drives_jump(tmp_path):
    sim = build(tmp_path, wheel_urdf(), 'position', ['axle'])
    names = set(sim.constraint_names)
    sim.command_joints({'axle': 0.3})
    sim.step(10)
    assert sim.drive_saturation()['saturated'] == {'axle': 1}
    assert set(sim.constraint_names) == names        # the drive is still there
    assert set(sim.constraint_violation()) == names
    sim.set_joint_state({'axle': 0.1})
    assert sim.drive_saturation()['saturated'] == {}
    sim.step()
    assert abs(sim.joint_state().positions[0] - 0.1) < 1e-12
    sim.command_joints({'axle': 0.3})
    sim.reset()
    assert sim.drive_saturation()['saturated'] == {}
    sim.step(100)
    assert abs(sim.joint_state().positions[0]) < 1e-12
    # effort_limits: false: the unbounded drive, whose first effort after a jump is the
    # Baumgarte acceleration's I ω² Δ (test_exact_drives), here 36 N m > E.
    free = build(tmp_path, wheel_urdf(), 'position', ['axle'], effort_limits=False)
    assert free.drive_saturation() == {}
    free.command_joints({'axle': 0.3})
    assert free.joint_state().efforts[0] == pytest.approx(I_AXLE * 20.0**2 * 0.3, rel=1e-12)


def test_effort_limits_must_be_a_boolean(tmp_path):
    with pytest.raises(SceneError, match=r'robots\[0\].effort_limits.*true or false'):
        build(tmp_path, wheel_urdf(), 'position', ['axle'], effort_limits='yes')


def test_which_drives_a_command_saturates_is_the_lcp_of_their_impulses(tmp_path):
    # The 3-link arm from rest, every joint a velocity drive with E = 1 N m (E dt = 1e-3
    # N m s), commanded to v: the impulses with every drive engaged are M(q) v, all three
    # past E dt; but a saturated drive's missing impulse falls on the others: the box
    # LCP of the impulses (S = M⁻¹, |p| ≤ E dt) saturates j1 (towards −, against its own
    # engaged impulse's sign) and j2, and j3 stays engaged. Saturating each drive whose
    # own impulse is past its bound would saturate all three.
    text = ARM.replace('effort="1e6"', 'effort="1.0"')
    sim = build(tmp_path, text, 'velocity', ['j1', 'j2', 'j3'], gravity=True)
    names = sim.joint_names()
    q = np.array([0.2, 0.5, -0.4])
    sim.set_joint_state(dict(zip(names, q)))
    v = np.array([-0.358, 2.728, -0.001])
    M = JointSpaceModel.from_urdf(text).mass_matrix(q)
    p_star, b = M @ v, np.full(3, 1e-3)
    assert np.all(np.abs(p_star) > b)
    ref = solve_direct(np.linalg.inv(M), -np.linalg.solve(M, p_star), -b, b, start=p_star)
    assert list(ref.state) == [-1, 1, 0]
    sim.command_joints(dict(zip(names, v)))
    assert sim.drive_saturation()['saturated'] == {'j1': -1, 'j2': 1}
    sim.step()
    # j3's drive engaged: its rate is v3 after the step's projection (to the law's
    # ω Φ, Φ of order the step's own error: far below 1e-9).
    assert abs(sim.joint_state().velocities[2] - v[2]) <= 1e-9
