"""
Each connected component of the constraint graph takes the sub-steps it needs.

A fast spinning top on a ball joint needs about 4 sub-steps per step at
dt = 1e-2 (100 rad/s, at most 0.25 rad a sub-step); a slow pendulum or a free
body beside it needs none. Stepping them in one scene must give each exactly the
motion it has alone (bit for bit: the same arithmetic on the same numbers), and
the sub-step counter must count the top's sub-steps only.
"""

import numpy as np
import pytest
from rigid_body_sim.core import Constraint, Gravity, INTEGRATORS, RigidBody, Simulation
from rigid_body_sim.core import rotation as so3
from rigid_body_sim.core.mechanisms import ring

DT = 1e-2
STEPS = 60


def top(offset):
    tilt = so3.exp_quat(np.array([0.0, np.radians(20.0), 0.0]))
    axis = so3.rotate(tilt, np.array([0.0, 0.0, 1.0]))
    body = RigidBody('top', 0.5, [2e-3, 2e-3, 3e-3], position_world=offset + 0.1 * axis,
                     orientation_xyzw=tilt, angular_velocity_body=[0.0, 0.0, 100.0])
    return body, Constraint('tip', 'ball', 'top', None, anchor_world=offset)


def pendulum(offset):
    body = RigidBody('bob', 1.0, [1e-3, 2e-3, 3e-3], position_world=offset + [0.3, 0.0, 0.0])
    return body, Constraint('pivot', 'ball', 'bob', None, anchor_world=offset)


def free_body():
    return RigidBody('box', 2.0, [0.02, 0.03, 0.04], position_world=[5.0, 0.0, 0.0],
                     angular_velocity_body=[0.1, 3.0, 0.2], linear_velocity_world=[0, 0, 1])


def run(bodies, constraints, integrator):
    sim = Simulation(bodies, [Gravity()], integrator, DT, constraints)
    sim.step(STEPS)
    return sim


def state_of(sim, name):
    pos, quat = sim.pose(name)
    vel, omega = sim.twist(name)
    return np.concatenate([pos, quat, vel, omega])


@pytest.mark.parametrize('integrator', sorted(INTEGRATORS))
def test_components_move_as_they_do_alone(integrator):
    top_body, top_joint = top(np.array([0.0, 0.0, 0.0]))
    bob, pivot = pendulum(np.array([2.0, 0.0, 0.0]))
    box = free_body()
    together = run([top_body, bob, box], [top_joint, pivot], integrator)
    alone = {'top': run([top_body], [top_joint], integrator),
             'bob': run([bob], [pivot], integrator),
             'box': run([box], [], integrator)}
    for name, sim in alone.items():
        # Exact: the same compiled arithmetic on the same numbers, on this machine in this run.
        np.testing.assert_array_equal(state_of(together, name), state_of(sim, name))
    # Only the top is sub-stepped: 100 rad/s * 1e-2 s / 0.25 rad = 4 sub-steps a step.
    assert alone['top'].work()['substeps'] >= 4 * STEPS
    assert alone['bob'].work()['substeps'] == 0
    assert together.work()['substeps'] == alone['top'].work()['substeps']


