"""
Compiled kernels: a whole step of bodies that no constraint couples, in one call.

The integrators of :mod:`..integrators` take a step of an unconstrained scene
here, compiled by numba (``@njit(cache=True)``: the first run compiles and
caches to ``__pycache__``; ``NUMBA_DISABLE_JIT=1`` runs the same code as plain
Python for debugging). The arithmetic is that of the methods documented in
:mod:`..integrators`, written as loops over bodies instead of ~1,000 small numpy
calls a step; the results agree with the former numpy code to rounding.

Model arrays (built by :meth:`..dynamics.Dynamics.kernel_model` when the scene
changes, never per step)
---------------------------------------------------------------------------
``body`` : (n, 8)
    ``mass, 1/mass, J1, J2, J3, c_lin, c_ang, anisotropic`` per body (principal
    moments J; damping coefficients summed over the scene's damping effects;
    ``anisotropic`` non-zero if the gyroscopic term is: 1.0 for an asymmetric
    body, ``ROTOR_TOP + a`` for a symmetric top whose distinct axis is ``a``,
    see :data:`.layout.ROTOR_TOP` and :func:`drift`).
``gforce`` : (n, 3)
    N, world: the gravity force ``m g`` of each body (zeros without gravity).
``wrench`` : (k, W_WIDTH)
    The applied wrenches active in this step, one row each: ``body index,
    in_body (1.0 if force and torque are in the principal frame), force (3),
    torque (3), point of application (3, principal frame, from the centre of
    mass)``, kind ``WRENCH_APPLIED``; rows of kind ``WRENCH_DRIVE`` are joint
    drives, which only the constrained steps evaluate (:mod:`.drives`).
``flags`` : int
    Bit ``HAS_POSITION_FORCES``: a kick has something to add (gravity or an
    active wrench); bit ``HAS_DAMPING``: damping acts; ``HAS_DRIVES``: joint drives
    act (wrench rows of kind ``WRENCH_DRIVE``, constrained components only, see
    :mod:`.drives`), ``HAS_DRIVE_DAMPING``: some of them damp.

Work counts (``counts``: the simulation's int64 tally, :class:`.layout.Count`)
---------------------------------------------------------------------------
``RHS`` full right-hand sides, ``KICK`` kick evaluations (position-dependent
wrenches), ``GYRO`` bodies whose gyroscopic term or free-rotor sub-flow was
computed (a symmetric top's exact rotor flow counts one), ``ROT`` orientations
updated by an exponential map (or a rotation about a principal axis), ``FLOW`` exact
damping flows.

The columns of ``body`` and ``wrench`` and the slots of the tables are named in
:mod:`.layout`.
"""

from __future__ import annotations

import math

from numba import njit
import numpy as np

from .layout import (B_ANISOTROPIC, B_C_ANG, B_C_LIN, B_INV_MASS, B_MOMENTS, B_WIDTH, Count,
                     FR_COM_BODY, FR_QUAT_BODY_PRINCIPAL, FR_WIDTH, FREE_TABLE, FT_BODY, FT_COUNTS,
                     FT_FLAGS, FT_FRAMES, FT_GFORCE, FT_KICK, FT_METHOD, FT_N_COUNTS, FT_N_WRENCH,
                     FT_N_WS, FT_OUT, FT_WRENCH, FT_WS, O_ANG_VEL_BODY, O_ANG_VEL_WORLD,
                     O_ORIGIN_VEL_BODY, O_ORIGIN_VEL_WORLD, O_ORIGIN_WORLD, O_QUAT_BODY_WORLD,
                     O_WIDTH, ROTOR_TOP, S_OM, S_POS, S_QUAT, S_VEL, S_WIDTH, W_BODY, W_FORCE,
                     W_IN_BODY, W_KIND, W_POINT, W_TORQUE, W_WIDTH, WRENCH_APPLIED)
from .methods import (Method, ONE_STEP, RK4_A, RK4_B_DENOMINATOR, RK4_B_HAT_NUMERATORS,
                      RK4_B_NUMERATORS, TRIPLE_JUMP)
from .so3 import _matrix, dexpinv, normalize_quaternions, positive_product, quat_exp_multiply
from .views import Pinned, pinned, pinned_int, raw, raw_slice

HAS_POSITION_FORCES, HAS_DAMPING, HAS_DRIVES, HAS_DRIVE_DAMPING = 1, 2, 4, 8
# Bits of free_step's result.
KICK_VALID, FINITE = 1, 2


