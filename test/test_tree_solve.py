"""Tree-structured KKT solver (Baraff 1996) against dense numpy solves of G M⁻¹ Hᵀ."""

import os
from pathlib import Path
import subprocess
import sys

import numpy as np
import pytest
from rigid_body_sim.core.graph import tree_structure
from rigid_body_sim.core.kernels.tree_solve import factor_arrays, tree_factor, tree_solve

EPS = np.finfo(float).eps


class TreeSolver:
    """
    The compiled tree solve for these tests: structure, preallocated factors, factor, solve.

    Parameters
    ----------
    a, b : array_like of int, shape (m,)
        Bodies of each row (``b == n_bodies``: the world), see :func:`tree_structure`.
    n_bodies : int
        Number of bodies.

    Raises
    ------
    ValueError
        If the body/group graph has a cycle (use a general sparse solver).

    """

    def __init__(self, a, b, n_bodies: int):
        structure = tree_structure(a, b, n_bodies)
        if structure is None:
            raise ValueError('the constraint graph has a closed loop: not a tree')
        self.structure = structure
        self.m = int(np.size(a))
        self.S, self.piv, self.P, self.Q, self.B, self.W, self.E, self.tmp = \
            factor_arrays(structure)
        self.pivot = np.nan

    def factor(self, Ga, Gb, minv6, Ha=None, Hb=None, reg: float = 0.0) -> float:
        """
        Factorize ``G M⁻¹ Hᵀ + reg I`` (``H = G`` when ``Ha``/``Hb`` are omitted).

        Parameters
        ----------
        Ga, Gb : array_like, shape (m, 6)
            Blocks of ``G`` on bodies ``a`` and ``b``.
        minv6 : array_like, shape (n_bodies, 6)
            Diagonal inverse masses.
        Ha, Hb : array_like, shape (m, 6), optional
            Blocks of ``H``.
        reg : float
            Tikhonov term ``>= 0``.

        Returns
        -------
        float
            Smallest relative pivot (see :func:`tree_factor`).

        """
        Ga = np.ascontiguousarray(Ga, dtype=np.float64)
        Gb = np.ascontiguousarray(Gb, dtype=np.float64)
        Ha = Ga if Ha is None else np.ascontiguousarray(Ha, dtype=np.float64)
        Hb = Gb if Hb is None else np.ascontiguousarray(Hb, dtype=np.float64)
        minv6 = np.ascontiguousarray(minv6, dtype=np.float64)
        m, n = self.m, self.structure.n_bodies
        for name, x, shape in (('Ga', Ga, (m, 6)), ('Gb', Gb, (m, 6)), ('Ha', Ha, (m, 6)),
                               ('Hb', Hb, (m, 6)), ('minv6', minv6, (n, 6))):
            if x.shape != shape:
                raise ValueError(f'{name} must have shape {shape}, got {x.shape}')
        if not reg >= 0.0:
            raise ValueError(f'reg must be >= 0, got {reg}')
        self.pivot = tree_factor(*self.structure.arrays, Ga, Gb, Ha, Hb, minv6, float(reg),
                                 self.S, self.piv, self.P, self.Q, self.B, self.W,
                                 Ha is Ga and Hb is Gb)
        return self.pivot

    def solve(self, rhs) -> np.ndarray:
        """
        Solve with the last factorization.

        Parameters
        ----------
        rhs : array_like, shape (m,) or (m, q)
            One or ``q`` right-hand sides.

        Returns
        -------
        ndarray, shape of ``rhs``
            ``x`` with ``(A + reg I) x = rhs``.

        """
        rhs = np.asarray(rhs, dtype=np.float64)
        if rhs.ndim not in (1, 2) or rhs.shape[0] != self.m:
            raise ValueError(f'rhs must have shape ({self.m},) or ({self.m}, q)')
        args = (*self.structure.arrays[:4], self.S, self.piv, self.P, self.Q, self.B, self.E,
                self.tmp)
        if rhs.ndim == 1:
            out = np.empty(self.m)
            tree_solve(*args, np.ascontiguousarray(rhs), out)
            return out
        out = np.empty((rhs.shape[1], self.m))
        for q in range(rhs.shape[1]):
            tree_solve(*args, np.ascontiguousarray(rhs[:, q]), out[q])
        return out.T.copy()


def random_minv6(rng, n):
    """Inverse masses of bodies with mass 0.1..10 and principal inertias 1e-4..1."""
    mass = 10.0 ** rng.uniform(-1.0, 1.0, size=n)
    inertia = 10.0 ** rng.uniform(-4.0, 0.0, size=(n, 3))
    return np.hstack([np.repeat(1.0 / mass[:, None], 3, axis=1), 1.0 / inertia])


