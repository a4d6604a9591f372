"""
Issue 19's premise: the null-space (articulated-inertia) tree solve against today's.

At random states of random mechanisms (:mod:`nullspace_scenes` in ``test/``: random
link directions, so random joint angles; random body orientations, masses 0.1..10 kg
and link-like principal inertias; joints made as the constraint set makes them, the
state then moved 1 cm / 0.01 rad off them, so ``Φ ≠ 0``; each joint's body a/b order
random), on chains of 10 and 50 bodies and 30-body random trees, the root joined to
the world, with all four built-in joints mixed and with hinges only (and, for
information, chains of 30 of each other type):

* **agreement**: ``‖λ_new − λ_old‖∞ / ‖λ_old‖∞`` of
  :func:`rigid_body_sim.core.kernels.nullspace_solve.nullspace_factor` /
  ``nullspace_solve`` against :func:`~rigid_body_sim.core.kernels.tree_solve.tree_factor`
  (``H = G``, symmetric, ``reg = 0``) / ``tree_solve``, largest over the states and
  right-hand sides; and each one's error against an extended-precision reference
  (iterative refinement with double-double residuals from the blocks,
  ``Mechanism.reference``), with the largest cond(A);
* the same for SHAKE's unsymmetric Newton matrix ``G_E diag(I, J_r) M⁻¹ G_Sᵀ`` (second
  table): :func:`rigid_body_sim.core.kernels.nullspace_shake.shake_factor` /
  ``shake_solve`` against ``tree_factor(symmetric=False)`` / ``tree_solve`` on the
  step's ``G_E diag(I, J_r)`` (``ShakeSystem`` in ``test/nullspace_scenes.py``: the end
  configuration the start moved by a random drift of about 0.05 rad and 5 mm per body,
  ``J_r`` the bodies' right Jacobians over it and, on every other state, ``I + 0.1 N(0,
  1)``), with the reference of the unsymmetric system;
* **time per call** of the factorization and of the solve, both measured inside a
  compiled loop (the step calls them from compiled code: Python's dispatch, a few µs
  per call with this many arguments, is in neither), old and new interleaved
  repetition by repetition in one run: median and range (min–max) over the
  repetitions, and the ratio of the medians (old / new).

The rotations ``R`` the new factorization takes are the step's (``frames`` runs for
the geometry already), so they are not timed; nor is ``_apply_jacobians``, which forms
the old SHAKE factorization's ``G_E diag(I, J_r)`` (the new one folds ``J_r`` into each
body's inertia inside the timed factorization). Writes ``bench/out/nullspace_premise.md``.
Run: ``python bench/nullspace_premise.py [--quick]``.
"""

from __future__ import annotations

import argparse
from pathlib import Path
import sys
import time

from numba import njit
import numpy as np

# This checkout's package (the prototype is not installed) and the test's mechanisms.
ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / 'test')]
from nullspace_scenes import (chain_parents, Mechanism, mixed_kinds,  # noqa: E402, I100
                              ShakeSystem, tree_parents)
from rigid_body_sim.core.graph import tree_structure  # noqa: E402, I100
from rigid_body_sim.core.kernels.nullspace_shake import (  # noqa: E402
    shake_arrays, shake_factor, shake_solve)
from rigid_body_sim.core.kernels.nullspace_solve import (  # noqa: E402
    nullspace_arrays, nullspace_factor, nullspace_solve, nullspace_structure)
from rigid_body_sim.core.kernels.tree_solve import (  # noqa: E402
    factor_arrays, tree_factor, tree_solve)

OUT = Path(__file__).resolve().parent / 'out'

# The loops are compiled afresh each run (not cache=True): numba's cache of a caller is
# keyed on the caller's file only, so a cached loop would keep running a kernel since edited.


@njit
def old_factor_loop(number, group_ptr, group_rows, group_child, group_parent, row_side, Ga, Gb,
                    minv6, S, piv, P, Q, B, W):
    """Call tree_factor (symmetric, reg 0) ``number`` times."""
    pivot = 0.0
    for _ in range(number):
        pivot = tree_factor(group_ptr, group_rows, group_child, group_parent, row_side, Ga, Gb,
                            Ga, Gb, minv6, 0.0, S, piv, P, Q, B, W, True)
    return pivot


@njit
def new_factor_loop(number, j_child, j_parent, j_type, j_rows, j_cside, Ga, Gb, minv6, R,
                    IA, JS, JU, JD, JV, work):
    """Call nullspace_factor ``number`` times."""
    pivot = 0.0
    for _ in range(number):
        pivot = nullspace_factor(j_child, j_parent, j_type, j_rows, j_cside, Ga, Gb, minv6, R,
                                 IA, JS, JU, JD, JV, work)
    return pivot


