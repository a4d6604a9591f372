"""Heavy symmetric top (steady precession) and double pendulum against independent solutions."""

from joint_scenes import G, POINT_INERTIA
import numpy as np
import pytest
from rigid_body_sim.core import Constraint, Gravity, INTEGRATORS, RigidBody, Simulation
from rigid_body_sim.core import rotation as so3
from scipy.integrate import solve_ivp
from scipy.spatial.transform import Rotation


def steady_top(name, dt, spin, theta=np.radians(30.0)):
    """
    Build a top on a ball joint at its tip in steady precession, and its precession rate.

    Mass m, centre of mass at l from the pivot on the symmetry axis (body z), axial
    moment I3 and transverse I1 about the centre of mass (I1p = I1 + m l² about the
    pivot). Steady precession at rate Ω about the vertical with total spin component
    ω3 along the axis requires I1p Ω² cos θ − I3 ω3 Ω + m g l = 0; the slow root is used.
    """
    m, l, i1, i3 = 0.5, 0.1, 2e-3, 3e-3
    i1p = i1 + m * l**2
    c = np.cos(theta)
    rate = (i3 * spin - np.sqrt((i3 * spin) ** 2 - 4 * i1p * c * m * G * l)) / (2 * i1p * c)
    R = Rotation.from_euler('y', theta)            # body z tilted by theta in the x-z plane
    axis = R.apply([0.0, 0.0, 1.0])
    w_world = rate * np.array([0.0, 0.0, 1.0]) + (spin - rate * c) * axis
    body = RigidBody('top', m, [i1, i1, i3], position_world=l * axis,
                     orientation_xyzw=R.as_quat(),
                     linear_velocity_world=np.cross(w_world, l * axis),
                     angular_velocity_body=R.inv().apply(w_world))
    sim = Simulation([body], [Gravity((0.0, 0.0, -G))], name, dt,
                     [Constraint('tip', 'ball', 'top', None, anchor_world=[0.0, 0.0, 0.0])])
    return sim, rate


@pytest.mark.parametrize('name', sorted(INTEGRATORS))
def test_heavy_top_steady_precession(name):
    theta = np.radians(30.0)
    sim, rate = steady_top(name, 1e-3, spin=60.0, theta=theta)
    tilts, azimuths, times = [], [], []
    for _ in range(40):
        sim.step(25)
        _, q = sim.pose('top')
        axis = so3.rotate(q, np.array([0.0, 0.0, 1.0]))
        tilts.append(np.arccos(axis[2]))
        azimuths.append(np.arctan2(axis[1], axis[0]))
        times.append(sim.time)
    # No nutation: the tilt stays at theta; the precession rate is the root of
    # I1p Ω² cos θ − I3 ω3 Ω + m g l = 0. Measured over 1 s at dt = 1e-3 (tilt drift
    # rad / rate error): symplectic_euler 1.3e-3 / 2.4e-4, lie_poisson2 4.4e-5 / 3.7e-5,
    # lie_poisson4 5.0e-8 / 3.1e-8, rkmk4 6.7e-8 / 1.0e-7; halving dt divides them by
    # 2, 4, 16, 16. Bounds about 3x.
    # bound: C dt^p (p = 1, 2, 4, 4; C from those errors) x3; rounding (a 1-ulp change: 8e-15)
    tilt_tol, rate_tol = {'symplectic_euler': (4e-3, 8e-4), 'lie_poisson2': (1.5e-4, 1.2e-4),
                          'lie_poisson4': (1.5e-7, 1e-7), 'rkmk4': (2e-7, 3e-7)}[name]
    assert np.max(np.abs(np.array(tilts) - theta)) < tilt_tol
    measured = np.polyfit(times, np.unwrap(azimuths), 1)[0]
    assert abs(measured / rate - 1.0) < rate_tol


def double_pendulum_reference(l1, l2, m1, m2, th1, th2, t_eval):
    """Double pendulum in joint angles (from the vertical), by DOP853 at rtol 1e-12."""
    def rhs(t, y):
        a1, a2, w1, w2 = y
        d = a1 - a2
        den = 2 * m1 + m2 - m2 * np.cos(2 * d)
        dw1 = (-G * (2 * m1 + m2) * np.sin(a1) - m2 * G * np.sin(a1 - 2 * a2)
               - 2 * np.sin(d) * m2 * (w2**2 * l2 + w1**2 * l1 * np.cos(d))) / (l1 * den)
        dw2 = (2 * np.sin(d) * (w1**2 * l1 * (m1 + m2) + G * (m1 + m2) * np.cos(a1)
                                + w2**2 * l2 * m2 * np.cos(d))) / (l2 * den)
        return [w1, w2, dw1, dw2]

    sol = solve_ivp(rhs, (0.0, t_eval[-1]), [th1, th2, 0.0, 0.0], method='DOP853',
                    t_eval=t_eval, rtol=1e-12, atol=1e-12)
    a1, a2 = sol.y[0], sol.y[1]
    p1 = np.stack([l1 * np.sin(a1), np.zeros_like(a1), -l1 * np.cos(a1)], axis=1)
    p2 = p1 + np.stack([l2 * np.sin(a2), np.zeros_like(a2), -l2 * np.cos(a2)], axis=1)
    return p1, p2


# Largest position error (m) over 2 s at dt = 1e-3 measured: symplectic_euler 1.0e-3,
# lie_poisson2 3.3e-5, lie_poisson4 2.6e-8, rkmk4 2.2e-9 (halving dt: ratios 2.0, 4.0,
# 16, 16). Bounds about 3x.
# bound: C dt^p (p = 1, 2, 4, 4) x3; rounding (a 1-ulp change: 8e-15 m), DOP853's 1e-12 far below
DOUBLE_TOL = {'symplectic_euler': 3e-3, 'lie_poisson2': 1e-4, 'rkmk4': 7e-9,
              'lie_poisson4': 8e-8}


@pytest.mark.parametrize('name', sorted(INTEGRATORS))
def test_double_pendulum_against_joint_angle_reference(name):
    l1, l2, m1, m2 = 0.3, 0.2, 1.0, 0.5
    th1, th2 = np.radians(60.0), np.radians(-30.0)
    p1 = np.array([l1 * np.sin(th1), 0.0, -l1 * np.cos(th1)])
    p2 = p1 + np.array([l2 * np.sin(th2), 0.0, -l2 * np.cos(th2)])
    bodies = [RigidBody('bob1', m1, POINT_INERTIA, position_world=p1),
              RigidBody('bob2', m2, POINT_INERTIA, position_world=p2)]
    # Rigid massless rods between centres of mass: distance constraints.
    rods = [Constraint('rod1', 'distance', 'bob1', None, anchor_b_body=[0.0, 0.0, 0.0]),
            Constraint('rod2', 'distance', 'bob2', 'bob1')]
    sim = Simulation(bodies, [Gravity((0.0, 0.0, -G))], name, 1e-3, rods)
    times = np.arange(1, 21) * 0.1
    ref1, ref2 = double_pendulum_reference(l1, l2, m1, m2, th1, th2, times)
    err = 0.0
    for k in range(len(times)):
        sim.step(100)
        pos, _ = sim.pose()
        err = max(err, np.max(np.abs(pos[0] - ref1[k])), np.max(np.abs(pos[1] - ref2[k])))
    assert err < DOUBLE_TOL[name]
