"""Bad input: a clear SpecError naming the field, and nothing else breaks."""

import numpy as np
import pytest
from rigid_body_sim.core import (AppliedWrenches, Damping, Gravity, RigidBody, Simulation,
                                 SpecError)

NAN, INF = float('nan'), float('inf')


def body(**overrides):
    kwargs = {'name': 'b', 'mass': 1.0, 'inertia': [1.0, 2.0, 2.5]}
    kwargs.update(overrides)
    return RigidBody(**kwargs)


@pytest.mark.parametrize('mass', [0.0, -1.0])
def test_non_positive_mass(mass):
    with pytest.raises(SpecError, match=r'^mass: must be positive'):
        body(mass=mass)


@pytest.mark.parametrize('inertia, message', [
    ([[1.0, 0.1, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], r'^inertia: not symmetric'),
    ([1.0, -2.0, 2.5], r'^inertia: not positive definite'),
    ([[1.0, 2.0, 0.0], [2.0, 1.0, 0.0], [0.0, 0.0, 1.0]], r'^inertia: not positive definite'),
    ([1.0, 1.0, 3.0], r'^inertia: violates the triangle inequality'),
    ([1.0, 2.0], r'^inertia: expected shape \(3, 3\)'),
])
def test_non_physical_inertia(inertia, message):
    with pytest.raises(SpecError, match=message):
        body(inertia=inertia)


@pytest.mark.parametrize('overrides, message', [
    ({'mass': 1e-320}, r'^mass: mass 1e-320 is outside \[1e-100, 1e\+100\]'),
    ({'mass': '1'}, r"^mass: expected a number, got '1'"),
    ({'inertia': [1e308] * 3}, r'^inertia: largest entry 1e\+308 is outside'),
    ({'inertia': [1e-120] * 3}, r'^inertia: smallest principal moment 1e-120 is outside'),
])
def test_values_whose_arithmetic_would_overflow(overrides, message):
    with pytest.raises(SpecError, match=message):
        body(**overrides)


def test_constraint_time_constant_is_named():
    with pytest.raises(SpecError, match=r'^constraint_time_constant: must be positive'):
        Simulation([body()], [], 'rkmk4', 1e-3, constraint_time_constant=0.0)


@pytest.mark.parametrize('entry, message', [
    ({'body': 'b', 'forc': [1.0, 0.0, 0.0]}, r'^effects\[0\]\[0\]\.forc: unknown key'),
    ({'force': [1.0, 0.0, 0.0]}, r'^effects\[0\]\[0\]\.body: required'),
])
def test_wrench_entry_keys(entry, message):
    with pytest.raises(SpecError, match=message):
        Simulation([body()], [AppliedWrenches([entry])], 'rkmk4', 1e-3)


@pytest.mark.parametrize('field, value', [
    ('mass', NAN), ('inertia', [1.0, NAN, 2.0]), ('com_body', [0.0, INF, 0.0]),
    ('position_world', [NAN, 0.0, 0.0]), ('orientation_xyzw', [0.0, 0.0, NAN, 1.0]),
    ('linear_velocity_world', [0.0, 0.0, INF]), ('angular_velocity_body', [NAN, 0.0, 0.0]),
])
def test_non_finite_body_fields(field, value):
    with pytest.raises(SpecError, match=rf'^{field}: must be finite'):
        body(**{field: value})


def test_non_unit_quaternion():
    with pytest.raises(SpecError, match=r'^orientation_xyzw: quaternion .* unit norm'):
        body(orientation_xyzw=[0.0, 0.0, 0.0, 2.0])


@pytest.mark.parametrize('make, message', [
    (lambda: Gravity([0.0, NAN, -9.81]), r'^g_world: must be finite'),
    (lambda: Damping(linear=INF), r'^linear: must be finite'),
    (lambda: Damping(angular=-1.0), r'^angular: must be non-negative'),
])
def test_non_finite_effect_parameters(make, message):
    with pytest.raises(SpecError, match=message):
        make()


@pytest.mark.parametrize('dt', [0.0, -1e-3, NAN, INF])
def test_non_positive_or_non_finite_step(dt):
    with pytest.raises(SpecError, match=r'^dt: must be'):
        Simulation([body()], [], 'rkmk4', dt)


def test_unknown_integrator():
    with pytest.raises(SpecError, match=r"^integrator: unknown integrator 'rk45'; known: "):
        Simulation([body()], [], 'rk45', 1e-3)


def test_not_an_effect():
    with pytest.raises(SpecError, match=r'^effects\[0\]: expected an Effect'):
        Simulation([body()], ['gravity'], 'rkmk4', 1e-3)


def test_unknown_body_in_damping():
    with pytest.raises(SpecError, match=r"^effects\[0\]\.bodies\[0\]: unknown body 'x'"):
        Simulation([body()], [Damping(0.1, bodies=['x'])], 'rkmk4', 1e-3)


def test_duplicate_body_names():
    with pytest.raises(SpecError, match=r"^bodies\[1\]\.name: duplicate body name 'b'"):
        Simulation([body(), body()], [], 'rkmk4', 1e-3)


@pytest.mark.parametrize('kwargs, message', [
    ({'body': 'nobody'}, r"^body: unknown body 'nobody'"),
    ({'body': 'b', 'force': [NAN, 0.0, 0.0]}, r'^force: must be finite'),
    ({'body': 'b', 'torque': [0.0, INF, 0.0]}, r'^torque: must be finite'),
    ({'body': 'b', 'point_body': [0.0, 0.0, NAN]}, r'^point_body: must be finite'),
    ({'body': 'b', 'frame': 'map'}, r"^frame: must be 'world' or 'body'"),
    ({'body': 'b', 'force': [1.0, 0.0, 0.0], 'duration': 0.0}, r'^duration: must be positive'),
])
def test_bad_wrench_is_rejected_and_nothing_else_breaks(kwargs, message):
    sim = Simulation([body(angular_velocity_body=[0.0, 1.0, 0.0])], [Gravity()], 'lie_poisson2',
                     1e-3)
    reference = Simulation([body(angular_velocity_body=[0.0, 1.0, 0.0])], [Gravity()],
                           'lie_poisson2', 1e-3)
    with pytest.raises(SpecError, match=message):
        sim.apply_wrench(**kwargs)
    sim.step(100)
    reference.step(100)
    np.testing.assert_array_equal(sim.pose('b')[0], reference.pose('b')[0])
    np.testing.assert_array_equal(sim.twist('b')[1], reference.twist('b')[1])


def test_bad_wrench_in_initial_table():
    with pytest.raises(SpecError, match=r"^effects\[0\]\[0\]\.body: unknown body 'x'"):
        Simulation([body()], [AppliedWrenches([{'body': 'x'}])], 'rkmk4', 1e-3)


@pytest.mark.parametrize('n', [-1, 1.5, True])
def test_bad_step_count(n):
    sim = Simulation([body()], [], 'rkmk4', 1e-3)
    with pytest.raises(SpecError, match=r'^n: must be a non-negative integer'):
        sim.step(n)
