"""
SO(3) on arrays: hat/vee, exponential map, quaternions.

Convention (the only one used in this package)
----------------------------------------------
* Quaternions are Hamilton quaternions stored **scalar-last**,
  ``q = (x, y, z, w)``, the order of ROS messages and of
  ``scipy.spatial.transform.Rotation``.
* A quaternion or rotation matrix ``R`` is **active** and maps coordinates in
  the rotated (body) frame to the fixed (world) frame: ``p_world = R @ p_body``.
* Composition ``q_a ⊗ q_b`` corresponds to ``R_a @ R_b``.
* Angular velocity in the body frame ``Ω`` (the seed's capital Omega) satisfies
  ``dR/dt = R hat(Ω)``; in the world frame ``ω = R Ω`` and ``dR/dt = hat(ω) R``.
  A body-frame rotation vector ``u`` updates ``R <- R exp(hat(u))``, i.e.
  ``q <- q ⊗ exp_quat(u)``.

Every function accepts a leading batch dimension ``(..., 3)``, ``(..., 4)`` or
``(..., 3, 3)`` and is vectorized over it.

"""

from __future__ import annotations

import numpy as np

# Below this angle (rad) the series expansions are used; their truncation error
# (theta**6 / 5040 relative, for sin(theta)/theta) is below double rounding.
_SMALL_ANGLE = 1e-4


def hat(v: np.ndarray) -> np.ndarray:
    """
    Return the skew-symmetric matrix of ``v``: its product with ``b`` is ``v × b``.

    Parameters
    ----------
    v : ndarray, shape (..., 3)
        Vectors.

    Returns
    -------
    ndarray, shape (..., 3, 3)

    """
    v = np.asarray(v, dtype=float)
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1] = -v[..., 2]
    out[..., 0, 2] = v[..., 1]
    out[..., 1, 0] = v[..., 2]
    out[..., 1, 2] = -v[..., 0]
    out[..., 2, 0] = -v[..., 1]
    out[..., 2, 1] = v[..., 0]
    return out


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """
    Cross product over the last axis, broadcasting; shapes (..., 3).

    Same result as ``np.cross`` for 3-vectors, without its axis bookkeeping,
    which dominates the cost for the short arrays of a time step.
    """
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    out = np.empty(a.shape if a.shape == b.shape else np.broadcast_shapes(a.shape, b.shape))
    out[..., 0] = a1 * b2 - a2 * b1
    out[..., 1] = a2 * b0 - a0 * b2
    out[..., 2] = a0 * b1 - a1 * b0
    return out


def vee(m: np.ndarray) -> np.ndarray:
    """
    Inverse of :func:`hat`, from the antisymmetric part of ``m``.

    Parameters
    ----------
    m : ndarray, shape (..., 3, 3)
        Matrices.

    Returns
    -------
    ndarray, shape (..., 3)

    """
    m = np.asarray(m, dtype=float)
    return 0.5 * np.stack(
        [m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]],
        axis=-1,
    )


def exp_quat(u: np.ndarray) -> np.ndarray:
    """
    Return the unit quaternion of rotation vector ``u`` (angle ``|u|`` about ``u/|u|``).

    Parameters
    ----------
    u : ndarray, shape (..., 3)
        Rotation vectors (rad).

    Returns
    -------
    ndarray, shape (..., 4)
        Quaternions ``(x, y, z, w)``, unit to rounding error.

    """
    u = np.asarray(u, dtype=float)
    theta = np.linalg.norm(u, axis=-1)
    half = 0.5 * theta
    small = theta < _SMALL_ANGLE
    # sin(theta/2)/theta, with its Taylor series near zero.
    safe = np.where(small, 1.0, theta)
    coef = np.where(small, 0.5 - theta**2 / 48.0 + theta**4 / 3840.0, np.sin(half) / safe)
    out = np.empty(u.shape[:-1] + (4,))
    out[..., :3] = coef[..., None] * u
    out[..., 3] = np.cos(half)
    return out


def log_quat(q: np.ndarray) -> np.ndarray:
    """
    Rotation vector of the unit quaternion ``q`` (angle in [0, pi]).

    Parameters
    ----------
    q : ndarray, shape (..., 4)
        Unit quaternions (x, y, z, w).

    Returns
    -------
    ndarray, shape (..., 3)

    """
    q = np.asarray(q, dtype=float)
    # q and -q are the same rotation: take w >= 0 so the angle is <= pi.
    q = np.where(q[..., 3:4] < 0.0, -q, q)
    s = np.linalg.norm(q[..., :3], axis=-1)
    theta = 2.0 * np.arctan2(s, q[..., 3])
    # arctan2 is accurate for small arguments, so theta / s only needs s > 0;
    # at s == 0 its limit 2 / w applies.
    zero = s == 0.0
    coef = np.where(zero, 2.0 / np.where(zero, q[..., 3], 1.0), theta / np.where(zero, 1.0, s))
    return coef[..., None] * q[..., :3]


