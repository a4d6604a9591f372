"""Bad constraint input: a clear SpecError naming the field; the simulation carries on."""

import math

import numpy as np
import pytest
from rigid_body_sim.core import Constraint, Gravity, RigidBody, Simulation, SpecError
from rigid_body_sim.core.mechanisms import chain

NAN = float('nan')


def simulation():
    bodies = [RigidBody('a', 1.0, [0.1, 0.1, 0.1], position_world=[0.5, 0.0, 0.0]),
              RigidBody('b', 1.0, [0.1, 0.2, 0.25], position_world=[1.0, 0.0, 0.0])]
    return Simulation(bodies, [Gravity()], 'lie_poisson2', 1e-3,
                      [Constraint('pivot', 'ball', 'a', None, anchor_world=[0.0, 0.0, 0.0])])


@pytest.mark.parametrize('make, message', [
    (lambda: Constraint('j', 'ball', 'a', 'a'),
     r'^body_b: a body cannot be constrained to itself'),
    (lambda: Constraint('j', 'hinge', 'a', 'b', anchor_world=[0, 0, 0], axis_world=[0, 0, 0]),
     r'^axis_world: zero-length axis'),
    (lambda: Constraint('j', 'hinge', 'a', 'b'), r'^axis_world: required for a hinge'),
    (lambda: Constraint('j', 'ball', 'a', 'b', anchor_world=[0.0, NAN, 0.0]),
     r'^anchor_world: must be finite'),
    (lambda: Constraint('j', 'ball', 'a', 'b', anchor_a_body=[np.inf, 0, 0]),
     r'^anchor_a_body: must be finite'),
    (lambda: Constraint('j', 'weld', 'a', 'b'), r"^type: unknown constraint type 'weld'"),
    (lambda: Constraint('j', 'generic', 'a', 'b'), r'^function: a generic constraint needs'),
    (lambda: Constraint('', 'ball', 'a', 'b'), r'^name: must be a non-empty string'),
    (lambda: Constraint('j', 'ball', None), r'^body_a: must name a body, got None'),
    (lambda: Constraint('j', 'ball', 'a', 3), r'^body_b: must name a body, or be None or '),
    (lambda: Constraint('j', 'distance', 'a', 'b', length=-1.0), r'^length: must be positive'),
])
def test_bad_constraint_spec(make, message):
    with pytest.raises(SpecError, match=message):
        make()


@pytest.mark.parametrize('spec, message', [
    (Constraint('j', 'ball', 'nobody', 'b'), r"^body_a: unknown body 'nobody'"),
    (Constraint('j', 'ball', 'a', 'nobody'), r"^body_b: unknown body 'nobody'"),
    (Constraint('pivot', 'ball', 'b', None), r"^name: duplicate constraint name 'pivot'"),
    (Constraint('j', 'generic', 'a', 'b', function=lambda xa, Ra, xb, Rb: np.array([NAN])),
     r'^function: must return a non-empty 1-D array of finite numbers'),
    (Constraint('j', 'generic', 'a', 'b', function=lambda xa, Ra, xb, Rb: 1 / 0),
     r'^function: raised ZeroDivisionError'),
    (Constraint('j', 'distance', 'a', 'b', anchor_a_body=[0.25, 0, 0],
                anchor_b_body=[-0.25, 0, 0]), r'^length: the anchors coincide'),
    # The pivot holds a's point (-0.5, 0, 0) at the world origin; this one would hold the
    # same point 0.3 m away: no configuration satisfies both.
    (Constraint('j', 'ball', 'a', None, anchor_a_body=[-0.5, 0, 0], anchor_b_body=[0.3, 0, 0]),
     r"^constraint: constraint 'j' is inconsistent with \['pivot'\]: no configuration "
     r'satisfies them all \(the closest leaves max \|Φ\| = 0\.15 m or rad\); it was not added'),
])
def test_rejected_constraint_leaves_the_simulation_intact(spec, message):
    sim, reference = simulation(), simulation()
    with pytest.raises(SpecError, match=message):
        sim.add_constraint(spec)
    assert sim.constraint_names == ['pivot']
    sim.step(200)
    reference.step(200)
    np.testing.assert_array_equal(sim.pose()[0], reference.pose()[0])


def test_removing_an_unknown_constraint():
    sim = simulation()
    with pytest.raises(SpecError, match=r"^name: no constraint named 'nope'; constraints: "
                                        r"\['pivot'\]"):
        sim.remove_constraint('nope')
    sim.step(10)
    assert sim.constraint_names == ['pivot']