def test_a_closed_loop_beyond_the_dense_size_keeps_its_joints_and_energy():
    # A ring of 12 hinged links closed by a ball joint: 63 rows (more than DENSE_ROWS,
    # not a tree; 3 of them redundant), solved densely inside the compiled step.
    n, radius = 12, 1.0
    bodies, joints = [], []
    for i in range(n):
        a0, a1 = 2 * np.pi * i / n, 2 * np.pi * (i + 1) / n
        p0 = radius * np.array([np.cos(a0), 0.0, np.sin(a0)])
        p1 = radius * np.array([np.cos(a1), 0.0, np.sin(a1)])
        bodies.append(RigidBody(f'l{i}', 1.0, [1e-3, 2e-3, 3e-3], position_world=(p0 + p1) / 2))
        joints.append(Constraint(f'j{i}', 'hinge', f'l{i}', f'l{i - 1}' if i else None,
                                 anchor_world=p0, axis_world=[0.0, 1.0, 0.0]))
    joints.append(Constraint('close', 'ball', f'l{n - 1}', 'l0',
                             anchor_world=[radius, 0.0, 0.0]))
    sim = Simulation(bodies, [Gravity()], 'lie_poisson2', 1e-3, joints)
    assert sim.dynamics.solver.constraints.n_rows == 63
    e0 = sim.diagnostics().total_energy
    sim.step(300)
    d = sim.diagnostics()
    # bound: SHAKE stops at 1e-13 m (or 16 sqrt(m) eps |x| = 3e-14); measured 2e-14; x1000
    assert d.constraint_violation < 1e-10
    # lie_poisson2's bounded O(dt²) energy error, measured 1.0e-5 J: 1e-7 of m g R n.
    # bound: C dt² = 1.0e-5 J (4.0x less at dt / 2), rounding 300 eps 118 J = 8e-12 J; x11
    assert abs(d.total_energy - e0) < 1e-6 * n * 9.81 * radius
    assert sim.dynamics.solver.counters.rank_deficient_solves > 0   # the redundant rows


@pytest.mark.parametrize('name', sorted(INTEGRATORS))
def test_a_closed_loop_solved_through_its_spanning_tree_moves_as_when_solved_densely(
        name, monkeypatch):
    # A ring of 12 hinged rods closed by a ball joint (63 rows, 3 redundant): the tree
    # solve of its spanning chain plus the Schur complement of the closing joint's rows
    # must give the motion of the dense solve (which it replaced for closed loops).
    from rigid_body_sim.core import solver
    from rigid_body_sim.core.kernels.layout import Solve
    loop = ring(12, name)
    assert loop.dynamics.solver.kernel_setup().components[0].solve == Solve.LOOP
    monkeypatch.setattr(solver, 'DENSE_ROWS', 1000)
    monkeypatch.setattr(solver, 'LOOP_DENSE_ROWS', 1000)
    dense = ring(12, name)
    assert dense.dynamics.solver.kernel_setup().components[0].solve == Solve.DENSE
    for _ in range(4):
        loop.step(50)
        dense.step(50)
        for field in ('pos_com_world', 'quat_principal_world', 'vel_com_world',
                      'ang_vel_principal'):
            # bound: solve rounding (1.1e-12 in a step) grown <= 32x: measured 7.7e-12; x130
            np.testing.assert_allclose(getattr(loop.state, field), getattr(dense.state, field),
                                       rtol=0, atol=1e-9)
    # The same violation (rkmk4 has no position projection: ~1e-10 m; the others ~1e-13).
    v_loop, v_dense = (s.diagnostics().constraint_violation for s in (loop, dense))
    # bound: rkmk4's O(dt⁴) drift 1.3e-10 (x7); the states' difference moves it 2e-14 (x500)
    assert v_loop < 1e-9 and abs(v_loop - v_dense) < 1e-11
    # The redundant rows are found in the closing joint's block, as the dense solve finds them.
    assert loop.dynamics.solver.counters.rank_deficient_solves > 0


@pytest.mark.parametrize('name', sorted(INTEGRATORS))
def test_outputs_computed_inside_a_constrained_step_equal_those_computed_when_read(name):
    # As for free bodies (test_free_body): a step of a one-component scene whose start
    # state was read computes the new outputs in its kernel, exactly as the read would.
    def read(sim):
        parts = (*sim.pose(), *sim.twist(), *sim.twist(frame='body'))
        return np.concatenate([np.ravel(p) for p in parts])

    every, late = ring(12, name), ring(12, name)
    read(every)
    for k in range(1, 30):
        every.step()
        late.step()
        assert every.bodies.outputs_cache.key[0] is every.state
        got = read(every)
        if k % 7 == 0:
            # Exact: the step's kernel and the read call the same compiled outputs function.
            assert np.array_equal(got, read(late))
    assert np.array_equal(read(every), read(late))


