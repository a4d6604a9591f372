"""Every joint type: momenta conserved without external force; Jacobians are right."""

from conftest import random_body
import numpy as np
import pytest
from rigid_body_sim.core import Constraint, INTEGRATORS, Simulation
from rigid_body_sim.core import rotation as so3

EPS = np.finfo(float).eps


def hand_distance(x_a, R_a, x_b, R_b):
    """Return a generic constraint: the centres of mass 0.7 m apart (invariant)."""
    d = x_a - x_b
    return np.array([d @ d - 0.49])


def hand_distance_jacobian(x_a, R_a, x_b, R_b):
    """Return the analytic Jacobian of ``hand_distance`` (no rotation dependence)."""
    d = x_a - x_b
    return np.concatenate([2 * d, np.zeros(3), -2 * d, np.zeros(3)])[None, :]


E_X, E_Y, E_Z = np.eye(3)


def parallel_axes(x_a, R_a, x_b, R_b):
    """Return a generic constraint that depends on rotation only: z_a stays along z_b."""
    z_a = R_a @ E_Z
    return np.array([z_a @ (R_b @ E_X), z_a @ (R_b @ E_Y)])


def parallel_axes_jacobian(x_a, R_a, x_b, R_b):
    """
    Return the analytic Jacobian of ``parallel_axes``, δΘ in each body frame.

    ``δ(R e) = R (δΘ × e)``, so ``∂(R_a e · u)/∂δΘ_a = e × (R_aᵀ u)``.
    """
    z_a = R_a @ E_Z
    rows = []
    for e in (E_X, E_Y):
        u = R_b @ e
        rows.append(np.concatenate([np.zeros(3), np.cross(E_Z, R_a.T @ u),
                                    np.zeros(3), np.cross(e, R_b.T @ z_a)]))
    return np.array(rows)


def joint(kind: str) -> Constraint:
    anchor = [0.1, 0.2, -0.1]
    return {
        'ball': Constraint('j', 'ball', 'a', 'b', anchor_world=anchor),
        'hinge': Constraint('j', 'hinge', 'a', 'b', anchor_world=anchor, axis_world=[1, 2, 3]),
        'slider': Constraint('j', 'slider', 'a', 'b', anchor_world=anchor,
                             axis_world=[1, -2, 0.5]),
        'fixed': Constraint('j', 'fixed', 'a', 'b', anchor_world=anchor),
        'distance': Constraint('j', 'distance', 'a', 'b', anchor_a_body=[0.1, 0, 0],
                               anchor_b_body=[0, 0.2, 0]),
        'generic': Constraint('j', 'generic', 'a', 'b', function=hand_distance),
        'generic_axes': Constraint('j', 'generic', 'a', 'b', function=parallel_axes),
        'generic_axes_jacobian': Constraint('j', 'generic', 'a', 'b', function=parallel_axes,
                                            jacobian=parallel_axes_jacobian),
    }[kind]


def two_bodies(rng, kind, name='lie_poisson2', dt=1e-3):
    a, b = random_body(rng, 'a'), random_body(rng, 'b')
    if kind == 'generic':   # start on the constraint: |x_a - x_b| = 0.7
        b = random_body(rng, 'b')
        sim0 = Simulation([a, b], [], name, dt)
        xa = sim0.state.pos_com_world[0]
        direction = rng.normal(size=3)
        offset = b.position_world - sim0.state.pos_com_world[1]
        from dataclasses import replace
        b = replace(b, position_world=xa + 0.7 * direction / np.linalg.norm(direction) + offset)
    if kind.startswith('generic_axes'):   # start on it: the same orientation
        from dataclasses import replace
        b = replace(b, orientation_xyzw=a.orientation_xyzw)
    return Simulation([a, b], [], name, dt, [joint(kind)])


# The random bodies' inertia tensors are not diagonal in their body frames, so the
# generic rows also check the conversion between body and principal frames.
KINDS = ['ball', 'hinge', 'slider', 'fixed', 'distance', 'generic', 'generic_axes',
         'generic_axes_jacobian']