def test_removed_joint_releases_the_body_into_free_fall():
    sim = simulation()
    sim.run(0.3)
    sim.remove_constraint('pivot')
    x0, v0 = sim.state.pos_com_world[0].copy(), sim.state.vel_com_world[0].copy()
    sim.run(0.5)
    g = np.array([0.0, 0.0, -9.81])
    # bound: worst-case rounding N u (|x| + t |v|) = 500 x 1.1e-16 x (2.4 + 0.5 x 6.6) = 3e-13
    np.testing.assert_allclose(sim.state.pos_com_world[0], x0 + 0.5 * v0 + 0.125 * g,
                               rtol=1e-12, atol=1e-12)
    assert sim.constraint_names == []
    assert not sim.dynamics.constrained


def test_inconsistent_initial_constraint_is_named():
    bodies = [RigidBody('a', 1.0, [0.1, 0.1, 0.1], position_world=[0.5, 0.0, 0.0]),
              RigidBody('b', 1.0, [0.1, 0.2, 0.25], position_world=[1.0, 0.0, 0.0])]
    joints = [Constraint('pivot', 'ball', 'a', None, anchor_world=[0.0, 0.0, 0.0]),
              Constraint('link', 'ball', 'b', 'a', anchor_world=[0.75, 0.0, 0.0]),
              # The pivot keeps a's centre 0.5 m from the origin: 0.2 m cannot hold.
              Constraint('rod', 'distance', 'a', None, length=0.2),
              Constraint('spare', 'distance', 'b', None)]
    with pytest.raises(SpecError, match=r"^constraints\[2\]: constraint 'rod' is inconsistent "
                                        r"with \['pivot', 'link'\].*no simulation was built"):
        Simulation(bodies, [Gravity()], 'lie_poisson2', 1e-3, joints)


def test_consistent_but_violated_constraint_is_accepted():
    # The pivot keeps a's point (0.5, 0, 0) 1 m from the origin; (0.6, 0.8, 0) is 1 m away:
    # reachable, so the joint is added 0.8 m violated and closes along exp(-t / tau).
    sim = simulation()
    sim.add_constraint(Constraint('far', 'ball', 'a', None, anchor_a_body=[0.5, 0, 0],
                                  anchor_b_body=[0.6, 0.8, 0.0]))
    assert sim.constraint_violation()['far'] > 0.7
    sim.run(1.0)
    # bound: 0.8 exp(-1 s / 0.05 s) = 1.6e-9 + SHAKE's floor 5e-12; half the rate: 3.6e-5
    assert sim.constraint_violation()['far'] < 1e-7


def test_reachable_only_by_folding_is_accepted():
    # A straight chain is a singular start: Gauss–Newton from it stalls, although folding
    # the chain (0.5 m long) puts its tip on a point 0.45 m away at 162 degrees.
    sim = chain(5, 'lie_poisson2')
    angle = 0.9 * np.pi
    sim.add_constraint(Constraint('tip', 'ball', 'l4', None, anchor_a_body=[0.05, 0, 0],
                                  anchor_b_body=[0.45 * np.cos(angle), 0.45 * np.sin(angle),
                                                 0.0]))
    assert sim.constraint_violation()['tip'] > 0.5
    sim.run(2.0)
    # bound: 0.93 exp(-2 s / 0.05 s) = 4e-18 + SHAKE's floor 1e-13 / (1 - exp(-dt / tau)) = 5e-12
    assert sim.constraint_violation()['tip'] < 1e-9


def test_generic_function_undefined_away_from_here_is_accepted():
    # sqrt(x - 0.4) exists only for x >= 0.4: the consistency search may step outside;
    # it cannot tell, so the constraint is accepted and the motion goes on.
    sim = simulation()
    sim.add_constraint(Constraint('g', 'generic', 'b', None,
                                  function=lambda xa, Ra, xb, Rb: np.array(
                                      [math.sqrt(xa[0] - 0.4) - 0.7])))
    assert sim.constraint_names == ['pivot', 'g']
    sim.run(1.0)
    # bound: 0.075 m exp(-1 s / 0.05 s) = 1.5e-10 + SHAKE's floor 5e-12; half the rate: 3e-6
    assert sim.constraint_violation()['g'] < 1e-8