@njit
def old_shake_factor_loop(number, group_ptr, group_rows, group_child, group_parent, row_side,
                          Ga2, Gb2, GaS, GbS, minv6, S, piv, P, Q, B, W):
    """Call tree_factor (unsymmetric, reg 0) ``number`` times."""
    pivot = 0.0
    for _ in range(number):
        pivot = tree_factor(group_ptr, group_rows, group_child, group_parent, row_side, Ga2,
                            Gb2, GaS, GbS, minv6, 0.0, S, piv, P, Q, B, W, False)
    return pivot


@njit
def new_shake_factor_loop(number, j_child, j_parent, j_type, j_rows, j_cside, GaE, GbE, GaS,
                          GbS, Jr, minv6, RS, RE, IA, JS, JU, JD, JV, work):
    """Call shake_factor ``number`` times."""
    pivot = 0.0
    for _ in range(number):
        pivot = shake_factor(j_child, j_parent, j_type, j_rows, j_cside, GaE, GbE, GaS, GbS,
                             Jr, minv6, RS, RE, IA, JS, JU, JD, JV, work)
    return pivot


@njit
def new_shake_solve_loop(number, j_child, j_parent, j_type, j_rows, IA, JS, JU, JD, JV, P,
                         Acc, JG, JQ, rhs, out):
    """Call shake_solve ``number`` times."""
    for _ in range(number):
        shake_solve(j_child, j_parent, j_type, j_rows, IA, JS, JU, JD, JV, P, Acc, JG, JQ, rhs,
                    out)


@njit
def old_solve_loop(number, group_ptr, group_rows, group_child, group_parent, S, piv, P, Q, B,
                   E, tmp, rhs, out):
    """Call tree_solve ``number`` times."""
    for _ in range(number):
        tree_solve(group_ptr, group_rows, group_child, group_parent, S, piv, P, Q, B, E, tmp,
                   rhs, out)


@njit
def new_solve_loop(number, j_child, j_parent, j_type, j_rows, IA, JS, JU, JD, JV, P, Acc, JG,
                   JQ, rhs, out):
    """Call nullspace_solve ``number`` times."""
    for _ in range(number):
        nullspace_solve(j_child, j_parent, j_type, j_rows, IA, JS, JU, JD, JV, P, Acc, JG, JQ,
                        rhs, out)


class Pair:
    """Both solvers set up on one mechanism: factor, solve, and the timed loops."""

    def __init__(self, mech: Mechanism, shake: ShakeSystem):
        self.mech = mech
        self.shake = shake
        st = tree_structure(mech.a, mech.b, mech.n)
        self.st = st
        self.old = factor_arrays(st)
        self.nst = nullspace_structure(mech.a, mech.b, mech.kind, mech.comp, mech.n)
        if self.nst is None:
            raise ValueError('not a mechanism the prototype recognizes')
        self.new = nullspace_arrays(len(self.nst[0]), mech.n)
        self.old_u = factor_arrays(st)
        self.new_u = shake_arrays(len(self.nst[0]), mech.n)
        self.rhs = np.zeros(mech.m)
        self.out = np.zeros(mech.m)

    def old_factor(self, number=1):
        """Factor with tree_factor."""
        m = self.mech
        S, piv, P, Q, B, W, _, _ = self.old
        return old_factor_loop(number, *self.st.arrays, m.Ga, m.Gb, m.minv6, S, piv, P, Q, B, W)

    def new_factor(self, number=1):
        """Factor with nullspace_factor."""
        m = self.mech
        IA, JS, JU, JD, JV, work = self.new[:6]
        return new_factor_loop(number, *self.nst, m.Ga, m.Gb, m.minv6, m.R, IA, JS, JU, JD, JV,
                               work)

    def old_solve(self, number=1):
        """Solve for self.rhs into self.out with tree_solve."""
        S, piv, P, Q, B, _, E, tmp = self.old
        old_solve_loop(number, *self.st.arrays[:4], S, piv, P, Q, B, E, tmp, self.rhs, self.out)
        return self.out.copy()

    def new_solve(self, number=1):
        """Solve for self.rhs into self.out with nullspace_solve."""
        IA, JS, JU, JD, JV, _, P, Acc, JG, JQ = self.new
        new_solve_loop(number, *self.nst[:4], IA, JS, JU, JD, JV, P, Acc, JG, JQ, self.rhs,
                       self.out)
        return self.out.copy()

    def old_shake_factor(self, number=1):
        """Factor SHAKE's matrix with tree_factor(symmetric=False)."""
        m, sh = self.mech, self.shake
        S, piv, P, Q, B, W, _, _ = self.old_u
        return old_shake_factor_loop(number, *self.st.arrays, sh.Ga2, sh.Gb2, sh.GaS, sh.GbS,
                                     m.minv6, S, piv, P, Q, B, W)

    def new_shake_factor(self, number=1):
        """Factor SHAKE's matrix with shake_factor."""
        m, sh = self.mech, self.shake
        return new_shake_factor_loop(number, *self.nst, sh.GaE, sh.GbE, sh.GaS, sh.GbS, sh.Jr,
                                     m.minv6, sh.RS, sh.RE, *self.new_u[:6])

    def old_shake_solve(self, number=1):
        """Solve SHAKE's system for self.rhs into self.out with tree_solve."""
        S, piv, P, Q, B, _, E, tmp = self.old_u
        old_solve_loop(number, *self.st.arrays[:4], S, piv, P, Q, B, E, tmp, self.rhs, self.out)
        return self.out.copy()

    def new_shake_solve(self, number=1):
        """Solve SHAKE's system for self.rhs into self.out with shake_solve."""
        IA, JS, JU, JD, JV, _, P, Acc, JG, JQ = self.new_u
        new_shake_solve_loop(number, *self.nst[:4], IA, JS, JU, JD, JV, P, Acc, JG, JQ,
                             self.rhs, self.out)
        return self.out.copy()