@pytest.mark.parametrize('name', sorted(INTEGRATORS))
@pytest.mark.parametrize('kind', KINDS)
def test_momenta_conserved(kind, name, rng):
    # Random velocities disagree with the joint: the simulation reconciles them when
    # the joint is added (a plastic impact); from then on the motion conserves.
    sim = two_bodies(rng, kind, name)
    d0 = sim.diagnostics()
    sim.step(300)
    d = sim.diagnostics()
    p0, l0 = d0.linear_momentum_world, d0.angular_momentum_world
    # Constraint forces are internal: measured drift at most 1.2e-12 relative.
    # bound: 300 k eps = 3e-13; generic: G's rounding (1e-10) over N random steps ~5e-12; x20
    assert np.linalg.norm(d.linear_momentum_world - p0) <= 1e-10 * np.linalg.norm(p0)
    assert np.linalg.norm(d.angular_momentum_world - l0) <= 1e-10 * np.linalg.norm(l0)
    # bound: SHAKE's 1e-13, or the unprojected O(dt^3..4) drift 3.7e-11 (not rounding); x2.7
    assert d.constraint_violation < 1e-10
    # Ideal constraints do no work: the energy error is the method's C T dt^p (measured at
    # most 3.7e-5 relative for symplectic Euler, 1.6e-8 for lie_poisson2 and 1e-11 for the
    # fourth order, over 0.3 s; 2x, 4x, 16x less at dt / 2), + rounding 300 k eps = 3e-13.
    e0 = d0.total_energy
    tol = {1: 2e-4, 2: 1e-7, 4: 1e-10}[INTEGRATORS[name].order]   # bound: C T dt^p; x5 to x10
    assert abs(d.total_energy - e0) < tol * e0


def finite_difference_jacobian(cs, s, h=1e-6):
    pos0, quat0 = s.pos_com_world, s.quat_principal_world
    m = len(cs.geometry(pos0, quat0).phi)
    G = np.zeros((m, 6 * len(pos0)))
    for body in range(len(pos0)):
        for j in range(6):
            out = []
            for sign in (1.0, -1.0):
                pos, quat = pos0.copy(), quat0.copy()
                step = np.zeros(3)
                step[j % 3] = sign * h
                if j < 3:
                    pos[body] += step
                else:
                    quat[body] = so3.quat_multiply(quat[body], so3.exp_quat(step))
                out.append(cs.geometry(pos, quat).phi)
            G[:, 6 * body + j] = (out[0] - out[1]) / (2 * h)
    return G


@pytest.mark.parametrize('kind', KINDS)
def test_jacobian_velocity_and_bias_terms(kind, rng):
    sim = two_bodies(rng, kind)
    cs = sim.dynamics.solver.constraints
    s = sim.state
    ev = cs.evaluate(s.pos_com_world, s.quat_principal_world, s.vel_com_world,
                     s.ang_vel_principal)
    G = ev.jacobian.toarray()
    # Analytic (and, for generic, automatic) G against central differences: the
    # difference error is O(h²) ~ 1e-12 plus rounding / h.
    # bound: Φ± round by ~5 eps of 3 m: / h = 3.3e-9, twice for generic (G a difference); x10
    np.testing.assert_allclose(G, finite_difference_jacobian(cs, s), rtol=0, atol=7e-8)
    nu = np.hstack([s.vel_com_world, s.ang_vel_principal]).ravel()
    # bound: each of Φ̇ and G ν within γ_12 |G||ν| (12 terms): 24 eps; x10
    np.testing.assert_allclose(ev.phi_dot, G @ nu, rtol=0,
                               atol=240 * EPS * np.max(np.abs(G) @ np.abs(nu)))

    # γ = Ġν is the second derivative of Φ along x(t) = x + t v, R(t) = R exp(t Ω).
    def phi_at(t):
        q = so3.quat_multiply(s.quat_principal_world, so3.exp_quat(t * s.ang_vel_principal))
        return cs.geometry(s.pos_com_world + t * s.vel_com_world, q).phi

    h = 1e-4
    second = (phi_at(h) - 2 * phi_at(0.0) + phi_at(-h)) / h**2
    first = (phi_at(h) - phi_at(-h)) / (2 * h)
    # bound: h² |d³Φ| / 6 ~ 2e-8 (|Ω|, |v| ~ 2) + rounding 5 eps 3 m / h = 3e-11; x50
    np.testing.assert_allclose(ev.phi_dot, first, rtol=0, atol=1e-6)
    # bound: h² |d⁴Φ| / 12 ~ 1e-8 + 4 (5 eps 3 m) / h² = 1.3e-6, twice for generic rows; x8
    np.testing.assert_allclose(ev.gamma, second, rtol=0,
                               atol=2e-5 * max(1.0, np.abs(second).max()))


def test_generic_with_and_without_jacobian_move_alike(rng):
    with_jac = Constraint('j', 'generic', 'a', 'b', function=hand_distance,
                          jacobian=hand_distance_jacobian)
    sims = [two_bodies(np.random.default_rng(7), 'generic') for _ in range(2)]
    sims[1].remove_constraint('j')
    sims[1].add_constraint(with_jac)
    for sim in sims:
        sim.step(200)
    # Same physics, Jacobians differing by finite-difference error only.
    # bound: G off by eps |Φ| / h ~ 1e-10 relative deflects v so: 1e-10 |v| T = 4e-11 m; x10
    np.testing.assert_allclose(sims[0].pose()[0], sims[1].pose()[0], rtol=0, atol=5e-10)
