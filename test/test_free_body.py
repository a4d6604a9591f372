"""Free bodies against analytic solutions and a DOP853 reference."""

import numpy as np
import pytest
from rigid_body_sim.core import (AppliedWrenches, Gravity, INTEGRATORS, RigidBody,
                                 Simulation, State)
from rigid_body_sim.core import rotation as so3
from rigid_body_sim.core.reference import (free_body_reference, intermediate_axis_period,
                                           symmetric_body_omega)

ALL = sorted(INTEGRATORS)
MOMENTS = (1.0, 2.0, 3.0)
EPS = np.finfo(float).eps


def rotation_angle_between(q_a: np.ndarray, q_b: np.ndarray) -> float:
    return float(np.linalg.norm(so3.log_quat(so3.quat_multiply(so3.quat_conjugate(q_a), q_b))))


# Error of each integrator at dt = 1e-3 over 10 s of the intermediate-axis body
# (Ω0 = (0.01, 1, 0.01)) against the DOP853 reference (rtol 1e-12: itself 2.7e-12 off).
# The method's C T dt^p was measured against a reference at rtol 1e-14, the order
# confirmed at 2 dt; rounding: N = 1e4 steps, a perturbation grows <= 12x by t = 10 s.
TOLERANCE_10S = {
    'symplectic_euler': 1e-2,   # bound: C T dt = 2.2e-3; x4.5
    'lie_poisson2': 3e-6,       # bound: C T dt² = 2.5e-7; x12
    'rkmk4': 5e-11,   # bound: method 1e-12 + reference 2.7e-12 + N eps 12 = 2.7e-11; x1.6
    'lie_poisson4': 5e-11,      # bound: as rkmk4's
}


@pytest.mark.parametrize('name', ALL)
def test_intermediate_axis_against_dop853(name):
    omega0 = (0.01, 1.0, 0.01)
    sim = Simulation([RigidBody('b', 1.0, MOMENTS, angular_velocity_body=omega0)], [], name,
                     1e-3)
    sim.run(10.0)
    w_ref, q_ref = free_body_reference(MOMENTS, omega0, (0, 0, 0, 1), [10.0])
    err_w = np.max(np.abs(sim.state.ang_vel_principal[0] - w_ref[-1]))
    err_q = rotation_angle_between(sim.state.quat_principal_world[0], q_ref[-1])
    assert max(err_w, err_q) < TOLERANCE_10S[name]


@pytest.mark.parametrize('name', ['lie_poisson2', 'rkmk4', 'lie_poisson4'])
def test_flip_period_matches_landau_lifshitz(name):
    # A larger perturbation than the long-run test so that several flips fit in 30 s.
    omega0 = (0.1, 2.0, 0.1)
    period = intermediate_axis_period(MOMENTS, omega0)
    dt = 2e-3
    sim = Simulation([RigidBody('b', 1.0, MOMENTS, angular_velocity_body=omega0)], [], name, dt)
    n = int(3.2 * period / dt)
    w2 = np.empty(n)
    for k in range(n):
        sim.step()
        w2[k] = sim.twist('b', frame='body')[1][1]
    t = dt * np.arange(1, n + 1)
    i = np.flatnonzero((w2[:-1] < 0.0) & (w2[1:] >= 0.0))   # Ω2 back to positive: one period
    crossings = t[i] + dt * (-w2[i]) / (w2[i + 1] - w2[i])
    assert len(crossings) >= 2   # the body flips over and back at least twice
    measured = np.diff(crossings)
    # bound: phase error C dt^p (+ interpolation) 6.4e-7 or 5.6e-11, + N eps = 5e-12; x10
    tol = 7e-6 if INTEGRATORS[name].order == 2 else 6e-10
    np.testing.assert_allclose(measured, period, rtol=tol)


