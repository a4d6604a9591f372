"""
Joint position limits (issue 20, first part): rests, impacts, restitution, releases.

References are closed forms (statics, free fall) and the same scenes without limits
(the integrator's own energy error); the impact time of a swing converges at the
integrator's order to a DOP853 event time.
"""

import re

from joint_space_reference import JointSpaceModel
import numpy as np
import pytest
from rigid_body_sim.core.errors import SpecError
from rigid_body_sim.core.limits import LOCATION_TOLERANCE
from rigid_body_sim.scene import SceneError
from robot_helpers import inertial, joint, link, robot, robot_scene
from scipy.integrate import solve_ivp

G = 9.81
M, L, I_AXIS = 1.0, 0.5, 1e-3           # kg, m (pivot to centre of mass), kg m² (own)
UPPER = 0.8                             # rad
INTEGRATORS = ['symplectic_euler', 'lie_poisson2', 'lie_poisson4', 'rkmk4']


def pendulum(tmp_path, integrator='lie_poisson2', dt=1e-3, lower=-0.5, upper=UPPER, **entry):
    """Build a rod on a hinge about y at the world origin, horizontal at q = 0 (falls to +q)."""
    text = robot('pend', link('world'),
                 link('rod', inertial(M, xyz=(L, 0, 0), ixx=I_AXIS, iyy=I_AXIS, izz=I_AXIS)),
                 joint('j', 'revolute', 'world', 'rod', axis=(0, 1, 0),
                       extra=f'<limit lower="{lower!r}" upper="{upper!r}" effort="100" '
                             f'velocity="100"/>'))
    return robot_scene(tmp_path, text, gravity=(0.0, 0.0, -G), dt=dt, integrator=integrator,
                       **entry).simulation


def pendulum_energy(sim):
    """½ I q̇² − m g L sin q (J): the centre of mass is at height −L sin q."""
    js = sim.joint_state()
    q, qd = js.positions[0], js.velocities[0]
    return 0.5 * (I_AXIS + M * L * L) * qd * qd - M * G * L * np.sin(q)


def slider(tmp_path, integrator='lie_poisson2', dt=1e-3, lower=-0.5, mass=2.0, **entry):
    """Build a block on a vertical prismatic joint at q = 0, falling onto ``lower``."""
    text = robot('drop', link('world'), link('block', inertial(mass)),
                 joint('z', 'prismatic', 'world', 'block', axis=(0, 0, 1),
                       extra=f'<limit lower="{lower!r}" upper="1.0" effort="100" '
                             f'velocity="100"/>'))
    return robot_scene(tmp_path, text, gravity=(0.0, 0.0, -G), dt=dt, integrator=integrator,
                       **entry).simulation


@pytest.mark.parametrize('integrator', INTEGRATORS)
def test_pendulum_comes_to_rest_on_its_limit_with_the_static_torque(integrator, tmp_path):
    sim = pendulum(tmp_path, integrator)
    sim.step(2000)
    js = sim.joint_state()
    [impact] = sim.limits.impacts          # one inelastic impact, then rest
    assert impact.side == -1 and impact.approach < -1.0 and impact.rebound == 0.0
    # bound: while its bound is active the joint is an equality row, held to the
    # projection's tolerance (1e-13) plus rounding of the angle (1e-15): 1e-10 is the
    # stated bound with room.
    assert abs(js.positions[0] - UPPER) <= 1e-10
    assert abs(js.velocities[0]) <= 1e-9
    # The bound's torque holds gravity's: −m g L cos q_lim (it pushes towards −q). bound:
    # one acceleration-level solve of a 6-row system in double precision: 1e-12 relative.
    np.testing.assert_allclose(js.efforts[0], -M * G * L * np.cos(UPPER), rtol=1e-9)
    assert sim.limits.counters.releases == 0


def test_the_bounds_reaction_is_the_joints_and_its_row_is_not_a_constraint(tmp_path):
    sim = pendulum(tmp_path)
    sim.step(1500)
    assert sim.joint_limits()['active'] == {'j': 'upper'}
    assert sim.constraint_names == ['j']            # the bound's row counts as the joint's
    [joint] = sim.reactions()['j'].values()        # on the rod (the world is not listed)
    weight = np.array([0.0, 0.0, -M * G])
    com = L * np.array([np.cos(UPPER), 0.0, -np.sin(UPPER)])   # from the pivot (anchor)
    # At rest the hinge and its bound hold the rod's weight and its moment. bound: one
    # solve in double precision, 1e-12 of |m g| and |m g L|.
    np.testing.assert_allclose(joint.force_world, -weight, atol=1e-11)
    np.testing.assert_allclose(joint.torque_anchor_world, -np.cross(com, weight), atol=1e-11)
    with pytest.raises(SpecError, match='j_limit.*holds'):
        sim.remove_constraint('j_limit')