@njit(cache=True)
def position_wrench(quat: np.ndarray, body: np.ndarray, gforce: np.ndarray,
                    wrench: np.ndarray, force: np.ndarray, torque: np.ndarray) -> None:
    """
    Gravity and applied wrenches: force (n, 3) world and torque (n, 3) principal.

    Overwrites ``force`` and ``torque``.
    """
    force[:] = gforce
    torque[:] = 0.0
    for e in range(wrench.shape[0]):
        if wrench[e, W_KIND] != WRENCH_APPLIED:
            continue   # a joint drive (.drives)
        i = int(wrench[e, W_BODY])
        # (the rotation as nine numbers, quat_matrix's arithmetic: no (3, 3) array a call)
        R00, R01, R02, R10, R11, R12, R20, R21, R22 = _matrix(quat[i, 0], quat[i, 1],
                                                              quat[i, 2], quat[i, 3])
        f0, f1, f2 = wrench[e, W_FORCE], wrench[e, W_FORCE + 1], wrench[e, W_FORCE + 2]
        t0, t1, t2 = wrench[e, W_TORQUE], wrench[e, W_TORQUE + 1], wrench[e, W_TORQUE + 2]
        r0, r1, r2 = wrench[e, W_POINT], wrench[e, W_POINT + 1], wrench[e, W_POINT + 2]
        if wrench[e, W_IN_BODY] != 0.0:
            # Principal-frame force at a principal-frame point: torque τ + r × f.
            force[i, 0] += R00 * f0 + R01 * f1 + R02 * f2
            force[i, 1] += R10 * f0 + R11 * f1 + R12 * f2
            force[i, 2] += R20 * f0 + R21 * f1 + R22 * f2
            torque[i, 0] += t0 + (r1 * f2 - r2 * f1)
            torque[i, 1] += t1 + (r2 * f0 - r0 * f2)
            torque[i, 2] += t2 + (r0 * f1 - r1 * f0)
        else:
            force[i, 0] += f0
            force[i, 1] += f1
            force[i, 2] += f2
            # World torque τ + (R r) × f, then into the principal frame.
            w0 = R00 * r0 + R01 * r1 + R02 * r2
            w1 = R10 * r0 + R11 * r1 + R12 * r2
            w2 = R20 * r0 + R21 * r1 + R22 * r2
            c0 = t0 + (w1 * f2 - w2 * f1)
            c1 = t1 + (w2 * f0 - w0 * f2)
            c2 = t2 + (w0 * f1 - w1 * f0)
            torque[i, 0] += R00 * c0 + R10 * c1 + R20 * c2
            torque[i, 1] += R01 * c0 + R11 * c1 + R21 * c2
            torque[i, 2] += R02 * c0 + R12 * c1 + R22 * c2


@njit(cache=True)
def finish_accelerations(vel: np.ndarray, om: np.ndarray, body: np.ndarray, flags: int,
                         acc: np.ndarray, om_dot: np.ndarray, counts: np.ndarray) -> None:
    """
    Turn force (world) and torque (principal) into accelerations, in place.

    Adds damping and the gyroscopic term ``−Ω × JΩ`` to the position-dependent
    force and torque in ``acc, om_dot`` (n, 3), then divides by mass and moments.
    """
    for i in range(acc.shape[0]):
        if flags & HAS_DAMPING:
            for a in range(3):
                acc[i, a] -= body[i, B_C_LIN] * vel[i, a]
                om_dot[i, a] -= body[i, B_C_ANG] * om[i, a]
        if body[i, B_ANISOTROPIC] != 0.0:
            # The gyroscopic term Ω × JΩ.
            w0, w1, w2 = om[i, 0], om[i, 1], om[i, 2]
            J0, J1, J2 = body[i, B_MOMENTS], body[i, B_MOMENTS + 1], body[i, B_MOMENTS + 2]
            l0, l1, l2 = J0 * w0, J1 * w1, J2 * w2
            om_dot[i, 0] -= w1 * l2 - w2 * l1
            om_dot[i, 1] -= w2 * l0 - w0 * l2
            om_dot[i, 2] -= w0 * l1 - w1 * l0
            counts[Count.GYRO] += 1
        for a in range(3):
            acc[i, a] *= body[i, B_INV_MASS]
            om_dot[i, a] /= body[i, B_MOMENTS + a]


@njit(cache=True)
def accelerations(quat: np.ndarray, vel: np.ndarray, om: np.ndarray, body: np.ndarray,
                  gforce: np.ndarray, wrench: np.ndarray, flags: int, acc: np.ndarray,
                  om_dot: np.ndarray, counts: np.ndarray) -> None:
    """Free (unconstrained) linear acceleration (n, 3) and dΩ/dt (n, 3): every effect."""
    position_wrench(quat, body, gforce, wrench, acc, om_dot)
    counts[Count.RHS] += 1
    finish_accelerations(vel, om, body, flags, acc, om_dot, counts)


@njit(cache=True)
def rkmk4_stage(s: int, h: float, pos: np.ndarray, quat: np.ndarray, vel: np.ndarray,
                om: np.ndarray, kp: np.ndarray, kv: np.ndarray, kw: np.ndarray,
                kr: np.ndarray, p: np.ndarray, q: np.ndarray, v: np.ndarray, w: np.ndarray,
                u: np.ndarray, counts: np.ndarray) -> None:
    """
    Set ``p, q, v, w`` to the state of RKMK4 stage ``s`` (0..3), ``u`` to its rotation.

    ``kp, kv, kw, kr`` (4, n, 3) hold the earlier stages' slopes of position,
    velocity, Ω and the rotation vector (:data:`.methods.RK4_A`: a stage takes the
    slopes of the stage before it only).
    """
    a = h * RK4_A[s][s - 1] if s else 0.0
    n = pos.shape[0]
    for i in range(n):
        for c in range(3):
            if s == 0:
                p[i, c], v[i, c], w[i, c], u[i, c] = pos[i, c], vel[i, c], om[i, c], 0.0
            else:
                p[i, c] = pos[i, c] + a * kp[s - 1, i, c]
                v[i, c] = vel[i, c] + a * kv[s - 1, i, c]
                w[i, c] = om[i, c] + a * kw[s - 1, i, c]
                u[i, c] = a * kr[s - 1, i, c]
        if s == 0:
            for c in range(4):
                q[i, c] = quat[i, c]
        else:
            quat_exp_multiply(quat[i], u[i, 0], u[i, 1], u[i, 2], q[i])
    if s:
        counts[Count.ROT] += n


