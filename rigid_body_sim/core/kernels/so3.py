"""
Rotations in compiled kernels: unit quaternions ``(x, y, z, w)`` and their matrices.

The conventions are those of :mod:`..rotation` (the rotation of a quaternion maps
the principal frame to the world), written for one body at a time over floats.
"""

from __future__ import annotations

import math

from numba import njit
import numpy as np

# Below this angle (rad) exp uses its series (as rotation.exp_quat).
_SMALL_ANGLE = 1e-4


@njit(cache=True)
def quat_exp_multiply(q: np.ndarray, u0: float, u1: float, u2: float, out: np.ndarray) -> None:
    """``out = q ⊗ exp(u)`` for one body (q, out: (4,), may be the same array)."""
    theta = math.sqrt(u0 * u0 + u1 * u1 + u2 * u2)
    half = 0.5 * theta
    if theta < _SMALL_ANGLE:
        t2 = theta * theta
        coef = 0.5 - t2 / 48.0 + t2 * t2 / 3840.0
    else:
        coef = math.sin(half) / theta
    bx, by, bz, bw = coef * u0, coef * u1, coef * u2, math.cos(half)
    ax, ay, az, aw = q[0], q[1], q[2], q[3]
    out[0] = aw * bx + ax * bw + ay * bz - az * by
    out[1] = aw * by - ax * bz + ay * bw + az * bx
    out[2] = aw * bz + ax * by - ay * bx + az * bw
    out[3] = aw * bw - ax * bx - ay * by - az * bz


@njit(cache=True)
def _matrix(x: float, y: float, z: float, w: float) -> tuple:
    """Rotation matrix of the unit quaternion (x, y, z, w), row by row (9 floats)."""
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz = x * y, x * z, y * z
    wx, wy, wz = w * x, w * y, w * z
    return (1.0 - 2.0 * (yy + zz), 2.0 * (xy - wz), 2.0 * (xz + wy),
            2.0 * (xy + wz), 1.0 - 2.0 * (xx + zz), 2.0 * (yz - wx),
            2.0 * (xz - wy), 2.0 * (yz + wx), 1.0 - 2.0 * (xx + yy))


@njit(cache=True)
def positive_product(ax: float, ay: float, az: float, aw: float, bx: float, by: float,
                     bz: float, bw: float) -> tuple:
    """Return the quaternion product ``a ⊗ b`` (xyzw), its sign chosen so that ``w >= 0``."""
    x = aw * bx + ax * bw + ay * bz - az * by
    y = aw * by - ax * bz + ay * bw + az * bx
    z = aw * bz + ax * by - ay * bx + az * bw
    w = aw * bw - ax * bx - ay * by - az * bz
    if w < 0.0:
        return -x, -y, -z, -w
    return x, y, z, w


@njit(cache=True)
def quat_matrix(q: np.ndarray, R: np.ndarray) -> None:
    """Rotation matrix ``R`` (3, 3) of the unit quaternion ``q`` (4,, xyzw)."""
    x, y, z, w = q[0], q[1], q[2], q[3]
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz = x * y, x * z, y * z
    wx, wy, wz = w * x, w * y, w * z
    R[0, 0] = 1.0 - 2.0 * (yy + zz)
    R[0, 1] = 2.0 * (xy - wz)
    R[0, 2] = 2.0 * (xz + wy)
    R[1, 0] = 2.0 * (xy + wz)
    R[1, 1] = 1.0 - 2.0 * (xx + zz)
    R[1, 2] = 2.0 * (yz - wx)
    R[2, 0] = 2.0 * (xz - wy)
    R[2, 1] = 2.0 * (yz + wx)
    R[2, 2] = 1.0 - 2.0 * (xx + yy)


@njit(cache=True)
def dexpinv(u: np.ndarray, w: np.ndarray, out: np.ndarray) -> None:
    """
    Inverse right-trivialized ``dexp`` to second order, row by row.

    ``du/dt = w + u × w / 2 + u × (u × w) / 12 + O(|u|⁴)`` for ``R(t) = R0
    exp(hat(u(t)))`` with ``dR/dt = R hat(w)``: enough for order 4 (Hairer,
    Lubich & Wanner, Geometric Numerical Integration, IV.8.2).
    """
    for i in range(u.shape[0]):
        a0, a1, a2 = u[i, 0], u[i, 1], u[i, 2]
        b0, b1, b2 = w[i, 0], w[i, 1], w[i, 2]
        c0, c1, c2 = a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0
        d0, d1, d2 = a1 * c2 - a2 * c1, a2 * c0 - a0 * c2, a0 * c1 - a1 * c0
        out[i, 0] = b0 + 0.5 * c0 + d0 / 12.0
        out[i, 1] = b1 + 0.5 * c1 + d1 / 12.0
        out[i, 2] = b2 + 0.5 * c2 + d2 / 12.0


@njit(cache=True)
def normalize_quaternions(quat: np.ndarray) -> None:
    """Remove the rounding error of the unit quaternions (n, 4), in place."""
    for i in range(quat.shape[0]):
        s = math.sqrt(quat[i, 0] ** 2 + quat[i, 1] ** 2 + quat[i, 2] ** 2 + quat[i, 3] ** 2)
        for c in range(4):
            quat[i, c] /= s
