"""
Issue 19, SHAKE: the null-space solve of the unsymmetric Newton matrix (no timing here).

:mod:`rigid_body_sim.core.kernels.nullspace_shake` solves SHAKE's ``G_E diag(I, J_r)
M⁻¹ G_Sᵀ λ = rhs`` as :func:`~rigid_body_sim.core.kernels.tree_solve.tree_factor`
(``symmetric=False``) / ``tree_solve`` do in the step (``_shake``), by eliminating
each joint's freedoms. Checked on random mechanisms (``nullspace_scenes``): the start
is a random state off the joints (``Φ ≠ 0``), the end the start moved by a random
drift (``ShakeSystem``: ``step`` 0.05, i.e. 5 mm and about 0.05 rad per body, 0.5
for the large steps), ``J_r`` either each body's right Jacobian of its rotation over
the drift (as ``_shake`` forms it for isotropic bodies; not symmetric) or ``I + 0.1
N(0, 1)`` (a general 3 x 3, as for anisotropic bodies). Against (a) a reference of the
unsymmetric system refined with double-double residuals (``ShakeSystem.reference``,
about 1e-30 cond(A), ``J_r`` not rounded into ``G_E``) and (b) today's tree solve on
the same matrix as the step forms it (``G_E diag(I, J_r)`` rounded, ``_apply_jacobians``).

Bounds, from what was measured (``bench/nullspace_premise.py``: 20 states x 10 rhs
per case, ``J_r`` of either kind on alternate states; and these tests): the new
solve's error is rounding, at most 1.6e-14 on random mechanisms at step 0.05 (cond(A)
up to 5e7; fixed chains of cond 3e8 stay at 2.2e-15, ball chains at 1.1e-14), as in
the symmetric prototype (5.5e-14); the bound is that worst seen times about 4 for
another CPU, as there, rounded up: 2e-13. (Nothing in the unsymmetric recursion
guarantees the symmetric one's small growth; it was not seen on these draws.) Two cases go further,
and each has its own bound below: the near-straight chain, where the relative pivot
``δ / scale`` of a joint (returned by ``shake_factor``) falls to 3e-5 once the end
and the start rows differ (``D = S_Sᵀ I^A S_E`` cancels as in the symmetric case, but
``S_E ≠ S_S`` removes its positive definiteness) and the error grows as eps / pivot
(error x pivot at most 3.3e-15 measured, 15 eps); and the large step (0.5 rad), at
most 1.6e-12 (cond(A) up to 4e9, where today's solve is off by up to 2e-10).
Today's solve is off by up to 7.2e-11 at step 0.05 (bench: fixed chains, cond 3e8),
so the difference of the two is asserted no larger than the two errors together.
"""

from nullspace_scenes import (chain_parents, Mechanism, mixed_kinds, ShakeSystem,
                              tree_parents, TYPES)
import numpy as np
import pytest
from rigid_body_sim.core.graph import tree_structure
from rigid_body_sim.core.kernels.nullspace_shake import shake_arrays, shake_factor, shake_solve
from rigid_body_sim.core.kernels.nullspace_solve import (nullspace_arrays, nullspace_factor,
                                                         nullspace_solve, nullspace_structure)
from rigid_body_sim.core.kernels.tree_solve import factor_arrays, tree_factor, tree_solve

N_RHS = 4
JACOBIANS = ('right', 'random')

# New solve against the reference (module docstring): worst seen 1.6e-14 at step 0.05, x4
# for another CPU's rounding and rounded up.
BOUND = 2e-13
# Large steps (0.5 rad): worst seen 1.6e-12 (hinge chain of 50), x4 and rounded up.
LARGE_STEP = 1e-11
# Near-straight chains: error x relative pivot, worst seen 3.3e-15, x4 and rounded up.
STRAIGHT = 2e-14


def factor_new(mech, shake):
    """Factor with shake_factor; return the structure, the arrays and the pivot ratio."""
    nst = nullspace_structure(mech.a, mech.b, mech.kind, mech.comp, mech.n)
    assert nst is not None
    arrays = shake_arrays(len(nst[0]), mech.n)
    pivot = shake_factor(*nst, shake.GaE, shake.GbE, shake.GaS, shake.GbS, shake.Jr,
                         mech.minv6, shake.RS, shake.RE, *arrays[:6])
    return nst, arrays, pivot


def solve_new(nst, arrays, rhs):
    """Return ``λ`` of shake_solve for each column of rhs."""
    IA, JS, JU, JD, JV, _, P, Acc, JG, JQ = arrays
    new = np.empty_like(rhs)
    out = np.empty(rhs.shape[0])
    for q in range(rhs.shape[1]):
        shake_solve(*nst[:4], IA, JS, JU, JD, JV, P, Acc, JG, JQ,
                    np.ascontiguousarray(rhs[:, q]), out)
        new[:, q] = out
    return new


