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
* **time per call** of the factorization and of the solve, both measured inside a
  compiled loop (the step calls them from compiled code: Python's dispatch, a few µs
  per call with this many arguments, is in neither), old and new interleaved
  repetition by repetition in one run: median and range (min–max) over the
  repetitions, and the ratio of the medians (old / new).

The rotations ``R`` the new factorization takes are the step's (``frames`` runs for
the geometry already), so they are not timed. Writes ``bench/out/nullspace_premise.md``.
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
                              tree_parents)
from rigid_body_sim.core.graph import tree_structure  # noqa: E402, I100
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

    def __init__(self, mech: Mechanism):
        self.mech = mech
        st = tree_structure(mech.a, mech.b, mech.n)
        self.st = st
        self.old = factor_arrays(st)
        self.nst = nullspace_structure(mech.a, mech.b, mech.kind, mech.comp, mech.n)
        if self.nst is None:
            raise ValueError('not a mechanism the prototype recognizes')
        self.new = nullspace_arrays(len(self.nst[0]), mech.n)
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
    """Largest relative differences (new vs old, old vs ref, new vs ref) and largest cond(A)."""
    worst = np.zeros(3)
    cond = 0.0
    for _ in range(states):
        pair = Pair(Mechanism(rng, parents(), kinds()))
        pair.old_factor()
        pair.new_factor()
        rhs = rng.normal(size=(pair.mech.m, n_rhs))
        ref, c = pair.mech.reference(rhs)
        cond = max(cond, c)
        for q in range(n_rhs):
            pair.rhs[:] = rhs[:, q]
            old, new = pair.old_solve(), pair.new_solve()
            exact = ref[:, q].astype(float)
            scale_old, scale_ref = np.abs(old).max(), np.abs(exact).max()
            worst = np.maximum(worst, [np.abs(new - old).max() / scale_old,
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
    """Per-call µs (median, min, max) of old/new factor and solve, interleaved per repetition."""
    pair.rhs[:] = np.random.default_rng(0).normal(size=pair.mech.m)
    fns = [pair.old_factor, pair.new_factor, pair.old_solve, pair.new_solve]
    for fn in fns:
        fn()   # compile and warm up
    numbers = [calls_for(fn, min_time) for fn in fns]
    times = np.zeros((4, repeats))
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
        pair = Pair(Mechanism(rng, parents(), kinds()))
        times = timing(pair, repeats, min_time)
        med = np.median(times, axis=1)
        rows.append((label, pair.mech.n, pair.mech.m, worst, cond, times, med[0] / med[1],
                     med[2] / med[3]))
        print(f'  {label:16s} agreement {worst[0]:.1e}  factor x{med[0] / med[1]:.2f}  '
              f'solve x{med[2] / med[3]:.2f}', flush=True)
    return rows


def table(rows):
    """Markdown table of the rows."""
    lines = ['| case | N | rows | max rel. diff new vs old | old vs ref | new vs ref '
             '| max cond(A) | factor old µs | factor new µs | factor old/new '
             '| solve old µs | solve new µs | solve old/new |',
             '|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|']
    for label, n, m, worst, cond, times, rf, rs in rows:
        lines.append(f'| {label} | {n} | {m} | {worst[0]:.1e} | {worst[1]:.1e} | '
                     f'{worst[2]:.1e} | {cond:.1e} | {fmt(times[0])} | {fmt(times[1])} | '
                     f'**{rf:.2f}** | {fmt(times[2])} | {fmt(times[3])} | {rs:.2f} |')
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
            f'[min–max] of {repeats} interleaved repetitions; ratios of the medians.\n\n'
            + table(rows) + '\n')
    print(text)
    OUT.mkdir(exist_ok=True)
    (OUT / 'nullspace_premise.md').write_text(text)


if __name__ == '__main__':
    main()
