"""
The held rows' complementarity problem in the simulation: its matrix and its answers.

A three-link arm (hinges about y, no gravity) pressed onto its upper bounds; the
joint-space model (:mod:`joint_space_reference`) gives the reference: with the
hinges held, the rows' Schur complement is the inverse joint-space mass matrix's
block of the held joints, and the bounds that stay are the solution of the box LCP
``w = M⁻¹ (f − f*)``, ``f ≤ 0`` (an upper bound pushes towards −q), complementary.
"""

from joint_space_reference import JointSpaceModel
import numpy as np
import pytest
from rigid_body_sim.core.complementarity import FREE, solve_direct
from robot_helpers import inertial, joint, link, robot, robot_scene

UPPER = 0.5
LIMIT = f'<limit lower="-0.5" upper="{UPPER}" effort="100" velocity="100"/>'


def arm_text(friction=0.0, rubbing=('j1', 'j2', 'j3')):
    """Return a three-link arm in the x–z plane, each hinge limited to [−0.5, 0.5] rad."""
    def extra(name):
        return LIMIT + (f'<dynamics friction="{friction!r}"/>'
                        if friction and name in rubbing else '')
    return robot('arm3', link('world'),
                 link('a', inertial(2.0, (0.25, 0, 0), ixx=0.01, iyy=0.03, izz=0.03)),
                 link('b', inertial(1.5, (0.2, 0, 0), ixx=0.01, iyy=0.02, izz=0.02)),
                 link('c', inertial(1.0, (0.15, 0, 0), ixx=0.01, iyy=0.01, izz=0.01)),
                 joint('j1', 'revolute', 'world', 'a', axis=(0, 1, 0), extra=extra('j1')),
                 joint('j2', 'revolute', 'a', 'b', xyz=(0.5, 0, 0), axis=(0, 1, 0),
                       extra=extra('j2')),
                 joint('j3', 'revolute', 'b', 'c', xyz=(0.4, 0, 0), axis=(0, 1, 0),
                       extra=extra('j3')))


def pressed_arm(tmp_path, friction=0.0):
    """Return the arm at rest on its three upper bounds, pressed there by 3 N m each."""
    sim = robot_scene(tmp_path, arm_text(friction),
                      initial_positions={'j1': UPPER, 'j2': UPPER, 'j3': UPPER}).simulation
    sim.set_joint_efforts({'j1': 3.0, 'j2': 3.0, 'j3': 3.0})
    sim.step(20)
    assert list(sim.limits.active) == [-1, -1, -1]
    return sim


def test_the_rows_schur_complement_is_the_inverse_mass_matrix_block(tmp_path):
    # Joints 1 and 3 held, joint 2 free: a force on the held joints accelerates them by
    # (M⁻¹)_HH (joint 2 moving freely): the Schur complement of their rows in the
    # constraint matrix with the hinges held, from one projection per row.
    sim = robot_scene(tmp_path, arm_text(),
                      initial_positions={'j1': UPPER + 0.1, 'j2': 0.2, 'j3': -0.6}).simulation
    assert list(sim.limits.active) == [-1, 0, 1]   # (a start beyond: both held)
    q = sim.joint_state().positions
    names = [sim.limits.names[0], sim.limits.names[2]]
    S = sim.events._schur(names, sim.state)
    model = JointSpaceModel.from_urdf(arm_text(), gravity=(0, 0, 0))
    expected = np.linalg.inv(model.mass_matrix(q))[np.ix_([0, 2], [0, 2])]
    # bound: the projections' rounding (1e-15 relative) through an inverse of a 2x2 block
    # whose condition is about 10.
    np.testing.assert_allclose(S, expected, rtol=1e-12)


def test_the_bounds_that_stay_are_the_lcps_not_the_pulling_rows(tmp_path):
    # New efforts: j1 still pressed, j2 and j3 pulled away (their all-held rows pull).
    # Releasing both would be wrong: with j3 free, j2's row pushes again (the arm's
    # coupling). The LCP of the three rows keeps j1 and j2 and releases j3, in one
    # solve; j2 then stays on its bound (no later impact), j3 swings away.
    tau = np.array([4.486, -1.882, -0.767])
    sim = pressed_arm(tmp_path)
    q = sim.joint_state().positions
    model = JointSpaceModel.from_urdf(arm_text(), gravity=(0, 0, 0))
    Minv = np.linalg.inv(model.mass_matrix(q))
    f_star = -tau                                  # holding all three at rest
    ref = solve_direct(Minv, -Minv @ f_star, np.full(3, -np.inf), np.zeros(3))
    assert list(ref.state == FREE) == [True, True, False]
    assert list(f_star <= 0.0) == [True, False, False]   # the pulling rows: j2, j3
    impacts, solves = sim.limits.counters.impacts, sim.complementarity()['lcp_solves']
    sim.set_joint_efforts(dict(zip(['j1', 'j2', 'j3'], tau)))
    # The pivots at the state (what a step does where it finds the rows past their
    # bounds): pivoting the row furthest past its bound and solving again, the
    # sequential rule, would release j2, then j3 (both pull in turn): j2 would then
    # accelerate into its bound.
    sim.events._release(sim.state, q)
    assert list(sim.limits.active) == [-1, -1, 0]
    # One round: the solution was exact (the re-solve after its pivots finds no more).
    assert sim.complementarity()['lcp_solves'] == solves + 1
    sim.step()
    lam = sim.dynamics.solver.multipliers(sim.dynamics, sim.state)
    f = sim.events.efforts(lam)
    # The held rows carry the LCP's forces (at the step's end j3 has moved by ½ q̈ dt²:
    # 1e-5 of its coupling; bound with room).
    np.testing.assert_allclose(f[:2], ref.f[:2], rtol=1e-3)
    sim.step(200)
    qs = sim.joint_state().positions
    assert sim.limits.counters.impacts == impacts    # j2 never left to come back
    assert list(sim.limits.active[:2]) == [-1, -1] and qs[2] < UPPER - 0.01
    assert abs(qs[1] - UPPER) <= 1e-10