def test_a_bound_stays_right_when_other_constraints_come_and_go(tmp_path):
    # A pinned ball beside the pendulum: removing its pin (rows before the bound's) and
    # adding another moves the bound's row in λ; the rod must stay on its bound, with
    # its static torque.
    from rigid_body_sim.core.constraints import Constraint
    from rigid_body_sim.scene import scene_from_dict
    text = robot('pend', link('world'),
                 link('rod', inertial(M, xyz=(L, 0, 0), ixx=I_AXIS, iyy=I_AXIS, izz=I_AXIS)),
                 joint('j', 'revolute', 'world', 'rod', axis=(0, 1, 0),
                       extra=f'<limit lower="-0.5" upper="{UPPER!r}" effort="100" '
                             f'velocity="100"/>'))
    (tmp_path / 'pend.urdf').write_text(text)
    sim = scene_from_dict({
        'dt': 1e-3, 'effects': {'gravity': {'g_world': [0.0, 0.0, -G]}},
        'bodies': [{'name': 'ball', 'mass': 1.0, 'inertia': [0.1, 0.1, 0.1],
                    'position_world': [0.0, 2.0, 0.0]}],
        'constraints': [{'name': 'pin', 'type': 'ball', 'body_a': 'ball', 'body_b': 'world',
                         'anchor_world': [0.0, 2.0, 0.5]}],
        'robots': [{'urdf': str(tmp_path / 'pend.urdf')}]},
        str(tmp_path / 'scene.yaml')).simulation
    sim.step(1000)
    assert sim.joint_limits()['active'] == {'j': 'upper'}
    sim.remove_constraint('pin')
    sim.step(300)
    sim.add_constraint(Constraint('pin2', 'ball', 'ball', None,
                                  anchor_world=sim.pose('ball')[0] + [0.0, 0.0, 0.5]))
    sim.step(300)
    assert sim.joint_limits()['active'] == {'j': 'upper'}
    assert sim.limits.counters.releases == 0
    assert abs(sim.joint_state().positions[0] - UPPER) <= 1e-10
    np.testing.assert_allclose(sim.joint_state().efforts[0], -M * G * L * np.cos(UPPER),
                               rtol=1e-9)


def _swing_impact_time():
    """Time (s) at which the released rod reaches UPPER: DOP853 with an event, rtol 1e-13."""
    inertia = I_AXIS + M * L * L

    def rhs(t, y):
        return [y[1], M * G * L * np.cos(y[0]) / inertia]

    def hit(t, y):
        return y[0] - UPPER
    hit.terminal = True
    sol = solve_ivp(rhs, (0.0, 2.0), [0.0, 0.0], method='DOP853', rtol=1e-13, atol=1e-14,
                    events=hit)
    return float(sol.t_events[0][0])


@pytest.mark.parametrize('integrator, order', [('lie_poisson2', 2), ('rkmk4', 4)])
def test_impact_time_converges_at_the_integrators_order(integrator, order, tmp_path):
    # The impact is located inside the step, so its time carries the method's own
    # error, O(dt^p), not the step's O(dt) of an event seen at the step's end.
    reference = _swing_impact_time()
    errors = []
    for dt in (4e-3, 2e-3):
        sim = pendulum(tmp_path, integrator, dt)
        sim.step(int(round(0.6 / dt)))
        [impact] = sim.limits.impacts
        errors.append(abs(impact.time - reference))
    # bound: halving dt divides an order-p error by 2^p up to the next term: within a
    # factor 1.5 here (an event time's error also has the location's 1e-10 / |q̇| =
    # 3e-11 s, far below these).
    assert 2 ** order / 1.5 < errors[0] / errors[1] < 2 ** order * 1.5
    assert errors[0] < 1e-4


@pytest.mark.parametrize('integrator', ['rkmk4', 'lie_poisson4'])
def test_with_the_knob_the_impact_time_holds_to_its_tolerance(integrator, tmp_path):
    # The accuracy knob at 1e-10 (local error per unit time) and dt = 1e-3: the impact is
    # located to tolerance dt = 1e-13 rad (not the default 1e-10), so the knob's promise
    # holds across it: the impact time is the DOP853 event time to the knob's global
    # error over the 0.35 s swing (1e-10 x 0.35 s = 3.5e-11 rad) over the rate there
    # (3.3 rad/s): 1e-11 s, and no step misses its tolerance.
    reference = _swing_impact_time()
    sim = pendulum(tmp_path, integrator, 1e-3)
    sim.set_tolerance(1e-10)
    worst = 0.0
    for _ in range(600):
        sim.step()
        worst = max(worst, sim.joint_state().positions[0] - UPPER)
    [impact] = sim.limits.impacts
    assert sim.events.location == pytest.approx(1e-13)
    # bound: the 1e-11 s above, times 3 for the estimate's own error (an estimate).
    assert abs(impact.time - reference) < 3e-11
    # bound: the location's 1e-13 rad, then the row's drift (SHAKE's 1e-13 a step,
    # closed along exp(-t/τ)): 3e-13.
    assert worst < 3e-13
    assert sim.accuracy().misses == 0


