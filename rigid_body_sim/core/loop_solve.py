"""
Sparse solve of ``(G M⁻¹ Hᵀ + reg I) x = rhs`` for constraint graphs with closed loops.

Conventions are those of :mod:`.tree_solve` (rows act on bodies ``a[r]`` and
``b[r]``, ``b[r] == n`` the world; blocks ``Ga, Gb, Ha, Hb`` (m, 6); diagonal
inverse masses ``minv6`` (n, 6)).

Method
------
The groups of rows between two bodies (joints) form a graph on the bodies; a
closed loop is a cycle of it (rows to the world never close one: the world does
not move, so it couples no rows). :func:`loop_structure` takes a spanning forest
of that graph, whose rows ``T`` the tree solve of :mod:`.tree_solve` factorizes
in linear time, and leaves out the ``c`` rows ``C`` of the groups that close the
loops. With ``A = G M⁻¹ Hᵀ + reg I`` partitioned accordingly, block elimination
(the Schur complement of ``A_TT``, as in the capacitance-matrix method) gives::

    X = A_TT⁻¹ A_TC                       (c tree solves)
    S = A_CC − A_CT X                     (c x c, dense)
    y = A_TT⁻¹ rhs_T,   S x_C = rhs_C − A_CT y,   x_T = y − X x_C

The blocks ``A_TC = G_T M⁻¹ H_Cᵀ`` and ``A_CT = G_C M⁻¹ H_Tᵀ`` are never formed
as matrices: a column of ``A_TC`` is ``G_T`` applied to the (two-body) impulse
response ``M⁻¹ H_jᵀ``, and ``A_CT y`` is ``G_C M⁻¹ (H_Tᵀ y)``. The cost is a
tree factorization plus ``c`` tree solves, ``O(c m)``, and a dense ``c³``
factorization of ``S`` (by the caller: :mod:`.constrained_kernels` factors it
as it factors a small dense system, with a truncated SVD when closure rows are
redundant, as in a planar loop modelled in 3D); linear in the size of the
mechanism for a fixed number of loops, where a dense solve is ``O(m³)``.

The kernels are compiled with numba (``@njit(cache=True)``), take only arrays
and scalars, and allocate nothing.
"""

from __future__ import annotations

from typing import NamedTuple, Optional

from numba import njit
import numpy as np

from .tree_solve import tree_solve, tree_structure, TreeStructure


class LoopStructure(NamedTuple):
    """
    A spanning forest of the constraint graph and the rows that close its loops.

    Attributes
    ----------
    tree : TreeStructure
        The tree solve's structure of the forest's rows, in the numbering of
        all ``m`` rows (the closure rows are in no group).
    closure : ndarray of int64, shape (c,)
        The rows of the groups left out of the forest, ascending.

    """

    tree: TreeStructure
    closure: np.ndarray


def loop_structure(a, b, n_bodies: int) -> Optional[LoopStructure]:
    """
    Split the rows into a spanning forest and loop-closing rows (plain Python, per set).

    Groups are taken in the order of their first row; a group whose two bodies
    are already connected closes a loop. Returns None when there is no loop
    (use :func:`.tree_solve.tree_structure` alone).
    """
    a = np.asarray(a, dtype=np.int64).ravel()
    b = np.asarray(b, dtype=np.int64).ravel()
    n = int(n_bodies)
    root = list(range(n))

    def find(i: int) -> int:
        while root[i] != i:
            root[i] = root[root[i]]
            i = root[i]
        return i

    closing: dict = {}   # pair -> closes a loop
    for ar, br in zip(a.tolist(), b.tolist()):
        if br == n or br == ar:
            continue
        key = (min(ar, br), max(ar, br))
        if key in closing:
            continue
        ri, rj = find(ar), find(br)
        closing[key] = ri == rj
        if ri != rj:
            root[ri] = rj
    closure = np.array([r for r in range(a.size)
                        if b[r] != n and b[r] != a[r]
                        and closing[(min(a[r], b[r]), max(a[r], b[r]))]], dtype=np.int64)
    if not closure.size:
        return None
    keep = np.setdiff1d(np.arange(a.size), closure)
    sub = tree_structure(a[keep], b[keep], n)
    side = np.zeros(a.size, dtype=np.int64)
    side[keep] = sub.row_side
    group = np.full(a.size, -1, dtype=np.int64)
    group[keep] = sub.row_group
    tree = sub._replace(group_rows=keep[sub.group_rows], row_side=side, row_group=group)
    return LoopStructure(tree, closure)


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
def _transpose_times(tree_rows, a, b, Ha, Hb, y, f):
    """``f`` (n, 6) = ``H_Tᵀ y`` over the rows ``tree_rows`` (overwritten)."""
    n = f.shape[0]
    for i in range(n):
        for t in range(6):
            f[i, t] = 0.0
    for r in tree_rows:
        v = y[r]
        if v != 0.0:
            for t in range(6):
                f[a[r], t] += Ha[r, t] * v
            if b[r] < n:
                for t in range(6):
                    f[b[r], t] += Hb[r, t] * v


