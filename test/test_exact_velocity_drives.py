"""
Exact velocity drives (``interface: velocity, mode: exact``): a moving driving constraint.

The drive holds ``q − c(t) = 0`` with ``c(t) = c₀ + v* (t − t₀)``, one more row of the
multiplier solve, so the joint follows ``q̇ = v*`` exactly and its effort is the row's
multiplier. References: the straight line ``q₀ + v* t`` itself, the joint-space inverse
dynamics of ``joint_space_reference`` (RNEA, its own parser: a joint moving at constant
rates needs ``τ = RNEA(q, v*, 0)``), and the statics of a slider moving at constant
speed. Bounds: SHAKE ends every (sub)step on ``Φ = exp(−h/τ) Φ_start`` to its position
tolerance (1e-13), and the velocity projection on ``G ν = ċ − ωΦ`` (ω = 1/τ = 20/s).
"""

from joint_space_reference import JointSpaceModel
import numpy as np
import pytest
from rigid_body_sim.core import SpecError
from robot_helpers import inertial, joint, link, robot
from test_exact_drives import G, I_AXLE, INTEGRATORS, MASS, pendulum_urdf, scene, SPLITTINGS

OMEGA = 20.0     # 1/s: the Baumgarte rate, 1 / the default time constant (0.05 s)
SHAKE_TOL = 1e-13   # rad or m: SHAKE's position tolerance, per (sub)step
#: rad or m: a splitting's tracking error, SHAKE's tolerance plus the rounding of the
#: target c (a few ulps of |c| <= 100 rad: 1e-13), with room for another CPU's last bits.
TRACK = 1e-12
#: rkmk4 has no position correction: its O(h⁵) drift per step decays through the
#: velocity target, ~1e-12 at dt = 1e-3 (the integrators module's measurement), x10.
TRACK_RKMK4 = 1e-11


def track_bound(integrator):
    """Return the tracking error bound of ``integrator`` (see TRACK, TRACK_RKMK4)."""
    return TRACK_RKMK4 if integrator == 'rkmk4' else TRACK


def velocity_group(joints):
    """Return one command group of exact velocity drives."""
    return [{'name': 'turn', 'joints': list(joints), 'interface': 'velocity',
             'mode': 'exact'}]


def pendulum(tmp_path, **kw):
    """Return the bob of ``test_exact_drives.pendulum_urdf``, its pivot turned at v*."""
    return scene(tmp_path, pendulum_urdf(), velocity_group(['pivot']), **kw)


def wheel(tmp_path, rpy=(0.0, 0.0, 0.0), **kw):
    """Build a wheel on a world axle (z) through its centre of mass, no gravity."""
    text = robot('w', link('world'),
                 link('wheel', inertial(2.0, rpy=rpy, ixx=0.3, iyy=0.4, izz=I_AXLE)),
                 joint('axle', 'continuous', 'world', 'wheel', xyz=(0, 0, 1), axis=(0, 0, 1),
                       extra='<limit effort="1e9" velocity="1e9"/>'))
    return scene(tmp_path, text, velocity_group(['axle']), gravity=False, **kw)


ARM = robot('arm', link('world'),
            link('l1', inertial(1.2, (0.05, 0.0, 0.2), (0.1, 0.2, 0.3), ixx=0.02, iyy=0.03,
                                izz=0.01)),
            link('l2', inertial(0.8, (0.15, 0.02, 0.0), (0.3, -0.1, 0.2), ixx=0.004, iyy=0.01,
                                izz=0.012)),
            link('l3', inertial(0.5, (0.1, 0.0, 0.01), (0.0, 0.4, 0.0), ixx=0.002, iyy=0.003,
                                izz=0.004)),
            joint('j1', 'revolute', 'world', 'l1', xyz=(0, 0, 0.1), axis=(0, 0, 1)),
            joint('j2', 'revolute', 'l1', 'l2', xyz=(0, 0, 0.4), rpy=(0.2, 0, 0),
                  axis=(0, 1, 0)),
            joint('j3', 'continuous', 'l2', 'l3', xyz=(0.3, 0, 0), axis=(0, 0.6, 0.8),
                  extra='<limit effort="1e6" velocity="1e6"/>'))