@pytest.mark.parametrize('integrator', ['lie_poisson2', 'lie_poisson4'])
def test_elastic_limit_keeps_the_energy_to_the_integrators_own_error(integrator, tmp_path):
    limited = pendulum(tmp_path, integrator, limit_restitution=1.0)
    free = pendulum(tmp_path, integrator, lower=-10.0, upper=10.0)
    e0 = pendulum_energy(limited)
    worst_free, worst = 0.0, 0.0
    for _ in range(3000):
        limited.step()
        free.step()
        worst = max(worst, abs(pendulum_energy(limited) - e0))
        worst_free = max(worst_free, abs(pendulum_energy(free) - e0))
    impacts = limited.limits.impacts
    assert len(impacts) >= 4
    for impact in impacts:        # Newton's law with e = 1: the speed is returned
        assert impact.rebound == pytest.approx(-impact.approach, rel=1e-15)
    # bound: each impact is located to 1e-10 rad (an energy error of m g L 1e-10 = 5e-10
    # J) and reverses the rate exactly; the rest is the method's own energy error,
    # measured here on the same swing without limits (twice it, for the swing's
    # other phases).
    assert worst <= 2.0 * worst_free + 1e-8
    assert limited.joint_state().positions.max() <= UPPER + LOCATION_TOLERANCE


@pytest.mark.parametrize('integrator', ['lie_poisson2', 'lie_poisson4', 'rkmk4'])
def test_block_falls_onto_its_limit_at_the_free_fall_time(integrator, tmp_path):
    h, mass = 0.5, 2.0
    sim = slider(tmp_path, integrator, lower=-h, mass=mass)
    sim.step(1000)
    [impact] = sim.limits.impacts
    # These methods are exact for a constant force, so the fall is the closed form:
    # t* = sqrt(2 h / g), arriving at v = sqrt(2 g h). bound: the location's 1e-10 m at
    # 3 m/s is 3e-11 s; rounding of the partial steps, 1e-13.
    assert impact.time == pytest.approx(np.sqrt(2.0 * h / G), abs=1e-10)
    # The impulse is m v: the joint's rate goes from −sqrt(2 g h) to 0.
    assert impact.approach == pytest.approx(-np.sqrt(2.0 * G * h), rel=1e-9)
    js = sim.joint_state()
    assert abs(js.positions[0] + h) <= 1e-10 and abs(js.velocities[0]) <= 1e-9
    np.testing.assert_allclose(js.efforts[0], mass * G, rtol=1e-9)   # rest: the weight


def test_bouncing_block_rises_to_e_squared_of_its_drop(tmp_path):
    h, e = 0.5, 0.5
    sim = slider(tmp_path, 'lie_poisson2', lower=-h, limit_restitution=e)
    apex = -np.inf
    sim.step(400)                       # past the first impact (0.32 s)
    assert len(sim.limits.impacts) == 1
    for _ in range(400):                # up and down again (0.32 s of flight)
        sim.step()
        apex = max(apex, sim.joint_state().positions[0])
    first, second = list(sim.limits.impacts)[:2]
    assert first.rebound == pytest.approx(e * np.sqrt(2.0 * G * h), rel=1e-9)
    # The apex of the bounce, sampled at the steps: e² h above the bound, to the
    # sampling (v = g dt / 2 near the apex: g dt² / 8 = 1.2e-6 m at dt = 1e-3).
    assert apex + h == pytest.approx(e * e * h, abs=2e-6)
    assert second.approach == pytest.approx(-first.rebound, rel=1e-9)


def test_a_push_away_releases_the_limit_and_a_weaker_one_does_not(tmp_path):
    static = M * G * L * np.cos(UPPER)
    for push, leaves in ((0.9 * static, False), (1.1 * static, True)):
        sim = pendulum(tmp_path)
        sim.step(1000)                                 # at rest on the upper bound
        sim.set_joint_efforts({'j': -push})            # towards −q
        sim.step(200)
        q = sim.joint_state().positions[0]
        if leaves:
            assert sim.limits.counters.releases == 1
            # (τ − m g L cos q) / I pulls it off: 0.1 static / I over 0.2 s.
            assert q < UPPER - 1e-3
        else:
            assert sim.limits.counters.releases == 0
            assert abs(q - UPPER) <= 1e-10


