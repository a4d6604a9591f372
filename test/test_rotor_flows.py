"""
The free rotor's exact flows in the drift (``kernels.free_step``) and SHAKE's derivative of them.

A symmetric top (two equal principal moments) drifts by one exact flow
(``top_flow``): checked against the closed-form Ω(t) and a DOP853 reference, and
for its conservation of energy and |L|. The rotations about principal axes use
the half-angle form (``axis_rotation``): checked against the direct cos/sin
against an extended-precision reference. ``constrained_step._rotor_jacobians``
(the derivative of the drift's end orientation with respect to its start
momentum, SHAKE's Newton matrix) is checked against central differences of
``drift`` for symmetric tops, asymmetric and isotropic bodies.
"""

import math

import numpy as np
import pytest
from rigid_body_sim.core import RigidBody, Simulation
from rigid_body_sim.core import rotation as so3
from rigid_body_sim.core.bodies import top_axes
from rigid_body_sim.core.kernels.constrained_step import _rotor_jacobians
from rigid_body_sim.core.kernels.free_step import axis_rotation, drift, top_angle, TOP_SHAKE_ANGLE
from rigid_body_sim.core.kernels.layout import (B_ANISOTROPIC, B_MOMENTS, B_WIDTH, Count,
                                                N_COUNTS, ROTOR_TOP)
from rigid_body_sim.core.reference import free_body_reference, symmetric_body_omega

EPS = np.finfo(float).eps


def body_row(moments, code):
    """Return a ``body`` model array (1, B_WIDTH) with ``moments`` and rotor ``code``."""
    body = np.zeros((1, B_WIDTH))
    body[0, :2] = 1.0
    body[0, B_MOMENTS:B_MOMENTS + 3] = moments
    body[0, B_ANISOTROPIC] = code
    return body


def run_drift(moments, code, quat, mom, tau, symmetric=True, times=1, max_top_angle=math.inf):
    """Drift one body ``times`` times by ``tau``; return quat (4,), mom (3,) and the counts."""
    q, L = np.array([quat], dtype=float), np.array([mom], dtype=float)
    counts = np.zeros(N_COUNTS, dtype=np.int64)
    body = body_row(moments, code)
    for _ in range(times):
        drift(np.zeros((1, 3)), q, np.zeros((1, 3)), L, body, tau, symmetric, counts,
              max_top_angle)
    return q[0], L[0], counts


def angle_between(qa, qb):
    """Angle (rad) of ``qa⁻¹ ⊗ qb``."""
    d = so3.quat_multiply(so3.quat_conjugate(qa), qb)
    return 2.0 * math.atan2(np.linalg.norm(d[:3]), abs(d[3]))


# -- which bodies are symmetric tops ----------------------------------------------------


def test_top_axes_and_body_codes():
    moments = np.array([[1.0, 2.0, 3.0], [1.0, 1.0, 1.0], [0.5, 2.0, 2.0], [1.0, 1.0, 0.3],
                        [2.0, 0.7, 2.0], [1.0, 1.0 + 1e-13, 2.0], [1.0, 1.0 + 1e-9, 2.0]])
    assert top_axes(moments).tolist() == [-1, -1, 0, 2, 1, 2, -1]
    # A rod along a rotated axis: eigh's moments are equal to rounding, a top all the same.
    R = so3.quat_to_matrix(so3.quat_normalize(np.array([0.3, -0.2, 0.9, 0.4])))
    rod = RigidBody('rod', 1.0, R @ np.diag([5e-5, 1e-3, 1e-3]) @ R.T)
    box = RigidBody('box', 1.0, (1.0, 2.0, 3.0))
    ball = RigidBody('ball', 1.0, (1.0, 1.0, 1.0))
    sim = Simulation([rod, box, ball], [], 'lie_poisson2', 1e-3)
    codes = sim.dynamics.kernel_model(0.0)[0][:, B_ANISOTROPIC]
    assert codes.tolist() == [ROTOR_TOP + 0, 1.0, 0.0]
    # The body set keeps its tops' axes (the model is rebuilt after every wrench) while
    # the moments are the same, and finds them again when they change.
    bodies = sim.bodies
    assert bodies.top_axes() is bodies.top_axes()
    assert bodies.top_axes().tolist() == top_axes(bodies.moments).tolist() == [0, -1, -1]
    bodies.moments[2] = (0.5, 2.0, 2.0)   # (the ball made a top: its axis 0)
    assert bodies.top_axes().tolist() == [0, -1, 0]


# -- the half-angle form ------------------------------------------------------------------


