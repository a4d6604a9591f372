"""
The tree solve in inertia form against the row-space tree solve, side by side (issue 19).

Each scene is built twice, one with ``ConstraintSolver.inertia_form`` off (every
system by the row-space tree solve, Baraff's elimination of each joint's rows) and
one with it on (the default: where the forest's joints are recognized, the
systems eliminate each joint's freedoms, ``core/kernels/nullspace_solve.py`` and
``nullspace_shake.py``). Per scene and method, after a warm-up that compiles: the
median wall time per step over interleaved repetitions, their ratio, the
factorizations per step (the solver's counters), and, from the same start, the
largest difference of the two runs' states (positions, m; velocities, m/s;
quaternions; angular velocities, rad/s: the state buffer's largest entry
difference) after 1,000 steps. The two solve the same systems, so their states
differ by rounding only, carried along by the dynamics: these scenes are chaotic
(a chain released horizontal, a ring falling), and a difference in the last bits
grows with time. The last column measures that growth alone: the row-space run
against itself started from positions changed by one ulp (relative 2.2e-16).

Scenes: planar hinge chains of 10 and 50 rods (0.1 m, 1 kg, released
horizontal), a 3-D tree of 30 bodies on hinges, a chain of 12 mixed joints
(hinge, ball, slider, fixed), the 7-DOF test arm with its gripper's mimic joint
(a loop solve: the mimic row closes over a forest of nine joints), and a ring of
12 hinged rods closed by a ball joint (a loop solve); gravity, dt 1e-3.

Run: ``./dev.sh python bench/inertia_form.py [--quick]``; writes
``bench/out/inertia_form.md``.
"""

from __future__ import annotations

import argparse
from pathlib import Path
import statistics
import sys
import tempfile
import time

import numpy as np
from rigid_body_sim.core import Simulation
from rigid_body_sim.core.mechanisms import ring
from rigid_body_sim.scene import scene_from_dict

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / 'bench' / 'out'
sys.path.insert(0, str(ROOT / 'bench'))
sys.path.insert(1, str(ROOT / 'test'))
from constraints import hinge_chain  # noqa: E402, I100 - bench/constraints.py
from test_inertia_form import chain, mechanism, tree  # noqa: E402 - the tests' scenes

METHODS = ('lie_poisson2', 'rkmk4')


def arm7(method: str) -> Simulation:
    """Load the 7-DOF test arm with its gripper's mimic joint, under gravity."""
    tmp = Path(tempfile.mkdtemp())
    text = (ROOT / 'test' / 'urdf' / 'arm7.urdf').read_text()
    (tmp / 'arm7.urdf').write_text(text)
    data = {'dt': 1e-3, 'integrator': method, 'robots': [{'urdf': str(tmp / 'arm7.urdf')}],
            'effects': {'gravity': {'g_world': [0.0, 0.0, -9.81]}}}
    return scene_from_dict(data, str(tmp / 'scene.yaml')).simulation


def _mixed(method: str) -> Simulation:
    return mechanism(2, ['hinge', 'ball', 'slider', 'fixed'] * 3, chain(12))(method)


def _tree30(method: str) -> Simulation:
    return mechanism(3, ['hinge'] * 30, tree(np.random.default_rng(3), 30))(method)


SCENES = {
    'hinge chain 10': lambda method: hinge_chain(10, method),
    'hinge chain 50': lambda method: hinge_chain(50, method),
    'hinge tree 30 (3-D)': _tree30,
    'mixed chain 12': _mixed,
    'arm7 + gripper mimic (loop)': arm7,
    'ring 12 (loop)': lambda method: ring(12, method),
}


def per_step(sim: Simulation, steps: int) -> float:
    """Return the wall time per step of ``steps`` steps (s)."""
    t0 = time.perf_counter()
    sim.step(steps)
    return (time.perf_counter() - t0) / steps


def build(scene: str, method: str, inertia: bool) -> Simulation:
    """Build a scene with the inertia form on or off."""
    sim = SCENES[scene](method)
    sim.dynamics.solver.inertia_form = inertia
    return sim


def compare(scene: str, method: str, reps: int, steps: int) -> dict:
    """Time both variants interleaved; difference of their states after 1,000 steps."""
    sims = {v: build(scene, method, v) for v in (False, True)}
    for sim in sims.values():
        sim.step(200)   # compiles, and leaves the release transient
    times = {False: [], True: []}
    for r in range(reps):
        for v in ((False, True) if r % 2 == 0 else (True, False)):
            times[v].append(per_step(sims[v], steps))
    fresh = {v: build(scene, method, v) for v in (False, True)}
    fresh['ulp'] = build(scene, method, False)
    fresh['ulp'].state.pos_com_world[...] *= 1.0 + np.finfo(float).eps
    for sim in fresh.values():
        sim.step(1000)
    diff = float(np.max(np.abs(fresh[True].state.y - fresh[False].state.y)))
    ulp = float(np.max(np.abs(fresh['ulp'].state.y - fresh[False].state.y)))
    solver = fresh[True].dynamics.solver
    comp = solver.kernel_setup().components
    return {'old': statistics.median(times[False]), 'new': statistics.median(times[True]),
            'diff': diff, 'ulp': ulp, 'rows': sum(len(c.rows) for c in comp),
            'joints': sum(int(c.views['nullspace_child'].size) for c in comp),
            'fallbacks': solver.counters.inertia_form_fallbacks,
            'factorizations': solver.counters.factorizations / 1000.0}


def main(argv=None) -> None:
    """Print the table and write it to ``bench/out/inertia_form.md``."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    p.add_argument('--quick', action='store_true', help='fewer repetitions, shorter')
    args = p.parse_args(argv)
    reps, steps = (3, 200) if args.quick else (7, 500)
    lines = ['| scene | method | rows | joints in inertia form | row-space µs / step | '
             'inertia form µs / step | ratio | factorizations / step | fallbacks | '
             'largest state difference after 1,000 steps | the same, row-space against '
             'itself from positions one ulp apart |',
             '|---|---|---|---|---|---|---|---|---|---|---|']
    for scene in SCENES:
        for method in METHODS:
            r = compare(scene, method, reps, steps)
            lines.append(f'| {scene} | `{method}` | {r["rows"]} | {r["joints"]} | '
                         f'{1e6 * r["old"]:.1f} | {1e6 * r["new"]:.1f} | '
                         f'{r["old"] / r["new"]:.2f} | {r["factorizations"]:.2f} | '
                         f'{r["fallbacks"]} | {r["diff"]:.1e} | {r["ulp"]:.1e} |')
            print(lines[-1], flush=True)
    table = '\n'.join(lines)
    OUT.mkdir(exist_ok=True)
    (OUT / 'inertia_form.md').write_text(table + '\n')


if __name__ == '__main__':
    main()