@njit(cache=True)
def rkmk4_slopes(s: int, v: np.ndarray, w: np.ndarray, u: np.ndarray, kp: np.ndarray,
                 kr: np.ndarray) -> None:
    """Stage ``s``'s position slope (its velocity) and rotation-vector slope."""
    kp[s] = v
    if s:
        dexpinv(u, w, kr[s])
    else:
        kr[s] = w


@njit(cache=True)
def rkmk4_finish(h: float, pos: np.ndarray, quat: np.ndarray, vel: np.ndarray,
                 om: np.ndarray, kp: np.ndarray, kv: np.ndarray, kw: np.ndarray,
                 kr: np.ndarray, u: np.ndarray, counts: np.ndarray) -> None:
    """Combine the four stages (weights :data:`.methods.RK4_B_NUMERATORS`) into the new state."""
    b0 = h * RK4_B_NUMERATORS[0] / RK4_B_DENOMINATOR   # = b3
    b1 = h * RK4_B_NUMERATORS[1] / RK4_B_DENOMINATOR   # = b2
    n = pos.shape[0]
    for i in range(n):
        for c in range(3):
            pos[i, c] += b0 * (kp[0, i, c] + kp[3, i, c]) + b1 * (kp[1, i, c] + kp[2, i, c])
            vel[i, c] += b0 * (kv[0, i, c] + kv[3, i, c]) + b1 * (kv[1, i, c] + kv[2, i, c])
            om[i, c] += b0 * (kw[0, i, c] + kw[3, i, c]) + b1 * (kw[1, i, c] + kw[2, i, c])
            u[i, c] = b0 * (kr[0, i, c] + kr[3, i, c]) + b1 * (kr[1, i, c] + kr[2, i, c])
        quat_exp_multiply(quat[i], u[i, 0], u[i, 1], u[i, 2], quat[i])
    counts[Count.ROT] += n


@njit(cache=True)
def rkmk4_embedded_error(vel: np.ndarray, om: np.ndarray, u: np.ndarray, kp: np.ndarray,
                         kv: np.ndarray, kw: np.ndarray, kr: np.ndarray) -> float:
    """
    Return the embedded third-order estimate of a finished RKMK4 step, per unit time.

    The pair (Hairer, Nørsett & Wanner, Solving ODEs I, II.4): the stages of the
    classical tableau and a fifth, the slopes at the new state (first same as
    last), with weights ``b̂ = (1/6, 1/3, 1/3, 0, 1/6)``
    (:data:`.methods.RK4_B_HAT_NUMERATORS`) give a third-order
    solution; the difference from the fourth-order one is ``h/6 (k4 − k5)``.
    Its largest component over every body's position (m), velocity (m/s), Ω
    (rad/s) and rotation vector (rad), divided by ``h``, is returned: the local
    error per unit time of the third-order solution, an upper bound (by a factor
    of order ``1/h``) of the fourth-order one's, which is kept. ``kv[4], kw[4]``
    must hold the accelerations at the new state ``vel, om``; ``u`` is the step's
    rotation vector (left by :func:`rkmk4_finish`).
    """
    kp[4] = vel
    dexpinv(u, om, kr[4])
    e = 0.0
    for i in range(vel.shape[0]):
        for c in range(3):
            e = max(e, abs(kp[3, i, c] - kp[4, i, c]), abs(kv[3, i, c] - kv[4, i, c]),
                    abs(kw[3, i, c] - kw[4, i, c]), abs(kr[3, i, c] - kr[4, i, c]))
    return e * (RK4_B_NUMERATORS[3] - RK4_B_HAT_NUMERATORS[3]) / RK4_B_DENOMINATOR


@njit(cache=True)
def workspace_size(n: int) -> int:
    """Length of the float64 workspace :func:`free_step` needs for ``n`` bodies."""
    return 76 * n


