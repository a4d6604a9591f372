"""A vectorized step of many bodies equals stepping each body alone."""

from dataclasses import replace

from conftest import random_body
import numpy as np
import pytest
from rigid_body_sim.core import AppliedWrenches, Damping, Gravity, INTEGRATORS, Simulation

EPS = np.finfo(float).eps


@pytest.mark.parametrize('name', sorted(INTEGRATORS))
def test_many_bodies_equal_each_alone(name, rng):
    bodies = [random_body(rng, f'b{i}') for i in range(20)]
    # One fast spinner (300 rad/s: 0.3 rad per step) must not change how the others
    # are stepped.
    bodies[7] = replace(bodies[7], angular_velocity_body=[10.0, 300.0, -20.0])
    damped = [b.name for b in bodies[::3]]
    wrenches = [{'body': b.name, 'force': rng.normal(size=3), 'torque': rng.normal(size=3),
                 'frame': 'body' if i % 2 else 'world', 'point_body': rng.normal(size=3)}
                for i, b in enumerate(bodies[::4])]

    def effects(names):
        return [Gravity((0.1, 0.0, -9.81)), Damping(0.2, 0.05, [n for n in damped if n in names]),
                AppliedWrenches([w for w in wrenches if w['body'] in names])]

    together = Simulation(bodies, effects({b.name for b in bodies}), name, 1e-3)
    together.step(200)
    pos_all, quat_all = together.pose()
    vel_all, w_all = together.twist()
    for i, body in enumerate(bodies):
        alone = Simulation([body], effects({body.name}), name, 1e-3)
        alone.step(200)
        pos, quat = alone.pose(body.name)
        vel, w = alone.twist(body.name)
        # The same arithmetic per body; only summation order in np.add.at and BLAS
        # kernels (and the vector width of a loop over 20 bodies or one) may differ.
        # bound: 200 steps x 2 eps a step x 100 (growth of a 1-ulp change, spinner: 80) x scale
        scale = max(1.0, *(np.abs(x).max() for x in (pos, vel, w)))
        # (9e-12 x scale, 3e-9 for the spinner; a force on a wrong body moves it dt^2 |a| ~ 1e-6)
        tol = 200 * 2 * EPS * 100 * scale
        np.testing.assert_allclose(pos_all[i], pos, rtol=0, atol=tol)
        np.testing.assert_allclose(quat_all[i], quat, rtol=0, atol=tol)
        np.testing.assert_allclose(vel_all[i], vel, rtol=0, atol=tol)
        np.testing.assert_allclose(w_all[i], w, rtol=0, atol=tol)