def rows_of(joints, n, rng):
    """Rows (a, b) of joints ``(body, other or -1: world, k)``; each row's side is random."""
    a, b = [], []
    for i, j, k in joints:
        for _ in range(k):
            if j < 0:
                a.append(i)
                b.append(n)
            elif rng.random() < 0.5:
                a.append(i)
                b.append(j)
            else:
                a.append(j)
                b.append(i)
    return np.array(a), np.array(b)


def blocks(rng, m):
    """Random Jacobian blocks Ga, Gb, shape (m, 6) each."""
    return rng.normal(size=(m, 6)), rng.normal(size=(m, 6))


def dense_A(a, b, Ga, Gb, Ha, Hb, minv6):
    """Assemble A = G M⁻¹ Hᵀ densely from the blocks."""
    n, m = minv6.shape[0], a.size
    G = np.zeros((m, 6 * n + 6))   # the extra block is the world, dropped below
    H = np.zeros((m, 6 * n + 6))
    for r in range(m):
        G[r, 6 * a[r]:6 * a[r] + 6] += Ga[r]
        H[r, 6 * a[r]:6 * a[r] + 6] += Ha[r]
        G[r, 6 * b[r]:6 * b[r] + 6] += Gb[r]
        H[r, 6 * b[r]:6 * b[r] + 6] += Hb[r]
    G, H = G[:, :6 * n], H[:, :6 * n]
    return G @ (minv6.ravel()[:, None] * H.T)


def draw(rng, a, b, n, unsymmetric):
    """Random blocks and masses; redrawn until cond(A) < 1e8 (see :func:`check`)."""
    for _ in range(50):
        Ga, Gb = blocks(rng, a.size)
        Ha, Hb = Ga, Gb
        if unsymmetric:
            Ha = Ga + 0.1 * rng.normal(size=Ga.shape)
            Hb = Gb + 0.1 * rng.normal(size=Gb.shape)
        minv6 = random_minv6(rng, n)
        A = dense_A(a, b, Ga, Gb, Ha, Hb, minv6)
        if np.linalg.cond(A) < 1e8:
            return Ga, Gb, Ha, Hb, minv6, A
    raise AssertionError('no well-conditioned draw')


def forward_bound(A):
    """
    Return the bound on the relative difference of two backward-stable solves of A x = b.

    Each is within cond(A) · η of the exact solution, η its backward error (about
    eps; measured at most 0.25 eps): two differ by at most 2 cond(A) eps. Times 5 for
    compiled code that differs in the last bits on another CPU (vector width, FMA).
    """
    return 10.0 * np.linalg.cond(A) * EPS


def assert_solves(A, rhs, x):
    """
    Assert that ``x`` solves ``A x = rhs`` as a backward-stable solve does.

    The forward error against numpy.linalg.solve is bounded by :func:`forward_bound`
    of the draw's own cond(A) (up to 1e8 here: 2e-8); the backward error (residual)
    is what catches a wrong solve, whose residual is of the order of ``rhs``.
    """
    expected = np.linalg.solve(A, rhs)
    err = np.linalg.norm(x - expected) / np.linalg.norm(expected)
    assert err < forward_bound(A), err   # bound: 2 cond(A) eps (measured <= 0.09 cond(A) eps), x5
    residual = np.linalg.norm(A @ x - rhs)
    # bound: the solve's backward error and the rounding of A x - rhs, each <= m eps |A|_F |x|
    assert residual < 2 * A.shape[0] * EPS * np.linalg.norm(A) * np.linalg.norm(x), residual


def check(rng, joints, n, unsymmetric=False, n_rhs=1):
    """
    Factor and solve with the tree solver; compare with numpy.linalg.solve.

    Any backward-stable solve has a forward error of up to about cond(A) · eps, so
    the draws keep cond(A) < 1e8 (random blocks with inertias down to 1e-4
    reach 1e12 now and then) to keep the forward comparison meaningful; it is made
    against the draw's own cond(A) · eps (:func:`assert_solves`), and the backward
    error (residual) against m · eps.
    """
    a, b = rows_of(joints, n, rng)
    Ga, Gb, Ha, Hb, minv6, A = draw(rng, a, b, n, unsymmetric)
    solver = TreeSolver(a, b, n)
    pivot = solver.factor(Ga, Gb, minv6, Ha, Hb)
    # bound: >= ~1/cond(A) > 1e-8 (rank test: 1e-12); <= 1 (H = G: Hadamard) to k eps = 1e-15
    assert 1e-12 < pivot <= 1.0 + 1e-12
    rhs = rng.normal(size=(a.size, n_rhs)) if n_rhs > 1 else rng.normal(size=a.size)
    assert_solves(A, rhs, solver.solve(rhs))
    return solver, A