def test_two_bounds_active_at_once_carry_the_statics(tmp_path):
    # Two links on hinges about y, both falling into their upper bounds.
    m1, m2, l1, c1, c2 = 1.0, 0.5, 0.4, 0.2, 0.15
    up1, up2 = 0.3, 0.5
    lim = 'effort="100" velocity="100"'
    text = robot('arm2', link('world'),
                 link('a', inertial(m1, xyz=(c1, 0, 0), ixx=1e-3, iyy=1e-3, izz=1e-3)),
                 link('b', inertial(m2, xyz=(c2, 0, 0), ixx=1e-3, iyy=1e-3, izz=1e-3)),
                 joint('j1', 'revolute', 'world', 'a', axis=(0, 1, 0),
                       extra=f'<limit lower="-1" upper="{up1}" {lim}/>'),
                 joint('j2', 'revolute', 'a', 'b', xyz=(l1, 0, 0), axis=(0, 1, 0),
                       extra=f'<limit lower="-1" upper="{up2}" {lim}/>'))
    sim = robot_scene(tmp_path, text, gravity=(0.0, 0.0, -G)).simulation
    sim.step(3000)
    js = sim.joint_state()
    assert list(sim.limits.active) == [-1, -1]
    np.testing.assert_allclose(js.positions, [up1, up2], atol=1e-10)
    # Gravity's torques about each joint; each bound pushes back with their negative.
    tau2 = m2 * G * c2 * np.cos(up1 + up2)
    tau1 = m1 * G * c1 * np.cos(up1) + m2 * G * (l1 * np.cos(up1) + c2 * np.cos(up1 + up2))
    np.testing.assert_allclose(js.efforts, [-tau1, -tau2], rtol=1e-9)


def test_a_start_beyond_a_limit_converges_to_it(tmp_path):
    sim = pendulum(tmp_path, initial_positions={'j': UPPER + 0.2})
    assert list(sim.limits.active) == [-1]
    sim.step(500)
    # A violated row decays along exp(−t/τ) (τ = 0.05 s): 0.2 e^−10 = 9e-6 rad at 0.5 s;
    # bound twice that for the discrete decay.
    assert 0.0 <= sim.joint_state().positions[0] - UPPER <= 2.0 * 0.2 * np.exp(-10.0)


def test_a_start_beyond_a_bound_that_gravity_leaves_converges_then_leaves(tmp_path):
    # 0.2 rad below the lower bound, gravity turning the rod towards +q: the row brings
    # it back along exp(−t/τ) (pulling, as it must while the joint is beyond), with no
    # release and no impact on the way; on the bound, gravity takes it away (a release).
    sim = pendulum(tmp_path, initial_positions={'j': -0.7})
    assert list(sim.limits.active) == [1]
    qs = []
    for _ in range(1200):     # back within 1e-10 after τ ln(0.2 / 1e-10) = 1.07 s (it
        # then swings onto its upper bound at 1.45 s: not within this run)
        sim.step()
        qs.append(sim.joint_state().positions[0])
    c = sim.limits.counters
    assert c.impacts == 0 and c.releases == 1
    # One located event, the return within the tolerance, where the bound (pulling, as
    # it did all along) is released at once: it carried no force past its bound. (A rule
    # by the gap alone let the row's margin appear inside a step, and the release was
    # located again and again: 32 partial steps and 4.3 N m counted.)
    assert c.located_steps == 1
    assert sim.complementarity()['max_force_excess'] == 0.0
    # Monotone back to the bound (no chatter), then away from it.
    k = int(np.argmax(np.array(qs) >= -0.5 - LOCATION_TOLERANCE))
    assert np.all(np.diff(qs[:k]) > 0.0) and k > 0
    assert qs[-1] > -0.5 + 0.01


def test_arm_under_random_efforts_never_passes_a_limit(tmp_path):
    from joint_space_reference import urdf_path
    from rigid_body_sim.scene import scene_from_dict
    rng = np.random.default_rng(7)
    sim = scene_from_dict({'dt': 1e-3, 'effects': {'gravity': {'g_world': [0, 0, -G]}},
                           'robots': [{'urdf': urdf_path('arm7.urdf')}]},
                          urdf_path('scene.yaml')).simulation
    names = sim.joint_names()
    specs = {j.name: j.spec for j in sim.joints.joints}
    lower = np.array([specs[n].lower for n in names])
    upper = np.array([specs[n].upper for n in names])
    effort = np.array([specs[n].effort for n in names])
    worst = 0.0
    for k in range(200):                        # a new random effort every 50 ms, 10 s
        sim.set_joint_efforts({n: float(rng.uniform(-0.6, 0.6) * effort[i])
                               for i, n in enumerate(names) if n != 'finger_joint2'})
        for _ in range(50):
            sim.step()
            q = sim.joint_state().positions
            worst = max(worst, float(np.max(np.maximum(lower - q, q - upper))))
    assert sim.limits.counters.impacts > 0
    # bound: the location's 1e-10 at impacts, the rows' drift while active.
    assert worst <= 1e-9


