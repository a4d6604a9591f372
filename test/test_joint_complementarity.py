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


def arm_text(friction=0.0):
    """Return a three-link arm in the x–z plane, each hinge limited to [−0.5, 0.5] rad."""
    extra = LIMIT + (f'<dynamics friction="{friction!r}"/>' if friction else '')
    return robot('arm3', link('world'),
                 link('a', inertial(2.0, (0.25, 0, 0), ixx=0.01, iyy=0.03, izz=0.03)),
                 link('b', inertial(1.5, (0.2, 0, 0), ixx=0.01, iyy=0.02, izz=0.02)),
                 link('c', inertial(1.0, (0.15, 0, 0), ixx=0.01, iyy=0.01, izz=0.01)),
                 joint('j1', 'revolute', 'world', 'a', axis=(0, 1, 0), extra=extra),
                 joint('j2', 'revolute', 'a', 'b', xyz=(0.5, 0, 0), axis=(0, 1, 0), extra=extra),
                 joint('j3', 'revolute', 'b', 'c', xyz=(0.4, 0, 0), axis=(0, 1, 0), extra=extra))


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