def test_ball_chain_to_world(rng):
    n = 12
    joints = [(0, -1, 3)] + [(i, i - 1, 3) for i in range(1, n)]
    check(rng, joints, n)


def test_hinge_chain(rng):
    n = 15
    joints = [(0, -1, 5)] + [(i, i - 1, 5) for i in range(1, n)]
    check(rng, joints, n)


def test_hinge_chain_unsymmetric(rng):
    n = 10
    joints = [(0, -1, 5)] + [(i, i - 1, 5) for i in range(1, n)]
    check(rng, joints, n, unsymmetric=True)


def random_tree_joints(rng, n, n_world):
    """
    Return the joints of a random tree (group sizes 1..6) with world groups of 1..3 rows.

    (World groups of up to 6 rows on several bodies over-constrain the tree so much that
    random draws have cond(A) up to 1e12; they are exercised in the other tests.)
    """
    joints = [(i, int(rng.integers(i)), int(rng.integers(1, 7))) for i in range(1, n)]
    for body in rng.choice(n, size=n_world, replace=False):
        joints.append((int(body), -1, int(rng.integers(1, 4))))
    order = rng.permutation(len(joints))
    return [joints[i] for i in order]


@pytest.mark.parametrize('seed', range(6))
@pytest.mark.parametrize('unsymmetric', [False, True])
def test_random_tree(seed, unsymmetric):
    rng = np.random.default_rng(seed)
    n = 30
    check(rng, random_tree_joints(rng, n, 3), n, unsymmetric=unsymmetric)


def test_star(rng):
    n = 11
    joints = [(0, -1, 3)] + [(c, 0, int(rng.integers(1, 7))) for c in range(1, n)]
    check(rng, joints, n)
    # The hub as a leaf of nothing: the star floating free (no world group).
    check(rng, [(0, c, 5) for c in range(1, n)], n)


def test_forest_and_unused_bodies(rng):
    # Bodies 0..4 and 5..9 form two trees, 10..12 are in no row, 13 only has world rows.
    n = 14
    joints = [(1, 0, 5), (2, 1, 3), (3, 1, 6), (4, 0, 2), (0, -1, 5),
              (6, 5, 5), (7, 6, 4), (8, 5, 1), (9, 8, 6), (13, -1, 3), (13, -1, 2)]
    solver, _ = check(rng, joints, n, unsymmetric=True)
    st = solver.structure
    used = set(st.group_parent.tolist()) | set(st.group_child.tolist()) - {-1}
    assert used == set(range(10)) | {13}


def test_welded_body_below_a_group(rng):
    """
    A body welded to the world (6 rows) below a hinge, and a loop closed through the world.

    In Baraff's KKT order this leaf would give the hinge a singular pivot block (the welded
    body has no mobility left); on A the pivot blocks are true Schur complements.
    """
    n = 6
    joints = [(0, -1, 3)] + [(i, i - 1, 5) for i in range(1, n)] + [(n - 1, -1, 6)]
    check(rng, joints, n)
    check(rng, joints, n, unsymmetric=True)


def test_immovable_body(rng):
    """A body with zero inverse mass (immovable) at the end of a chain."""
    n = 6
    a, b = rows_of([(0, -1, 3)] + [(i, i - 1, 5) for i in range(1, n)], n, rng)
    Ga, Gb, _, _, minv6, _ = draw(rng, a, b, n, False)
    minv6[n - 1] = 0.0
    A = dense_A(a, b, Ga, Gb, Ga, Gb, minv6)
    solver = TreeSolver(a, b, n)
    assert solver.factor(Ga, Gb, minv6) > 1e-12   # bound: the rank test; pivot ~ 1/cond(A)
    rhs = rng.normal(size=a.size)
    assert_solves(A, rhs, solver.solve(rhs))


def test_rows_on_one_body(rng):
    """A row with a[r] == b[r] acts on one body with the block Ga + Gb (like a world row)."""
    n = 5
    a, b = rows_of([(0, -1, 3), (1, 0, 5), (2, 1, 5), (3, 2, 2), (4, 2, 4)], n, rng)
    a, b = np.concatenate([a, [2, 4]]), np.concatenate([b, [2, 4]])
    Ga, Gb, Ha, Hb, minv6, A = draw(rng, a, b, n, True)
    solver = TreeSolver(a, b, n)
    assert solver.factor(Ga, Gb, minv6, Ha, Hb) > 1e-12   # bound: the rank test (pivot ~ 1/cond)
    rhs = rng.normal(size=a.size)
    assert_solves(A, rhs, solver.solve(rhs))


