"""
High-precision references, independent of the integrators they check.

* :func:`dop853_trajectory`: the equations of motion of a :class:`Simulation`
  integrated by scipy's DOP853 at tight tolerances, in another formulation
  (quaternion kinematics ``dq/dt = q ⊗ (Ω, 0) / 2``, no exponential map, no
  splitting), through the simulation's right-hand side and, for constraints,
  :func:`constrained_accelerations`.
* :func:`constrained_accelerations`: the labelled oracle of the constraint
  solve: the Baumgarte-stabilized multipliers by a dense pseudo-inverse, the
  naive way, as independent as possible of the compiled solve the steps use.
* :func:`free_body_reference`: the torque-free Euler equations alone.
* :func:`intermediate_axis_period`: the analytic period of the torque-free
  asymmetric body (Landau & Lifshitz, Mechanics, §37), the period of the
  tennis-racket flip.
* :func:`symmetric_body_omega`: the closed-form torque-free symmetric body
  (Landau & Lifshitz §33).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
from scipy.integrate import solve_ivp
from scipy.special import ellipk

from . import rotation as so3
from .bodies import State


def _quat_rate(q: np.ndarray, omega: np.ndarray) -> np.ndarray:
    """``dq/dt = q ⊗ (Ω, 0) / 2`` for (n, 4) quaternions and (n, 3) body rates."""
    pure = np.concatenate([omega, np.zeros((len(omega), 1))], axis=1)
    return 0.5 * so3.quat_multiply(q, pure)


def dop853_trajectory(sim, t_eval: Sequence[float], rtol: float = 1e-12,
                      atol: float = 1e-12) -> list:
    """
    Integrate ``sim``'s equations of motion from its current state with DOP853.

    Parameters
    ----------
    sim : Simulation
        Its dynamics (bodies, effects; constraints through their Baumgarte-
        stabilized accelerations) define the right-hand side; it is not stepped.
    t_eval : sequence of float
        Absolute times (s), after ``sim.time``.
    rtol, atol : float
        DOP853 tolerances.

    Returns
    -------
    list of State
        The reference states at ``t_eval`` (quaternions normalized).

    """
    s0 = sim.state
    n = len(sim.bodies)
    dyn = sim.dynamics

    def unpack(y):
        return (y[:3 * n].reshape(n, 3), y[3 * n:7 * n].reshape(n, 4),
                y[7 * n:10 * n].reshape(n, 3), y[10 * n:].reshape(n, 3))

    def rhs(t, y):
        pos, quat, vel, om = unpack(y)
        qn = so3.quat_normalize(quat)
        acc, om_dot = constrained_accelerations(dyn, t, pos, qn, vel, om)[:2]
        return np.concatenate([vel.ravel(), _quat_rate(quat, om).ravel(), acc.ravel(),
                               om_dot.ravel()])

    y0 = np.concatenate([s0.pos_com_world.ravel(), s0.quat_principal_world.ravel(),
                         s0.vel_com_world.ravel(), s0.ang_vel_principal.ravel()])
    t_eval = np.asarray(t_eval, dtype=float)
    sol = solve_ivp(rhs, (s0.time, t_eval[-1]), y0, method='DOP853', t_eval=t_eval,
                    rtol=rtol, atol=atol)
    if not sol.success:
        raise RuntimeError(f'DOP853 reference failed: {sol.message}')
    out = []
    for k, t in enumerate(sol.t):
        pos, quat, vel, om = unpack(sol.y[:, k])
        out.append(State(float(t), pos.copy(), so3.quat_normalize(quat), vel.copy(), om.copy()))
    return out


def constrained_accelerations(dyn, time: float, pos: np.ndarray, quat: np.ndarray,
                              vel: np.ndarray, omega: np.ndarray) -> tuple:
    """
    Accelerations of every body with the constraints' forces: the naive dense oracle.

    ``λ = (G M⁻¹ Gᵀ)⁺ (G a_u + γ + 2 ω Φ̇ + ω² Φ)`` by ``numpy.linalg.pinv`` of the
    assembled matrix (the minimum-norm multipliers when rows are redundant),
    ``a = a_u − M⁻¹ Gᵀ λ``, with ``a_u`` the free accelerations of
    :meth:`.dynamics.Dynamics.accelerations` and ``ω`` the solver's Baumgarte
    rate. Cubic in the rows: for references and tests only.

    Parameters
    ----------
    dyn : Dynamics
        The bodies, effects and constraint solver.
    time : float
        s.
    pos, quat, vel, omega : ndarray
        The state: (n, 3) world, (n, 4) xyzw, (n, 3) world, (n, 3) principal.

    Returns
    -------
    acc : ndarray, shape (n, 3)
        m/s², world.
    omega_dot : ndarray, shape (n, 3)
        dΩ/dt, rad/s², principal frames.
    lam : ndarray, shape (m,)
        The multipliers (empty without constraints).

    """
    acc, om_dot = dyn.accelerations(time, pos, quat, vel, omega)
    if not dyn.constrained:
        return acc, om_dot, np.zeros(0)
    solver = dyn.solver
    ev = solver.constraints.evaluate(pos, quat, vel, omega)
    G = ev.jacobian.toarray()
    minv = np.concatenate([np.repeat(dyn.bodies.inv_mass[:, None], 3, axis=1),
                           1.0 / dyn.bodies.moments], axis=1).ravel()
    w = solver.omega
    a6 = np.concatenate([acc, om_dot], axis=1)
    rhs = G @ a6.ravel() + ev.gamma + 2.0 * w * ev.phi_dot + w * w * ev.phi
    lam = np.linalg.pinv((G * minv) @ G.T, rcond=1e-13) @ rhs   # by SVD (eigh lost 1e-6 here)
    a6 = a6 - (minv * (G.T @ lam)).reshape(-1, 6)
    return a6[:, :3], a6[:, 3:], lam


def free_body_reference(moments: Sequence[float], omega0: Sequence[float],
                        quat0: Sequence[float], t_eval: Sequence[float],
                        rtol: float = 1e-12, atol: float = 1e-12) -> tuple:
    """
    Torque-free rigid body by DOP853: Euler's equations and quaternion kinematics.

    Parameters
    ----------
    moments : sequence of float, shape (3,)
        Principal moments J.
    omega0 : sequence of float, shape (3,)
        Initial Ω in the principal frame (rad/s).
    quat0 : sequence of float, shape (4,)
        Initial principal-frame orientation (x, y, z, w).
    t_eval : sequence of float
        Times (s) from 0.
    rtol, atol : float
        DOP853 tolerances.

    Returns
    -------
    omega : ndarray, shape (len(t_eval), 3)
    quat : ndarray, shape (len(t_eval), 4)

    """
    J = np.asarray(moments, dtype=float)

    def rhs(t, y):
        w, q = y[:3], y[3:]
        w_dot = np.array([(J[1] - J[2]) * w[1] * w[2] / J[0],
                          (J[2] - J[0]) * w[2] * w[0] / J[1],
                          (J[0] - J[1]) * w[0] * w[1] / J[2]])
        return np.concatenate([w_dot, _quat_rate(q[None], w[None])[0]])

    t_eval = np.asarray(t_eval, dtype=float)
    y0 = np.concatenate([np.asarray(omega0, dtype=float), np.asarray(quat0, dtype=float)])
    sol = solve_ivp(rhs, (0.0, t_eval[-1]), y0, method='DOP853', t_eval=t_eval,
                    rtol=rtol, atol=atol)
    if not sol.success:
        raise RuntimeError(f'DOP853 reference failed: {sol.message}')
    return sol.y[:3].T, so3.quat_normalize(sol.y[3:].T)


def intermediate_axis_period(moments: Sequence[float], omega0: Sequence[float]) -> float:
    """
    Period (s) of Ω(t) of a torque-free asymmetric body (Landau & Lifshitz §37).

    With ``I1 < I2 < I3``, energy ``E`` and ``M = |L|``: for ``M² > 2 E I2``
    the period is ``4 K(k²) sqrt(I1 I2 I3 / ((I3 − I2)(M² − 2 E I1)))`` with
    ``k² = (I2 − I1)(2 E I3 − M²) / ((I3 − I2)(M² − 2 E I1))``; for
    ``M² < 2 E I2`` the indices 1 and 3 exchange roles. Near the intermediate
    axis this is the period of the tennis-racket flip (one flip and back).

    Parameters
    ----------
    moments : sequence of float, shape (3,)
        Principal moments, strictly increasing.
    omega0 : sequence of float, shape (3,)
        Ω in the principal frame at any time (rad/s).

    Returns
    -------
    float

    """
    i1, i2, i3 = (float(v) for v in moments)
    if not i1 < i2 < i3:
        raise ValueError('moments must be strictly increasing')
    w = np.asarray(omega0, dtype=float)
    two_e = float(np.dot(moments, w * w))
    m2 = float(np.sum((np.asarray(moments) * w) ** 2))
    if m2 < two_e * i2:
        i1, i3 = i3, i1
    k2 = (i2 - i1) * (two_e * i3 - m2) / ((i3 - i2) * (m2 - two_e * i1))
    rate = np.sqrt((i3 - i2) * (m2 - two_e * i1) / (i1 * i2 * i3))
    return float(4.0 * ellipk(k2) / rate)


def symmetric_body_omega(moments: Sequence[float], omega0: Sequence[float],
                         t: np.ndarray) -> np.ndarray:
    """
    Ω(t) (principal frame) of a torque-free symmetric body, ``J1 = J2`` (L&L §33).

    ``Ω3`` is constant and ``(Ω1, Ω2)`` rotates at ``λ = (J3 − J1) Ω3 / J1``:
    ``Ω1 + i Ω2 = (Ω1(0) + i Ω2(0)) exp(i λ t)``.

    Parameters
    ----------
    moments : sequence of float, shape (3,)
        ``(J1, J1, J3)``.
    omega0 : sequence of float, shape (3,)
        Initial Ω (rad/s).
    t : ndarray, shape (k,)
        Times (s).

    Returns
    -------
    ndarray, shape (k, 3)

    """
    j1, j2, j3 = (float(v) for v in moments)
    if j1 != j2:
        raise ValueError('a symmetric body needs J1 == J2')
    w = np.asarray(omega0, dtype=float)
    t = np.asarray(t, dtype=float)
    lam = (j3 - j1) * w[2] / j1
    z = (w[0] + 1j * w[1]) * np.exp(1j * lam * t)
    return np.stack([z.real, z.imag, np.full_like(t, w[2])], axis=1)
