"""
The accuracy knob's estimators for ``rkmk4`` side by side.

The default, the embedded pair alone and step doubling alone.
Each scene runs under ``sim.set_tolerance(tol, estimator=...)`` at the fixed dt
1e-2 for every tolerance, and is compared with a DOP853 reference at rtol 1e-13
(``accuracy.state_distance``: the largest error in position, orientation,
velocity or angular velocity, SI units). Printed per run: the error over
``tol * T`` (what the knob promises is about 1 or less, times the error growth
of the motion), the sub-steps of the last step, right-hand sides per step (the
work), wall time per simulated second (median of ``--reps``, the three
estimators interleaved) and misses. Scenes: a free body (moments 1, 2, 3)
turning at 2, 20 and 100 rad/s, the pendulum of ``test/test_accuracy_knob.py``
(a bob on a ball joint, 0.5 m) and the four-bar linkage (``mechanisms.four_bar``).

Run: ``python bench/knob_estimators.py [--quick]`` in the environment of
``./dev.sh`` (about 1 minute; ``--quick``: 1e-3 and 1e-7 only, one repetition).
Writes ``bench/out/knob_estimators.md`` and ``bench/out/knob_estimators.png``
(right-hand sides per step against the error reached).
"""

from __future__ import annotations

import argparse
from pathlib import Path
import statistics
import time

from rigid_body_sim.core import Constraint, Gravity, RigidBody, Simulation
from rigid_body_sim.core.accuracy import state_distance
from rigid_body_sim.core.mechanisms import four_bar
from rigid_body_sim.core.reference import dop853_trajectory

OUT = Path(__file__).resolve().parent / 'out'
DT = 1e-2
ESTIMATORS = (None, 'embedded', 'doubling')


def free_body(rate: float):
    def build(integrator: str) -> Simulation:
        body = RigidBody('b', 1.0, (1.0, 2.0, 3.0),
                         angular_velocity_body=(rate, 0.01 * rate, 0.01 * rate))
        return Simulation([body], [], integrator, DT)
    return build


def pendulum(integrator: str) -> Simulation:
    bob = RigidBody('bob', 1.0, (1e-3, 2e-3, 3e-3), position_world=(0.5, 0.0, 0.0))
    return Simulation([bob], [Gravity()], integrator, DT,
                      [Constraint('pivot', 'ball', 'bob', None, anchor_world=(0.0, 0.0, 0.0))])


SCENES = (('free body 2 rad/s', free_body(2.0), 2.0),
          ('free body 20 rad/s', free_body(20.0), 1.0),
          ('free body 100 rad/s', free_body(100.0), 0.2),
          ('pendulum', pendulum, 1.0),
          ('four-bar', lambda name: four_bar(name, DT), 1.0))


def run(build, tolerance: float, estimator, duration: float) -> tuple:
    """One run: (final state, wall s, the accuracy report, right-hand sides)."""
    sim = build('rkmk4')
    sim.set_tolerance(tolerance, estimator=estimator)
    start = time.perf_counter()
    sim.run(duration)
    wall = time.perf_counter() - start
    return sim.state, wall, sim.accuracy(), sim.work()['rhs_evaluations']


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('--quick', action='store_true')
    parser.add_argument('--reps', type=int, default=3)
    args = parser.parse_args(argv)
    tolerances = (1e-3, 1e-7) if args.quick else (1e-3, 1e-5, 1e-7, 1e-9)
    reps = 1 if args.quick else args.reps
    run(SCENES[3][1], 1e-3, None, 0.02)   # compile or load the kernels first
    header = ('| scene | tolerance | estimator | error / (tol T) | sub-steps (last step) '
              '| right-hand sides a step | wall ms / simulated s | misses |')
    lines = [header, '|' + '---|' * 8]
    points = []
    print(header, flush=True)
    for scene, build, duration in SCENES:
        reference = dop853_trajectory(build('rkmk4'), [duration], rtol=1e-13, atol=1e-13)[0]
        for tol in tolerances:
            walls = {e: [] for e in ESTIMATORS}
            for rep in range(reps):
                order = ESTIMATORS[rep % 3:] + ESTIMATORS[:rep % 3]
                for estimator in order:
                    state, wall, report, rhs = run(build, tol, estimator, duration)
                    walls[estimator].append(wall)
                    if rep == 0:
                        walls[(estimator, 'run')] = (state, report, rhs)
            for estimator in ESTIMATORS:
                state, report, rhs = walls[(estimator, 'run')]
                error = state_distance(state, reference)
                per_step = rhs / report.steps
                ms = 1e3 * statistics.median(walls[estimator]) / duration
                name = estimator or 'default'
                row = (f'| {scene} | {tol:g} | {name} | {error / (tol * duration):.2g} | '
                       f'{report.substeps} | {per_step:.1f} | {ms:.3g} | {report.misses} |')
                print(row, flush=True)
                lines.append(row)
                points.append((scene, name, error, per_step))
    OUT.mkdir(exist_ok=True)
    (OUT / 'knob_estimators.md').write_text('\n'.join(lines) + '\n')
    try:
        import matplotlib
        matplotlib.use('Agg')
        import matplotlib.pyplot as plt
    except ImportError:
        print(f'wrote {OUT / "knob_estimators.md"} (no matplotlib: no plot)')
        return
    fig, axes = plt.subplots(1, len(SCENES), figsize=(4 * len(SCENES), 3.6), sharey=True)
    for ax, (scene, _, _) in zip(axes, SCENES):
        for name, marker in (('default', 'o-'), ('embedded', 's--'), ('doubling', '^:')):
            xs = [p[2] for p in points if p[0] == scene and p[1] == name]
            ys = [p[3] for p in points if p[0] == scene and p[1] == name]
            ax.loglog(xs, ys, marker, label=name)
        ax.set_title(scene, fontsize=9)
        ax.set_xlabel('error at T')
        ax.grid(True, which='both', alpha=0.3)
    axes[0].set_ylabel('right-hand sides per step')
    axes[0].legend(fontsize=8)
    fig.suptitle(f'rkmk4 under the accuracy knob, dt {DT:g}: the estimators')
    fig.tight_layout()
    fig.savefig(OUT / 'knob_estimators.png', dpi=110)
    print(f'wrote {OUT / "knob_estimators.md"}, {OUT / "knob_estimators.png"}')


if __name__ == '__main__':
    main()
