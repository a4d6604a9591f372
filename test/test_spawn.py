"""
Bodies added and removed at run time (``Simulation.add_body``, ``remove_body``).

References: free bodies already there go on bit for bit as in a run without the spawn
(the same compiled arithmetic, body by body); bodies held by constraints and contacts
go on as without it to the solvers' tolerances (their warm starts restart: the
constraint solve's and the friction fixed point's, whose stopping tolerances, 1e-8 of
an impulse, bound what a restart changes); the spawned body flies the closed form from
its own initial conditions; the same spawns at the same steps give bit-identical runs;
a removal names the constraints it took; every refusal names its field and changes
nothing; a reset puts spawned bodies back where they were spawned, and
``remove_spawned`` removes them.
"""

import numpy as np
import pytest

from rigid_body_sim.core import CollisionShape, Constraint, Damping, Gravity, RigidBody, \
    Simulation, SpecError

G = 9.81


def _scene():
    return Simulation(
        [RigidBody('a', 1.0, (0.1, 0.2, 0.3), position_world=(0.0, 0.0, 1.0),
                   angular_velocity_body=(1.0, 2.0, 3.0)),
         RigidBody('b', 2.0, (0.1, 0.1, 0.1), position_world=(1.0, 0.0, 1.0),
                   linear_velocity_world=(0.0, 0.5, 0.0)),
         RigidBody('box', 1.0, (0.02, 0.02, 0.02), position_world=(-3.0, 0.0, 0.1))],
        [Gravity(), Damping(linear=0.1, bodies=['a', 'b'])], integrator='rkmk4',
        constraints=[Constraint('pin', 'ball', 'b', None, anchor_world=(1.0, 0.0, 2.0))],
        shapes=[CollisionShape('plane', None, friction=0.5),
                CollisionShape('sphere', 'a', radius=0.1),
                CollisionShape('box', 'box', size=(0.2, 0.2, 0.2), friction=0.5)])


def _rows(sim, names):
    idx = [sim.bodies.index[n] for n in names]
    return [p[idx].copy() for p in sim.state.parts]


def _same(x, y):
    return all(np.array_equal(u, v) for u, v in zip(x, y))


def _close(x, y):
    """
    Positions to 1e-10 m, velocities to 1e-8 m/s (and rad, rad/s): the solvers' restart.

    A restarted fixed point may end 1e-8 of an impulse (~m g dt) apart: 1e-10 m/s a
    step, 3e-11 m over 300 steps of 1 ms; measured: 1e-17.
    """
    for k, (u, v) in enumerate(zip(x, y)):
        np.testing.assert_allclose(u, v, rtol=0, atol=1e-10 if k < 2 else 1e-8)


def test_free_bodies_go_on_bit_for_bit_across_a_spawn_and_a_removal():
    def free():
        return Simulation([RigidBody('a', 1.0, (0.1, 0.2, 0.3), angular_velocity_body=(1, 2, 3)),
                           RigidBody('b', 2.0, (0.3, 0.2, 0.1), linear_velocity_world=(0, 1, 0))],
                          [Gravity(), Damping(linear=0.2, angular=0.1)], integrator='rkmk4')
    sim, ref = free(), free()
    sim.step(10)
    ref.step(10)
    sim.add_body(RigidBody('c', 1.0, (0.1,) * 3, angular_velocity_body=(0, 0, 5)))
    sim.step(100)
    ref.step(100)
    assert _same(_rows(sim, ['a', 'b']), _rows(ref, ['a', 'b']))
    sim.remove_body('c')
    sim.step(100)
    ref.step(100)
    assert np.array_equal(sim.state.y, ref.state.y)


