"""
Joint limits (issue 20): their cost per step and how far joints pass their bounds, beside MuJoCo.

The Franka Panda of ``bench/robot_panda.py`` (its URDF from PyPI ``example-robot-data``,
fingers fixed, no ``<dynamics>``) swings from its "ready" pose under gravity with zero
joint torques, for 2 s at dt = 1e-3, with its URDF position limits enforced, so that
joints run into their bounds and then lie on them (the arm's elbow, ``panda_joint4``,
has its upper bound at −0.07 rad, 0.72 rad from the ready pose). Side by side in one
run, each variant's repetitions interleaved (the order rotating) and the median wall
time per step of a loop that steps once and reads the joint state, as a node does:

* ours (``lie_poisson2``) with the limits off (``limits: false``), and on;
* MuJoCo 4.0.0 (RK4 and implicitfast) with the limits off (``jnt_limited = 0``) and on
  (its URDF import's limits: soft constraints, default ``solref``/``solimp``).

Cost is reported over the whole run and step by step, by what the limits did in
each step; before any joint reaches a bound ours only watches the bounds, one
comparison a joint in the kernel that reads the joint coordinates after the step,
the events' loop entered only for a step that ends past one ("only the effects a
scene calls for": inactive limits should cost nothing measurable). Beside
the costs, each variant's largest excursion past a bound over the run (rad), the
joints that touched a bound, and ours' impacts, releases and located steps.

Run: ``./dev.sh python bench/joint_limits.py [--quick]`` (with ``bench/requirements.txt``;
``--quick``: 0.6 s, 3 repetitions). Prints the tables and writes
``bench/out/joint_limits.md``.
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

OUT = Path(__file__).resolve().parent / 'out'
DT = panda.DT


def run_ours(sim, lower: np.ndarray, upper: np.ndarray):
    """
    Run ``sim`` from its initial state n steps, reading the joint state after each.

    Besides the total, each step's own wall time and what the limits did in it: an
    impact or a release (the active set changed), a bound active throughout, or
    none active (``kinds``: 'event', 'resting', 'free').
    """
    def run(n: int) -> tuple:
        sim.reset()
        q = np.empty((n + 1, len(lower)))
        q[0] = sim.joint_state().positions
        lim = sim.limits
        each = np.empty(n)
        kinds = []
        gc.collect()
        clock = time.perf_counter
        t0 = clock()
        events = 0
        for k in range(1, n + 1):
            before = None if lim is None else (lim.counters.activations + lim.counters.releases,
                                               bool(lim.active.any()))
            t = clock()   # (the step and its read only: not the bookkeeping around them)
            sim.step()
            q[k] = sim.joint_state().positions
            each[k - 1] = clock() - t
            if lim is not None:
                changed = lim.counters.activations + lim.counters.releases != before[0]
                events += changed
                kinds.append('event' if changed else 'resting' if before[1] else
                             'free' if not events else 'free later')
        wall = clock() - t0
        counts = ({'each': each} if lim is None else
                  dict(lim.counters.as_dict(), first=min((i.time for i in lim.impacts),
                                                         default=None),
                       each=each, kinds=np.array(kinds)))
        return wall, q, counts
    return run


def run_mujoco(model, idx: np.ndarray):
    """Run fresh MjData from the ready pose n steps, copying qpos after each."""
    mujoco = panda.mujoco

    def run(n: int) -> tuple:
        data = mujoco.MjData(model)
        data.qpos[idx] = panda.READY
        mujoco.mj_forward(model, data)
        q = np.empty((n + 1, len(idx)))
        q[0] = data.qpos[idx]
        gc.collect()
        t0 = time.perf_counter()
        for k in range(1, n + 1):
            mujoco.mj_step(model, data)
            q[k] = data.qpos[idx]
        return time.perf_counter() - t0, q, {}
    return run


def excursion(q: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """Per step, the largest distance past a bound over the joints (rad; 0 inside)."""
    return np.max(np.maximum(np.maximum(lower - q, q - upper), 0.0), axis=1)


def measure(variants: list, n: int, reps: int) -> dict:
    """Time each variant ``reps`` times (interleaved, rotating); keep the first records."""
    walls = {name: [] for name, _ in variants}
    eaches = {name: [] for name, _ in variants}   # each step's own time, every timed run
    records = {}
    for name, run in variants:
        run(n)   # untimed: first calls and the kernels an impact loads on first use
    for rep in range(reps):
        shift = rep % len(variants)
        for name, run in variants[shift:] + variants[:shift]:
            wall, q, counts = run(n)
            walls[name].append(wall / n)
            eaches[name].append(counts.get('each'))
            records.setdefault(name, (q, counts))
            print(f'  [{rep + 1}/{reps}] {name:28s} {wall / n * 1e6:9.1f} us/step', flush=True)
    return {'walls': walls, 'records': records, 'eaches': eaches}


def joint_limits(quick: bool, reps: int) -> dict:
    """Build the variants, run them side by side; return the results."""
    xml = panda.benchmark_urdf(panda.panda_urdf().read_text())
    duration = 0.6 if quick else 2.0
    n = int(round(duration / DT))
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / 'panda_fixed_fingers.urdf'
        path.write_text(xml)
        off = panda.our_scene(path, 'lie_poisson2', limits=False).simulation
        on = panda.our_scene(path, 'lie_poisson2', limits=True).simulation
    specs = {j.name: j.spec for j in on.joints.joints}
    names = on.joint_names()
    lower = np.array([specs[j].lower for j in names])
    upper = np.array([specs[j].upper for j in names])
    variants = [('ours lie_poisson2, limits off', run_ours(off, lower, upper)),
                ('ours lie_poisson2, limits on', run_ours(on, lower, upper))]
    for integrator in ('RK4', 'implicitfast'):
        for limits in (False, True):
            model, idx = panda.mujoco_model(xml, integrator, limits=limits)
            variants.append((f'MuJoCo {integrator}, limits {"on" if limits else "off"}',
                             run_mujoco(model, idx)))
    res = measure(variants, n, reps)
    res.update(lower=lower, upper=upper, names=names, n=n)
    return res


def table(res: dict) -> str:
    """Markdown table of :func:`joint_limits`."""
    lower, upper, names = res['lower'], res['upper'], res['names']
    walls, records = res['walls'], res['records']
    base = {'ours': statistics.median(walls['ours lie_poisson2, limits off'])}
    for name in walls:
        if name.startswith('MuJoCo') and name.endswith('off'):
            base[name.rsplit(',', 1)[0]] = statistics.median(walls[name])
    rows = ['| variant | us / step (median) | on / off | largest excursion past a bound '
            '[rad] | joints that reached a bound | impacts, releases, located steps |',
            '|---|---|---|---|---|---|']
    for name, w in walls.items():
        q, counts = records[name]
        med = statistics.median(w)
        key = 'ours' if name.startswith('ours') else name.rsplit(',', 1)[0]
        ex = excursion(q, lower, upper)
        touched = [names[j] for j in range(len(names))
                   if np.any(q[:, j] <= lower[j] + 1e-6) or np.any(q[:, j] >= upper[j] - 1e-6)]
        events = ('-' if 'impacts' not in counts else
                  f'{counts["impacts"]}, {counts["releases"]}, {counts["located_steps"]}')
        rows.append(f'| {name} | {med * 1e6:.1f} | {med / base[key]:.2f} | {ex.max():.2e} | '
                    f'{", ".join(touched) or "none"} | {events} |')
    counts = records['ours lie_poisson2, limits on'][1]
    kinds = counts['kinds']   # the same in every run: the runs are deterministic
    on_runs = res['eaches']['ours lie_poisson2, limits on']
    off_runs = res['eaches']['ours lie_poisson2, limits off']
    parts = []
    for kind, what in (('free', 'no bound active, before the first impact (the same motion '
                                'as the run without limits; the bounds watched in the '
                                "coordinates' kernel)"),
                       ('free later', 'no bound active, after an impact (another motion than '
                                      "the run without limits' same steps)"),
                       ('resting', 'a bound active throughout (the row in the solve; the '
                                   'read solves for its force)'),
                       ('event', 'an impact or a release (rows added or removed, the impact '
                                 'located)')):
        sel = kinds == kind
        if sel.any():
            # Per timed run, the median over these steps.
            on = np.array([np.median(e[sel]) for e in on_runs])
            off = np.array([np.median(e[sel]) for e in off_runs])
            ratio = on / off
            parts.append(f'| {what} | {int(sel.sum())} | {np.median(on) * 1e6:.2f} | '
                         f'{np.median(off) * 1e6:.2f} | {np.median(ratio):.3f} '
                         f'({ratio.min():.3f} to {ratio.max():.3f}) |')
    first = counts.get('first')
    lines = ['\n'.join(rows), '',
             f'Ours step by step, each step (and its read) timed alone in each of the '
             f'{len(on_runs)} timed runs, by what the limits did in it, against the same '
             'steps of the run with the limits off (the same motion until the first impact'
             + (f', at {first:.4f} s' if first is not None else '; none in this run')
             + '): per run the median over those steps; the median over the runs, and '
             "the median and range of the runs' on / off ratios (the on and off runs "
             'alternate: each ratio is of two neighbouring runs).',
             '', '| steps with | steps | limits on, median us | limits off, median us | '
             'on / off, median (range) |', '|---|---|---|---|---|', *parts]
    return '\n'.join(lines)


def main(argv=None) -> int:
    """Run the benchmark; print and write ``bench/out/joint_limits.md``."""
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--quick', action='store_true', help='0.6 s, 3 repetitions')
    p.add_argument('--reps', type=int, default=7)
    args = p.parse_args(argv)
    if panda.mujoco is None:
        print('MuJoCo is not installed: pip install -r bench/requirements.txt')
        return 1
    t0 = time.perf_counter()
    res = joint_limits(args.quick, 3 if args.quick else args.reps)
    text = table(res)
    report.write_page(OUT, 'joint_limits', 'Joint limits: the Panda swinging into its bounds',
                      args.quick, text, t0)
    return 0


if __name__ == '__main__':
    sys.exit(main())
