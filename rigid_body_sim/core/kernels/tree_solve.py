"""
Linear-time solve of ``(G M⁻¹ Hᵀ + reg I) x = rhs`` for chains and trees (Baraff 1996).

Conventions
-----------
There are ``n`` bodies with diagonal inverse masses ``minv6`` (shape (n, 6):
``1/m`` three times, then ``1/J1, 1/J2, 1/J3``; zeros, i.e. immovable bodies,
are allowed) and ``m`` constraint rows. Row ``r`` acts on body ``a[r]``
(``0 <= a[r] < n``) with the Jacobian block ``Ga[r]`` (6,) and on body ``b[r]``
(``0 <= b[r] <= n``) with ``Gb[r]`` (6,); ``b[r] == n`` is the fixed world,
which has no columns, and ``Gb[r]`` is then ignored (``b[r] == a[r]`` is
allowed: the row acts on one body with the block ``Ga[r] + Gb[r]``). A second
Jacobian ``H`` has the same sparsity (blocks ``Ha``, ``Hb``); the matrix is
``A = G M⁻¹ Hᵀ`` (m x m): symmetric positive semidefinite when ``H == G``,
unsymmetric otherwise (a SHAKE projection).

Graph
-----
Rows acting on the same unordered pair of distinct bodies form a *group* (a
joint of up to 6 rows, or several joints on the same pair, possibly
redundant); the rows of a body to the world (or to itself) form one group of
that body. As in D. Baraff, "Linear-time dynamics using Lagrange multipliers",
SIGGRAPH 1996, the graph has one node per body and one per group, with an edge
between a group and each of its bodies. When it is a forest
(:func:`..graph.tree_structure` returns ``None`` otherwise: a closed loop), each tree
is rooted at a body, and every group gets a *parent* body (the one nearer the
root, or its only body) and, between two bodies, a *child* body.

Elimination
-----------
Baraff factorizes the KKT matrix ``[[M, Hᵀ], [G, 0]]`` by block elimination
of the graph's nodes, leaves first, which creates no fill-in. The same
elimination is done here directly on ``A + reg I`` (equivalently: the body
nodes are eliminated in mobility form). The groups are eliminated in an order
where every group comes after all other groups of its child body (the groups
of the subtree below it and the world rows of that body). Then the Schur
complement of the remaining groups keeps the form ``Σ_b G_b W_b H_bᵀ + reg I``
(``G_b``: the columns of body ``b``), where ``W_b`` (6x6, initially
``M_b⁻¹``) is the *articulated mobility* of body ``b``: eliminating group
``x`` with child body ``c`` and parent body ``p`` couples only groups at
``p``, and amounts to::

    S_x = reg I + G_xc W_c H_xcᵀ + G_xp W_p H_xpᵀ        (k x k pivot block, LU with
    P_x = W_p H_xpᵀ,   Q_x = S_x⁻¹ G_xp W_p                 partial pivoting)
    W_p ← W_p − P_x Q_x

The solve runs forward over the groups (``z_x = rhs_x − G_xc e_c − G_xp e_p``,
``v_x = S_x⁻¹ z_x``, ``e_p += P_x v_x``) and backward (``x_x = v_x − Q_x f_p``,
``f_p += H_xpᵀ x_x``, ``f_c += H_xcᵀ x_x``) with one 6-vector ``e_b``,
``f_b`` per body. Factor and solve cost ``O(Σ_x k_x³ + 36 k_x)``: linear in the
number of rows and bodies for any tree shape (a star included). There is no
pivoting between blocks.

Unlike the KKT order, every pivot block ``S_x`` is a true Schur complement of
``A + reg I``: a group to the world (a leaf with a zero diagonal block in the
KKT form) or a group hanging below a body welded to the world needs no
special case, and for ``H == G`` the blocks are positive definite whenever
``A`` is.

Rank deficiency
---------------
Redundant rows (a joint added twice) make a pivot block singular.
:func:`tree_factor` returns the smallest absolute pivot of the block LUs
divided by ``max |diag A|``: about machine epsilon or zero for redundant rows,
so the caller can test ``pivot < 1e-12`` and fall back, or refactor with a
Tikhonov term ``reg = 1e-12 * max|diag A|`` that factors ``A + reg I``. An
exactly zero pivot is replaced by ``eps * max|diag A|`` so that the
factorization finishes (the solution is then meaningless; the returned pivot
is 0).

The kernels are compiled with numba (``@njit(cache=True)``), take only numpy
arrays and scalars (callable from other compiled code), allocate nothing, and
run unchanged as plain Python with ``NUMBA_DISABLE_JIT=1``. The structure
of the graph they take is built by :func:`..graph.tree_structure`.
"""

