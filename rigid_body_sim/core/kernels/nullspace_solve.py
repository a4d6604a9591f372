"""
Prototype: the tree solve of ``G M⁻¹ Gᵀ λ = rhs`` in inertia (articulated-body) form.

This is the premise check of issue 19 (``../shared/research/chain-perf.md``,
option 1 and Appendix A), not yet a path of the step. It solves the same
system as :func:`.tree_solve.tree_factor` / :func:`.tree_solve.tree_solve`
with ``H = G`` and ``reg = 0``, for forests whose groups are the built-in
joints, but eliminates each joint's ``d = 6 − k`` freedoms instead of its
``k`` rows.

Formulation
-----------
With ``M a = Gᵀ λ`` and ``G a = rhs``, ``λ = (G M⁻¹ Gᵀ)⁻¹ rhs``: the
multipliers are those of the KKT system ``[[M, −Gᵀ], [G, 0]]``, which is
eliminated body by body, leaves first (Featherstone's articulated-body
recursion, derived as block elimination of this augmented system by Pai,
Ascher & Kry, ICRA 2000; the null-space method of Benzi, Golub & Liesen,
Acta Numerica 2005, §6, applied per joint). Everything is in world axes at
each body's centre of mass: ``ν = (v, ω)``, ``ω = R Ω``, so a row's block
``(g_v, g_Ω)`` on a body becomes ``w = (g_v, R g_Ω)`` and ``M_b = diag(m I,
R J Rᵀ)``.

Per joint ``x`` (child body ``c``; parent body ``p``, or the world), with the
child blocks ``W_c`` (6 x k) of its rows, everything is read from the rows'
own blocks, so it holds where ``Φ ≠ 0`` too:

* a point row's child block is ``s (e_j, ρ_c × e_j)`` (``s = ±1``: the
  child is body a or b), which gives the lever ``ρ_c`` from the child's
  centre of mass to its anchor, and the parent's gives ``ρ_p``; a dot row's
  is ``(0, t)``; a line row's ``(f, τ)`` with ``f ⟂ τ``;
* the shift ``X = [[I, −[d]×], [0, I]]`` (``v_c = v_p + ω_p × d``, ``ω_c =
  ω_p``) with ``W_cᵀ X = −W_pᵀ`` for every row: ``d = ρ_p − ρ_c`` when the
  joint has point rows, and for a slider's line rows (``f_k × d = τ_ck +
  τ_pk =: σ_k``, ``f_1 ⟂ f_2`` unit) ``d = σ_1 × f_1 + ((σ_2 × f_2) · f_1)
  f_1`` (that is ``x_c − x_p``); dot rows hold for any ``d``;
* the motion subspace ``S`` (6 x d) with ``W_cᵀ S = 0``: hinge ``n = t_1 ×
  t_2``, ``S = (ρ_c × n, n)``; ball ``S = ([ρ_c]×, I)``; slider ``n = f_1 ×
  f_2``, ``S = (n, 0)``; fixed: none;
* a particular solution ``g`` of ``W_cᵀ g = c`` (``c``: the rows' rhs),
  from dual bases of the dot torques (``b_i · t_j = δ_ij``: for two,
  ``b_1 = t_2 × n / |n|²``, ``b_2 = n × t_1 / |n|²``; for three, the
  reciprocal basis ``t_j × t_k / det``) and of a slider's line directions:
  ``g_ω = Σ c_dot,i b_i``, then ``g_v = s c_pt − g_ω × ρ_c`` (point rows) or
  ``g_v = Σ (c_line,k − τ_k · g_ω) b_line,k`` (slider).

Factor (leaves first): ``I^A_c = M_c + Σ_children Xᵀ Ia X``, ``U = I^A_c S``,
``D = Sᵀ U``, ``Ia = I^A_c − U D⁻¹ Uᵀ``, ``I^A_p += Xᵀ Ia X``.

Solve: up, ``z = p_c + I^A_c g``, ``q₀ = −D⁻¹ Sᵀ z``, ``p_p += Xᵀ (z + U
q₀)``; down, ``y = X a_p`` (0 at the world), ``a_c = y + g + S (q₀ − D⁻¹ Uᵀ
y)``; then the joint's wrench on its child ``F = I^A_c a_c + p_c = W_c λ``,
read with the same dual bases: point rows ``λ = s F_v``, dot rows ``λ_i = b_i
· (F_ω − ρ_c × F_v)``; a slider's lines ``λ_k = b_line,k · F_v``, its dots
``b_i · (F_ω − Σ λ_k τ_k)``.

A ball is eliminated through its anchor. There (``Y = X(−ρ_c)``, ``S = Y (0,
I)``) ``Yᵀ I^A_c Y = [[A, B̂], [B̂ᵀ, D]]`` with ``B̂ = U_0:3``, so ``Ia`` is
exactly ``Y⁻ᵀ [[K, 0], [0, 0]] Y⁻¹``: a point mass ``K = A − B̂ D⁻¹ B̂ᵀ`` at
the anchor, which the parent receives at its own lever ``ρ_p`` as ``X(ρ_p)ᵀ
[[K, 0], [0, 0]] X(ρ_p)``. ``K`` is formed from ``D = L diag(δ) Lᵀ`` as ``A −
Σ_k w_k w_kᵀ / δ_k`` (``w = L⁻¹ B̂ᵀ``), each term bounded by ``A``. In the
solve the ball passes up the force ``f = z_v + B̂ q₀`` at its anchor (``(f,
ρ_p × f)`` to the parent); down, with the parent's anchor acceleration ``ŷ =
a_p,v + a_p,ω × ρ_p``, ``ω̇_c = q₀ − D⁻¹ B̂ᵀ ŷ``, ``a_c = (ŷ + g_v + ρ_c ×
ω̇_c, ω̇_c)`` and ``λ = s (f + K ŷ)``. Written as the general recursion, with
``D⁻¹`` explicit (an adjugate), the ball lost accuracy in the factor: the
update ``U D⁻¹ Uᵀ`` has rounding errors of order ``eps |U| |D⁻¹| |Uᵀ|``, up to
50 times ``|I^A|`` on random ball chains, and a step's error then perturbed the
parent's ``D`` by up to 8e-13 relative (1.4e-14 as above); λ was off by up to
1.2e-12 at cond(A) 6e3 (now 8.3e-15: ``bench/nullspace_premise.py``, whose
worst case over all joint types is 5.5e-14, ``test/test_nullspace_premise.py``).
``q₀ = −D⁻¹ Sᵀ z`` with an explicit ``D⁻¹`` alone makes λ's error about 10
times larger.

Free-floating trees. A tree without a joint to the world (a floating-base robot,
two bodies hinged together in space) is rooted at its lowest-numbered body, entered
as a joint-less entry of type ``FREE`` (no rows, ``j_parent = -1``, after its
subtree as every joint is). Its articulated inertia ``I^A_root`` (symmetric positive
definite) is complete when the entry is reached; the factor overwrites it with its
Cholesky factor ``L`` (below the diagonal, ``1 / L_kk`` on it), the up pass leaves its
bias ``p_root`` as the children passed it, and the down pass starts from ``a_root =
−(I^A_root)⁻¹ p_root`` (the joint wrench on a root without a joint is 0). A
component may hold several trees, hung and free, in any mix.

Distance rows. A ``distance`` constraint (one row ``|P_a − P_b| − L``, ``k = 1``, five
freedoms) is eliminated by the range-space step instead, so that its tree stays in
inertia form: the child's whole acceleration, then the row's multiplier. With the
row's child and parent blocks ``w_c``, ``w_p`` (world axes at each centre of mass;
``w_p = 0`` at the world), block elimination of ``[[I^A_c, −w_c], [w_cᵀ, 0]]`` (the
child's block first) gives ``a_c = a₀ + h λ`` with ``a₀ = −(I^A_c)⁻¹ p_c`` and ``h =
(I^A_c)⁻¹ w_c``, and from the row ``w_cᵀ a_c + w_pᵀ a_p = c``: ``s λ = τ − w_pᵀ a_p``,
``s = w_cᵀ h``, ``τ = c − w_cᵀ a₀``. The row's force on the parent, ``w_p λ``, is then
``I^A_p += w_p w_pᵀ / s`` and ``p_p −= w_p τ / s``. The factor takes ``I^A_c = L Lᵀ``
in place (as a free root's) and ``s = |L⁻¹ w_c|²``; up, ``a₀`` is kept in ``Acc[c]``
until the down pass adds ``h λ``. Storage of a ``DISTANCE`` entry: the row in slot 0,
``w_p``, ``w_c`` in ``JS[j, :, 0]``, ``JS[j, :, 1]``, ``h`` in ``JU[j, :, 0]``, ``1 / s``
in ``JD[j, 2, 2]``, ``τ`` in ``JQ[j, 0]``.

Scope: each tree hangs from one body joined to the world, or floats free; within it
each pair of bodies shares one built-in fixed, hinge, ball or slider joint or one
distance row. Outside it :func:`nullspace_structure` returns None (the caller falls
back to the row-space tree solve): angle (drive) and generic rows, several joints
(or a joint and a distance row, or a partial joint) between one pair of bodies, a
second joint to the world or any other closed loop, rows on one body, immovable
bodies, redundant rows. A free body alone has no rows and never reaches these
kernels. The unsymmetric SHAKE matrix ``G_E D M⁻¹ G_Sᵀ`` is not built
here (it extends: ``K = M diag(I, J_r⁻¹)``, ``S_E, X_E`` from the end rows,
``S_S, X_S`` from the start rows, Appendix A).

The kernels are compiled with numba (``@njit(cache=True)``), take only numpy
arrays and scalars, and allocate nothing. The ball's solve steps are inlined
(``inline='always'``): called, with this many arrays, they made the solve 2.5
times slower.
"""