def test_a_bound_pulled_past_its_friction_slides_away_at_once(tmp_path):
    # A joint on its bound with friction F: one row, s f ≥ −F. Pulled by less than F it
    # sticks there; by more, it slides away with friction −F against it, from the
    # pivot on (never stuck in between).
    friction = 0.4
    sim = pressed_arm(tmp_path, friction)
    sim.set_joint_efforts({'j1': 3.0, 'j2': 3.0, 'j3': -0.3})   # below F on j3
    sim.step()
    assert list(sim.limits.active) == [-1, -1, 0]
    assert sim.joint_friction()['sticking'] == ['j3']
    (tmp_path / 'b').mkdir()
    sim = pressed_arm(tmp_path / 'b', friction)
    before = dict(sim.joint_friction()['counters'])
    solves = sim.complementarity()['lcp_solves']
    sim.set_joint_efforts({'j1': 3.0, 'j2': 3.0, 'j3': -1.0})   # above F
    sim.step()
    fr = sim.joint_friction()
    assert list(sim.limits.active) == [-1, -1, 0] and fr['slipping'] == {'j3': -1}
    assert fr['counters'] == {'sticks': before['sticks'], 'slips': before['slips'] + 1}
    assert sim.complementarity()['lcp_solves'] == solves + 1
    # j3 alone moving, j1 and j2 held: M₃₃ q̈₃ + h₃ = τ₃ + F (friction against −q).
    q, v = sim.joint_state().positions, sim.joint_state().velocities
    model = JointSpaceModel.from_urdf(arm_text(friction), gravity=(0, 0, 0))
    inertia = model.mass_matrix(q)[2, 2]
    bias = model.bias(q, v)[2]
    expected = (-1.0 + friction - bias) / inertia
    sim.step(10)
    v2 = sim.joint_state().velocities[2]
    # bound: q̈3 changes with q over 10 ms by |d(M33)/dq| q̇ ~ 1e-3 relative.
    assert (v2 - v[2]) / (10 * sim.dt) == pytest.approx(expected, rel=1e-2)


# -- impacts: the rows' impulses as one LCP ---------------------------------------------------


def impact_reference(q, v, held, hit, e=0.0):
    """
    Joint rates after an impact (no gravity), from the joint-space model.

    ``held``: joints whose rows may take impulses (each ``(joint, side)``: a bound on
    ``side``); ``hit``: the joint that hits. The impulses solve the box LCP with
    ``S = (M⁻¹)_UU`` (the free joints move), targets 0 for resting rows and the
    rebound ``−e v`` for the hit, ``s p ≥ 0``.
    """
    model = JointSpaceModel.from_urdf(arm_text(), gravity=(0, 0, 0))
    Minv = np.linalg.inv(model.mass_matrix(q))
    idx = [j for j, _ in held]
    S = Minv[np.ix_(idx, idx)]
    target = np.array([-e * v[j] if j == hit else 0.0 for j in idx])
    p_star = np.linalg.solve(S, target - v[idx])
    lo = np.array([0.0 if s > 0 else -np.inf for _, s in held])
    hi = np.array([np.inf if s > 0 else 0.0 for _, s in held])
    sol = solve_direct(S, -S @ p_star, lo, hi, start=p_star)
    impulse = np.zeros(3)
    impulse[idx] = sol.f
    return v + Minv @ impulse, p_star