@njit(cache=True)
def rkmk4_step(pos: np.ndarray, quat: np.ndarray, vel: np.ndarray, om: np.ndarray, h: float,
               body: np.ndarray, gforce: np.ndarray, wrench: np.ndarray, flags: int,
               counts: np.ndarray, err: np.ndarray, ws: np.ndarray) -> None:
    """
    One classical RK4 Munthe-Kaas step of every body, in place.

    With ``err`` of length 1 the step also evaluates the slopes at its end and
    raises ``err[0]`` to the embedded estimate (:func:`rkmk4_embedded_error`);
    with length 0 it does not. ``ws``: a float64 workspace of at least
    :func:`workspace_size` entries (the stages live there: no allocation).
    """
    n = pos.shape[0]
    estimate = err.shape[0] > 0
    slots = 5 if estimate else 4
    size = slots * n * 3
    kp = raw_slice(ws, 0, (slots, n, 3))
    kv = raw_slice(ws, size, (slots, n, 3))
    kw = raw_slice(ws, 2 * size, (slots, n, 3))
    kr = raw_slice(ws, 3 * size, (slots, n, 3))
    o = 4 * size
    p = raw_slice(ws, o, (n, 3))
    v = raw_slice(ws, o + 3 * n, (n, 3))
    w = raw_slice(ws, o + 6 * n, (n, 3))
    u = raw_slice(ws, o + 9 * n, (n, 3))
    q = raw_slice(ws, o + 12 * n, (n, 4))
    for s in range(4):
        rkmk4_stage(s, h, pos, quat, vel, om, kp, kv, kw, kr, p, q, v, w, u, counts)
        accelerations(q, v, w, body, gforce, wrench, flags, kv[s], kw[s], counts)
        rkmk4_slopes(s, v, w, u, kp, kr)
    rkmk4_finish(h, pos, quat, vel, om, kp, kv, kw, kr, u, counts)
    if estimate:
        accelerations(quat, vel, om, body, gforce, wrench, flags, kv[4], kw[4], counts)
        err[0] = max(err[0], rkmk4_embedded_error(vel, om, u, kp, kv, kw, kr))


@njit(cache=True)
def axis_rotation(q: np.ndarray, mom: np.ndarray, axis: int, phi: float) -> None:
    """
    Turn one body by ``phi`` about its principal axis ``axis``, in place.

    ``q ← q ⊗ exp(φ e_axis)`` and the principal-frame momentum turned by ``−φ``
    about the axis (the world momentum is unchanged). Half-angle form: ``cos``
    and ``sin`` of ``φ/2`` once, ``cos φ = 1 − 2 sin²(φ/2)`` and ``sin φ =
    2 sin(φ/2) cos(φ/2)``: two transcendental calls, not four, for the same
    rotation to rounding (a few ulp of each entry, for any φ:
    ``test_rotor_flows.py``).
    """
    half = 0.5 * phi
    ch, sh = math.cos(half), math.sin(half)
    c, s = 1.0 - 2.0 * sh * sh, 2.0 * sh * ch
    j, k = (axis + 1) % 3, (axis + 2) % 3
    lj, lk = mom[j], mom[k]
    mom[j] = c * lj + s * lk
    mom[k] = c * lk - s * lj
    qi, qj, qk, qw = q[axis], q[j], q[k], q[3]
    q[axis] = ch * qi + sh * qw
    q[j] = ch * qj + sh * qk
    q[k] = ch * qk - sh * qj
    q[3] = ch * qw - sh * qi


@njit(cache=True)
def axis_flow(q: np.ndarray, mom: np.ndarray, moment: float, axis: int, dt: float) -> None:
    """
    Exact flow of ``L_axis² / (2 J_axis)`` over ``dt`` for one body, in place.

    A rotation by ``φ = dt L_axis / J_axis`` about the principal axis
    (:func:`axis_rotation`), ``L_axis`` constant.
    """
    axis_rotation(q, mom, axis, dt * mom[axis] / moment)


@njit(cache=True)
def top_flow(q: np.ndarray, mom: np.ndarray, moments: np.ndarray, axis: int,
             dt: float) -> None:
    """
    Exact flow of a symmetric top's free rotor over ``dt`` for one body, in place.

    With ``a = axis`` the distinct principal axis and ``J_s`` the shared moment
    (the mean of the other two, which agree to :data:`..bodies.ISOTROPY_RTOL`), the
    rotor's energy ``T = |L|²/(2 J_s) + L_a² (1/J_a − 1/J_s)/2`` is a sum of two
    parts whose flows commute (``|L|²`` is a Casimir of the rotor's Lie–Poisson
    bracket), so the flow of ``T`` is the composition of theirs, exact:

    * ``|L|²/(2 J_s)``: the isotropic rotor, ``q ← q ⊗ exp(dt L/J_s)`` with the
      principal-frame ``L`` constant (a rotation about ``L`` by ``dt |L|/J_s``);
    * ``L_a² (1/J_a − 1/J_s)/2``: a rotation by ``φ = dt L_a (1/J_a − 1/J_s)``
      about ``e_a`` (:func:`axis_rotation`), which also turns ``L`` by ``−φ``.

    The end is ``q ⊗ exp(dt L₀/J_s) ⊗ exp(φ e_a)``, ``L = Rot(e_a, −φ) L₀``:
    ``T``, ``L_a`` and ``|L|`` are conserved to rounding, and the flow is
    symplectic. One ``sqrt`` and four transcendental calls, against twenty for
    the five flows of the 1-2-3-2-1 splitting.
    """
    j, k = (axis + 1) % 3, (axis + 2) % 3
    ja, js = moments[axis], 0.5 * (moments[j] + moments[k])
    g = dt / js
    quat_exp_multiply(q, g * mom[0], g * mom[1], g * mom[2], q)
    axis_rotation(q, mom, axis, dt * mom[axis] * ((js - ja) / (ja * js)))


