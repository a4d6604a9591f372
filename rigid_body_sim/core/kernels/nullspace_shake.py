"""
Prototype: SHAKE's unsymmetric Newton solve ``G_E D M⁻¹ G_Sᵀ λ = rhs`` in inertia form.

The unsymmetric counterpart of :mod:`.nullspace_solve` (issue 19,
``../shared/research/chain-perf.md`` option 1 and Appendix A, "SHAKE
(unsymmetric)"), not yet a path of the step. It solves the system that
:func:`.constrained_step._shake` factors with ``tree_factor(Ga2, Gb2, GaS, GbS,
minv6, 0, ..., symmetric=False)``, ``G2 = G_E diag(I, J_r)``: ``G_E`` the rows'
blocks at the end configuration, ``G_S`` at the start (the same rows, so the same
joints), ``M⁻¹`` the diagonal ``minv6`` and per body ``D_b = diag(I, J_r,b)``,
``J_r,b`` a general 3 x 3 (:func:`.constrained_step._rotor_jacobians`). The scope,
the joints and the conventions are those of :mod:`.nullspace_solve` (read its
docstring first); its :func:`~.nullspace_solve.nullspace_structure` gives the
joints, from either configuration's rows.

Formulation
-----------
In world axes at each centre of mass a block ``(g_v, g_Ω)`` is ``w = (g_v, R g_Ω)``
with the rotation of its configuration, so a body's term of ``A`` is ``w_Eᵀ diag(I /
m, R_E J_r J⁻¹ R_Sᵀ) w_S`` and ``A = W_E K⁻¹ W_Sᵀ`` with the per-body "inertia" ``K
= diag(m I, R_S J J_r⁻¹ R_Eᵀ)`` (``M diag(I, J_r⁻¹)`` in the principal axes). With
``K a = W_Sᵀ λ`` and ``W_E a = rhs``, ``λ = A⁻¹ rhs``: the accelerations obey the end
rows and the joint forces act along the start rows. So per joint ``x`` (child
``c``), everything from :mod:`.nullspace_solve` is read twice: from the end rows
the shift ``X_E``, the motion subspace ``S_E`` and the particular solution ``g_E``
(``W_E,cᵀ g_E = c``, with the end rows' dual bases); from the start rows ``X_S``,
``S_S`` and the dual bases that read ``λ`` from the joint wrench.

The recursion is that of the symmetric one with the sides kept apart. The joint
wrench on the child is ``F = I^A_c a_c + p_c = W_S,c λ`` (its children's joint forces
on it, ``−X_Sᵀ F_child``, are in ``I^A_c`` and ``p_c``), with ``a_c = y + g_E + S_E
q`` and ``y = X_E a_p``; ``S_Sᵀ W_S,c = 0`` gives ``D q = −S_Sᵀ (I^A_c y + z)``, ``z
= p_c + I^A_c g_E``, ``D = S_Sᵀ I^A_c S_E``. Hence, with ``U_E = I^A_c S_E``, ``U_S
= I^A_cᵀ S_S``, ``q₀ = −D⁻¹ S_Sᵀ z``:

* factor: ``I^A_c = K_c + Σ_children X_Sᵀ Ia X_E``, ``Ia = I^A_c − U_E D⁻¹ U_Sᵀ``
  (so that ``F = Ia y + p′``);
* up: ``p′ = z + U_E q₀``, ``p_p += X_Sᵀ p′``;
* down: ``q = q₀ − D⁻¹ U_Sᵀ y``, ``a_c = y + g_E + S_E q``, ``F = I^A_c a_c + p_c``,
  ``λ`` from ``F`` with the start rows' dual bases (as in :mod:`.nullspace_solve`).

A free-floating tree's root (a ``FREE`` entry, :mod:`.nullspace_solve`) has a general
``I^A_root`` (not symmetric): the factor overwrites it with its LU factors, with
partial pivoting (the pivot rows in ``JD`` of the entry), and the down pass starts from
``a_root = −(I^A_root)⁻¹ p_root``.

A distance row (a ``DISTANCE`` entry) is eliminated by the range-space step of
:mod:`.nullspace_solve` with the sides kept apart: the row's force on the child is
``w_S,c λ`` and the child obeys the end row, so block elimination of ``[[I^A_c,
−w_S,c], [w_E,cᵀ, 0]]`` gives ``a_c = a₀ + h λ``, ``a₀ = −(I^A_c)⁻¹ p_c``, ``h =
(I^A_c)⁻¹ w_S,c``, ``s = w_E,cᵀ h``, ``τ = c − w_E,cᵀ a₀``, ``λ = (τ − w_E,pᵀ a_p) / s``;
the parent receives ``I^A_p += w_S,p w_E,pᵀ / s`` and ``p_p −= w_S,p τ / s``. ``I^A_c``
is factored as a free root's (LU with partial pivoting, in place); ``JS[j, :, 0:2]``
hold the end blocks ``w_E,p``, ``w_E,c``, ``JS[j, :, 3:5]`` the start blocks ``w_S,p``,
``w_S,c``, ``JU[j, :, 0]`` ``h``, ``JD[j, 2, 2]`` ``1 / s``.

``D`` (d x d, unsymmetric) is factored as ``L diag(δ) U`` (L unit lower, U unit
upper) without pivoting: it is ``S_Sᵀ I^A S_E`` with ``S_S ≈ S_E`` and ``I^A``
near symmetric positive definite for a drift's small rotations, and the returned
ratio (the smallest ``|δ|`` over its scale) lets a caller fall back where it is not.

A ball is eliminated through its anchor, as in :mod:`.nullspace_solve`, now with two
anchor frames ``Y_E = X(−ρ_c,E)``, ``Y_S = X(−ρ_c,S)`` (``S = Y (0, I)``): ``Y_Sᵀ I^A
Y_E = [[A, B̂_E], [B̂_Sᵀ, D]]`` (``B̂_E = U_E,0:3``, ``B̂_S = U_S,0:3``), so ``Ia =
Y_S⁻ᵀ [[K̂, 0], [0, 0]] Y_E⁻¹`` exactly, a point "mass" ``K̂ = A − B̂_E D⁻¹ B̂_Sᵀ`` (3 x
3, unsymmetric) that the parent receives as ``X(ρ_p,S)ᵀ [[K̂, 0], [0, 0]] X(ρ_p,E)``.
``K̂ = A − Σ_k w_E,k w_S,kᵀ / δ_k`` with ``w_E = B̂_E U⁻¹``, ``w_S = L⁻¹ B̂_Sᵀ``. The up
step passes the force ``f = z_v + B̂_E q₀`` at the start anchor (``(f, ρ_p,S × f)``
to the parent); down, with the parent's end-anchor acceleration ``ŷ = a_p,v + a_p,ω
× ρ_p,E``, ``ω̇_c = q₀ − D⁻¹ B̂_Sᵀ ŷ``, ``a_c = (ŷ + g_v + ρ_c,E × ω̇_c, ω̇_c)`` and ``λ
= s (f + K̂ ŷ)``. Measured on SHAKE ball chains of 30 (``bench/nullspace_shake_ball.py``,
12 seeds): the general recursion is off the reference by up to 1.9e-12 with an
explicit ``D⁻¹`` (the adjugate) and 2.0e-14 with LU solves, the anchor form by 5.7e-15
(and it is cheaper).

Accuracy (``test/test_nullspace_shake.py``, ``bench/nullspace_premise.py``): at most
1.6e-14 off the reference on random mechanisms (drift 0.05 rad), where today's
``tree_solve`` is off by up to 7e-11. Without positive definiteness a joint's ``D``
can cancel further than in the symmetric case: on near-straight hinge chains the
relative pivot falls to 3e-5 and the error grows as eps / pivot (up to 2.5e-11
measured there, as much as today's). Drifts of 1 to 2 rad, beyond a sub-step's
``max_rotation`` (0.25 rad), lose more: up to 3.5e-11 where today's solve has 8e-13
(the test's ``test_large_step``).

The kernels are compiled with numba (``@njit(cache=True)``), take only numpy
arrays and scalars, allocate nothing, and run as Python with
``NUMBA_DISABLE_JIT=1``.
"""

from __future__ import annotations

from numba import njit
import numpy as np

