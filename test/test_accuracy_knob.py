"""
The accuracy knob: requested tolerances are met, the estimate is right, misses are told.

References are DOP853 solutions of the same equations at rtol 1e-13
(``reference.dop853_trajectory``); errors are ``accuracy.state_distance`` (the
largest difference in position, orientation, velocity or angular velocity,
SI units). The knob promises a local error per unit time below the tolerance,
so after a run of T seconds the global error should be about ``tolerance * T``
or less, times the growth of errors in the motion itself. Measured (dt = 1e-2):
free body (stable axis) 0.23 x ``tolerance * T`` at worst, pendulum 0.03 x
(rkmk4), four-bar 6 to 20 x (its motion amplifies errors); the bounds below
state those factors with a margin.
"""

import numpy as np
import pytest
from rigid_body_sim.core import Constraint, Gravity, RigidBody, Simulation
from rigid_body_sim.core.accuracy import ErrorControl, state_distance
from rigid_body_sim.core.errors import SpecError
from rigid_body_sim.core.mechanisms import four_bar
from rigid_body_sim.core.reference import dop853_trajectory
from rigid_body_sim.scene import load_scene, SceneError

TOLERANCES = (1e-3, 1e-5, 1e-7, 1e-9)


def free_body(integrator, dt=1e-2):
    body = RigidBody('b', 1.0, (1.0, 2.0, 3.0), angular_velocity_body=(2.0, 0.01, 0.01))
    return Simulation([body], [], integrator, dt)


def pendulum(integrator, dt=1e-2):
    bob = RigidBody('bob', 1.0, (1e-3, 2e-3, 3e-3), position_world=(0.5, 0.0, 0.0))
    return Simulation([bob], [Gravity()], integrator, dt,
                      [Constraint('pivot', 'ball', 'bob', None, anchor_world=(0.0, 0.0, 0.0))])


def global_error(build, integrator, tolerance, duration):
    reference = dop853_trajectory(build(integrator), [duration], rtol=1e-13, atol=1e-13)[0]
    sim = build(integrator)
    sim.set_tolerance(tolerance)
    sim.run(duration)
    return state_distance(sim.state, reference), sim.accuracy()


@pytest.mark.parametrize('integrator', ['rkmk4', 'lie_poisson2', 'lie_poisson4'])
@pytest.mark.parametrize('tolerance', TOLERANCES)
def test_free_body_meets_the_tolerance(integrator, tolerance):
    error, report = global_error(free_body, integrator, tolerance, 2.0)
    assert report.misses == 0
    assert error <= tolerance * 2.0


@pytest.mark.parametrize('tolerance', TOLERANCES)
def test_pendulum_meets_the_tolerance(tolerance):
    error, report = global_error(pendulum, 'rkmk4', tolerance, 1.0)
    assert report.misses == 0
    assert error <= 0.3 * tolerance * 1.0


@pytest.mark.parametrize('tolerance', TOLERANCES)
def test_four_bar_meets_the_tolerance_within_its_error_growth(tolerance):
    error, report = global_error(lambda name: four_bar(name, 1e-2), 'rkmk4', tolerance, 1.0)
    assert report.misses == 0
    assert error <= 50.0 * tolerance * 1.0


# Steps long enough that the true error is far above rounding (1e-13).
@pytest.mark.parametrize('build', [lambda name: free_body(name, 0.1),
                                   lambda name: pendulum(name, 2e-2),
                                   lambda name: four_bar(name, 2e-2)])
@pytest.mark.parametrize('integrator', ['rkmk4', 'lie_poisson2', 'lie_poisson4',
                                        'symplectic_euler'])
@pytest.mark.parametrize('k', [1, 4])
def test_the_estimate_is_within_a_factor_of_two_of_the_true_local_error(build, integrator, k):
    # Measured ratios estimate / true: 0.86 to 1.56.
    sim = build(integrator)
    sim.step(3)
    dt = sim.dt
    exact = dop853_trajectory(sim, [sim.time + dt], rtol=1e-13, atol=1e-14)[0]
    control = ErrorControl(1e-30, budget=2 * k)
    control.k = k
    fine = control.step(sim.integrator, sim.state, dt, sim.time + dt)
    true = state_distance(fine, exact) / dt
    assert 0.5 <= control.estimate / true <= 2.0


def test_a_tolerance_out_of_reach_is_reported_never_silently_missed():
    # A first-order method needs far more than 8 sub-steps for 1e-7.
    sim = pendulum('symplectic_euler')
    sim.set_tolerance(1e-7, budget=8)
    sim.step(20)
    report = sim.accuracy()
    assert report.misses == report.steps == 20
    assert report.substeps == 8 and report.error_estimate > 1e-7
    assert sim.diagnostics().accuracy == report
    sim.reset()
    assert sim.accuracy().misses == 0 and sim.accuracy().steps == 0


def test_without_the_knob_a_step_is_one_integrator_step():
    sim = pendulum('lie_poisson2')
    sim.step(10)
    assert sim.work()['steps'] == 10
    assert sim.accuracy().tolerance is None


def test_scene_files_take_a_tolerance_and_bad_values_are_named(tmp_path):
    text = """
dt: 0.01
tolerance: 1.0e-6
bodies:
  - {name: b, mass: 1.0, inertia: [1.0, 2.0, 3.0], angular_velocity_body: [2.0, 0.0, 0.0]}
"""
    path = tmp_path / 'scene.yaml'
    path.write_text(text)
    assert load_scene(path).simulation.accuracy().tolerance == 1e-6
    for bad in ('-1.0', '.nan', '"tight"', '0'):
        path.write_text(text.replace('1.0e-6', bad))
        with pytest.raises(SceneError, match=r'scene\.yaml: tolerance: must be'):
            load_scene(path)
    with pytest.raises(SpecError, match='tolerance_budget'):
        Simulation([RigidBody('b', 1.0, (1.0, 1.0, 1.0))], tolerance=1e-6, tolerance_budget=6)
    assert np.isnan(free_body('rkmk4').accuracy().error_estimate)