#: SHAKE's bound on a symmetric top's cone angle ``θ`` per drift (:func:`top_angle`).
#: The top's flow answers a change ``δL`` of its start momentum by a world-frame
#: turn ``(h/J_s) R J_l(u) δL`` (plus ``δφ e_a``), and across ``u = h L/J_s``
#: ``J_l(u) = (2 sin(θ/2)/θ) Rot(û, θ/2)``: a gain ``2 sin(θ/2)/θ`` turned by ``θ/2``,
#: whose symmetric part has the smallest eigenvalue ``sin θ/θ``. SHAKE's Newton
#: matrix ``G_E D M⁻¹ G_Sᵀ`` is ``G M⁻¹ Gᵀ`` (positive definite) at ``θ → 0`` and keeps
#: a positive definite symmetric part while every body's does: below ``θ = π``,
#: with the margin ``sin θ/θ ≥ 2/π`` (a response at most 1.6 times softer, turned
#: by at most 45°) up to ``π/2``. Beyond, the exact flow's derivative degenerates
#: (``sin θ/θ`` is 0 at ``π``: a rod turned by π ends along the same line whatever
#: the tilt of its turn; the gain is 0 at ``2π``: a full cone), and SHAKE's
#: Newton steps overshoot without bound. The default step control keeps ``θ ≤
#: 0.25 √6 = 0.61`` (``h max|Ω_k| ≤ 0.25`` and ``J_a ≤ 2 J_s``); larger ``θ`` come
#: with it off or capped, or from a diverging iterate.
TOP_SHAKE_ANGLE = 0.5 * math.pi


@njit(cache=True, inline='always')
def top_angle(mom: np.ndarray, moments: np.ndarray, axis: int, tau: float) -> float:
    """
    Return ``θ = |tau| |L| / J_s``, the angle a top's flow over ``tau`` turns it about ``L``.

    ``|L|`` is conserved by the flow (and by the 1-2-3-2-1 splitting), so ``θ`` is
    the same at a drift's start and end: a choice made by it is time-reversible.
    """
    j, k = (axis + 1) % 3, (axis + 2) % 3
    norm = math.sqrt(mom[0] * mom[0] + mom[1] * mom[1] + mom[2] * mom[2])
    return abs(tau) * norm / (0.5 * (moments[j] + moments[k]))


@njit(cache=True)
def drift(pos: np.ndarray, quat: np.ndarray, vel: np.ndarray, mom: np.ndarray,
          body: np.ndarray, tau: float, symmetric: bool, counts: np.ndarray,
          max_top_angle: float = math.inf) -> None:
    """
    Free flight ``x += tau v`` and the free rotor of every body, in place.

    The rotor by the column ``anisotropic`` of ``body`` (:data:`.layout.ROTOR_TOP`):
    an isotropic body (0) turns by ``exp(tau Ω)``, exact; a symmetric top (its
    distinct axis ``a`` coded ``ROTOR_TOP + a``) by its exact flow
    (:func:`top_flow`, whatever ``symmetric``) while its cone angle
    (:func:`top_angle`) is at most ``max_top_angle`` (SHAKE passes
    :data:`TOP_SHAKE_ANGLE`), else as an asymmetric body; an asymmetric body (1) by
    the exact flows about its principal axes, 1-2-3-2-1 with half steps on the
    outer ones if ``symmetric`` (Strang, order 2), 1-2-3 otherwise (order 1).
    """
    n = pos.shape[0]
    for i in range(n):
        for c in range(3):
            pos[i, c] += tau * vel[i, c]
        code = body[i, B_ANISOTROPIC]
        moments = body[i, B_MOMENTS:B_MOMENTS + 3]
        if code >= ROTOR_TOP and top_angle(mom[i], moments, int(code - ROTOR_TOP),
                                           tau) <= max_top_angle:
            top_flow(quat[i], mom[i], moments, int(code - ROTOR_TOP), tau)
            counts[Count.GYRO] += 1
            counts[Count.ROT] += 2
        elif code != 0.0:
            if symmetric:
                axis_flow(quat[i], mom[i], body[i, B_MOMENTS], 0, 0.5 * tau)
                axis_flow(quat[i], mom[i], body[i, B_MOMENTS + 1], 1, 0.5 * tau)
                axis_flow(quat[i], mom[i], body[i, B_MOMENTS + 2], 2, tau)
                axis_flow(quat[i], mom[i], body[i, B_MOMENTS + 1], 1, 0.5 * tau)
                axis_flow(quat[i], mom[i], body[i, B_MOMENTS], 0, 0.5 * tau)
                counts[Count.GYRO] += 5
                counts[Count.ROT] += 5
            else:
                for a in range(3):
                    axis_flow(quat[i], mom[i], body[i, B_MOMENTS + a], a, tau)
                counts[Count.GYRO] += 3
                counts[Count.ROT] += 3
        else:
            # Isotropic: Ω is constant during the drift and exp is exact.
            quat_exp_multiply(quat[i], tau * mom[i, 0] / body[i, B_MOMENTS],
                              tau * mom[i, 1] / body[i, B_MOMENTS + 1],
                              tau * mom[i, 2] / body[i, B_MOMENTS + 2],
                              quat[i])
            counts[Count.ROT] += 1