from __future__ import annotations

from numba import njit
import numpy as np

FIXED, HINGE, BALL, SLIDER, FREE, DISTANCE = 0, 1, 2, 3, 4, 5
# Slots of a joint's rows in ``j_rows``: the point rows by component, the dots, the lines.
SLOT_POINT, SLOT_DOT, SLOT_LINE, N_SLOTS = 0, 3, 6, 8
# Vectors of a joint in ``JV``: lever, shift, point-row signs, dual bases, line torques.
V_RHO, V_D, V_SIGN, V_DUAL, V_LDUAL, V_TAU, N_VECS = 0, 1, 2, 3, 6, 8, 10
# A ball's (it has no line rows): the parent's lever ρ_p.
V_RHOP = V_LDUAL
_DOF = np.array([0, 1, 3, 1, 6, 5], dtype=np.int64)

_KIND_POINT, _KIND_DOT, _KIND_LINE, _KIND_DISTANCE = 0, 1, 2, 3   # as in .rows


def nullspace_structure(a, b, kind, comp, n_bodies: int, only=None):
    """
    Recognize the joints of a row set and order them leaves first (plain Python, once).

    Parameters
    ----------
    a, b : array_like of int, shape (m,)
        Bodies of each row (``b == n_bodies``: the world).
    kind, comp : array_like of int, shape (m,)
        The rows' kinds and point components (``.rows`` conventions).
    n_bodies : int
        Number of bodies.
    only : array_like of int, optional
        The rows to take (default: all): the forest of a loop solve leaves its
        closure rows out.

    Returns
    -------
    tuple or None
        ``(j_child, j_parent, j_type, j_rows, j_cside)``: per joint, leaves first, its
        child body, parent body (``-1``: the world), type code, rows by slot (``-1``:
        none) and whether each slot's child block is in ``Gb`` (1) or ``Ga`` (0). A
        free-floating tree's root is an entry of type ``FREE`` (parent ``-1``, no rows)
        after its subtree; a distance row an entry of type ``DISTANCE`` (its row in slot
        0). None when the rows are outside the scope (see the module
        docstring).

    """
    a = np.asarray(a, dtype=np.int64)
    b = np.asarray(b, dtype=np.int64)
    n = int(n_bodies)
    groups: dict = {}
    for r in (range(a.size) if only is None else np.asarray(only, dtype=np.int64).tolist()):
        if a[r] == b[r]:
            return None
        key = (min(a[r], b[r]), max(a[r], b[r]))
        groups.setdefault(key, []).append(r)
    adjacent = [[] for _ in range(n)]
    world = {}
    for key, rows in groups.items():
        if key[1] == n:
            world[key[0]] = rows
        else:
            adjacent[key[0]].append((key[1], rows))
            adjacent[key[1]].append((key[0], rows))
    parent = np.full(n, -2, dtype=np.int64)
    up_rows = [None] * n
    order = []

    def grow(root, rows):
        """Add the tree of ``root`` (joined to the world by ``rows``, or None) root first."""
        parent[root] = -1
        up_rows[root] = rows
        order.append(root)
        head = len(order) - 1
        while head < len(order):
            body = order[head]
            head += 1
            for other, joint in adjacent[body]:
                if other == parent[body]:
                    continue
                if parent[other] != -2:
                    return False   # a closed loop
                parent[other] = body
                up_rows[other] = joint
                order.append(other)
        return True

    for root in sorted(world):
        if parent[root] != -2:
            return None   # a second joint to the world: a loop through it
        if not grow(root, world[root]):
            return None
    # Free-floating trees: each from its lowest-numbered body, a root without a joint.
    for root in range(n):
        if adjacent[root] and parent[root] == -2 and not grow(root, None):
            return None
    nj = len(order)
    j_child = np.array(order[::-1], dtype=np.int64)
    j_parent = parent[j_child]
    j_type = np.zeros(nj, dtype=np.int64)
    j_rows = np.full((nj, N_SLOTS), -1, dtype=np.int64)
    j_cside = np.zeros((nj, N_SLOTS), dtype=np.int64)
    kind = np.asarray(kind)
    comp = np.asarray(comp)
    for j, c in enumerate(j_child.tolist()):
        rows = up_rows[c]
        if rows is None:
            j_type[j] = FREE   # a free root: no rows
            continue
        pts = [r for r in rows if kind[r] == _KIND_POINT]
        dots = [r for r in rows if kind[r] == _KIND_DOT]
        lines = [r for r in rows if kind[r] == _KIND_LINE]
        counts = (len(pts), len(dots), len(lines), len(rows))
        if len(rows) == 1 and kind[rows[0]] == _KIND_DISTANCE:
            j_type[j] = DISTANCE
            j_rows[j, 0] = rows[0]
            j_cside[j, 0] = 0 if a[rows[0]] == c else 1
            continue
        types = {(3, 3, 0, 6): FIXED, (3, 2, 0, 5): HINGE, (3, 0, 0, 3): BALL,
                 (0, 3, 2, 5): SLIDER}
        if counts not in types or sorted(int(comp[r]) for r in pts) != [0, 1, 2][:len(pts)]:
            return None
        j_type[j] = types[counts]
        for r in pts:
            j_rows[j, SLOT_POINT + comp[r]] = r
        for i, r in enumerate(dots):
            j_rows[j, SLOT_DOT + i] = r
        for i, r in enumerate(lines):
            j_rows[j, SLOT_LINE + i] = r
        for s in range(N_SLOTS):
            r = j_rows[j, s]
            if r >= 0:
                j_cside[j, s] = 0 if a[r] == c else 1
    return j_child, j_parent, j_type, j_rows, j_cside


