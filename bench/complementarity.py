"""
The complementarity problem of the rows with bounds (issue 20): its solvers, and its pivots.

Two tables, side by side in one run:

* **The solvers** (``core/complementarity.py``) on random box LCPs of ``n`` rows
  (``S`` symmetric positive definite of condition 100, bounds of every kind: pushing
  only, two-sided, free, as a mechanism's rows have): the direct method (primal active
  set) from zero and warm-started from the solution of a neighbouring problem (``q``
  moved by 1 %: the next event's); beyond 32 rows, PGS then the direct method from
  zero (what ``solve`` does started cold), and PGS alone from the warm start; median
  µs a solve, iterations (PGS sweeps, plus the direct method's), the natural-map
  residual.
* **The pivots in the simulation**: the Panda of ``bench/robot_panda.py`` with its
  seven arm joints seated on their bounds (pressed there by 30 % of their effort
  limits, gravity on), then random efforts; the pivots at that state by the held
  rows' LCP (``JointEvents._release``: one problem, its Schur complement from one
  projection per row, the pivots together) against the sequential rule it replaced
  (pivot the row furthest past its bound, solve again, repeat); µs per event, rows
  released, and how often the sequential rule ends on another set than the LCP
  (then a released joint accelerates into its bound: an impact follows).

Run: ``./dev.sh python bench/complementarity.py [--quick]`` (``bench/requirements.txt``
for the Panda). Prints the tables and writes ``bench/out/complementarity.md``.
"""

from __future__ import annotations

import argparse
from pathlib import Path
import statistics
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import report  # noqa: E402, I100
import robot_panda as panda  # noqa: E402, I100

from rigid_body_sim.core.complementarity import (  # noqa: E402, I100
    DIRECT_LIMIT, solve, solve_direct, solve_pgs)
from rigid_body_sim.core.joint_events import JointEvents  # noqa: E402, I100

OUT = Path(__file__).resolve().parent / 'out'


def random_problem(rng, n: int) -> tuple:
    """Return ``(S, q, lo, hi)``: SPD ``S`` of condition 100, mixed boxes."""
    Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    S = (Q * np.geomspace(1.0, 100.0, n)) @ Q.T
    S = 0.5 * (S + S.T)
    kind = rng.integers(0, 3, n)
    width = rng.uniform(0.1, 2.0, n)
    lo = np.where(kind == 0, 0.0, np.where(kind == 1, -width, -np.inf))
    hi = np.where(kind == 0, np.inf, np.where(kind == 1, width, np.inf))
    return S, rng.standard_normal(n) * 3.0, lo, hi


def timed(fn, reps: int) -> tuple:
    """Return (median seconds, last result) of ``reps`` calls."""
    walls, out = [], None
    for _ in range(reps):
        t = time.perf_counter()
        out = fn()
        walls.append(time.perf_counter() - t)
    return statistics.median(walls), out


def solvers(sizes: list, reps: int) -> str:
    """Markdown table of the solvers on random problems."""
    rng = np.random.default_rng(1)
    rows = ['| rows | method | start | µs / solve (median) | iterations | residual |',
            '|---|---|---|---|---|---|']
    for n in sizes:
        S, q, lo, hi = random_problem(rng, n)
        last = solve_direct(S, 1.01 * q, lo, hi).f     # a neighbouring problem's answer
        cases = [('direct', 'zero', lambda: solve_direct(S, q, lo, hi)),
                 ('direct', 'warm', lambda: solve_direct(S, q, lo, hi, last))]
        if n > DIRECT_LIMIT:
            cases += [('PGS + direct', 'zero', lambda: solve(S, q, lo, hi)),
                      ('PGS alone, to 1e-9', 'warm',
                       lambda: solve_pgs(S, q, lo, hi, last, 1e-9, 100000))]
        for method, start, fn in cases:
            wall, sol = timed(fn, reps)
            assert sol.converged
            rows.append(f'| {n} | {method} | {start} | {wall * 1e6:.0f} | {sol.iterations} | '
                        f'{sol.residual:.1e} |')
    return '\n'.join(rows)


def seated_panda(tmp: Path, side: np.ndarray):
    """Return the Panda with its arm joints pressed onto the bounds ``side`` (+1 lower)."""
    from rigid_body_sim.scene import scene_from_dict
    path = tmp / 'panda.urdf'
    if not path.exists():
        path.write_text(panda.benchmark_urdf(panda.panda_urdf().read_text()))
    sim = scene_from_dict({'dt': panda.DT, 'effects': {'gravity': {'g_world': [0, 0, -9.81]}},
                           'robots': [{'urdf': str(path)}]},
                          str(tmp / 'scene.yaml')).simulation
    names = sim.joint_names()
    specs = {j.name: j.spec for j in sim.joints.joints}
    bound = [specs[n].lower if s > 0 else specs[n].upper for n, s in zip(names, side)]
    sim.set_joint_state(dict(zip(names, bound)))
    effort = np.array([specs[n].effort for n in names])
    sim.set_joint_efforts(dict(zip(names, -0.3 * side * effort)))
    sim.step(20)
    return sim, names, effort


def pivots(trials: int) -> str:
    """Markdown table: the LCP's pivots against the sequential rule's, on the Panda."""
    rng = np.random.default_rng(2)
    lcp_pivots = JointEvents._pivots
    walls = {'LCP': [], 'sequential': []}
    released = {'LCP': [], 'sequential': []}
    differ = 0
    held = []
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(trials):
            side = rng.choice([-1, 1], 7)
            tau = rng.uniform(-0.5, 0.5, 7)
            sets = {}
            for rule in ('LCP', 'sequential'):
                sim, names, effort = seated_panda(Path(tmp), side)
                seated = int(np.count_nonzero(sim.limits.active))
                sim.set_joint_efforts(dict(zip(names, tau * effort)))
                q = sim.joint_state().positions
                JointEvents._pivots = lcp_pivots if rule == 'LCP' else (lambda *a: [])
                try:
                    t = time.perf_counter()
                    sim.events._release(sim.state, q)
                    walls[rule].append(time.perf_counter() - t)
                finally:
                    JointEvents._pivots = lcp_pivots
                sets[rule] = tuple(np.flatnonzero(sim.limits.active))
                released[rule].append(seated - len(sets[rule]))
            held.append(seated)
            differ += sets['LCP'] != sets['sequential']
    rows = ['| rule | µs / event (median) | rows held before | rows released (mean) | '
            "a set unlike the LCP's |", '|---|---|---|---|---|']
    for rule in ('LCP', 'sequential'):
        rows.append(f'| {rule} | {statistics.median(walls[rule]) * 1e6:.0f} | '
                    f'{statistics.mean(held):.1f} | {statistics.mean(released[rule]):.2f} | '
                    f'{"-" if rule == "LCP" else f"{differ} of {trials}"} |')
    return '\n'.join(rows)


def main(argv=None) -> int:
    """Run the benchmark; print and write ``bench/out/complementarity.md``."""
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--quick', action='store_true', help='fewer sizes, trials, repetitions')
    args = p.parse_args(argv)
    t0 = time.perf_counter()
    sizes = [4, 16, 64] if args.quick else [4, 16, 64, 256]
    first = solvers(sizes, 5 if args.quick else 21)
    second = pivots(6 if args.quick else 20)
    text = '\n'.join(['The solvers on random problems:', '', first, '',
                      'Pivots on the Panda seated on its bounds, then random efforts:', '',
                      second])
    report.write_page(OUT, 'complementarity',
                      'The rows with bounds: their complementarity problem', args.quick, text,
                      t0)
    return 0


if __name__ == '__main__':
    sys.exit(main())