def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """
    Hamilton product ``a ⊗ b`` of scalar-last quaternions.

    Parameters
    ----------
    a, b : ndarray, shape (..., 4)
        Quaternions (x, y, z, w).

    Returns
    -------
    ndarray, shape (..., 4)

    """
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    ax, ay, az, aw = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    bx, by, bz, bw = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    return np.stack(
        [
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz,
        ],
        axis=-1,
    )


def quat_conjugate(q: np.ndarray) -> np.ndarray:
    """Conjugate (inverse, for unit quaternions) of ``q``; shape (..., 4)."""
    q = np.asarray(q, dtype=float)
    out = q.copy()
    out[..., :3] *= -1.0
    return out


def quat_normalize(q: np.ndarray) -> np.ndarray:
    """
    Divide ``q`` by its norm; shape (..., 4).

    The integrators update orientation by the exponential map, so a quaternion
    leaves the unit sphere only by rounding error (about 1e-16 a step); this
    removes that rounding error and nothing else.
    """
    q = np.asarray(q, dtype=float)
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """
    Rotation matrix of the unit quaternion ``q``.

    Parameters
    ----------
    q : ndarray, shape (..., 4)
        Unit quaternions (x, y, z, w).

    Returns
    -------
    ndarray, shape (..., 3, 3)

    """
    q = np.asarray(q, dtype=float)
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz = x * y, x * z, y * z
    wx, wy, wz = w * x, w * y, w * z
    out = np.empty(q.shape[:-1] + (3, 3))
    out[..., 0, 0] = 1.0 - 2.0 * (yy + zz)
    out[..., 0, 1] = 2.0 * (xy - wz)
    out[..., 0, 2] = 2.0 * (xz + wy)
    out[..., 1, 0] = 2.0 * (xy + wz)
    out[..., 1, 1] = 1.0 - 2.0 * (xx + zz)
    out[..., 1, 2] = 2.0 * (yz - wx)
    out[..., 2, 0] = 2.0 * (xz - wy)
    out[..., 2, 1] = 2.0 * (yz + wx)
    out[..., 2, 2] = 1.0 - 2.0 * (xx + yy)
    return out


def matrix_to_quat(m: np.ndarray) -> np.ndarray:
    """
    Return the unit quaternion (``w >= 0``) of the rotation matrix ``m``.

    Uses Shepperd's method: the largest of ``w, x, y, z`` is computed from the
    trace or the diagonal, the others from off-diagonal sums, so the result is
    accurate for every rotation.

    Parameters
    ----------
    m : ndarray, shape (..., 3, 3)
        Matrices.

    Returns
    -------
    ndarray, shape (..., 4)

    """
    m = np.asarray(m, dtype=float)
    batch = m.shape[:-2]
    m = m.reshape((-1, 3, 3))
    tr = np.trace(m, axis1=-2, axis2=-1)
    d = np.stack([m[:, 0, 0], m[:, 1, 1], m[:, 2, 2], tr], axis=-1)
    k = np.argmax(d, axis=-1)
    q = np.empty((m.shape[0], 4))
    # Case w largest.
    i = k == 3
    s = np.sqrt(1.0 + tr[i]) * 2.0
    q[i, 3] = 0.25 * s
    q[i, 0] = (m[i, 2, 1] - m[i, 1, 2]) / s
    q[i, 1] = (m[i, 0, 2] - m[i, 2, 0]) / s
    q[i, 2] = (m[i, 1, 0] - m[i, 0, 1]) / s
    # Cases x, y or z largest: cyclic permutations (a, b, c).
    for a, b, c in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):
        i = k == a
        s = np.sqrt(1.0 + m[i, a, a] - m[i, b, b] - m[i, c, c]) * 2.0
        q[i, a] = 0.25 * s
        q[i, 3] = (m[i, c, b] - m[i, b, c]) / s
        q[i, b] = (m[i, b, a] + m[i, a, b]) / s
        q[i, c] = (m[i, c, a] + m[i, a, c]) / s
    q = np.where(q[:, 3:4] < 0.0, -q, q)
    return q.reshape(batch + (4,))


def rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors ``v`` by unit quaternions ``q``: ``R(q) @ v``; shapes (..., 4), (..., 3)."""
    return np.einsum('...ij,...j->...i', quat_to_matrix(q), v)


def orthonormality_error(m: np.ndarray) -> np.ndarray:
    """Largest entry of ``|Mᵀ M - I|`` for each matrix; shape (..., 3, 3) -> (...)."""
    m = np.asarray(m, dtype=float)
    g = np.einsum('...ki,...kj->...ij', m, m) - np.eye(3)
    return np.max(np.abs(g), axis=(-2, -1))