def nullspace_arrays(n_joints: int, n_bodies: int) -> tuple:
    """
    Allocate the factor and work arrays (once).

    Returns
    -------
    tuple
        ``(IA, JS, JU, JD, JV, work, P, Acc, JG, JQ)``: articulated inertias (n, 6, 6);
        per joint S, U (nj, 6, 3; a ball's: K and B̂ D⁻¹), D⁻¹ (nj, 3, 3; a ball's:
        ``L diag(δ) Lᵀ``), vectors (nj, N_VECS, 3); a (6, 6) factor workspace; the
        solve's bias forces P and accelerations Acc (n, 6), particular solutions JG (nj,
        6; a ball's: ``g_v`` and ``f``) and ``q₀`` JQ (nj, 3).

    """
    nj, n = n_joints, n_bodies
    return (np.zeros((n, 6, 6)), np.zeros((nj, 6, 3)), np.zeros((nj, 6, 3)),
            np.zeros((nj, 3, 3)), np.zeros((nj, N_VECS, 3)), np.zeros((6, 6)),
            np.zeros((n, 6)), np.zeros((n, 6)), np.zeros((nj, 6)), np.zeros((nj, 3)))


@njit(cache=True)
def _world_torque(G, r, R, body):
    """``R[body] @ G[r, 3:6]`` as a 3-tuple: a block's angular part in world axes."""
    g0, g1, g2 = G[r, 3], G[r, 4], G[r, 5]
    return (R[body, 0, 0] * g0 + R[body, 0, 1] * g1 + R[body, 0, 2] * g2,
            R[body, 1, 0] * g0 + R[body, 1, 1] * g1 + R[body, 1, 2] * g2,
            R[body, 2, 0] * g0 + R[body, 2, 1] * g1 + R[body, 2, 2] * g2)


@njit(cache=True)
def _put3(A, j, k, v):
    """``A[j, k] = v`` (a 3-tuple)."""
    A[j, k, 0], A[j, k, 1], A[j, k, 2] = v[0], v[1], v[2]


@njit(cache=True)
def _add_shifted(W, IA, p, d0, d1, d2):
    """
    ``IA[p] += Xᵀ W X`` for the shift ``X = [[I, −[d]×], [0, I]]`` (W symmetric).

    With ``W = [[A, B], [Bᵀ, C]]``: ``Xᵀ W X = [[A, B'], [B'ᵀ, C']]``, ``B' = B − A [d]×``
    (row i: ``B_i + d × A_i``), ``C' = C − Bᵀ[d]× + [d]× B'`` (symmetric).
    """
    # B' over W[0:3, 3:6] (the lower-left block keeps Bᵀ).
    for i in range(3):
        a0, a1, a2 = W[i, 0], W[i, 1], W[i, 2]
        W[i, 3] += d1 * a2 - d2 * a1
        W[i, 4] += d2 * a0 - d0 * a2
        W[i, 5] += d0 * a1 - d1 * a0
    # C' = C − Bᵀ[d]× + [d]× B': (Bᵀ[d]×)_ij = (B col i × d)_j, ([d]× B')_ij = (d × B' col j)_i.
    for i in range(3):
        b0, b1, b2 = W[3 + i, 0], W[3 + i, 1], W[3 + i, 2]   # B col i
        m0 = b1 * d2 - b2 * d1
        m1 = b2 * d0 - b0 * d2
        m2 = b0 * d1 - b1 * d0
        for j in range(i, 3):
            c0, c1, c2 = W[0, 3 + j], W[1, 3 + j], W[2, 3 + j]   # B' col j
            if i == 0:
                e = d1 * c2 - d2 * c1
            elif i == 1:
                e = d2 * c0 - d0 * c2
            else:
                e = d0 * c1 - d1 * c0
            mj = m0 if j == 0 else (m1 if j == 1 else m2)
            v = W[3 + i, 3 + j] - mj + e
            IA[p, 3 + i, 3 + j] += v
            if j != i:
                IA[p, 3 + j, 3 + i] += v
    for i in range(3):
        for j in range(3):
            IA[p, i, j] += W[i, j]
            v = W[i, 3 + j]
            IA[p, i, 3 + j] += v
            IA[p, 3 + j, i] += v


@njit(cache=True)
def _add_point_mass(JU, j, IA, p, e0, e1, e2):
    """
    ``IA[p] += X(e)ᵀ [[K, 0], [0, 0]] X(e)``: a point mass ``K = JU[j, 0:3]`` at ``e``.

    That is ``[[K, E], [Eᵀ, [e]× E]]`` with ``E = −K [e]×`` (row i: ``e × K_i``):
    :func:`_add_shifted` with ``B = C = 0``, without their terms.
    """
    k00, k01, k02 = JU[j, 0, 0], JU[j, 0, 1], JU[j, 0, 2]
    k11, k12, k22 = JU[j, 1, 1], JU[j, 1, 2], JU[j, 2, 2]
    # E rows e × K_i.
    x00, x01, x02 = e1 * k02 - e2 * k01, e2 * k00 - e0 * k02, e0 * k01 - e1 * k00
    x10, x11, x12 = e1 * k12 - e2 * k11, e2 * k01 - e0 * k12, e0 * k11 - e1 * k01
    x20, x21, x22 = e1 * k22 - e2 * k12, e2 * k02 - e0 * k22, e0 * k12 - e1 * k02
    IA[p, 0, 0] += k00
    IA[p, 1, 1] += k11
    IA[p, 2, 2] += k22
    IA[p, 0, 1] += k01
    IA[p, 1, 0] += k01
    IA[p, 0, 2] += k02
    IA[p, 2, 0] += k02
    IA[p, 1, 2] += k12
    IA[p, 2, 1] += k12
    IA[p, 0, 3] += x00
    IA[p, 0, 4] += x01
    IA[p, 0, 5] += x02
    IA[p, 1, 3] += x10
    IA[p, 1, 4] += x11
    IA[p, 1, 5] += x12
    IA[p, 2, 3] += x20
    IA[p, 2, 4] += x21
    IA[p, 2, 5] += x22
    IA[p, 3, 0] += x00
    IA[p, 4, 0] += x01
    IA[p, 5, 0] += x02
    IA[p, 3, 1] += x10
    IA[p, 4, 1] += x11
    IA[p, 5, 1] += x12
    IA[p, 3, 2] += x20
    IA[p, 4, 2] += x21
    IA[p, 5, 2] += x22
    # [e]× E: entry (i, t) is (e × E col t)_i, symmetric.
    c00 = e1 * x20 - e2 * x10
    c11 = e2 * x01 - e0 * x21
    c22 = e0 * x12 - e1 * x02
    c01 = e1 * x21 - e2 * x11
    c02 = e1 * x22 - e2 * x12
    c12 = e2 * x02 - e0 * x22
    IA[p, 3, 3] += c00
    IA[p, 4, 4] += c11
    IA[p, 5, 5] += c22
    IA[p, 3, 4] += c01
    IA[p, 4, 3] += c01
    IA[p, 3, 5] += c02
    IA[p, 5, 3] += c02
    IA[p, 4, 5] += c12
    IA[p, 5, 4] += c12


