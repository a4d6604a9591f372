"""
Compiled kernels: a whole step of a constrained scene in one call.

The methods are those of :mod:`..integrators` (RATTLE with SHAKE's Newton
iterations in the splittings, Baumgarte-stabilized multipliers at every stage
and a velocity projection in ``rkmk4``), written over flat arrays and compiled by numba
(``@njit(cache=True)``; ``NUMBA_DISABLE_JIT=1`` runs it as Python). The
constraint rows are those of :mod:`.rows` (point, dot, line, distance);
the systems ``G M⁻¹ Hᵀ`` are solved densely (Cholesky, LU, or a truncated SVD
for redundant rows) for small components and by the tree solve of
:mod:`.tree_solve` for larger ones; a component whose joints close loops is
solved by the tree solve of a spanning forest and a dense system of the rows
that close the loops (their Schur complement, :mod:`.loop_solve`). The solver
chooses (:data:`..solver.KERNEL_DENSE_ROWS`, :data:`..solver.LOOP_DENSE_ROWS`).
Where the forest's joints are all recognized (the null-space storage,
:func:`nullspace_storage`), the symmetric systems and SHAKE's are factorized in
inertia form instead (:mod:`.nullspace_solve`, :mod:`.nullspace_shake`; see
:func:`_sym_factor` and :func:`_shake_inertia`), falling back to the tree solve,
counted, where a joint's pivot is too small.
This is the one implementation of the constraint solve: besides the step,
:class:`..solver.ConstraintSolver` calls it for the multipliers at a state
(:func:`component_multipliers`: the reactions a user reads), the velocity
projection (:func:`component_project_velocities`) and the consistency search
(:func:`component_reach`).

A step is split into sub-steps when a constrained body turns fast, and redone
with twice as many when SHAKE stops converging (see :mod:`..integrators`); both
happen inside the call.

Parameters array ``par`` (float64)
----------------------------------
``[time_constant, omega, position_tolerance, max_iterations, rank_rtol,
regularization, closing, max_rotation, max_substeps, t_start, t_end]`` (see
:class:`..solver.ConstraintSolver` and :class:`..integrators.Integrator`; the
times, s, of the step's start and end are read only where a row's target moves:
an exact velocity drive's, ``c0 + ċ (t − t0)`` at the time of each configuration
the step evaluates, left at ``t_end``).

Work counts (``counts``: the simulation's int64 tally of work counters, which
the kernels add to; see :class:`..dynamics.Dynamics`): the slots below.
"""

from __future__ import annotations

import math

from numba import njit, objmode
import numpy as np

from . import drives
from .free_step import (all_finite, damping_flow, drift, finish_accelerations, HAS_DAMPING,
                        HAS_DRIVE_DAMPING, HAS_DRIVES,
                        outputs, position_wrench, rkmk4_embedded_error, rkmk4_finish,
                        rkmk4_slopes, rkmk4_stage, state_parts, top_angle, TOP_SHAKE_ANGLE)
from .layout import (B_ANISOTROPIC, B_INV_MASS, B_MOMENTS, B_WIDTH, BODY_VECTORS, COMP, COMPONENT,
                     COMPONENT_TABLE, Count, CT_BODY, CT_COUNTS, CT_FLAGS, CT_FLOATS, CT_FRAMES,
                     CT_GENERIC, CT_GFORCE, CT_INTS, CT_LAM, CT_LAYOUT, CT_METHOD, CT_N_COUNTS,
                     CT_N_FLOATS, CT_N_INTS, CT_N_LAM, CT_N_LAYOUT, CT_N_PAR, CT_N_WRENCH, CT_OUT,
                     CT_PAR, CT_SOLVE, CT_WRENCH, CX_FLOATS, CX_INTS, CX_KEY, CX_LAYOUT, CX_SOLVE,
                     D_F, D_PIV, D_S, D_U, D_VT, DENSE0, DENSE_SLOTS, FACTOR_STATE, FORCE,
                     FR_WIDTH, FRAMES, FREE_ACC, FS_MODE, FS_VALID, G2, GENERAL, GT_LAMBDA, JAC,
                     JR, KIND, L_OFFSET, L_SHAPE, L_WIDTH, MINV, O_WIDTH, OMEGA_WORLD, P_CLOSING,
                     P_MAX_IT, P_MAX_ROT, P_MAX_SUB, P_OMEGA, P_POS_TOL, P_RANK_RTOL, P_REG, P_TAU,
                     PHI, QUATS, ROTOR, ROTOR_TOP, ROW_A, ROW_B, ROW_OWNER, ROW_PAR, Solve, STAGES,
                     STORAGES, SYMMETRIC, T_B, T_CLOSURE, T_E, T_G, T_GROUP_CHILD, T_GROUP_PARENT,
                     T_GROUP_PTR, T_GROUP_ROWS, T_P, T_PIV, T_Q, T_ROW_SIDE, T_S, T_TMP, T_W,
                     T_WORK, T_X, T_XC, T_Y, T_Z, TORQUE, TREE0, TREE_SLOTS, V_GAMMA, V_PHI_DOT,
                     V_RHS, V_SOLUTION, VECTORS, VM, W_WIDTH, WATCH, X_COMP, X_KIND, X_PAR,
                     X_WEIGHT, XV_GAMMA, XV_PHI, XV_PHI_DOT, XVEC)
from .layout import (NS_ACC, NS_CHILD, NS_CSIDE, NS_FRAMES_START, NS_IA, NS_JD, NS_JG, NS_JQ,
                     NS_JS, NS_JU, NS_JV, NS_P, NS_PARENT, NS_ROWS, NS_SHAKE_ACC, NS_SHAKE_IA,
                     NS_SHAKE_JD, NS_SHAKE_JG, NS_SHAKE_JQ, NS_SHAKE_JS, NS_SHAKE_JU,
                     NS_SHAKE_JV, NS_SHAKE_P, NS_SHAKE_WORK, NS_TYPE, NS_WORK, NULLSPACE0)
from .layout import NULLSPACE as NULLSPACE_FIELDS
from .layout import P_T_END, P_T_START, PAR_C0, PAR_RATE, PAR_SCALAR, PAR_T0
from .layout import TREE as TREE_FIELDS
from .loop_solve import (loop_back, loop_close, loop_column, loop_column_solved, loop_forward,
                         loop_reduce, loop_rhs, loop_schur)
from .methods import Method, ONE_STEP, TRIPLE_JUMP
from .nullspace_shake import shake_arrays, shake_factor, shake_solve
from .nullspace_solve import N_SLOTS, nullspace_arrays, nullspace_factor, nullspace_solve
from .rows import framed_geometry, framed_rates, frames
from .so3 import normalize_quaternions, positive_product, quat_exp_multiply
from .tree_solve import _lu, _lu_solve_vec, factor_arrays, tree_factor, tree_solve
from .views import Pinned, pinned, pinned_int, raw, raw_slice

# SHAKE's rounding floor in units of the coordinates' rounding (see _rounding_floor).
ROUNDING_ULPS = 16.0

# Factorization modes (internal: what _fac returns and _sol reads); INERTIA is added when
# the forest of a tree or loop solve is factorized in inertia form (see _sym_factor).
CHOLESKY, LU, SVD, TREE, INERTIA = 0, 1, 2, 3, 8


@njit(cache=True, inline='always')
def _schur(Ga, Gb, Ha, Hb, a, b, own, minv6, A):
    """
    Dense ``A = G M⁻¹ Hᵀ`` (m, m) from the part blocks (world: ``b == n``).

    Part ``i`` adds to row ``own[i]`` (see :data:`.layout.ROWS`).
    """
    parts = Ga.shape[0]
    n = minv6.shape[0]
    for i in range(A.shape[0]):
        for j in range(A.shape[1]):
            A[i, j] = 0.0
    for i in range(parts):
        for j in range(parts):
            s = 0.0
            ai, bi, aj, bj = a[i], b[i], a[j], b[j]
            if ai == aj:
                for c in range(6):
                    s += Ga[i, c] * minv6[ai, c] * Ha[j, c]
            if bj < n and ai == bj:
                for c in range(6):
                    s += Ga[i, c] * minv6[ai, c] * Hb[j, c]
            if bi < n and bi == aj:
                for c in range(6):
                    s += Gb[i, c] * minv6[bi, c] * Ha[j, c]
            if bi < n and bj < n and bi == bj:
                for c in range(6):
                    s += Gb[i, c] * minv6[bi, c] * Hb[j, c]
            A[own[i], own[j]] += s


@njit(cache=True)
def _peak_diagonal(Ga, Gb, Ha, Hb, a, b, m, minv6):
    """
    Largest ``|diag(G M⁻¹ Hᵀ)|`` of the ``m`` rows' own parts (1.0 if all are zero).

    A scale for the pivots (coupling parts, if any, left out: an estimate).
    """
    n = minv6.shape[0]
    peak = 0.0
    for i in range(m):
        d = 0.0
        for c in range(6):
            d += Ga[i, c] * Ha[i, c] * minv6[a[i], c]
            if b[i] < n:
                d += Gb[i, c] * Hb[i, c] * minv6[b[i], c]
        peak = max(peak, abs(d))
    return peak if peak > 0.0 else 1.0


@njit(cache=True)
def _factor_tree(Ga, Gb, Ha, Hb, a, b, own, minv6, symmetric, par, cx, slot, counts):
    """
    Factorize ``G M⁻¹ Hᵀ`` by the tree solve (Tikhonov term for redundant rows).

    Into the tree storage ``slot`` of the component ``cx``. For ``SOLVE_LOOP`` the
    component has closed loops: the tree solve factorizes the rows of its
    spanning forest, and the Schur complement of the rows that close the loops
    (:func:`.loop_solve.loop_schur`) is factorized into the dense storage
    ``slot`` as a small dense system, with the truncated SVD when closure rows
    are redundant. Returns the mode for :func:`_sol`.
    """
    counts[Count.FACTORIZATIONS] += 1
    rtol = par[P_RANK_RTOL]
    tree = _tree(cx, slot)
    tg_ptr, tg_rows, tg_child = tree[T_GROUP_PTR], tree[T_GROUP_ROWS], tree[T_GROUP_CHILD]
    tg_parent, t_side = tree[T_GROUP_PARENT], tree[T_ROW_SIDE]
    tS, tpiv, tP, tQ, tB, tW = tree[T_S], tree[T_PIV], tree[T_P], tree[T_Q], tree[T_B], tree[T_W]
    pivot = tree_factor(tg_ptr, tg_rows, tg_child, tg_parent, t_side, Ga, Gb, Ha, Hb,
                        minv6, 0.0, tS, tpiv, tP, tQ, tB, tW, symmetric)
    reg = 0.0
    peak = 0.0   # the largest |diagonal entry|, computed once if needed
    if not pivot > rtol:
        counts[Count.RANK_DEFICIENT] += 1
        peak = _peak_diagonal(Ga, Gb, Ha, Hb, a, b, _rows_count(cx), minv6)
        reg = par[P_REG] * peak
        tree_factor(tg_ptr, tg_rows, tg_child, tg_parent, t_side, Ga, Gb, Ha, Hb,
                    minv6, reg, tS, tpiv, tP, tQ, tB, tW, symmetric)
    if cx[CX_SOLVE] != Solve.LOOP:
        return TREE
    closure, X, Y, work, g = tree[T_CLOSURE], tree[T_X], tree[T_Y], tree[T_WORK], tree[T_G]
    loop_schur(tg_ptr, tg_rows, tg_child, tg_parent, tS, tpiv, tP, tQ, tB, tree[T_E], tree[T_TMP],
               closure, a, b, own, Ga, Gb, Ha, Hb, minv6, reg, X, Y,
               _f2(cx, DENSE0 + DENSE_SLOTS * slot + D_F),
               work, g)
    # Pivots of S are measured against the whole system's scale: a redundant closure row
    # leaves only rounding in S.
    if peak == 0.0:
        peak = _peak_diagonal(Ga, Gb, Ha, Hb, a, b, _rows_count(cx), minv6)
    tiny = rtol * peak
    return _factor_matrix(closure.shape[0], symmetric, tiny, tiny, cx, slot, counts)


