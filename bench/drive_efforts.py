"""
Effort-limited exact drives (issue 20): what the bound costs a step, and when it acts.

The Franka Panda of ``bench/robot_panda.py`` (its URDF from PyPI ``example-robot-data``,
fingers fixed) under gravity with its seven arm joints on exact position drives, at
dt = 1e-3, in four scenes, each with the drives' URDF effort limits off
(``effort_limits: false``: the unbounded drive) and on (87 N m on the shoulder joints,
12 N m on the wrist):

* **hold**: the drives hold the ready pose (no command);
* **stream 100 Hz** and **stream 1 kHz**: a trajectory streamed as position targets every
  10 steps or every step, each joint ``q_ready + 0.3 sin(2π 0.5 t)`` (a smooth motion:
  every command a small jump, which the projection closes within the effort's ``E dt``
  or, beyond it, a saturation);
* **jump**: at the start every joint's target jumps 0.5 rad (far beyond ``E dt``: the
  drives saturate, close the jump at full effort and engage).

Side by side in one run, each variant's repetitions interleaved (the order rotating),
the median wall time per step of a loop that steps once (commanding first when the
scene says so) and reads the joint state, as a node does. Beside the cost: the largest
effort read over the run against its joint's limit (on: never above it; off: what the
unbounded drive asked), and the saturations and engagements. No peer: MuJoCo's
position actuators with a ``forcerange`` are servos (a spring, no exact motion) and its
joint equality constraints are soft and unbounded.

Run: ``./dev.sh python bench/drive_efforts.py [--quick]`` (with ``bench/requirements.txt``;
``--quick``: 0.5 s, 3 repetitions). Prints the table and writes
``bench/out/drive_efforts.md``.
"""

from __future__ import annotations

import argparse
import gc
from pathlib import Path
import statistics
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import report  # noqa: E402, I100
import robot_panda as panda  # noqa: E402, I100
from rigid_body_sim.scene import scene_from_dict  # noqa: E402, I100

OUT = Path(__file__).resolve().parent / 'out'
DT = panda.DT
SCENES = ('hold', 'stream 100 Hz', 'stream 1 kHz', 'jump')


def build(path: Path, limited: bool):
    """Our Panda with its arm on exact position drives (effort limits on or off)."""
    data = {'dt': DT, 'integrator': 'lie_poisson2',
            'effects': {'gravity': {'g_world': [0.0, 0.0, -panda.G]}},
            'robots': [{'urdf': str(path), 'fixed_base': True, 'limits': False,
                        'effort_limits': limited,
                        'initial_positions': dict(zip(panda.ARM, panda.READY))}],
            'command_groups': [{'name': 'arm', 'joints': list(panda.ARM),
                                'interface': 'position', 'mode': 'exact'}]}
    return scene_from_dict(data, str(path)).simulation


def commands(scene: str, n: int) -> list:
    """Return ``[(step, {joint: target}), ...]`` of a scene over ``n`` steps."""
    ready = np.array(panda.READY)
    if scene == 'hold':
        return []
    if scene == 'jump':
        return [(0, dict(zip(panda.ARM, ready + 0.5)))]
    every = 10 if scene == 'stream 100 Hz' else 1
    out = []
    for k in range(0, n, every):
        t = (k + 1) * DT
        out.append((k, dict(zip(panda.ARM, ready + 0.3 * np.sin(2 * np.pi * 0.5 * t)))))
    return out


def run(sim, scene: str):
    """Return a run of ``scene`` on ``sim``: a callable of n giving (wall, record)."""
    def go(n: int) -> tuple:
        sim.reset()
        plan = dict(commands(scene, n))
        limit = sim.joints.effort_limit
        worst = 0.0
        gc.disable()
        t0 = time.perf_counter()
        for k in range(n):
            if k in plan:
                sim.command_joints(plan[k])
            sim.step()
            worst = max(worst, float(np.max(np.abs(sim.joint_state().efforts) / limit)))
        wall = time.perf_counter() - t0
        gc.enable()
        counts = sim.drive_saturation().get('counters', {})
        return wall / n, {'worst': worst, **counts}
    return go


def measure(variants: list, n: int, reps: int) -> dict:
    """Run the variants ``reps`` times, interleaved with the order rotating."""
    walls = {name: [] for name, _ in variants}
    records = {}
    for _, fn in variants:   # warm up (compiled kernels, caches)
        fn(min(n, 50))
    for r in range(reps):
        for name, fn in variants[r % len(variants):] + variants[:r % len(variants)]:
            wall, record = fn(n)
            walls[name].append(wall)
            records[name] = record
    return {'walls': walls, 'records': records}


def drive_efforts(quick: bool, reps: int) -> dict:
    """Build the variants, run them side by side; return the results."""
    xml = panda.benchmark_urdf(panda.panda_urdf().read_text())
    n = int(round((0.5 if quick else 2.0) / DT))
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / 'panda_fixed_fingers.urdf'
        path.write_text(xml)
        sims = {limited: build(path, limited) for limited in (False, True)}
    variants = [(f'{scene}, limits {"on" if limited else "off"}', run(sims[limited], scene))
                for scene in SCENES for limited in (False, True)]
    res = measure(variants, n, reps)
    res['n'] = n
    res['limits'] = dict(zip(panda.ARM, sims[True].joints.effort_limit))
    return res


def table(res: dict) -> str:
    """Markdown table of :func:`drive_efforts`."""
    walls, records = res['walls'], res['records']
    rows = ['| scene | effort limits | us / step (median) | on / off | largest effort / its '
            'limit | saturations, engagements |', '|---|---|---|---|---|---|']
    for scene in SCENES:
        off = statistics.median(walls[f'{scene}, limits off'])
        for limited in ('off', 'on'):
            name = f'{scene}, limits {limited}'
            med = statistics.median(walls[name])
            rec = records[name]
            counts = (f'{rec["saturations"]}, {rec["engagements"]}' if 'saturations' in rec
                      else '-')
            rows.append(f'| {scene} | {limited} | {med * 1e6:.1f} | {med / off:.2f} | '
                        f'{rec["worst"]:.3g} | {counts} |')
    limits = ', '.join(f'{j.replace("panda_", "")} {e:g}' for j, e in res['limits'].items())
    return '\n'.join(rows + ['', f'Effort limits (N m): {limits}; {res["n"]} steps a run.'])


def main(argv=None) -> int:
    """Run the benchmark; print and write ``bench/out/drive_efforts.md``."""
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--quick', action='store_true', help='0.5 s, 3 repetitions')
    p.add_argument('--reps', type=int, default=7)
    args = p.parse_args(argv)
    t0 = time.perf_counter()
    res = drive_efforts(args.quick, 3 if args.quick else args.reps)
    text = table(res)
    report.write_page(OUT, 'drive_efforts', 'Effort-limited exact drives: the Panda',
                      args.quick, text, t0)
    return 0


if __name__ == '__main__':
    sys.exit(main())
