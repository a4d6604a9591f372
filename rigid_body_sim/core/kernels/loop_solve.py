"""
Sparse solve of ``(G M⁻¹ Hᵀ + reg I) x = rhs`` for constraint graphs with closed loops.

Conventions are those of :mod:`.tree_solve` (rows act on bodies ``a[r]`` and
``b[r]``, ``b[r] == n`` the world; blocks ``Ga, Gb, Ha, Hb`` (m, 6); diagonal
inverse masses ``minv6`` (n, 6)).

Method
------
The groups of rows between two bodies (joints) form a graph on the bodies; a
closed loop is a cycle of it (rows to the world never close one: the world does
not move, so it couples no rows). :func:`..graph.loop_structure` takes a
spanning forest of that graph, whose rows ``T`` the tree solve of
:mod:`.tree_solve` factorizes in linear time, and leaves out the ``c`` rows
``C`` of the groups that close the loops. With ``A = G M⁻¹ Hᵀ + reg I``
partitioned accordingly, block elimination (the Schur complement of ``A_TT``,
as in the capacitance-matrix method) gives::

    X = A_TT⁻¹ A_TC                       (c tree solves)
    S = A_CC − A_CT X                     (c x c, dense)
    y = A_TT⁻¹ rhs_T,   S x_C = rhs_C − A_CT y,   x_T = y − X x_C

The blocks ``A_TC = G_T M⁻¹ H_Cᵀ`` and ``A_CT = G_C M⁻¹ H_Tᵀ`` are computed
from the row blocks: a column of ``A_TC`` is ``G_T`` applied to the (two-body)
impulse response ``M⁻¹ H_jᵀ``, non-zero only on the forest rows that share a
body with closure row ``j``. The cost is a tree factorization plus ``c`` tree
solves and the products with ``X`` and ``A_CT`` (kept as (c, m) arrays, so a
solve needs no blocks), ``O(c² m)``, and a dense ``c³``
factorization of ``S`` (by the caller: :mod:`.constrained_step` factors it
as it factors a small dense system, with a truncated SVD when closure rows are
redundant, as in a planar loop modelled in 3D); linear in the size of the
mechanism for a fixed number of loops, where a dense solve is ``O(m³)``.

The kernels are compiled with numba (``@njit(cache=True)``), take only arrays
and scalars, and allocate nothing.
"""

from __future__ import annotations

from numba import njit

from .tree_solve import tree_solve


@njit(cache=True)
def _response(r, a, b, Hblock_a, Hblock_b, minv6, n, g):
    """``g`` (2, 6): ``M⁻¹ H_rᵀ`` on bodies ``a[r]`` (row 0) and ``b[r]`` (row 1)."""
    for t in range(6):
        g[0, t] = minv6[a[r], t] * Hblock_a[r, t]
        g[1, t] = minv6[b[r], t] * Hblock_b[r, t] if b[r] < n else 0.0


@njit(cache=True)
def _apply(i, a, b, Ga, Gb, n, body0, body1, g):
    """``G_i`` applied to a response ``g`` on bodies ``body0`` (g[0]) and ``body1`` (g[1])."""
    s = 0.0
    for side in range(2):
        bi = a[i] if side == 0 else b[i]
        if bi >= n:
            continue
        for k in range(2):
            bk = body0 if k == 0 else body1
            if bk == bi and bk < n:
                for t in range(6):
                    s += (Ga[i, t] if side == 0 else Gb[i, t]) * g[k, t]
    return s