@njit(cache=True, inline='always')
def _fac(Ga, Gb, Ha, Hb, a, b, own, minv6, symmetric, par, cx, slot, counts):
    """
    Factorize ``G M⁻¹ Hᵀ`` (``H = G`` if ``symmetric``) into the storages ``slot``.

    ``slot`` is ``GENERAL`` or ``SYMMETRIC`` (see :func:`constrained_step`); the
    component's ``solve`` (``cx[CX_SOLVE]``) says which storages are in use. Returns
    the mode for :func:`_sol`.
    """
    if cx[CX_SOLVE] == Solve.DENSE:
        return _factor_dense(Ga, Gb, Ha, Hb, a, b, own, minv6, symmetric, par, cx, slot,
                             counts)
    return _factor_tree(Ga, Gb, Ha, Hb, a, b, own, minv6, symmetric, par, cx, slot, counts)


@njit(cache=True)
def _inertia_solve(cx, slot, rhs, out):
    """
    ``out = A_TT⁻¹ rhs`` at the forest's rows, with its factors in inertia form.

    ``slot`` SYMMETRIC: the symmetric factors (:func:`_sym_factor`); GENERAL: SHAKE's
    (:func:`_shake_inertia`). ``out`` may be ``rhs``.
    """
    ns = _nullspace(cx)
    if slot == SYMMETRIC:
        nullspace_solve(ns[NS_CHILD], ns[NS_PARENT], ns[NS_TYPE], ns[NS_ROWS], ns[NS_IA],
                        ns[NS_JS], ns[NS_JU], ns[NS_JD], ns[NS_JV], ns[NS_P], ns[NS_ACC],
                        ns[NS_JG], ns[NS_JQ], rhs, out)
    else:
        IA, JS, JU, JD, JV, work, P, Acc, JG, JQ = _shake_factors(cx)
        shake_solve(ns[NS_CHILD], ns[NS_PARENT], ns[NS_TYPE], ns[NS_ROWS], IA, JS, JU, JD, JV,
                    P, Acc, JG, JQ, rhs, out)


@njit(cache=True)
def _inertia_loop(Ga, Gb, a, b, minv6, par, cx, counts):
    """
    Factorize the closure rows' Schur complement over a forest in inertia form.

    As :func:`_factor_tree` for ``SOLVE_LOOP`` (symmetric, into the storages
    ``SYMMETRIC``), with :func:`_inertia_solve` as the forest's solve; its rows
    are recognized joints, never redundant (no Tikhonov term). Returns the mode of
    the dense factor of the complement.
    """
    tree = _tree(cx, SYMMETRIC)
    rows, closure, X, Y = tree[T_GROUP_ROWS], tree[T_CLOSURE], tree[T_X], tree[T_Y]
    work, g = tree[T_WORK], tree[T_G]
    F = _f2(cx, DENSE0 + DENSE_SLOTS * SYMMETRIC + D_F)
    own = _own(cx)
    for k in range(closure.shape[0]):
        loop_column(k, rows, closure, a, b, own, Ga, Gb, Ga, Gb, minv6, 0.0, X, Y, F, work, g)
        _inertia_solve(cx, SYMMETRIC, work, work)
        loop_column_solved(k, rows, X, work)
    loop_close(rows, X, Y, F)
    tiny = par[P_RANK_RTOL] * _peak_diagonal(Ga, Gb, Ga, Gb, a, b, _rows_count(cx), minv6)
    return _factor_matrix(closure.shape[0], True, tiny, tiny, cx, SYMMETRIC, counts)


@njit(cache=True)
def _shake_inertia(quat_s, GaE, GbE, GaS, GbS, a, b, Jr, minv6, par, cx, counts):
    """
    Factorize SHAKE's ``G_E diag(I, J_r) M⁻¹ G_Sᵀ`` in inertia form, or return -1.

    Where the component's forest is recognized (a non-empty null-space storage):
    :func:`.nullspace_shake.shake_factor` with the start rotations (of ``quat_s``)
    and the end's (the scratch ``FRAMES``, of the current geometry), into the storage's
    ``shake_*`` factors; a loop solve's closure complement then as in
    :func:`_factor_tree`, with that forest solve (the rows' ``G_E diag(I, J_r)`` into
    the scratch ``G2``). Returns the mode for :func:`_sol` (storages ``GENERAL``), or
    -1 where a joint's pivot is at most ``rank_rtol`` of its scale (counted: the
    caller factorizes by the row-space path).
    """
    ns = _nullspace(cx)
    counts[Count.FACTORIZATIONS] += 1
    IA, JS, JU, JD, JV, work, P, Acc, JG, JQ = _shake_factors(cx)
    RS = _v3(cx[CX_FLOATS], cx[CX_LAYOUT], NULLSPACE0 + NS_FRAMES_START)
    frames(quat_s, RS)
    ratio = shake_factor(ns[NS_CHILD], ns[NS_PARENT], ns[NS_TYPE], ns[NS_ROWS], ns[NS_CSIDE],
                         GaE, GbE, GaS, GbS, Jr, minv6, RS, _f3(cx, FRAMES), IA, JS, JU, JD,
                         JV, work)
    if not ratio > par[P_RANK_RTOL]:
        counts[Count.INERTIA_FALLBACKS] += 1
        return -1
    if cx[CX_SOLVE] == Solve.TREE:
        return TREE + INERTIA
    g2 = _f3(cx, G2)
    Ga2, Gb2 = g2[0], g2[1]
    _apply_jacobians(GaE, GbE, a, b, Jr, Ga2, Gb2)
    tree = _tree(cx, GENERAL)
    rows, closure, X, Y = tree[T_GROUP_ROWS], tree[T_CLOSURE], tree[T_X], tree[T_Y]
    F = _f2(cx, DENSE0 + DENSE_SLOTS * GENERAL + D_F)
    own = _own(cx)
    for k in range(closure.shape[0]):
        loop_column(k, rows, closure, a, b, own, Ga2, Gb2, GaS, GbS, minv6, 0.0, X, Y, F,
                    tree[T_WORK], tree[T_G])
        _inertia_solve(cx, GENERAL, tree[T_WORK], tree[T_WORK])
        loop_column_solved(k, rows, X, tree[T_WORK])
    loop_close(rows, X, Y, F)
    tiny = par[P_RANK_RTOL] * _peak_diagonal(Ga2, Gb2, GaS, GbS, a, b, _rows_count(cx), minv6)
    return _factor_matrix(closure.shape[0], False, tiny, tiny, cx, GENERAL, counts) + INERTIA


@njit(cache=True, inline='always')
def _sol(mode, rhs, out, cx, slot):
    """Solve with the factors in the storages ``slot`` (see :func:`_fac`)."""
    solve = cx[CX_SOLVE]
    if solve == Solve.DENSE:
        _solve_dense(mode, rhs, out, cx, slot)
        return
    inertia = mode >= INERTIA
    if inertia:
        mode -= INERTIA
        if solve == Solve.TREE:   # before the tree storage's views: none are needed
            _inertia_solve(cx, slot, rhs, out)
            return
    t = _tree(cx, slot)
    if solve == Solve.TREE:
        tree_solve(t[T_GROUP_PTR], t[T_GROUP_ROWS], t[T_GROUP_CHILD], t[T_GROUP_PARENT],
                   t[T_S], t[T_PIV], t[T_P], t[T_Q], t[T_B], t[T_E], t[T_TMP], rhs, out)
        return
    # Closed loops: forest, then the closure rows' Schur complement, then back.
    z, xc = t[T_Z], t[T_XC]
    if inertia:
        loop_rhs(t[T_CLOSURE], rhs, z)
        _inertia_solve(cx, slot, rhs, out)
        loop_reduce(t[T_GROUP_ROWS], t[T_CLOSURE], t[T_Y], out, z)
    else:
        loop_forward(t[T_GROUP_PTR], t[T_GROUP_ROWS], t[T_GROUP_CHILD], t[T_GROUP_PARENT],
                     t[T_S], t[T_PIV], t[T_P], t[T_Q], t[T_B], t[T_E], t[T_TMP],
                     t[T_CLOSURE], t[T_Y], rhs, out, z)
    _solve_dense(mode, z, xc, cx, slot)
    loop_back(t[T_GROUP_ROWS], t[T_CLOSURE], t[T_X], xc, out)


@njit(cache=True, inline='always')
def _factor_dense(Ga, Gb, Ha, Hb, a, b, own, minv6, symmetric, par, cx, slot, counts):
    """
    Factorize ``G M⁻¹ Hᵀ`` densely; returns the mode for :func:`_solve_dense`.

    Cholesky (symmetric) or LU with partial pivoting; a pivot below
    ``rank_rtol`` times the largest diagonal entry marks redundant rows, which
    get the truncated SVD (minimum-norm solution).
    """
    counts[Count.FACTORIZATIONS] += 1
    F = _f2(cx, DENSE0 + DENSE_SLOTS * slot + D_F)
    m = F.shape[0]
    _schur(Ga, Gb, Ha, Hb, a, b, own, minv6, F)
    scale = 0.0
    for i in range(m):
        scale = max(scale, abs(F[i, i]))
    if not scale > 0.0:
        scale = 1.0
    return _factor_matrix(m, symmetric, par[P_RANK_RTOL] * scale, 0.0, cx, slot, counts)


@njit(cache=True)
def _factor_matrix(m, symmetric, tiny, floor, cx, slot, counts):
    """
    Factorize the matrix ``F`` (m, m) of the dense storage ``slot`` in place; return the mode.

    Cholesky (``symmetric``) or LU with partial pivoting; a pivot at most
    ``tiny`` marks redundant rows, which get the truncated SVD (minimum-norm
    solution): singular values at most ``1e-13`` of the largest, or ``floor``,
    count as zero. The storage's ``U`` keeps a copy of the matrix for that SVD.
    """
    F, dpiv, U, sv, Vt = _dense(cx, slot)
    for i in range(m):
        for j in range(m):
            U[i, j] = F[i, j]
    ok = True
    if symmetric:
        # Cholesky, lower triangle in place.
        for j in range(m):
            d = F[j, j]
            for k in range(j):
                d -= F[j, k] * F[j, k]
            if not d > tiny:
                ok = False
                break
            d = math.sqrt(d)
            F[j, j] = d
            for i in range(j + 1, m):
                s = F[i, j]
                for k in range(j):
                    s -= F[i, k] * F[j, k]
                F[i, j] = s / d
        if ok:
            return CHOLESKY
    elif _lu(F, dpiv, m, tiny) > tiny:   # LU with partial pivoting (tree_solve's)
        return LU
    counts[Count.RANK_DEFICIENT] += 1
    u, s, vt = np.linalg.svd(U)   # the copy: F now holds a partial factorization
    U[:, :] = u
    Vt[:, :] = vt
    for i in range(m):
        sv[i] = s[i] if s[i] > 1e-13 * s[0] and s[i] > floor else 0.0
    return SVD


@njit(cache=True, inline='always')
def _solve_dense(mode, rhs, out, cx, slot):
    """Solve with the factors of :func:`_factor_matrix`; ``out`` (m,) may not alias ``rhs``."""
    m = rhs.shape[0]
    F, dpiv, U, sv, Vt = _dense(cx, slot)
    if mode == SVD:
        y = np.zeros(m)
        for k in range(m):
            if sv[k] > 0.0:
                s = 0.0
                for i in range(m):
                    s += U[i, k] * rhs[i]
                y[k] = s / sv[k]
        for i in range(m):
            s = 0.0
            for k in range(m):
                s += Vt[k, i] * y[k]
            out[i] = s
        return
    for i in range(m):
        out[i] = rhs[i]
    if mode == LU:
        _lu_solve_vec(F, dpiv, m, out)
        return
    # Cholesky: L y = rhs, Lᵀ x = y.
    for i in range(m):
        s = out[i]
        for k in range(i):
            s -= F[i, k] * out[k]
        out[i] = s / F[i, i]
    for i in range(m - 1, -1, -1):
        s = out[i]
        for k in range(i + 1, m):
            s -= F[k, i] * out[k]
        out[i] = s / F[i, i]


