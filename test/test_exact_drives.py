"""
Exact joint drives (command groups of ``mode: exact``): a driving constraint ``q = q*``.

The drive is one more row of the multiplier solve, so the joint follows its target
exactly and its effort is the row's multiplier. References: the static torques and
forces in closed form, the joint-space inverse dynamics of ``joint_space_reference``
(RNEA/CRBA, its own parser), and the exponential closing of a violated constraint
that the solver states (``Φ_end = exp(−h / τ) Φ_start`` per step in the splittings).
"""

from joint_space_reference import JointSpaceModel, urdf_path
import numpy as np
import pytest
from rigid_body_sim.core import SpecError
from rigid_body_sim.core.robots import CommandGroup
from rigid_body_sim.scene import scene_from_dict
from robot_helpers import arm7_free_fingers, inertial, joint, joint_accelerations, link, robot

SPLITTINGS = ['symplectic_euler', 'lie_poisson2', 'lie_poisson4']
INTEGRATORS = SPLITTINGS + ['rkmk4']
G = 9.81
MASS, LENGTH = 1.5, 0.4          # kg, m: the pendulum's bob
I_AXLE = 0.6                     # kg m²: the wheel's moment about its axle


def scene(tmp_path, text, groups, gravity=True, integrator='lie_poisson2', dt=1e-3,
          **entry):
    """Load a scene of one URDF robot with command groups."""
    path = tmp_path / 'robot.urdf'
    path.write_text(text)
    data = {'dt': dt, 'integrator': integrator, 'robots': [dict(urdf=str(path), **entry)],
            'command_groups': groups}
    if gravity:
        data['effects'] = {'gravity': {'g_world': [0.0, 0.0, -G]}}
    return scene_from_dict(data, str(tmp_path / 'scene.yaml')).simulation


def pendulum_urdf():
    """Return a bob of MASS at LENGTH along x from a world hinge 'pivot' about y."""
    return robot('p', link('world'),
                 link('rod', inertial(MASS, (LENGTH, 0, 0), (0.2, -0.1, 0.3), ixx=0.01,
                                      iyy=0.02, izz=0.015)),
                 joint('pivot', 'continuous', 'world', 'rod', xyz=(0, 0, 1), axis=(0, 1, 0),
                       extra='<limit effort="1e9" velocity="1e9"/>'))


def pendulum(tmp_path, **kw):
    """Build the pendulum of :func:`pendulum_urdf` held by an exact drive (q tips it down)."""
    return scene(tmp_path, pendulum_urdf(), [{'name': 'hold', 'joints': ['pivot'],
                                             'interface': 'position', 'mode': 'exact'}], **kw)


def wheel(tmp_path, **kw):
    """Build a wheel on a world axle through its centre of mass (z), no gravity."""
    text = robot('w', link('world'),
                 link('wheel', inertial(2.0, ixx=0.3, iyy=0.4, izz=I_AXLE)),
                 joint('axle', 'continuous', 'world', 'wheel', xyz=(0, 0, 1), axis=(0, 0, 1),
                       extra='<limit effort="1e9" velocity="1e9"/>'))
    return scene(tmp_path, text, [{'name': 'motor', 'joints': ['axle'],
                                   'interface': 'position', 'mode': 'exact'}],
                 gravity=False, **kw)


def lift(tmp_path, **kw):
    """Build a block of MASS on a tilted prismatic joint to the world, under gravity."""
    text = robot('l', link('world'),
                 link('block', inertial(MASS, (0.05, 0.02, 0.1), (0.4, 0.1, -0.2))),
                 joint('slide', 'prismatic', 'world', 'block', xyz=(0.3, 0, 0.5),
                       rpy=(0.3, 0.2, 0.1), axis=(0, 0, 1)))
    sim = scene(tmp_path, text, [{'name': 'jack', 'joints': ['slide'],
                                  'interface': 'position', 'mode': 'exact'}], **kw)
    return sim