def _hinge_chain(n, name, again=False):
    from rigid_body_sim.core.mechanisms import rod
    bodies = [rod(f'l{i}', np.array([0.1 * i, 0, 0]), np.array([1.0, 0, 0]), 0.1, 1.0)
              for i in range(n)]
    joints = [Constraint(f'j{i}', 'hinge', f'l{i}', f'l{i - 1}' if i else None,
                         anchor_world=(0.1 * i, 0, 0), axis_world=(0, 1, 0)) for i in range(n)]
    if again:   # the joint between l1 and l2 once more: 5 redundant rows
        joints.append(Constraint('again', 'hinge', 'l2', 'l1', anchor_world=(0.2, 0, 0),
                                 axis_world=(0, 1, 0)))
    return Simulation(bodies, [Gravity()], name, 1e-3, joints)


@pytest.mark.parametrize('name', sorted(INTEGRATORS))
def test_mid_sized_components_take_the_tree_solve_unless_they_close_a_loop(name, monkeypatch):
    # 25 to 48 rows: an open chain takes the tree solve (faster there) and moves as under
    # the dense solve; the same chain with a joint added twice (a loop of two, redundant
    # rows) keeps the dense solve and its truncated SVD, and moves as without the copy.
    from rigid_body_sim.core import solver
    from rigid_body_sim.core.kernels.layout import Solve
    tree = _hinge_chain(6, name)
    twice = _hinge_chain(5, name, again=True)
    assert tree.dynamics.solver.constraints.n_rows == twice.dynamics.solver.constraints.n_rows
    assert tree.dynamics.solver.kernel_setup().components[0].solve == Solve.TREE
    assert twice.dynamics.solver.kernel_setup().components[0].solve == Solve.DENSE
    once = _hinge_chain(5, name)
    monkeypatch.setattr(solver, 'KERNEL_DENSE_ROWS', 48)
    dense = _hinge_chain(6, name)
    assert dense.dynamics.solver.kernel_setup().components[0].solve == Solve.DENSE
    for sim in (tree, dense, twice, once):
        sim.step(400)   # 0.4 s of a falling chain
    # bound: the solves' rounding grown by the chain (a 1e-12 push grows 130x): 1e-12; x1000
    np.testing.assert_allclose(tree.state.y, dense.state.y, rtol=0, atol=1e-9)
    # bound: the copy's rows split the load by a truncated SVD (1e-13 of s[0]): 1.7e-11; x60
    np.testing.assert_allclose(twice.state.y, once.state.y, rtol=0, atol=1e-9)
    assert twice.dynamics.solver.counters.rank_deficient_solves > 0


@pytest.mark.parametrize('name', sorted(INTEGRATORS))
def test_a_loop_through_the_world_is_closed_like_one_among_bodies(name, monkeypatch):
    # The four-bar's loop runs through the world (crank and rocker hinged to it): its
    # last joint to the world closes the loop, and its 3 redundant rows meet the
    # closure block's truncated SVD. It must move as under the dense solve of the whole
    # system, as unbiased (the tree solve's Tikhonov term would not be).
    from rigid_body_sim.core import solver
    from rigid_body_sim.core.kernels.layout import Solve
    from rigid_body_sim.core.mechanisms import four_bar
    loop = four_bar(name, 1e-3)
    assert loop.dynamics.solver.kernel_setup().components[0].solve == Solve.LOOP
    monkeypatch.setattr(solver, 'LOOP_DENSE_ROWS', 1000)
    dense = four_bar(name, 1e-3)
    assert dense.dynamics.solver.kernel_setup().components[0].solve == Solve.DENSE
    for sim in (loop, dense):
        sim.step(1000)
    # bound: rounding grown <= 150x: 1e-11; rkmk4's drift, split otherwise: 2.5e-10; x4
    np.testing.assert_allclose(loop.state.y, dense.state.y, rtol=0, atol=1e-9)
    assert loop.dynamics.solver.counters.rank_deficient_solves > 0