@njit(cache=True)
def damping_flow(vel: np.ndarray, mom: np.ndarray, body: np.ndarray, tau: float,
                 counts: np.ndarray) -> None:
    """Exact flow of linear damping over ``tau``, in place (velocities and momenta)."""
    for i in range(vel.shape[0]):
        fv = math.exp(-body[i, B_C_LIN] * body[i, B_INV_MASS] * tau)
        for a in range(3):
            vel[i, a] *= fv
            mom[i, a] *= math.exp(-body[i, B_C_ANG] * tau / body[i, B_MOMENTS + a])
    counts[Count.FLOW] += 1


@njit(cache=True)
def splitting_step(method: int, pos: np.ndarray, quat: np.ndarray, vel: np.ndarray,
                   om: np.ndarray, dt: float, body: np.ndarray, gforce: np.ndarray,
                   wrench: np.ndarray, flags: int, kick: np.ndarray, kick_valid: bool,
                   counts: np.ndarray, ws: np.ndarray) -> bool:
    """
    One step of symplectic Euler or a Lie–Poisson splitting, in place.

    ``kick`` (n, 6: force world, torque principal) holds the last kick's
    wrench; ``kick_valid`` says it belongs to the configuration ``pos, quat`` it
    starts from (first same as last). Returns whether ``kick`` is valid for the
    configuration the step ends at. ``ws``: workspace (:func:`workspace_size`).
    """
    n = pos.shape[0]
    symmetric = method != Method.SYMPLECTIC_EULER
    weights = TRIPLE_JUMP if method == Method.LIE_POISSON4 else ONE_STEP
    n_sub = 3 if method == Method.LIE_POISSON4 else 1
    mom = raw_slice(ws, 0, (n, 3))
    for i in range(n):
        for a in range(3):
            mom[i, a] = om[i, a] * body[i, B_MOMENTS + a]
    force = kick[:, :3]
    torque = kick[:, 3:]
    forces = flags & HAS_POSITION_FORCES
    damping = flags & HAS_DAMPING
    for sub in range(n_sub):
        h = weights[sub] * dt
        first = 0.5 * h if symmetric else h
        for half in range(2 if symmetric else 1):
            tau = first if half == 0 else 0.5 * h
            if half == 1:
                drift(pos, quat, vel, mom, body, h, symmetric, counts)
                kick_valid = False
            if damping and half == 0:
                damping_flow(vel, mom, body, tau, counts)
            if forces:
                if not kick_valid:
                    position_wrench(quat, body, gforce, wrench, force, torque)
                    counts[Count.KICK] += 1
                    kick_valid = True
                for i in range(n):
                    for a in range(3):
                        vel[i, a] += tau * body[i, B_INV_MASS] * force[i, a]
                        mom[i, a] += tau * torque[i, a]
            if damping and half == 1:
                damping_flow(vel, mom, body, tau, counts)
        if not symmetric:
            drift(pos, quat, vel, mom, body, h, symmetric, counts)
            kick_valid = False
    for i in range(n):
        for a in range(3):
            om[i, a] = mom[i, a] / body[i, B_MOMENTS + a]
    return kick_valid


@njit(cache=True)
def free_step(method: int, pos: np.ndarray, quat: np.ndarray, vel: np.ndarray,
              om: np.ndarray, dt: float, body: np.ndarray, gforce: np.ndarray,
              wrench: np.ndarray, flags: int, kick: np.ndarray, kick_valid: bool,
              counts: np.ndarray, err: np.ndarray, ws: np.ndarray, frames: np.ndarray,
              out: np.ndarray) -> int:
    """
    One step of ``method`` for bodies no constraint couples; the arrays are updated.

    Parameters
    ----------
    method : int
        ``SYMPLECTIC_EULER``, ``LIE_POISSON2``, ``LIE_POISSON4`` or ``RKMK4``.
    pos, vel : ndarray, shape (n, 3)
        Centre-of-mass positions and velocities, world frame (m, m/s).
    quat : ndarray, shape (n, 4)
        Principal-frame orientations (xyzw).
    om : ndarray, shape (n, 3)
        Principal-frame angular velocities Ω (rad/s).
    dt : float
        s.
    body, gforce, wrench, flags
        The model (see the module docstring).
    kick : ndarray, shape (n, 6)
        The splittings' last kick (first same as last); unused by ``RKMK4``.
    kick_valid : bool
        ``kick`` was evaluated at ``pos, quat``.
    counts : ndarray of int64, shape (5,) or longer
        The work tally (its first five slots), added to.
    err : ndarray, shape (1,) or (0,)
        ``RKMK4`` with length 1: ``err[0]`` is raised to the step's embedded
        error estimate per unit time (:func:`rkmk4_embedded_error`); ignored by
        the splittings.
    ws : ndarray of float64
        Workspace of at least :func:`workspace_size` entries (overwritten).
    frames, out : ndarray, shapes (n, 7) and (n, 19) or (0, 19)
        With ``n`` rows, ``out`` gets the :func:`outputs` of the new state.

    Returns
    -------
    int
        Bit ``KICK_VALID``: ``kick`` is valid for the new configuration; bit
        ``FINITE``: every entry of the new state is finite.

    """
    if ws.shape[0] < workspace_size(pos.shape[0]):
        raise ValueError('free_step: ws is smaller than workspace_size(n)')
    if method == Method.RKMK4:
        # Its many small calls pass the arrays on: views without reference counts.
        pos, quat, vel, om = raw(pos), raw(quat), raw(vel), raw(om)
        rkmk4_step(pos, quat, vel, om, dt, raw(body), raw(gforce), raw(wrench), flags,
                   raw(counts), raw(err), raw(ws))
        valid = False
    else:
        valid = splitting_step(method, pos, quat, vel, om, dt, body, gforce, wrench, flags,
                               kick, kick_valid, counts, ws)
    normalize_quaternions(quat)
    if out.shape[0]:
        outputs(pos, quat, vel, om, frames, out)
    return (KICK_VALID if valid else 0) | (FINITE if all_finite(pos, quat, vel, om) else 0)


