"""
Issue 19, the inertia form's wider scope: free-floating trees (no timing here).

A tree without a joint to the world (a floating-base robot) is solved in inertia form
by both kernels: its root's articulated inertia ``I^A_root`` gives ``a_root =
−(I^A_root)⁻¹ p_root`` (a 6 x 6 Cholesky in :mod:`.nullspace_solve`, an LU with
partial pivoting in :mod:`.nullspace_shake`), from which the down pass starts.
Checked as the tests of the world-hung trees are (``test_nullspace_premise``,
``test_nullspace_shake``, whose helpers and bounds are used here): at random states
off the joints (``Φ ≠ 0``) against the double-double reference and against today's
``tree_solve``, for free chains and trees of every joint type, forests of free and
world-hung trees, near-straight chains and 1:1000 mass ratios.

Bounds: those of the world-hung trees (2e-13 for both kernels; the near-straight
SHAKE chain through its pivot). Measured here: at most 1.8e-14 off the reference (the
SHAKE kernel, mixed free chain of 10), the free root's factorization adds nothing
visible (its 6 x 6 is well conditioned relative to its diagonal: the returned pivot
ratios stay above 0.05 on these draws).
"""

from nullspace_scenes import chain_parents, Mechanism, mixed_kinds, tree_parents, TYPES
import numpy as np
import pytest
from rigid_body_sim.core.kernels.nullspace_solve import FREE, nullspace_structure
import test_nullspace_premise as sym
import test_nullspace_shake as shake

KINDS = TYPES + ('mixed',)


def kinds_of(rng, kind, n):
    """Joint types of n bodies: all ``kind``, or drawn from all four (``'mixed'``)."""
    return mixed_kinds(rng, n) if kind == 'mixed' else [kind] * n


def forest(rng, sizes, free):
    """Parents of a forest of random trees of these sizes; return them and the free roots."""
    parents, roots = [], []
    for size in sizes:
        base = len(parents)
        roots.append(base)
        parents += [-1] + [base + int(rng.integers(i)) for i in range(1, size)]
    return parents, tuple(r for r, f in zip(roots, free) if f)


def check_both(mech, rng, straight=False):
    """Assert both kernels accurate on the mechanism (symmetric, then SHAKE)."""
    sym.assert_accurate(mech, rng, sym.OTHERS)
    bound = (lambda pivot: shake.STRAIGHT / pivot) if straight else shake.BOUND
    shake.assert_accurate(mech, rng, bound, jacobian='random')


@pytest.mark.parametrize('kind', KINDS)
def test_free_chain(rng, kind):
    """A free-floating chain of 12, every joint type: the root has no joint."""
    mech = Mechanism(rng, chain_parents(12), kinds_of(rng, kind, 12), free=(0,))
    nst = nullspace_structure(mech.a, mech.b, mech.kind, mech.comp, mech.n)
    assert nst is not None and list(nst[2]).count(FREE) == 1 and nst[0][-1] == 0
    check_both(mech, rng)


@pytest.mark.parametrize('seed', range(3))
def test_free_tree(seed):
    """A free-floating random tree of 30 with mixed joints."""
    rng = np.random.default_rng(500 + seed)
    mech = Mechanism(rng, tree_parents(rng, 30), mixed_kinds(rng, 30), free=(0,))
    check_both(mech, rng)


@pytest.mark.parametrize('seed', range(3))
def test_forest_of_free_and_hung_trees(seed):
    """One component of trees, some hung from the world, some free (as a step groups them)."""
    rng = np.random.default_rng(600 + seed)
    parents, free = forest(rng, (8, 10, 6), (False, True, seed % 2 == 0))
    mech = Mechanism(rng, parents, mixed_kinds(rng, len(parents)), free=free)
    nst = nullspace_structure(mech.a, mech.b, mech.kind, mech.comp, mech.n)
    assert list(nst[2]).count(FREE) == len(free)
    check_both(mech, rng)


def test_two_bodies_hinged_in_space(rng):
    """The smallest free tree: two bodies and a hinge."""
    check_both(Mechanism(rng, [-1, 0], ['hinge', 'hinge'], free=(0,)), rng)


def test_near_straight_free_chain(rng):
    """A free hinge chain of 50 with all axes and links nearly parallel (1e-6 apart)."""
    mech = Mechanism(rng, chain_parents(50), ['hinge'] * 50, straight=1e-6, free=(0,))
    check_both(mech, rng, straight=True)


@pytest.mark.parametrize('kind', ['hinge', 'mixed'])
def test_free_mass_ratio_1_to_1000(rng, kind):
    """Masses alternating 1 and 1000 kg along a free chain of 30."""
    mech = Mechanism(rng, chain_parents(30), kinds_of(rng, kind, 30), mass_ratio=1000.0,
                     free=(0,))
    check_both(mech, rng)


def test_free_tree_with_a_loop_falls_back():
    """A closed loop in a free tree is still refused (None)."""
    rng = np.random.default_rng(7)
    mech = Mechanism(rng, chain_parents(4), ['ball'] * 4, free=(0,))
    a, b, kind, comp, n = mech.a, mech.b, mech.kind, mech.comp, mech.n
    assert nullspace_structure(a, b, kind, comp, n) is not None
    # A ball between bodies 0 and 3 closes the chain.
    assert nullspace_structure(np.r_[a, 0, 0, 0], np.r_[b, 3, 3, 3], np.r_[kind, 0, 0, 0],
                               np.r_[comp, 0, 1, 2], n) is None