@njit(cache=True, inline='always')
def _gt_lambda(Ga, Gb, a, b, own, lam, out):
    """``out = Gᵀ λ`` as (n, 6) (overwritten); part ``r`` carries ``λ[own[r]]``."""
    n = out.shape[0]
    for i in range(n):
        for c in range(6):
            out[i, c] = 0.0
    for r in range(Ga.shape[0]):
        lr = lam[own[r]]
        for c in range(6):
            out[a[r], c] += Ga[r, c] * lr
        if b[r] < n:
            for c in range(6):
                out[b[r], c] += Gb[r, c] * lr


@njit(cache=True, inline='always')
def _copy(src, dst):
    """``dst[:, :] = src`` for arrays of the same shape (r, c)."""
    for i in range(src.shape[0]):
        for c in range(src.shape[1]):
            dst[i, c] = src[i, c]


@njit(cache=True, inline='always')
def _g_times(Ga, Gb, a, b, own, x6, out):
    """``out = G x`` (m,) for generalized vectors ``x6`` (n, 6); part ``r`` adds to ``own[r]``."""
    n = x6.shape[0]
    m = out.shape[0]
    for r in range(Ga.shape[0]):
        s = 0.0
        for c in range(6):
            s += Ga[r, c] * x6[a[r], c]
        if b[r] < n:
            for c in range(6):
                s += Gb[r, c] * x6[b[r], c]
        if r < m:
            out[r] = s
        else:
            out[own[r]] += s


# A component's arrays live in the buffers of :func:`pack`; the compiled step passes them
# on as one context ``cx = (floats, ints, layout, key, solve)`` (``key``: the component's
# generic rows, -1 if none; ``solve``: a :class:`.layout.Solve`), and each
# function takes the views it uses from it with the accessors below. A tuple of arrays is
# passed by value: the ~75 arrays of a component as tuples cost each call ~400 machine
# words copied (perf: most of a pendulum step), the context 25.
#
# The slots (KIND, PHI, ...) are those of :data:`.layout.COMPONENT`: the rows ``(kind,
# comp, a, b, par)`` of :mod:`.rows`, the workspace (see :func:`workspace`) and the scratch
# arrays (see :func:`scratch`), then the dense and the tree storages (GENERAL: SHAKE's
# factorizations; SYMMETRIC: the factor kept for the current geometry, see _sym_factor).
# Which geometry, in the workspace's Φ (3, m) and G (3, 2, m, 6).
START, CURRENT, END = 0, 1, 2


@njit(cache=True)
def _f1(cx, k):
    """Float slot ``k`` (1-D) of the context ``cx``."""
    return _v1(cx[CX_FLOATS], cx[CX_LAYOUT], k)


@njit(cache=True)
def _f2(cx, k):
    """Float slot ``k`` (2-D) of the context ``cx``."""
    return _v2(cx[CX_FLOATS], cx[CX_LAYOUT], k)


@njit(cache=True)
def _f3(cx, k):
    """Float slot ``k`` (3-D) of the context ``cx``."""
    return _v3(cx[CX_FLOATS], cx[CX_LAYOUT], k)


@njit(cache=True)
def _f4(cx, k):
    """Float slot ``k`` (4-D) of the context ``cx``."""
    return _v4(cx[CX_FLOATS], cx[CX_LAYOUT], k)


@njit(cache=True)
def _i1(cx, k):
    """Integer slot ``k`` (1-D) of the context ``cx``."""
    return _v1(cx[CX_INTS], cx[CX_LAYOUT], k)


@njit(cache=True)
def _rows(cx):
    """Return the rows ``(kind, comp, a, b, par)`` (see :mod:`.rows`)."""
    return _i1(cx, KIND), _i1(cx, COMP), _i1(cx, ROW_A), _i1(cx, ROW_B), _f2(cx, ROW_PAR)


@njit(cache=True)
def _own(cx):
    """Return ``row_owner`` (m + e,): the row each part adds to (see :data:`.layout.ROWS`)."""
    return _i1(cx, ROW_OWNER)


@njit(cache=True)
def _rows_count(cx):
    """Return m, the component's rows (multipliers)."""
    return cx[CX_LAYOUT][PHI, L_SHAPE + 1]


@njit(cache=True)
def _dense(cx, slot):
    """Dense storage ``slot``: ``(F, piv, U, s, Vt)`` (see :func:`dense_storage`)."""
    d = DENSE0 + DENSE_SLOTS * slot
    return (_f2(cx, d + D_F), _i1(cx, d + D_PIV), _f2(cx, d + D_U), _f1(cx, d + D_S),
            _f2(cx, d + D_VT))


@njit(cache=True)
def _tree(cx, slot):
    """Tree storage ``slot`` (see :func:`tree_storage`)."""
    return _tree_views(cx[CX_FLOATS], cx[CX_INTS], cx[CX_LAYOUT], TREE0 + TREE_SLOTS * slot)


@njit(cache=True)
def _nullspace(cx):
    """Return the null-space storage's joints and symmetric factors, by ``NS_*`` slots."""
    f, i, L, k = cx[CX_FLOATS], cx[CX_INTS], cx[CX_LAYOUT], NULLSPACE0
    return (_v1(i, L, k + NS_CHILD), _v1(i, L, k + NS_PARENT), _v1(i, L, k + NS_TYPE),
            _v2(i, L, k + NS_ROWS), _v2(i, L, k + NS_CSIDE), _v3(f, L, k + NS_IA),
            _v3(f, L, k + NS_JS), _v3(f, L, k + NS_JU), _v3(f, L, k + NS_JD),
            _v3(f, L, k + NS_JV), _v2(f, L, k + NS_WORK), _v2(f, L, k + NS_P),
            _v2(f, L, k + NS_ACC), _v2(f, L, k + NS_JG), _v2(f, L, k + NS_JQ))


@njit(cache=True)
def _shake_factors(cx):
    """Return SHAKE's unsymmetric factors ``(IA, JS, JU, JD, JV, work, P, Acc, JG, JQ)``."""
    f, L, k = cx[CX_FLOATS], cx[CX_LAYOUT], NULLSPACE0
    return (_v3(f, L, k + NS_SHAKE_IA), _v3(f, L, k + NS_SHAKE_JS), _v3(f, L, k + NS_SHAKE_JU),
            _v3(f, L, k + NS_SHAKE_JD), _v3(f, L, k + NS_SHAKE_JV),
            _v2(f, L, k + NS_SHAKE_WORK), _v2(f, L, k + NS_SHAKE_P),
            _v2(f, L, k + NS_SHAKE_ACC), _v2(f, L, k + NS_SHAKE_JG),
            _v2(f, L, k + NS_SHAKE_JQ))


# Generic rows (a user's Python function) are evaluated by Python from inside the
# compiled step (numba's object mode): the kernel calls these with the key of its
# component, registered by the solver (see ConstraintSolver.kernel_setup).
GENERIC: dict = {}


def generic_geometry(key: int, pos: np.ndarray, quat: np.ndarray, phi: np.ndarray,
                     Ga: np.ndarray, Gb: np.ndarray) -> None:
    """Fill Φ and the G blocks of a component's generic rows (after its built-in rows)."""
    GENERIC[key].geometry(pos, quat, phi, Ga, Gb)


def generic_gamma(key: int, pos: np.ndarray, quat: np.ndarray, vel: np.ndarray,
                  om: np.ndarray, gamma: np.ndarray) -> None:
    """Fill γ of a component's generic rows (after its built-in rows)."""
    GENERIC[key].gamma(pos, quat, vel, om, gamma)


@njit(cache=True)
def _generic_geometry(key, pos, quat, phi, Ga, Gb):
    """Φ and G of the generic rows by :func:`generic_geometry` (Python, in object mode)."""
    with objmode():
        generic_geometry(key, pos, quat, phi, Ga, Gb)


@njit(cache=True)
def _generic_rates(key, pos, quat, vel, om, Ga, Gb, a, b, first, vm):
    """
    Φ̇ and γ of the generic rows (from row ``first``) into ``vm[V_PHI_DOT]``, ``vm[V_GAMMA]``.

    Φ̇ = G ν here, γ from the user's function (:func:`generic_gamma`, in object mode).
    """
    n = pos.shape[0]
    for r in range(first, vm.shape[1]):
        rate = 0.0
        for c in range(3):
            rate += Ga[r, c] * vel[a[r], c] + Ga[r, 3 + c] * om[a[r], c]
            if b[r] < n:
                rate += Gb[r, c] * vel[b[r], c] + Gb[r, 3 + c] * om[b[r], c]
        vm[V_PHI_DOT, r] = rate
    gamma = vm[V_GAMMA]
    with objmode():
        generic_gamma(key, pos, quat, vel, om, gamma)


@njit(cache=True, inline='always')
def _geometry(pos, quat, cx, which, counts):
    """
    Φ and G of every row at ``pos, quat`` into slot ``which`` of the workspace's Φ, G.

    The built-in rows are the first ``len(kind)``; with ``key >= 0`` (``cx[CX_KEY]``)
    the generic rows after them are filled by :func:`generic_geometry` (Python,
    in object mode); then the coupling parts (:data:`.layout.ROWS`), weighted, each
    added to its row's Φ. The rotations go to the scratch ``FRAMES``.
    """
    phi3, G3, R = _f2(cx, PHI), _f4(cx, JAC), _f3(cx, FRAMES)
    phi_w, Ga_w, Gb_w = phi3[which], G3[which, 0], G3[which, 1]
    frames(quat, R)
    kind, comp, a, b, rpar = _rows(cx)
    framed_geometry(pos, R, kind, comp, a, b, rpar, phi_w, Ga_w, Gb_w)
    if cx[CX_KEY] >= 0:
        _generic_geometry(cx[CX_KEY], pos, quat, phi_w, Ga_w, Gb_w)
    x_kind = _i1(cx, X_KIND)
    if x_kind.shape[0]:
        m, own, weight = phi_w.shape[0], _own(cx), _f1(cx, X_WEIGHT)
        xv = _f2(cx, XVEC)
        framed_geometry(pos, R, x_kind, _i1(cx, X_COMP), a[m:], b[m:], _f2(cx, X_PAR),
                        xv[XV_PHI], Ga_w[m:], Gb_w[m:])
        for x in range(x_kind.shape[0]):
            w = weight[x]
            phi_w[own[m + x]] += w * xv[XV_PHI, x]
            for c in range(6):
                Ga_w[m + x, c] *= w
                Gb_w[m + x, c] *= w
    counts[Count.GEOMETRY] += 1
    if which == CURRENT:
        _i1(cx, FACTOR_STATE)[FS_VALID] = 0   # the symmetric factor was of the geometry replaced


@njit(cache=True)
def _moving(cx):
    """Tell whether some row's target moves (a ``rate`` ċ, :data:`.layout.ROW_PARAMETERS`)."""
    rpar = _f2(cx, ROW_PAR)
    for k in range(rpar.shape[0]):
        if rpar[k, PAR_RATE] != 0.0:
            return True
    return False


@njit(cache=True)
def _targets_at(cx, t):
    """
    Put the moving rows' targets at the time ``t`` (s): ``c0 + ċ (t − t0)``.

    An exact velocity drive's target, a function of time (the expression of
    :meth:`..constraints.ConstraintSet.drive_targets_at`, so Python and the kernels
    agree bit for bit). Every evaluation of Φ in a step is at the time of its
    configuration: SHAKE's end at the (sub)step's end, the stages of ``rkmk4`` at
    theirs; a step redone with more sub-steps starts again from its start's.
    """
    rpar = _f2(cx, ROW_PAR)
    for k in range(rpar.shape[0]):
        rate = rpar[k, PAR_RATE]
        if rate != 0.0:
            rpar[k, PAR_SCALAR] = rpar[k, PAR_C0] + rate * (t - rpar[k, PAR_T0])