from .nullspace_solve import (_DOF, _world_block, _world_torque, BALL, DISTANCE, FREE, HINGE,
                              N_VECS, SLIDER, SLOT_DOT, SLOT_LINE, V_D, V_DUAL, V_LDUAL, V_RHO,
                              V_RHOP, V_SIGN, V_TAU)

# The two configurations' vectors in ``JV``: the end rows' at ``E + V_*``, the start's at
# ``S + V_*``; their motion subspaces in ``JS[:, :, E_COL:E_COL + 3]`` and
# ``JS[:, :, S_COL:S_COL + 3]``.
E, S = 0, N_VECS
E_COL, S_COL = 0, 3


def shake_arrays(n_joints: int, n_bodies: int) -> tuple:
    """
    Allocate the factor and work arrays (once).

    Returns
    -------
    tuple
        ``(IA, JS, JU, JD, JV, work, P, Acc, JG, JQ)``: articulated inertias (n, 6,
        6); per joint ``S_E`` and ``S_S`` (nj, 6, 6: columns 0:3 and 3:6), ``U_E``
        and ``U_S`` (nj, 6, 6; a ball's: ``K̂`` in 0:3, 0:3, ``B̂_E D⁻¹`` in 3:6, 0:3,
        ``(D⁻¹ B̂_Sᵀ)ᵀ`` in 3:6, 3:6), ``D = L diag(δ) U`` (nj, 3, 3: L below, U
        above, ``1 / δ`` on the diagonal), vectors (nj, 2 N_VECS, 3); a (6, 6) factor
        workspace; the solve's bias forces P and accelerations Acc (n, 6), particular
        solutions JG (nj, 6; a ball's: ``g_v`` and ``f``) and ``q₀`` JQ (nj, 3).

    """
    nj, n = n_joints, n_bodies
    return (np.zeros((n, 6, 6)), np.zeros((nj, 6, 6)), np.zeros((nj, 6, 6)),
            np.zeros((nj, 3, 3)), np.zeros((nj, 2 * N_VECS, 3)), np.zeros((6, 6)),
            np.zeros((n, 6)), np.zeros((n, 6)), np.zeros((nj, 6)), np.zeros((nj, 3)))


@njit(cache=True, inline='always')
def _put(JV, j, k, v):
    """``JV[j, k] = v`` (a 3-tuple)."""
    JV[j, k, 0], JV[j, k, 1], JV[j, k, 2] = v[0], v[1], v[2]


@njit(cache=True, inline='always')
def _read_joint(j, typ, c, p, j_rows, j_cside, Ga, Gb, R, JV, JS, base, col, work):
    """
    Read joint j's lever, shift, signs, dual bases and ``S`` from one configuration's rows.

    Into ``JV[j, base + V_*]`` and ``JS[j, :, col:col + d]`` (as :mod:`.nullspace_solve`
    reads them: from the rows' own blocks, so with ``Φ ≠ 0`` too). ``work[0:2]`` is
    overwritten.
    """
    rho0 = rho1 = rho2 = 0.0
    rp0 = rp1 = rp2 = 0.0
    d0 = d1 = d2 = 0.0
    if typ != SLIDER:
        # Point rows 0 and 1: child torques s ρ × e_x = s (0, ρz, −ρy), s (−ρz, 0, ρx).
        for s in range(2):
            r = j_rows[j, s]
            if j_cside[j, s] == 0:
                _put(JV, j, base + V_TAU + s, _world_torque(Ga, r, R, c))
                JV[j, base + V_SIGN, s] = Ga[r, s]
            else:
                _put(JV, j, base + V_TAU + s, _world_torque(Gb, r, R, c))
                JV[j, base + V_SIGN, s] = Gb[r, s]
        r = j_rows[j, 2]
        JV[j, base + V_SIGN, 2] = Ga[r, 2] if j_cside[j, 2] == 0 else Gb[r, 2]
        s0, s1 = JV[j, base + V_SIGN, 0], JV[j, base + V_SIGN, 1]
        rho0 = s1 * JV[j, base + V_TAU + 1, 2]
        rho1 = -s0 * JV[j, base + V_TAU, 2]
        rho2 = s0 * JV[j, base + V_TAU, 1]
        if p >= 0:
            for s in range(2):
                r = j_rows[j, s]
                if j_cside[j, s] == 0:
                    _put(JV, j, base + V_TAU + s, _world_torque(Gb, r, R, p))
                else:
                    _put(JV, j, base + V_TAU + s, _world_torque(Ga, r, R, p))
            # The parent's signs are −s: ρ_p = −(the same reading).
            rp0 = -s1 * JV[j, base + V_TAU + 1, 2]
            rp1 = s0 * JV[j, base + V_TAU, 2]
            rp2 = -s0 * JV[j, base + V_TAU, 1]
            d0, d1, d2 = rp0 - rho0, rp1 - rho1, rp2 - rho2
    JV[j, base + V_RHO, 0], JV[j, base + V_RHO, 1], JV[j, base + V_RHO, 2] = rho0, rho1, rho2
    nd = 2 if typ == HINGE else (0 if typ == BALL else 3)
    for i in range(nd):
        r = j_rows[j, SLOT_DOT + i]
        if j_cside[j, SLOT_DOT + i] == 0:
            _put(JV, j, base + V_DUAL + i, _world_torque(Ga, r, R, c))
        else:
            _put(JV, j, base + V_DUAL + i, _world_torque(Gb, r, R, c))
    if typ == HINGE:
        t0, t1, t2 = JV[j, base + V_DUAL, 0], JV[j, base + V_DUAL, 1], JV[j, base + V_DUAL, 2]
        u0, u1 = JV[j, base + V_DUAL + 1, 0], JV[j, base + V_DUAL + 1, 1]
        u2 = JV[j, base + V_DUAL + 1, 2]
        n0, n1, n2 = t1 * u2 - t2 * u1, t2 * u0 - t0 * u2, t0 * u1 - t1 * u0
        inv = 1.0 / (n0 * n0 + n1 * n1 + n2 * n2)
        # b1 = u × n / |n|², b2 = n × t / |n|².
        JV[j, base + V_DUAL, 0] = (u1 * n2 - u2 * n1) * inv
        JV[j, base + V_DUAL, 1] = (u2 * n0 - u0 * n2) * inv
        JV[j, base + V_DUAL, 2] = (u0 * n1 - u1 * n0) * inv
        JV[j, base + V_DUAL + 1, 0] = (n1 * t2 - n2 * t1) * inv
        JV[j, base + V_DUAL + 1, 1] = (n2 * t0 - n0 * t2) * inv
        JV[j, base + V_DUAL + 1, 2] = (n0 * t1 - n1 * t0) * inv
        JS[j, 0, col] = rho1 * n2 - rho2 * n1
        JS[j, 1, col] = rho2 * n0 - rho0 * n2
        JS[j, 2, col] = rho0 * n1 - rho1 * n0
        JS[j, 3, col], JS[j, 4, col], JS[j, 5, col] = n0, n1, n2
    elif nd == 3:
        # The reciprocal basis t_j × t_k / det.
        t0, t1, t2 = JV[j, base + V_DUAL, 0], JV[j, base + V_DUAL, 1], JV[j, base + V_DUAL, 2]
        u0, u1 = JV[j, base + V_DUAL + 1, 0], JV[j, base + V_DUAL + 1, 1]
        u2 = JV[j, base + V_DUAL + 1, 2]
        w0, w1 = JV[j, base + V_DUAL + 2, 0], JV[j, base + V_DUAL + 2, 1]
        w2 = JV[j, base + V_DUAL + 2, 2]
        x0, x1, x2 = u1 * w2 - u2 * w1, u2 * w0 - u0 * w2, u0 * w1 - u1 * w0
        y0, y1, y2 = w1 * t2 - w2 * t1, w2 * t0 - w0 * t2, w0 * t1 - w1 * t0
        z0, z1, z2 = t1 * u2 - t2 * u1, t2 * u0 - t0 * u2, t0 * u1 - t1 * u0
        inv = 1.0 / (t0 * x0 + t1 * x1 + t2 * x2)
        JV[j, base + V_DUAL, 0], JV[j, base + V_DUAL, 1] = x0 * inv, x1 * inv
        JV[j, base + V_DUAL, 2] = x2 * inv
        JV[j, base + V_DUAL + 1, 0], JV[j, base + V_DUAL + 1, 1] = y0 * inv, y1 * inv
        JV[j, base + V_DUAL + 1, 2] = y2 * inv
        JV[j, base + V_DUAL + 2, 0], JV[j, base + V_DUAL + 2, 1] = z0 * inv, z1 * inv
        JV[j, base + V_DUAL + 2, 2] = z2 * inv
    if typ == SLIDER:
        # Line rows: directions f_k (child, world) and torques τ_k; σ_k = τ_ck + τ_pk gives d.
        for k in range(2):
            r = j_rows[j, SLOT_LINE + k]
            if j_cside[j, SLOT_LINE + k] == 0:
                _put(JV, j, base + V_TAU + k, _world_torque(Ga, r, R, c))
                tp = _world_torque(Gb, r, R, p if p >= 0 else R.shape[0] - 1)
                for t in range(3):
                    JV[j, base + V_LDUAL + k, t] = Ga[r, t]
            else:
                _put(JV, j, base + V_TAU + k, _world_torque(Gb, r, R, c))
                tp = _world_torque(Ga, r, R, p if p >= 0 else R.shape[0] - 1)
                for t in range(3):
                    JV[j, base + V_LDUAL + k, t] = Gb[r, t]
            work[k, 0], work[k, 1], work[k, 2] = tp[0], tp[1], tp[2]
        f0, f1 = JV[j, base + V_LDUAL, 0], JV[j, base + V_LDUAL, 1]
        f2 = JV[j, base + V_LDUAL, 2]
        h0, h1 = JV[j, base + V_LDUAL + 1, 0], JV[j, base + V_LDUAL + 1, 1]
        h2 = JV[j, base + V_LDUAL + 1, 2]
        if p >= 0:
            a0 = JV[j, base + V_TAU, 0] + work[0, 0]
            a1 = JV[j, base + V_TAU, 1] + work[0, 1]
            a2 = JV[j, base + V_TAU, 2] + work[0, 2]
            b0 = JV[j, base + V_TAU + 1, 0] + work[1, 0]
            b1 = JV[j, base + V_TAU + 1, 1] + work[1, 1]
            b2 = JV[j, base + V_TAU + 1, 2] + work[1, 2]
            # d = σ1 × f1 + ((σ2 × f2) · f1) f1
            e = (b1 * h2 - b2 * h1) * f0 + (b2 * h0 - b0 * h2) * f1 + (b0 * h1 - b1 * h0) * f2
            d0 = a1 * f2 - a2 * f1 + e * f0
            d1 = a2 * f0 - a0 * f2 + e * f1
            d2 = a0 * f1 - a1 * f0 + e * f2
        n0, n1, n2 = f1 * h2 - f2 * h1, f2 * h0 - f0 * h2, f0 * h1 - f1 * h0
        inv = 1.0 / (n0 * n0 + n1 * n1 + n2 * n2)
        JV[j, base + V_LDUAL, 0] = (h1 * n2 - h2 * n1) * inv
        JV[j, base + V_LDUAL, 1] = (h2 * n0 - h0 * n2) * inv
        JV[j, base + V_LDUAL, 2] = (h0 * n1 - h1 * n0) * inv
        JV[j, base + V_LDUAL + 1, 0] = (n1 * f2 - n2 * f1) * inv
        JV[j, base + V_LDUAL + 1, 1] = (n2 * f0 - n0 * f2) * inv
        JV[j, base + V_LDUAL + 1, 2] = (n0 * f1 - n1 * f0) * inv
        JS[j, 0, col], JS[j, 1, col], JS[j, 2, col] = n0, n1, n2
        JS[j, 3, col] = JS[j, 4, col] = JS[j, 5, col] = 0.0
    elif typ == BALL:
        # S = ([ρ]×, I): column k is (ρ × e_k, e_k); the parent's lever for the point mass.
        for k in range(3):
            for i in range(6):
                JS[j, i, col + k] = 0.0
            JS[j, 3 + k, col + k] = 1.0
        JS[j, 1, col], JS[j, 2, col] = rho2, -rho1
        JS[j, 0, col + 1], JS[j, 2, col + 1] = -rho2, rho0
        JS[j, 0, col + 2], JS[j, 1, col + 2] = rho1, -rho0
        JV[j, base + V_RHOP, 0], JV[j, base + V_RHOP, 1] = rp0, rp1
        JV[j, base + V_RHOP, 2] = rp2
    JV[j, base + V_D, 0], JV[j, base + V_D, 1], JV[j, base + V_D, 2] = d0, d1, d2