def test_several_rhs_one_factorization(rng):
    n = 20
    solver, A = check(rng, random_tree_joints(rng, n, 2), n, unsymmetric=True, n_rhs=4)
    for _ in range(3):   # Newton-like reuse: each solve matches a fresh dense solve
        rhs = rng.normal(size=A.shape[0])
        assert_solves(A, rhs, solver.solve(rhs))


def test_kernels_directly(rng):
    n = 6
    a, b = rows_of([(0, -1, 6), (1, 0, 5), (2, 1, 5), (3, 1, 3), (5, 4, 2), (4, 3, 1)], n, rng)
    Ga, Gb, _, _, minv6, A = draw(rng, a, b, n, False)
    st = tree_structure(a, b, n)
    assert st is not None and st.block_size == 6 and st.n_groups == 6
    assert np.array_equal(np.sort(st.group_rows), np.arange(a.size))
    for r in range(a.size):
        x = st.row_group[r]
        assert r in st.group_rows[st.group_ptr[x]:st.group_ptr[x + 1]]
        assert st.group_parent[x] in (a[r], b[r]) and st.group_child[x] in (a[r], b[r], -1)
    # Every group comes after the other groups of its child body.
    for x in range(st.n_groups):
        c = st.group_child[x]
        others = [y for y in range(st.n_groups)
                  if y != x and c in (st.group_child[y], st.group_parent[y])]
        assert c < 0 or all(y < x for y in others)
    S, piv, P, Q, B, W, E, tmp = factor_arrays(st)
    pivot = tree_factor(*st.arrays, Ga, Gb, Ga, Gb, minv6, 0.0, S, piv, P, Q, B, W)
    assert pivot > 1e-12   # bound: the rank test; a full-rank draw's pivot is ~ 1/cond(A)
    rhs = rng.normal(size=a.size)
    out = np.empty_like(rhs)
    tree_solve(*st.arrays[:4], S, piv, P, Q, B, E, tmp, rhs, out)
    assert_solves(A, rhs, out)
    # The symmetric path (H = G promised): half of each symmetric product, mirrored.
    S, piv, P, Q, B, W, E, tmp = factor_arrays(st)
    tree_factor(*st.arrays, Ga, Gb, Ga, Gb, minv6, 0.0, S, piv, P, Q, B, W, True)
    # Exact: the lower half is a copy of the upper one (same run, no arithmetic).
    assert np.array_equal(W, np.transpose(W, (0, 2, 1)))
    sym = np.empty_like(rhs)
    tree_solve(*st.arrays[:4], S, piv, P, Q, B, E, tmp, rhs, sym)
    assert_solves(A, rhs, sym)
    # bound: two backward-stable solves (other rounding in the products): forward_bound
    assert np.linalg.norm(sym - out) < forward_bound(A) * np.linalg.norm(out)


@pytest.mark.parametrize('duplicate', ['between bodies', 'to the world'])
def test_redundant_group_pivot_and_regularization(rng, duplicate):
    n = 8
    joints = [(0, -1, 3)] + [(i, i - 1, 5) for i in range(1, n)]
    a, b = rows_of(joints, n, rng)
    Ga, Gb = blocks(rng, a.size)
    # Add a copy of the rows of one joint: the same joint twice.
    copy = np.flatnonzero((a == 4) & (b == 3) | (a == 3) & (b == 4))
    if duplicate == 'to the world':
        copy = np.flatnonzero(b == n)
    a, b = np.concatenate([a, a[copy]]), np.concatenate([b, b[copy]])
    Ga, Gb = np.vstack([Ga, Ga[copy]]), np.vstack([Gb, Gb[copy]])
    minv6 = random_minv6(rng, n)
    A = dense_A(a, b, Ga, Gb, Ga, Gb, minv6)
    solver = TreeSolver(a, b, n)
    full = TreeSolver(a[:-copy.size], b[:-copy.size], n)
    # bound: full rank, cond 1.6e5: pivot ~ 1/cond = 6e-6 (measured 1.6e-4), far above 1e-9
    assert full.factor(Ga[:-copy.size], Gb[:-copy.size], minv6) > 1e-9
    assert solver.factor(Ga, Gb, minv6) < 1e-12   # bound: 0 exactly, rounding ~ k eps = 1e-15
    reg = 1e-12 * np.abs(np.diag(A)).max()
    # bound: the null pivot becomes reg / max|diag A| = 1e-12 (to k eps = 1e-15): > 0.1e-12
    assert solver.factor(Ga, Gb, minv6, reg=reg) > 0.1e-12
    rhs = A @ rng.normal(size=a.size)   # consistent: the physical case
    x = solver.solve(rhs)
    # cond(A + reg I) is about 2e12: two backward-stable solves agree to about 2e12 · eps in
    # the null-space direction of A (how the load splits between the copies), exactly in A x.
    A_reg = A + reg * np.eye(a.size)
    forward = forward_bound(A_reg)   # bound: 2 cond(A + reg I) eps, x5: 5e-3 here
    expected = np.linalg.solve(A_reg, rhs)
    assert np.linalg.norm(x - expected) < forward * np.linalg.norm(expected)
    # bound: A x - rhs = -reg x exactly for the exact x_reg, + rounding 2 m eps |A|_F |x| (x10)
    m = a.size
    assert (np.linalg.norm(A @ x - rhs)
            < (reg + 20 * m * EPS * np.linalg.norm(A)) * np.linalg.norm(x))
    # bound: reg's bias reg / (smallest nonzero singular value) plus the rounding, forward
    sigma = np.linalg.svd(A, compute_uv=False)[-copy.size - 1]
    assert (np.linalg.norm(x - np.linalg.pinv(A) @ rhs)
            < (reg / sigma + forward) * np.linalg.norm(x))
    # The copies share the load equally (the minimum-norm multipliers); the exact x_reg
    # shares it exactly. bound: |e_copy - e_other| <= 2 |x - x_reg| <= 2 forward |x|
    assert np.linalg.norm(x[copy] - x[-copy.size:]) < 2 * forward * np.linalg.norm(x)