def test_arm_without_actuation_never_gains_energy_at_its_limits(tmp_path):
    # arm7 (limits, restitution 1 on every joint, no friction, no damping) falling under
    # gravity from a pose near its bounds, with rates into them: elastic impacts keep
    # the energy, and nothing else may add any beyond the integrator's own error,
    # measured on the same arm without limits (its swing is as fast).
    from joint_space_reference import urdf_path
    from rigid_body_sim.scene import scene_from_dict
    text = re.sub(r'<dynamics[^>]*/>', '', open(urdf_path('arm7.urdf')).read())
    (tmp_path / 'arm.urdf').write_text(text)
    start = {'joint2': 1.5, 'joint4': -0.2, 'joint6': 3.5}
    rates = {'joint2': 1.0, 'joint4': 2.0, 'joint6': 2.0}

    def arm(limits):
        return scene_from_dict({'dt': 1e-3, 'effects': {'gravity': {'g_world': [0, 0, -G]}},
                                'robots': [{'urdf': str(tmp_path / 'arm.urdf'), 'limits': limits,
                                            'limit_restitution': 1.0,
                                            'initial_positions': start,
                                            'initial_velocities': rates}]},
                               str(tmp_path / 'scene.yaml')).simulation
    limited, free = arm(True), arm(False)
    e0, f0 = limited.diagnostics().total_energy, free.diagnostics().total_energy
    gain, drift = 0.0, 0.0
    for _ in range(10000):                      # 10 s
        limited.step()
        free.step()
        gain = max(gain, limited.diagnostics().total_energy - e0)
        drift = max(drift, abs(free.diagnostics().total_energy - f0))
    assert limited.limits.counters.impacts >= 3
    # bound: twice the method's own energy error on the free arm, plus the impacts'
    # location (1e-10 rad against torques of 10 N m: 1e-9 J each).
    assert gain <= 2.0 * drift + 1e-7


def test_infinite_or_negative_friction_is_refused(tmp_path):
    for value, message in ((float('inf'), 'finite'), (-1.0, '>= 0')):
        with pytest.raises(SceneError, match=f'dynamics.friction.*{message}'):
            rubbing_pendulum(tmp_path, value)


def test_a_lower_bound_above_the_upper_is_refused(tmp_path):
    with pytest.raises(SceneError, match='limit: lower 1.0 is above upper 0.5'):
        pendulum(tmp_path, lower=1.0, upper=0.5)


@pytest.mark.parametrize('value, field, message', [
    (1.5, 'robots[0].limit_restitution', 'in \\[0, 1\\]'),
    ({'nope': 0.5}, 'robots[0].limit_restitution.nope', 'unknown joint'),
    (float('nan'), 'robots[0].limit_restitution', 'finite'),
])
def test_bad_restitution_is_refused_naming_the_field(value, field, message, tmp_path):
    with pytest.raises(SceneError, match=f'{re.escape(field)}: .*{message}'):
        pendulum(tmp_path, limit_restitution=value)


def test_limits_off_lets_the_joint_pass(tmp_path):
    sim = pendulum(tmp_path, limits=False)
    assert sim.limits is None
    sim.step(600)
    assert sim.joint_state().positions[0] > UPPER


@pytest.mark.parametrize('integrator', INTEGRATORS)
@pytest.mark.parametrize('tolerance', [None, 1e-6])
def test_limits_never_reached_change_nothing_bit_for_bit(integrator, tolerance, tmp_path):
    # Inactive limits are watched in the kernel that reads the coordinates (one
    # comparison per joint); the step itself is the one without limits. So a swing that
    # never reaches its bounds is the same to the last bit with limits on and off, with
    # the knob off and on.
    runs = []
    for limits in (True, False):
        sim = pendulum(tmp_path, integrator, lower=-2.0, upper=4.0, limits=limits)
        if tolerance is not None:
            sim.set_tolerance(tolerance)
        assert (sim.limits is not None) == limits
        sim.step(600)   # from horizontal through the bottom (π/2) and up the other side
        js = sim.joint_state()
        runs.append((js.positions[0], js.velocities[0], sim.state.parts))
    (q_on, v_on, parts_on), (q_off, v_off, parts_off) = runs
    assert q_on > np.pi / 2   # it did swing past the bottom, inside its bounds
    assert (q_on, v_on) == (q_off, v_off)
    for a, b in zip(parts_on, parts_off):
        np.testing.assert_array_equal(a, b)


def test_a_watched_step_past_a_bound_is_taken_again_by_the_events(tmp_path):
    # The first step whose end lies past a bound (by more than the tolerance) is the
    # events' to take: the impact is located inside it, so the joint never shows a
    # coordinate past its bound beyond the location tolerance.
    sim = pendulum(tmp_path, lower=-2.0, upper=UPPER)
    worst = 0.0
    for _ in range(400):
        sim.step()
        worst = max(worst, sim.joint_state().positions[0] - UPPER)
    assert sim.limits.counters.impacts == 1 and sim.limits.counters.located_steps >= 1
    # bound: the location's tolerance at the impact (1e-10); the row's drift after it
    # stays within it (the resting test's 1e-10).
    assert worst <= LOCATION_TOLERANCE


