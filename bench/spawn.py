"""
Spawning and deleting at run time (issue 22): their cost against scene size.

Scenes of N free spheres (0.05 m, 1 kg) resting on a ground in a square grid, gravity,
``rkmk4``, ``dt`` 1 ms, N = 10, 100, 1000. Per scene: the mean wall time of
``Simulation.add_body`` (a sphere with its shape dropped above the grid) and of
``Simulation.remove_body`` (that sphere), each over several repetitions, beside the cost
of one step of the same scene (``step(100)`` per call), and how many steps a spawn costs.
A spawn makes the simulation anew around the new body, reusing what did not change (each
shape's numbers, the robots' conversions, the compiled steps' components), and carries
the running state over.

Robots: ``config/servo_arm.urdf`` (3 moving links, 3 joints; each with its prefix) spawned
one after another with ``Simulation.add_robot`` into 10 free boxes under gravity, the
wall time of the k-th spawn against the k - 1 robots there (each over the repetitions,
from a fresh scene), the components it planned and copied, the same spawn's time with no
component copied (in the same run), then of ``remove_robot`` of the last one.

Run: ``./dev.sh python bench/spawn.py [--quick]`` (``--quick``: 3 repetitions, else 7).
Prints the table and writes ``bench/out/spawn.md``.
"""

from __future__ import annotations

import argparse
from dataclasses import replace
import math
from pathlib import Path
import sys
import time

sys.path.insert(0, str(Path(__file__).resolve().parent))
import report  # noqa: E402, I100

from rigid_body_sim.core import CollisionShape, Gravity, RigidBody, Simulation  # noqa: E402
from rigid_body_sim.core import solver as solver_module  # noqa: E402
from rigid_body_sim.scene import robot_from_dict  # noqa: E402

OUT = Path(__file__).resolve().parent / 'out'
ROOT = Path(__file__).resolve().parents[1]
R = 0.05