def solve_old(mech, shake, rhs):
    """Return ``λ`` of tree_factor(symmetric=False) / tree_solve, as ``_shake`` calls them."""
    st = tree_structure(mech.a, mech.b, mech.n)
    S, piv, P, Q, B, W, E, tmp = factor_arrays(st)
    tree_factor(*st.arrays, shake.Ga2, shake.Gb2, shake.GaS, shake.GbS, mech.minv6, 0.0, S,
                piv, P, Q, B, W, False)
    old = np.empty_like(rhs)
    out = np.empty(rhs.shape[0])
    for q in range(rhs.shape[1]):
        tree_solve(*st.arrays[:4], S, piv, P, Q, B, E, tmp, np.ascontiguousarray(rhs[:, q]),
                   out)
        old[:, q] = out
    return old


def assert_accurate(mech, rng, bound, step=0.05, jacobian='right'):
    """
    Assert the new solve within ``bound`` of the reference, and its difference to today's.

    ``bound`` may be a function of the returned pivot ratio. Returns (new error, pivot).
    """
    shake = ShakeSystem(mech, rng, step, jacobian)
    nst, arrays, pivot = factor_new(mech, shake)
    rhs = rng.normal(size=(mech.m, N_RHS))
    new, old = solve_new(nst, arrays, rhs), solve_old(mech, shake, rhs)
    ref = shake.reference(rhs)[0]
    scale = np.abs(ref).max(axis=0)
    new_err = np.max(np.abs(new - ref).max(axis=0) / scale)
    old_err = np.max(np.abs(old - ref).max(axis=0) / scale)
    diff = np.max(np.abs(new - old).max(axis=0) / np.abs(old).max(axis=0))
    assert np.abs(mech.phi).max() > 1e-3   # the blocks are taken off the joints
    # The end rows are not the start's (the drift moves Φ by about step x LINK, 5e-3).
    assert np.abs(shake.phiE - mech.phi).max() > 1e-4
    limit = bound(pivot) if callable(bound) else bound
    assert new_err < limit, (new_err, pivot)
    # bound: |new − old| <= |new − ref| + |old − ref| (the scales differ by the errors: x2;
    # 1e-15: rounding of the difference itself)
    assert diff < 2.0 * (old_err + new_err) + 1e-15, (diff, old_err, new_err)
    return new_err, pivot


@pytest.mark.parametrize('jacobian', JACOBIANS)
@pytest.mark.parametrize('kind', TYPES)
def test_each_joint_type(rng, kind, jacobian):
    assert_accurate(Mechanism(rng, chain_parents(12), [kind] * 12), rng, BOUND,
                    jacobian=jacobian)


@pytest.mark.parametrize('jacobian', JACOBIANS)
@pytest.mark.parametrize('n', [10, 50])
def test_hinge_chain(n, jacobian):
    rng = np.random.default_rng(n)
    assert_accurate(Mechanism(rng, chain_parents(n), ['hinge'] * n), rng, BOUND,
                    jacobian=jacobian)


@pytest.mark.parametrize('seed', range(2))
@pytest.mark.parametrize('shape', ['chain 10', 'chain 50', 'tree 30'])
def test_mixed_joints(seed, shape):
    rng = np.random.default_rng(300 + seed)
    topology, n = shape.split()
    n = int(n)
    parents = chain_parents(n) if topology == 'chain' else tree_parents(rng, n)
    assert_accurate(Mechanism(rng, parents, mixed_kinds(rng, n)), rng, BOUND,
                    jacobian=JACOBIANS[seed])


def test_hinge_tree(rng):
    assert_accurate(Mechanism(rng, tree_parents(rng, 30), ['hinge'] * 30), rng, BOUND)


@pytest.mark.parametrize('seed', range(6))
def test_ball_chain_30(seed):
    """
    Ball chains of 30: the anchor elimination keeps them at rounding (worst seen 5.7e-15).

    The general recursion loses up to 1.9e-12 here with an explicit ``D⁻¹``, 2.0e-14
    with LU solves (``bench/nullspace_shake_ball.py``).
    """
    rng = np.random.default_rng(400 + seed)
    assert_accurate(Mechanism(rng, chain_parents(30), ['ball'] * 30), rng, BOUND,
                    jacobian=JACOBIANS[seed % 2])


def test_near_straight_chain(rng):
    """
    All hinge axes and links nearly parallel (1e-6 apart).

    ``D`` cancels (relative pivot down to 3e-5 measured, 1e-3 in the symmetric case) and
    the error grows as eps / pivot: bounded through the returned pivot.
    """
    mech = Mechanism(rng, chain_parents(50), ['hinge'] * 50, straight=1e-6)
    _, pivot = assert_accurate(mech, rng, lambda pivot: STRAIGHT / pivot)
    # bound: the smallest relative pivot measured, 2.7e-5, / 30: a collapse, not a wobble
    assert pivot > 1e-6


@pytest.mark.parametrize('kinds', ['hinge', 'mixed'])
def test_mass_ratio_1_to_1000(rng, kinds):
    """Masses alternating 1 and 1000 kg along a chain of 30."""
    k = ['hinge'] * 30 if kinds == 'hinge' else mixed_kinds(rng, 30)
    assert_accurate(Mechanism(rng, chain_parents(30), k, mass_ratio=1000.0), rng, BOUND,
                    jacobian='random')