@pytest.mark.parametrize('integrator', INTEGRATORS)
def test_a_held_pendulum_stays_and_its_effort_is_the_static_torque(tmp_path, integrator):
    sim = pendulum(tmp_path, integrator=integrator, initial_positions={'pivot': 0.7})
    js = sim.joint_state()
    assert js.positions[0] == pytest.approx(0.7, abs=1e-14)
    # The bob at angle q about +y from +x sits at LENGTH (cos q, 0, −sin q): gravity's
    # torque about +y, r × F with F = −m g z, is +m g LENGTH cos q (it swings the bob
    # down), so the drive holds it with −m g LENGTH cos q.
    static = -MASS * G * LENGTH * np.cos(0.7)
    # bound: one multiplier solve of 6 rows (condition ~1e3 from the small moments): 1e-13
    # relative, with room for another CPU's last bits.
    assert js.efforts[0] == pytest.approx(static, rel=1e-10)
    sim.run(1.0)
    js = sim.joint_state()
    # bound: the drive row is held to SHAKE's tolerance (1e-13) or, for rkmk4, by the
    # velocity projection every step from rest (nothing moves): rounding, 1e-12.
    assert js.positions[0] == pytest.approx(0.7, abs=1e-12)
    assert abs(js.velocities[0]) < 1e-10
    assert js.efforts[0] == pytest.approx(static, rel=1e-10)


@pytest.mark.parametrize('integrator', INTEGRATORS)
def test_a_held_slider_carries_the_weight(tmp_path, integrator):
    # A tilted prismatic axis: the drive carries the weight's component along it.
    sim = lift(tmp_path, integrator=integrator, initial_positions={'slide': 0.2})
    axis_world = sim.joints.R_jp[0] @ sim.joints.axis[0]   # parent = the world
    static = MASS * G * axis_world[2]
    assert sim.joint_state().efforts[0] == pytest.approx(static, rel=1e-10)   # bound: above
    sim.run(0.5)
    js = sim.joint_state()
    assert js.positions[0] == pytest.approx(0.2, abs=1e-12)   # bound: as the pendulum's
    assert js.efforts[0] == pytest.approx(static, rel=1e-10)


@pytest.mark.parametrize('integrator', SPLITTINGS)
@pytest.mark.parametrize('builder, joint_name, jump',
                         [(wheel, 'axle', 0.3), (lift, 'slide', 0.05)])
def test_a_target_jump_closes_along_the_time_constant(tmp_path, integrator, builder,
                                                      joint_name, jump):
    sim = builder(tmp_path, integrator=integrator)
    q0 = sim.joint_state().positions[0]
    sim.command_joints({joint_name: q0 + jump})
    steps = 120
    sim.step(steps)
    # SHAKE ends each step on Φ = ρ Φ_start, ρ = exp(−dt / τ) (τ = 0.05 s, the scene's
    # default time constant), so after k steps q − q* = −jump ρ^k exactly, up to the
    # position tolerance per step (1e-13) accumulated over the steps: 1e-11.
    expected = -jump * np.exp(-steps * sim.dt / 0.05)
    assert sim.joint_state().positions[0] - (q0 + jump) == pytest.approx(expected, abs=1e-11)


def test_the_first_effort_of_a_jump_is_the_baumgarte_acceleration(tmp_path):
    # At rest, with Φ = −Δ and Φ̇ = 0, the acceleration-level solve asks for
    # q̈ = −2ωΦ̇ − ω²Φ = ω² Δ (ω = 1/τ = 20/s): the wheel's effort is I ω² Δ.
    sim = wheel(tmp_path)
    sim.command_joints({'axle': 0.3})
    effort = sim.joint_state().efforts[0]
    # bound: one solve on a principal-axis wheel, rounding of a few terms: 1e-12 relative.
    assert effort == pytest.approx(I_AXLE * 20.0**2 * 0.3, rel=1e-12)
    # And the joint then turns toward the target, the drive's effort being what turns it.
    sim.step(10)
    assert 0.0 < sim.joint_state().positions[0] < 0.3