@njit(cache=True)
def nullspace_factor(j_child, j_parent, j_type, j_rows, j_cside, Ga, Gb, minv6, R,
                     IA, JS, JU, JD, JV, work):
    """
    Factorize ``G M⁻¹ Gᵀ`` in inertia form, leaves first (allocation-free).

    Parameters
    ----------
    j_child, j_parent, j_type, j_rows, j_cside : ndarray of int64
        From :func:`nullspace_structure`.
    Ga, Gb : ndarray of float64, shape (m, 6)
        The rows' blocks (``(δx_world, δΘ_principal)``, as for ``tree_factor``).
    minv6 : ndarray of float64, shape (n, 6)
        Diagonal inverse masses (all positive).
    R : ndarray of float64, shape (n + 1, 3, 3)
        Principal-to-world rotations (:func:`.rows.frames`).
    IA, JS, JU, JD, JV, work : ndarray
        From :func:`nullspace_arrays` (overwritten: the factors; the ``IA`` of a free
        root and of a distance row's child by its Cholesky factor).

    Returns
    -------
    float
        The smallest ``D`` over its scale ``Σ S_i² I^A_ii`` (the pivots of the joint
        freedoms; 1 without any): small for a nearly massless subtree.

    """
    n = minv6.shape[0]
    for i in range(n):
        m = 1.0 / minv6[i, 0]
        j0, j1, j2 = 1.0 / minv6[i, 3], 1.0 / minv6[i, 4], 1.0 / minv6[i, 5]
        for r in range(6):
            for t in range(6):
                IA[i, r, t] = 0.0
        IA[i, 0, 0] = m
        IA[i, 1, 1] = m
        IA[i, 2, 2] = m
        for r in range(3):
            x0, x1, x2 = j0 * R[i, r, 0], j1 * R[i, r, 1], j2 * R[i, r, 2]
            for t in range(r, 3):
                v = x0 * R[i, t, 0] + x1 * R[i, t, 1] + x2 * R[i, t, 2]
                IA[i, 3 + r, 3 + t] = v
                IA[i, 3 + t, 3 + r] = v
    smallest = 1.0
    for j in range(j_child.shape[0]):
        c = j_child[j]
        p = j_parent[j]
        typ = j_type[j]
        if typ == FREE or typ == DISTANCE:
            ratio = _free_factor(IA, c)
            if ratio < smallest or ratio != ratio:   # (NaN: kept, the caller falls back)
                smallest = ratio
            if typ == DISTANCE:
                _distance_factor(j, c, p, j_rows, j_cside, Ga, Gb, R, IA, JS, JU, JD)
            continue
        # Child torques of the rows in world axes: points 0, 1 (lever), dots, lines.
        rho0 = rho1 = rho2 = 0.0
        rp0 = rp1 = rp2 = 0.0
        d0 = d1 = d2 = 0.0
        if typ != SLIDER:
            for s in range(2):
                r = j_rows[j, s]
                if j_cside[j, s] == 0:
                    _put3(JV, j, V_TAU + s, _world_torque(Ga, r, R, c))
                    JV[j, V_SIGN, s] = Ga[r, s]
                else:
                    _put3(JV, j, V_TAU + s, _world_torque(Gb, r, R, c))
                    JV[j, V_SIGN, s] = Gb[r, s]
            r = j_rows[j, 2]
            JV[j, V_SIGN, 2] = Ga[r, 2] if j_cside[j, 2] == 0 else Gb[r, 2]
            s0, s1 = JV[j, V_SIGN, 0], JV[j, V_SIGN, 1]
            # τ_0 = s0 ρ × e_x = s0 (0, ρz, −ρy); τ_1 = s1 (−ρz, 0, ρx).
            rho0 = s1 * JV[j, V_TAU + 1, 2]
            rho1 = -s0 * JV[j, V_TAU, 2]
            rho2 = s0 * JV[j, V_TAU, 1]
            if p >= 0:
                for s in range(2):
                    r = j_rows[j, s]
                    if j_cside[j, s] == 0:
                        _put3(JV, j, V_TAU + s, _world_torque(Gb, r, R, p))
                    else:
                        _put3(JV, j, V_TAU + s, _world_torque(Ga, r, R, p))
                # The parent's signs are −s: ρ_p = −(the same reading).
                rp0 = -s1 * JV[j, V_TAU + 1, 2]
                rp1 = s0 * JV[j, V_TAU, 2]
                rp2 = -s0 * JV[j, V_TAU, 1]
                d0, d1, d2 = rp0 - rho0, rp1 - rho1, rp2 - rho2
        JV[j, V_RHO, 0], JV[j, V_RHO, 1], JV[j, V_RHO, 2] = rho0, rho1, rho2
        # Dot torques t_i (child, world) into the dual slots, inverted below.
        nd = 2 if typ == HINGE else (0 if typ == BALL else 3)
        for i in range(nd):
            r = j_rows[j, SLOT_DOT + i]
            if j_cside[j, SLOT_DOT + i] == 0:
                _put3(JV, j, V_DUAL + i, _world_torque(Ga, r, R, c))
            else:
                _put3(JV, j, V_DUAL + i, _world_torque(Gb, r, R, c))
        if typ == HINGE:
            t0, t1, t2 = JV[j, V_DUAL, 0], JV[j, V_DUAL, 1], JV[j, V_DUAL, 2]
            u0, u1, u2 = JV[j, V_DUAL + 1, 0], JV[j, V_DUAL + 1, 1], JV[j, V_DUAL + 1, 2]
            n0, n1, n2 = t1 * u2 - t2 * u1, t2 * u0 - t0 * u2, t0 * u1 - t1 * u0
            inv = 1.0 / (n0 * n0 + n1 * n1 + n2 * n2)
            # b1 = u × n / |n|², b2 = n × t / |n|².
            JV[j, V_DUAL, 0] = (u1 * n2 - u2 * n1) * inv
            JV[j, V_DUAL, 1] = (u2 * n0 - u0 * n2) * inv
            JV[j, V_DUAL, 2] = (u0 * n1 - u1 * n0) * inv
            JV[j, V_DUAL + 1, 0] = (n1 * t2 - n2 * t1) * inv
            JV[j, V_DUAL + 1, 1] = (n2 * t0 - n0 * t2) * inv
            JV[j, V_DUAL + 1, 2] = (n0 * t1 - n1 * t0) * inv
            JS[j, 0, 0] = rho1 * n2 - rho2 * n1
            JS[j, 1, 0] = rho2 * n0 - rho0 * n2
            JS[j, 2, 0] = rho0 * n1 - rho1 * n0
            JS[j, 3, 0], JS[j, 4, 0], JS[j, 5, 0] = n0, n1, n2
        elif nd == 3:
            t0, t1, t2 = JV[j, V_DUAL, 0], JV[j, V_DUAL, 1], JV[j, V_DUAL, 2]
            u0, u1, u2 = JV[j, V_DUAL + 1, 0], JV[j, V_DUAL + 1, 1], JV[j, V_DUAL + 1, 2]
            w0, w1, w2 = JV[j, V_DUAL + 2, 0], JV[j, V_DUAL + 2, 1], JV[j, V_DUAL + 2, 2]
            x0, x1, x2 = u1 * w2 - u2 * w1, u2 * w0 - u0 * w2, u0 * w1 - u1 * w0
            y0, y1, y2 = w1 * t2 - w2 * t1, w2 * t0 - w0 * t2, w0 * t1 - w1 * t0
            z0, z1, z2 = t1 * u2 - t2 * u1, t2 * u0 - t0 * u2, t0 * u1 - t1 * u0
            inv = 1.0 / (t0 * x0 + t1 * x1 + t2 * x2)
            JV[j, V_DUAL, 0], JV[j, V_DUAL, 1], JV[j, V_DUAL, 2] = x0 * inv, x1 * inv, x2 * inv
            JV[j, V_DUAL + 1, 0], JV[j, V_DUAL + 1, 1] = y0 * inv, y1 * inv
            JV[j, V_DUAL + 1, 2] = y2 * inv
            JV[j, V_DUAL + 2, 0], JV[j, V_DUAL + 2, 1] = z0 * inv, z1 * inv
            JV[j, V_DUAL + 2, 2] = z2 * inv
        if typ == SLIDER:
            # Line rows: f_k (child, world) and τ_k; σ_k = τ_ck + τ_pk gives d.
            for k in range(2):
                r = j_rows[j, SLOT_LINE + k]
                if j_cside[j, SLOT_LINE + k] == 0:
                    _put3(JV, j, V_TAU + k, _world_torque(Ga, r, R, c))
                    tp = _world_torque(Gb, r, R, p if p >= 0 else R.shape[0] - 1)
                    work[k, 0], work[k, 1], work[k, 2] = tp[0], tp[1], tp[2]
                    for t in range(3):
                        JV[j, V_LDUAL + k, t] = Ga[r, t]
                else:
                    _put3(JV, j, V_TAU + k, _world_torque(Gb, r, R, c))
                    tp = _world_torque(Ga, r, R, p if p >= 0 else R.shape[0] - 1)
                    work[k, 0], work[k, 1], work[k, 2] = tp[0], tp[1], tp[2]
                    for t in range(3):
                        JV[j, V_LDUAL + k, t] = Gb[r, t]
            f0, f1, f2 = JV[j, V_LDUAL, 0], JV[j, V_LDUAL, 1], JV[j, V_LDUAL, 2]
            h0, h1, h2 = JV[j, V_LDUAL + 1, 0], JV[j, V_LDUAL + 1, 1], JV[j, V_LDUAL + 1, 2]
            if p >= 0:
                a0 = JV[j, V_TAU, 0] + work[0, 0]
                a1 = JV[j, V_TAU, 1] + work[0, 1]
                a2 = JV[j, V_TAU, 2] + work[0, 2]
                b0 = JV[j, V_TAU + 1, 0] + work[1, 0]
                b1 = JV[j, V_TAU + 1, 1] + work[1, 1]
                b2 = JV[j, V_TAU + 1, 2] + work[1, 2]
                # d = σ1 × f1 + ((σ2 × f2) · f1) f1
                e = (b1 * h2 - b2 * h1) * f0 + (b2 * h0 - b0 * h2) * f1 + (b0 * h1 - b1 * h0) * f2
                d0 = a1 * f2 - a2 * f1 + e * f0
                d1 = a2 * f0 - a0 * f2 + e * f1
                d2 = a0 * f1 - a1 * f0 + e * f2
            n0, n1, n2 = f1 * h2 - f2 * h1, f2 * h0 - f0 * h2, f0 * h1 - f1 * h0
            inv = 1.0 / (n0 * n0 + n1 * n1 + n2 * n2)
            JV[j, V_LDUAL, 0] = (h1 * n2 - h2 * n1) * inv
            JV[j, V_LDUAL, 1] = (h2 * n0 - h0 * n2) * inv
            JV[j, V_LDUAL, 2] = (h0 * n1 - h1 * n0) * inv
            JV[j, V_LDUAL + 1, 0] = (n1 * f2 - n2 * f1) * inv
            JV[j, V_LDUAL + 1, 1] = (n2 * f0 - n0 * f2) * inv
            JV[j, V_LDUAL + 1, 2] = (n0 * f1 - n1 * f0) * inv
            JS[j, 0, 0], JS[j, 1, 0], JS[j, 2, 0] = n0, n1, n2
            JS[j, 3, 0] = JS[j, 4, 0] = JS[j, 5, 0] = 0.0
        JV[j, V_D, 0], JV[j, V_D, 1], JV[j, V_D, 2] = d0, d1, d2
        # U = I^A S, D = Sᵀ U, Ia = I^A − U D⁻¹ Uᵀ (into work).
        dof = _DOF[typ]
        if dof == 1:
            s0, s1, s2 = JS[j, 0, 0], JS[j, 1, 0], JS[j, 2, 0]
            s3, s4, s5 = JS[j, 3, 0], JS[j, 4, 0], JS[j, 5, 0]
            dd = 0.0
            scale = 0.0
            for i in range(6):
                u = ((IA[c, i, 0] * s0 + IA[c, i, 1] * s1) + (IA[c, i, 2] * s2 + IA[c, i, 3] * s3)
                     + (IA[c, i, 4] * s4 + IA[c, i, 5] * s5))
                JU[j, i, 0] = u
                si = JS[j, i, 0]
                dd += si * u
                scale += si * si * IA[c, i, i]
            if dd < smallest * scale:
                smallest = dd / scale
            dinv = 1.0 / dd
            JD[j, 0, 0] = dinv
            if p >= 0:
                for i in range(6):
                    ui = JU[j, i, 0] * dinv
                    for t in range(i, 6):
                        work[i, t] = IA[c, i, t] - ui * JU[j, t, 0]
                for i in range(1, 6):
                    for t in range(i):
                        work[i, t] = work[t, i]
        elif dof == 3:
            # Ball: S = ([ρ]×, I); S col k = (ρ × e_k, e_k).
            for k in range(3):
                for i in range(6):
                    JS[j, i, k] = 0.0
                JS[j, 3 + k, k] = 1.0
            JS[j, 1, 0], JS[j, 2, 0] = rho2, -rho1
            JS[j, 0, 1], JS[j, 2, 1] = -rho2, rho0
            JS[j, 0, 2], JS[j, 1, 2] = rho1, -rho0
            # U = I^A S: row i is (I^A_i,0:3 × ρ) + I^A_i,3:6; D = Sᵀ U, column q is
            # (U_0:3,q × ρ) + U_3:6,q.
            for i in range(6):
                x0, x1, x2 = IA[c, i, 0], IA[c, i, 1], IA[c, i, 2]
                JU[j, i, 0] = (x1 * rho2 - x2 * rho1) + IA[c, i, 3]
                JU[j, i, 1] = (x2 * rho0 - x0 * rho2) + IA[c, i, 4]
                JU[j, i, 2] = (x0 * rho1 - x1 * rho0) + IA[c, i, 5]
            for q in range(3):
                x0, x1, x2 = JU[j, 0, q], JU[j, 1, q], JU[j, 2, q]
                work[0, q] = (x1 * rho2 - x2 * rho1) + JU[j, 3, q]
                work[1, q] = (x2 * rho0 - x0 * rho2) + JU[j, 4, q]
                work[2, q] = (x0 * rho1 - x1 * rho0) + JU[j, 5, q]
            for k in range(3):
                sc = 0.0
                for t in range(6):
                    sc += JS[j, t, k] * JS[j, t, k] * IA[c, t, t]
                if work[k, k] < smallest * sc:
                    smallest = work[k, k] / sc
            # D = L diag(δ) Lᵀ (L unit lower; JD holds L below the diagonal, 1 / δ on it).
            a00, a01, a02 = work[0, 0], work[0, 1], work[0, 2]
            a11, a12, a22 = work[1, 1], work[1, 2], work[2, 2]
            r0 = 1.0 / a00
            l10 = a01 * r0
            l20 = a02 * r0
            r1 = 1.0 / (a11 - l10 * a01)
            m12 = a12 - l20 * a01
            l21 = m12 * r1
            r2 = 1.0 / (a22 - l20 * a02 - l21 * m12)
            JD[j, 0, 0], JD[j, 1, 1], JD[j, 2, 2] = r0, r1, r2
            JD[j, 1, 0], JD[j, 2, 0], JD[j, 2, 1] = l10, l20, l21
            JD[j, 0, 1] = JD[j, 0, 2] = JD[j, 1, 2] = 0.0
            # The subtree passes on a point mass at the anchor, K = A − B̂ D⁻¹ B̂ᵀ (B̂ =
            # U_0:3 = A [ρ]× + B), formed as A − Σ_k w_k w_kᵀ / δ_k with w = L⁻¹ B̂ᵀ (each
            # term <= A: no growth). The solve takes K (into U_0:3) and B̂ D⁻¹ = wᵀ
            # diag(δ)⁻¹ L⁻ᵀ... (into U_3:6); it reads no other part of U for a ball.
            for i in range(3):
                w0 = JU[j, i, 0]
                w1 = JU[j, i, 1] - l10 * w0
                w2 = JU[j, i, 2] - l20 * w0 - l21 * w1
                work[3 + i, 0], work[3 + i, 1], work[3 + i, 2] = w0, w1, w2
                e2 = w2 * r2
                e1 = w1 * r1 - l21 * e2
                JU[j, 3 + i, 0] = w0 * r0 - l10 * e1 - l20 * e2
                JU[j, 3 + i, 1] = e1
                JU[j, 3 + i, 2] = e2
            if p >= 0:
                for i in range(3):
                    for t in range(i, 3):
                        v = IA[c, i, t] - ((work[3 + i, 0] * work[3 + t, 0] * r0
                                            + work[3 + i, 1] * work[3 + t, 1] * r1)
                                           + work[3 + i, 2] * work[3 + t, 2] * r2)
                        JU[j, i, t] = v
                        JU[j, t, i] = v
                JV[j, V_RHOP, 0], JV[j, V_RHOP, 1], JV[j, V_RHOP, 2] = rp0, rp1, rp2
                _add_point_mass(JU, j, IA, p, rp0, rp1, rp2)
            continue
        elif p >= 0:   # fixed: nothing eliminated
            for i in range(6):
                for t in range(6):
                    work[i, t] = IA[c, i, t]
        if p >= 0:
            _add_shifted(work, IA, p, d0, d1, d2)
    return smallest


