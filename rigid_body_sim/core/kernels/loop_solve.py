"""
Sparse solve of ``(G M⁻¹ Hᵀ + reg I) x = rhs`` for constraint graphs with closed loops.

Conventions are those of :mod:`.tree_solve` (rows act on bodies ``a[r]`` and
``b[r]``, ``b[r] == n`` the world; blocks ``Ga, Gb, Ha, Hb`` (m + e, 6) with the
coupling parts after the m rows; diagonal inverse masses ``minv6`` (n, 6)).

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
from the row blocks: a column of ``A_TC`` is ``G_T`` applied to the impulse
response ``M⁻¹ H_jᵀ``, non-zero only on the forest rows that share a body with
closure row ``j``. A row that couples more than two bodies (a mimic joint's,
made of parts, see :data:`.layout.ROWS`) is always a closure row: its response
is the sum of its parts'. The cost is a tree factorization plus ``c`` tree
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
def _responses(j, a, b, own, Ga, Gb, Ha, Hb, minv6, g):
    """
    ``g[0] = M⁻¹ H_jᵀ`` and ``g[1] = M⁻¹ G_jᵀ`` (each (n, 6)) of row ``j``, over all its parts.

    A row's parts are its own (``j``) and the coupling parts after the ``m`` rows
    that add to it (``own[r] == j``, see :data:`.layout.ROWS`).
    """
    n = minv6.shape[0]
    for i in range(n):
        for t in range(6):
            g[0, i, t] = 0.0
            g[1, i, t] = 0.0
    for r in range(Ga.shape[0]):
        if own[r] != j:
            continue
        for t in range(6):
            g[0, a[r], t] += minv6[a[r], t] * Ha[r, t]
            g[1, a[r], t] += minv6[a[r], t] * Ga[r, t]
        if b[r] < n:
            for t in range(6):
                g[0, b[r], t] += minv6[b[r], t] * Hb[r, t]
                g[1, b[r], t] += minv6[b[r], t] * Gb[r, t]


@njit(cache=True)
def _part_times(r, a, b, Ga, Gb, n, v):
    """Part ``r``'s blocks applied to a generalized vector ``v`` (n, 6)."""
    s = 0.0
    for t in range(6):
        s += Ga[r, t] * v[a[r], t]
    if b[r] < n:
        for t in range(6):
            s += Gb[r, t] * v[b[r], t]
    return s


@njit(cache=True)
def loop_column(k, group_rows, closure, a, b, own, Ga, Gb, Ha, Hb, minv6, reg, X, Y, F, work,
                g):
    """
    Column ``k`` of :func:`loop_schur` up to its forest solve (any solve of ``A_TT``).

    Writes row ``k`` of ``Y = A_CT``, column ``k`` of ``A_CC + reg I`` into ``F``,
    zeroes row ``k`` of ``X`` and puts column ``k`` of ``A_TC`` into ``work`` (at
    the forest rows; zero elsewhere): the caller solves ``A_TT`` in place on
    ``work``, then calls :func:`loop_column_solved`.
    """
    m = X.shape[1]
    n = minv6.shape[0]
    c = closure.shape[0]
    j = closure[k]
    _responses(j, a, b, own, Ga, Gb, Ha, Hb, minv6, g)
    for r in range(m):
        X[k, r] = 0.0
        Y[k, r] = 0.0
        work[r] = 0.0
    # Row k of A_CT (closure row j applied to each forest row's impulse response,
    # H_r M⁻¹ G_jᵀ), and column k of A_TC (G_r M⁻¹ H_jᵀ), to be solved.
    for r in group_rows:
        Y[k, r] = _part_times(r, a, b, Ha, Hb, n, g[1])
        work[r] = _part_times(r, a, b, Ga, Gb, n, g[0])
    # Column k of A_CC: each closure row's parts applied to M⁻¹ H_jᵀ.
    for i in range(c):
        F[i, k] = _part_times(closure[i], a, b, Ga, Gb, n, g[0])
    for r in range(m, Ga.shape[0]):
        for i in range(c):
            if own[r] == closure[i]:
                F[i, k] += _part_times(r, a, b, Ga, Gb, n, g[0])
    F[k, k] += reg


