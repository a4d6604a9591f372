"""
Joint drives in compiled kernels: servos and passive joint damping.

They are the wrench rows of kind ``WRENCH_DRIVE`` (:data:`.layout.WRENCH`).

A drive acts along one joint's free direction between its child body a and its
parent b (the world when ``parent >= n``) as a pair of equal and opposite wrenches:
a torque ``τ k`` about the axis (rotary joints) or a force ``τ k`` along it, through
the child's joint point P (prismatic joints). Its generalized force is

    τ = clip(kp (q* − q) + kd (v* − q̇), ±effort_max) − d q̇

(the servo, an actuator limited to ``effort_max``, and the passive damping d).
In the splittings the rate terms, which have an exact flow for one joint at frozen
positions, enter as that flow, and the servo's spring ``kp (q* − q)`` enters the
kicks like any force of the positions (a saturated servo, a constant ``±effort_max``,
enters the kicks whole). With ``D = d + kd`` (``d`` alone when saturated) and
``v_eq = kd v* / D``:

    s' = v_eq + (s − v_eq) exp(−D c t),   the impulse (s' − s) / c along the joint,

with ``s = j ν`` the joint rate and ``c = j M⁻¹ jᵀ`` its inverse inertia (``kᵀ(J_a⁻¹ +
J_b⁻¹) k`` for a rotary joint, in principal frames); the velocity projection that
follows puts the constraints' share back (a splitting of order 2, as for the
bodies' damping). The flow conserves momentum and, for ``v* = 0``, removes energy,
for any gain and step. The angle of a rotary joint is
``atan2((R_b e2_b)·(R_a e1_a), (R_b e1_b)·(R_a e1_a))``, taken within π of
``center`` (the caller keeps ``center`` within π/2 of the angle); a slide is
``(R_b k_b)·(P − P_b)``, with P_b the parent's joint point.
"""

from __future__ import annotations

import math

from numba import njit
import numpy as np

from .layout import (B_INV_MASS, B_MOMENTS, W_BODY, W_CENTER, W_DAMPING, W_E1_CHILD,
                     W_E1_PARENT, W_E2_PARENT, W_EFFORT_MAX, W_K_CHILD, W_K_PARENT, W_KD,
                     W_KIND, W_KP, W_PARENT, W_Q_TARGET, W_R_CHILD, W_R_PARENT, W_ROTARY,
                     W_V_TARGET, WRENCH_DRIVE)
from .so3 import quat_matrix

TWO_PI = 2.0 * math.pi


@njit(cache=True)
def _vec(row: np.ndarray, k: int, out: np.ndarray) -> None:
    for c in range(3):
        out[c] = row[k + c]


@njit(cache=True)
def _rot(R: np.ndarray, v: np.ndarray, out: np.ndarray) -> None:
    """``out = R v``."""
    for r in range(3):
        out[r] = R[r, 0] * v[0] + R[r, 1] * v[1] + R[r, 2] * v[2]


@njit(cache=True)
def _rot_t(R: np.ndarray, v: np.ndarray, out: np.ndarray) -> None:
    """``out = Rᵀ v``."""
    for r in range(3):
        out[r] = R[0, r] * v[0] + R[1, r] * v[1] + R[2, r] * v[2]