@njit(cache=True, inline='always')
def _ball_up(j, c, p, j_rows, IA, JD, JU, JV, P, JG, JQ, rhs):
    """
    Take a ball's up step: ``q₀ = −D⁻¹ Sᵀ z`` and the force ``f`` it passes to its parent.

    In the anchor frame the ball's bias wrench ``z + U q₀`` is the pure force ``f = z_v
    + B̂ q₀`` at the anchor (its moment there is ``Sᵀ z + D q₀ = 0``): the parent gets
    ``(f, ρ_p × f)``. ``g = (s c, 0)``; ``z = p_c + I^A g``; ``f`` goes to ``JG[j, 3:6]``.
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
    # Sᵀ z = z_ω − ρ × z_v (the moment about the anchor), then L Lᵀ q₀ = −Sᵀ z.
    r0, r1, r2 = JV[j, V_RHO, 0], JV[j, V_RHO, 1], JV[j, V_RHO, 2]
    t0 = z3 - (r1 * z2 - r2 * z1)
    t1 = z4 - (r2 * z0 - r0 * z2)
    t2 = z5 - (r0 * z1 - r1 * z0)
    q0, q1, q2 = _ldl_solve(JD, j, -t0, -t1, -t2)
    JQ[j, 0], JQ[j, 1], JQ[j, 2] = q0, q1, q2
    # f = z_v + B̂ q₀ = z_v − (B̂ D⁻¹) Sᵀ z: off q₀'s chain of dependent operations.
    f0 = z0 - (JU[j, 3, 0] * t0 + JU[j, 3, 1] * t1 + JU[j, 3, 2] * t2)
    f1 = z1 - (JU[j, 4, 0] * t0 + JU[j, 4, 1] * t1 + JU[j, 4, 2] * t2)
    f2 = z2 - (JU[j, 5, 0] * t0 + JU[j, 5, 1] * t1 + JU[j, 5, 2] * t2)
    JG[j, 3], JG[j, 4], JG[j, 5] = f0, f1, f2
    if p >= 0:
        e0, e1, e2 = JV[j, V_RHOP, 0], JV[j, V_RHOP, 1], JV[j, V_RHOP, 2]
        P[p, 0] += f0
        P[p, 1] += f1
        P[p, 2] += f2
        P[p, 3] += e1 * f2 - e2 * f1
        P[p, 4] += e2 * f0 - e0 * f2
        P[p, 5] += e0 * f1 - e1 * f0


@njit(cache=True, inline='always')
def _ball_down(j, c, p, j_rows, JD, JU, JV, Acc, JG, JQ, out):
    """
    Take a ball's down step: its child's acceleration and ``λ = s (f + K ŷ)``.

    ``ŷ = a_p,v + a_p,ω × ρ_p`` is the parent's anchor acceleration (0 at the world);
    the child's ``ω̇ = q₀ − D⁻¹ B̂ᵀ ŷ`` (the parent's ``ω̇`` drops out exactly), ``a_v =
    ŷ + g_v + ρ_c × ω̇``; the joint force on the child, ``F_v = K (ŷ + g_v) + (f − K g_v)``,
    is ``f + K ŷ`` (at the world, ``ŷ = 0`` and ``F_v = z_v + B̂ q₀``).
    """
    y0 = y1 = y2 = 0.0
    q0, q1, q2 = JQ[j, 0], JQ[j, 1], JQ[j, 2]
    f0, f1, f2 = JG[j, 3], JG[j, 4], JG[j, 5]
    if p >= 0:
        e0, e1, e2 = JV[j, V_RHOP, 0], JV[j, V_RHOP, 1], JV[j, V_RHOP, 2]
        w0, w1, w2 = Acc[p, 3], Acc[p, 4], Acc[p, 5]
        y0 = Acc[p, 0] + (w1 * e2 - w2 * e1)
        y1 = Acc[p, 1] + (w2 * e0 - w0 * e2)
        y2 = Acc[p, 2] + (w0 * e1 - w1 * e0)
        # D⁻¹ B̂ᵀ ŷ = (B̂ D⁻¹)ᵀ ŷ.
        q0 -= JU[j, 3, 0] * y0 + JU[j, 4, 0] * y1 + JU[j, 5, 0] * y2
        q1 -= JU[j, 3, 1] * y0 + JU[j, 4, 1] * y1 + JU[j, 5, 1] * y2
        q2 -= JU[j, 3, 2] * y0 + JU[j, 4, 2] * y1 + JU[j, 5, 2] * y2
        f0 += JU[j, 0, 0] * y0 + JU[j, 0, 1] * y1 + JU[j, 0, 2] * y2
        f1 += JU[j, 1, 0] * y0 + JU[j, 1, 1] * y1 + JU[j, 1, 2] * y2
        f2 += JU[j, 2, 0] * y0 + JU[j, 2, 1] * y1 + JU[j, 2, 2] * y2
    a0 = y0 + JG[j, 0]
    a1 = y1 + JG[j, 1]
    a2 = y2 + JG[j, 2]
    r0, r1, r2 = JV[j, V_RHO, 0], JV[j, V_RHO, 1], JV[j, V_RHO, 2]
    Acc[c, 0] = a0 + (r1 * q2 - r2 * q1)
    Acc[c, 1] = a1 + (r2 * q0 - r0 * q2)
    Acc[c, 2] = a2 + (r0 * q1 - r1 * q0)
    Acc[c, 3], Acc[c, 4], Acc[c, 5] = q0, q1, q2
    out[j_rows[j, 0]] = JV[j, V_SIGN, 0] * f0
    out[j_rows[j, 1]] = JV[j, V_SIGN, 1] * f1
    out[j_rows[j, 2]] = JV[j, V_SIGN, 2] * f2


@njit(cache=True)
def _free_factor(IA, c):
    """
    Factorize ``I^A_c = L Lᵀ`` in place (Cholesky; allocation-free).

    A free root's or a distance row's child. ``L`` goes below the diagonal of ``IA[c]``
    and ``1 / L_kk`` on it (the upper triangle keeps ``I^A_c``). Returns the smallest
    ``L_kk² / I^A_kk`` (its pivots over their scale; not positive, or NaN, where
    ``I^A_c`` is not positive definite).
    """
    smallest = 1.0
    for k in range(6):
        s = IA[c, k, k]
        scale = s
        for t in range(k):
            s -= IA[c, k, t] * IA[c, k, t]
        if s < smallest * scale or s != s:   # (NaN: kept)
            smallest = s / scale
        inv = 1.0 / np.sqrt(s)
        IA[c, k, k] = inv
        for i in range(k + 1, 6):
            v = IA[c, i, k]
            for t in range(k):
                v -= IA[c, i, t] * IA[c, k, t]
            IA[c, i, k] = v * inv
    return smallest


@njit(cache=True)
def _free_solve(IA, c, P, Acc):
    """Set a free root's acceleration ``a_c = −(I^A_c)⁻¹ p_c`` (:func:`_free_factor`'s ``L``)."""
    for k in range(6):
        v = -P[c, k]
        for t in range(k):
            v -= IA[c, k, t] * Acc[c, t]
        Acc[c, k] = v * IA[c, k, k]
    for k in range(5, -1, -1):
        v = Acc[c, k]
        for t in range(k + 1, 6):
            v -= IA[c, t, k] * Acc[c, t]
        Acc[c, k] = v * IA[c, k, k]


@njit(cache=True)
def _world_block(G, r, R, body, JS, j, col):
    """``JS[j, :, col] = (G[r, 0:3], R[body] G[r, 3:6])``: a row's block in world axes."""
    t = _world_torque(G, r, R, body)
    JS[j, 0, col], JS[j, 1, col], JS[j, 2, col] = G[r, 0], G[r, 1], G[r, 2]
    JS[j, 3, col], JS[j, 4, col], JS[j, 5, col] = t[0], t[1], t[2]