def start(sim, positions, velocities):
    """Command ``velocities`` ({joint: v*}), then put the joints at ``positions`` moving so."""
    sim.command_joints(velocities)
    sim.set_joint_state(positions)   # the targets restart there; q̇ projected onto v*


@pytest.mark.parametrize('integrator', INTEGRATORS)
def test_a_driven_pendulum_follows_the_line_at_every_step(tmp_path, integrator):
    # Under gravity the bob needs a torque that changes with the angle; the drive gives
    # it, and q = q0 + v t at every step end, q̇ = v.
    sim = pendulum(tmp_path, integrator=integrator)
    q0, v = 0.3, 2.0
    start(sim, {'pivot': q0}, {'pivot': v})
    worst_q = worst_v = 0.0
    for _ in range(300):
        sim.step()
        js = sim.joint_state()
        worst_q = max(worst_q, abs(js.positions[0] - (q0 + v * sim.time)))
        worst_v = max(worst_v, abs(js.velocities[0] - v))
    assert worst_q < track_bound(integrator)
    # bound: the projection puts G ν = v − ωΦ, |Φ| below the tracking bound; plus the
    # projection's rounding (1e-14 of v): ω times the bound, + 1e-12.
    assert worst_v < OMEGA * track_bound(integrator) + 1e-12


@pytest.mark.parametrize('integrator', INTEGRATORS)
def test_the_efforts_of_a_moving_arm_are_its_inverse_dynamics(tmp_path, integrator):
    # A 3-link arm (skewed axes and inertias) under gravity, every joint on an exact
    # velocity drive: q = q0 + v t, q̈ = 0, so each drive's effort is RNEA(q, v, 0).
    reference = JointSpaceModel.from_urdf(ARM)
    sim = scene(tmp_path, ARM, velocity_group(['j1', 'j2', 'j3']), integrator=integrator)
    names = sim.joint_names()
    q0, v = np.array([0.2, 0.5, -0.4]), np.array([0.7, -1.3, 2.1])
    start(sim, dict(zip(names, q0)), dict(zip(names, v)))
    worst_q = worst_tau = scale = 0.0
    for k in range(301):
        if k:
            sim.step()
        js = sim.joint_state()
        q = q0 + v * sim.time
        tau = reference.inverse_dynamics(q, v, np.zeros(3))
        scale = max(scale, np.max(np.abs(tau)))
        worst_q = max(worst_q, np.max(np.abs(js.positions - q)))
        worst_tau = max(worst_tau, np.max(np.abs(js.efforts - tau)))
    assert worst_q < track_bound(integrator)
    # bound: the multipliers see Φ and Φ̇ = G ν − v at the tracking bound e and ωe: the
    # Baumgarte terms ask ω² e + 2ω² e = 1.2e-9 (rkmk4) rad/s², times the joint-space
    # inertia (< 0.1 kg m²) 1.2e-10 N m; and the solve's rounding, 1e-12 of the scale
    # (as the arm7 test's): 1e-10 of the scale, with room (scale 3 N m).
    assert worst_tau < 1e-10 * scale + 3 * OMEGA**2 * track_bound(integrator) * 0.1