from __future__ import annotations

from numba import njit
import numpy as np


def factor_arrays(structure: tuple) -> tuple:
    """
    Allocate the factor and work arrays of a structure (once; reused every step).

    Parameters
    ----------
    structure : TreeStructure
        From :func:`..graph.tree_structure`.

    Returns
    -------
    tuple
        ``(S, piv, P, Q, B, W, E, tmp)``, all zeroed, with ``ng = n_groups``,
        ``K = block_size``, ``n = n_bodies``:

        * ``S`` (ng, K, K) float64: LU factors of the pivot blocks (unit lower part;
          the diagonal holds the reciprocals of U's diagonal);
        * ``piv`` (ng, K) int64: their row interchanges (row ``j`` swapped with ``piv[j]``);
        * ``P`` (ng, 6, K) float64: ``W_p H_xpᵀ``;
        * ``Q`` (ng, K, 6) float64: ``S_x⁻¹ G_xp W_p``;
        * ``B`` (ng, 4, K, 6) float64: the blocks ``G_xc, G_xp, H_xc, H_xp`` of each group;
        * ``W`` (n, 6, 6) float64: articulated mobilities (factor workspace);
        * ``E`` (2, n, 6) float64: solve workspace (``e``, ``f``);
        * ``tmp`` (K,) float64: solve workspace.

    """
    ng, k, n = structure.n_groups, structure.block_size, structure.n_bodies
    return (np.zeros((ng, k, k)), np.zeros((ng, k), dtype=np.int64), np.zeros((ng, 6, k)),
            np.zeros((ng, k, 6)), np.zeros((ng, 4, k, 6)), np.zeros((n, 6, 6)),
            np.zeros((2, n, 6)), np.zeros(k))


@njit(cache=True)
def _lu(d, piv, s, floor):
    """LU of ``d[:s, :s]`` in place with partial pivoting; return the smallest |pivot|."""
    smallest = np.inf
    for j in range(s):
        p = j
        best = abs(d[j, j])
        for r in range(j + 1, s):
            v = abs(d[r, j])
            if v > best:
                best = v
                p = r
        piv[j] = p
        if p != j:
            for c in range(s):
                t = d[j, c]
                d[j, c] = d[p, c]
                d[p, c] = t
        pivot = d[j, j]
        if abs(pivot) < smallest:
            smallest = abs(pivot)
        if pivot == 0.0:
            pivot = floor
            d[j, j] = floor
        for r in range(j + 1, s):
            lrj = d[r, j] / pivot
            d[r, j] = lrj
            if lrj != 0.0:
                for c in range(j + 1, s):
                    d[r, c] -= lrj * d[j, c]
    return smallest


@njit(cache=True)
def _lu_solve_vec(d, piv, s, x):
    """Overwrite ``x[:s]`` with ``d⁻¹ x`` (factors from :func:`_lu`)."""
    for j in range(s):
        p = piv[j]
        if p != j:
            t = x[j]
            x[j] = x[p]
            x[p] = t
    for j in range(s):
        v = x[j]
        for c in range(j):
            v -= d[j, c] * x[c]
        x[j] = v
    for j in range(s - 1, -1, -1):
        v = x[j]
        for c in range(j + 1, s):
            v -= d[j, c] * x[c]
        x[j] = v / d[j, j]