@njit(cache=True, inline='always')
def _sym_factor(quat, Ga, Gb, a, b, minv6, par, cx, counts):
    """
    Factorize ``G M⁻¹ Gᵀ`` of the current geometry (at ``quat``), or reuse its factors.

    A splitting step's second kick and its velocity projection, and the next
    step's first kick, all solve with the matrix of one configuration: it is
    factorized once, into the storages ``SYMMETRIC``. The workspace's factor
    state (``FACTOR_STATE``) is [the factors are of the current geometry, their mode].

    A forest whose joints are all recognized (a non-empty null-space storage: a
    tree solve's, or a loop solve's spanning forest) is factorized in inertia form
    (:mod:`.nullspace_solve`: each joint's freedoms eliminated, not its rows),
    unless a joint's pivot ``D`` is at most ``rank_rtol`` of its scale (a freedom
    with next to no inertia): then, and for every other component, by :func:`_fac`.
    """
    fs = _i1(cx, FACTOR_STATE)
    if fs[FS_VALID] == 1:
        return fs[FS_MODE]
    mode = -1
    ns = _nullspace(cx)
    if ns[NS_CHILD].shape[0] > 0:
        counts[Count.FACTORIZATIONS] += 1
        R = _f3(cx, FRAMES)
        frames(quat, R)
        pivot = nullspace_factor(ns[NS_CHILD], ns[NS_PARENT], ns[NS_TYPE], ns[NS_ROWS],
                                 ns[NS_CSIDE], Ga, Gb, minv6, R, ns[NS_IA], ns[NS_JS],
                                 ns[NS_JU], ns[NS_JD], ns[NS_JV], ns[NS_WORK])
        if pivot > par[P_RANK_RTOL]:
            if cx[CX_SOLVE] == Solve.TREE:
                mode = TREE + INERTIA
            else:
                mode = _inertia_loop(Ga, Gb, a, b, minv6, par, cx, counts) + INERTIA
        else:
            counts[Count.INERTIA_FALLBACKS] += 1
    if mode < 0:
        mode = _fac(Ga, Gb, Ga, Gb, a, b, _own(cx), minv6, True, par, cx, SYMMETRIC, counts)
    fs[FS_VALID] = 1
    fs[FS_MODE] = mode
    return mode


@njit(cache=True)
def _multipliers(pos, quat, vel, om, cx, par, lam, counts):
    """
    λ of the acceleration-level solve at the current geometry; ``GT_LAMBDA`` gets ``Gᵀλ``.

    ``FREE_ACC`` holds the free accelerations (n, 6); ``Φ̈ = −2ωΦ̇ − ω²Φ`` with
    ``Φ̇ = Gν − ċ`` (a moving target's rate, :func:`.rows.framed_rates`; ``c̈ = 0``).
    The solve uses the symmetric factor (see :func:`_sym_factor`).
    """
    phi, G = _f2(cx, PHI)[CURRENT], _f4(cx, JAC)
    Ga, Gb = G[CURRENT, 0], G[CURRENT, 1]
    vm, g6, a6, minv6 = _f2(cx, VM), _f2(cx, GT_LAMBDA), _f2(cx, FREE_ACC), _f2(cx, MINV)
    kind, comp, a, b, rpar = _rows(cx)
    R = _f3(cx, FRAMES)
    frames(quat, R)
    framed_rates(pos, vel, om, R, _f2(cx, OMEGA_WORLD), kind, comp, a, b, rpar, Ga, Gb,
                 True, vm[V_PHI_DOT], vm[V_GAMMA])
    if cx[CX_KEY] >= 0:
        _generic_rates(cx[CX_KEY], pos, quat, vel, om, Ga, Gb, a, b, kind.shape[0], vm)
    x_kind = _i1(cx, X_KIND)
    if x_kind.shape[0]:
        # The coupling parts: Φ̇ from their (weighted) blocks, γ weighted here.
        m, own, weight = phi.shape[0], _own(cx), _f1(cx, X_WEIGHT)
        xv = _f2(cx, XVEC)
        framed_rates(pos, vel, om, R, _f2(cx, OMEGA_WORLD), x_kind, _i1(cx, X_COMP), a[m:],
                     b[m:], _f2(cx, X_PAR), Ga[m:], Gb[m:], True, xv[XV_PHI_DOT],
                     xv[XV_GAMMA])
        for x in range(x_kind.shape[0]):
            vm[V_PHI_DOT, own[m + x]] += xv[XV_PHI_DOT, x]
            vm[V_GAMMA, own[m + x]] += weight[x] * xv[XV_GAMMA, x]
    w = par[P_OMEGA]
    _g_times(Ga, Gb, a, b, _own(cx), a6, vm[V_RHS])
    for r in range(phi.shape[0]):
        vm[V_RHS, r] += vm[V_GAMMA, r] + 2.0 * w * vm[V_PHI_DOT, r] + w * w * phi[r]
    mode = _sym_factor(quat, Ga, Gb, a, b, minv6, par, cx, counts)
    counts[Count.ACC_SOLVES] += 1
    _sol(mode, vm[V_RHS], lam, cx, SYMMETRIC)
    _gt_lambda(Ga, Gb, a, b, _own(cx), lam, g6)


@njit(cache=True, inline='always')
def _free_accelerations(pos, quat, vel, om, body, gforce, wrench, flags, a6, force, torque,
                        counts):
    """
    Free accelerations (every effect and the gyroscopic term) into ``a6`` (n, 6).

    The force (world) and torque (principal) of gravity, the wrenches and the
    joint servos alone go to ``force`` and ``torque`` (n, 3; the kick applies
    them); the passive joint damping only to ``a6`` (a flow applies it). The
    callers pass the workspace's ``ws[4]``, ``ws[5]``, ``ws[6]``.
    """
    position_wrench(quat, body, gforce, wrench, force, torque)
    for i in range(quat.shape[0]):
        for c in range(3):
            a6[i, c] = force[i, c]
            a6[i, 3 + c] = torque[i, c]
    if flags & (HAS_DRIVES | HAS_DRIVE_DAMPING):
        drives.drive_wrenches(pos, quat, vel, om, wrench, force, torque, a6[:, :3], a6[:, 3:])
    finish_accelerations(vel, om, body, flags, a6[:, :3], a6[:, 3:], counts)


@njit(cache=True, inline='always')
def _kick(pos, quat, vel, mom, tau, body, gforce, wrench, flags, cx, par, lam, c_valid,
          counts):
    """
    ``v += tau f/m`` and ``L += tau τ`` with the constraint force ``−Gᵀλ``, in place.

    λ comes from the full accelerations (damping and the gyroscopic term
    included), so the kick, the flows and the free rotor together follow the
    constrained vector field; the solve uses the symmetric factor (see
    :func:`_sym_factor`). Returns True (the current geometry is valid).
    """
    n = pos.shape[0]
    counts[Count.KICK] += 1
    if flags & HAS_DAMPING:
        counts[Count.DAMP_IN_KICK] += 1
    om = _f3(cx, BODY_VECTORS)[1]
    for i in range(n):
        for c in range(3):
            om[i, c] = mom[i, c] / body[i, B_MOMENTS + c]
    force, torque, g6 = _f2(cx, FORCE), _f2(cx, TORQUE), _f2(cx, GT_LAMBDA)
    _free_accelerations(pos, quat, vel, om, body, gforce, wrench, flags, _f2(cx, FREE_ACC),
                        force, torque, counts)
    if not c_valid:
        _geometry(pos, quat, cx, CURRENT, counts)
    _multipliers(pos, quat, vel, om, cx, par, lam, counts)
    for i in range(n):
        for c in range(3):
            vel[i, c] += tau * body[i, B_INV_MASS] * (force[i, c] - g6[i, c])
            mom[i, c] += tau * (torque[i, c] - g6[i, 3 + c])
    return True


@njit(cache=True, inline='always')
def _free_kick(pos, quat, vel, mom, tau, body, gforce, wrench, flags, cx, force, torque,
               counts):
    """
    ``v += tau f/m`` and ``L += tau τ`` of gravity, the wrenches and servos alone, in place.

    RATTLE's last kick when the velocity projection follows it directly: the
    projection removes any impulse along ``M⁻¹ Gᵀ`` (it solves for the end
    velocities from scratch), so the constraint force a :func:`_kick` would add
    changes nothing but the rounding, and its acceleration-level solve is skipped.
    ``force``, ``torque`` (n, 3): scratch (the workspace's ``ws[5]``, ``ws[6]``).
    """
    counts[Count.KICK] += 1
    position_wrench(quat, body, gforce, wrench, force, torque)
    if flags & HAS_DRIVES:
        # The servos' springs (.drives.split); ``a6`` is scratch here.
        om, a6 = _f3(cx, BODY_VECTORS)[1], _f2(cx, FREE_ACC)
        for i in range(vel.shape[0]):
            for c in range(3):
                om[i, c] = mom[i, c] / body[i, B_MOMENTS + c]
        drives.drive_wrenches(pos, quat, vel, om, wrench, force, torque, a6[:, :3],
                              a6[:, 3:])
    for i in range(vel.shape[0]):
        for c in range(3):
            vel[i, c] += tau * body[i, B_INV_MASS] * force[i, c]
            mom[i, c] += tau * torque[i, c]


@njit(cache=True, inline='always')
def _project_velocities(pos, quat, vel, mom, body, cx, par, counts):
    """
    Project velocities onto ``Φ̇ = −ωΦ`` at the current geometry, in place.

    ``Φ̇ = Gν − ċ``: a moving target's rows (exact velocity drives) get
    ``Gν = ċ − ωΦ``. The solve uses the symmetric factor (see :func:`_sym_factor`).
    """
    n = pos.shape[0]
    counts[Count.VEL_PROJECTIONS] += 1
    phi, G = _f2(cx, PHI)[CURRENT], _f4(cx, JAC)
    Ga, Gb = G[CURRENT, 0], G[CURRENT, 1]
    vm, g6, x6, minv6 = _f2(cx, VM), _f2(cx, GT_LAMBDA), _f2(cx, FREE_ACC), _f2(cx, MINV)
    a, b = _i1(cx, ROW_A), _i1(cx, ROW_B)
    for i in range(n):
        for c in range(3):
            x6[i, c] = vel[i, c]
            x6[i, 3 + c] = mom[i, c] / body[i, B_MOMENTS + c]
    _g_times(Ga, Gb, a, b, _own(cx), x6, vm[V_RHS])
    w = par[P_OMEGA]
    for r in range(phi.shape[0]):
        vm[V_RHS, r] += w * phi[r]
    rpar = _f2(cx, ROW_PAR)
    for r in range(rpar.shape[0]):   # the built-in rows; generic ones do not move
        vm[V_RHS, r] -= rpar[r, PAR_RATE]
    mode = _sym_factor(quat, Ga, Gb, a, b, minv6, par, cx, counts)
    _sol(mode, vm[V_RHS], vm[V_SOLUTION], cx, SYMMETRIC)
    _gt_lambda(Ga, Gb, a, b, _own(cx), vm[V_SOLUTION], g6)
    for i in range(n):
        for c in range(3):
            vel[i, c] = x6[i, c] - minv6[i, c] * g6[i, c]
            mom[i, c] = (x6[i, 3 + c] - minv6[i, 3 + c] * g6[i, 3 + c]) * body[i, B_MOMENTS + c]