def test_half_angle_rotation_matches_direct_to_rounding():
    # Angles of every size (small, near multiples of π/2 and π, large), and the rotation of
    # a unit L by the half-angle form against cos φ, sin φ in extended precision (80-bit
    # long double, 1e-19: a reference for both forms). The entries of the 2 x 2 rotation
    # are cos φ and sin φ of the same double φ: the direct calls are within 0.25 eps
    # (measured); 1 − 2 sin²(φ/2) and 2 sin(φ/2) cos(φ/2) carry the half-angle calls'
    # own 1/2 ulp through terms at most 1 in size plus two roundings: within 2 eps
    # absolute (measured 1.5 eps), and the rotated unit L within 6 eps (two products and
    # a sum per component on top).
    rng = np.random.default_rng(19)
    phis = np.concatenate([rng.uniform(-10, 10, 4000), 10.0 ** rng.uniform(-12, 3, 2000),
                           np.arange(-64, 65) * (np.pi / 2) + rng.normal(0, 1e-9, 129),
                           [0.0, 1e-300, np.pi, -np.pi, 2 * np.pi, 1e3 * np.pi]])
    worst_half = worst_direct = 0.0
    for phi in phis:
        L = rng.normal(size=3)
        L /= np.linalg.norm(L)
        axis = int(rng.integers(3))
        j, k = (axis + 1) % 3, (axis + 2) % 3
        q = so3.quat_normalize(rng.normal(size=4))
        half = L.copy()
        axis_rotation(q.copy(), half, axis, phi)
        c, s = np.cos(np.longdouble(phi)), np.sin(np.longdouble(phi))
        lj, lk = np.longdouble(L[j]), np.longdouble(L[k])
        exact = (c * lj + s * lk, c * lk - s * lj)
        cd, sd = math.cos(phi), math.sin(phi)
        direct = (cd * L[j] + sd * L[k], cd * L[k] - sd * L[j])
        worst_half = max(worst_half, *(float(abs(half[r] - e)) for r, e in zip((j, k), exact)))
        worst_direct = max(worst_direct, *(float(abs(d - e)) for d, e in zip(direct, exact)))
        assert half[axis] == L[axis]
    assert worst_half <= 6 * EPS
    assert worst_direct <= 6 * EPS


# -- the symmetric top's exact flow --------------------------------------------------------

TOPS = [((0.4, 1.0, 1.0), 0), ((1.3, 0.6, 1.3), 1), ((1.0, 1.0, 0.3), 2), ((1.0, 1.0, 1.7), 2)]


@pytest.mark.parametrize('moments, axis', TOPS)
@pytest.mark.parametrize('tau', [0.05, 1.7])
def test_top_flow_matches_the_free_body_reference(moments, axis, tau):
    # DOP853 at rtol 1e-13 over at most 1.7 s at |Ω| ~ 3 rad/s: its global error is about
    # 1e-12 or less (the top's flow is within 1e-13 of it, measured); bound 1e-10, a
    # hundredfold margin and far below the 1-2-3-2-1 splitting's error of one such drift
    # (1e-7 to 1e-2 at τ = 0.05, order 1 at 1.7).
    rng = np.random.default_rng(int(100 * tau) + axis)
    J = np.array(moments)
    om0 = rng.normal(size=3) * 1.5
    q0 = so3.quat_normalize(rng.normal(size=4))
    quat, mom, counts = run_drift(J, ROTOR_TOP + axis, q0, J * om0, tau)
    om_ref, q_ref = free_body_reference(J, om0, q0, [0.0, tau], rtol=1e-13, atol=1e-14)
    assert np.max(np.abs(mom / J - om_ref[-1])) < 1e-10
    assert angle_between(quat, q_ref[-1]) < 1e-10
    assert counts[Count.GYRO] == 1 and counts[Count.ROT] == 2
    # The same flow without the Strang composition (symplectic Euler): it is exact.
    quat1, mom1, _ = run_drift(J, ROTOR_TOP + axis, q0, J * om0, tau, symmetric=False)
    assert np.array_equal(quat1, quat) and np.array_equal(mom1, mom)
    if axis == 2:
        # The closed form (Landau & Lifshitz §33): Ω₁ + iΩ₂ turns at (J₃ − J₁) Ω₃ / J₁.
        # Rounding only: a few eps of |Ω| per rotation (τ |Ω| / J < 10 rad here).
        om_exact = symmetric_body_omega(J, om0, np.array([tau]))[0]
        assert np.max(np.abs(mom / J - om_exact)) < 100 * EPS * np.linalg.norm(om0)


def test_top_flow_conserves_energy_and_momentum_norm():
    # Each drift rounds T and |L| by a few eps (one rotation of L: 6 eps per component,
    # as above); over N drifts at most N times that: bound 10 N eps relative. The
    # 1-2-3-2-1 splitting of the same top at this step changes T by more than 1e-6.
    J = np.array([0.4, 1.0, 1.0])
    L0 = np.array([0.7, -1.9, 2.4])
    q0 = so3.quat_normalize(np.array([0.1, 0.2, -0.3, 0.9]))
    n = 2000
    _, L, _ = run_drift(J, ROTOR_TOP, q0, L0, 0.3, times=n)
    energy = 0.5 * np.sum(L ** 2 / J)
    energy0 = 0.5 * np.sum(L0 ** 2 / J)
    assert abs(energy - energy0) <= 10 * n * EPS * energy0
    assert abs(np.linalg.norm(L) - np.linalg.norm(L0)) <= 10 * n * EPS * np.linalg.norm(L0)
    assert L[0] == L0[0]   # L_a: untouched by either part of the flow
    _, L5, _ = run_drift(J, 1.0, q0, L0, 0.3)
    assert abs(0.5 * np.sum(L5 ** 2 / J) - energy0) > 1e-6 * energy0