@njit(cache=True)
def _add_shifted(W, IA, p, e0, e1, e2, f0, f1, f2):
    """
    ``IA[p] += X(f)ᵀ W X(e)`` for shifts ``X(d) = [[I, −[d]×], [0, I]]`` (W general).

    With ``W = [[A, B], [C, E]]``: ``W X(e) = [[A, B′], [C, E′]]``, ``B′ = B − A [e]×``
    (row i: ``B_i + e × A_i``), ``E′ = E − C [e]×``; then ``X(f)ᵀ`` adds ``[f]× A`` to
    the lower left and ``[f]× B′`` to the lower right (column t: ``f × (column t)``).
    ``W`` is overwritten.
    """
    for i in range(3):
        a0, a1, a2 = W[i, 0], W[i, 1], W[i, 2]
        W[i, 3] += e1 * a2 - e2 * a1
        W[i, 4] += e2 * a0 - e0 * a2
        W[i, 5] += e0 * a1 - e1 * a0
        a0, a1, a2 = W[3 + i, 0], W[3 + i, 1], W[3 + i, 2]
        W[3 + i, 3] += e1 * a2 - e2 * a1
        W[3 + i, 4] += e2 * a0 - e0 * a2
        W[3 + i, 5] += e0 * a1 - e1 * a0
    for t in range(6):
        x0, x1, x2 = W[0, t], W[1, t], W[2, t]
        IA[p, 0, t] += x0
        IA[p, 1, t] += x1
        IA[p, 2, t] += x2
        IA[p, 3, t] += W[3, t] + (f1 * x2 - f2 * x1)
        IA[p, 4, t] += W[4, t] + (f2 * x0 - f0 * x2)
        IA[p, 5, t] += W[5, t] + (f0 * x1 - f1 * x0)


@njit(cache=True)
def _add_point_mass(JU, j, IA, p, e0, e1, e2, f0, f1, f2):
    """
    ``IA[p] += X(f)ᵀ [[K̂, 0], [0, 0]] X(e)``: a point "mass" ``K̂ = JU[j, 0:3, 0:3]``.

    That is ``[[K̂, T], [[f]× K̂, [f]× T]]`` with ``T = −K̂ [e]×`` (row i: ``e × K̂_i``).
    """
    k00, k01, k02 = JU[j, 0, 0], JU[j, 0, 1], JU[j, 0, 2]
    k10, k11, k12 = JU[j, 1, 0], JU[j, 1, 1], JU[j, 1, 2]
    k20, k21, k22 = JU[j, 2, 0], JU[j, 2, 1], JU[j, 2, 2]
    t00, t01, t02 = e1 * k02 - e2 * k01, e2 * k00 - e0 * k02, e0 * k01 - e1 * k00
    t10, t11, t12 = e1 * k12 - e2 * k11, e2 * k10 - e0 * k12, e0 * k11 - e1 * k10
    t20, t21, t22 = e1 * k22 - e2 * k21, e2 * k20 - e0 * k22, e0 * k21 - e1 * k20
    IA[p, 0, 0] += k00
    IA[p, 0, 1] += k01
    IA[p, 0, 2] += k02
    IA[p, 1, 0] += k10
    IA[p, 1, 1] += k11
    IA[p, 1, 2] += k12
    IA[p, 2, 0] += k20
    IA[p, 2, 1] += k21
    IA[p, 2, 2] += k22
    IA[p, 0, 3] += t00
    IA[p, 0, 4] += t01
    IA[p, 0, 5] += t02
    IA[p, 1, 3] += t10
    IA[p, 1, 4] += t11
    IA[p, 1, 5] += t12
    IA[p, 2, 3] += t20
    IA[p, 2, 4] += t21
    IA[p, 2, 5] += t22
    # Lower half: column by column, f × (the upper half's column).
    IA[p, 3, 0] += f1 * k20 - f2 * k10
    IA[p, 4, 0] += f2 * k00 - f0 * k20
    IA[p, 5, 0] += f0 * k10 - f1 * k00
    IA[p, 3, 1] += f1 * k21 - f2 * k11
    IA[p, 4, 1] += f2 * k01 - f0 * k21
    IA[p, 5, 1] += f0 * k11 - f1 * k01
    IA[p, 3, 2] += f1 * k22 - f2 * k12
    IA[p, 4, 2] += f2 * k02 - f0 * k22
    IA[p, 5, 2] += f0 * k12 - f1 * k02
    IA[p, 3, 3] += f1 * t20 - f2 * t10
    IA[p, 4, 3] += f2 * t00 - f0 * t20
    IA[p, 5, 3] += f0 * t10 - f1 * t00
    IA[p, 3, 4] += f1 * t21 - f2 * t11
    IA[p, 4, 4] += f2 * t01 - f0 * t21
    IA[p, 5, 4] += f0 * t11 - f1 * t01
    IA[p, 3, 5] += f1 * t22 - f2 * t12
    IA[p, 4, 5] += f2 * t02 - f0 * t22
    IA[p, 5, 5] += f0 * t12 - f1 * t02