@njit(cache=True)
def loop_schur(group_ptr, group_rows, group_child, group_parent, S, piv, P, Q, B, E, tmp,
               closure, a, b, Ga, Gb, Ha, Hb, minv6, reg, X, Y, F, work, g):
    """
    Given the tree factors of ``A_TT``, compute ``X``, ``Y = A_CT`` and ``F = S``.

    Parameters
    ----------
    group_ptr, group_rows, group_child, group_parent, S, piv, P, Q, B, E, tmp
        The forest's structure and its factors (:func:`.tree_solve.tree_factor` of
        the same ``G, H, minv6, reg``) and the solve's workspace.
    closure : ndarray of int64, shape (c,)
        The closure rows (:class:`..graph.LoopStructure`).
    a, b, Ga, Gb, Ha, Hb, minv6, reg
        The system (see the module docstring).
    X : ndarray, shape (c, m)
        Written: column ``k`` of ``A_TT⁻¹ A_TC`` as row ``k`` (zero at closure rows).
    Y : ndarray, shape (c, m)
        Written: ``A_CT`` (zero at closure rows); only the rows of the forest that
        share a body with a closure row are non-zero.
    F : ndarray, shape (c, c)
        Written: the Schur complement ``A_CC + reg I − A_CT X``.
    work : ndarray, shape (m,)
        Workspace (overwritten).
    g : ndarray, shape (2, 6)
        Workspace (overwritten).

    """
    m = Ga.shape[0]
    n = minv6.shape[0]
    c = closure.shape[0]
    for k in range(c):
        j = closure[k]
        for r in range(m):
            X[k, r] = 0.0
            Y[k, r] = 0.0
        # Row k of A_CT: closure row j applied to each forest row's impulse response.
        for r in group_rows:
            if a[r] == a[j] or a[r] == b[j] or (b[r] < n and (b[r] == a[j] or b[r] == b[j])):
                _response(r, a, b, Ha, Hb, minv6, n, g)
                Y[k, r] = _apply(j, a, b, Ga, Gb, n, a[r], b[r], g)
        # Column k of A_TC: the forest rows' response to an impulse along H_jᵀ, solved.
        _response(j, a, b, Ha, Hb, minv6, n, g)
        for r in range(m):
            work[r] = 0.0
        for r in group_rows:
            if a[r] == a[j] or a[r] == b[j] or (b[r] < n and (b[r] == a[j] or b[r] == b[j])):
                work[r] = _apply(r, a, b, Ga, Gb, n, a[j], b[j], g)
        tree_solve(group_ptr, group_rows, group_child, group_parent, S, piv, P, Q, B, E, tmp,
                   work, work)
        for r in group_rows:
            X[k, r] = work[r]
        # Column k of A_CC.
        for i in range(c):
            F[i, k] = _apply(closure[i], a, b, Ga, Gb, n, a[j], b[j], g)
        F[k, k] += reg
    # S = A_CC + reg I − A_CT X.
    for i in range(c):
        for k in range(c):
            s = 0.0
            for r in group_rows:
                s += Y[i, r] * X[k, r]
            F[i, k] -= s


@njit(cache=True)
def loop_forward(group_ptr, group_rows, group_child, group_parent, S, piv, P, Q, B, E, tmp,
                 closure, Y, rhs, out, z):
    """
    First half of a solve: ``out_T = A_TT⁻¹ rhs_T`` and ``z = rhs_C − A_CT out_T``.

    ``out`` (m,) may be ``rhs``; ``z`` (c,) is the right-hand side of ``S x_C = z``
    (solved by the caller), then :func:`loop_back` finishes.
    """
    c = closure.shape[0]
    for k in range(c):
        z[k] = rhs[closure[k]]
    tree_solve(group_ptr, group_rows, group_child, group_parent, S, piv, P, Q, B, E, tmp,
               rhs, out)
    for k in range(c):
        s = 0.0
        for r in group_rows:
            s += Y[k, r] * out[r]
        z[k] -= s


@njit(cache=True)
def loop_back(group_rows, closure, X, x_closure, out):
    """Second half: ``out_C = x_C`` and ``out_T −= X x_C``."""
    c = closure.shape[0]
    for k in range(c):
        v = x_closure[k]
        out[closure[k]] = v
        if v != 0.0:
            for r in group_rows:
                out[r] -= X[k, r] * v