@pytest.mark.parametrize('integrator', SPLITTINGS)
def test_a_new_velocity_continues_from_where_the_target_is(tmp_path, integrator):
    # v changes from 2 to −1 rad/s mid-run: q stays continuous and follows the new line
    # from the switch, q_s + v2 (t − t_s), exactly (SHAKE lands on the target of each step
    # end, the step of the switch too: it started on its target).
    sim = pendulum(tmp_path, integrator=integrator)
    q0, v1, v2 = 0.3, 2.0, -1.0
    start(sim, {'pivot': q0}, {'pivot': v1})
    sim.step(100)
    t_s = sim.time
    q_s = q0 + v1 * t_s
    assert sim.joint_state().positions[0] == pytest.approx(q_s, abs=TRACK)
    sim.command_joints({'pivot': v2})
    for _ in range(100):
        sim.step()
        js = sim.joint_state()
        assert js.positions[0] == pytest.approx(q_s + v2 * (sim.time - t_s), abs=TRACK)
    # bound: as test_a_driven_pendulum_follows_the_line_at_every_step.
    assert js.velocities[0] == pytest.approx(v2, abs=OMEGA * TRACK + 1e-12)


def test_rkmk4_takes_a_new_velocity_within_its_baumgarte_envelope(tmp_path):
    # rkmk4 has no position correction: in the step of the switch the acceleration-level
    # solve asks Φ̈ = −2ωΦ̇ − ω²Φ from Φ = 0, Φ̇ = v1 − v2, which leaves |Φ| <= |Δv| dt;
    # the velocity projection then puts Φ̇ = −ωΦ: Φ decays as exp(−ωt). q stays continuous.
    sim = pendulum(tmp_path, integrator='rkmk4')
    q0, v1, v2 = 0.3, 2.0, -1.0
    start(sim, {'pivot': q0}, {'pivot': v1})
    sim.step(100)
    t_s = sim.time
    q_s = q0 + v1 * t_s
    sim.command_joints({'pivot': v2})
    dv, dt = abs(v1 - v2), sim.dt
    for _ in range(200):
        sim.step()
        error = abs(sim.joint_state().positions[0] - (q_s + v2 * (sim.time - t_s)))
        # bound: |Δv| dt, decaying from the end of the first step (+ the tracking bound)
        assert error <= dv * dt * np.exp(-OMEGA * (sim.time - t_s - dt)) + TRACK_RKMK4
    assert error > 0.0   # (no position correction: the closing is the projection's)


@pytest.mark.parametrize('integrator', INTEGRATORS)
def test_a_wheel_turns_many_revolutions(tmp_path, integrator):
    # 100 rad/s for 2 s: 32 turns. The angle row takes θ − c in (−π, π] with c counting
    # turns; the joint angle counts them too. About its principal axis the wheel needs no
    # torque at constant speed.
    sim = wheel(tmp_path, integrator=integrator)
    v = 100.0
    start(sim, {'axle': 0.5}, {'axle': v})
    worst = 0.0
    for _ in range(20):
        sim.step(100)
        worst = max(worst, abs(sim.joint_state().positions[0] - (0.5 + v * sim.time)))
    js = sim.joint_state()
    assert js.positions[0] > 0.5 + 2 * np.pi * 31
    # bound: the tracking bound, with c up to 200 rad (its ulp 2.8e-14: TRACK covers it).
    assert worst < track_bound(integrator)
    assert js.velocities[0] == pytest.approx(v, abs=OMEGA * track_bound(integrator) + 1e-12)
    # bound: I_AXLE times the Baumgarte acceleration of the tracking error (ω² e + 2ω² e).
    assert abs(js.efforts[0]) < I_AXLE * 3 * OMEGA**2 * track_bound(integrator) + 1e-11


@pytest.mark.parametrize('integrator', INTEGRATORS)
def test_a_wheel_too_fast_for_one_step_is_sub_stepped_and_tracks(tmp_path, integrator):
    # 600 rad/s at dt = 1e-3 turns 0.6 rad a step: 3 sub-steps (max_rotation 0.25 rad),
    # each ending on the target of its own time.
    sim = wheel(tmp_path, integrator=integrator)
    v = 600.0
    start(sim, {'axle': 0.0}, {'axle': v})
    worst = 0.0
    for _ in range(100):
        sim.step()
        worst = max(worst, abs(sim.joint_state().positions[0] - v * sim.time))
    assert sim.work()['substeps'] == 3 * 100
    assert worst < track_bound(integrator)   # bound: as above (c up to 60 rad)