@njit(cache=True)
def shake_factor(j_child, j_parent, j_type, j_rows, j_cside, GaE, GbE, GaS, GbS, Jr, minv6,
                 RS, RE, IA, JS, JU, JD, JV, work):
    """
    Factorize ``G_E diag(I, J_r) M⁻¹ G_Sᵀ`` in inertia form, leaves first (allocation-free).

    Parameters
    ----------
    j_child, j_parent, j_type, j_rows, j_cside : ndarray of int64
        From :func:`.nullspace_solve.nullspace_structure`.
    GaE, GbE, GaS, GbS : ndarray of float64, shape (m, 6)
        The rows' blocks at the end and at the start configuration (``(δx_world,
        δΘ_principal)``, as for ``tree_factor``).
    Jr : ndarray of float64, shape (n, 3, 3)
        Per body ``J_r`` (invertible), as :func:`.constrained_step._rotor_jacobians`
        fills it.
    minv6 : ndarray of float64, shape (n, 6)
        Diagonal inverse masses (all positive).
    RS, RE : ndarray of float64, shape (n + 1, 3, 3)
        Principal-to-world rotations at the start and at the end (:func:`.rows.frames`).
    IA, JS, JU, JD, JV, work : ndarray
        From :func:`shake_arrays` (overwritten: the factors; the ``IA`` of a free root
        and of a distance row's child by its LU factors, ``JD`` by its pivot rows).

    Returns
    -------
    float
        The smallest pivot ``|δ|`` of the joints' ``D = L diag(δ) U`` over its scale
        ``Σ_i |S_S,i S_E,i I^A_ii|`` (1 without any): small for a nearly massless
        subtree, or where ``D`` needs pivoting (then fall back).

    Notes
    -----
    The start side (``JV[:, S:]``, ``JS[:, :, 3:6]``) depends on the start rows only,
    which stay the same for all of a step's SHAKE iterations (and are the rows of the
    symmetric factorization at the start); reading them is about a third of this
    factorization's time (hinge chain of 50: 15.0 µs, 10.1 µs without, compiled), which a
    caller could share instead.

    """
    n = minv6.shape[0]
    for i in range(n):
        m = 1.0 / minv6[i, 0]
        for r in range(6):
            for t in range(6):
                IA[i, r, t] = 0.0
        IA[i, 0, 0] = m
        IA[i, 1, 1] = m
        IA[i, 2, 2] = m
        # J J_r⁻¹ (by the adjugate) into work[0:3], then R_S (J J_r⁻¹) R_Eᵀ.
        a00, a01, a02 = Jr[i, 0, 0], Jr[i, 0, 1], Jr[i, 0, 2]
        a10, a11, a12 = Jr[i, 1, 0], Jr[i, 1, 1], Jr[i, 1, 2]
        a20, a21, a22 = Jr[i, 2, 0], Jr[i, 2, 1], Jr[i, 2, 2]
        c00, c01, c02 = a11 * a22 - a12 * a21, a12 * a20 - a10 * a22, a10 * a21 - a11 * a20
        inv = 1.0 / (a00 * c00 + a01 * c01 + a02 * c02)
        j0, j1, j2 = inv / minv6[i, 3], inv / minv6[i, 4], inv / minv6[i, 5]
        work[0, 0], work[0, 1], work[0, 2] = j0 * c00, j0 * (a02 * a21 - a01 * a22), \
            j0 * (a01 * a12 - a02 * a11)
        work[1, 0], work[1, 1], work[1, 2] = j1 * c01, j1 * (a00 * a22 - a02 * a20), \
            j1 * (a02 * a10 - a00 * a12)
        work[2, 0], work[2, 1], work[2, 2] = j2 * c02, j2 * (a01 * a20 - a00 * a21), \
            j2 * (a00 * a11 - a01 * a10)
        for r in range(3):
            x0, x1, x2 = RS[i, r, 0], RS[i, r, 1], RS[i, r, 2]
            work[3 + r, 0] = x0 * work[0, 0] + x1 * work[1, 0] + x2 * work[2, 0]
            work[3 + r, 1] = x0 * work[0, 1] + x1 * work[1, 1] + x2 * work[2, 1]
            work[3 + r, 2] = x0 * work[0, 2] + x1 * work[1, 2] + x2 * work[2, 2]
        for r in range(3):
            x0, x1, x2 = work[3 + r, 0], work[3 + r, 1], work[3 + r, 2]
            for t in range(3):
                IA[i, 3 + r, 3 + t] = x0 * RE[i, t, 0] + x1 * RE[i, t, 1] + x2 * RE[i, t, 2]
    smallest = 1.0
    for j in range(j_child.shape[0]):
        c = j_child[j]
        p = j_parent[j]
        typ = j_type[j]
        if typ == FREE or typ == DISTANCE:
            ratio = _free_factor(IA, c, JD, j, work)
            if ratio < smallest or ratio != ratio:   # (NaN: kept, the caller falls back)
                smallest = ratio
            if typ == DISTANCE:
                _distance_factor(j, c, p, j_rows, j_cside, GaE, GbE, GaS, GbS, RE, RS, IA,
                                 JS, JU, JD)
            continue
        _read_joint(j, typ, c, p, j_rows, j_cside, GaE, GbE, RE, JV, JS, E, E_COL, work)
        _read_joint(j, typ, c, p, j_rows, j_cside, GaS, GbS, RS, JV, JS, S, S_COL, work)
        dof = _DOF[typ]
        if dof == 1:
            # U_E = I^A S_E, U_S = I^Aᵀ S_S, D = S_Sᵀ U_E, Ia = I^A − U_E U_Sᵀ / D.
            e0, e1, e2 = JS[j, 0, E_COL], JS[j, 1, E_COL], JS[j, 2, E_COL]
            e3, e4, e5 = JS[j, 3, E_COL], JS[j, 4, E_COL], JS[j, 5, E_COL]
            s0, s1, s2 = JS[j, 0, S_COL], JS[j, 1, S_COL], JS[j, 2, S_COL]
            s3, s4, s5 = JS[j, 3, S_COL], JS[j, 4, S_COL], JS[j, 5, S_COL]
            dd = 0.0
            scale = 0.0
            for i in range(6):
                u = ((IA[c, i, 0] * e0 + IA[c, i, 1] * e1) + (IA[c, i, 2] * e2 + IA[c, i, 3] * e3)
                     + (IA[c, i, 4] * e4 + IA[c, i, 5] * e5))
                JU[j, i, 0] = u
                JU[j, i, 3] = ((IA[c, 0, i] * s0 + IA[c, 1, i] * s1)
                               + (IA[c, 2, i] * s2 + IA[c, 3, i] * s3)
                               + (IA[c, 4, i] * s4 + IA[c, 5, i] * s5))
                si = JS[j, i, S_COL]
                dd += si * u
                scale += abs(si * JS[j, i, E_COL] * IA[c, i, i])
            if abs(dd) < smallest * scale:
                smallest = abs(dd) / scale
            dinv = 1.0 / dd
            JD[j, 0, 0] = dinv
            if p >= 0:
                for i in range(6):
                    ui = JU[j, i, 0] * dinv
                    for t in range(6):
                        work[i, t] = IA[c, i, t] - ui * JU[j, t, 3]
        elif dof == 3:
            _ball_factor(j, c, p, IA, JS, JU, JD, JV, work)
            for k in range(3):
                sc = 0.0
                for t in range(6):
                    sc += abs(JS[j, t, S_COL + k] * JS[j, t, E_COL + k] * IA[c, t, t])
                pk = abs(1.0 / JD[j, k, k])
                if pk < smallest * sc:
                    smallest = pk / sc
            if p >= 0:
                _add_point_mass(JU, j, IA, p, JV[j, E + V_RHOP, 0], JV[j, E + V_RHOP, 1],
                                JV[j, E + V_RHOP, 2], JV[j, S + V_RHOP, 0],
                                JV[j, S + V_RHOP, 1], JV[j, S + V_RHOP, 2])
            continue
        elif p >= 0:   # fixed: nothing eliminated
            for i in range(6):
                for t in range(6):
                    work[i, t] = IA[c, i, t]
        if p >= 0:
            _add_shifted(work, IA, p, JV[j, E + V_D, 0], JV[j, E + V_D, 1], JV[j, E + V_D, 2],
                         JV[j, S + V_D, 0], JV[j, S + V_D, 1], JV[j, S + V_D, 2])
    return smallest