@pytest.mark.parametrize('integrator', INTEGRATORS)
def test_the_watched_path_and_the_events_loop_agree_to_the_last_bit(integrator, tmp_path):
    # The same swing into its bound and resting there, once as it runs (the inactive
    # limits watched in the coordinates' kernel until the impact) and once with every
    # step taken by the events' loop: the same states, bit for bit.
    runs = []
    for watched in (True, False):
        sim = pendulum(tmp_path, integrator)
        if not watched:
            sim.events.quiet = lambda: False
        sim.step(1500)
        js = sim.joint_state()
        runs.append((js.positions[0], js.velocities[0], js.efforts[0], sim.state.parts))
        assert sim.limits.counters.impacts == 1
    (q1, v1, e1, parts1), (q2, v2, e2, parts2) = runs
    assert (q1, v1, e1) == (q2, v2, e2)
    for a, b in zip(parts1, parts2):
        np.testing.assert_array_equal(a, b)


def test_limits_must_be_true_or_false(tmp_path):
    with pytest.raises(SceneError, match='robots\\[0\\].limits: expected true or false'):
        pendulum(tmp_path, limits='yes')


# -- Coulomb joint friction -------------------------------------------------------------------


def rubbing_pendulum(tmp_path, force, integrator='lie_poisson2', dt=1e-3, gravity=True,
                     **entry):
    """Build the pendulum of :func:`pendulum`, wide limits, ``<dynamics friction>`` force."""
    text = robot('pend', link('world'),
                 link('rod', inertial(M, xyz=(L, 0, 0), ixx=I_AXIS, iyy=I_AXIS, izz=I_AXIS)),
                 joint('j', 'revolute', 'world', 'rod', axis=(0, 1, 0),
                       extra=f'<limit lower="-10" upper="10" effort="100" velocity="100"/>'
                             f'<dynamics friction="{force!r}"/>'))
    return robot_scene(tmp_path, text, gravity=(0.0, 0.0, -G) if gravity else None, dt=dt,
                       integrator=integrator, **entry).simulation


def test_below_breakaway_the_joint_does_not_move_at_all(tmp_path):
    # Horizontal: gravity's torque m g L; a friction 10 % above it holds the rod.
    sim = rubbing_pendulum(tmp_path, 1.1 * M * G * L)
    assert sim.joint_friction()['sticking'] == ['j']
    for _ in range(10):
        sim.step(1000)
        # bound: the sticking row is an equality row held to the projection's
        # tolerance (1e-13 rad) over 10 s.
        assert abs(sim.joint_state().positions[0]) <= 1e-10
    js = sim.joint_state()
    # The friction carries the weight's moment: −m g L (towards −q). bound: one solve.
    np.testing.assert_allclose(js.efforts[0], -M * G * L, rtol=1e-9)
    assert sim.joint_friction()['counters'] == {'sticks': 0, 'slips': 0}


@pytest.mark.parametrize('integrator', ['lie_poisson2', 'rkmk4'])
def test_above_breakaway_the_joint_accelerates_at_effort_minus_friction(integrator, tmp_path):
    # No gravity: an effort τ against friction F gives q̈ = (τ − F) / I once it slips.
    friction, tau = 0.3, 0.5
    sim = rubbing_pendulum(tmp_path, friction, integrator, gravity=False)
    sim.set_joint_efforts({'j': tau})
    sim.step(100)
    assert sim.joint_friction()['slipping'] == {'j': 1}
    v1, t1 = sim.joint_state().velocities[0], sim.time
    sim.step(200)
    v2, t2 = sim.joint_state().velocities[0], sim.time
    inertia = I_AXIS + M * L * L
    # Constant forces: both methods are exact for them (rounding of 300 steps: 1e-12).
    assert (v2 - v1) / (t2 - t1) == pytest.approx((tau - friction) / inertia, rel=1e-9)
    # The breakaway is located where the force passed F: at the command (the first
    # step's start), so the joint accelerates from then on (rounding: 1e-12).
    assert v1 == pytest.approx((tau - friction) / inertia * t1, rel=1e-9)
    assert sim.joint_state().efforts[0] == pytest.approx(tau - friction, rel=1e-12)


def _stop_angle(friction):
    """Return the first turning point of the swing from the horizontal: m g L sin θ = F θ."""
    from scipy.optimize import brentq
    return brentq(lambda th: M * G * L * np.sin(th) - friction * th, np.pi / 2, np.pi)