@pytest.mark.parametrize('integrator, dt', [('symplectic_euler', 2e-2),
                                            ('lie_poisson4', 3e-2)])
def test_redone_steps_restart_the_targets(tmp_path, integrator, dt):
    # A wheel whose axle is not a principal axis, at 100 rad/s and 2 or 3 rad a step with
    # the up-front sub-steps off: SHAKE's iterations stop converging in some steps, which
    # are redone with twice the sub-steps from the step's start, targets included (a
    # target left where the failed attempt put it would be off by v dt = 2 or 3 rad).
    sim = wheel(tmp_path, rpy=(0.3, 0.2, 0.1), integrator=integrator, dt=dt)
    sim.integrator.max_rotation = None
    v = 100.0
    start(sim, {'axle': 0.0}, {'axle': v})
    worst = 0.0
    for _ in range(30):
        sim.step()
        worst = max(worst, abs(sim.joint_state().positions[0] - v * sim.time))
    assert sim.work()['retries'] > 0
    assert sim.dynamics.solver.counters.projection_fallbacks == 0
    assert worst < TRACK   # bound: SHAKE's tolerance per sub-step, as above


@pytest.mark.parametrize('integrator', INTEGRATORS)
def test_a_slider_moves_at_its_speed_carrying_the_weight(tmp_path, integrator):
    # A block on a tilted prismatic axis under gravity, driven at 0.2 m/s: at constant
    # speed the drive carries the weight's component along the axis, as at rest.
    text = robot('l', link('world'),
                 link('block', inertial(MASS, (0.05, 0.02, 0.1), (0.4, 0.1, -0.2))),
                 joint('slide', 'prismatic', 'world', 'block', xyz=(0.3, 0, 0.5),
                       rpy=(0.3, 0.2, 0.1), axis=(0, 0, 1)))
    sim = scene(tmp_path, text, velocity_group(['slide']), integrator=integrator)
    v = 0.2
    start(sim, {'slide': -0.1}, {'slide': v})
    axis_world = sim.joints.R_jp[0] @ sim.joints.axis[0]   # parent = the world
    static = MASS * G * axis_world[2]
    worst = 0.0
    for _ in range(500):
        sim.step()
        worst = max(worst, abs(sim.joint_state().positions[0] - (-0.1 + v * sim.time)))
    js = sim.joint_state()
    assert worst < track_bound(integrator)
    assert js.velocities[0] == pytest.approx(v, abs=OMEGA * track_bound(integrator) + 1e-12)
    # bound: one multiplier solve (1e-10 relative, as test_exact_drives' slider) and the
    # Baumgarte terms on the tracking error times the mass (3 ω² e MASS).
    assert js.efforts[0] == pytest.approx(
        static, abs=1e-10 * static + 3 * OMEGA**2 * track_bound(integrator) * MASS)


def test_a_velocity_command_starts_from_rest_without_a_position_jump(tmp_path):
    # Commanded while the pendulum is held at rest (v* = 0 after loading): the target
    # moves from where it is, so after the first step the joint has moved by v dt, exactly.
    sim = pendulum(tmp_path, initial_positions={'pivot': 0.4})
    assert sim.joint_interfaces() == {'pivot': 'velocity'}
    sim.run(0.1)
    q_s = sim.joint_state().positions[0]
    assert q_s == pytest.approx(0.4, abs=TRACK)   # held: v* = 0 from the start
    t_s = sim.time
    sim.command_joints({'pivot': 1.5})
    sim.step(50)
    js = sim.joint_state()
    assert js.positions[0] == pytest.approx(q_s + 1.5 * (sim.time - t_s), abs=TRACK)
    assert js.velocities[0] == pytest.approx(1.5, abs=OMEGA * TRACK + 1e-12)