def test_rkmk4_closes_a_jump_within_its_baumgarte_envelope(tmp_path):
    # rkmk4 stabilizes at the acceleration level, Φ̈ = −2ωΦ̇ − ω²Φ (critically damped,
    # Φ = −Δ (1 + ωt) e^{−ωt}), and projects velocities onto Φ̇ = −ωΦ each step; either
    # way the error is below Δ (1 + ωt) e^{−ωt}, 2.8e-4 Δ at ωt = 12.
    sim = wheel(tmp_path, integrator='rkmk4')
    sim.command_joints({'axle': 0.3})
    sim.run(0.6)
    error = abs(sim.joint_state().positions[0] - 0.3)
    assert error < 0.3 * (1 + 12.0) * np.exp(-12.0)
    assert error > 0.0


@pytest.mark.parametrize('seed', [1, 2, 3])
def test_exact_efforts_are_the_inverse_dynamics(seed, tmp_path):
    # arm7 with joints 2, 4, 6 driven exactly, the others free, at a random state where the
    # free joints move: the driven joints do not accelerate (Φ = Φ̇ = 0), the free ones
    # accelerate as M_ff q̈_f = −h_f − D_f q̇_f, and the drives' efforts are the inverse
    # dynamics τ_d = M_df q̈_f + h_d of that motion.
    rng = np.random.default_rng(seed)
    reference = JointSpaceModel.from_urdf(open(urdf_path('arm7.urdf')).read())
    driven = ['joint2', 'joint4', 'joint6']
    # (the fingers apart: without their mimic, which test_mimic_joints.py covers; limits
    # and friction off: the reference has neither)
    data = {'dt': 1e-3, 'robots': [{'urdf': arm7_free_fingers(tmp_path), 'limits': False,
                                    'friction': False}],
            'effects': {'gravity': {'g_world': [0.0, 0.0, -G]}},
            'command_groups': [{'name': 'exact', 'joints': driven, 'interface': 'position',
                                'mode': 'exact'}]}
    sim = scene_from_dict(data, urdf_path('scene.yaml')).simulation
    names = sim.joint_names()
    d = np.array([names.index(j) for j in driven])
    f = np.setdiff1d(np.arange(len(names)), d)
    q = np.concatenate([rng.uniform(-2.5, 2.5, 7), rng.uniform(0.0, 0.04, 2)])
    qd = np.concatenate([rng.normal(size=7), 0.1 * rng.normal(size=2)])
    qd[d] = 0.0
    sim.set_joint_state(dict(zip(names, q)), dict(zip(names, qd)))
    js = sim.joint_state()
    np.testing.assert_allclose(js.positions, q, atol=1e-12)
    np.testing.assert_allclose(js.velocities, qd, atol=1e-12)
    M = reference.mass_matrix(q)
    h = reference.bias(q, qd) + reference.damping * qd
    qdd = np.zeros(len(q))
    qdd[f] = np.linalg.solve(M[np.ix_(f, f)], -h[f])
    tau_d = M[np.ix_(d, f)] @ qdd[f] + h[d]
    # bound: as test_robot_dynamics' arm7 (solves of a 9-coordinate system, condition
    # ~1e4): 1e-12 of the scale, with room for another CPU's last bits: 1e-10.
    scale = np.max(np.abs(qdd))
    np.testing.assert_allclose(joint_accelerations(sim), qdd, atol=1e-10 * scale)
    np.testing.assert_allclose(js.efforts[d], tau_d, atol=1e-10 * np.max(np.abs(tau_d)))
    # The free joints report their damping only (no command, no drive).
    np.testing.assert_allclose(js.efforts[f], -reference.damping[f] * qd[f], rtol=1e-12)


def test_set_joint_state_moves_the_drive_target_and_reset_restores_it(tmp_path):
    sim = pendulum(tmp_path, initial_positions={'pivot': 0.2})
    sim.set_joint_state({'pivot': -0.5})
    sim.run(0.2)
    # bound: held as in test_a_held_pendulum... (SHAKE's tolerance, rounding): 1e-12.
    assert sim.joint_state().positions[0] == pytest.approx(-0.5, abs=1e-12)
    sim.command_joints({'pivot': 1.0})
    sim.run(0.2)
    sim.reset()
    assert sim.joint_state().positions[0] == pytest.approx(0.2, abs=1e-14)
    sim.run(0.2)
    assert sim.joint_state().positions[0] == pytest.approx(0.2, abs=1e-12)