def scene(n: int) -> Simulation:
    """Return N spheres resting on the ground in a grid 0.15 m apart."""
    side = math.ceil(math.sqrt(n))
    bodies = [RigidBody(f's{k}', 1.0, (0.4 * R * R,) * 3,
                        position_world=(0.15 * (k % side), 0.15 * (k // side), R))
              for k in range(n)]
    shapes = [CollisionShape('plane', None, friction=0.5)] + [
        CollisionShape('sphere', b.name, radius=R, friction=0.5) for b in bodies]
    return Simulation(bodies, [Gravity()], integrator='rkmk4', dt=1e-3, shapes=shapes)


def run(sizes: list, repeats: int) -> list:
    """Return ``[(N, step s, spawn s, delete s)]``."""
    rows = []
    for n in sizes:
        sim = scene(n)
        sim.step(100)   # (settled; the kernels loaded)
        extra = RigidBody('warm', 1.0, (0.4 * R * R,) * 3, position_world=(-1.0, -1.0, 1.0))
        sim.add_body(extra, [CollisionShape('sphere', extra.name, radius=R)])
        sim.step(10)
        sim.remove_body(extra.name)   # (a spawn's own kernels loaded: not timed)
        sim.step(10)
        t0 = time.perf_counter()
        sim.step(100)
        step = (time.perf_counter() - t0) / 100
        spawn = delete = 0.0
        for k in range(repeats):
            body = RigidBody(f'new{k}', 1.0, (0.4 * R * R,) * 3, position_world=(-1.0, -1.0, 1.0))
            t0 = time.perf_counter()
            sim.add_body(body, [CollisionShape('sphere', body.name, radius=R)])
            spawn += time.perf_counter() - t0
            sim.step(10)
            t0 = time.perf_counter()
            sim.remove_body(body.name)
            delete += time.perf_counter() - t0
            sim.step(10)
        rows.append((n, step, spawn / repeats, delete / repeats))
        print(f'N = {n}: step {step * 1e6:.0f} us, spawn {spawn / repeats * 1e3:.1f} ms, '
              f'delete {delete / repeats * 1e3:.1f} ms', flush=True)
    return rows


def robots(counts: list, repeats: int) -> list:
    """
    Return ``[(robots there, spawn s, delete s, planned, copied, spawn s planning all)]``.

    The k-th arm's spawn and deletion; the components the spawn planned and copied
    (:attr:`.ConstraintSolver.plan_counts`), and the spawn's time when every component
    is planned anew (no plan copied: as before plans were kept), in the same run.
    """
    spec = robot_from_dict({'urdf': str(ROOT / 'config' / 'servo_arm.urdf')})[0]
    most = max(counts)
    spawn, delete = dict.fromkeys(counts, 0.0), dict.fromkeys(counts, 0.0)
    plans, every = {}, dict.fromkeys(counts, 0.0)
    content = solver_module._content
    for rep in range(2 * repeats + 1):   # (the first loads the joint kernels: not timed)
        replan = rep % 2 == 0   # (reps 2, 4, ...: no plan copied)
        solver_module._content = (lambda *args: None) if replan else content
        sim = Simulation([RigidBody(f'b{i}', 1.0, (0.1, 0.2, 0.3), position_world=(i, 0, 0))
                          for i in range(10)], [Gravity()], integrator='rkmk4', dt=1e-3)
        sim.step(10)
        for k in range(most + 1):
            arm = replace(spec, name=f'arm{k}', prefix=f'arm{k}_', base_xyz=(k, -5.0, 0.0))
            t0 = time.perf_counter()
            sim.add_robot(arm)
            spent = time.perf_counter() - t0
            sim.step(5)
            if k in spawn and rep and replan:
                every[k] += spent
            elif k in spawn and rep:
                spawn[k] += spent
                plans[k] = dict(sim.dynamics.solver.plan_counts)
                t0 = time.perf_counter()
                sim.remove_robot(arm.name)
                delete[k] += time.perf_counter() - t0
                sim.add_robot(arm)
            sim.step(5)
    solver_module._content = content
    rows = [(k, spawn[k] / repeats, delete[k] / repeats, plans[k]['planned'],
             plans[k]['copied'], every[k] / repeats) for k in counts]
    for k, s, d, p, c, e in rows:
        print(f'{k} robots there: spawn {s * 1e3:.1f} ms ({p} components planned, {c} '
              f'copied; {e * 1e3:.1f} ms planning all), delete {d * 1e3:.1f} ms', flush=True)
    return rows


def table(rows: list, robot_rows: list = ()) -> str:
    """Return the markdown table."""
    lines = ['| bodies N | step, us | spawn, ms | delete, ms | a spawn costs (steps) |',
             '|---|---|---|---|---|']
    for n, step, spawn, delete in rows:
        lines.append(f'| {n} | {step * 1e6:.0f} | {spawn * 1e3:.1f} | {delete * 1e3:.1f} | '
                     f'{spawn / step:.0f} |')
    return '\n'.join(lines) + (
        '\n\nA spawn or a deletion makes the simulation anew around the change and carries '
        'the running state over, body by body. What does not change is not made again: '
        "each shape's numbers are made once (the detector's tables stack them), each "
        "robot's URDF conversion is kept, and the compiled steps' components (bodies "
        'joined by joints) that a change leaves as they were are copied, not planned '
        "(ConstraintSolver.plans). What is left grows with N: the bodies' arrays (one "
        "batched eigendecomposition of the inertias), the scene's tables and the state, "
        'made or copied anew.') + (
        '\n\n| robots there | spawn an arm, ms | components planned / copied | '
        'spawn planning every component, ms | delete it, ms |\n|---|---|---|---|---|\n'
        + '\n'.join(f'| {k} | {s * 1e3:.1f} | {p} / {c} | {e * 1e3:.1f} | {d * 1e3:.1f} |'
                    for k, s, d, p, c, e in robot_rows)
        + "\n\nA robot's spawn converts its URDF once; the robots already there keep "
          "their conversions and their components (copied; planned: the new arm's), and "
          'the constraint tables are built once. The column beside it is the same spawn '
          'with no plan copied, measured in the same run.'
        if robot_rows else '')


def main(argv=None) -> int:
    """Run the benchmark; print and write ``bench/out/spawn.md``."""
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--quick', action='store_true', help='3 repetitions (7 without)')
    args = p.parse_args(argv)
    t0 = time.perf_counter()
    rows = run([10, 100, 1000], 3 if args.quick else 7)
    robot_rows = robots([0, 5, 10, 20], 2 if args.quick else 5)
    report.write_page(OUT, 'spawn', 'Spawning and deleting: cost against scene size',
                      args.quick, table(rows, robot_rows), t0)
    return 0


if __name__ == '__main__':
    sys.exit(main())
