"""One constraint solve: the multipliers a user reads are the ones the step uses."""

import ast
from pathlib import Path

from joint_scenes import pendulum
import numpy as np
import pytest
from rigid_body_sim.core import Constraint, Damping, Gravity, RigidBody, Simulation
from rigid_body_sim.core import rotation as so3
from rigid_body_sim.core.mechanisms import chain, four_bar, ring, tree
from rigid_body_sim.core.reference import constrained_accelerations

EPS = np.finfo(float).eps


def two_components(name, damping=False):
    """Build a pendulum, a separate hinged pair and a free body: the per-component path."""
    bodies = [RigidBody('bob', 1.0, [1e-3, 2e-3, 3e-3], position_world=[0.3, 0.0, -0.4],
                        linear_velocity_world=[0.0, 0.5, 0.0]),
              RigidBody('p', 2.0, [0.02, 0.03, 0.04], position_world=[2.0, 0.0, 0.0],
                        angular_velocity_body=[0.3, -0.2, 0.5]),
              RigidBody('q', 1.5, [0.05, 0.02, 0.03], position_world=[2.0, 0.0, -0.5]),
              RigidBody('free', 1.0, [1.0, 2.0, 3.0], position_world=[5.0, 0.0, 0.0],
                        angular_velocity_body=[0.1, 2.0, 0.1])]
    joints = [Constraint('pivot', 'ball', 'bob', None, anchor_world=[0, 0, 0]),
              Constraint('top', 'ball', 'p', None, anchor_world=[2.0, 0.0, 0.25]),
              Constraint('pair', 'hinge', 'p', 'q', anchor_world=[2.0, 0.0, -0.25],
                         axis_world=[0.0, 1.0, 0.0])]
    effects = [Gravity()] + ([Damping(0.1, 0.01)] if damping else [])
    return Simulation(bodies, effects, name, 1e-3, joints)


SCENES = {
    'pendulum': lambda name: pendulum(name, 1e-3, np.radians(60.0)),   # dense
    'chain30': lambda name: chain(30, name),                           # tree solve
    'four_bar': lambda name: four_bar(name, 1e-3),                     # loop, redundant rows
    'two_components': two_components,                                  # several components
}


def oracle(sim):
    """Return the naive oracle's constraint wrench on each body now, and cond(G M⁻¹ Gᵀ)."""
    s, dyn = sim.state, sim.dynamics
    args = (s.time, s.pos_com_world, s.quat_principal_world, s.vel_com_world,
            s.ang_vel_principal)
    free, free_dot = dyn.accelerations(*args)
    acc, om_dot, lam = constrained_accelerations(dyn, *args)
    force = (acc - free) * dyn.bodies.mass[:, None]
    torque_principal = (om_dot - free_dot) * dyn.bodies.moments
    torque = np.einsum('nij,nj->ni', so3.quat_to_matrix(s.quat_principal_world),
                       torque_principal)
    ev = dyn.solver.constraints.evaluate(*args[1:])
    G = ev.jacobian.toarray()
    minv = np.concatenate([np.repeat(dyn.bodies.inv_mass[:, None], 3, axis=1),
                           1.0 / dyn.bodies.moments], axis=1).ravel()
    sv = np.linalg.svd((G * minv) @ G.T, compute_uv=False)
    kept = sv[sv > 1e-13 * sv[0]]
    return np.concatenate([force, torque], axis=1), sv[0] / kept[-1]


@pytest.mark.parametrize('name', ['symplectic_euler', 'lie_poisson2'])
@pytest.mark.parametrize('scene', sorted(SCENES))
def test_the_multipliers_read_at_a_state_are_the_ones_the_next_step_uses(scene, name):
    # Both methods take their one solve for λ in the kick at the step's start state
    # (sub-steps stay at one: these scenes turn by far less than max_rotation a step;
    # no damping, whose flow would come between the start state and the kick).
    sim = SCENES[scene](name)
    sim.step(3)
    dyn = sim.dynamics
    read = dyn.solver.multipliers(dyn, sim.state)
    sim.step(1)
    used = dyn.last_multipliers
    _, cond = oracle(sim)
    # bound: the same compiled code on the same state, except that the kick recomputes
    # Ω = (JΩ)/J (2 eps relative in the velocities): |dλ| <= cond(A) 2 eps |λ|, x10
    assert np.max(np.abs(used - read)) <= 20.0 * cond * EPS * np.max(np.abs(read))
    assert np.max(np.abs(read)) > 0.0


@pytest.mark.parametrize('scene', ['pendulum', 'chain30', 'four_bar', 'ring12', 'tree15',
                                   'two_components'])