def test_set_joint_state_restarts_the_target_and_reset_holds_again(tmp_path):
    sim = pendulum(tmp_path, initial_positions={'pivot': 0.2})
    sim.command_joints({'pivot': 1.0})
    sim.run(0.1)
    sim.set_joint_state({'pivot': -0.5}, {'pivot': 7.0})   # 7.0 is projected onto v* = 1
    t_s = sim.time
    js = sim.joint_state()
    assert js.velocities[0] == pytest.approx(1.0, abs=1e-12)   # bound: one projection
    sim.run(0.1)
    assert sim.joint_state().positions[0] == pytest.approx(-0.5 + (sim.time - t_s), abs=TRACK)
    sim.reset()   # the scene's state, every target held (v* = 0)
    assert sim.joint_state().positions[0] == pytest.approx(0.2, abs=1e-14)
    sim.run(0.1)
    js = sim.joint_state()
    assert js.positions[0] == pytest.approx(0.2, abs=TRACK)
    assert abs(js.velocities[0]) < OMEGA * TRACK + 1e-12


def test_the_accuracy_knob_steps_see_the_targets_of_their_times(tmp_path):
    # Step doubling takes each step twice from its start (one and two sub-steps) and
    # sub-steps the step it keeps: every run from the start sees the targets of its time.
    sim = pendulum(tmp_path, integrator='lie_poisson2')
    start(sim, {'pivot': 0.3}, {'pivot': 2.0})
    sim.set_tolerance(1e-9, estimator='doubling')
    for _ in range(50):
        sim.step()
        assert sim.joint_state().positions[0] == pytest.approx(0.3 + 2.0 * sim.time,
                                                               abs=TRACK)
    assert sim.accuracy().substeps > 1


def test_a_non_finite_velocity_is_refused_naming_the_joint_and_changes_nothing(tmp_path):
    sim = pendulum(tmp_path)
    start(sim, {'pivot': 0.3}, {'pivot': 2.0})
    sim.step(10)
    twin = pendulum(tmp_path)
    start(twin, {'pivot': 0.3}, {'pivot': 2.0})
    twin.step(10)
    before = sim.state.y.copy()
    for bad in (np.nan, np.inf, 'fast'):
        with pytest.raises(SpecError, match='values.pivot'):
            sim.command_joints({'pivot': bad})
    np.testing.assert_array_equal(sim.state.y, before)
    # The drive still moves at 2 rad/s: the next steps are those of the twin, bit for bit.
    sim.step(10)
    twin.step(10)
    np.testing.assert_array_equal(sim.state.y, twin.state.y)
    assert sim.joint_state().efforts[0] == twin.joint_state().efforts[0]


def test_an_exact_velocity_group_loads_from_a_scene_file(tmp_path):
    # The YAML form, with a position group beside it on the same robot.
    path = tmp_path / 'robot.urdf'
    path.write_text(ARM)
    text = (f'dt: 0.001\nrobots:\n  - {{urdf: {path}}}\ncommand_groups:\n'
            f'  - {{name: spin, joints: [j3], interface: velocity, mode: exact}}\n'
            f'  - {{name: hold, joints: [j1, j2], interface: position, mode: exact}}\n')
    (tmp_path / 'scene.yaml').write_text(text)
    from rigid_body_sim.scene import load_scene
    sim = load_scene(tmp_path / 'scene.yaml').simulation
    assert sim.joint_interfaces() == {'j1': 'position', 'j2': 'position', 'j3': 'velocity'}
    sim.command_joints({'j3': -3.0, 'j1': 0.1})
    sim.run(0.3)
    js = sim.joint_state()
    assert js.positions[2] == pytest.approx(-3.0 * 0.3, abs=TRACK)
    # j1's jump of 0.1 closes along exp(−t/τ): 0.1 e^{−6} to go, to SHAKE's tolerance.
    assert js.positions[0] - 0.1 == pytest.approx(-0.1 * np.exp(-0.3 / 0.05), abs=1e-11)