# -- SHAKE's derivative of the drift -------------------------------------------------------

JACOBIAN_CASES = [((0.4, 1.0, 1.0), ROTOR_TOP + 0, True), ((1.3, 0.6, 1.3), ROTOR_TOP + 1, True),
                  ((1.0, 1.0, 0.3), ROTOR_TOP + 2, False), ((1.0, 2.0, 3.0), 1.0, True),
                  ((1.0, 2.0, 3.0), 1.0, False), ((1.5, 1.5, 1.5), 0.0, True)]


@pytest.mark.parametrize('moments, code, symmetric', JACOBIAN_CASES)
@pytest.mark.parametrize('h', [1e-3, 0.4])
def test_rotor_jacobians_match_central_differences(moments, code, symmetric, h):
    # J_r = (∂Θ_end/∂L_start) J / h, Θ the body-frame rotation at the end. Central
    # differences with step ε = 1e-5 |L|: truncation ε²/6 |∂³Θ/∂L³| ≲ 1e-10 (h |Ω| / J
    # ≲ 1 rad: derivatives of order (h/J)^k |L|^(1−k) ≲ 1), rounding eps / ε ~ 1e-11; times
    # J/h (at most 1.5e3 at h = 1e-3, but Θ itself is then O(h)). Bound 1e-7.
    rng = np.random.default_rng(7)
    J = np.array(moments)
    q0 = so3.quat_normalize(rng.normal(size=4))
    L0 = J * rng.normal(size=3) * 2.0
    quat_e, _, _ = run_drift(J, code, q0, L0, h, symmetric)
    Jr = np.zeros((1, 3, 3))
    _rotor_jacobians(np.array([q0]), np.array([quat_e]), np.array([L0]), body_row(J, code), h,
                     symmetric, Jr, np.zeros((6, 3)))
    eps = 1e-5 * np.linalg.norm(L0)
    fd = np.zeros((3, 3))
    for c in range(3):
        ends = []
        for sign in (1.0, -1.0):
            L = L0.copy()
            L[c] += sign * eps
            q, _, _ = run_drift(J, code, q0, L, h, symmetric)
            ends.append(so3.log_quat(so3.quat_multiply(so3.quat_conjugate(quat_e), q)))
        fd[:, c] = (ends[0] - ends[1]) / (2 * eps) * J[c] / h
    assert np.max(np.abs(Jr[0] - fd)) < 1e-7


@pytest.mark.parametrize('moments, axis', [((0.015, 1.0, 1.0), 0), ((2.0, 2.0, 3.0), 2)])
def test_shake_takes_a_top_beyond_its_cone_bound_as_an_asymmetric_body(moments, axis):
    # SHAKE's drift turns a top by its exact flow only up to the cone angle
    # TOP_SHAKE_ANGLE (beyond, the flow's derivative degenerates: free_step); past it,
    # drift and derivative are the 1-2-3-2-1 splitting's, bit for bit (that derivative
    # is checked against central differences above). A thin rod and a flat top.
    J = np.array(moments)
    code = ROTOR_TOP + axis
    rng = np.random.default_rng(11)
    q0 = so3.quat_normalize(rng.normal(size=4))
    L0 = J * rng.normal(size=3)
    h = 2.0 * TOP_SHAKE_ANGLE / top_angle(L0, J, axis, 1.0)   # θ = π
    assert top_angle(L0, J, axis, h) > TOP_SHAKE_ANGLE
    quat_e, mom_e, counts = run_drift(J, code, q0, L0, h, max_top_angle=TOP_SHAKE_ANGLE)
    quat_s, mom_s, _ = run_drift(J, 1.0, q0, L0, h)
    assert np.array_equal(quat_e, quat_s) and np.array_equal(mom_e, mom_s)
    assert counts[Count.GYRO] == 5
    quat_t, _, _ = run_drift(J, code, q0, L0, 0.25 * h, max_top_angle=TOP_SHAKE_ANGLE)
    assert np.array_equal(quat_t, run_drift(J, code, q0, L0, 0.25 * h)[0])   # θ = π/4: exact
    Jr = np.zeros((1, 3, 3))
    _rotor_jacobians(np.array([q0]), np.array([quat_e]), np.array([L0]), body_row(J, code), h,
                     True, Jr, np.zeros((6, 3)), TOP_SHAKE_ANGLE)
    Js = np.zeros((1, 3, 3))
    _rotor_jacobians(np.array([q0]), np.array([quat_e]), np.array([L0]), body_row(J, 1.0), h,
                     True, Js, np.zeros((6, 3)))
    assert np.array_equal(Jr, Js)