def test_a_spawn_leaves_the_others_going_on_and_the_new_body_flies_its_closed_form():
    sim, ref = _scene(), _scene()
    for s in (sim, ref):
        s.step(10)
        s.add_constraint(Constraint('tie', 'ball', 'a', 'b', anchor_world=(0.5, 0.0, 1.0)))
        s.apply_wrench('a', force=(1.0, 0.0, 0.0), key='push')
        s.step(7)
    sim.add_body(RigidBody('c', 0.5, (0.01,) * 3, position_world=(5.0, 5.0, 3.0),
                           linear_velocity_world=(1.0, 0.0, 0.0)),
                 [CollisionShape('sphere', 'c', radius=0.1)])
    assert sim.spawned == ['c'] and sim.time == ref.time
    # The run-time constraint is anchored where it was.
    assert all(np.array_equal(x[1], y[1]) for x, y in zip(
        sim.dynamics.solver.constraints.anchors('tie'),
        ref.dynamics.solver.constraints.anchors('tie')))
    sim.step(300)
    ref.step(300)
    _close(_rows(sim, ['a', 'b', 'box']), _rows(ref, ['a', 'b', 'box']))
    t = 0.3
    np.testing.assert_allclose(sim.pose('c')[0], [5.0 + t, 5.0, 3.0 - 0.5 * G * t * t],
                               rtol=0, atol=1e-12)


def test_the_same_spawns_at_the_same_steps_give_bit_identical_runs():
    runs = []
    for _ in range(2):
        sim = _scene()
        for k in range(5):
            sim.step(20)
            sim.add_body(RigidBody(f's{k}', 1.0, (0.004,) * 3,
                                   position_world=(0.3 * k - 2.0, 1.0, 0.5)),
                         [CollisionShape('sphere', f's{k}', radius=0.1, restitution=0.5)])
        sim.step(50)
        sim.remove_body('s2')
        sim.step(200)   # (the spheres land and bounce: contact steps, impacts located)
        runs.append(sim.state.y.copy())
    assert np.array_equal(runs[0], runs[1])
    assert len(runs[0]) == len(_scene().state.y) // 3 * 7


def test_a_removal_takes_its_constraints_and_its_mentions_and_leaves_the_others():
    sim, ref = _scene(), _scene()
    for s in (sim, ref):
        s.apply_wrench('b', force=(0.0, 0.0, 5.0), key='lift')
        s.step(10)
    # (a second pin at the first's point: redundant, consistent, on 'b' alone)
    sim.add_constraint(Constraint('pin2', 'ball', 'b', None, anchor_world=(1.0, 0.0, 2.0)))
    assert sorted(sim.remove_body('b')) == ['pin', 'pin2']
    assert sim.bodies.names == ['a', 'box'] and sim.constraint_names == []
    assert sim.dynamics.effects[1].body_names == ['a']   # (the damping forgets it)
    # 'a' and the box went on as without 'b' (neither met it).
    ref.remove_constraint('pin')
    ref.step(200)
    sim.step(200)
    _close(_rows(sim, ['a', 'box']), _rows(ref, ['a', 'box']))


@pytest.mark.parametrize('body, shapes, field, words', [
    ('not a body', [], 'body', 'RigidBody'),
    (RigidBody('a', 1.0, (0.1,) * 3), [], 'body.name', 'taken'),
    (RigidBody('c', 1.0, (0.1,) * 3), [CollisionShape('sphere', 'a', radius=0.1)],
     'shapes[0]', "on body 'c'"),
    (RigidBody('c', 1.0, (0.1,) * 3, position_world=(-3.0, 0.0, 0.25)),
     [CollisionShape('sphere', 'c', radius=0.1)], 'body.position_world', "'box/box'"),
])
def test_a_refused_spawn_names_its_field_and_changes_nothing(body, shapes, field, words):
    sim = _scene()
    sim.step(5)
    before, names = sim.state.y.copy(), list(sim.bodies.names)
    with pytest.raises(SpecError) as err:
        sim.add_body(body, shapes)
    assert words in str(err.value) and err.value.field.endswith(field)
    assert np.array_equal(sim.state.y, before) and sim.bodies.names == names
    sim.step(5)   # (and it runs on)


