"""Each integrator's measured order of convergence matches its declared order."""

import numpy as np
import pytest
from rigid_body_sim.core import (AppliedWrenches, Damping, Gravity, INTEGRATORS, RigidBody,
                                 Simulation)
from rigid_body_sim.core import rotation as so3
from rigid_body_sim.core.reference import dop853_trajectory

T_END = 1.0


def build(name: str, dt: float) -> Simulation:
    """
    Build a scene with every code path at once.

    Gravity, damping, world and body wrenches off the centre of mass, an
    anisotropic body with a non-diagonal inertia and an isotropic one.
    """
    inertia = np.array([[0.30, 0.02, -0.05], [0.02, 0.25, 0.01], [-0.05, 0.01, 0.20]])
    bodies = [RigidBody('box', 3.0, inertia, com_body=[0.1, -0.2, 0.05],
                        orientation_xyzw=so3.quat_normalize(np.array([0.2, -0.3, 0.1, 0.9])),
                        linear_velocity_world=[1.0, 0.0, 2.0],
                        angular_velocity_body=[1.5, -2.0, 3.0]),
              RigidBody('ball', 1.0, [0.1, 0.1, 0.1], position_world=[1.0, 0.0, 0.0],
                        angular_velocity_body=[0.0, 4.0, 1.0])]
    wrenches = [{'body': 'box', 'force': [0.5, -0.3, 0.2], 'torque': [0.05, 0.0, -0.1],
                 'frame': 'body', 'point_body': [0.2, 0.1, -0.1]},
                {'body': 'ball', 'force': [0.0, 0.4, 0.0], 'frame': 'world',
                 'point_body': [0.0, 0.0, 0.3]}]
    effects = [Gravity((0.0, 0.0, -9.81)), Damping(linear=0.3, angular=0.05),
               AppliedWrenches(wrenches)]
    return Simulation(bodies, effects, name, dt)


def state_error(s, ref) -> float:
    """Largest error over positions, velocities, angular velocities and rotation angles."""
    rot = so3.log_quat(so3.quat_multiply(so3.quat_conjugate(ref.quat_principal_world),
                                         s.quat_principal_world))
    return max(np.max(np.abs(s.pos_com_world - ref.pos_com_world)),
               np.max(np.abs(s.vel_com_world - ref.vel_com_world)),
               np.max(np.abs(s.ang_vel_principal - ref.ang_vel_principal)),
               np.max(np.linalg.norm(rot, axis=1)))


@pytest.fixture(scope='module')
def reference():
    return dop853_trajectory(build('rkmk4', 1e-3), [T_END])[-1]


# dt pairs where the error is far above the rounding floor (~1e-13) and in the
# asymptotic regime (checked: the next halving gives the same ratio within 0.1).
# Measured errors at the smaller dt: 5.6e-10 (rkmk4) to 2.5e-2, orders within 0.01.
DTS = {'symplectic_euler': 1e-2, 'lie_poisson2': 1e-2, 'rkmk4': 2e-2, 'lie_poisson4': 2e-2}


@pytest.mark.parametrize('name', sorted(INTEGRATORS))
def test_order_of_convergence(name, reference):
    errors = []
    for dt in (DTS[name], DTS[name] / 2):
        sim = build(name, dt)
        sim.run(T_END)
        errors.append(state_error(sim.state, reference))
    observed = np.log2(errors[0] / errors[1])
    # bound: floor = the reference's error (DOP853 rtol 1e-12: 7.7e-13) + rounding (~1e-13);
    # above 10 x that floor it shifts the order by < 0.15
    assert errors[1] > 1e-11, 'too close to rounding to measure an order'
    # bound: p + O(dt) (next halving agrees within 0.1) + the floor's < 0.15
    assert abs(observed - INTEGRATORS[name].order) < 0.3, (errors, observed)