def make_pair(rng, parents, kinds, k):
    """Both solvers on a new draw of a case (state k: ``J_r`` right Jacobians, or random)."""
    mech = Mechanism(rng, parents(), kinds())
    return Pair(mech, ShakeSystem(mech, rng, 0.05, 'right' if k % 2 == 0 else 'random'))


def cases(rng):
    """(label, parents, kinds) of the mechanisms (a new draw of each per state)."""
    return [
        ('hinge chain 10', lambda: chain_parents(10), lambda: ['hinge'] * 10),
        ('hinge chain 50', lambda: chain_parents(50), lambda: ['hinge'] * 50),
        ('hinge tree 30', lambda: tree_parents(rng, 30), lambda: ['hinge'] * 30),
        ('mixed chain 10', lambda: chain_parents(10), lambda: mixed_kinds(rng, 10)),
        ('mixed chain 50', lambda: chain_parents(50), lambda: mixed_kinds(rng, 50)),
        ('mixed tree 30', lambda: tree_parents(rng, 30), lambda: mixed_kinds(rng, 30)),
        ('ball chain 30', lambda: chain_parents(30), lambda: ['ball'] * 30),
        ('slider chain 30', lambda: chain_parents(30), lambda: ['slider'] * 30),
        ('fixed chain 30', lambda: chain_parents(30), lambda: ['fixed'] * 30),
    ]


def agreement(rng, parents, kinds, states, n_rhs):
    """
    Largest relative differences and cond(A), symmetric then SHAKE's.

    Returns ``(worst, cond)`` with ``worst`` (2, 4): per system new vs old, old vs ref,
    new vs ref and the smallest pivot ratio of the new factorization; ``cond`` (2,).
    """
    worst = np.zeros((2, 4))
    worst[:, 3] = np.inf
    cond = np.zeros(2)
    for k in range(states):
        pair = make_pair(rng, parents, kinds, k)
        pair.old_factor()
        pair.old_shake_factor()
        pivots = pair.new_factor(), pair.new_shake_factor()
        rhs = rng.normal(size=(pair.mech.m, n_rhs))
        refs = pair.mech.reference(rhs), pair.shake.reference(rhs)
        solvers = ((pair.old_solve, pair.new_solve),
                   (pair.old_shake_solve, pair.new_shake_solve))
        for s, ((ref, c), (old_solve, new_solve)) in enumerate(zip(refs, solvers)):
            cond[s] = max(cond[s], c)
            worst[s, 3] = min(worst[s, 3], pivots[s])
            for q in range(n_rhs):
                pair.rhs[:] = rhs[:, q]
                old, new = old_solve(), new_solve()
                exact = ref[:, q].astype(float)
                scale_old, scale_ref = np.abs(old).max(), np.abs(exact).max()
                worst[s, :3] = np.maximum(worst[s, :3], [np.abs(new - old).max() / scale_old,
                                                         np.abs(old - exact).max() / scale_ref,
                                                         np.abs(new - exact).max() / scale_ref])
    return worst, cond


def calls_for(fn, min_time):
    """Return the calls per timed repetition: enough for ``min_time`` seconds."""
    number = 1
    while True:
        t0 = time.perf_counter()
        fn(number)
        if time.perf_counter() - t0 >= min_time or number >= 1 << 20:
            return number
        number *= 2