@njit(cache=True)
def _closure_times(closure, a, b, Ga, Gb, minv6, f, out):
    """``out[j] = G_j M⁻¹ f`` for the closure rows ``j`` (``f`` (n, 6))."""
    n = f.shape[0]
    for k in range(closure.shape[0]):
        j = closure[k]
        s = 0.0
        for t in range(6):
            s += Ga[j, t] * minv6[a[j], t] * f[a[j], t]
        if b[j] < n:
            for t in range(6):
                s += Gb[j, t] * minv6[b[j], t] * f[b[j], t]
        out[k] = s


@njit(cache=True)
def loop_schur(group_ptr, group_rows, group_child, group_parent, S, piv, P, Q, B, E, tmp,
               closure, a, b, Ga, Gb, Ha, Hb, minv6, reg, X, F, work, f, g):
    """
    Given the tree factors of ``A_TT``, compute ``X = A_TT⁻¹ A_TC`` and ``F = S``.

    Parameters
    ----------
    group_ptr, group_rows, group_child, group_parent, S, piv, P, Q, B, E, tmp
        The forest's structure and its factors (:func:`.tree_solve.tree_factor` of
        the same ``G, H, minv6, reg``) and the solve's workspace.
    closure : ndarray of int64, shape (c,)
        The closure rows (:class:`LoopStructure`).
    a, b, Ga, Gb, Ha, Hb, minv6, reg
        The system (see the module docstring).
    X : ndarray, shape (c, m)
        Written: column ``k`` of ``A_TT⁻¹ A_TC`` as row ``k`` (zero at closure rows).
    F : ndarray, shape (c, c)
        Written: the Schur complement ``A_CC + reg I − A_CT X``.
    work : ndarray, shape (m,)
        Workspace (overwritten).
    f, g : ndarray, shapes (n, 6) and (2, 6)
        Workspace (overwritten).

    """
    m = Ga.shape[0]
    n = minv6.shape[0]
    c = closure.shape[0]
    for k in range(c):
        j = closure[k]
        # Column j of A: the tree rows' response to an impulse along H_jᵀ.
        _response(j, a, b, Ha, Hb, minv6, n, g)
        for r in range(m):
            work[r] = 0.0
        for r in group_rows:
            work[r] = _apply(r, a, b, Ga, Gb, n, a[j], b[j], g)
        tree_solve(group_ptr, group_rows, group_child, group_parent, S, piv, P, Q, B, E, tmp,
                   work, work)
        for r in range(m):
            X[k, r] = 0.0
        for r in group_rows:
            X[k, r] = work[r]
        # Column k of S: A_CC[:, k] + reg e_k − A_CT X_k (A_CT X_k into work[:c]).
        _transpose_times(group_rows, a, b, Ha, Hb, work, f)
        _closure_times(closure, a, b, Ga, Gb, minv6, f, work)
        for i in range(c):
            F[i, k] = _apply(closure[i], a, b, Ga, Gb, n, a[j], b[j], g) - work[i]
        F[k, k] += reg


@njit(cache=True)
def loop_forward(group_ptr, group_rows, group_child, group_parent, S, piv, P, Q, B, E, tmp,
                 closure, a, b, Ga, Gb, Ha, Hb, minv6, rhs, out, z, f, tmp2):
    """
    First half of a solve: ``out_T = A_TT⁻¹ rhs_T`` and ``z = rhs_C − A_CT out_T``.

    ``out`` (m,) may be ``rhs``; ``z`` (c,) is the right-hand side of ``S x_C = z``
    (solved by the caller), then :func:`loop_back` finishes. ``f`` (n, 6) and
    ``tmp2`` (c,): workspace.
    """
    c = closure.shape[0]
    for k in range(c):
        z[k] = rhs[closure[k]]
    tree_solve(group_ptr, group_rows, group_child, group_parent, S, piv, P, Q, B, E, tmp,
               rhs, out)
    _transpose_times(group_rows, a, b, Ha, Hb, out, f)
    _closure_times(closure, a, b, Ga, Gb, minv6, f, tmp2)
    for k in range(c):
        z[k] -= tmp2[k]


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