@njit(cache=True)
def _distance_factor(j, c, p, j_rows, j_cside, Ga, Gb, R, IA, JS, JU, JD):
    """
    Eliminate a distance row's child (``IA[c]`` already its Cholesky factor, in place).

    ``JS[j, :, 0]`` the parent block ``w_p`` (0 at the world), ``JS[j, :, 1]`` the
    child's ``w_c``, ``JU[j, :, 0]`` ``h = (I^A_c)⁻¹ w_c``, ``JD[j, 2, 2]`` ``1 / s``
    with ``s = w_cᵀ h``; the parent receives ``w_p w_pᵀ / s``.
    """
    r = j_rows[j, 0]
    if j_cside[j, 0] == 0:
        _world_block(Ga, r, R, c, JS, j, 1)
        if p >= 0:
            _world_block(Gb, r, R, p, JS, j, 0)
    else:
        _world_block(Gb, r, R, c, JS, j, 1)
        if p >= 0:
            _world_block(Ga, r, R, p, JS, j, 0)
    if p < 0:
        for i in range(6):
            JS[j, i, 0] = 0.0
    # h = L⁻ᵀ L⁻¹ w_c, s = |L⁻¹ w_c|².
    ss = 0.0
    for k in range(6):
        v = JS[j, k, 1]
        for t in range(k):
            v -= IA[c, k, t] * JU[j, t, 0]
        v *= IA[c, k, k]
        JU[j, k, 0] = v
        ss += v * v
    for k in range(5, -1, -1):
        v = JU[j, k, 0]
        for t in range(k + 1, 6):
            v -= IA[c, t, k] * JU[j, t, 0]
        JU[j, k, 0] = v * IA[c, k, k]
    sinv = 1.0 / ss
    JD[j, 2, 2] = sinv
    if p >= 0:
        for i in range(6):
            wi = JS[j, i, 0] * sinv
            for t in range(6):
                IA[p, i, t] += wi * JS[j, t, 0]