@njit(cache=True)
def _cross(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> None:
    out[0] = a[1] * b[2] - a[2] * b[1]
    out[1] = a[2] * b[0] - a[0] * b[2]
    out[2] = a[0] * b[1] - a[1] * b[0]


@njit(cache=True)
def _dot(a: np.ndarray, b: np.ndarray) -> float:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@njit(cache=True)
def _frames(pos, quat, vel, om, i, n, x, R, v, w):
    """Centre of mass, rotation, velocity and world angular velocity of body i (world: 0)."""
    if i >= n:
        for r in range(3):
            x[r] = v[r] = w[r] = 0.0
            for c in range(3):
                R[r, c] = 1.0 if r == c else 0.0
        return
    quat_matrix(quat[i], R)
    for r in range(3):
        x[r] = pos[i, r]
        v[r] = vel[i, r]
    for r in range(3):
        w[r] = R[r, 0] * om[i, 0] + R[r, 1] * om[i, 1] + R[r, 2] * om[i, 2]


@njit(cache=True)
def _measure(pos, quat, vel, om, row, n, S):
    """
    Measure the joint's coordinate and rate, and its direction, into the scratch ``S``.

    Rows of S: 0 x_a, 1 v_a, 2 w_a, 3 x_b, 4 v_b, 5 w_b, 6 k (world), 7 ρ_a = P − x_a,
    8 ρ_b = P − x_b, 9-11 work. ``Ra``, ``Rb`` are S's companions (returned).
    Returns (q, rate).
    """
    a, b = int(row[W_BODY]), int(row[W_PARENT])
    Ra, Rb = np.empty((3, 3)), np.empty((3, 3))
    _frames(pos, quat, vel, om, a, n, S[0], Ra, S[1], S[2])
    _frames(pos, quat, vel, om, b, n, S[3], Rb, S[4], S[5])
    _vec(row, W_K_PARENT, S[9])
    _rot(Rb, S[9], S[6])
    # The child's joint point P and its lever arms.
    _vec(row, W_R_CHILD, S[9])
    _rot(Ra, S[9], S[7])
    for c in range(3):
        S[8, c] = S[0, c] + S[7, c] - S[3, c]
    if row[W_ROTARY] > 0.0:
        _vec(row, W_E1_CHILD, S[9])
        _rot(Ra, S[9], S[10])          # e1 of the child, world
        _vec(row, W_E1_PARENT, S[9])
        _rot(Rb, S[9], S[11])
        cos_q = _dot(S[11], S[10])
        _vec(row, W_E2_PARENT, S[9])
        _rot(Rb, S[9], S[11])
        sin_q = _dot(S[11], S[10])
        q = math.atan2(sin_q, cos_q)
        center = row[W_CENTER]
        q += TWO_PI * np.round((center - q) / TWO_PI)
        rate = 0.0
        for c in range(3):
            rate += S[6, c] * (S[2, c] - S[5, c])
        return q, rate, Ra, Rb
    # Slide: k · (P − P_b), P_b = x_b + R_b r_b.
    _vec(row, W_R_PARENT, S[9])
    _rot(Rb, S[9], S[10])
    q = 0.0
    for c in range(3):
        q += S[6, c] * (S[8, c] - S[10, c])
    # Rate: k · (v_a + w_a × ρ_a − v_b − w_b × ρ_b).
    _cross(S[2], S[7], S[10])
    _cross(S[5], S[8], S[11])
    rate = 0.0
    for c in range(3):
        rate += S[6, c] * (S[1, c] + S[10, c] - S[4, c] - S[11, c])
    return q, rate, Ra, Rb


@njit(cache=True)
def _apply(row, n, tau, S, Ra, Rb, force, torque):
    """Add the wrench pair of generalized force ``tau``: force (world), torque (principal)."""
    a, b = int(row[W_BODY]), int(row[W_PARENT])
    f, t = np.empty(3), np.empty(3)
    if row[W_ROTARY] > 0.0:
        for c in range(3):
            torque[a, c] += tau * row[W_K_CHILD + c]
        if b < n:
            for c in range(3):
                torque[b, c] -= tau * row[W_K_PARENT + c]
        return
    for c in range(3):
        f[c] = tau * S[6, c]
        force[a, c] += f[c]
    _cross(S[7], f, t)
    _rot_t(Ra, t, S[9])
    for c in range(3):
        torque[a, c] += S[9, c]
    if b < n:
        for c in range(3):
            force[b, c] -= f[c]
        _cross(S[8], f, t)
        _rot_t(Rb, t, S[9])
        for c in range(3):
            torque[b, c] -= S[9, c]


@njit(cache=True)
def servo_effort(row, q, rate) -> float:
    """Return the servo's generalized force at coordinate q and rate, clamped to its limit."""
    tau = row[W_KP] * (row[W_Q_TARGET] - q) + row[W_KD] * (row[W_V_TARGET] - rate)
    limit = row[W_EFFORT_MAX]
    return min(max(tau, -limit), limit)


@njit(cache=True)
def split(row, q, rate) -> tuple:
    """
    Split the drive at (q, rate) into ``(kick, D, v_eq)``: the kicks' force, the flow's.

    Unsaturated, the kick takes the spring ``kp (q* − q)`` and the flow the rate terms
    (``D = d + kd``); saturated, the kick takes the clamped effort and the flow ``d``.
    """
    kp, kd, d = row[W_KP], row[W_KD], row[W_DAMPING]
    if kp == 0.0 and kd == 0.0:
        return 0.0, d, 0.0
    spring = kp * (row[W_Q_TARGET] - q)
    total = spring + kd * (row[W_V_TARGET] - rate)
    limit = row[W_EFFORT_MAX]
    if abs(total) <= limit:
        return spring, d + kd, kd * row[W_V_TARGET] / (d + kd) if d + kd > 0.0 else 0.0
    return min(max(total, -limit), limit), d, 0.0


@njit(cache=True)
def drive_wrenches(pos, quat, vel, om, wrench, force, torque, acc_force, acc_torque):
    """
    Add every drive's kick force to ``force, torque``, its whole force to ``acc_*``.

    All (n, 3): forces in the world frame, torques in the principal frames; ``om``
    principal. The kicks apply ``force, torque`` (:func:`split`); ``acc_*`` are the
    full accelerations' (the splittings apply the rate terms as their exact flow).
    """
    n = pos.shape[0]
    S = np.empty((12, 3))
    for e in range(wrench.shape[0]):
        row = wrench[e]
        if row[W_KIND] != WRENCH_DRIVE:
            continue
        q, rate, Ra, Rb = _measure(pos, quat, vel, om, row, n, S)
        kick, _, _ = split(row, q, rate)
        if kick != 0.0:
            _apply(row, n, kick, S, Ra, Rb, force, torque)
        full = -row[W_DAMPING] * rate
        if row[W_KP] != 0.0 or row[W_KD] != 0.0:
            full += servo_effort(row, q, rate)
        if full != 0.0:
            _apply(row, n, full, S, Ra, Rb, acc_force, acc_torque)


@njit(cache=True)
def _inverse_inertia(row, n, body, S, Ra, Rb, u, f):
    """
    ``c = j M⁻¹ jᵀ`` along the joint (after :func:`_measure` filled S, Ra, Rb).

    For a prismatic joint, ``u`` and ``f`` get the principal-frame lever vectors
    ``R_aᵀ (ρ_a × k)`` and ``R_bᵀ (ρ_b × k)`` that :func:`_impulse` applies.
    """
    a, b = int(row[W_BODY]), int(row[W_PARENT])
    if row[W_ROTARY] > 0.0:
        inv = 0.0
        for c in range(3):
            inv += row[W_K_CHILD + c] ** 2 / body[a, B_MOMENTS + c]
            if b < n:
                inv += row[W_K_PARENT + c] ** 2 / body[b, B_MOMENTS + c]
        return inv
    t = np.empty(3)
    inv = body[a, B_INV_MASS]
    _cross(S[7], S[6], t)
    _rot_t(Ra, t, u)
    for c in range(3):
        inv += u[c] ** 2 / body[a, B_MOMENTS + c]
    if b < n:
        inv += body[b, B_INV_MASS]
        _cross(S[8], S[6], t)
        _rot_t(Rb, t, f)
        for c in range(3):
            inv += f[c] ** 2 / body[b, B_MOMENTS + c]
    return inv


@njit(cache=True)
def _impulse(row, n, p, body, S, u, f, vel, mom):
    """Apply the generalized impulse p along the joint: +p on the child, −p on the parent."""
    a, b = int(row[W_BODY]), int(row[W_PARENT])
    if row[W_ROTARY] > 0.0:
        for c in range(3):
            mom[a, c] += p * row[W_K_CHILD + c]
            if b < n:
                mom[b, c] -= p * row[W_K_PARENT + c]
        return
    for c in range(3):
        vel[a, c] += p * body[a, B_INV_MASS] * S[6, c]
        mom[a, c] += p * u[c]
        if b < n:
            vel[b, c] -= p * body[b, B_INV_MASS] * S[6, c]
            mom[b, c] -= p * f[c]


@njit(cache=True)
def damping_flow(pos, quat, vel, mom, body, wrench, tau, backward):
    """
    Take the exact flow of each drive's rate terms over ``tau``, joint after joint.

    ``mom`` (n, 3): principal angular momenta; ``vel`` world velocities; in place.
    ``backward``: the joints in reverse order (the second half of a symmetric step).
    """
    n = pos.shape[0]
    S = np.empty((12, 3))
    om = np.empty((n, 3))
    f, u = np.zeros(3), np.zeros(3)
    k = wrench.shape[0]
    for step in range(k):
        e = k - 1 - step if backward else step
        row = wrench[e]
        if row[W_KIND] != WRENCH_DRIVE or (row[W_DAMPING] == 0.0 and row[W_KD] == 0.0):
            continue
        a, b = int(row[W_BODY]), int(row[W_PARENT])
        for i in (a, b):
            if i < n:
                for c in range(3):
                    om[i, c] = mom[i, c] / body[i, B_MOMENTS + c]
        q, rate, Ra, Rb = _measure(pos, quat, vel, om, row, n, S)
        _, D, v_eq = split(row, q, rate)
        if D == 0.0:
            continue
        inv = _inverse_inertia(row, n, body, S, Ra, Rb, u, f)
        p = (v_eq - rate) * (1.0 - math.exp(-D * inv * tau)) / inv
        _impulse(row, n, p, body, S, u, f, vel, mom)