def test_an_impact_that_would_pull_a_resting_bound_lets_it_go(tmp_path):
    # j1 rests on its upper bound (pressed onto it by 1 N m), j2 free, j3 swings onto its
    # upper bound at 2 rad/s: with both rows held the impact's impulse on j1 pulls it
    # (the coupling), which no bound can: the impulse LCP lets j1 go, and it leaves
    # with the rate the joint-space model gives with only j3's row taking an impulse.
    sim = robot_scene(tmp_path, arm_text(), dt=1e-4,
                      initial_positions={'j1': UPPER, 'j2': 0.0, 'j3': 0.45},
                      initial_velocities={'j3': 2.0}).simulation
    sim.set_joint_efforts({'j1': 1.0})
    sim.step(5)
    assert list(sim.limits.active) == [-1, 0, 0]
    solves = sim.complementarity()['lcp_solves']
    while sim.limits.counters.impacts < 2:
        js = sim.joint_state()
        q, v = js.positions.copy(), js.velocities.copy()
        sim.step()
    after = sim.joint_state().velocities
    expected, p_star = impact_reference(q, v, [(0, -1), (2, -1)], 2)
    assert p_star[0] > 0.0                       # held, j1's row would pull
    assert sim.complementarity()['lcp_solves'] == solves + 1
    assert list(sim.limits.active) == [0, 0, -1]  # j1 let go, j3 held (e = 0)
    # bound: the reference is at the step's start, the impact inside the step (0.1 ms:
    # the rates change by |q̈| dt < 1e-3 rad/s there: Coriolis and 1 N m, a few rad/s²).
    np.testing.assert_allclose(after, expected, atol=2e-3)
    assert after[0] < -0.05                       # j1 leaves its bound


def test_an_impact_moves_a_sticking_joint_which_then_slips(tmp_path):
    # j1 held still by friction (2 N m), j3 swings onto its upper bound: joint friction
    # is a bounded torque, so its impulse is at most F dt (2e-4 N m s here), far below
    # what holding j1 would take; j1 moves off with the rate the model gives with j1
    # free in the impact (to that impulse), and slips that way.
    sim = robot_scene(tmp_path, arm_text(2.0, ('j1',)), dt=1e-4,
                      initial_positions={'j1': 0.0, 'j2': 0.0, 'j3': 0.45},
                      initial_velocities={'j3': 2.0}).simulation
    assert sim.joint_friction()['sticking'] == ['j1']
    while sim.limits.counters.impacts < 1:
        js = sim.joint_state()
        q, v = js.positions.copy(), js.velocities.copy()
        sim.step()
    after = sim.joint_state().velocities
    expected, _ = impact_reference(q, v, [(2, -1)], 2)
    assert sim.joint_friction()['slipping'] == {'j1': 1 if expected[0] > 0 else -1}
    # bound: as above, and friction's impulse F dt at the impact and F over the rest of
    # the step on j1's inertia (about 0.5 kg m²): 8e-4 rad/s at most.
    np.testing.assert_allclose(after, expected, atol=2e-3)
    assert abs(expected[0]) > 0.05


def test_an_arm_seated_on_its_bounds_then_let_go_never_passes_one(tmp_path):
    # Hostile: arm7 set on a random bound of each arm joint, pressed onto them by 30 %
    # of its efforts under gravity (seating impacts on all at once), then random
    # efforts: coupled impacts and releases, each solved as one LCP. No bound passed
    # beyond the location's tolerance, no step cut short, no problem unsolved.
    from joint_space_reference import urdf_path
    from rigid_body_sim.scene import scene_from_dict
    rng = np.random.default_rng(3)
    for trial in range(4):
        sim = scene_from_dict({'dt': 1e-3, 'effects': {'gravity': {'g_world': [0, 0, -9.81]}},
                               'robots': [{'urdf': urdf_path('arm7.urdf')}]},
                              str(tmp_path / f'scene{trial}.yaml')).simulation
        specs = {j.name: j.spec for j in sim.joints.joints}
        names = [n for n in sim.joint_names() if n.startswith('joint')]
        side = rng.choice([-1, 1], len(names))
        sim.set_joint_state({n: specs[n].lower if s > 0 else specs[n].upper
                             for n, s in zip(names, side)})
        effort = np.array([specs[n].effort for n in names])
        sim.set_joint_efforts(dict(zip(names, -0.3 * side * effort)))
        lower = np.array([specs[n].lower for n in sim.joint_names()])
        upper = np.array([specs[n].upper for n in sim.joint_names()])
        worst = 0.0
        for k in range(300):
            if k == 100:
                sim.set_joint_efforts(dict(zip(names, rng.uniform(-0.5, 0.5, 7) * effort)))
            sim.step()
            q = sim.joint_state().positions
            worst = max(worst, float(np.max(np.maximum(lower - q, q - upper))))
        c = sim.complementarity()
        assert sim.limits.counters.impacts >= 7 and c['lcp_solves'] > 0
        assert sim.limits.counters.events_capped == 0 and c['lcp_failures'] == 0
        # bound: impacts located to 1e-10 rad, the rows' drift while held below it.
        assert worst <= 1e-10
        # bound: the direct method's residual is rounding of forces up to 87 N m.
        assert c['lcp_residual_max'] <= 1e-11