@pytest.mark.parametrize('integrator, order', [('lie_poisson2', 2), ('rkmk4', 4)])
def test_a_rubbing_swing_stops_at_the_energy_balance_angle(integrator, order, tmp_path):
    # Released from the horizontal at rest, F = 0.6 m g L: the rod swings down and up to
    # θ1 with m g L sin θ1 = F θ1 (the work of friction), where gravity's torque,
    # m g L |cos θ1| = 0.09 m g L < F, cannot move it again: it stays.
    friction = 0.6 * M * G * L
    theta1 = _stop_angle(friction)
    assert M * G * L * abs(np.cos(theta1)) < friction
    errors = []
    for dt in (2e-3, 1e-3):
        sim = rubbing_pendulum(tmp_path, friction, integrator, dt)
        assert sim.joint_friction()['sticking'] == ['j']
        sim.step(int(round(1.5 / dt)))
        state = sim.joint_friction()
        assert state['sticking'] == ['j'] and state['counters'] == {'sticks': 1, 'slips': 1}
        errors.append(abs(sim.joint_state().positions[0] - theta1))
        sim.step(int(round(1.0 / dt)))     # and it stays there
        moved = abs(sim.joint_state().positions[0] - theta1) - errors[-1]
        assert abs(moved) <= 1e-10
    # bound: the stop is located to 1e-9 rad/s; its angle carries the method's O(dt^p)
    # error (the breakaway, located at the release, does not change where it stops:
    # the energy balance does not depend on when it starts). Measured ratios 3.9 and
    # 15.3.
    assert 2 ** order / 1.5 < errors[0] / errors[1] < 2 ** order * 1.5
    assert errors[1] < 1e-5


def test_clearing_the_wrenches_keeps_the_slipping_friction(tmp_path):
    friction, tau = 0.3, 0.5
    sim = rubbing_pendulum(tmp_path, friction, gravity=False)
    sim.set_joint_efforts({'j': tau})
    sim.step(100)
    v0 = sim.joint_state().velocities[0]
    sim.clear_wrenches()          # the effort goes; the friction decelerates the rod
    sim.step(50)
    inertia = I_AXIS + M * L * L
    assert sim.joint_state().velocities[0] == pytest.approx(v0 - friction / inertia * 0.05,
                                                            rel=1e-9)
    sim.step(50)                  # it stops at v0 I / F = 0.067 s and sticks
    assert sim.joint_friction()['sticking'] == ['j']
    assert abs(sim.joint_state().velocities[0]) <= 1e-12   # (the stick's projection)


def test_friction_false_leaves_the_joint_free(tmp_path):
    sim = rubbing_pendulum(tmp_path, 1.1 * M * G * L, friction=False)
    assert sim.friction is None
    sim.step(100)
    assert sim.joint_state().positions[0] > 1e-3


def _turning_arm(tmp_path, theta0, omega, dt=1e-3,
                 extra='<limit lower="0" upper="3" effort="1e6" velocity="1e6"/>'):
    """
    Return a 2-link arm whose j1 (axis x) turns at ``omega`` (an exact velocity drive).

    j2 (axis x, at the end of link 1) has its lower bound at 0, where link 2 continues
    link 1; gravity holds it there while link 2 points below the horizontal's far side.
    """
    from test_exact_drives import scene
    text = robot('turn', link('world'),
                 link('l1', inertial(1.0, (0, 0.25, 0), ixx=0.02, iyy=0.01, izz=0.02)),
                 link('l2', inertial(0.5, (0, 0.2, 0), ixx=0.01, iyy=0.004, izz=0.01)),
                 joint('j1', 'revolute', 'world', 'l1', xyz=(0, 0, 1), axis=(1, 0, 0)),
                 joint('j2', 'revolute', 'l1', 'l2', xyz=(0, 0.5, 0), axis=(1, 0, 0),
                       extra=extra))
    sim = scene(tmp_path, text, [{'name': 'turn', 'joints': ['j1'], 'interface': 'velocity',
                                  'mode': 'exact'}], integrator='lie_poisson4', dt=dt)
    sim.command_joints({'j1': omega})
    sim.set_joint_state({'j1': theta0, 'j2': 0.0})
    return sim, JointSpaceModel.from_urdf(text)