@njit(cache=True, error_model='numpy')
def tree_factor(group_ptr, group_rows, group_child, group_parent, row_side, Ga, Gb, Ha, Hb,
                minv6, reg, S, piv, P, Q, B, W, symmetric=False):
    """
    Factorize ``A + reg I = G M⁻¹ Hᵀ + reg I`` along the tree (allocation-free).

    A first pass copies each group's row blocks into ``B`` (``G_xc, G_xp, H_xc,
    H_xp``, zero child blocks for a world group) and finds ``max |diag A|``; a
    second pass eliminates the groups in order (see the module docstring): ``P =
    W_p H_xpᵀ``, the pivot block ``S_x``, its LU with partial pivoting (as
    :func:`_lu`, but the reciprocals of U's diagonal are stored), ``Q = S_x⁻¹
    G_xp W_p`` and the rank-k update ``W_p −= P Q``.

    Written for speed under numba: every array is indexed in full (a view such as
    ``W[p]`` costs two atomic reference counts per use), the loops over the six
    body coordinates have the literal length 6 (unrolled), a row of 6 reused
    across a loop is held in scalars, and 6-term dot products are summed
    pairwise (shorter dependency chains; plain IEEE arithmetic, no fastmath).

    Parameters
    ----------
    group_ptr, group_rows, group_child, group_parent, row_side : ndarray of int64
        ``TreeStructure.arrays`` (see :class:`..graph.TreeStructure`).
    Ga, Gb : ndarray of float64, shape (m, 6)
        Blocks of ``G`` on bodies ``a[r]`` and ``b[r]``.
    Ha, Hb : ndarray of float64, shape (m, 6)
        Blocks of ``H`` (pass ``Ga, Gb`` again for the symmetric ``G M⁻¹ Gᵀ``).
    minv6 : ndarray of float64, shape (n, 6)
        Diagonal inverse masses (``>= 0``).
    reg : float
        Tikhonov term ``>= 0``: factorizes ``A + reg I``.
    S, piv, P, Q, B, W : ndarray
        The first six arrays of :func:`factor_arrays` (overwritten; ``S`` to ``B``
        are the factors used by :func:`tree_solve`).
    symmetric : bool
        ``H`` is ``G`` (the caller's promise): the pivot blocks and mobilities are
        then symmetric, ``S_x⁻¹ G_xp W_p = S_x⁻¹ P_xᵀ``, and the upper half of each
        symmetric product is computed and mirrored (``W`` stays exactly symmetric).

    Returns
    -------
    float
        Smallest absolute pivot of the block LUs over ``max |diag A|`` (about
        1e-16 or 0 for redundant rows; ``inf`` without rows; 0 when ``A`` is zero).

    """
    ng = group_child.shape[0]
    for i in range(minv6.shape[0]):
        for r in range(6):
            for t in range(6):
                W[i, r, t] = 0.0
            W[i, r, r] = minv6[i, r]
    # B[x] = (G_xc, G_xp, H_xc, H_xp), and the scale max |diag A|.
    scale = 0.0
    for x in range(ng):
        r0 = group_ptr[x]
        k = group_ptr[x + 1] - r0
        c = group_child[x]
        p = group_parent[x]
        for j in range(k):
            r = group_rows[r0 + j]
            side = row_side[r]
            diag = 0.0
            if side == 2:   # a[r] == b[r]: one block, no child
                for t in range(6):
                    gp = Ga[r, t] + Gb[r, t]
                    hp = Ha[r, t] + Hb[r, t]
                    diag += gp * minv6[p, t] * hp
                    B[x, 0, j, t] = 0.0
                    B[x, 1, j, t] = gp
                    B[x, 2, j, t] = 0.0
                    B[x, 3, j, t] = hp
            elif c < 0:     # to the world: no child block
                for t in range(6):
                    gp = Ga[r, t] if side == 0 else Gb[r, t]
                    hp = Ha[r, t] if side == 0 else Hb[r, t]
                    diag += gp * minv6[p, t] * hp
                    B[x, 0, j, t] = 0.0
                    B[x, 1, j, t] = gp
                    B[x, 2, j, t] = 0.0
                    B[x, 3, j, t] = hp
            else:
                for t in range(6):
                    if side == 0:
                        gp, hp, gc, hc = Ga[r, t], Ha[r, t], Gb[r, t], Hb[r, t]
                    else:
                        gp, hp, gc, hc = Gb[r, t], Hb[r, t], Ga[r, t], Ha[r, t]
                    diag += gc * minv6[c, t] * hc
                    diag += gp * minv6[p, t] * hp
                    B[x, 0, j, t] = gc
                    B[x, 1, j, t] = gp
                    B[x, 2, j, t] = hc
                    B[x, 3, j, t] = hp
            if abs(diag) > scale:
                scale = abs(diag)
    floor = 2.220446049250313e-16 * scale if scale > 0.0 else 1e-300
    smallest = np.inf
    for x in range(ng):
        k = group_ptr[x + 1] - group_ptr[x]
        c = group_child[x]
        p = group_parent[x]
        # P = W_p H_xpᵀ (6 x k); Q temporarily W_c H_xcᵀ transposed (k x 6).
        for j in range(k):
            h0, h1, h2 = B[x, 3, j, 0], B[x, 3, j, 1], B[x, 3, j, 2]
            h3, h4, h5 = B[x, 3, j, 3], B[x, 3, j, 4], B[x, 3, j, 5]
            for i in range(6):
                P[x, i, j] = ((W[p, i, 0] * h0 + W[p, i, 1] * h1)
                              + (W[p, i, 2] * h2 + W[p, i, 3] * h3)
                              + (W[p, i, 4] * h4 + W[p, i, 5] * h5))
            if c >= 0:
                h0, h1, h2 = B[x, 2, j, 0], B[x, 2, j, 1], B[x, 2, j, 2]
                h3, h4, h5 = B[x, 2, j, 3], B[x, 2, j, 4], B[x, 2, j, 5]
                for i in range(6):
                    Q[x, j, i] = ((W[c, i, 0] * h0 + W[c, i, 1] * h1)
                                  + (W[c, i, 2] * h2 + W[c, i, 3] * h3)
                                  + (W[c, i, 4] * h4 + W[c, i, 5] * h5))
        # Pivot block S = reg I + G_xp W_p H_xpᵀ + G_xc W_c H_xcᵀ.
        for i in range(k):
            g0, g1, g2 = B[x, 1, i, 0], B[x, 1, i, 1], B[x, 1, i, 2]
            g3, g4, g5 = B[x, 1, i, 3], B[x, 1, i, 4], B[x, 1, i, 5]
            d0, d1, d2 = B[x, 0, i, 0], B[x, 0, i, 1], B[x, 0, i, 2]
            d3, d4, d5 = B[x, 0, i, 3], B[x, 0, i, 4], B[x, 0, i, 5]
            for j in range(i if symmetric else 0, k):
                v = ((g0 * P[x, 0, j] + g1 * P[x, 1, j]) + (g2 * P[x, 2, j] + g3 * P[x, 3, j])
                     + (g4 * P[x, 4, j] + g5 * P[x, 5, j]))
                if c >= 0:
                    v += ((d0 * Q[x, j, 0] + d1 * Q[x, j, 1]) + (d2 * Q[x, j, 2] + d3 * Q[x, j, 3])
                          + (d4 * Q[x, j, 4] + d5 * Q[x, j, 5]))
                if i == j:
                    v += reg
                S[x, i, j] = v
                if symmetric:
                    S[x, j, i] = v
        # LU of S_x in place with partial pivoting, as _lu; U's diagonal is stored inverted.
        for j in range(k):
            q = j
            best = abs(S[x, j, j])
            for r in range(j + 1, k):
                v = abs(S[x, r, j])
                if v > best:
                    best = v
                    q = r
            piv[x, j] = q
            if q != j:
                for t in range(k):
                    v = S[x, j, t]
                    S[x, j, t] = S[x, q, t]
                    S[x, q, t] = v
            pivot = S[x, j, j]
            if abs(pivot) < smallest:
                smallest = abs(pivot)
            if pivot == 0.0:
                pivot = floor
            inv = 1.0 / pivot
            S[x, j, j] = inv
            for r in range(j + 1, k):
                lrj = S[x, r, j] * inv
                S[x, r, j] = lrj
                if lrj != 0.0:
                    for t in range(j + 1, k):
                        S[x, r, t] -= lrj * S[x, j, t]
        # Q = G_xp W_p (k x 6) ...
        if symmetric:
            for i in range(k):
                for j in range(6):
                    Q[x, i, j] = P[x, j, i]   # G_xp W_p = (W_p G_xpᵀ)ᵀ, W_p symmetric
        else:
            for i in range(k):
                g0, g1, g2 = B[x, 1, i, 0], B[x, 1, i, 1], B[x, 1, i, 2]
                g3, g4, g5 = B[x, 1, i, 3], B[x, 1, i, 4], B[x, 1, i, 5]
                for j in range(6):
                    Q[x, i, j] = ((g0 * W[p, 0, j] + g1 * W[p, 1, j])
                                  + (g2 * W[p, 2, j] + g3 * W[p, 3, j])
                                  + (g4 * W[p, 4, j] + g5 * W[p, 5, j]))
        # ... then Q = S_x⁻¹ Q, the six columns at once (rows interchanged, L, then U).
        for j in range(k):
            q = piv[x, j]
            if q != j:
                for t in range(6):
                    v = Q[x, j, t]
                    Q[x, j, t] = Q[x, q, t]
                    Q[x, q, t] = v
        for j in range(1, k):
            for i in range(j):
                lji = S[x, j, i]
                for t in range(6):
                    Q[x, j, t] -= lji * Q[x, i, t]
        for j in range(k - 1, -1, -1):
            for i in range(j + 1, k):
                uji = S[x, j, i]
                for t in range(6):
                    Q[x, j, t] -= uji * Q[x, i, t]
            inv = S[x, j, j]
            for t in range(6):
                Q[x, j, t] *= inv
        # W_p −= P Q, one rank-one term per row of the group.
        if symmetric:
            for t in range(k):
                for i in range(6):
                    pit = P[x, i, t]
                    for j in range(i, 6):
                        W[p, i, j] -= pit * Q[x, t, j]
            for i in range(1, 6):
                for j in range(i):
                    W[p, i, j] = W[p, j, i]
        else:
            for t in range(k):
                for i in range(6):
                    pit = P[x, i, t]
                    for j in range(6):
                        W[p, i, j] -= pit * Q[x, t, j]
    if ng == 0:
        return np.inf
    if scale == 0.0:
        return 0.0
    return smallest / scale