def timing(pair, repeats, min_time):
    """
    Per-call µs of old/new factor and solve, symmetric then SHAKE's, interleaved.

    Returns (8, repeats): old/new factor, old/new solve, the same for SHAKE's matrix.
    """
    pair.rhs[:] = np.random.default_rng(0).normal(size=pair.mech.m)
    fns = [pair.old_factor, pair.new_factor, pair.old_solve, pair.new_solve,
           pair.old_shake_factor, pair.new_shake_factor, pair.old_shake_solve,
           pair.new_shake_solve]
    for fn in fns:
        fn()   # compile and warm up
    numbers = [calls_for(fn, min_time) for fn in fns]
    times = np.zeros((len(fns), repeats))
    for k in range(repeats):
        for i, (fn, number) in enumerate(zip(fns, numbers)):
            t0 = time.perf_counter()
            fn(number)
            times[i, k] = 1e6 * (time.perf_counter() - t0) / number
    return times


def fmt(t):
    """Median [min–max] of per-call µs."""
    return f'{np.median(t):.2f} [{t.min():.2f}–{t.max():.2f}]'


def run(states, n_rhs, repeats, min_time, seed=19):
    """Rows of the table, one per case."""
    rng = np.random.default_rng(seed)
    rows = []
    for label, parents, kinds in cases(rng):
        worst, cond = agreement(rng, parents, kinds, states, n_rhs)
        pair = make_pair(rng, parents, kinds, 0)
        times = timing(pair, repeats, min_time)
        med = np.median(times, axis=1)
        rows.append((label, pair.mech.n, pair.mech.m, worst, cond, times, med[0::2] / med[1::2]))
        print(f'  {label:16s} agreement {worst[0, 0]:.1e} / {worst[1, 0]:.1e}  factor '
              f'x{med[0] / med[1]:.2f} / x{med[4] / med[5]:.2f}  solve x{med[2] / med[3]:.2f} / '
              f'x{med[6] / med[7]:.2f}', flush=True)
    return rows


def table(rows, s):
    """Markdown table of the rows, of the symmetric system (``s = 0``) or SHAKE's (1)."""
    lines = ['| case | N | rows | max rel. diff new vs old | old vs ref | new vs ref '
             '| min pivot ratio | max cond(A) | factor old µs | factor new µs | factor old/new '
             '| solve old µs | solve new µs | solve old/new |',
             '|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|']
    for label, n, m, worst, cond, times, ratios in rows:
        w, t, r = worst[s], times[4 * s:4 * s + 4], ratios[2 * s:2 * s + 2]
        lines.append(f'| {label} | {n} | {m} | {w[0]:.1e} | {w[1]:.1e} | {w[2]:.1e} | '
                     f'{w[3]:.1e} | {cond[s]:.1e} | {fmt(t[0])} | {fmt(t[1])} | '
                     f'**{r[0]:.2f}** | {fmt(t[2])} | {fmt(t[3])} | {r[1]:.2f} |')
    return '\n'.join(lines)


def main(argv=None):
    """Run the benchmark, print the table and write bench/out/nullspace_premise.md."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('--quick', action='store_true', help='fewer states and repetitions')
    args = parser.parse_args(argv)
    states, n_rhs, repeats, min_time = (3, 4, 5, 0.01) if args.quick else (20, 10, 11, 0.02)
    rows = run(states, n_rhs, repeats, min_time)
    text = (f'# Issue 19 premise: null-space (articulated-inertia) tree solve vs tree_solve\n\n'
            f'Agreement: largest ‖λ_new − λ_old‖∞ / ‖λ_old‖∞ over {states} random states x '
            f'{n_rhs} random rhs per case; "ref": an extended-precision reference '
            f'(double-double residuals). Times: µs per call inside a compiled loop, median '
            f'[min–max] of {repeats} interleaved repetitions (all eight timings of a case '
            f'interleaved); ratios of the medians.\n\n'
            + table(rows, 0) + '\n\n'
            "## SHAKE's unsymmetric matrix: shake_factor / shake_solve vs "
            'tree_factor(symmetric=False) / tree_solve\n\n'
            'The end configuration is the start moved by a random drift (about 0.05 rad and '
            '5 mm per body); J_r the right Jacobians over it, or I + 0.1 N(0, 1) on every '
            'other state. Old: G_E diag(I, J_r) formed beforehand (not timed).\n\n'
            + table(rows, 1) + '\n')
    print(text)
    OUT.mkdir(exist_ok=True)
    (OUT / 'nullspace_premise.md').write_text(text)


if __name__ == '__main__':
    main()