def test_a_bound_lets_go_where_its_force_reaches_zero_located_inside_the_step(tmp_path):
    # j1 turns at ω = 1 rad/s from θ0 = 1.2; link 2 lies on j2's lower bound, collinear
    # with link 1, so the bound carries only its weight's torque, f = m g l cos(θ1): no
    # centrifugal torque about j2. f reaches 0 when link 2 passes the vertical, at t* =
    # (π/2 − θ0)/ω = 0.37 s, inside a step; there the bound lets go (located to
    # FORCE_TOLERANCE of the force's change over the step) and link 2 swings free of it,
    # j1 still driven: q̈2 = −h2(q, q̇) / M22 with q1 = θ0 + ω t (the joint-space
    # reference). lie_poisson4 keeps its fourth order through the release.
    theta0, omega, m2, l2 = 1.2, 1.0, 0.5, 0.2
    t_star = (0.5 * np.pi - theta0) / omega
    errors = []
    for dt in (1e-3, 5e-4):
        sim, reference = _turning_arm(tmp_path, theta0, omega, dt)
        worst_f = 0.0
        while sim.time + sim.dt < t_star:
            sim.step()
            if sim.time > 0.01:   # (the first step seats the joint on its bound)
                f = m2 * G * l2 * np.cos(theta0 + omega * sim.time)
                worst_f = max(worst_f, abs(sim.joint_state().efforts[1] - f))
        assert sim.joint_limits()['active'] == {'j2': 'lower'}
        # bound: the solve's rounding, 1e-12 of the torques (~1 N m).
        assert worst_f < 1e-11

        def rhs(t, y):
            q = np.array([theta0 + omega * t, y[0]])
            qd = np.array([omega, y[1]])
            h = reference.inverse_dynamics(q, qd, np.zeros(2))
            return [y[1], -h[1] / reference.mass_matrix(q)[1, 1]]

        ref = solve_ivp(rhs, (t_star, 0.7), [0.0, 0.0], method='DOP853', dense_output=True,
                        rtol=1e-13, atol=1e-16)
        worst = 0.0
        while sim.time < 0.7 - 0.5 * dt:
            sim.step()
            worst = max(worst, abs(sim.joint_state().positions[1] - ref.sol(sim.time)[0]))
        assert sim.joint_limits()['active'] == {}
        assert sim.joint_limits()['counters']['releases'] == 1
        assert ref.sol(0.7)[0] > 0.1      # it swung away from the bound
        errors.append(worst)
    # bound: the release is located to 1e-9 of the force's change over the step: in
    # time, 1e-12 s, moving q2 (which leaves with q̈2 = 0, q⃛2 = f'/I) by far less than
    # 1e-15 rad; what remains is lie_poisson4's error over 0.33 s of swing, measured
    # 5.8e-11, 3.6e-12 and 3.4e-13 at dt 1e-3, 5e-4 and 2.5e-4: fourth order. A release
    # one step late would be off by about f' dt t² / (2 I) = 1e-3 rad (first order).
    assert errors[0] < 1e-10
    assert errors[0] / errors[1] > 8.0    # order 3 or more through the release


def test_a_sticking_joint_breaks_away_where_its_force_reaches_f_located_inside_the_step(
        tmp_path):
    # The turning arm with j2 free of bounds but with Coulomb friction F = 0.5 N m: j2
    # sticks, collinear, while the torque that holds it, m g l cos(θ1), is within F; as
    # link 2 passes the vertical it falls to −F at cos θ1 = −F / (m g l), at t* = 0.91 s,
    # inside a step: there the joint breaks away (located) and slips towards +q2 under
    # gravity and −F: q̈2 = (−h2 − F) / M22, j1 still driven.
    theta0, omega, m2, l2, friction = 1.2, 1.0, 0.5, 0.2, 0.5
    t_star = (np.arccos(-friction / (m2 * G * l2)) - theta0) / omega
    extra = ('<limit lower="-3" upper="3" effort="1e6" velocity="1e6"/>'
             f'<dynamics friction="{friction!r}"/>')
    errors = []
    for dt in (1e-3, 5e-4):
        sim, reference = _turning_arm(tmp_path, theta0, omega, dt, extra)
        while sim.time + sim.dt < t_star:
            sim.step()
        assert sim.joint_friction()['sticking'] == ['j2']
        assert abs(sim.joint_state().positions[1]) < 1e-12

        def rhs(t, y):
            q = np.array([theta0 + omega * t, y[0]])
            qd = np.array([omega, y[1]])
            h = reference.inverse_dynamics(q, qd, np.zeros(2))
            return [y[1], (-h[1] - friction) / reference.mass_matrix(q)[1, 1]]

        end = t_star + 0.3
        ref = solve_ivp(rhs, (t_star, end), [0.0, 0.0], method='DOP853', dense_output=True,
                        rtol=1e-13, atol=1e-16)
        worst = 0.0
        while sim.time < end - 0.5 * dt:
            sim.step()
            worst = max(worst, abs(sim.joint_state().positions[1] - ref.sol(sim.time)[0]))
        assert sim.joint_friction()['slipping'] == {'j2': 1}
        assert ref.sol(end)[0] > 0.05
        errors.append(worst)
    # bound: as the release's (the test above): the breakaway located to 1e-12 s, and
    # lie_poisson4's fourth-order error over 0.3 s of slip (the slip's constant −F is a
    # held wrench: no discontinuity inside a step).
    assert errors[0] < 1e-10
    assert errors[0] / errors[1] > 8.0
