"""A step evaluates only the effects a scene lists; work counters show it."""

import pytest
from rigid_body_sim.core import Constraint, Damping, Gravity, INTEGRATORS, RigidBody, Simulation

STEPS = 50
# Right-hand sides per step: rkmk4 has 4 stages; the splitting methods evaluate
# position-dependent forces in kicks, reusing the last kick of a step as the first of
# the next (first same as last): 1 per Strang sub-step (+1 at the very start).
KICKS = {'symplectic_euler': (STEPS, 0), 'lie_poisson2': (STEPS + 1, 0),
         'lie_poisson4': (3 * STEPS + 1, 0)}
# Free-rotor sub-flows per step and anisotropic body (splittings) or gyroscopic
# evaluations (rkmk4: one per stage).
GYRO = {'symplectic_euler': 3, 'lie_poisson2': 5, 'lie_poisson4': 15, 'rkmk4': 4}


def scene(name, gravity, moments):
    bodies = [RigidBody(f'b{i}', 1.0, moments, angular_velocity_body=(0.1, 1.0, 0.2))
              for i in range(3)]
    return Simulation(bodies, [Gravity()] if gravity else [], name, 1e-3)


@pytest.mark.parametrize('name', sorted(INTEGRATORS))
def test_no_gravity_term_without_gravity(name):
    sim = scene(name, False, (1.0, 2.0, 3.0))
    sim.step(STEPS)
    work = sim.work()
    assert 'gravity_evaluations' not in work
    assert work['kick_evaluations'] == 0 or name == 'rkmk4'


@pytest.mark.parametrize('name', sorted(INTEGRATORS))
def test_gravity_evaluated_once_per_force_evaluation(name):
    sim = scene(name, True, (1.0, 2.0, 3.0))
    sim.step(STEPS)
    work = sim.work()
    expected = 4 * STEPS if name == 'rkmk4' else KICKS[name][0]
    assert work['gravity_evaluations'] == expected
    assert work['gravity_body_evaluations'] == 3 * expected


@pytest.mark.parametrize('name', sorted(INTEGRATORS))
def test_no_gyroscopic_work_for_isotropic_bodies(name):
    sim = scene(name, True, (2.0, 2.0, 2.0))
    sim.step(STEPS)
    assert sim.work()['gyroscopic_body_evaluations'] == 0


@pytest.mark.parametrize('name', sorted(INTEGRATORS))
def test_gyroscopic_work_for_anisotropic_bodies_only(name):
    bodies = [RigidBody('iso', 1.0, (1.0, 1.0, 1.0), angular_velocity_body=(0, 1, 0)),
              RigidBody('aniso', 1.0, (1.0, 2.0, 3.0), angular_velocity_body=(0, 1, 0))]
    sim = Simulation(bodies, [], name, 1e-3)
    sim.step(STEPS)
    assert sim.work()['gyroscopic_body_evaluations'] == GYRO[name] * STEPS * 1


def test_no_constraint_work_without_constraints():
    sim = scene('rkmk4', True, (1.0, 2.0, 3.0))
    sim.step(STEPS)
    counters = sim.dynamics.solver.counters
    assert counters.geometry_evaluations == counters.factorizations == 0


def test_reading_outputs_does_no_counted_work():
    # Reactions, diagnostics and violations are read between steps (a node publishes
    # them at its own rate): the work counters must show the steps' work only.
    def pendulum():
        return Simulation([RigidBody('bob', 1.0, (1.0, 2.0, 3.0), position_world=(0.3, 0, 0))],
                          [Gravity()], 'lie_poisson2', 1e-3,
                          [Constraint('rod', 'ball', 'bob', None, anchor_world=(0, 0, 0))])

    quiet, watched = pendulum(), pendulum()
    held = (watched.dynamics.counters, watched.dynamics.solver.counters)
    for _ in range(STEPS):
        quiet.step()
        watched.step()
        watched.reactions()
        watched.diagnostics()
        watched.constraint_violation()
    assert watched.work() == quiet.work()
    assert watched.dynamics.solver.counters == quiet.dynamics.solver.counters
    # Nor may reading change the motion (the reads share the step's workspaces).
    assert (watched.state.y == quiet.state.y).all()
    # Counters are restored in place: references a caller holds stay live.
    assert held[0] is watched.dynamics.counters and held[1] is watched.dynamics.solver.counters


@pytest.mark.parametrize('name', sorted(INTEGRATORS))
def test_effect_work_deferred_over_a_run_equals_work_counted_every_step(name):
    # The effects' counters of whole-scene steps are settled when the model changes or
    # they are read: a run read once must count what a run read after every step
    # counts, across wrenches that start, stop and are replaced mid-run, a damping
    # effect and a second body that no wrench touches.
    def run(read_every_step):
        bodies = [RigidBody('a', 1.0, (1.0, 2.0, 3.0), angular_velocity_body=(0.1, 1.0, 0.2)),
                  RigidBody('b', 2.0, (1.0, 1.0, 1.0), position_world=(1.0, 0.0, 0.0))]
        sim = Simulation(bodies, [Gravity(), Damping(0.1, 0.01)], name, 1e-3)
        for k in range(STEPS):
            if k == 10:
                sim.apply_wrench('a', (1.0, 0.0, 0.0), duration=0.015)
            if k == 20:
                sim.apply_wrench('a', (0.0, 1.0, 0.0), point_body=(0.1, 0.0, 0.0))
                sim.apply_wrench('b', (0.0, 0.0, 1.0), start=0.03, duration=0.005)
            if k == 40:
                sim.clear_wrenches('a')
            sim.step()
            if read_every_step:
                sim.work()
        return sim.work()

    once, every = run(False), run(True)
    assert once == every
    # The wrenches did work in some steps only: a wrong settlement would count them in all.
    assert 0 < once['wrenches_body_evaluations'] < 2 * once['gravity_evaluations']
    assert once['wrenches_evaluations'] < once['gravity_evaluations']


@pytest.mark.parametrize('name', sorted(INTEGRATORS))
def test_a_cleared_wrench_table_counts_no_more_work(name):
    bodies = [RigidBody('a', 1.0, (1.0, 2.0, 3.0), angular_velocity_body=(0.1, 1.0, 0.2))]
    sim = Simulation(bodies, [Gravity()], name, 1e-3)
    sim.apply_wrench('a', (1.0, 0.0, 0.0))
    sim.step(10)
    acting = sim.work()['wrenches_evaluations']
    sim.clear_wrenches()
    sim.step(10)
    assert acting > 0
    assert sim.work()['wrenches_evaluations'] == acting


def test_counters_reset_and_restore_in_place():
    sim = scene('lie_poisson2', True, (1.0, 2.0, 3.0))
    sim.step(3)
    counters = sim.dynamics.counters
    saved = counters.as_dict()
    assert saved['steps'] == 3
    counters.reset()
    assert set(counters.as_dict().values()) == {0}
    assert sim.dynamics.tally[list(counters.SLOTS.values())].tolist() == [0] * len(saved)
    counters.restore(saved)
    assert counters.as_dict() == saved and counters is sim.dynamics.counters
    with pytest.raises(TypeError, match="no counter 'bogus'"):
        counters.restore({'bogus': 1})