@njit(cache=True)
def _project_positions(pos, quat, target, cx, par, counts):
    """
    Orthogonal projection of ``pos, quat`` onto ``Φ = target`` (SHAKE's last resort).

    Newton steps ``δ = −M⁻¹ Gᵀ (G M⁻¹ Gᵀ)⁻¹ (Φ − target)`` at the current
    configuration; ends with the current geometry at the returned configuration.
    Factorizes into the storages ``GENERAL``.
    """
    n = pos.shape[0]
    max_it = int(par[P_MAX_IT])
    vm, g6, minv6 = _f2(cx, VM), _f2(cx, GT_LAMBDA), _f2(cx, MINV)
    phi3, G = _f2(cx, PHI), _f4(cx, JAC)
    a, b = _i1(cx, ROW_A), _i1(cx, ROW_B)
    for it in range(max_it + 1):
        if it:
            _geometry(pos, quat, cx, CURRENT, counts)
        phi, Ga, Gb = phi3[CURRENT], G[CURRENT, 0], G[CURRENT, 1]
        norm = 0.0
        for r in range(phi.shape[0]):
            vm[V_RHS, r] = phi[r] - target[r]
            norm = max(norm, abs(vm[V_RHS, r]))
        if norm <= par[P_POS_TOL]:
            break
        if it == max_it:
            if norm > _rounding_floor(pos, phi.shape[0]):
                counts[Count.UNCONVERGED] += 1
            break
        counts[Count.POS_ITERATIONS] += 1
        mode = _fac(Ga, Gb, Ga, Gb, a, b, _own(cx), minv6, True, par, cx, GENERAL, counts)
        _sol(mode, vm[V_RHS], vm[V_SOLUTION], cx, GENERAL)
        _gt_lambda(Ga, Gb, a, b, _own(cx), vm[V_SOLUTION], g6)
        for i in range(n):
            for c in range(3):
                pos[i, c] -= minv6[i, c] * g6[i, c]
            quat_exp_multiply(quat[i], -minv6[i, 3] * g6[i, 3], -minv6[i, 4] * g6[i, 4],
                              -minv6[i, 5] * g6[i, 5], quat[i])
            s = math.sqrt(quat[i, 0] ** 2 + quat[i, 1] ** 2 + quat[i, 2] ** 2 + quat[i, 3] ** 2)
            for c in range(4):
                quat[i, c] /= s


@njit(cache=True, inline='always')
def _right_jacobian(u0, u1, u2, out):
    """
    ``J_r(u)`` (3, 3) of the rotation vector ``u`` into ``out``.

    ``exp(u + δu) = exp(u) exp(J_r(u) δu)`` with ``J_r(u) = I − (1 − cos θ)/θ²
    hat(u) + (θ − sin θ)/θ³ hat(u)²``, ``θ = |u|`` (any θ).
    """
    t2 = u0 * u0 + u1 * u1 + u2 * u2
    theta = math.sqrt(t2)
    if theta < 1e-4:
        ca, cb = 0.5 - t2 / 24.0, 1.0 / 6.0 - t2 / 120.0
    else:
        ca = (1.0 - math.cos(theta)) / t2
        cb = (theta - math.sin(theta)) / (t2 * theta)
    # hat(u) and hat(u)² = u uᵀ − θ² I.
    H = ((0.0, -u2, u1), (u2, 0.0, -u0), (-u1, u0, 0.0))
    uu = (u0, u1, u2)
    for r in range(3):
        for c in range(3):
            h2 = uu[r] * uu[c] - (t2 if r == c else 0.0)
            out[r, c] = (1.0 if r == c else 0.0) - ca * H[r][c] + cb * h2


@njit(cache=True, inline='always')
def _rotation_jacobian(q_s, q_e, out):
    """``J_r(u)`` (3, 3) of one body's rotation ``u = log(q_s⁻¹ ⊗ q_e)`` into ``out``."""
    # q = conj(q_s) ⊗ q_e
    x, y, z, w = positive_product(-q_s[0], -q_s[1], -q_s[2], q_s[3], q_e[0], q_e[1], q_e[2],
                                  q_e[3])
    s = math.sqrt(x * x + y * y + z * z)
    theta = 2.0 * math.atan2(s, w)
    k = theta / s if s > 0.0 else 2.0 / w
    _right_jacobian(k * x, k * y, k * z, out)


@njit(cache=True, inline='always')
def _right_jacobians(quat_s, quat_e, Jr):
    """``J_r(u)`` (n, 3, 3) of each body's rotation ``u = log(q_s⁻¹ ⊗ q_e)``."""
    for i in range(quat_s.shape[0]):
        _rotation_jacobian(quat_s[i], quat_e[i], Jr[i])


@njit(cache=True, inline='always')
def _top_jacobian(mom_s, moments, axis, h, out):
    """
    ``(∂Θ_end/∂L_start) J / h`` (3, 3) of a symmetric top's exact drift into ``out``.

    The drift ends at ``q ⊗ exp(u) ⊗ exp(φ e_a)`` (``free_step.top_flow``) with
    ``u = h L/J_s`` and ``φ = h L_a c``, ``c = 1/J_a − 1/J_s``. Perturbing ``L``:
    ``exp(u + δu) exp((φ + δφ) e_a) = exp(u) exp(φ e_a) exp(R_a(φ)ᵀ J_r(u) δu + δφ e_a)``
    to first order, so ``∂Θ/∂L = R_a(φ)ᵀ J_r(u) h/J_s + h c e_a e_aᵀ``, and times
    ``J/h``: ``R_a(φ)ᵀ J_r(u) J/J_s`` plus ``c J_a = 1 − J_a/J_s`` at ``(a, a)``.
    """
    a = axis
    j, k = (a + 1) % 3, (a + 2) % 3
    ja, js = moments[a], 0.5 * (moments[j] + moments[k])
    g = h / js
    _right_jacobian(g * mom_s[0], g * mom_s[1], g * mom_s[2], out)
    phi = h * mom_s[a] * ((js - ja) / (ja * js))
    cs, sn = math.cos(phi), math.sin(phi)
    for c in range(3):
        scale = moments[c] / js
        tj, tk = out[j, c], out[k, c]
        out[j, c] = (cs * tj + sn * tk) * scale
        out[k, c] = (cs * tk - sn * tj) * scale
        out[a, c] *= scale
    out[a, a] += (js - ja) / js


@njit(cache=True, inline='always')
def _rotor_jacobians(quat_s, quat_e, mom_s, body, h, symmetric, Jr, scratch,
                     max_top_angle=math.inf):
    """
    Per body, how the end orientation of a drift responds to its start momentum.

    ``Jr[i] = (∂Θ_end/∂L_start) J_i / h`` (3, 3), ``δΘ`` the body-frame rotation at
    the end: for an isotropic body ``J_r(u)`` of its rotation over the drift
    (:func:`_rotation_jacobian`); for a symmetric top, that of its exact flow
    (:func:`_top_jacobian`) where ``drift`` with the same ``max_top_angle`` takes
    it (``free_step.top_angle``), else as for an asymmetric body; for an
    asymmetric one, the derivative carried
    through the drift's rotor flows about the principal axes, each a rotation by
    ``φ = τ L_k / J_k`` that also turns ``L`` (see ``free_step.axis_flow``).
    ``scratch`` (6, 3) is overwritten.
    """
    dL, L, row, ex = scratch[0:3], scratch[3], scratch[4], scratch[5]
    if symmetric:
        axes, weights = (0, 1, 2, 1, 0), (0.5, 0.5, 1.0, 0.5, 0.5)
    else:
        axes, weights = (0, 1, 2, 0, 0), (1.0, 1.0, 1.0, 0.0, 0.0)
    for i in range(quat_s.shape[0]):
        code = body[i, B_ANISOTROPIC]
        if code == 0.0:
            _rotation_jacobian(quat_s[i], quat_e[i], Jr[i])
            continue
        if code >= ROTOR_TOP and top_angle(mom_s[i], body[i, B_MOMENTS:B_MOMENTS + 3],
                                           int(code - ROTOR_TOP), h) <= max_top_angle:
            _top_jacobian(mom_s[i], body[i, B_MOMENTS:B_MOMENTS + 3], int(code - ROTOR_TOP), h,
                          Jr[i])
            continue
        dT = Jr[i]   # the derivative of the end rotation, scaled into J_r at the end
        for r in range(3):
            L[r] = mom_s[i, r]
            for c in range(3):
                dT[r, c] = 0.0
                dL[r, c] = 1.0 if r == c else 0.0
        for f in range(5 if symmetric else 3):
            k = axes[f]
            tau = weights[f] * h
            gain = tau / body[i, B_MOMENTS + k]
            phi = gain * L[k]
            cs, sn = math.cos(phi), math.sin(phi)
            j, kk = (k + 1) % 3, (k + 2) % 3
            for c in range(3):
                row[c] = gain * dL[k, c]   # δφ per δL_start
            # L <- Rot(e_k, -φ) L
            lj, lk = L[j], L[kk]
            L[j] = cs * lj + sn * lk
            L[kk] = cs * lk - sn * lj
            # e_k × L_new
            ex[k] = 0.0
            ex[j] = -L[kk]
            ex[kk] = L[j]
            for c in range(3):
                tj, tk = dT[j, c], dT[kk, c]
                dT[j, c] = cs * tj + sn * tk
                dT[kk, c] = cs * tk - sn * tj
                dT[k, c] += row[c]
                mj, mk = dL[j, c], dL[kk, c]
                dL[j, c] = cs * mj + sn * mk
                dL[kk, c] = cs * mk - sn * mj
                for r in range(3):
                    dL[r, c] -= ex[r] * row[c]
        for r in range(3):
            for c in range(3):
                dT[r, c] = dT[r, c] * body[i, B_MOMENTS + c] / h


@njit(cache=True, inline='always')
def _apply_jacobians(Ga, Gb, a, b, Jr, Ga2, Gb2):
    """Rows' angular blocks times each body's ``J_r``: ``G2 = G diag(I, J_r)``."""
    n = Jr.shape[0]
    for r in range(Ga.shape[0]):
        for c in range(3):
            Ga2[r, c] = Ga[r, c]
            Gb2[r, c] = Gb[r, c]
        i, j = a[r], b[r]
        for c in range(3):
            s = 0.0
            for k in range(3):
                s += Ga[r, 3 + k] * Jr[i, k, c]
            Ga2[r, 3 + c] = s
            if j < n:
                s = 0.0
                for k in range(3):
                    s += Gb[r, 3 + k] * Jr[j, k, c]
                Gb2[r, 3 + c] = s
            else:
                Gb2[r, 3 + c] = Gb[r, 3 + c]


