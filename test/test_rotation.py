"""SO(3) utilities against scipy's Rotation (same scalar-last, active convention)."""

import numpy as np
import pytest
from rigid_body_sim.core import rotation as so3
from scipy.spatial.transform import Rotation


@pytest.fixture
def quats(rng):
    return so3.quat_normalize(rng.normal(size=(200, 4)))


def test_quat_to_matrix_matches_scipy(quats):
    np.testing.assert_allclose(so3.quat_to_matrix(quats), Rotation.from_quat(quats).as_matrix(),
                               atol=1e-15)


def test_matrix_to_quat_round_trip(quats):
    q = so3.matrix_to_quat(so3.quat_to_matrix(quats))
    same_sign = np.where(quats[:, 3:] < 0.0, -quats, quats)
    np.testing.assert_allclose(q, same_sign, atol=2e-15)


def test_matrix_to_quat_near_pi():
    # Rotations by pi (trace -1) take the diagonal branches of Shepperd's method.
    for axis in np.eye(3):
        for eps in (0.0, 1e-9):
            u = (np.pi - eps) * axis
            q = so3.matrix_to_quat(so3.quat_to_matrix(so3.exp_quat(u)))
            np.testing.assert_allclose(so3.quat_to_matrix(q),
                                       Rotation.from_rotvec(u).as_matrix(), atol=1e-15)


@pytest.mark.parametrize('scale', [1e-12, 1e-9, 1e-5, 1e-3, 1.0, 3.0])
def test_exp_matches_scipy_and_log_inverts_it(rng, scale):
    u = scale * rng.normal(size=(100, 3))
    u *= np.minimum(1.0, 3.1 / np.linalg.norm(u, axis=1, keepdims=True))  # angle < pi
    q = so3.exp_quat(u)
    np.testing.assert_allclose(so3.quat_to_matrix(q), Rotation.from_rotvec(u).as_matrix(),
                               atol=1e-15)
    np.testing.assert_allclose(so3.log_quat(q), u, rtol=1e-12, atol=1e-300)


def test_composition_is_matrix_product(quats):
    a, b = quats[:100], quats[100:]
    np.testing.assert_allclose(so3.quat_to_matrix(so3.quat_multiply(a, b)),
                               so3.quat_to_matrix(a) @ so3.quat_to_matrix(b), atol=1e-15)


def test_hat_vee_and_cross(rng):
    a, b = rng.normal(size=(2, 50, 3))
    np.testing.assert_allclose(so3.hat(a) @ b[..., None], np.cross(a, b)[..., None],
                               atol=1e-15)
    np.testing.assert_allclose(so3.cross(a, b), np.cross(a, b), atol=0)
    np.testing.assert_allclose(so3.vee(so3.hat(a)), a, atol=0)


def test_body_frame_update_convention():
    # R <- R exp(hat(u)) rotates about the BODY axis u: body x axis turned 90 deg about
    # body z of a frame already turned 90 deg about world x.
    q = so3.exp_quat(np.array([np.pi / 2, 0.0, 0.0]))
    q2 = so3.quat_multiply(q, so3.exp_quat(np.array([0.0, 0.0, np.pi / 2])))
    x_axis_world = so3.quat_to_matrix(q2) @ np.array([1.0, 0.0, 0.0])
    np.testing.assert_allclose(x_axis_world, [0.0, 0.0, 1.0], atol=1e-15)