def test_reset_returns_spawned_bodies_to_their_spawn_and_remove_spawned_removes_them():
    sim = _scene()
    sim.step(30)
    sim.add_body(RigidBody('c', 1.0, (0.1,) * 3, position_world=(7.0, 0.0, 2.0)))
    sim.step(30)
    sim.reset()
    assert sim.time == 0.0
    np.testing.assert_array_equal(sim.pose('c')[0], [7.0, 0.0, 2.0])
    assert sim.remove_spawned() == ['c'] and sim.bodies.names == ['a', 'b', 'box']
    assert sim.remove_spawned() == []


def test_reset_scene_brings_back_the_scene_as_built():
    sim = _scene()
    sim.step(10)
    sim.add_body(RigidBody('c', 1.0, (0.1,) * 3, position_world=(7.0, 0.0, 2.0)))
    assert sim.remove_body('b') == ['pin']
    assert sim.scene_changed
    sim.set_step(5e-4)
    sim.reset_scene()
    assert sim.bodies.names == ['a', 'b', 'box'] and sim.constraint_names == ['pin']
    assert sim.spawned == [] and not sim.scene_changed and sim.dt == 5e-4 and sim.time == 0.0
    fresh = _scene()
    fresh.set_step(5e-4)
    sim.step(100)
    fresh.step(100)
    assert np.array_equal(sim.state.y, fresh.state.y)


def test_a_spawn_keeps_the_knob_a_reused_constraint_name_and_the_contact_forces():
    # The accuracy knob's budget and estimator (and its state) go on; a scene constraint
    # removed and added anew under its name is there once; the last step's contact forces
    # still carry a resting box (its acceleration reads 0, not −g: to the friction fixed
    # point's tolerance, 1e-8 of its impulse, 1e-7 m/s² here).
    sim, ref = _scene(), _scene()
    for s in (sim, ref):
        s.set_tolerance(1e-9, budget=4, estimator='doubling')
        s.step(10)
    sim.remove_constraint('pin')
    sim.add_constraint(Constraint('pin', 'ball', 'b', None, anchor_world=(1.0, 0.0, 2.0)))
    assert np.max(np.abs(sim.accelerations()[0][2])) <= 1e-7   # (the box at rest)
    sim.add_body(RigidBody('c', 1.0, (0.1,) * 3, position_world=(50.0, 0.0, 5.0)))
    assert sim.constraint_names.count('pin') == 1
    np.testing.assert_allclose(sim.accelerations()[0][2], 0.0, rtol=0, atol=1e-7)
    report = sim.accuracy()
    assert (report.tolerance, report.budget) == (1e-9, 4)
    assert sim._control.estimator == 'doubling'
    sim.reset_scene()
    assert (sim.accuracy().tolerance, sim.accuracy().budget) == (1e-9, 4)


def test_the_compiled_steps_contact_record_goes_on_across_a_spawn():
    # A box resting on the ground, every step compiled (its record kept lazily): after a
    # spawn the ground still carries it (acceleration 0 to the fixed point's tolerance)
    # and its four contacts are still reported.
    sim = Simulation([RigidBody('box', 1.0, (0.02 / 6,) * 3, position_world=(0, 0, 0.1))],
                     [Gravity()], integrator='rkmk4',
                     shapes=[CollisionShape('plane', None, friction=0.5),
                             CollisionShape('box', 'box', size=(0.2, 0.2, 0.2))])
    sim.step(20)
    assert sim.contact.counters['compiled_steps'] == 20
    sim.add_body(RigidBody('c', 1.0, (0.1,) * 3, position_world=(5.0, 0.0, 3.0)),
                 [CollisionShape('sphere', 'c', radius=0.1)])
    acc = sim.accelerations()[0]
    np.testing.assert_allclose(acc[0], 0.0, rtol=0, atol=1e-7)
    np.testing.assert_allclose(acc[1], [0.0, 0.0, -G], rtol=0, atol=1e-12)
    report = sim.contacts()
    assert len(report['depth']) == 4 and set(report['body_a']) == {'box'}