def test_nearly_massless_tip(rng):
    """A distal link of 1e-6 kg on a hinge chain of 30: eliminated with no loss."""
    mech = Mechanism(rng, chain_parents(30), ['hinge'] * 30, massless_tip=True)
    _, pivot = assert_accurate(mech, rng, BOUND)
    # bound: the relative pivot measures the link against its own inertia (0.03 to 0.17
    # measured on such chains)
    assert pivot > 1e-3


@pytest.mark.parametrize('kinds', ['hinge', 'ball', 'mixed'])
def test_large_step(rng, kinds):
    """
    A drift of 0.5 rad (2.5 cm), twice the step's ``max_rotation`` (0.25 rad).

    ``K`` and ``D`` are far from symmetric; no pivoting was needed. Further out the
    unsymmetric recursion loses accuracy (measured, chains of 20, 3 seeds: 3.8e-12 on
    ball chains at 1 rad where today's solve has 6e-14, 3.5e-11 on hinge chains at 2
    rad against 8e-13; LU with pivoting in the general recursion does no better at 1
    rad, 1.1e-12), which a sub-step never reaches.
    """
    k = mixed_kinds(rng, 30) if kinds == 'mixed' else [kinds] * 30
    assert_accurate(Mechanism(rng, chain_parents(30), k), rng, LARGE_STEP, step=0.5,
                    jacobian='random')


@pytest.mark.parametrize('kind', TYPES + ('mixed',))
def test_symmetric_case_is_the_prototype(rng, kind):
    """With the end rows the start's and ``J_r = I`` it is ``nullspace_solve``'s system."""
    n = 20
    mech = Mechanism(rng, chain_parents(n), mixed_kinds(rng, n) if kind == 'mixed' else
                     [kind] * n)
    nst = nullspace_structure(mech.a, mech.b, mech.kind, mech.comp, mech.n)
    IA, JS, JU, JD, JV, work, P, Acc, JG, JQ = nullspace_arrays(len(nst[0]), n)
    nullspace_factor(*nst, mech.Ga, mech.Gb, mech.minv6, mech.R, IA, JS, JU, JD, JV, work)
    rhs = rng.normal(size=(mech.m, 1))
    sym = np.empty(mech.m)
    nullspace_solve(*nst[:4], IA, JS, JU, JD, JV, P, Acc, JG, JQ, rhs[:, 0], sym)
    arrays = shake_arrays(len(nst[0]), n)
    Jr = np.repeat(np.eye(3)[None], n, axis=0)
    shake_factor(*nst, mech.Ga, mech.Gb, mech.Ga, mech.Gb, Jr, mech.minv6, mech.R, mech.R,
                 *arrays[:6])
    new = solve_new(nst, arrays, rhs)[:, 0]
    # bound: the same recursion rounded differently (LDU for LDLᵀ, full for half products):
    # 1.2e-15 measured, x4 and rounded up
    assert np.abs(new - sym).max() < 5e-15 * np.abs(sym).max()


@pytest.mark.parametrize('kind', TYPES + ('mixed',))
def test_accelerations(rng, kind):
    """
    ``Acc`` holds ``a = K⁻¹ W_Sᵀ λ`` (world axes), which obeys the end rows: ``W_E a = rhs``.

    Both against the scale of their terms (``|G_E| |a|``, ``|D| |M⁻¹| |G_Sᵀ| |λ|``): on
    these chains of 30 the end rows' residual is at most 6e-16 of it and the force side
    1.3e-15 (relative to ``|a|`` itself, up to 8e-11 on fixed chains: their large internal
    λ cancel in ``G_Sᵀ λ``). bound: about x15 for other draws and CPUs.
    """
    n = 30
    mech = Mechanism(rng, chain_parents(n), mixed_kinds(rng, n) if kind == 'mixed' else
                     [kind] * n)
    shake = ShakeSystem(mech, rng, 0.05, 'random')
    nst, arrays, _ = factor_new(mech, shake)
    rhs = rng.normal(size=(mech.m, 1))
    lam = solve_new(nst, arrays, rhs)[:, 0]
    acc = arrays[7]
    # The end rows: G_E (a_v, R_Eᵀ a_ω) = rhs.
    a = np.hstack([acc[:, :3], np.einsum('bji,bj->bi', shake.RE[:n], acc[:, 3:])]).ravel()
    GE, D, GS = shake.dense()
    scale = (np.abs(GE) @ np.abs(a)).max()
    assert np.abs(GE @ a - rhs[:, 0]).max() < 1e-14 * scale
    # The force side: a = D M⁻¹ G_Sᵀ λ (angular part to world axes by R_E).
    minv = mech.minv6.ravel()
    b = (D @ (minv * (GS.T @ lam))).reshape(n, 6)
    b[:, 3:] = np.einsum('bij,bj->bi', shake.RE[:n], b[:, 3:])
    scale = (np.abs(D) @ (minv * (np.abs(GS.T) @ np.abs(lam)))).max()
    assert np.abs(acc - b).max() < 2e-14 * scale