def test_the_net_reaction_on_each_body_is_the_oracles(scene):
    # The per-constraint split of a redundant loop's load is a convention (here: the
    # step's own); the net constraint wrench on each body is unique, and must be the one
    # the naive pseudo-inverse gives.
    build = dict(SCENES, ring12=lambda name: ring(12, name),
                 tree15=lambda name: tree(15, name),
                 two_components=lambda name: two_components(name, damping=True))[scene]
    sim = build('rkmk4')
    sim.step(5)
    names = list(sim.dynamics.bodies.names)
    net = np.zeros((len(names), 6))
    for per_body in sim.reactions().values():
        for body, r in per_body.items():
            net[names.index(body)] += np.concatenate([r.force_world, r.torque_com_world])
    expected, cond = oracle(sim)
    # bound: two backward-stable solves of one system differ by <= 2 cond(A) eps relative
    # (cond of the rank the truncation keeps); x5 for compiled code on another CPU
    scale = np.max(np.abs(expected))
    assert np.max(np.abs(net - expected)) <= 10.0 * cond * EPS * scale
    assert scale > 0.0


@pytest.mark.parametrize('scene', ['pendulum', 'chain30', 'two_components'])
def test_the_multipliers_computed_afresh_are_the_oracles(scene):
    # Without the geometry a step left (here: just built), the multipliers come from a
    # fresh geometry and factorization; for rows without redundancy λ is unique.
    sim = SCENES[scene]('lie_poisson2')
    sim.step(2)
    dyn, s = sim.dynamics, sim.state
    dyn.solver.kernel_setup().geometry_of[0] = None
    read = dyn.solver.multipliers(dyn, s)
    lam = constrained_accelerations(dyn, s.time, s.pos_com_world, s.quat_principal_world,
                                    s.vel_com_world, s.ang_vel_principal)[2]
    _, cond = oracle(sim)
    # bound: two backward-stable solves of one full-rank system: 2 cond(A) eps, x5
    assert np.max(np.abs(read - lam)) <= 10.0 * cond * EPS * np.max(np.abs(lam))


@pytest.mark.parametrize('name', ['lie_poisson2', 'rkmk4'])
def test_the_reaction_read_when_a_wrench_has_just_ended_is_without_it(name):
    sim = SCENES['pendulum'](name)
    sim.apply_wrench(sim.dynamics.bodies.names[0], (0.0, 0.0, 50.0), duration=2e-3)
    sim.step(2)   # the wrench ends with this step
    net = sum(np.concatenate([r.force_world, r.torque_com_world])
              for per_body in sim.reactions().values() for r in per_body.values())
    expected, cond = oracle(sim)
    # bound: as the net reaction above (one body)
    assert np.max(np.abs(net - expected[0])) <= 10.0 * cond * EPS * np.max(np.abs(expected))


def test_a_step_that_raises_leaves_no_geometry_claimed():
    # A generic constraint whose function fails in the middle of a step: the workspaces
    # then hold an iterate, not the state's geometry, and nothing may reuse it.
    calls = {'n': 0}

    def rod(xa, Ra, xb, Rb):
        calls['n'] += 1
        if calls['n'] == calls.get('fail', -1):
            raise ValueError('failing on purpose')
        return np.array([xa @ xa - 0.25])

    bob = RigidBody('bob', 1.0, [1e-3, 1e-3, 1e-3], position_world=[0.3, 0.0, -0.4])
    sim = Simulation([bob], [Gravity()], 'lie_poisson2', 1e-2,
                     [Constraint('rod', 'generic', 'bob', None, function=rod)])
    sim.step(2)
    setup = sim.dynamics.solver.kernel_setup()
    assert setup.geometry_of[0] is sim.state.y   # a step that ended claims its geometry
    calls['fail'] = calls['n'] + 2
    with pytest.raises(Exception, match='failing on purpose'):
        sim.step()
    assert setup.geometry_of[0] is None


def test_the_solver_has_no_solve_of_its_own():
    # One implementation: the constraint solver calls the compiled kernels; it imports
    # no linear algebra (scipy) to solve beside them.
    source = (Path(__file__).resolve().parents[1] / 'rigid_body_sim' / 'core'
              / 'solver.py').read_text()
    imported = {alias.name.split('.')[0] for node in ast.walk(ast.parse(source))
                if isinstance(node, ast.Import) for alias in node.names}
    imported |= {(node.module or '').split('.')[0] for node in ast.walk(ast.parse(source))
                 if isinstance(node, ast.ImportFrom) and node.level == 0}
    assert 'scipy' not in imported
    assert 'linalg' not in source.replace('kernels', '')