@pytest.mark.parametrize('name', ALL)
def test_symmetric_body_closed_form(name):
    # Body frame = principal frame up to the order of the axes: the core sorts moments,
    # so this also checks that outputs come back in the user's frame.
    moments = (2.0, 2.0, 1.0)
    omega0 = np.array([0.3, 0.1, 5.0])
    # bound: C T dt^p = 3.7e-4, 9e-7 or 8.9e-12 (orders seen at 2 dt), + N eps |Ω| = 5e-12; x10
    tol = {1: 4e-3, 2: 1e-5, 4: 1e-10}[INTEGRATORS[name].order]

    def build():
        return Simulation([RigidBody('top', 1.0, moments, angular_velocity_body=omega0)], [],
                          name, 1e-3)

    sim = build()
    L_world = sim.diagnostics().angular_momentum_world
    l_hat = L_world / np.linalg.norm(L_world)
    cone = np.arccos(moments[2] * omega0[2] / np.linalg.norm(L_world))

    def symmetry_axis(s):
        _, q = s.pose('top')
        return so3.rotate(q, np.array([0.0, 0.0, 1.0]))

    e1 = np.cross(l_hat, [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(l_hat, e1)
    a0 = symmetry_axis(sim)
    phi0 = np.arctan2(a0 @ e2, a0 @ e1)
    rate = np.linalg.norm(L_world) / moments[0]
    for _ in range(5):
        sim.run(1.0)
        _, w_body = sim.twist('top', frame='body')
        w_exact = symmetric_body_omega(moments, omega0, [sim.time])[0]
        np.testing.assert_allclose(w_body, w_exact, rtol=0, atol=tol)
        # The symmetry axis keeps its angle to the fixed angular momentum and precesses
        # about it at |L| / J1.
        a = symmetry_axis(sim)
        assert abs(np.arccos(np.clip(a @ l_hat, -1, 1)) - cone) < tol
        phi = np.arctan2(a @ e2, a @ e1)
        # bound: the precession phase's C T dt^p, measured 3.6x that of Ω; x10 of that
        assert abs(np.angle(np.exp(1j * (phi - phi0 - rate * sim.time)))) < 10 * tol


@pytest.mark.parametrize('name', ALL)
def test_free_fall(name):
    g = np.array([0.3, -0.2, -9.81])
    x0, v0 = np.array([1.0, 2.0, 3.0]), np.array([0.5, -1.0, 4.0])
    sim = Simulation([RigidBody('ball', 2.0, [0.1, 0.1, 0.1], position_world=x0,
                                linear_velocity_world=v0)], [Gravity(g)], name, 1e-2)
    sim.run(2.0)
    t = sim.time
    pos, _ = sim.pose('ball')
    vel, _ = sim.twist('ball')
    # The symmetric and fourth-order methods integrate a constant acceleration exactly
    # (rounding only); symplectic Euler (kick, then drift) has the known discrete solution
    # x_n = x0 + v0 t + g t (t + h) / 2.
    extra = 0.5 * g * t * 1e-2 if name == 'symplectic_euler' else 0.0
    # bound: 200 steps of <= 9 roundings of terms <= |x|: 4e-13 relative (worst case); x2.5
    np.testing.assert_allclose(pos, x0 + v0 * t + 0.5 * g * t**2 + extra, rtol=1e-12,
                               atol=1e-12)
    np.testing.assert_allclose(vel, v0 + g * t, rtol=1e-12, atol=1e-12)   # bound: as above


def _off_centre_body():
    # Inertia not diagonal in the body frame, COM offset from the body origin, rotated.
    inertia = np.array([[0.30, 0.02, -0.05], [0.02, 0.25, 0.01], [-0.05, 0.01, 0.20]])
    return RigidBody('box', 3.0, inertia, com_body=[0.1, -0.2, 0.05],
                     position_world=[0.5, 0.0, 1.0],
                     orientation_xyzw=so3.quat_normalize(np.array([0.2, -0.3, 0.1, 0.9])),
                     angular_velocity_body=[0.4, -0.7, 1.1])


@pytest.mark.parametrize('frame', ['world', 'body'])
def test_off_centre_wrench_gives_exact_accelerations(frame):
    body = _off_centre_body()
    force = np.array([2.0, -1.0, 3.0])
    torque = np.array([0.1, 0.2, -0.3])
    point = np.array([0.3, 0.1, -0.2])
    wrench = {'body': 'box', 'force': force, 'torque': torque, 'frame': frame,
              'point_body': point}
    sim = Simulation([body], [AppliedWrenches([wrench])], 'rkmk4', 1e-3)
    s = sim.state
    acc, om_dot = sim.dynamics.accelerations(0.0, s.pos_com_world, s.quat_principal_world,
                                             s.vel_com_world, s.ang_vel_principal)
    # Independent computation in the world frame, from the user's body-frame data.
    R_wb = so3.quat_to_matrix(body.orientation_xyzw)
    f_w = force if frame == 'world' else R_wb @ force
    t_w = torque if frame == 'world' else R_wb @ torque
    lever = R_wb @ (point - body.com_body)
    I_w = R_wb @ body.inertia @ R_wb.T
    w_w = R_wb @ body.angular_velocity_body
    alpha_expected = np.linalg.solve(I_w, t_w + np.cross(lever, f_w) - np.cross(w_w, I_w @ w_w))
    R_wp = so3.quat_to_matrix(s.quat_principal_world[0])
    # bound: f through two rotations (entries 4 eps off) and a division: 16 eps |a|; x10
    a_expected = f_w / body.mass
    np.testing.assert_allclose(acc[0], a_expected, rtol=0,
                               atol=160 * EPS * np.linalg.norm(a_expected))
    # bound: backward-stable eigh, solve: cond(I) = 1.85 x ~20 eps of the torques: 40 eps; x10
    np.testing.assert_allclose(R_wp @ om_dot[0], alpha_expected, rtol=0,
                               atol=400 * EPS * np.linalg.norm(alpha_expected))


@pytest.mark.parametrize('name', ALL)
def test_timed_wrench_delivers_its_impulse(name):
    dt = 1e-3
    sim = Simulation([_off_centre_body()], [], name, dt)
    p0 = sim.diagnostics().linear_momentum_world
    force = np.array([1.0, -2.0, 0.5])
    sim.apply_wrench('box', force=force, duration=0.25)   # 250 whole steps
    sim.run(0.5)
    p1 = sim.diagnostics().linear_momentum_world
    # bound: 250 steps of <= 6 kicks rounding by eps (|p0| + |J|): 4e-13 (worst case); x2.5
    np.testing.assert_allclose(p1 - p0, force * 0.25, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize('name', sorted(INTEGRATORS))
def test_outputs_computed_inside_the_step_equal_those_computed_when_read(name):
    # A step whose start state was read computes the new outputs in its kernel; they
    # must be exactly those computed on reading, in every frame, for every body
    # (offset centres of mass, rotated principal frames), whatever the reading pattern.
    def scene():
        bodies = [RigidBody('a', 1.0, np.diag([1.0, 2.0, 3.0]) + 0.1, com_body=(0.1, -0.2, 0.3),
                            orientation_xyzw=(0.1, 0.2, 0.3, np.sqrt(0.86)),
                            angular_velocity_body=(0.3, 1.0, -0.2)),
                  RigidBody('b', 2.0, (1.0, 1.0, 2.0), position_world=(1.0, 0.0, 0.0),
                            linear_velocity_world=(0.0, 1.0, 0.0))]
        return Simulation(bodies, [Gravity()], name, 1e-3)

    def read(sim, body):
        parts = (*sim.pose(body), *sim.twist(body), *sim.twist(body, 'body'))
        return np.concatenate([np.ravel(p) for p in parts])

    every, late = scene(), scene()
    read(every, 'a')
    for k in range(1, 40):
        every.step()
        late.step()
        # The step computed them: what this test is about.
        assert every.bodies.outputs_cache.key[0] is every.state
        got = np.concatenate([read(every, 'a'), read(every, 'b')])
        if k % 7 == 0:
            # Read late: its outputs come from the separate kernel at the read; exact, as both
            # call the same compiled function on the same state (same machine, same run).
            assert np.array_equal(got, np.concatenate([read(late, 'a'), read(late, 'b')]))
        if k == 20:
            # A state the user sets is never taken for one whose outputs are kept.
            late.state.vel_com_world = late.state.vel_com_world + 0.5
            every.state = late.state.copy()
            assert np.array_equal(read(every, None), read(late, None))
    assert np.array_equal(read(every, None), read(late, None))


def test_state_is_one_buffer_that_steps_replace():
    """The four state arrays are views of one buffer; a step or an assignment replaces it."""
    sim = Simulation([RigidBody('a', 1.0, (1.0, 2.0, 3.0), angular_velocity_body=(0.1, 2, 0.1)),
                      RigidBody('b', 2.0, (1.0, 1.0, 1.0), position_world=(1, 2, 3))],
                     [Gravity()], 'lie_poisson2', 1e-2)
    s0 = sim.state
    parts = (s0.pos_com_world, s0.quat_principal_world, s0.vel_com_world, s0.ang_vel_principal)
    assert [p.shape for p in parts] == [(2, 3), (2, 4), (2, 3), (2, 3)]
    assert all(np.shares_memory(p, s0.y) for p in parts)
    assert np.array_equal(s0.y, np.concatenate([p.ravel() for p in parts]))
    before = s0.y.copy()
    sim.step(3)
    # The step made a new state with a new buffer; the old one is untouched.
    assert sim.state.y is not s0.y and np.array_equal(s0.y, before)
    assert not np.array_equal(sim.state.pos_com_world, s0.pos_com_world)
    # Assigning an attribute gives the state a new buffer (caches keyed on it see it).
    s = sim.state
    old_y, old_quat = s.y, s.quat_principal_world
    s.vel_com_world = s.vel_com_world + 1.0
    assert s.y is not old_y and np.array_equal(s.vel_com_world, old_y[14:20].reshape(2, 3) + 1)
    assert np.array_equal(s.quat_principal_world, old_quat)
    copy = s.copy()
    copy.pos_com_world[0, 0] = 99.0
    assert s.pos_com_world[0, 0] != 99.0
    with pytest.raises(ValueError, match='quat_principal_world: expected shape'):
        State(0.0, np.zeros((2, 3)), np.zeros((2, 3)), np.zeros((2, 3)), np.zeros((2, 3)))