@njit(cache=True, error_model='numpy')
def tree_solve(group_ptr, group_rows, group_child, group_parent, S, piv, P, Q, B, E, tmp, rhs,
               out):
    """
    Solve ``(A + reg I) x = rhs`` with the factors of :func:`tree_factor` (allocation-free).

    One pass forward over the groups and one backward (see the module docstring).
    As in :func:`tree_factor`, arrays are indexed in full (no views), and the
    6-vectors ``e_p``, ``e_c``, ``f_p`` and the group's contributions to ``e_p``,
    ``f_p``, ``f_c`` are held in scalars, stored once per group.

    Parameters
    ----------
    group_ptr, group_rows, group_child, group_parent : ndarray of int64
        The first four of ``TreeStructure.arrays``.
    S, piv, P, Q, B : ndarray
        Factors from :func:`tree_factor` (read only).
    E : ndarray of float64, shape (2, n, 6)
        Workspace from :func:`factor_arrays` (overwritten).
    tmp : ndarray of float64, shape (K,)
        Workspace from :func:`factor_arrays` (overwritten).
    rhs : ndarray of float64, shape (m,)
        Right-hand side.
    out : ndarray of float64, shape (m,)
        Receives ``x`` (may be the same array as ``rhs``).

    """
    ng = group_child.shape[0]
    for i in range(E.shape[1]):
        for t in range(6):
            E[0, i, t] = 0.0
            E[1, i, t] = 0.0
    # Forward: z_x = rhs_x − G_xc e_c − G_xp e_p, v_x = S_x⁻¹ z_x, e_p += P_x v_x.
    for x in range(ng):
        r0 = group_ptr[x]
        k = group_ptr[x + 1] - r0
        c = group_child[x]
        p = group_parent[x]
        e0, e1, e2 = E[0, p, 0], E[0, p, 1], E[0, p, 2]
        e3, e4, e5 = E[0, p, 3], E[0, p, 4], E[0, p, 5]
        d0 = d1 = d2 = d3 = d4 = d5 = 0.0
        if c >= 0:
            d0, d1, d2 = E[0, c, 0], E[0, c, 1], E[0, c, 2]
            d3, d4, d5 = E[0, c, 3], E[0, c, 4], E[0, c, 5]
        for j in range(k):
            v = rhs[group_rows[r0 + j]] - ((B[x, 1, j, 0] * e0 + B[x, 1, j, 1] * e1)
                                           + (B[x, 1, j, 2] * e2 + B[x, 1, j, 3] * e3)
                                           + (B[x, 1, j, 4] * e4 + B[x, 1, j, 5] * e5))
            if c >= 0:
                v -= ((B[x, 0, j, 0] * d0 + B[x, 0, j, 1] * d1)
                      + (B[x, 0, j, 2] * d2 + B[x, 0, j, 3] * d3)
                      + (B[x, 0, j, 4] * d4 + B[x, 0, j, 5] * d5))
            tmp[j] = v
        # tmp = S_x⁻¹ tmp: rows interchanged, L (unit lower), U (inverted diagonal).
        for j in range(k):
            q = piv[x, j]
            if q != j:
                v = tmp[j]
                tmp[j] = tmp[q]
                tmp[q] = v
        for j in range(1, k):
            v = tmp[j]
            for i in range(j):
                v -= S[x, j, i] * tmp[i]
            tmp[j] = v
        for j in range(k - 1, -1, -1):
            v = tmp[j]
            for i in range(j + 1, k):
                v -= S[x, j, i] * tmp[i]
            tmp[j] = v * S[x, j, j]
        a0 = a1 = a2 = a3 = a4 = a5 = 0.0
        for j in range(k):
            v = tmp[j]
            out[group_rows[r0 + j]] = v
            a0 += P[x, 0, j] * v
            a1 += P[x, 1, j] * v
            a2 += P[x, 2, j] * v
            a3 += P[x, 3, j] * v
            a4 += P[x, 4, j] * v
            a5 += P[x, 5, j] * v
        E[0, p, 0] = e0 + a0
        E[0, p, 1] = e1 + a1
        E[0, p, 2] = e2 + a2
        E[0, p, 3] = e3 + a3
        E[0, p, 4] = e4 + a4
        E[0, p, 5] = e5 + a5
    # Backward: x_x = v_x − Q_x f_p, f_p += H_xpᵀ x_x, f_c += H_xcᵀ x_x.
    for x in range(ng - 1, -1, -1):
        r0 = group_ptr[x]
        k = group_ptr[x + 1] - r0
        c = group_child[x]
        p = group_parent[x]
        f0, f1, f2 = E[1, p, 0], E[1, p, 1], E[1, p, 2]
        f3, f4, f5 = E[1, p, 3], E[1, p, 4], E[1, p, 5]
        a0 = a1 = a2 = a3 = a4 = a5 = 0.0   # H_xpᵀ x_x
        b0 = b1 = b2 = b3 = b4 = b5 = 0.0   # H_xcᵀ x_x (zero blocks without a child)
        for j in range(k):
            r = group_rows[r0 + j]
            v = out[r] - ((Q[x, j, 0] * f0 + Q[x, j, 1] * f1) + (Q[x, j, 2] * f2 + Q[x, j, 3] * f3)
                          + (Q[x, j, 4] * f4 + Q[x, j, 5] * f5))
            out[r] = v
            a0 += B[x, 3, j, 0] * v
            a1 += B[x, 3, j, 1] * v
            a2 += B[x, 3, j, 2] * v
            a3 += B[x, 3, j, 3] * v
            a4 += B[x, 3, j, 4] * v
            a5 += B[x, 3, j, 5] * v
            b0 += B[x, 2, j, 0] * v
            b1 += B[x, 2, j, 1] * v
            b2 += B[x, 2, j, 2] * v
            b3 += B[x, 2, j, 3] * v
            b4 += B[x, 2, j, 4] * v
            b5 += B[x, 2, j, 5] * v
        E[1, p, 0] = f0 + a0
        E[1, p, 1] = f1 + a1
        E[1, p, 2] = f2 + a2
        E[1, p, 3] = f3 + a3
        E[1, p, 4] = f4 + a4
        E[1, p, 5] = f5 + a5
        if c >= 0:
            E[1, c, 0] += b0
            E[1, c, 1] += b1
            E[1, c, 2] += b2
            E[1, c, 3] += b3
            E[1, c, 4] += b4
            E[1, c, 5] += b5
