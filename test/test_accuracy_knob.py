"""
The accuracy knob: requested tolerances are met, the estimate is right, misses are told.

References are DOP853 solutions of the same equations at rtol 1e-13
(``reference.dop853_trajectory``); errors are ``accuracy.state_distance`` (the
largest difference in position, orientation, velocity or angular velocity,
SI units). The knob promises a local error per unit time below the tolerance,
so after a run of T seconds the global error should be about ``tolerance * T``
or less, times the growth of errors in the motion itself. Measured (dt = 1e-2):
free body (stable axis) 0.24 x ``tolerance * T`` at worst, pendulum 0.03 x
(rkmk4), four-bar 6 to 16 x at tolerances down to 1e-8 (its motion amplifies
errors); the bounds below state those factors with a margin. The four-bar's
accurate solutions agree only to about 7e-8 at T = 1 s (DOP853 at rtol 1e-11 to
1e-14, the knob at 1e-11, lie_poisson4 at dt = 1.6e-4: the rounding of its
redundant rows, amplified by the motion, so different on another CPU; at 1e-9
the measured error, 3.5e-8, is that floor): its bound adds the floor, x7,
``FOUR_BAR_FLOOR``. The free body's and the pendulum's floors (~1e-12) are far
below every bound.
"""

import numpy as np
import pytest
from rigid_body_sim.core import Constraint, Gravity, RigidBody, Simulation
from rigid_body_sim.core.accuracy import ErrorControl, state_distance
from rigid_body_sim.core.errors import SpecError
from rigid_body_sim.core.integrators import RKMK4
from rigid_body_sim.core.mechanisms import four_bar
from rigid_body_sim.core.reference import dop853_trajectory
from rigid_body_sim.scene import load_scene, SceneError

TOLERANCES = (1e-3, 1e-5, 1e-7, 1e-9)
FOUR_BAR_FLOOR = 5e-7


def free_body(integrator, dt=1e-2):
    body = RigidBody('b', 1.0, (1.0, 2.0, 3.0), angular_velocity_body=(2.0, 0.01, 0.01))
    return Simulation([body], [], integrator, dt)


def pendulum(integrator, dt=1e-2):
    bob = RigidBody('bob', 1.0, (1e-3, 2e-3, 3e-3), position_world=(0.5, 0.0, 0.0))
    return Simulation([bob], [Gravity()], integrator, dt,
                      [Constraint('pivot', 'ball', 'bob', None, anchor_world=(0.0, 0.0, 0.0))])


def global_error(build, integrator, tolerance, duration, estimator=None):
    reference = dop853_trajectory(build(integrator), [duration], rtol=1e-13, atol=1e-13)[0]
    sim = build(integrator)
    sim.set_tolerance(tolerance, estimator=estimator)
    sim.run(duration)
    return state_distance(sim.state, reference), sim.accuracy()


@pytest.mark.parametrize('integrator, estimator', [
    ('rkmk4', None), ('rkmk4', 'embedded'), ('rkmk4', 'doubling'),
    ('lie_poisson2', None), ('lie_poisson4', None)])
@pytest.mark.parametrize('tolerance', TOLERANCES)
def test_free_body_meets_the_tolerance(integrator, estimator, tolerance):
    error, report = global_error(free_body, integrator, tolerance, 2.0, estimator)
    assert report.misses == 0
    assert error <= tolerance * 2.0   # bound: tolerance x T x 1 (measured 0.24), floor ~1e-12


@pytest.mark.parametrize('estimator', [None, 'embedded', 'doubling'])
@pytest.mark.parametrize('tolerance', TOLERANCES)
def test_pendulum_meets_the_tolerance(estimator, tolerance):
    error, report = global_error(pendulum, 'rkmk4', tolerance, 1.0, estimator)
    assert report.misses == 0
    assert error <= 0.3 * tolerance * 1.0   # bound: tolerance x T x 0.03 (measured), x10


@pytest.mark.parametrize('tolerance', TOLERANCES)
def test_four_bar_meets_the_tolerance_within_its_error_growth(tolerance):
    error, report = global_error(lambda name: four_bar(name, 1e-2), 'rkmk4', tolerance, 1.0)
    assert report.misses == 0
    # bound: tolerance x T x 16 (measured growth), x3, + floor; 1e-7's sub-steps at 1e-9: 1.1e-6
    assert error <= 50.0 * tolerance * 1.0 + FOUR_BAR_FLOOR


# Steps long enough that the true error is far above rounding (1e-13).
@pytest.mark.parametrize('build', [lambda name: free_body(name, 0.1),
                                   lambda name: pendulum(name, 2e-2),
                                   lambda name: four_bar(name, 2e-2)])
@pytest.mark.parametrize('integrator', ['rkmk4', 'lie_poisson2', 'lie_poisson4',
                                        'symplectic_euler'])
@pytest.mark.parametrize('k', [1, 4])
def test_the_doubling_estimate_is_within_a_factor_of_two_of_the_true_local_error(
        build, integrator, k):
    # Measured ratios estimate / true: 0.86 to 1.20; the true local errors 2.6e-12 and up,
    # over 100 x the reference's and the rounding's (~1e-14).
    sim = build(integrator)
    sim.step(3)
    dt = sim.dt
    exact = dop853_trajectory(sim, [sim.time + dt], rtol=1e-13, atol=1e-14)[0]
    control = ErrorControl(1e-30, budget=2 * k, estimator='doubling')
    control.k = k
    fine = control.step(sim.integrator, sim.state, dt, sim.time + dt)
    true = state_distance(fine, exact) / dt
    assert 0.5 <= control.estimate / true <= 2.0   # bound: Richardson's 1 + O(h), factor 2


