"""Tree-structured KKT solver (Baraff 1996) against dense numpy solves of G M⁻¹ Hᵀ."""

import os
from pathlib import Path
import subprocess
import sys

import numpy as np
import pytest
from rigid_body_sim.core.tree_solve import (factor_arrays, tree_factor, tree_solve,
                                            tree_structure, TreeSolver)


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


def check(rng, joints, n, unsymmetric=False, n_rhs=1):
    """
    Factor and solve with the tree solver; compare with numpy.linalg.solve.

    Any backward-stable solve has a forward error of about cond(A) · eps, so
    the draws keep cond(A) < 1e8 (random blocks with inertias down to 1e-4
    reach 1e12 now and then) to make the 1e-10 comparison meaningful; the
    backward error (residual) is checked at 1e-14.
    """
    a, b = rows_of(joints, n, rng)
    Ga, Gb, Ha, Hb, minv6, A = draw(rng, a, b, n, unsymmetric)
    solver = TreeSolver(a, b, n)
    pivot = solver.factor(Ga, Gb, minv6, Ha, Hb)
    assert 1e-12 < pivot <= 1.0 + 1e-12
    rhs = rng.normal(size=(a.size, n_rhs)) if n_rhs > 1 else rng.normal(size=a.size)
    x = solver.solve(rhs)
    expected = np.linalg.solve(A, rhs)
    err = np.linalg.norm(x - expected) / np.linalg.norm(expected)
    assert err < 1e-10, err
    assert np.linalg.norm(A @ x - rhs) < 1e-14 * np.linalg.norm(A) * np.linalg.norm(x)
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
    assert solver.factor(Ga, Gb, minv6) > 1e-12
    rhs = rng.normal(size=a.size)
    x = solver.solve(rhs)
    assert np.linalg.norm(x - np.linalg.solve(A, rhs)) < 1e-10 * np.linalg.norm(x)


def test_rows_on_one_body(rng):
    """A row with a[r] == b[r] acts on one body with the block Ga + Gb (like a world row)."""
    n = 5
    a, b = rows_of([(0, -1, 3), (1, 0, 5), (2, 1, 5), (3, 2, 2), (4, 2, 4)], n, rng)
    a, b = np.concatenate([a, [2, 4]]), np.concatenate([b, [2, 4]])
    Ga, Gb, Ha, Hb, minv6, A = draw(rng, a, b, n, True)
    solver = TreeSolver(a, b, n)
    assert solver.factor(Ga, Gb, minv6, Ha, Hb) > 1e-12
    rhs = rng.normal(size=a.size)
    x = solver.solve(rhs)
    assert np.linalg.norm(x - np.linalg.solve(A, rhs)) < 1e-10 * np.linalg.norm(x)


def test_several_rhs_one_factorization(rng):
    n = 20
    solver, A = check(rng, random_tree_joints(rng, n, 2), n, unsymmetric=True, n_rhs=4)
    for _ in range(3):   # Newton-like reuse: each solve matches a fresh dense solve
        rhs = rng.normal(size=A.shape[0])
        x = solver.solve(rhs)
        assert np.linalg.norm(x - np.linalg.solve(A, rhs)) < 1e-10 * np.linalg.norm(x)


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
    assert pivot > 1e-12
    rhs = rng.normal(size=a.size)
    out = np.empty_like(rhs)
    tree_solve(*st.arrays[:4], S, piv, P, Q, B, E, tmp, rhs, out)
    assert np.linalg.norm(out - np.linalg.solve(A, rhs)) < 1e-10 * np.linalg.norm(out)
    # The symmetric path (H = G promised): half of each symmetric product, mirrored.
    S, piv, P, Q, B, W, E, tmp = factor_arrays(st)
    tree_factor(*st.arrays, Ga, Gb, Ga, Gb, minv6, 0.0, S, piv, P, Q, B, W, True)
    assert np.array_equal(W, np.transpose(W, (0, 2, 1)))
    sym = np.empty_like(rhs)
    tree_solve(*st.arrays[:4], S, piv, P, Q, B, E, tmp, rhs, sym)
    assert np.linalg.norm(sym - out) < 1e-12 * np.linalg.norm(out)


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
    assert full.factor(Ga[:-copy.size], Gb[:-copy.size], minv6) > 1e-9
    assert solver.factor(Ga, Gb, minv6) < 1e-12
    reg = 1e-12 * np.abs(np.diag(A)).max()
    assert solver.factor(Ga, Gb, minv6, reg=reg) > 0.1e-12
    rhs = A @ rng.normal(size=a.size)   # consistent: the physical case
    x = solver.solve(rhs)
    # cond(A + reg I) is about 1e12: two backward-stable solves agree to about 1e12 · eps in
    # the null-space direction of A (how the load splits between the copies), exactly in A x.
    expected = np.linalg.solve(A + reg * np.eye(a.size), rhs)
    assert np.linalg.norm(x - expected) < 1e-3 * np.linalg.norm(expected)
    assert np.linalg.norm(A @ x - rhs) < 1e-9 * np.linalg.norm(rhs)
    assert np.linalg.norm(x - np.linalg.pinv(A) @ rhs) < 1e-3 * np.linalg.norm(x)
    # The copies share the load equally (the minimum-norm multipliers).
    assert np.allclose(x[copy], x[-copy.size:], rtol=1e-3, atol=1e-3 * np.abs(x).max())


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
        'from rigid_body_sim.core.tree_solve import TreeSolver\n'
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
        'assert p > 1e-12 and np.allclose(x, np.linalg.solve(A, rhs), rtol=1e-10, atol=0)\n'
        'import numba; assert numba.config.DISABLE_JIT\n'
    )
    env = dict(os.environ, NUMBA_DISABLE_JIT='1')
    root = Path(__file__).resolve().parents[1]
    result = subprocess.run([sys.executable, '-c', code], env=env, cwd=root,
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