def test_a_hinge_goes_the_shorter_way_to_its_target(tmp_path):
    # From 0 to 1.5 π: the row's Φ is taken in (−π, π], so the wheel turns −π/2.
    sim = wheel(tmp_path)
    sim.command_joints({'axle': 1.5 * np.pi})
    sim.run(1.0)
    # bound: 20 time constants: e^-20 of π/2 = 3e-9; the angle counts turns (tracked).
    assert sim.joint_state().positions[0] == pytest.approx(-0.5 * np.pi, abs=1e-8)


def test_exact_drive_specs_are_checked():
    assert CommandGroup('g', ['j'], interface='velocity', mode='exact').kd == 0.0
    with pytest.raises(SpecError, match='mode.*effort has nothing to hold'):
        CommandGroup('g', ['j'], interface='effort', mode='exact')
    with pytest.raises(SpecError, match='kp.*an exact drive has no gains'):
        CommandGroup('g', ['j'], interface='position', mode='exact', kp=10.0)
    with pytest.raises(SpecError, match="mode.*must be 'servo' or 'exact'"):
        CommandGroup('g', ['j'], interface='position', mode='stiff')


def test_a_drive_cannot_be_removed_or_named_by_users(tmp_path):
    sim = pendulum(tmp_path)
    assert 'pivot_drive' in sim.constraint_names
    before = sim.state.y.copy()
    with pytest.raises(SpecError, match="name.*'pivot_drive' is the exact drive of joint "
                                        "'pivot'"):
        sim.remove_constraint('pivot_drive')
    assert 'pivot_drive' in sim.constraint_names
    np.testing.assert_array_equal(sim.state.y, before)
    from rigid_body_sim.core import Constraint
    with pytest.raises(SpecError, match=r"type.*'drive' constraints are made by command "
                                        r'groups'):
        Constraint('d', 'drive', 'rod')


def test_a_drives_tracking_error_is_not_a_constraint_violation(tmp_path):
    sim = wheel(tmp_path)
    sim.command_joints({'axle': 0.3})
    sim.step(5)
    # The hinge holds to SHAKE's tolerance (1e-13, with room: 1e-11); the drive is still
    # 0.3 ρ^5 from its target, and says so per constraint.
    assert sim.diagnostics().constraint_violation < 1e-11
    expected = 0.3 * np.exp(-5 * sim.dt / 0.05)
    assert sim.constraint_violation()['axle_drive'] == pytest.approx(expected, abs=1e-11)


def test_drives_keep_their_joints_rows_independent_and_tree_solved():
    # A drive is its joint's sixth row on the joint's own pair of bodies: not a joint added
    # twice (redundant rows, a dense solve with a truncated SVD), not a loop. The arm keeps
    # the linear-time tree solve (its fingers' mimic row, over three bodies, is the loop
    # solve's one closure row), and no factorization meets a redundant row.
    from rigid_body_sim.core.kernels.layout import Solve
    # (friction off: its sticking rows would be rows of the component too)
    data = {'dt': 1e-3, 'effects': {'gravity': {'g_world': [0.0, 0.0, -G]}},
            'robots': [{'urdf': urdf_path('arm7.urdf'), 'friction': False}],
            'command_groups': [{'name': 'exact', 'joints': ['joint2', 'joint4', 'joint6'],
                                'interface': 'position', 'mode': 'exact'}]}
    sim = scene_from_dict(data, urdf_path('scene.yaml')).simulation
    [component] = sim.dynamics.solver.kernel_setup().components
    assert len(component.rows) == 9 * 5 + 3 + 1 and component.solve is Solve.LOOP
    closure = component.views['general_tree_closure']
    mimic = sim.dynamics.solver.constraints.rows_of('finger_joint2_mimic')
    assert component.rows[closure].tolist() == mimic.tolist()   # the mimic row alone
    sim.step(20)
    counters = sim.dynamics.solver.counters
    assert counters.factorizations > 0 and counters.rank_deficient_solves == 0
