"""
What reading the reactions costs, next to the step it follows.

``Simulation.reactions()`` is the step's own compiled solve at the current state
(the multipliers a kick there uses); after a step it reuses that step's geometry
and, where the step left one, its factorization. For a pendulum, hinge chains
of 10 and 100 rods, a binary tree of 31 rods and a ring of 12 rods closed by a
ball joint (``lie_poisson2``, dt 1e-3, gravity), the median wall time of one
step and of one step followed by ``reactions()`` (interleaved, after a warm-up
that compiles), and their ratio. Run: ``./dev.sh python bench/reactions.py
[--quick]``; writes ``bench/out/reactions.md``.
"""

from __future__ import annotations

import argparse
from pathlib import Path
import statistics
import time

import numpy as np
from rigid_body_sim.core import Constraint, Gravity, RigidBody, Simulation
from rigid_body_sim.core.mechanisms import chain, ring, tree

OUT = Path(__file__).resolve().parent / 'out'


def pendulum(name: str) -> Simulation:
    """Build a bob on a ball joint, released at 60°."""
    bob = RigidBody('bob', 1.0, [1e-3, 1e-3, 1e-3],
                    position_world=[np.sin(np.radians(60.0)), 0.0, -np.cos(np.radians(60.0))])
    return Simulation([bob], [Gravity()], name, 1e-3,
                      [Constraint('pivot', 'ball', 'bob', None, anchor_world=[0, 0, 0])])


SCENES = {'pendulum': pendulum, 'chain 10': lambda name: chain(10, name),
          'chain 100': lambda name: chain(100, name), 'tree 31': lambda name: tree(31, name),
          'ring 12': lambda name: ring(12, name)}


def per_call(fn, reps: int) -> float:
    """Return the median wall time of ``fn()`` over ``reps`` batches of 20 calls (s)."""
    times = []
    for _ in range(reps):
        t0 = time.perf_counter()
        for _ in range(20):
            fn()
        times.append((time.perf_counter() - t0) / 20)
    return statistics.median(times)


def main(argv=None) -> None:
    """Print the table and write it to ``bench/out/reactions.md``."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    p.add_argument('--quick', action='store_true', help='fewer repetitions')
    args = p.parse_args(argv)
    reps = 5 if args.quick else 25
    lines = ['| scene | rows | step µs | step + reactions() µs | reading / step |',
             '|---|---|---|---|---|']
    for label, build in SCENES.items():
        sim = build('lie_poisson2')
        sim.step(3)
        sim.reactions()   # compiles and warms up

        def step():
            sim.step()

        def step_and_read():
            sim.step()
            sim.reactions()

        a, b = [], []
        for _ in range(3):   # interleaved
            a.append(per_call(step, reps))
            b.append(per_call(step_and_read, reps))
        t_step, t_both = min(a), min(b)
        rows = sim.dynamics.solver.constraints.n_rows
        lines.append(f'| {label} | {rows} | {1e6 * t_step:.1f} | {1e6 * t_both:.1f} | '
                     f'{(t_both - t_step) / t_step:.2f} |')
    table = '\n'.join(lines)
    print(table)
    OUT.mkdir(exist_ok=True)
    (OUT / 'reactions.md').write_text(table + '\n')


if __name__ == '__main__':
    main()