def free_table(method: int, model: tuple, kick: np.ndarray, counts: np.ndarray,
               ws: np.ndarray, frames: np.ndarray, out: np.ndarray) -> Pinned:
    """
    Pin the arrays of :func:`pinned_free_step` (keyed on ``model``).

    ``model`` is ``(body, gforce, wrench, flags)``; the other arguments are those
    of :func:`free_step`, ``out`` with all ``n`` rows.
    """
    body, gforce, wrench, flags = model
    return FREE_TABLE.pin(model, body=body, gforce=gforce, wrench=wrench, kick=kick,
                          counts=counts, ws=ws, frames=frames, out=out, n_wrench=len(wrench),
                          flags=flags, method=method, n_counts=len(counts), n_ws=len(ws))


@njit(cache=True)
def state_parts(y: np.ndarray) -> tuple:
    """
    Return ``pos, quat, vel, om`` of a state's buffer ``y`` (13 n) as :func:`raw` views.

    The layout of :class:`..bodies.State`: positions (n, 3), quaternions (n, 4),
    velocities (n, 3), Ω (n, 3), one after the other.
    """
    n = y.shape[0] // S_WIDTH
    return (raw_slice(y, S_POS * n, (n, 3)), raw_slice(y, S_QUAT * n, (n, 4)),
            raw_slice(y, S_VEL * n, (n, 3)), raw_slice(y, S_OM * n, (n, 3)))


@njit(cache=True)
def pinned_free_step(y: np.ndarray, dt: float, kick_valid: bool, with_outputs: bool,
                     err: np.ndarray, table: np.ndarray) -> int:
    """
    :func:`free_step` of the state buffer ``y`` (:func:`state_parts`), in place.

    Its other arrays are in the table of :func:`free_table`. ``with_outputs``:
    the outputs of the new state are written to the table's ``out``. Returns
    what :func:`free_step` returns.
    """
    pos, quat, vel, om = state_parts(y)
    n = pos.shape[0]
    t = table
    return free_step(t[FT_METHOD], pos, quat, vel, om, dt, pinned(t, FT_BODY, (n, B_WIDTH)),
                     pinned(t, FT_GFORCE, (n, 3)), pinned(t, FT_WRENCH, (t[FT_N_WRENCH], W_WIDTH)),
                     t[FT_FLAGS], pinned(t, FT_KICK, (n, 6)), kick_valid,
                     pinned_int(t, FT_COUNTS, (t[FT_N_COUNTS],)), err,
                     pinned(t, FT_WS, (t[FT_N_WS],)), pinned(t, FT_FRAMES, (n, FR_WIDTH)),
                     pinned(t, FT_OUT, (n if with_outputs else 0, O_WIDTH)))


@njit(cache=True)
def all_finite(pos: np.ndarray, quat: np.ndarray, vel: np.ndarray, om: np.ndarray) -> bool:
    """Tell whether every entry of the four state arrays is finite."""
    for i in range(pos.shape[0]):
        for c in range(3):
            if not (math.isfinite(pos[i, c]) and math.isfinite(vel[i, c])
                    and math.isfinite(om[i, c])):
                return False
        for c in range(4):
            if not math.isfinite(quat[i, c]):
                return False
    return True