@njit(cache=True)
def _free_factor(IA, c, JD, j, work):
    """
    Factorize ``I^A_c = Pᵀ L U`` in place (partial pivoting; allocation-free).

    A free root's or a distance row's child. ``IA[c]`` receives ``L`` (unit lower, below
    the diagonal) and ``U``; ``JD[j]`` the
    pivot row of each step k at ``JD[j].flat[k]`` (as a float). Returns the smallest
    ``|U_kk| / |I^A_kk|`` (``work[0]``: the diagonal before the factorization; 0 where
    ``I^A_c`` is singular).
    """
    smallest = 1.0
    for k in range(6):
        work[0, k] = abs(IA[c, k, k])
    for k in range(6):
        piv = k
        best = abs(IA[c, k, k])
        for i in range(k + 1, 6):
            v = abs(IA[c, i, k])
            if v > best:
                piv, best = i, v
        JD[j, k // 3, k % 3] = piv
        if piv != k:
            for t in range(6):
                IA[c, k, t], IA[c, piv, t] = IA[c, piv, t], IA[c, k, t]
        scale = work[0, k]
        if best < smallest * scale or best != best:   # (NaN: kept)
            smallest = best / scale
        inv = 1.0 / IA[c, k, k]
        for i in range(k + 1, 6):
            v = IA[c, i, k] * inv
            IA[c, i, k] = v
            for t in range(k + 1, 6):
                IA[c, i, t] -= v * IA[c, k, t]
    return smallest


@njit(cache=True)
def _free_solve(IA, c, JD, j, P, Acc):
    """Set a free root's acceleration ``a_c = −(I^A_c)⁻¹ p_c`` with :func:`_free_factor`'s LU."""
    for k in range(6):
        Acc[c, k] = -P[c, k]
    for k in range(6):   # the row exchanges, in order (whole rows of L were exchanged too)
        piv = int(JD[j, k // 3, k % 3])
        if piv != k:
            Acc[c, k], Acc[c, piv] = Acc[c, piv], Acc[c, k]
    for k in range(6):
        v = Acc[c, k]
        for i in range(k + 1, 6):
            Acc[c, i] -= IA[c, i, k] * v
    for k in range(5, -1, -1):
        v = Acc[c, k]
        for t in range(k + 1, 6):
            v -= IA[c, k, t] * Acc[c, t]
        Acc[c, k] = v / IA[c, k, k]


@njit(cache=True)
def _distance_factor(j, c, p, j_rows, j_cside, GaE, GbE, GaS, GbS, RE, RS, IA, JS, JU, JD):
    """
    Eliminate a distance row's child (``IA[c]`` already its LU factors, in place).

    ``JS[j, :, 0]``, ``JS[j, :, 1]``: the end blocks ``w_E,p`` (0 at the world), ``w_E,c``;
    ``JS[j, :, 3]``, ``JS[j, :, 4]`` the start blocks ``w_S,p``, ``w_S,c``; ``JU[j, :, 0]``
    ``h = (I^A_c)⁻¹ w_S,c``; ``JD[j, 2, 2]`` ``1 / s``, ``s = w_E,cᵀ h``. The parent
    receives ``w_S,p w_E,pᵀ / s``.
    """
    r = j_rows[j, 0]
    if j_cside[j, 0] == 0:
        _world_block(GaE, r, RE, c, JS, j, 1)
        _world_block(GaS, r, RS, c, JS, j, 4)
        if p >= 0:
            _world_block(GbE, r, RE, p, JS, j, 0)
            _world_block(GbS, r, RS, p, JS, j, 3)
    else:
        _world_block(GbE, r, RE, c, JS, j, 1)
        _world_block(GbS, r, RS, c, JS, j, 4)
        if p >= 0:
            _world_block(GaE, r, RE, p, JS, j, 0)
            _world_block(GaS, r, RS, p, JS, j, 3)
    if p < 0:
        for i in range(6):
            JS[j, i, 0] = 0.0
            JS[j, i, 3] = 0.0
    for k in range(6):
        JU[j, k, 0] = JS[j, k, 4]
    for k in range(6):   # the row exchanges, then L and U
        piv = int(JD[j, k // 3, k % 3])
        if piv != k:
            JU[j, k, 0], JU[j, piv, 0] = JU[j, piv, 0], JU[j, k, 0]
    for k in range(6):
        v = JU[j, k, 0]
        for i in range(k + 1, 6):
            JU[j, i, 0] -= IA[c, i, k] * v
    for k in range(5, -1, -1):
        v = JU[j, k, 0]
        for t in range(k + 1, 6):
            v -= IA[c, k, t] * JU[j, t, 0]
        JU[j, k, 0] = v / IA[c, k, k]
    ss = 0.0
    for k in range(6):
        ss += JS[j, k, 1] * JU[j, k, 0]
    sinv = 1.0 / ss
    JD[j, 2, 2] = sinv
    if p >= 0:
        for i in range(6):
            wi = JS[j, i, 3] * sinv
            for t in range(6):
                IA[p, i, t] += wi * JS[j, t, 0]


@njit(cache=True)
def _distance_up(j, c, p, j_rows, IA, JS, JD, P, Acc, JQ, rhs):
    """
    Take a distance row's up step: ``a₀ = −(I^A_c)⁻¹ p_c`` (kept in ``Acc[c]``) and ``τ``.

    ``τ = rhs − w_E,cᵀ a₀`` (into ``JQ[j, 0]``); the parent's bias gets ``−w_S,p τ / s``.
    """
    _free_solve(IA, c, JD, j, P, Acc)
    t = rhs[j_rows[j, 0]]
    for i in range(6):
        t -= JS[j, i, 1] * Acc[c, i]
    JQ[j, 0] = t
    if p >= 0:
        ts = t * JD[j, 2, 2]
        for i in range(6):
            P[p, i] -= JS[j, i, 3] * ts


@njit(cache=True)
def _distance_down(j, c, p, j_rows, JS, JU, JD, Acc, JQ, out):
    """Take a distance row's down step: ``λ = (τ − w_E,pᵀ a_p) / s``, ``a_c = a₀ + h λ``."""
    t = JQ[j, 0]
    if p >= 0:
        for i in range(6):
            t -= JS[j, i, 0] * Acc[p, i]
    lam = t * JD[j, 2, 2]
    out[j_rows[j, 0]] = lam
    for i in range(6):
        Acc[c, i] += JU[j, i, 0] * lam


@njit(cache=True, inline='always')
def _ball_factor(j, c, p, IA, JS, JU, JD, JV, work):
    """
    Eliminate a ball's freedoms through its anchors: ``D``'s factors, ``K̂`` and the solve's terms.

    ``U_E = I^A S_E`` (row i: ``(I^A_i,0:3 × ρ_E) + I^A_i,3:6``), ``U_S = I^Aᵀ S_S``
    likewise with the columns, ``D = S_Sᵀ U_E`` (column q: ``(U_E,0:3,q × ρ_S) +
    U_E,3:6,q``), ``D = L diag(δ) U``; with ``w_E = B̂_E U⁻¹`` and ``w_S = L⁻¹ B̂_Sᵀ``
    (into ``work[3:6]``), ``K̂ = A − Σ_k w_E,k w_S,kᵀ / δ_k`` (into ``JU[j, 0:3,
    0:3]``, only below a body), ``B̂_E D⁻¹`` (into ``JU[j, 3:6, 0:3]``) and ``(D⁻¹
    B̂_Sᵀ)ᵀ`` (into ``JU[j, 3:6, 3:6]``).
    """
    r0, r1, r2 = JV[j, E + V_RHO, 0], JV[j, E + V_RHO, 1], JV[j, E + V_RHO, 2]
    q0, q1, q2 = JV[j, S + V_RHO, 0], JV[j, S + V_RHO, 1], JV[j, S + V_RHO, 2]
    for i in range(6):
        x0, x1, x2 = IA[c, i, 0], IA[c, i, 1], IA[c, i, 2]
        JU[j, i, 0] = (x1 * r2 - x2 * r1) + IA[c, i, 3]
        JU[j, i, 1] = (x2 * r0 - x0 * r2) + IA[c, i, 4]
        JU[j, i, 2] = (x0 * r1 - x1 * r0) + IA[c, i, 5]
        x0, x1, x2 = IA[c, 0, i], IA[c, 1, i], IA[c, 2, i]
        JU[j, i, 3] = (x1 * q2 - x2 * q1) + IA[c, 3, i]
        JU[j, i, 4] = (x2 * q0 - x0 * q2) + IA[c, 4, i]
        JU[j, i, 5] = (x0 * q1 - x1 * q0) + IA[c, 5, i]
    for k in range(3):
        x0, x1, x2 = JU[j, 0, k], JU[j, 1, k], JU[j, 2, k]
        work[0, k] = (x1 * q2 - x2 * q1) + JU[j, 3, k]
        work[1, k] = (x2 * q0 - x0 * q2) + JU[j, 4, k]
        work[2, k] = (x0 * q1 - x1 * q0) + JU[j, 5, k]
    # D = L diag(δ) U (JD: L below the diagonal, U above, 1 / δ on it).
    a00, a01, a02 = work[0, 0], work[0, 1], work[0, 2]
    a10, a11, a12 = work[1, 0], work[1, 1], work[1, 2]
    a20, a21, a22 = work[2, 0], work[2, 1], work[2, 2]
    i0 = 1.0 / a00
    l10, l20, u01, u02 = a10 * i0, a20 * i0, a01 * i0, a02 * i0
    b11 = a11 - l10 * a01
    b12 = a12 - l10 * a02
    b21 = a21 - l20 * a01
    i1 = 1.0 / b11
    l21, u12 = b21 * i1, b12 * i1
    i2 = 1.0 / ((a22 - l20 * a02) - l21 * b12)
    JD[j, 0, 0], JD[j, 1, 1], JD[j, 2, 2] = i0, i1, i2
    JD[j, 1, 0], JD[j, 2, 0], JD[j, 2, 1] = l10, l20, l21
    JD[j, 0, 1], JD[j, 0, 2], JD[j, 1, 2] = u01, u02, u12
    for i in range(3):
        # w_E row i (x U = B̂_E,i), then B̂_E D⁻¹ row i (y L = w_E,i / δ).
        w0 = JU[j, i, 0]
        w1 = JU[j, i, 1] - u01 * w0
        w2 = JU[j, i, 2] - u02 * w0 - u12 * w1
        work[3 + i, 0], work[3 + i, 1], work[3 + i, 2] = w0, w1, w2
        y2 = w2 * i2
        y1 = w1 * i1 - l21 * y2
        JU[j, 3 + i, 0] = w0 * i0 - l10 * y1 - l20 * y2
        JU[j, 3 + i, 1] = y1
        JU[j, 3 + i, 2] = y2
        # w_S for B̂_S row i (L x = B̂_S,iᵀ), then D⁻¹ B̂_S,iᵀ (U y = w_S / δ).
        v0 = JU[j, i, 3]
        v1 = JU[j, i, 4] - l10 * v0
        v2 = JU[j, i, 5] - l20 * v0 - l21 * v1
        work[3 + i, 3], work[3 + i, 4], work[3 + i, 5] = v0, v1, v2
        y2 = v2 * i2
        y1 = v1 * i1 - u12 * y2
        JU[j, 3 + i, 3] = v0 * i0 - u01 * y1 - u02 * y2
        JU[j, 3 + i, 4] = y1
        JU[j, 3 + i, 5] = y2
    if p >= 0:
        for i in range(3):
            w0, w1, w2 = work[3 + i, 0] * i0, work[3 + i, 1] * i1, work[3 + i, 2] * i2
            for t in range(3):
                JU[j, i, t] = IA[c, i, t] - ((w0 * work[3 + t, 3] + w1 * work[3 + t, 4])
                                             + w2 * work[3 + t, 5])


@njit(cache=True, inline='always')
def _ldu_solve(JD, j, b0, b1, b2):
    """``D⁻¹ b`` with joint j's ``D = L diag(δ) U`` (``JD[j]``)."""
    y1 = b1 - JD[j, 1, 0] * b0
    y2 = ((b2 - JD[j, 2, 0] * b0) - JD[j, 2, 1] * y1) * JD[j, 2, 2]
    y1 = y1 * JD[j, 1, 1] - JD[j, 1, 2] * y2
    y0 = (b0 * JD[j, 0, 0] - JD[j, 0, 1] * y1) - JD[j, 0, 2] * y2
    return y0, y1, y2


@njit(cache=True, inline='always')
def _ball_up(j, c, p, j_rows, IA, JD, JU, JV, P, JG, JQ, rhs):
    """
    Take a ball's up step: ``q₀ = −D⁻¹ S_Sᵀ z`` and the force ``f`` it passes to its parent.

    ``g = (s c, 0)``; ``z = p_c + I^A g``; ``f = z_v + B̂_E q₀`` (into ``JG[j, 3:6]``), at
    the start anchor: the parent gets ``(f, ρ_p,S × f)``.
    """
    v0 = JV[j, V_SIGN, 0] * rhs[j_rows[j, 0]]
    v1 = JV[j, V_SIGN, 1] * rhs[j_rows[j, 1]]
    v2 = JV[j, V_SIGN, 2] * rhs[j_rows[j, 2]]
    JG[j, 0], JG[j, 1], JG[j, 2] = v0, v1, v2
    z0 = P[c, 0] + (IA[c, 0, 0] * v0 + IA[c, 0, 1] * v1 + IA[c, 0, 2] * v2)
    z1 = P[c, 1] + (IA[c, 1, 0] * v0 + IA[c, 1, 1] * v1 + IA[c, 1, 2] * v2)
    z2 = P[c, 2] + (IA[c, 2, 0] * v0 + IA[c, 2, 1] * v1 + IA[c, 2, 2] * v2)
    z3 = P[c, 3] + (IA[c, 3, 0] * v0 + IA[c, 3, 1] * v1 + IA[c, 3, 2] * v2)
    z4 = P[c, 4] + (IA[c, 4, 0] * v0 + IA[c, 4, 1] * v1 + IA[c, 4, 2] * v2)
    z5 = P[c, 5] + (IA[c, 5, 0] * v0 + IA[c, 5, 1] * v1 + IA[c, 5, 2] * v2)
    # S_Sᵀ z = z_ω − ρ_S × z_v (the moment about the start anchor).
    r0, r1, r2 = JV[j, S + V_RHO, 0], JV[j, S + V_RHO, 1], JV[j, S + V_RHO, 2]
    t0 = z3 - (r1 * z2 - r2 * z1)
    t1 = z4 - (r2 * z0 - r0 * z2)
    t2 = z5 - (r0 * z1 - r1 * z0)
    q0, q1, q2 = _ldu_solve(JD, j, -t0, -t1, -t2)
    JQ[j, 0], JQ[j, 1], JQ[j, 2] = q0, q1, q2
    f0 = z0 - (JU[j, 3, 0] * t0 + JU[j, 3, 1] * t1 + JU[j, 3, 2] * t2)
    f1 = z1 - (JU[j, 4, 0] * t0 + JU[j, 4, 1] * t1 + JU[j, 4, 2] * t2)
    f2 = z2 - (JU[j, 5, 0] * t0 + JU[j, 5, 1] * t1 + JU[j, 5, 2] * t2)
    JG[j, 3], JG[j, 4], JG[j, 5] = f0, f1, f2
    if p >= 0:
        e0, e1, e2 = JV[j, S + V_RHOP, 0], JV[j, S + V_RHOP, 1], JV[j, S + V_RHOP, 2]
        P[p, 0] += f0
        P[p, 1] += f1
        P[p, 2] += f2
        P[p, 3] += e1 * f2 - e2 * f1
        P[p, 4] += e2 * f0 - e0 * f2
        P[p, 5] += e0 * f1 - e1 * f0


@njit(cache=True, inline='always')
def _ball_down(j, c, p, j_rows, JU, JV, Acc, JG, JQ, out):
    """
    Take a ball's down step: its child's acceleration and ``λ = s (f + K̂ ŷ)``.

    ``ŷ = a_p,v + a_p,ω × ρ_p,E`` (0 at the world), ``ω̇ = q₀ − D⁻¹ B̂_Sᵀ ŷ``, ``a_v = ŷ
    + g_v + ρ_c,E × ω̇``.
    """
    y0 = y1 = y2 = 0.0
    q0, q1, q2 = JQ[j, 0], JQ[j, 1], JQ[j, 2]
    f0, f1, f2 = JG[j, 3], JG[j, 4], JG[j, 5]
    if p >= 0:
        e0, e1, e2 = JV[j, E + V_RHOP, 0], JV[j, E + V_RHOP, 1], JV[j, E + V_RHOP, 2]
        w0, w1, w2 = Acc[p, 3], Acc[p, 4], Acc[p, 5]
        y0 = Acc[p, 0] + (w1 * e2 - w2 * e1)
        y1 = Acc[p, 1] + (w2 * e0 - w0 * e2)
        y2 = Acc[p, 2] + (w0 * e1 - w1 * e0)
        q0 -= JU[j, 3, 3] * y0 + JU[j, 4, 3] * y1 + JU[j, 5, 3] * y2
        q1 -= JU[j, 3, 4] * y0 + JU[j, 4, 4] * y1 + JU[j, 5, 4] * y2
        q2 -= JU[j, 3, 5] * y0 + JU[j, 4, 5] * y1 + JU[j, 5, 5] * y2
        f0 += JU[j, 0, 0] * y0 + JU[j, 0, 1] * y1 + JU[j, 0, 2] * y2
        f1 += JU[j, 1, 0] * y0 + JU[j, 1, 1] * y1 + JU[j, 1, 2] * y2
        f2 += JU[j, 2, 0] * y0 + JU[j, 2, 1] * y1 + JU[j, 2, 2] * y2
    a0 = y0 + JG[j, 0]
    a1 = y1 + JG[j, 1]
    a2 = y2 + JG[j, 2]
    r0, r1, r2 = JV[j, E + V_RHO, 0], JV[j, E + V_RHO, 1], JV[j, E + V_RHO, 2]
    Acc[c, 0] = a0 + (r1 * q2 - r2 * q1)
    Acc[c, 1] = a1 + (r2 * q0 - r0 * q2)
    Acc[c, 2] = a2 + (r0 * q1 - r1 * q0)
    Acc[c, 3], Acc[c, 4], Acc[c, 5] = q0, q1, q2
    out[j_rows[j, 0]] = JV[j, V_SIGN, 0] * f0
    out[j_rows[j, 1]] = JV[j, V_SIGN, 1] * f1
    out[j_rows[j, 2]] = JV[j, V_SIGN, 2] * f2


@njit(cache=True)
def shake_solve(j_child, j_parent, j_type, j_rows, IA, JS, JU, JD, JV, P, Acc, JG, JQ, rhs,
                out):
    """
    Solve ``G_E diag(I, J_r) M⁻¹ G_Sᵀ λ = rhs`` with the factors of :func:`shake_factor`.

    Allocation-free. ``P``, ``Acc`` (n, 6), ``JG`` (nj, 6) and ``JQ`` (nj, 3) are
    workspace from :func:`shake_arrays`; ``out`` (m,) receives ``λ`` (and ``Acc`` the
    body accelerations ``K⁻¹ W_Sᵀ λ`` in world axes, ``(a_v, a_ω)``).
    """
    nj = j_child.shape[0]
    for j in range(nj):
        c = j_child[j]
        for t in range(6):
            P[c, t] = 0.0
    # Up: g_E, z = p_c + I^A g_E, q₀ = −D⁻¹ S_Sᵀ z, p_p += X_Sᵀ (z + U_E q₀).
    for j in range(nj):
        c = j_child[j]
        p = j_parent[j]
        typ = j_type[j]
        if typ == BALL:
            _ball_up(j, c, p, j_rows, IA, JD, JU, JV, P, JG, JQ, rhs)
            continue
        if typ == FREE:   # a free root's bias p_c is complete: nothing to pass on
            continue
        if typ == DISTANCE:
            _distance_up(j, c, p, j_rows, IA, JS, JD, P, Acc, JQ, rhs)
            continue
        c1, c2 = rhs[j_rows[j, SLOT_DOT]], rhs[j_rows[j, SLOT_DOT + 1]]
        if typ == HINGE:
            w0 = c1 * JV[j, E + V_DUAL, 0] + c2 * JV[j, E + V_DUAL + 1, 0]
            w1 = c1 * JV[j, E + V_DUAL, 1] + c2 * JV[j, E + V_DUAL + 1, 1]
            w2 = c1 * JV[j, E + V_DUAL, 2] + c2 * JV[j, E + V_DUAL + 1, 2]
        else:
            c3 = rhs[j_rows[j, SLOT_DOT + 2]]
            w0 = (c1 * JV[j, E + V_DUAL, 0] + c2 * JV[j, E + V_DUAL + 1, 0]
                  + c3 * JV[j, E + V_DUAL + 2, 0])
            w1 = (c1 * JV[j, E + V_DUAL, 1] + c2 * JV[j, E + V_DUAL + 1, 1]
                  + c3 * JV[j, E + V_DUAL + 2, 1])
            w2 = (c1 * JV[j, E + V_DUAL, 2] + c2 * JV[j, E + V_DUAL + 1, 2]
                  + c3 * JV[j, E + V_DUAL + 2, 2])
        if typ == SLIDER:
            e1 = rhs[j_rows[j, SLOT_LINE]] - (JV[j, E + V_TAU, 0] * w0
                                              + JV[j, E + V_TAU, 1] * w1
                                              + JV[j, E + V_TAU, 2] * w2)
            e2 = rhs[j_rows[j, SLOT_LINE + 1]] - (JV[j, E + V_TAU + 1, 0] * w0
                                                  + JV[j, E + V_TAU + 1, 1] * w1
                                                  + JV[j, E + V_TAU + 1, 2] * w2)
            v0 = e1 * JV[j, E + V_LDUAL, 0] + e2 * JV[j, E + V_LDUAL + 1, 0]
            v1 = e1 * JV[j, E + V_LDUAL, 1] + e2 * JV[j, E + V_LDUAL + 1, 1]
            v2 = e1 * JV[j, E + V_LDUAL, 2] + e2 * JV[j, E + V_LDUAL + 1, 2]
        else:
            r0, r1, r2 = JV[j, E + V_RHO, 0], JV[j, E + V_RHO, 1], JV[j, E + V_RHO, 2]
            v0 = JV[j, V_SIGN, 0] * rhs[j_rows[j, 0]] - (w1 * r2 - w2 * r1)
            v1 = JV[j, V_SIGN, 1] * rhs[j_rows[j, 1]] - (w2 * r0 - w0 * r2)
            v2 = JV[j, V_SIGN, 2] * rhs[j_rows[j, 2]] - (w0 * r1 - w1 * r0)
        JG[j, 0], JG[j, 1], JG[j, 2] = v0, v1, v2
        JG[j, 3], JG[j, 4], JG[j, 5] = w0, w1, w2
        z0 = P[c, 0] + ((IA[c, 0, 0] * v0 + IA[c, 0, 1] * v1) + (IA[c, 0, 2] * v2
                        + IA[c, 0, 3] * w0) + (IA[c, 0, 4] * w1 + IA[c, 0, 5] * w2))
        z1 = P[c, 1] + ((IA[c, 1, 0] * v0 + IA[c, 1, 1] * v1) + (IA[c, 1, 2] * v2
                        + IA[c, 1, 3] * w0) + (IA[c, 1, 4] * w1 + IA[c, 1, 5] * w2))
        z2 = P[c, 2] + ((IA[c, 2, 0] * v0 + IA[c, 2, 1] * v1) + (IA[c, 2, 2] * v2
                        + IA[c, 2, 3] * w0) + (IA[c, 2, 4] * w1 + IA[c, 2, 5] * w2))
        z3 = P[c, 3] + ((IA[c, 3, 0] * v0 + IA[c, 3, 1] * v1) + (IA[c, 3, 2] * v2
                        + IA[c, 3, 3] * w0) + (IA[c, 3, 4] * w1 + IA[c, 3, 5] * w2))
        z4 = P[c, 4] + ((IA[c, 4, 0] * v0 + IA[c, 4, 1] * v1) + (IA[c, 4, 2] * v2
                        + IA[c, 4, 3] * w0) + (IA[c, 4, 4] * w1 + IA[c, 4, 5] * w2))
        z5 = P[c, 5] + ((IA[c, 5, 0] * v0 + IA[c, 5, 1] * v1) + (IA[c, 5, 2] * v2
                        + IA[c, 5, 3] * w0) + (IA[c, 5, 4] * w1 + IA[c, 5, 5] * w2))
        if typ != 0:   # hinge, slider: one freedom
            q = -((JS[j, 0, S_COL] * z0 + JS[j, 1, S_COL] * z1)
                  + (JS[j, 2, S_COL] * z2 + JS[j, 3, S_COL] * z3)
                  + (JS[j, 4, S_COL] * z4 + JS[j, 5, S_COL] * z5)) * JD[j, 0, 0]
            JQ[j, 0] = q
            if p >= 0:
                z0 += JU[j, 0, 0] * q
                z1 += JU[j, 1, 0] * q
                z2 += JU[j, 2, 0] * q
                z3 += JU[j, 3, 0] * q
                z4 += JU[j, 4, 0] * q
                z5 += JU[j, 5, 0] * q
        if p >= 0:
            d0, d1, d2 = JV[j, S + V_D, 0], JV[j, S + V_D, 1], JV[j, S + V_D, 2]
            P[p, 0] += z0
            P[p, 1] += z1
            P[p, 2] += z2
            P[p, 3] += z3 + (d1 * z2 - d2 * z1)
            P[p, 4] += z4 + (d2 * z0 - d0 * z2)
            P[p, 5] += z5 + (d0 * z1 - d1 * z0)
    # Down: y = X_E a_p, a_c = y + g_E + S_E (q₀ − D⁻¹ U_Sᵀ y), F = I^A a_c + p_c = W_S,c λ.
    for j in range(nj - 1, -1, -1):
        c = j_child[j]
        p = j_parent[j]
        typ = j_type[j]
        if typ == BALL:
            _ball_down(j, c, p, j_rows, JU, JV, Acc, JG, JQ, out)
            continue
        if typ == FREE:
            _free_solve(IA, c, JD, j, P, Acc)
            continue
        if typ == DISTANCE:
            _distance_down(j, c, p, j_rows, JS, JU, JD, Acc, JQ, out)
            continue
        y0 = y1 = y2 = y3 = y4 = y5 = 0.0
        if p >= 0:
            d0, d1, d2 = JV[j, E + V_D, 0], JV[j, E + V_D, 1], JV[j, E + V_D, 2]
            y3, y4, y5 = Acc[p, 3], Acc[p, 4], Acc[p, 5]
            y0 = Acc[p, 0] + (y4 * d2 - y5 * d1)
            y1 = Acc[p, 1] + (y5 * d0 - y3 * d2)
            y2 = Acc[p, 2] + (y3 * d1 - y4 * d0)
        a0 = y0 + JG[j, 0]
        a1 = y1 + JG[j, 1]
        a2 = y2 + JG[j, 2]
        a3 = y3 + JG[j, 3]
        a4 = y4 + JG[j, 4]
        a5 = y5 + JG[j, 5]
        if typ != 0:
            q = JQ[j, 0]
            if p >= 0:
                q -= JD[j, 0, 0] * ((JU[j, 0, 3] * y0 + JU[j, 1, 3] * y1)
                                    + (JU[j, 2, 3] * y2 + JU[j, 3, 3] * y3)
                                    + (JU[j, 4, 3] * y4 + JU[j, 5, 3] * y5))
            a0 += JS[j, 0, E_COL] * q
            a1 += JS[j, 1, E_COL] * q
            a2 += JS[j, 2, E_COL] * q
            a3 += JS[j, 3, E_COL] * q
            a4 += JS[j, 4, E_COL] * q
            a5 += JS[j, 5, E_COL] * q
        Acc[c, 0], Acc[c, 1], Acc[c, 2] = a0, a1, a2
        Acc[c, 3], Acc[c, 4], Acc[c, 5] = a3, a4, a5
        f0 = P[c, 0] + ((IA[c, 0, 0] * a0 + IA[c, 0, 1] * a1) + (IA[c, 0, 2] * a2
                        + IA[c, 0, 3] * a3) + (IA[c, 0, 4] * a4 + IA[c, 0, 5] * a5))
        f1 = P[c, 1] + ((IA[c, 1, 0] * a0 + IA[c, 1, 1] * a1) + (IA[c, 1, 2] * a2
                        + IA[c, 1, 3] * a3) + (IA[c, 1, 4] * a4 + IA[c, 1, 5] * a5))
        f2 = P[c, 2] + ((IA[c, 2, 0] * a0 + IA[c, 2, 1] * a1) + (IA[c, 2, 2] * a2
                        + IA[c, 2, 3] * a3) + (IA[c, 2, 4] * a4 + IA[c, 2, 5] * a5))
        f3 = P[c, 3] + ((IA[c, 3, 0] * a0 + IA[c, 3, 1] * a1) + (IA[c, 3, 2] * a2
                        + IA[c, 3, 3] * a3) + (IA[c, 3, 4] * a4 + IA[c, 3, 5] * a5))
        f4 = P[c, 4] + ((IA[c, 4, 0] * a0 + IA[c, 4, 1] * a1) + (IA[c, 4, 2] * a2
                        + IA[c, 4, 3] * a3) + (IA[c, 4, 4] * a4 + IA[c, 4, 5] * a5))
        f5 = P[c, 5] + ((IA[c, 5, 0] * a0 + IA[c, 5, 1] * a1) + (IA[c, 5, 2] * a2
                        + IA[c, 5, 3] * a3) + (IA[c, 5, 4] * a4 + IA[c, 5, 5] * a5))
        if typ == SLIDER:
            l1 = (JV[j, S + V_LDUAL, 0] * f0 + JV[j, S + V_LDUAL, 1] * f1
                  + JV[j, S + V_LDUAL, 2] * f2)
            l2 = (JV[j, S + V_LDUAL + 1, 0] * f0 + JV[j, S + V_LDUAL + 1, 1] * f1
                  + JV[j, S + V_LDUAL + 1, 2] * f2)
            out[j_rows[j, SLOT_LINE]] = l1
            out[j_rows[j, SLOT_LINE + 1]] = l2
            h0 = f3 - (l1 * JV[j, S + V_TAU, 0] + l2 * JV[j, S + V_TAU + 1, 0])
            h1 = f4 - (l1 * JV[j, S + V_TAU, 1] + l2 * JV[j, S + V_TAU + 1, 1])
            h2 = f5 - (l1 * JV[j, S + V_TAU, 2] + l2 * JV[j, S + V_TAU + 1, 2])
        else:
            out[j_rows[j, 0]] = JV[j, V_SIGN, 0] * f0
            out[j_rows[j, 1]] = JV[j, V_SIGN, 1] * f1
            out[j_rows[j, 2]] = JV[j, V_SIGN, 2] * f2
            r0, r1, r2 = JV[j, S + V_RHO, 0], JV[j, S + V_RHO, 1], JV[j, S + V_RHO, 2]
            h0 = f3 - (r1 * f2 - r2 * f1)
            h1 = f4 - (r2 * f0 - r0 * f2)
            h2 = f5 - (r0 * f1 - r1 * f0)
        nd = 2 if typ == HINGE else 3
        for i in range(nd):
            out[j_rows[j, SLOT_DOT + i]] = (JV[j, S + V_DUAL + i, 0] * h0
                                            + JV[j, S + V_DUAL + i, 1] * h1
                                            + JV[j, S + V_DUAL + i, 2] * h2)