def test_the_embedded_pair_is_third_order_and_differs_from_rk4_by_k4_minus_k5():
    # Butcher's conditions for the tableau extended by the first-same-as-last stage.
    # bound: exact rationals in numpy, rounding ~1e-16 << isclose's atol 1e-8; the two
    # failing conditions miss by 1/72 = 0.014.
    rk = RKMK4
    A = np.zeros((5, 5))
    A[:4, :4] = rk.A
    A[4, :4] = rk.B
    c = np.append(rk.C, 1.0)
    b = rk.B_HAT
    assert np.allclose(A.sum(axis=1), c)
    assert np.isclose(b.sum(), 1.0)
    assert np.isclose(b @ c, 1 / 2)
    assert np.isclose(b @ c ** 2, 1 / 3)
    assert np.isclose(b @ A @ c, 1 / 6)
    # Third order, not fourth: two of the four fourth-order conditions fail.
    assert np.isclose(b @ c ** 3, 1 / 4) and np.isclose(b @ (c * (A @ c)), 1 / 8)
    assert not np.isclose(b @ A @ c ** 2, 1 / 12)
    assert not np.isclose(b @ A @ A @ c, 1 / 24)
    # The kernels' estimate h/6 (k4 - k5) is the difference of the two solutions.
    assert np.allclose(np.append(rk.B, 0.0) - b, [0, 0, 0, 1 / 6, -1 / 6])


def test_retuning_keeps_the_sub_step_count_and_a_refused_value_changes_nothing():
    control = ErrorControl(1e-6, budget=64, estimator='doubling')
    control.k, control.steps, control.misses = 8, 5, 2
    control.retune(1e-8)
    assert (control.tolerance, control.budget, control.estimator) == (1e-8, 64, 'doubling')
    assert (control.k, control.steps, control.misses) == (8, 5, 2)
    with pytest.raises(SpecError, match='power of two'):
        control.retune(1e-9, budget=3)
    assert (control.tolerance, control.budget, control.k) == (1e-8, 64, 8)


def test_the_tableau_has_the_shape_the_kernels_use():
    # The kernels (kernels/free_step.py) read RKMK4's tableau from kernels/methods.py and
    # use its shape: a stage takes the slopes of the stage before only, the weights are
    # paired (b0 = b3, b1 = b2), the embedded pair differs in the last two slopes only.
    rk = RKMK4
    assert np.array_equal(rk.A, np.diag(np.diag(rk.A, -1), -1))
    assert rk.B[0] == rk.B[3] and rk.B[1] == rk.B[2]
    assert np.array_equal(rk.B_HAT[:3], rk.B[:3])


# Steps long enough that the local errors are far above rounding.
@pytest.mark.parametrize('build', [lambda dt: free_body('rkmk4', 4 * dt),
                                   lambda dt: pendulum('rkmk4', dt),
                                   lambda dt: four_bar('rkmk4', dt)])
def test_the_embedded_estimate_bounds_the_kept_error_and_goes_as_h_cubed(build):
    # Measured: estimate / true local error of the kept (fourth-order) result 6.6
    # to 27, about twice as large at h/2 (the margin goes as 1/h); the estimate's
    # ratio between h and h/2 8.3 to 9.0 (third order: 2^3 = 8).
    estimates = []
    for dt in (2e-2, 1e-2):
        sim, twin = build(dt), build(dt)
        sim.step(round(0.06 / dt))
        twin.step(round(0.06 / dt))
        exact = dop853_trajectory(sim, [sim.time + sim.dt], rtol=1e-13, atol=1e-14)[0]
        error = np.zeros(1)
        kept = sim.integrator.step(sim.state, sim.dt, sim.time + sim.dt, error)
        true = state_distance(kept, exact) / sim.dt
        assert 2.0 * true <= error[0]   # bound: third-order C h^3 over fourth's, >= 6.6, x3
        estimates.append(error[0])
        # The estimate does not change the step: the same compiled code in the same run,
        # bit for bit.
        plain = twin.integrator.step(twin.state, twin.dt, twin.time + twin.dt)
        for name in ('pos_com_world', 'quat_principal_world', 'vel_com_world',
                     'ang_vel_principal'):
            assert np.array_equal(getattr(kept, name), getattr(plain, name))
    # bound: third order, 2^(3 +- 0.4) (an order 2 or 4 estimate gives 4 or 16)
    assert 6.0 <= estimates[0] / estimates[1] <= 10.0


def test_steps_of_one_sub_step_are_checked_by_the_embedded_pair():
    # 5 right-hand sides a step where doubling's 1 + 2 sub-steps take 12.
    sim = free_body('rkmk4')
    sim.set_tolerance(1e-5)
    sim.step(50)
    assert sim.accuracy().substeps == 1 and sim.accuracy().misses == 0
    assert sim.work()['rhs_evaluations'] == 5 * 50
    sim.set_tolerance(1e-5, estimator='doubling')
    sim.step(50)
    assert sim.work()['rhs_evaluations'] == 5 * 50 + 12 * 50
    with pytest.raises(SpecError, match='estimator'):
        sim.set_tolerance(1e-5, estimator='richardson')


def test_a_tolerance_out_of_reach_is_reported_never_silently_missed():
    # A first-order method needs far more than 8 sub-steps for 1e-7.
    sim = pendulum('symplectic_euler')
    sim.set_tolerance(1e-7, budget=8)
    sim.step(20)
    report = sim.accuracy()
    assert report.misses == report.steps == 20
    # bound: first order, C h at h = dt / 8: measured 2.3e-2, 2e5 x the tolerance
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