@njit(cache=True)
def _shake(pos, quat, vel, mom, h, symmetric, body, cx, par, last_resort, counts):
    """
    Drift with the start impulse that lands on ``Φ = exp(−h/τ) Φ_start``, in place.

    Returns False when the Newton iterations stop converging on joints that
    hold (the step is then redone finer), True otherwise; on True the current
    geometry is that of the new configuration. Factorizes into the storages
    ``GENERAL``.
    """
    n = pos.shape[0]
    phi3, G = _f2(cx, PHI), _f4(cx, JAC)
    phiS, GaS, GbS = phi3[START], G[START, 0], G[START, 1]
    vm, g6, minv6 = _f2(cx, VM), _f2(cx, GT_LAMBDA), _f2(cx, MINV)
    a, b = _i1(cx, ROW_A), _i1(cx, ROW_B)
    m = phiS.shape[0]
    rho = math.exp(-h / par[P_TAU])
    target = _f2(cx, VECTORS)[0]
    closing = False
    for r in range(m):
        target[r] = rho * phiS[r]
        if abs(phiS[r]) > par[P_CLOSING]:
            closing = True
    max_it = int(par[P_MAX_IT])
    # The start of the drift (the body vectors' slots 0 and 1 are the caller's).
    body_vectors = _f3(cx, BODY_VECTORS)
    pos_s, mom_s, quat_s = body_vectors[2], body_vectors[3], _f2(cx, QUATS)
    vel_b, mom_b = body_vectors[4], body_vectors[5]   # the last iterate that cut the residual
    _copy(pos, pos_s)
    _copy(quat, quat_s)
    _copy(mom, mom_s)
    g2 = _f3(cx, G2)
    Jr, Ga2, Gb2 = _f3(cx, JR), g2[0], g2[1]
    previous = np.inf
    mode = -1
    for it in range(max_it + 1):
        if it:
            _copy(pos_s, pos)
            _copy(quat_s, quat)
            _copy(mom_s, mom)
        drift(pos, quat, vel, mom, body, h, symmetric, counts, TOP_SHAKE_ANGLE)
        _geometry(pos, quat, cx, CURRENT, counts)
        phiE, GaE, GbE = phi3[CURRENT], G[CURRENT, 0], G[CURRENT, 1]
        norm = 0.0
        for r in range(m):
            vm[V_RHS, r] = phiE[r] - target[r]
            norm = max(norm, abs(vm[V_RHS, r]))
        if norm <= par[P_POS_TOL]:
            break
        if it == max_it:
            if norm > _rounding_floor(pos, m):
                counts[Count.UNCONVERGED] += 1   # accepted above the tolerance: reported
            break
        if norm > 0.5 * previous:
            if norm <= _rounding_floor(pos, m):
                break   # converged as far as the coordinates resolve
            if not closing and not last_resort:
                return False
            counts[Count.FALLBACKS] += 1
            # Project from the last iterate that cut the residual, not from this one: a
            # Newton step taken near a singular matrix (σ_min of G_E D M⁻¹ G_Sᵀ falling
            # from 3 to 5e-3 within three iterations, a chain folded to reach its target)
            # turns bodies by radians within a sub-step (12 rad in 3e-4 s measured),
            # from where the projection need not converge, and its impulse stays in the
            # momenta (the next drifts turn them by many turns, then overflow).
            _copy(vel_b, vel)
            _copy(mom_b, mom_s)
            _copy(pos_s, pos)
            _copy(quat_s, quat)
            _copy(mom_s, mom)
            drift(pos, quat, vel, mom, body, h, symmetric, counts, TOP_SHAKE_ANGLE)
            _geometry(pos, quat, cx, CURRENT, counts)
            _project_positions(pos, quat, target, cx, par, counts)
            break
        # Refactor unless the last iteration cut the residual a hundredfold.
        refactor = mode < 0 or norm > 1e-2 * previous
        previous = norm
        counts[Count.POS_ITERATIONS] += 1
        # Φ(end) responds to a start impulse κ like h G_end D M⁻¹ G_startᵀ κ, where D
        # is, per body, the right Jacobian of exp at its rotation u over the drift: an
        # impulse changes u by δu and the end orientation by J_r(u) δu, not by δu.
        # For an anisotropic body D is carried through its rotor flows (which also
        # turn L): with D the first iteration is Newton's method.
        # A factorization serves the later iterations while they converge fast: their
        # matrices differ from it by as much as the configuration moved since (the
        # size of the corrections), and the iteration stays Newton's to that order.
        if refactor:
            _rotor_jacobians(quat_s, quat, mom_s, body, h, symmetric, Jr, _f2(cx, ROTOR),
                             TOP_SHAKE_ANGLE)
            mode = -1
            if _nullspace(cx)[NS_CHILD].shape[0] > 0:   # the forest in inertia form
                mode = _shake_inertia(quat_s, GaE, GbE, GaS, GbS, a, b, Jr, minv6, par, cx,
                                      counts)
            if mode < 0:
                _apply_jacobians(GaE, GbE, a, b, Jr, Ga2, Gb2)
                mode = _fac(Ga2, Gb2, GaS, GbS, a, b, _own(cx), minv6, False, par, cx,
                            GENERAL, counts)
        _sol(mode, vm[V_RHS], vm[V_SOLUTION], cx, GENERAL)
        _gt_lambda(GaS, GbS, a, b, _own(cx), vm[V_SOLUTION], g6)
        _copy(vel, vel_b)
        _copy(mom_s, mom_b)
        for i in range(n):
            for c in range(3):
                vel[i, c] += -minv6[i, c] * g6[i, c] / h
                mom_s[i, c] += (-minv6[i, 3 + c] * g6[i, 3 + c] / h) * body[i, B_MOMENTS + c]
    return True


@njit(cache=True)
def _rounding_floor(pos, m):
    """
    Return the smallest residual of ``m`` rows SHAKE resolves at the positions ``pos``.

    A row's residual is computed from world coordinates (positions of the
    centres of mass and joint points), each known to half an ulp: ``ε |x|``
    with ``ε = 2.2e-16``. Far from the origin that exceeds the 1e-13 m
    tolerance (at 1 km a position's ulp is 1.1e-13 m), and Newton's iteration,
    which cannot cut the rounding, stalled there and redid the step in ever
    more sub-steps (a pendulum 1 km from the origin took 2.5 sub-steps a step, at
    10 km 100; a ring of 1000 rods, 16 m across, 64 at times). A solve over
    ``m`` rows adds rounding that grows like ``sqrt(m)`` (measured on that ring:
    stalls at 15 to 60 ulps of its coordinates, m = 5003). Below
    ``ROUNDING_ULPS sqrt(m) ε max|x|`` a residual that no longer falls is
    accepted as converged; near the origin the floor is below the tolerance
    and changes nothing.
    """
    scale = 0.0
    for i in range(pos.shape[0]):
        for c in range(3):
            scale = max(scale, abs(pos[i, c]))
    return ROUNDING_ULPS * math.sqrt(m) * 2.220446049250313e-16 * scale


@njit(cache=True, inline='always')
def _splitting(method, pos, quat, vel, om, dt, body, gforce, wrench, flags, cx, par,
               last_resort, lam, c_valid, counts, s0, s1):
    """
    One (sub)step of a splitting method with RATTLE; returns (converged, c_valid).

    SHAKE factorizes into the storages ``GENERAL``; the kicks and the velocity
    projection solve with the symmetric factor in ``SYMMETRIC``. The (sub)step runs
    from the time ``s0`` to ``s1`` (s), ``s1 − s0 = dt`` to rounding: moving targets
    are at ``s0`` on entry and at ``s1`` on return (:func:`_targets_at`); each
    sub-step of the triple jump (one goes back in time) ends on its own.
    """
    n = pos.shape[0]
    symmetric = method != Method.SYMPLECTIC_EULER
    weights = TRIPLE_JUMP if method == Method.LIE_POISSON4 else ONE_STEP
    n_sub = 3 if method == Method.LIE_POISSON4 else 1
    damping = flags & HAS_DAMPING
    joint_damping = flags & HAS_DRIVE_DAMPING
    mom = _f3(cx, BODY_VECTORS)[0]
    phi, G = _f2(cx, PHI), _f4(cx, JAC)
    for i in range(n):
        for c in range(3):
            mom[i, c] = om[i, c] * body[i, B_MOMENTS + c]
    elapsed = 0.0
    for sub in range(n_sub):
        h = weights[sub] * dt
        elapsed += weights[sub]
        end = s1 if sub == n_sub - 1 else s0 + elapsed * (s1 - s0)
        if not c_valid:
            _geometry(pos, quat, cx, CURRENT, counts)
            c_valid = True
        for r in range(phi.shape[1]):
            phi[START, r] = phi[CURRENT, r]
        _copy(G[CURRENT, 0], G[START, 0])
        _copy(G[CURRENT, 1], G[START, 1])
        first = 0.5 * h if symmetric else h
        if damping:
            damping_flow(vel, mom, body, first, counts)
        if joint_damping:
            drives.damping_flow(pos, quat, vel, mom, body, wrench, first, False)
        _kick(pos, quat, vel, mom, first, body, gforce, wrench, flags, cx, par, lam, c_valid,
              counts)
        _targets_at(cx, end)   # SHAKE's end lands on the targets of its time
        if not _shake(pos, quat, vel, mom, h, symmetric, body, cx, par, last_resort, counts):
            return False, False
        if symmetric and (damping or joint_damping):
            # The damping flow between kick and projection is not along M⁻¹ Gᵀ: the
            # kick's constraint force is part of the method here. The flows in the
            # reverse order of the first half: the step stays symmetric.
            _kick(pos, quat, vel, mom, 0.5 * h, body, gforce, wrench, flags, cx, par, lam,
                  True, counts)
            if joint_damping:
                drives.damping_flow(pos, quat, vel, mom, body, wrench, 0.5 * h, True)
            if damping:
                damping_flow(vel, mom, body, 0.5 * h, counts)
        elif symmetric:
            _free_kick(pos, quat, vel, mom, 0.5 * h, body, gforce, wrench, flags, cx,
                       _f2(cx, FORCE), _f2(cx, TORQUE), counts)
        _project_velocities(pos, quat, vel, mom, body, cx, par, counts)
    for i in range(n):
        for c in range(3):
            om[i, c] = mom[i, c] / body[i, B_MOMENTS + c]
    return True, True


@njit(cache=True, inline='always')
def _rkmk4(pos, quat, vel, om, h, body, gforce, wrench, flags, cx, par, lam, c_valid, counts,
           err, s0, s1):
    """
    One RKMK4 (sub)step with constraint forces at every stage, then Φ̇ = −ωΦ.

    The (sub)step runs from the time ``s0`` to ``s1`` (s): each stage evaluates
    moving targets at its time (``s0``, the midpoint twice, ``s1``;
    :func:`_targets_at`), which stay at ``s1`` on return.

    With ``err`` of length 1, the slopes at the end (constraint forces included,
    before the velocity projection) give the embedded estimate
    (:func:`.free_step.rkmk4_embedded_error`), raising ``err[0]``. The solves
    use the symmetric factor (see :func:`_sym_factor`).
    """
    n = pos.shape[0]
    estimate = err.shape[0] > 0
    stages, vectors = _f4(cx, STAGES), _f3(cx, BODY_VECTORS)
    kp, kv, kw, kr = stages[0], stages[1], stages[2], stages[3]
    p, v, w, u, q = vectors[0], vectors[1], vectors[2], vectors[3], _f2(cx, QUATS)
    a6, g6, minv6 = _f2(cx, FREE_ACC), _f2(cx, GT_LAMBDA), _f2(cx, MINV)
    force, torque = _f2(cx, FORCE), _f2(cx, TORQUE)
    for s in range(4):
        rkmk4_stage(s, h, pos, quat, vel, om, kp, kv, kw, kr, p, q, v, w, u, counts)
        if s:
            c_valid = False
            _targets_at(cx, s1 if s == 3 else s0 + 0.5 * (s1 - s0))
        counts[Count.RHS] += 1
        _free_accelerations(p, q, v, w, body, gforce, wrench, flags, a6, force, torque, counts)
        if not c_valid:
            _geometry(p, q, cx, CURRENT, counts)
        _multipliers(p, q, v, w, cx, par, lam, counts)
        for i in range(n):
            for c in range(3):
                kv[s, i, c] = a6[i, c] - minv6[i, c] * g6[i, c]
                kw[s, i, c] = a6[i, 3 + c] - minv6[i, 3 + c] * g6[i, 3 + c]
        rkmk4_slopes(s, v, w, u, kp, kr)
    rkmk4_finish(h, pos, quat, vel, om, kp, kv, kw, kr, u, counts)
    # Velocities onto Φ̇ = −ωΦ at the end configuration: an internal impulse.
    _geometry(pos, quat, cx, CURRENT, counts)
    if estimate:
        # The fifth stage (its factorization is the projection's): λ to scratch, so
        # the reported multipliers are those of the step without the estimate.
        counts[Count.RHS] += 1
        _free_accelerations(pos, quat, vel, om, body, gforce, wrench, flags, a6, force, torque,
                            counts)
        _multipliers(pos, quat, vel, om, cx, par, _f2(cx, VECTORS)[1], counts)
        for i in range(n):
            for c in range(3):
                kv[4, i, c] = a6[i, c] - minv6[i, c] * g6[i, c]
                kw[4, i, c] = a6[i, 3 + c] - minv6[i, 3 + c] * g6[i, 3 + c]
        err[0] = max(err[0], rkmk4_embedded_error(vel, om, u, kp, kv, kw, kr))
    mom = vectors[0]
    for i in range(n):
        for c in range(3):
            mom[i, c] = om[i, c] * body[i, B_MOMENTS + c]
    _project_velocities(pos, quat, vel, mom, body, cx, par, counts)
    for i in range(n):
        for c in range(3):
            om[i, c] = mom[i, c] / body[i, B_MOMENTS + c]
    return True