@njit(cache=True)
def _distance_up(j, c, p, j_rows, IA, JS, JD, P, Acc, JQ, rhs):
    """
    Take a distance row's up step: ``a₀ = −(I^A_c)⁻¹ p_c`` (kept in ``Acc[c]``) and ``τ``.

    ``τ = rhs − w_cᵀ a₀`` (into ``JQ[j, 0]``); the parent's bias gets ``−w_p τ / s``.
    """
    _free_solve(IA, c, P, Acc)
    t = rhs[j_rows[j, 0]]
    for i in range(6):
        t -= JS[j, i, 1] * Acc[c, i]
    JQ[j, 0] = t
    if p >= 0:
        ts = t * JD[j, 2, 2]
        for i in range(6):
            P[p, i] -= JS[j, i, 0] * ts


@njit(cache=True)
def _distance_down(j, c, p, j_rows, JS, JU, JD, Acc, JQ, out):
    """Take a distance row's down step: ``λ = (τ − w_pᵀ a_p) / s``, ``a_c = a₀ + h λ``."""
    t = JQ[j, 0]
    if p >= 0:
        for i in range(6):
            t -= JS[j, i, 0] * Acc[p, i]
    lam = t * JD[j, 2, 2]
    out[j_rows[j, 0]] = lam
    for i in range(6):
        Acc[c, i] += JU[j, i, 0] * lam


@njit(cache=True, inline='always')
def _ldl_solve(JD, j, b0, b1, b2):
    """``D⁻¹ b`` with joint j's ``D = L diag(δ) Lᵀ`` (``JD[j]``: L below the diagonal, 1 / δ)."""
    x1 = b1 - JD[j, 1, 0] * b0
    x2 = (b2 - JD[j, 2, 0] * b0 - JD[j, 2, 1] * x1) * JD[j, 2, 2]
    x1 = x1 * JD[j, 1, 1] - JD[j, 2, 1] * x2
    x0 = b0 * JD[j, 0, 0] - JD[j, 1, 0] * x1 - JD[j, 2, 0] * x2
    return x0, x1, x2


