"""
Collision detection (issue 21, first part): its cost against the number of shapes, beside MuJoCo.

``N`` bodies, each a sphere of radius 5 cm or a box of 10 cm sides (alternating),
placed at random (seeded) in a cube whose side grows as ``N^(1/3)`` (a fixed density,
each shape within reach of a few others, as in a pile), over a ground plane. Timed
side by side in one run, each variant's repetitions interleaved, best of each:

* ours: :meth:`.shapes.ContactDetector.detect` at the bodies' poses (the shapes'
  frames, their boxes, the broad phase's grid, the narrow phases, the contacts copied out);
* ours' narrow phase on every pair instead of the broad phase's, called from a
  Python loop (up to 1000 shapes: what the broad phase saves, ``N²/2`` pairs);
* MuJoCo 4 (``mj_kinematics`` then ``mj_collision``: its geoms' frames, its broad
  phase and narrow phases) on the same bodies as free joints, ``margin`` 1 mm as ours.

Beside the times, the pairs each tested, the contacts found (MuJoCo's box on a plane
or a box gives up to 4 too, a sphere 1), and the growth exponent ``p`` of time ∝
``N^p`` between the two largest sizes (about 1 for the grid over a pile; 2 for every pair).

Run: ``./dev.sh python bench/contact_detection.py [--quick]`` (``bench/requirements.txt``
for MuJoCo; ``--quick``: up to 1000 shapes). Prints the table and writes
``bench/out/contact_detection.md``.
"""

from __future__ import annotations

import argparse
from pathlib import Path
import sys
import time

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import report  # noqa: E402, I100

from rigid_body_sim.core import CollisionShape, ContactDetector, RigidBody  # noqa: E402
from rigid_body_sim.core.bodies import BodySet  # noqa: E402
from rigid_body_sim.core.kernels.contact import collide  # noqa: E402

try:
    import mujoco
except ImportError:   # (bench/requirements.txt)
    mujoco = None

OUT = Path(__file__).resolve().parent / 'out'
MARGIN = 1e-3
RADIUS, HALF = 0.05, 0.05


def scene(n: int, seed: int = 0) -> tuple:
    """Return positions (n, 3), orientations xyzw (n, 4) and kinds of a pile of n shapes."""
    rng = np.random.default_rng(seed)
    side = 0.12 * n ** (1.0 / 3.0)   # about one shape per (12 cm)³
    pos = rng.uniform(0.0, side, size=(n, 3)) + np.array([0.0, 0.0, 0.04])
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1)[:, None]
    kinds = ['sphere' if i % 2 == 0 else 'box' for i in range(n)]
    return pos, q, kinds


def ours(n: int) -> tuple:
    """Return our detector and the bodies' outputs for the pile of n."""
    pos, q, kinds = scene(n)
    bodies = [RigidBody(f'b{i}', 1.0, (1e-3, 1e-3, 1e-3), position_world=pos[i],
                        orientation_xyzw=q[i]) for i in range(n)]
    shapes = [CollisionShape('sphere', b.name, radius=RADIUS) if k == 'sphere' else
              CollisionShape('box', b.name, size=(2 * HALF,) * 3)
              for b, k in zip(bodies, kinds)]
    shapes.append(CollisionShape('plane', name='ground'))
    bs = BodySet.from_bodies(bodies)
    bs.outputs(bs.initial_state(bodies))
    return ContactDetector(shapes, [b.name for b in bodies], margin=MARGIN), \
        bs.outputs_cache.out


def every_pair(det: ContactDetector, out: np.ndarray) -> int:
    """Run the narrow phase on every pair (no broad phase); return the contacts found."""
    c, R = det.frames(out)
    m = len(det.live)
    pts, nrm, dep = np.zeros((64, 3)), np.zeros((64, 3)), np.zeros(64)
    count = 0
    for i in range(m):
        for j in range(i + 1, m):
            a, b = (j, i) if det.kind[i] == 4 else (i, j)
            count += collide(int(det.kind[a]), c[a], R[a], det.size[a], int(det.kind[b]),
                             c[b], R[b], det.size[b], det.margin, pts, nrm, dep, 0)
    return count