@njit(cache=True, inline='always')
def constrained_step(method, pos0, quat0, vel0, om0, dt, body, gforce, wrench, flags, cx, par,
                     pos, quat, vel, om, lam, c_valid, counts, err):
    """
    One step of ``method`` with constraints; the new state goes to ``pos, quat, vel, om``.

    Parameters
    ----------
    method : int
        A method code of :mod:`.methods`.
    pos0, quat0, vel0, om0 : ndarray
        The state at the start (not modified); shapes (n, 3), (n, 4), (n, 3), (n, 3).
    dt : float
        s.
    body, gforce, wrench, flags
        The effects (see :mod:`.free_step`).
    cx : tuple
        The component's context ``(floats, ints, layout, key, solve)``: its rows,
        workspace (whose current geometry persists between calls), scratch and
        storages in the buffers of :func:`pack` (see the slots above). Two
        storages each, dense or tree as ``solve`` says (both for closed loops,
        the dense ones then hold the Schur complement of the loop-closing
        rows): ``GENERAL`` for SHAKE's factorizations, ``SYMMETRIC`` for the
        symmetric factor kept for the current geometry (see :func:`_sym_factor`).
        The workspace's ``WATCH`` (n,) marks the bodies some constraint touches
        (their rotation decides the sub-steps).
    par : ndarray
        Solver and sub-step parameters (see the module docstring).
    pos, quat, vel, om : ndarray
        Written: the state at the end.
    lam : ndarray, shape (m,)
        Written: the multipliers of the last acceleration-level solve.
    c_valid : bool
        The workspace's current geometry is that of ``pos0, quat0``.
    counts : ndarray of int64, shape (N_COUNTS,) or longer
        The work tally (slots above), added to.
    err : ndarray, shape (1,) or (0,)
        ``RKMK4`` with length 1: ``err[0]`` is raised to the largest embedded error
        estimate per unit time of the (sub)steps kept; ignored by the splittings.

    Returns
    -------
    bool
        Every entry of the new state is finite.

    """
    n = pos0.shape[0]
    max_rot = par[P_MAX_ROT]
    max_sub = int(par[P_MAX_SUB])
    watch = _i1(cx, WATCH)
    rate = 0.0
    for i in range(n):
        if watch[i]:
            for c in range(3):
                rate = max(rate, abs(om0[i, c]))
    # Compared as a float, before any int conversion: a huge, inf or NaN rate must
    # neither overflow it nor ask for unbounded work.
    want = rate * abs(dt) / max_rot
    if want <= max_sub:
        k = max(1, int(math.ceil(want)))
    else:
        counts[Count.CAPPED] += 1   # the work of one step stays bounded; the caller reports it
        k = max_sub
    valid0 = c_valid
    moving = _moving(cx)
    t_start, t_end = par[P_T_START], par[P_T_END]
    while True:
        last_resort = k >= max_sub
        if moving:
            _targets_at(cx, t_start)   # a redone step starts from the targets of its start
        _copy(pos0, pos)
        _copy(quat0, quat)
        _copy(vel0, vel)
        _copy(om0, om)
        c_valid = valid0
        ok = True
        if k > 1:
            counts[Count.SUBSTEPS] += k
        h = dt / k
        for j in range(k):
            # The (sub)step's times: the last one ends at the step's end exactly.
            s0 = t_start + j * h
            s1 = t_end if j == k - 1 else t_start + (j + 1) * h
            if method == Method.RKMK4:
                _rkmk4(pos, quat, vel, om, h, body, gforce, wrench, flags, cx, par, lam,
                       c_valid, counts, err, s0, s1)
            else:
                ok, c_valid = _splitting(method, pos, quat, vel, om, h, body, gforce, wrench,
                                         flags, cx, par, last_resort, lam, c_valid, counts,
                                         s0, s1)
                if not ok:
                    break
            c_valid = True
        if ok:
            break
        counts[Count.RETRIES] += 1
        k = min(2 * k, max_sub)
        valid0 = False   # the failed attempt overwrote the workspace's geometry
    normalize_quaternions(quat)
    return all_finite(pos, quat, vel, om)


def workspace(n: int, m: int, body: np.ndarray, e: int = 0) -> dict:
    """
    Arrays the constrained step works in, by name (allocated once per constraint set).

    ``phi`` (3, m), ``jac`` (3, 2, m + e, 6): Φ and G (its ``m + e`` parts, see
    :data:`.layout.ROWS`) of the geometries START, CURRENT and END; ``vm`` (4, m)
    vectors; ``xvec`` (3, e) the coupling parts' Φ, Φ̇, γ; ``gt_lambda`` (n, 6) Gᵀλ;
    ``free_acc`` (n, 6) free accelerations; ``force``, ``torque`` (n, 3);
    ``minv`` (n, 6) M⁻¹; ``factor_state`` (2,): [the symmetric factor is of the
    current geometry, its mode]; ``watch`` (n,): every body of the component.
    """
    minv6 = np.empty((n, 6))
    minv6[:, :3] = body[:, B_INV_MASS:B_INV_MASS + 1]
    minv6[:, 3:] = 1.0 / body[:, B_MOMENTS:B_MOMENTS + 3]
    return {'phi': np.zeros((3, m)), 'jac': np.zeros((3, 2, m + e, 6)), 'vm': np.zeros((4, m)),
            'xvec': np.zeros((3, e)),
            'gt_lambda': np.zeros((n, 6)), 'free_acc': np.zeros((n, 6)),
            'force': np.zeros((n, 3)), 'torque': np.zeros((n, 3)), 'minv': minv6,
            'factor_state': np.zeros(2, dtype=np.int64), 'watch': np.ones(n, dtype=np.int64)}


def scratch(n: int, m: int, parts: int) -> dict:
    """
    Scratch arrays of the constrained step, by name: nothing in them outlives a call.

    ``frames`` (n + 1, 3, 3) rotations, ``omega_world`` (n + 1, 3), ``jr`` (n, 3, 3)
    J_r, ``g2`` (2, parts, 6) G diag(I, J_r) (every part), ``vectors`` (2, m), ``body_vectors``
    (6, n, 3), ``quats`` (n, 4), ``stages`` (4, 5, n, 3) RKMK4 stages, ``rotor``
    (6, 3) rotor flow; they spare the step its allocations.
    """
    return {'frames': np.zeros((n + 1, 3, 3)), 'omega_world': np.zeros((n + 1, 3)),
            'jr': np.zeros((n, 3, 3)), 'g2': np.zeros((2, parts, 6)),
            'vectors': np.zeros((2, m)),
            'body_vectors': np.zeros((6, n, 3)), 'quats': np.zeros((n, 4)),
            'stages': np.zeros((4, 5, n, 3)), 'rotor': np.zeros((6, 3))}


def dense_storage(d: int) -> dict:
    """Dense factor storage by name: ``f``, ``u``, ``vt`` (d, d), ``piv``, ``s`` (d,)."""
    return {'f': np.zeros((d, d)), 'piv': np.zeros(d, dtype=np.int64), 'u': np.zeros((d, d)),
            's': np.zeros(d), 'vt': np.zeros((d, d))}


# ----------------------------------------------------------------------------------------
# Packed arguments. A compiled call from Python pays for every array it is passed (each is
# unboxed, typed and released: about 70 ns): a component's rows, workspace, scratch and two
# dense and two tree storages, 74 arrays, live in one float64 and one int64 buffer described
# by a layout table, and the compiled step takes views of them (see the context ``cx``).
# What is where: :data:`.layout.COMPONENT`.


def pack(rows: dict, ws: dict, dense: tuple, trees: tuple, nullspace: dict) -> tuple:
    """
    Copy a component's arrays into two buffers; return ``(packed, views)``.

    ``rows`` holds ``kind, comp, row_a, row_b, row_par`` (see :mod:`.rows`) and
    ``key`` (its generic rows, -1 if none); ``ws`` the workspace of
    :func:`workspace`, to which the scratch arrays of :func:`scratch` are added;
    ``dense`` and ``trees`` two storages each (:data:`.layout.STORAGES` order)
    of :func:`dense_storage` and :func:`tree_storage`, and ``nullspace`` the
    storage of :func:`nullspace_storage`. Every array is checked
    against :data:`.layout.COMPONENT` by name. ``packed`` is ``(key, floats,
    ints, layout)``, the arguments of :func:`packed_step`; ``views`` a dict of
    the same names, as views into the buffers (what the compiled step reads
    and writes).
    """
    n, m = ws['gt_lambda'].shape[0], ws['phi'].shape[1]
    named = {k: v for k, v in rows.items() if k != 'key'}
    named.update(ws)
    named.update(scratch(n, m, ws['jac'].shape[2]))
    for st, storage in zip(STORAGES, dense):
        named.update({f'{st}_dense_{k}': v for k, v in storage.items()})
    for st, storage in zip(STORAGES, trees):
        named.update({f'{st}_tree_{k}': v for k, v in storage.items()})
    named.update({f'nullspace_{k}': v for k, v in nullspace.items()})
    arrays = COMPONENT.check(named)
    layout = np.zeros((len(arrays), L_WIDTH), dtype=np.int64)
    sizes = {'f': 0, 'i': 0}
    for k, (x, field) in enumerate(zip(arrays, COMPONENT.fields)):
        layout[k, L_OFFSET] = sizes[field.kind]
        layout[k, L_SHAPE:L_SHAPE + x.ndim] = x.shape
        sizes[field.kind] += x.size
    floats, ints = np.zeros(sizes['f']), np.zeros(sizes['i'], dtype=np.int64)
    views = {}
    for k, (x, field) in enumerate(zip(arrays, COMPONENT.fields)):
        buf = floats if field.kind == 'f' else ints
        v = buf[layout[k, L_OFFSET]:layout[k, L_OFFSET] + x.size].reshape(x.shape)
        v[...] = x
        views[field.name] = v
    return (rows['key'], floats, ints, layout), views


@njit(cache=True)
def _v1(buf, L, k):
    return raw_slice(buf, L[k, L_OFFSET], (L[k, L_SHAPE],))


@njit(cache=True)
def _v2(buf, L, k):
    return raw_slice(buf, L[k, L_OFFSET], (L[k, L_SHAPE], L[k, L_SHAPE + 1]))


@njit(cache=True)
def _v3(buf, L, k):
    return raw_slice(buf, L[k, L_OFFSET], (L[k, L_SHAPE], L[k, L_SHAPE + 1], L[k, L_SHAPE + 2]))


@njit(cache=True)
def _v4(buf, L, k):
    return raw_slice(buf, L[k, L_OFFSET],
                     (L[k, L_SHAPE], L[k, L_SHAPE + 1], L[k, L_SHAPE + 2], L[k, L_SHAPE + 3]))


@njit(cache=True)
def _tree_views(f, i, L, k):
    """Return the tree storage starting at slot ``k``, a tuple indexed by the ``T_*`` slots."""
    return (_v1(i, L, k + T_GROUP_PTR), _v1(i, L, k + T_GROUP_ROWS),
            _v1(i, L, k + T_GROUP_CHILD), _v1(i, L, k + T_GROUP_PARENT),
            _v1(i, L, k + T_ROW_SIDE), _v3(f, L, k + T_S), _v2(i, L, k + T_PIV),
            _v3(f, L, k + T_P), _v3(f, L, k + T_Q), _v4(f, L, k + T_B), _v3(f, L, k + T_W),
            _v3(f, L, k + T_E), _v1(f, L, k + T_TMP), _v1(i, L, k + T_CLOSURE),
            _v2(f, L, k + T_X), _v2(f, L, k + T_Y), _v1(f, L, k + T_WORK), _v3(f, L, k + T_G),
            _v1(f, L, k + T_Z), _v1(f, L, k + T_XC))