@njit(cache=True)
def nullspace_solve(j_child, j_parent, j_type, j_rows, IA, JS, JU, JD, JV, P, Acc, JG, JQ,
                    rhs, out):
    """
    Solve ``G M⁻¹ Gᵀ λ = rhs`` with the factors of :func:`nullspace_factor` (allocation-free).

    ``P``, ``Acc`` (n, 6), ``JG`` (nj, 6) and ``JQ`` (nj, 3) are workspace from
    :func:`nullspace_arrays`; ``out`` (m,) receives ``λ`` (and ``Acc`` the body
    accelerations ``M⁻¹ Gᵀ λ`` in world axes, ``(a_v, a_ω)``).
    """
    nj = j_child.shape[0]
    for j in range(nj):
        c = j_child[j]
        for t in range(6):
            P[c, t] = 0.0
    # Up: g, z = p_c + I^A g, q₀ = −D⁻¹ Sᵀ z, p_p += Xᵀ (z + U q₀).
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
        w0 = w1 = w2 = 0.0
        if typ == HINGE:
            c1, c2 = rhs[j_rows[j, SLOT_DOT]], rhs[j_rows[j, SLOT_DOT + 1]]
            w0 = c1 * JV[j, V_DUAL, 0] + c2 * JV[j, V_DUAL + 1, 0]
            w1 = c1 * JV[j, V_DUAL, 1] + c2 * JV[j, V_DUAL + 1, 1]
            w2 = c1 * JV[j, V_DUAL, 2] + c2 * JV[j, V_DUAL + 1, 2]
        elif typ != BALL:
            c1, c2 = rhs[j_rows[j, SLOT_DOT]], rhs[j_rows[j, SLOT_DOT + 1]]
            c3 = rhs[j_rows[j, SLOT_DOT + 2]]
            w0 = c1 * JV[j, V_DUAL, 0] + c2 * JV[j, V_DUAL + 1, 0] + c3 * JV[j, V_DUAL + 2, 0]
            w1 = c1 * JV[j, V_DUAL, 1] + c2 * JV[j, V_DUAL + 1, 1] + c3 * JV[j, V_DUAL + 2, 1]
            w2 = c1 * JV[j, V_DUAL, 2] + c2 * JV[j, V_DUAL + 1, 2] + c3 * JV[j, V_DUAL + 2, 2]
        if typ == SLIDER:
            e1 = rhs[j_rows[j, SLOT_LINE]] - (JV[j, V_TAU, 0] * w0 + JV[j, V_TAU, 1] * w1
                                              + JV[j, V_TAU, 2] * w2)
            e2 = rhs[j_rows[j, SLOT_LINE + 1]] - (JV[j, V_TAU + 1, 0] * w0
                                                  + JV[j, V_TAU + 1, 1] * w1
                                                  + JV[j, V_TAU + 1, 2] * w2)
            v0 = e1 * JV[j, V_LDUAL, 0] + e2 * JV[j, V_LDUAL + 1, 0]
            v1 = e1 * JV[j, V_LDUAL, 1] + e2 * JV[j, V_LDUAL + 1, 1]
            v2 = e1 * JV[j, V_LDUAL, 2] + e2 * JV[j, V_LDUAL + 1, 2]
        else:
            r0, r1, r2 = JV[j, V_RHO, 0], JV[j, V_RHO, 1], JV[j, V_RHO, 2]
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
        dof = _DOF[typ]
        for k in range(dof):
            JQ[j, k] = -((JS[j, 0, k] * z0 + JS[j, 1, k] * z1) + (JS[j, 2, k] * z2
                         + JS[j, 3, k] * z3) + (JS[j, 4, k] * z4 + JS[j, 5, k] * z5))
        if dof == 1:
            JQ[j, 0] *= JD[j, 0, 0]
        elif dof == 3:
            u0, u1, u2 = JQ[j, 0], JQ[j, 1], JQ[j, 2]
            for k in range(3):
                JQ[j, k] = JD[j, k, 0] * u0 + JD[j, k, 1] * u1 + JD[j, k, 2] * u2
        if p >= 0:
            for k in range(dof):
                q = JQ[j, k]
                z0 += JU[j, 0, k] * q
                z1 += JU[j, 1, k] * q
                z2 += JU[j, 2, k] * q
                z3 += JU[j, 3, k] * q
                z4 += JU[j, 4, k] * q
                z5 += JU[j, 5, k] * q
            d0, d1, d2 = JV[j, V_D, 0], JV[j, V_D, 1], JV[j, V_D, 2]
            P[p, 0] += z0
            P[p, 1] += z1
            P[p, 2] += z2
            P[p, 3] += z3 + (d1 * z2 - d2 * z1)
            P[p, 4] += z4 + (d2 * z0 - d0 * z2)
            P[p, 5] += z5 + (d0 * z1 - d1 * z0)
    # Down: y = X a_p, a_c = y + g + S (q₀ − D⁻¹ Uᵀ y), F = I^A a_c + p_c = W_c λ.
    for j in range(nj - 1, -1, -1):
        c = j_child[j]
        p = j_parent[j]
        typ = j_type[j]
        if typ == BALL:
            _ball_down(j, c, p, j_rows, JD, JU, JV, Acc, JG, JQ, out)
            continue
        if typ == FREE:
            _free_solve(IA, c, P, Acc)
            continue
        if typ == DISTANCE:
            _distance_down(j, c, p, j_rows, JS, JU, JD, Acc, JQ, out)
            continue
        dof = _DOF[typ]
        y0 = y1 = y2 = y3 = y4 = y5 = 0.0
        if p >= 0:
            d0, d1, d2 = JV[j, V_D, 0], JV[j, V_D, 1], JV[j, V_D, 2]
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
        if dof == 1:
            q = JQ[j, 0]
            if p >= 0:
                q -= JD[j, 0, 0] * ((JU[j, 0, 0] * y0 + JU[j, 1, 0] * y1)
                                    + (JU[j, 2, 0] * y2 + JU[j, 3, 0] * y3)
                                    + (JU[j, 4, 0] * y4 + JU[j, 5, 0] * y5))
            a0 += JS[j, 0, 0] * q
            a1 += JS[j, 1, 0] * q
            a2 += JS[j, 2, 0] * q
            a3 += JS[j, 3, 0] * q
            a4 += JS[j, 4, 0] * q
            a5 += JS[j, 5, 0] * q
        elif dof == 3:
            e0 = e1 = e2 = 0.0
            if p >= 0:
                e0 = ((JU[j, 0, 0] * y0 + JU[j, 1, 0] * y1) + (JU[j, 2, 0] * y2
                      + JU[j, 3, 0] * y3) + (JU[j, 4, 0] * y4 + JU[j, 5, 0] * y5))
                e1 = ((JU[j, 0, 1] * y0 + JU[j, 1, 1] * y1) + (JU[j, 2, 1] * y2
                      + JU[j, 3, 1] * y3) + (JU[j, 4, 1] * y4 + JU[j, 5, 1] * y5))
                e2 = ((JU[j, 0, 2] * y0 + JU[j, 1, 2] * y1) + (JU[j, 2, 2] * y2
                      + JU[j, 3, 2] * y3) + (JU[j, 4, 2] * y4 + JU[j, 5, 2] * y5))
            q0 = JQ[j, 0] - (JD[j, 0, 0] * e0 + JD[j, 0, 1] * e1 + JD[j, 0, 2] * e2)
            q1 = JQ[j, 1] - (JD[j, 1, 0] * e0 + JD[j, 1, 1] * e1 + JD[j, 1, 2] * e2)
            q2 = JQ[j, 2] - (JD[j, 2, 0] * e0 + JD[j, 2, 1] * e1 + JD[j, 2, 2] * e2)
            # S = ([ρ]×, I): S q = (ρ × q, q).
            r0, r1, r2 = JV[j, V_RHO, 0], JV[j, V_RHO, 1], JV[j, V_RHO, 2]
            a0 += r1 * q2 - r2 * q1
            a1 += r2 * q0 - r0 * q2
            a2 += r0 * q1 - r1 * q0
            a3 += q0
            a4 += q1
            a5 += q2
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
            l1 = JV[j, V_LDUAL, 0] * f0 + JV[j, V_LDUAL, 1] * f1 + JV[j, V_LDUAL, 2] * f2
            l2 = JV[j, V_LDUAL + 1, 0] * f0 + JV[j, V_LDUAL + 1, 1] * f1 \
                + JV[j, V_LDUAL + 1, 2] * f2
            out[j_rows[j, SLOT_LINE]] = l1
            out[j_rows[j, SLOT_LINE + 1]] = l2
            h0 = f3 - (l1 * JV[j, V_TAU, 0] + l2 * JV[j, V_TAU + 1, 0])
            h1 = f4 - (l1 * JV[j, V_TAU, 1] + l2 * JV[j, V_TAU + 1, 1])
            h2 = f5 - (l1 * JV[j, V_TAU, 2] + l2 * JV[j, V_TAU + 1, 2])
        else:
            out[j_rows[j, 0]] = JV[j, V_SIGN, 0] * f0
            out[j_rows[j, 1]] = JV[j, V_SIGN, 1] * f1
            out[j_rows[j, 2]] = JV[j, V_SIGN, 2] * f2
            r0, r1, r2 = JV[j, V_RHO, 0], JV[j, V_RHO, 1], JV[j, V_RHO, 2]
            h0 = f3 - (r1 * f2 - r2 * f1)
            h1 = f4 - (r2 * f0 - r0 * f2)
            h2 = f5 - (r0 * f1 - r1 * f0)
        nd = 2 if typ == HINGE else (0 if typ == BALL else 3)
        for i in range(nd):
            out[j_rows[j, SLOT_DOT + i]] = (JV[j, V_DUAL + i, 0] * h0 + JV[j, V_DUAL + i, 1] * h1
                                            + JV[j, V_DUAL + i, 2] * h2)