def mujoco_model(n: int):
    """Return MuJoCo's model and data of the same pile (free bodies), positioned."""
    pos, q, kinds = scene(n)
    geoms = []
    for i, k in enumerate(kinds):
        g = (f'<geom type="sphere" size="{RADIUS}"/>' if k == 'sphere' else
             f'<geom type="box" size="{HALF} {HALF} {HALF}"/>')
        geoms.append(f'<body name="b{i}"><freejoint/>{g}</body>')
    xml = (f'<mujoco><option><flag contact="enable"/></option><default><geom '
           f'margin="{MARGIN}"/></default><size memory="2G"/><worldbody>'
           '<geom type="plane" size="0 0 1"/>' + ''.join(geoms) + '</worldbody></mujoco>')
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    for i in range(n):
        adr = model.jnt_qposadr[i]
        data.qpos[adr:adr + 3] = pos[i]
        x, y, z, w = q[i]
        data.qpos[adr + 3:adr + 7] = (w, x, y, z)
    return model, data


def best(fn, reps: int, inner: int) -> float:
    """Best over reps of the mean seconds of inner calls."""
    times = []
    for _ in range(reps):
        t0 = time.perf_counter()
        for _ in range(inner):
            fn()
        times.append((time.perf_counter() - t0) / inner)
    return min(times)


def run(sizes: list, reps: int) -> list:
    """Time each variant at each size; return the table's rows."""
    rows = []
    for n in sizes:
        det, out = ours(n)
        det.detect(out)   # (untimed: first calls)
        inner = max(1, 2000 // n)
        contacts = len(det.detect(out).depth)
        pairs = det.counters['pairs_tested'] // det.counters['detections']
        t_ours = best(lambda: det.detect(out), reps, inner)
        t_all = None
        if n <= 1000:
            every_pair(*ours(10))   # (untimed: its first call compiles)
            t_all = best(lambda: every_pair(det, out), 1, 1)
        t_mj, mj_contacts = None, None
        if mujoco is not None:
            model, data = mujoco_model(n)

            def mj():
                mujoco.mj_kinematics(model, data)
                mujoco.mj_collision(model, data)
            mj()
            t_mj = best(mj, reps, inner)
            mj_contacts = int(data.ncon)
        rows.append({'n': n, 'pairs': pairs, 'contacts': contacts, 'ours': t_ours,
                     'every': t_all, 'mujoco': t_mj, 'mj_contacts': mj_contacts})
        print(f'  N = {n:6d}: ours {t_ours * 1e6:9.1f} us, {contacts} contacts'
              + ('' if t_mj is None else f'; MuJoCo {t_mj * 1e6:9.1f} us, {mj_contacts}'),
              flush=True)
    return rows


def table(rows: list) -> str:
    """Markdown table of :func:`run`."""
    lines = ['| shapes N | pairs tested (ours) | contacts (ours) | ours, us | narrow phase on '
             'every pair, us | MuJoCo kinematics + collision, us | contacts (MuJoCo) | '
             'ours / MuJoCo |', '|---|---|---|---|---|---|---|---|']
    for r in rows:
        every = '-' if r['every'] is None else f'{r["every"] * 1e6:.0f}'
        mj = '-' if r['mujoco'] is None else f'{r["mujoco"] * 1e6:.1f}'
        ratio = '-' if r['mujoco'] is None else f'{r["ours"] / r["mujoco"]:.2f}'
        mj_count = '-' if r['mj_contacts'] is None else r['mj_contacts']
        lines.append(f'| {r["n"]} | {r["pairs"]} | {r["contacts"]} | {r["ours"] * 1e6:.1f} | '
                     f'{every} | {mj} | {mj_count} | {ratio} |')
    a, b = rows[-2], rows[-1]
    growth = np.log(b['ours'] / a['ours']) / np.log(b['n'] / a['n'])
    text = '\n'.join(lines) + (f'\n\nGrowth of ours between N = {a["n"]} and {b["n"]}: '
                               f'time ∝ N^{growth:.2f}.')
    if a['mujoco'] is not None:
        g = np.log(b['mujoco'] / a['mujoco']) / np.log(b['n'] / a['n'])
        text += f' MuJoCo: N^{g:.2f}.'
    return text


def main(argv=None) -> int:
    """Run the benchmark; print and write ``bench/out/contact_detection.md``."""
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--quick', action='store_true', help='up to 1000 shapes, 3 repetitions')
    args = p.parse_args(argv)
    t0 = time.perf_counter()
    sizes = [10, 100, 1000] if args.quick else [10, 100, 1000, 10000]
    rows = run(sizes, 3 if args.quick else 7)
    report.write_page(OUT, 'contact_detection', 'Collision detection: cost against shapes, '
                      'beside MuJoCo', args.quick, table(rows), t0)
    return 0


if __name__ == '__main__':
    sys.exit(main())