@njit(cache=True)
def outputs(pos: np.ndarray, quat: np.ndarray, vel: np.ndarray, om: np.ndarray,
            frames: np.ndarray, out: np.ndarray) -> None:
    """
    Poses and twists in the user's body frames, for every body.

    Parameters
    ----------
    pos, vel, om, quat
        The state (see :func:`free_step`).
    frames : ndarray, shape (n, FR_WIDTH)
        Principal frame in the body frame (xyzw), then the centre of mass in the
        body frame (m): :data:`.layout.FRAME`.
    out : ndarray, shape (n, O_WIDTH)
        Written (:data:`.layout.OUTPUT`): body-origin position (3, world), body
        orientation (4, xyzw, w >= 0), origin velocity (3, world), angular
        velocity (3, world), origin velocity (3, body), angular velocity (3, body).

    """
    fq, fc = FR_QUAT_BODY_PRINCIPAL, FR_COM_BODY
    op, oq, ov, ow = O_ORIGIN_WORLD, O_QUAT_BODY_WORLD, O_ORIGIN_VEL_WORLD, O_ANG_VEL_WORLD
    ovb, owb = O_ORIGIN_VEL_BODY, O_ANG_VEL_BODY
    for i in range(pos.shape[0]):
        # q_wb = q_wp ⊗ conj(q_bp), sign fixed to w >= 0.
        ax, ay, az, aw = quat[i, 0], quat[i, 1], quat[i, 2], quat[i, 3]
        q0, q1, q2, q3 = positive_product(ax, ay, az, aw, -frames[i, fq], -frames[i, fq + 1],
                                          -frames[i, fq + 2], frames[i, fq + 3])
        out[i, oq], out[i, oq + 1], out[i, oq + 2], out[i, oq + 3] = q0, q1, q2, q3
        r00, r01, r02, r10, r11, r12, r20, r21, r22 = _matrix(q0, q1, q2, q3)
        c0, c1, c2 = frames[i, fc], frames[i, fc + 1], frames[i, fc + 2]
        f0 = r00 * c0 + r01 * c1 + r02 * c2
        f1 = r10 * c0 + r11 * c1 + r12 * c2
        f2 = r20 * c0 + r21 * c1 + r22 * c2
        out[i, op] = pos[i, 0] - f0
        out[i, op + 1] = pos[i, 1] - f1
        out[i, op + 2] = pos[i, 2] - f2
        # World angular velocity ω = R_wp Ω; origin velocity v − ω × offset.
        p00, p01, p02, p10, p11, p12, p20, p21, p22 = _matrix(ax, ay, az, aw)
        o0, o1, o2 = om[i, 0], om[i, 1], om[i, 2]
        w0 = p00 * o0 + p01 * o1 + p02 * o2
        w1 = p10 * o0 + p11 * o1 + p12 * o2
        w2 = p20 * o0 + p21 * o1 + p22 * o2
        v0 = vel[i, 0] + (w1 * -f2 - w2 * -f1)
        v1 = vel[i, 1] + (w2 * -f0 - w0 * -f2)
        v2 = vel[i, 2] + (w0 * -f1 - w1 * -f0)
        out[i, ov], out[i, ov + 1], out[i, ov + 2] = v0, v1, v2
        out[i, ow], out[i, ow + 1], out[i, ow + 2] = w0, w1, w2
        out[i, ovb] = r00 * v0 + r10 * v1 + r20 * v2
        out[i, ovb + 1] = r01 * v0 + r11 * v1 + r21 * v2
        out[i, ovb + 2] = r02 * v0 + r12 * v1 + r22 * v2
        out[i, owb] = r00 * w0 + r10 * w1 + r20 * w2
        out[i, owb + 1] = r01 * w0 + r11 * w1 + r21 * w2
        out[i, owb + 2] = r02 * w0 + r12 * w1 + r22 * w2


@njit(cache=True)
def state_outputs(y: np.ndarray, frames: np.ndarray, out: np.ndarray) -> None:
    """:func:`outputs` of the state buffer ``y`` (:func:`state_parts`)."""
    pos, quat, vel, om = state_parts(y)
    outputs(pos, quat, vel, om, frames, out)


@njit(cache=True)
def state_distance(pos_a: np.ndarray, quat_a: np.ndarray, vel_a: np.ndarray,
                   om_a: np.ndarray, pos_b: np.ndarray, quat_b: np.ndarray,
                   vel_b: np.ndarray, om_b: np.ndarray) -> float:
    """
    Largest difference between two states of the same bodies (see ``accuracy.state_distance``).

    Position, velocity and Ω component by component; orientation as the angle
    of ``q_a⁻¹ ⊗ q_b`` from atan2 (arccos of the dot product would floor at
    about 3e-8 rad: it is ill-conditioned near 1).
    """
    d = 0.0
    for i in range(pos_a.shape[0]):
        for c in range(3):
            d = max(d, abs(pos_a[i, c] - pos_b[i, c]), abs(vel_a[i, c] - vel_b[i, c]),
                    abs(om_a[i, c] - om_b[i, c]))
        ax, ay, az, aw = quat_a[i, 0], quat_a[i, 1], quat_a[i, 2], quat_a[i, 3]
        bx, by, bz, bw = quat_b[i, 0], quat_b[i, 1], quat_b[i, 2], quat_b[i, 3]
        # conj(a) ⊗ b (xyzw)
        x = aw * bx - ax * bw - ay * bz + az * by
        y = aw * by - ay * bw - az * bx + ax * bz
        z = aw * bz - az * bw - ax * by + ay * bx
        w = aw * bw + ax * bx + ay * by + az * bz
        d = max(d, 2.0 * math.atan2(math.sqrt(x * x + y * y + z * z), abs(w)))
    return d