def tree_storage(structure, closure: np.ndarray, m: int, n: int) -> dict:
    """
    One tree storage of a component of ``m`` rows and ``n`` bodies (:data:`.layout.TREE`).

    ``structure``: the :class:`..graph.TreeStructure` of the forest (its
    arrays and the factors of :func:`.tree_solve.factor_arrays`); ``closure``:
    the rows that close loops (empty for a forest), for which the storage also
    holds ``x``, ``y`` (c, m), ``work`` (m,), ``g`` (2, n, 6) and the vectors
    ``z``, ``xc`` (c,) of :mod:`.loop_solve`.
    """
    c = closure.shape[0]
    arrays = (*structure.arrays, *factor_arrays(structure), closure.astype(np.int64),
              np.zeros((c, m)), np.zeros((c, m)), np.zeros(m), np.zeros((2, n, 6)), np.zeros(c),
              np.zeros(c))
    if len(arrays) != len(TREE_FIELDS):
        raise ValueError(f'tree storage: expected {len(TREE_FIELDS)} arrays, got {len(arrays)}')
    return dict(zip((f.name for f in TREE_FIELDS.fields), arrays))


def nullspace_storage(structure, n: int) -> dict:
    """
    Return the null-space storage of a component of ``n`` bodies (:data:`.layout.NULLSPACE`).

    ``structure``: the joints of :func:`.nullspace_solve.nullspace_structure`, or
    None (the component takes the row-space tree solve: no joints, empty factors).
    """
    if structure is None:
        structure = (np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64),
                     np.zeros(0, dtype=np.int64), np.zeros((0, N_SLOTS), dtype=np.int64),
                     np.zeros((0, N_SLOTS), dtype=np.int64))
        n = 0
    nj = len(structure[0])
    arrays = (*structure, *nullspace_arrays(nj, n), *shake_arrays(nj, n),
              np.zeros((n + 1, 3, 3)))
    if len(arrays) != len(NULLSPACE_FIELDS):
        raise ValueError(f'null-space storage: expected {len(NULLSPACE_FIELDS)} arrays, '
                         f'got {len(arrays)}')
    return dict(zip((f.name for f in NULLSPACE_FIELDS.fields), arrays))


# ----------------------------------------------------------------------------------------
# The other uses of a component's solve, outside a step: the multipliers at a state (the
# reactions a user reads), the velocity projection (reset, a new joint) and the Gauss-Newton
# search that decides whether constraints can hold together. Each is the step's own code
# (its geometry, factorizations and solves) on the component's packed buffers.


@njit(cache=True)
def component_multipliers(pos, quat, vel, om, body, gforce, wrench, flags, par, solve, key,
                          floats, ints, layout, c_valid, lam, counts):
    """
    λ (m,) at a state: the acceleration-level multipliers a kick there would use.

    Free accelerations of every effect (:func:`_free_accelerations`), then
    :func:`_multipliers`, as in :func:`_kick`. ``c_valid``: the workspace's
    current geometry is of ``pos, quat`` (a step ended there), so it is reused,
    with the symmetric factor if the step left one; otherwise both are computed
    here. Afterwards the workspace holds the geometry ``G`` (slot ``JAC``,
    ``CURRENT``) and ``Gᵀλ`` (``GT_LAMBDA``) of this state.
    """
    cx = (raw(floats), raw(ints), raw(layout), key, solve)   # CONTEXT's order
    _free_accelerations(pos, quat, vel, om, body, gforce, wrench, flags, _f2(cx, FREE_ACC),
                        _f2(cx, FORCE), _f2(cx, TORQUE), counts)
    if not c_valid:
        _geometry(pos, quat, cx, CURRENT, counts)
    _multipliers(pos, quat, vel, om, cx, par, lam, counts)


@njit(cache=True)
def component_project_velocities(pos, quat, vel, om, body, par, solve, key, floats, ints,
                                 layout, c_valid, counts):
    """
    Project ``vel``, ``om`` (in place) onto ``Φ̇ = −ωΦ``: the step's :func:`_project_velocities`.

    The mass-weighted minimum-norm change (a perfectly inelastic impact, which
    conserves momenta). ``c_valid`` as for :func:`component_multipliers`.
    """
    cx = (raw(floats), raw(ints), raw(layout), key, solve)   # CONTEXT's order
    if not c_valid:
        _geometry(pos, quat, cx, CURRENT, counts)
    mom = _f3(cx, BODY_VECTORS)[0]
    n = pos.shape[0]
    for i in range(n):
        for c in range(3):
            mom[i, c] = om[i, c] * body[i, B_MOMENTS + c]
    _project_velocities(pos, quat, vel, mom, body, cx, par, counts)
    for i in range(n):
        for c in range(3):
            om[i, c] = mom[i, c] / body[i, B_MOMENTS + c]


@njit(cache=True)
def component_reach(pos, quat, tolerance, max_iterations, par, solve, key, floats, ints,
                    layout, counts):
    """
    Smallest ``max |Φ|`` Gauss–Newton reaches from ``pos, quat`` (not modified).

    Minimum-norm steps ``δ = −M⁻¹ Gᵀ (G M⁻¹ Gᵀ)⁺ Φ`` (redundant rows: the
    truncated SVD of a dense system, the Tikhonov term of the tree solve, as in
    a step) converge quadratically to ``Φ = 0`` when the constraints can hold
    together; for an inconsistent set they stall at the least-squares
    compromise. Stops below ``tolerance``, after three iterations that do not
    reduce the residual, or after ``max_iterations``. Leaves the workspace's
    current geometry at the last iterate (not of the state).
    """
    cx = (raw(floats), raw(ints), raw(layout), key, solve)   # CONTEXT's order
    pos, quat = pos.copy(), quat.copy()
    n = pos.shape[0]
    vm, g6, minv6 = _f2(cx, VM), _f2(cx, GT_LAMBDA), _f2(cx, MINV)
    phi3, G = _f2(cx, PHI), _f4(cx, JAC)
    a, b = _i1(cx, ROW_A), _i1(cx, ROW_B)
    best, stalled = np.inf, 0
    for _ in range(max_iterations + 1):
        _geometry(pos, quat, cx, CURRENT, counts)
        phi, Ga, Gb = phi3[CURRENT], G[CURRENT, 0], G[CURRENT, 1]
        norm = 0.0
        for r in range(phi.shape[0]):
            if not abs(phi[r]) < np.inf:
                return best   # not finite: the last finite iterate's residual
            norm = max(norm, abs(phi[r]))
        if norm <= tolerance:
            return min(best, norm)
        # Far from the solution one step may overshoot; three without progress stall.
        stalled = stalled + 1 if norm >= (1.0 - 1e-6) * best else 0
        best = min(best, norm)
        if stalled == 3:
            return best
        mode = _fac(Ga, Gb, Ga, Gb, a, b, _own(cx), minv6, True, par, cx, GENERAL, counts)
        _sol(mode, phi, vm[V_SOLUTION], cx, GENERAL)
        _gt_lambda(Ga, Gb, a, b, _own(cx), vm[V_SOLUTION], g6)
        for i in range(n):
            for c in range(3):
                pos[i, c] -= minv6[i, c] * g6[i, c]
            quat_exp_multiply(quat[i], -minv6[i, 3] * g6[i, 3], -minv6[i, 4] * g6[i, 4],
                              -minv6[i, 5] * g6[i, 5], quat[i])
            s = math.sqrt(quat[i, 0] ** 2 + quat[i, 1] ** 2 + quat[i, 2] ** 2 + quat[i, 3] ** 2)
            for c in range(4):
                quat[i, c] /= s
    return best


@njit(cache=True)
def packed_step(method, pos0, quat0, vel0, om0, dt, body, gforce, wrench, flags, par,
                solve, key, floats, ints, layout, pos, quat, vel, om, lam, c_valid, counts,
                err, frames, out):
    """
    :func:`constrained_step` with a component's arrays packed by :func:`pack`.

    ``key, floats, ints, layout`` replace ``rows, watch, tree, dense, ws``;
    ``solve`` (``SOLVE_DENSE``, ``SOLVE_TREE`` or ``SOLVE_LOOP``) says which
    storages are in use. With ``n`` rows, ``out`` (n, 19) gets the
    :func:`.free_step.outputs` of the new state (``frames`` (n, 7)); with none,
    nothing. Returns whether every entry of the new state is finite.
    """
    finite = _packed_step(method, pos0, quat0, vel0, om0, dt, body, gforce, wrench, flags,
                          par, solve, key, floats, ints, layout, pos, quat, vel, om, lam,
                          c_valid, counts, err)
    if out.shape[0]:
        outputs(pos, quat, vel, om, frames, out)
    return finite


def component_table(method: int, model: tuple, par: np.ndarray, solve: int, packed: tuple,
                    lam: np.ndarray, counts: np.ndarray, frames: np.ndarray, out: np.ndarray,
                    key: object) -> Pinned:
    """
    Pin the arrays of :func:`pinned_packed_step` (:data:`.layout.COMPONENT_TABLE`).

    ``model`` is ``(body, gforce, wrench, flags)``, ``packed`` the ``(key, floats,
    ints, layout)`` of :func:`pack`; the others are arguments of
    :func:`packed_step`, ``out`` with all ``n`` rows.
    """
    body, gforce, wrench, flags = model
    generic, floats, ints, layout = packed
    return COMPONENT_TABLE.pin(
        key, body=body, gforce=gforce, wrench=wrench, par=par, floats=floats, ints=ints,
        layout=layout, lam=lam, counts=counts, frames=frames, out=out, n_wrench=len(wrench),
        flags=flags, method=method, solve=solve, generic=generic, n_par=len(par),
        n_floats=len(floats), n_ints=len(ints), n_layout=len(layout), n_lam=len(lam),
        n_counts=len(counts))


@njit(cache=True)
def pinned_packed_step(y0, y, dt, c_valid, with_outputs, err, table):
    """
    :func:`packed_step` from the state buffer ``y0`` to ``y`` (:func:`state_parts`).

    Its other arrays are in the table of :func:`component_table`.
    ``with_outputs``: the outputs of the new state are written to the table's
    ``out``. Returns whether every entry of the new state is finite.
    """
    pos0, quat0, vel0, om0 = state_parts(y0)
    pos, quat, vel, om = state_parts(y)
    n, t = pos0.shape[0], table
    return packed_step(
        t[CT_METHOD], pos0, quat0, vel0, om0, dt, pinned(t, CT_BODY, (n, B_WIDTH)),
        pinned(t, CT_GFORCE, (n, 3)), pinned(t, CT_WRENCH, (t[CT_N_WRENCH], W_WIDTH)),
        t[CT_FLAGS], pinned(t, CT_PAR, (t[CT_N_PAR],)), t[CT_SOLVE], t[CT_GENERIC],
        pinned(t, CT_FLOATS, (t[CT_N_FLOATS],)), pinned_int(t, CT_INTS, (t[CT_N_INTS],)),
        pinned_int(t, CT_LAYOUT, (t[CT_N_LAYOUT], L_WIDTH)), pos, quat, vel, om,
        pinned(t, CT_LAM, (t[CT_N_LAM],)), c_valid, pinned_int(t, CT_COUNTS, (t[CT_N_COUNTS],)),
        err, pinned(t, CT_FRAMES, (n, FR_WIDTH)),
        pinned(t, CT_OUT, (n if with_outputs else 0, O_WIDTH)))


@njit(cache=True)
def _packed_step(method, pos0, quat0, vel0, om0, dt, body, gforce, wrench, flags, par,
                 solve, key, floats, ints, layout, pos, quat, vel, om, lam, c_valid, counts,
                 err):
    """:func:`packed_step` without the outputs."""
    pos0, quat0, vel0, om0 = raw(pos0), raw(quat0), raw(vel0), raw(om0)
    pos, quat, vel, om = raw(pos), raw(quat), raw(vel), raw(om)
    body, gforce, wrench, par = raw(body), raw(gforce), raw(wrench), raw(par)
    lam, counts, err = raw(lam), raw(counts), raw(err)
    cx = (raw(floats), raw(ints), raw(layout), key, solve)   # CONTEXT's order
    return constrained_step(method, pos0, quat0, vel0, om0, dt, body, gforce, wrench, flags,
                            cx, par, pos, quat, vel, om, lam, c_valid, counts, err)
