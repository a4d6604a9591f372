"""Closed-loop solve (spanning forest + Schur complement of the loop-closing rows) vs numpy."""

import numpy as np
import pytest
from rigid_body_sim.core.graph import loop_structure
from rigid_body_sim.core.kernels.loop_solve import loop_back, loop_forward, loop_schur
from rigid_body_sim.core.kernels.tree_solve import factor_arrays, tree_factor
from test_tree_solve import assert_solves, draw, EPS, rows_of


def loop_solve(a, b, n, Ga, Gb, Ha, Hb, minv6, rhs, reg=0.0):
    """Factor and solve through the loop kernels; S's system by numpy (as the caller would)."""
    st = loop_structure(a, b, n)
    assert st is not None
    t = st.tree
    S, piv, P, Q, B, W, E, tmp = factor_arrays(t)
    tree_factor(*t.arrays, Ga, Gb, Ha, Hb, minv6, reg, S, piv, P, Q, B, W,
                Ha is Ga and Hb is Gb)
    c, m = st.closure.size, a.size
    X, Y, F = np.zeros((c, m)), np.zeros((c, m)), np.zeros((c, c))
    own = np.arange(m, dtype=np.int64)   # one part a row: no coupled rows
    loop_schur(*t.arrays[:4], S, piv, P, Q, B, E, tmp, st.closure, a, b, own, Ga, Gb, Ha, Hb,
               minv6, reg, X, Y, F, np.zeros(m), np.zeros((2, n, 6)))
    out, z = np.zeros(m), np.zeros(c)
    loop_forward(*t.arrays[:4], S, piv, P, Q, B, E, tmp, st.closure, Y, rhs, out, z)
    loop_back(t.group_rows, st.closure, X, np.linalg.solve(F, z), out)
    return st, F, out


def ring(n, k, to_world=True):
    """Joints of a ring of n bodies with k rows each, body 0 also held by the world."""
    joints = [(i, i - 1, k) for i in range(1, n)] + [(0, n - 1, k)]
    return ([(0, -1, 3)] if to_world else []) + joints


def ladder(n, k):
    """Two chains of n bodies joined by a rung at every body: n - 1 loops."""
    joints = [(0, -1, 3)]
    joints += [(i, i - 1, k) for i in range(1, n)]
    joints += [(n + i, n + i - 1, k) for i in range(1, n)]
    joints += [(i, n + i, k) for i in range(n)]
    return joints


@pytest.mark.parametrize('unsymmetric', [False, True])
@pytest.mark.parametrize('joints, n', [(ring(6, 3), 6), (ring(9, 5), 9), (ladder(5, 3), 10),
                                       (ring(4, 2, to_world=False), 4)])
def test_loop_solve_equals_dense_solve(rng, joints, n, unsymmetric):
    a, b = rows_of(joints, n, rng)
    Ga, Gb, Ha, Hb, minv6, A = draw(rng, a, b, n, unsymmetric)
    rhs = rng.normal(size=a.size)
    st, F, x = loop_solve(a, b, n, Ga, Gb, Ha, Hb, minv6, rhs)
    # bound: forward error 10 cond(A) eps of the draw (cond < 1e8), residual 2 m eps |A||x|
    assert_solves(A, rhs, x)
    # S is the Schur complement of the forest's rows, assembled densely here.
    C = st.closure
    T = np.setdiff1d(np.arange(a.size), C)
    X = np.linalg.solve(A[np.ix_(T, T)], A[np.ix_(T, C)])
    schur = A[np.ix_(C, C)] - A[np.ix_(C, T)] @ X
    # bound: X's forward error cond(A_TT) eps |X| (twice), times |A_CT|, + the product's m eps
    bound = 2 * (np.linalg.cond(A[np.ix_(T, T)]) + a.size) * EPS * (
        np.linalg.norm(A[np.ix_(C, T)], 2) * np.linalg.norm(X, 2))
    assert np.abs(F - schur).max() < 5 * bound   # x5 (measured at most 0.004 bound)


def test_closure_rows_are_those_of_the_loop_closing_joints(rng):
    n = 9
    a, b = rows_of(ring(n, 5), n, rng)
    st = loop_structure(a, b, n)
    # One loop: one joint of 5 rows closes it (the last one met: 0 - (n - 1)).
    assert st.closure.size == 5
    assert set(zip(a[st.closure].tolist(), b[st.closure].tolist())) <= {(0, n - 1), (n - 1, 0)}
    # Every other row is in exactly one group of the forest.
    assert sorted(st.tree.group_rows.tolist() + st.closure.tolist()) == list(range(a.size))
    a, b = rows_of(ladder(6, 3), 12, rng)
    assert loop_structure(a, b, 12).closure.size == 3 * 5


def test_loops_through_the_world_and_trees_need_no_closure(rng):
    # A four-bar grounded at both ends closes its loop through the world, which does not
    # move: its system is tree-structured. A chain has no loop either.
    a, b = rows_of([(0, -1, 5), (1, 0, 5), (2, 1, 5), (2, -1, 5)], 3, rng)
    assert loop_structure(a, b, 3) is None
    a, b = rows_of([(0, -1, 3)] + [(i, i - 1, 3) for i in range(1, 8)], 8, rng)
    assert loop_structure(a, b, 8) is None


def test_a_loop_through_the_world_can_be_closed_like_one_among_bodies(rng):
    # With through_world, the four-bar's last joint to the world closes its loop (its
    # redundant rows then meet the closure block's truncated SVD); the chain still has
    # no loop, nor has a body held twice by the world (one pair of bodies).
    a, b = rows_of([(0, -1, 5), (1, 0, 5), (2, 1, 5), (2, -1, 5)], 3, rng)
    st = loop_structure(a, b, 3, through_world=True)
    assert set(zip(a[st.closure].tolist(), b[st.closure].tolist())) == {(2, 3)}
    assert st.closure.size == 5
    assert sorted(st.tree.group_rows.tolist() + st.closure.tolist()) == list(range(a.size))
    a, b = rows_of([(0, -1, 3)] + [(i, i - 1, 3) for i in range(1, 8)], 8, rng)
    assert loop_structure(a, b, 8, through_world=True) is None
    a, b = rows_of([(0, -1, 3), (0, -1, 3)], 1, rng)
    assert loop_structure(a, b, 1, through_world=True) is None


def test_tikhonov_term_is_carried_into_the_closure_block(rng):
    n = 6
    a, b = rows_of(ring(n, 3), n, rng)
    Ga, Gb, Ha, Hb, minv6, A = draw(rng, a, b, n, False)
    reg = 0.3
    rhs = rng.normal(size=a.size)
    _, _, x = loop_solve(a, b, n, Ga, Gb, Ha, Hb, minv6, rhs, reg)
    # bound: 10 cond(A + reg I) eps (1e-9; reg dropped: >= reg / |A|), 2 m eps backward
    assert_solves(A + reg * np.eye(a.size), rhs, x)