def test_closed_loop_is_detected():
    n = 4
    a = np.repeat([0, 1, 2, 3], 5)
    b = np.repeat([1, 2, 3, 0], 5)
    assert tree_structure(a, b, n) is None
    with pytest.raises(ValueError):
        TreeSolver(a, b, n)
    # A loop closed through the world is fine: the world has no unknowns.
    assert tree_structure(np.array([0, 1, 1]), np.array([4, 0, 4]), n) is not None
    # Rows (a, b) and (b, a) are one group, not a loop of two groups.
    assert tree_structure(np.array([0, 1]), np.array([1, 0]), n).n_groups == 1


def test_bad_input():
    with pytest.raises(ValueError):
        tree_structure(np.array([0, 5]), np.array([1, 2]), 4)
    with pytest.raises(ValueError):
        tree_structure(np.array([0]), np.array([1, 2]), 4)


def test_without_jit():
    """The kernels run unchanged as plain Python (NUMBA_DISABLE_JIT=1)."""
    code = (
        'import numpy as np\n'
        'import sys; sys.path.insert(0, "test")\n'
        'from test_tree_solve import TreeSolver\n'
        'rng = np.random.default_rng(1)\n'
        'a = np.repeat(np.arange(5), 5); b = np.repeat(np.arange(-1, 4), 5); b[b < 0] = 5\n'
        'Ga, Gb, Ha = rng.normal(size=(3, 25, 6)); minv6 = 1 + rng.random((5, 6))\n'
        's = TreeSolver(a, b, 5); p = s.factor(Ga, Gb, minv6, Ha, Gb)\n'
        'rhs = rng.normal(size=25); x = s.solve(rhs)\n'
        'G = np.zeros((25, 36)); H = np.zeros((25, 36)); r = np.arange(25)\n'
        'for k in range(6):\n'
        '    G[r, 6 * a + k] += Ga[:, k]; G[r, 6 * b + k] += Gb[:, k]\n'
        '    H[r, 6 * a + k] += Ha[:, k]; H[r, 6 * b + k] += Gb[:, k]\n'
        'A = G[:, :30] @ (minv6.ravel()[:, None] * H[:, :30].T)\n'
        'e = np.linalg.norm(x - np.linalg.solve(A, rhs)) / np.linalg.norm(x)\n'
        'r = np.linalg.norm(A @ x - rhs) / (np.linalg.norm(A) * np.linalg.norm(x))\n'
        # bound: the rank test for p; as assert_solves: 10 cond(A) eps forward, 2 m eps backward
        'assert p > 1e-12 and e < 10 * np.linalg.cond(A) * 2.2e-16, e\n'
        'assert r < 2 * 25 * 2.2e-16, r\n'
        'import numba; assert numba.config.DISABLE_JIT\n'
    )
    env = dict(os.environ, NUMBA_DISABLE_JIT='1')
    root = Path(__file__).resolve().parents[1]
    result = subprocess.run([sys.executable, '-c', code], env=env, cwd=root,
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