@njit(cache=True)
def loop_column_solved(k, group_rows, X, work):
    """Row ``k`` of ``X``: the solved column ``A_TT⁻¹ A_TC e_k`` in ``work`` (forest rows)."""
    for r in group_rows:
        X[k, r] = work[r]


@njit(cache=True)
def loop_close(group_rows, X, Y, F):
    """Finish the Schur complement: ``F −= A_CT X`` (every column of X and Y written)."""
    c = F.shape[0]
    for i in range(c):
        for k in range(c):
            s = 0.0
            for r in group_rows:
                s += Y[i, r] * X[k, r]
            F[i, k] -= s


@njit(cache=True)
def loop_schur(group_ptr, group_rows, group_child, group_parent, S, piv, P, Q, B, E, tmp,
               closure, a, b, own, Ga, Gb, Ha, Hb, minv6, reg, X, Y, F, work, g):
    """
    Given the tree factors of ``A_TT``, compute ``X``, ``Y = A_CT`` and ``F = S``.

    Per closure row :func:`loop_column`, the tree solve, :func:`loop_column_solved`;
    then :func:`loop_close` (another solve of ``A_TT``, such as the inertia form of
    :mod:`.nullspace_solve`, takes the tree solve's place the same way).

    Parameters
    ----------
    group_ptr, group_rows, group_child, group_parent, S, piv, P, Q, B, E, tmp
        The forest's structure and its factors (:func:`.tree_solve.tree_factor` of
        the same ``G, H, minv6, reg``) and the solve's workspace.
    closure : ndarray of int64, shape (c,)
        The closure rows (:class:`..graph.LoopStructure`).
    a, b, own, Ga, Gb, Ha, Hb, minv6, reg
        The system (see the module docstring): ``m + e`` parts, part ``r`` adding
        to row ``own[r]`` (:data:`.layout.ROWS`); the forest rows have no other part.
    X : ndarray, shape (c, m)
        Written: column ``k`` of ``A_TT⁻¹ A_TC`` as row ``k`` (zero at closure rows).
    Y : ndarray, shape (c, m)
        Written: ``A_CT`` (zero at closure rows); only the rows of the forest that
        share a body with a closure row are non-zero.
    F : ndarray, shape (c, c)
        Written: the Schur complement ``A_CC + reg I − A_CT X``.
    work : ndarray, shape (m,)
        Workspace (overwritten).
    g : ndarray, shape (2, n, 6)
        Workspace (overwritten).

    """
    for k in range(closure.shape[0]):
        loop_column(k, group_rows, closure, a, b, own, Ga, Gb, Ha, Hb, minv6, reg, X, Y, F,
                    work, g)
        tree_solve(group_ptr, group_rows, group_child, group_parent, S, piv, P, Q, B, E, tmp,
                   work, work)
        loop_column_solved(k, group_rows, X, work)
    loop_close(group_rows, X, Y, F)


@njit(cache=True)
def loop_rhs(closure, rhs, z):
    """Before a solve's forest solve: ``z = rhs_C`` (``rhs`` may then be overwritten)."""
    for k in range(closure.shape[0]):
        z[k] = rhs[closure[k]]


@njit(cache=True)
def loop_reduce(group_rows, closure, Y, out, z):
    """After it (``out_T = A_TT⁻¹ rhs_T``): ``z −= A_CT out_T``, the rhs of ``S x_C = z``."""
    for k in range(closure.shape[0]):
        s = 0.0
        for r in group_rows:
            s += Y[k, r] * out[r]
        z[k] -= s


@njit(cache=True)
def loop_forward(group_ptr, group_rows, group_child, group_parent, S, piv, P, Q, B, E, tmp,
                 closure, Y, rhs, out, z):
    """
    First half of a solve: ``out_T = A_TT⁻¹ rhs_T`` and ``z = rhs_C − A_CT out_T``.

    ``out`` (m,) may be ``rhs``; ``z`` (c,) is the right-hand side of ``S x_C = z``
    (solved by the caller), then :func:`loop_back` finishes. :func:`loop_rhs` and
    :func:`loop_reduce` around the tree solve (or another solve of ``A_TT``).
    """
    loop_rhs(closure, rhs, z)
    tree_solve(group_ptr, group_rows, group_child, group_parent, S, piv, P, Q, B, E, tmp,
               rhs, out)
    loop_reduce(group_rows, closure, Y, out, z)


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
