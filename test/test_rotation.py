"""SO(3) utilities against scipy's Rotation (same scalar-last, active convention)."""

import numpy as np
import pytest
from rigid_body_sim.core import rotation as so3
from scipy.spatial.transform import Rotation

# Bounds below: entries of unit quaternions and rotation matrices are at most 1, so an
# operation on them rounds by eps in absolute terms; a rotation matrix computed from a
# quaternion is within 4 eps (three roundings of terms at most 2, |q| = 1 to eps), and a
# quaternion error dq moves it by at most 4 |dq|. Tolerances are 10x the bound (numpy's
# SIMD loops and libm differ in the last bits between CPUs).
EPS = np.finfo(float).eps


@pytest.fixture
def quats(rng):
    return so3.quat_normalize(rng.normal(size=(200, 4)))


def test_quat_to_matrix_matches_scipy(quats):
    # bound: each method within 4 eps: 8 eps; x10
    np.testing.assert_allclose(so3.quat_to_matrix(quats), Rotation.from_quat(quats).as_matrix(),
                               rtol=0, atol=80 * EPS)


def test_matrix_to_quat_round_trip(quats):
    q = so3.matrix_to_quat(so3.quat_to_matrix(quats))
    same_sign = np.where(quats[:, 3:] < 0.0, -quats, quats)
    # bound: R 4 eps; Shepperd: sums of two entries over s >= 2, 2 roundings: 6 eps; x10
    np.testing.assert_allclose(q, same_sign, rtol=0, atol=60 * EPS)


def test_matrix_to_quat_near_pi():
    # Rotations by pi (trace -1) take the diagonal branches of Shepperd's method.
    for axis in np.eye(3):
        for eps in (0.0, 1e-9):
            u = (np.pi - eps) * axis
            q = so3.matrix_to_quat(so3.quat_to_matrix(so3.exp_quat(u)))
            # bound: q 8 eps (exp, round trip) -> R 36 eps, scipy's 8; x10 (1e-13 << 1e-9)
            np.testing.assert_allclose(so3.quat_to_matrix(q),
                                       Rotation.from_rotvec(u).as_matrix(), rtol=0,
                                       atol=440 * EPS)


@pytest.mark.parametrize('scale', [1e-12, 1e-9, 1e-5, 1e-3, 1.0, 3.0])
def test_exp_matches_scipy_and_log_inverts_it(rng, scale):
    u = scale * rng.normal(size=(100, 3))
    u *= np.minimum(1.0, 3.1 / np.linalg.norm(u, axis=1, keepdims=True))  # angle < pi
    q = so3.exp_quat(u)
    # bound: q 2 eps (norm, sin, cos) -> R 12 eps, scipy's 12; x10 (< |R - I| at 1e-12)
    np.testing.assert_allclose(so3.quat_to_matrix(q), Rotation.from_rotvec(u).as_matrix(),
                               rtol=0, atol=240 * EPS)
    # bound: componentwise, the coefficients sin(θ/2)/θ and θ/s within ~5 eps each: 10 eps; x10
    np.testing.assert_allclose(so3.log_quat(q), u, rtol=100 * EPS, atol=1e-300)


def test_composition_is_matrix_product(quats):
    a, b = quats[:100], quats[100:]
    # bound: q_a q_b 4 eps -> R 20 eps; R_a R_b (entries 4 eps off, 3 terms) 15 eps; x10
    np.testing.assert_allclose(so3.quat_to_matrix(so3.quat_multiply(a, b)),
                               so3.quat_to_matrix(a) @ so3.quat_to_matrix(b), rtol=0,
                               atol=350 * EPS)


def test_hat_vee_and_cross(rng):
    a, b = rng.normal(size=(2, 50, 3))
    scale = np.max(np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1))
    # bound: a1 b2 - a2 b1 rounds by 2 eps |a||b| in each of two evaluations: 4 eps; x10
    np.testing.assert_allclose(so3.hat(a) @ b[..., None], np.cross(a, b)[..., None], rtol=0,
                               atol=40 * EPS * scale)
    np.testing.assert_allclose(so3.cross(a, b), np.cross(a, b), rtol=0,
                               atol=40 * EPS * scale)   # bound: as above (np.cross's own order)
    # Exact: vee takes (a - (-a)) / 2, and 2a and 0.5 · 2a round nothing.
    np.testing.assert_array_equal(so3.vee(so3.hat(a)), a)


def test_body_frame_update_convention():
    # R <- R exp(hat(u)) rotates about the BODY axis u: body x axis turned 90 deg about
    # body z of a frame already turned 90 deg about world x.
    q = so3.exp_quat(np.array([np.pi / 2, 0.0, 0.0]))
    q2 = so3.quat_multiply(q, so3.exp_quat(np.array([0.0, 0.0, np.pi / 2])))
    x_axis_world = so3.quat_to_matrix(q2) @ np.array([1.0, 0.0, 0.0])
    # bound: two exps 2 eps, product 4 + 4: q2 8 eps -> R 36 eps; x10 (a wrong axis errs by 1)
    np.testing.assert_allclose(x_axis_world, [0.0, 0.0, 1.0], rtol=0, atol=360 * EPS)
