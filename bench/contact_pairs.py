"""
Narrow phases by pair of kinds: their cost per pair beside MuJoCo's, and their contacts.

``N`` = 200 separate pairs of one kind each (shape ``a`` on a body resting on shape
``b`` fixed to the world, the pairs 1 m apart so each meets only its own), in three
poses per kind, each pair turned about the vertical at random (seeded) and tilted by
1e-4 rad at most, its lowest point 1e-5 m into ``b``:

* ``standing``: a cylinder on its cap (on a box's face, or on a cylinder's cap);
* ``lying``: a cylinder on its side (on a box's face, or across a lying cylinder);
* the reference pairs of closed-form narrow phases: a box on a box, a capsule lying
  on a box, a cylinder standing on the ground (a plane);
* a mesh: the hull of a cube's eight corners (the same cube as the boxes: ours
  :mod:`rigid_body_sim.core.hulls`, MuJoCo's mesh geom) on a box, on the ground and on
  another such hull.

Timed side by side in one run, best of the repetitions: ours,
:meth:`.shapes.ContactDetector.detect` (broad phase included) over the 200 pairs,
per pair; MuJoCo 4 (``mj_kinematics`` then ``mj_collision``) on the same pairs as
free bodies over world geoms, ``margin`` 1 mm as ours. Beside them, the contacts per
pair each finds (a standing cylinder has four, a lying one two; MuJoCo's general
convex pairs give one unless its multi-contact option is set, which is not here: its
defaults).

Run: ``./dev.sh python bench/contact_pairs.py [--quick]`` (``bench/requirements.txt``
for MuJoCo). Prints the table and writes ``bench/out/contact_pairs.md``.
"""

from __future__ import annotations

import argparse
from pathlib import Path
import sys
import time

import numpy as np
from scipy.spatial.transform import Rotation

sys.path.insert(0, str(Path(__file__).resolve().parent))
from contact_detection import best  # noqa: E402, I100
import report  # noqa: E402, I100

from rigid_body_sim.core import CollisionShape, ContactDetector, RigidBody  # noqa: E402
from rigid_body_sim.core.bodies import BodySet  # noqa: E402

try:
    import mujoco
except ImportError:   # (bench/requirements.txt)
    mujoco = None

OUT = Path(__file__).resolve().parent / 'out'
MARGIN = 1e-3
N = 200
R_CYL, HL = 0.05, 0.1   # a cylinder's radius and half length
#: (label, a's kind, a lying?, b's kind, b lying?)
CASES = [('box on box', 'box', False, 'box', False),
         ('capsule lying on box', 'capsule', True, 'box', False),
         ('cylinder standing on plane', 'cylinder', False, 'plane', False),
         ('cylinder standing on box', 'cylinder', False, 'box', False),
         ('cylinder lying on box', 'cylinder', True, 'box', False),
         ('cylinder standing on cylinder', 'cylinder', False, 'cylinder', False),
         ('cylinder lying across cylinder', 'cylinder', True, 'cylinder', True),
         ('hull (a cube) on box', 'hull', False, 'box', False),
         ('hull (a cube) on plane', 'hull', False, 'plane', False),
         ('hull (a cube) on hull (a cube)', 'hull', False, 'hull', False)]
#: A hull's vertices: the corners of the boxes' cube.
CUBE = np.array([[x, y, z] for x in (-HL, HL) for y in (-HL, HL) for z in (-HL, HL)])


def _lowest(kind: str, rot: Rotation) -> float:
    """Return how far the lowest point lies below the centre of a shape turned by rot."""
    if kind in ('box', 'hull'):
        return float(-np.min(rot.apply(CUBE)[:, 2]))
    axis = rot.apply([0, 0, 1.0])
    across = R_CYL * np.sqrt(max(1.0 - axis[2] ** 2, 0.0))
    if kind == 'capsule':
        return abs(axis[2]) * HL + R_CYL
    return abs(axis[2]) * HL + across


def _top(kind: str, lying: bool) -> float:
    """Return the height of b's top over its centre."""
    return R_CYL if lying else HL


def poses(case: tuple, seed: int = 0) -> list:
    """Return per pair: (a's centre, a's xyzw, b's centre, b's xyzw)."""
    _, ka, lying_a, kb, lying_b = case
    rng = np.random.default_rng(seed)
    out = []
    for i in range(N):
        origin = np.array([float(i % 20), float(i // 20), 0.0])
        yaw = Rotation.from_euler('z', rng.uniform(0, 2 * np.pi))
        tilt = Rotation.from_rotvec(rng.normal(size=3) * 1e-4 / np.sqrt(3))
        base_b = Rotation.from_euler('x', 90, degrees=True) if lying_b else Rotation.identity()
        rot_b = Rotation.from_euler('z', rng.uniform(0, 2 * np.pi)) * base_b
        base_a = Rotation.from_euler('y', 90, degrees=True) if lying_a else Rotation.identity()
        rot_a = tilt * yaw * base_a
        top = 0.0 if kb == 'plane' else _top(kb, lying_b)
        centre_a = origin + [0, 0, top + _lowest(ka, rot_a) - 1e-5]
        out.append((centre_a, rot_a.as_quat(), origin.copy(), rot_b.as_quat()))
    return out


def _shape(kind: str, body, name: str, quat=None, pos=None) -> CollisionShape:
    extra = {} if quat is None else {'orientation_xyzw': tuple(quat), 'position_body': tuple(pos)}
    if kind == 'box':
        return CollisionShape('box', body, size=(2 * HL,) * 3, name=name, **extra)
    if kind == 'plane':
        return CollisionShape('plane', None, name=name)
    if kind == 'hull':
        return CollisionShape('mesh', body, mesh=CUBE, name=name, **extra)
    return CollisionShape(kind, body, radius=R_CYL, length=2 * HL, name=name, **extra)


def ours(case: tuple) -> tuple:
    """Return our detector and the bodies' outputs for the case's pairs."""
    _, ka, _, kb, _ = case
    bodies, shapes = [], []
    for i, (ca, qa, cb, qb) in enumerate(poses(case)):
        bodies.append(RigidBody(f'a{i}', 1.0, (1e-3,) * 3, position_world=tuple(ca),
                                orientation_xyzw=tuple(qa)))
        shapes.append(_shape(ka, f'a{i}', f'a{i}'))
        if kb != 'plane':
            shapes.append(_shape(kb, None, f'b{i}', qb, cb))
    if kb == 'plane':
        shapes.append(_shape('plane', None, 'ground'))
    bs = BodySet.from_bodies(bodies)
    bs.outputs(bs.initial_state(bodies))
    return ContactDetector(shapes, [b.name for b in bodies], margin=MARGIN), \
        bs.outputs_cache.out


def _geom(kind: str, quat=None, pos=None) -> str:
    where = '' if quat is None else (f' pos="{pos[0]} {pos[1]} {pos[2]}" quat="{quat[3]} '
                                     f'{quat[0]} {quat[1]} {quat[2]}"')
    if kind == 'box':
        return f'<geom type="box" size="{HL} {HL} {HL}"{where}/>'
    if kind == 'plane':
        return '<geom type="plane" size="0 0 1"/>'
    if kind == 'hull':
        return f'<geom type="mesh" mesh="cube"{where}/>'
    return f'<geom type="{kind}" size="{R_CYL} {HL}"{where}/>'


def mujoco_model(case: tuple):
    """Return MuJoCo's model and data of the same pairs (free bodies over world geoms)."""
    _, ka, _, kb, _ = case
    world, bodies = [], []
    ps = poses(case)
    for i, (ca, qa, cb, qb) in enumerate(ps):
        bodies.append(f'<body name="a{i}"><freejoint/>{_geom(ka)}</body>')
        if kb != 'plane':
            world.append(_geom(kb, qb, cb))
    if kb == 'plane':
        world.append(_geom('plane'))
    cube = ' '.join(f'{x!r}' for x in CUBE.ravel().tolist())
    xml = (f'<mujoco><default><geom margin="{MARGIN}"/></default><size memory="1G"/>'
           f'<asset><mesh name="cube" vertex="{cube}"/></asset><worldbody>'
           + ''.join(world) + ''.join(bodies) + '</worldbody></mujoco>')
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    for i, (ca, qa, _, _) in enumerate(ps):
        adr = model.jnt_qposadr[i]
        data.qpos[adr:adr + 3] = ca
        x, y, z, w = qa
        data.qpos[adr + 3:adr + 7] = (w, x, y, z)
    return model, data


def run(reps: int) -> list:
    """Time each case; return the table's rows."""
    rows = []
    for case in CASES:
        det, out = ours(case)
        con = det.detect(out)   # (untimed: first calls)
        t_ours = best(lambda: det.detect(out), reps, 20) / N
        deepest = float(np.max(con.depth)) if len(con.depth) else float('nan')
        t_mj, mj_contacts = None, None
        if mujoco is not None:
            model, data = mujoco_model(case)

            def mj():
                mujoco.mj_kinematics(model, data)
                mujoco.mj_collision(model, data)
            mj()
            t_mj = best(mj, reps, 20) / N
            mj_contacts = data.ncon / N
        rows.append({'case': case[0], 'ours': t_ours, 'contacts': len(con.depth) / N,
                     'deepest': deepest, 'mujoco': t_mj, 'mj_contacts': mj_contacts})
        print(f'  {case[0]:32s} ours {t_ours * 1e6:7.2f} us/pair, '
              f'{len(con.depth) / N:.2f} contacts'
              + ('' if t_mj is None else f'; MuJoCo {t_mj * 1e6:7.2f} us/pair, '
                 f'{mj_contacts:.2f}'), flush=True)
    return rows


def table(rows: list) -> str:
    """Markdown table of :func:`run`."""
    lines = ['| pair (200 of them) | ours, us a pair | contacts a pair (ours) | deepest (ours, '
             'm; 1e-5 set) | MuJoCo, us a pair | contacts a pair (MuJoCo) | ours / MuJoCo |',
             '|---|---|---|---|---|---|---|']
    for r in rows:
        mj = '-' if r['mujoco'] is None else f'{r["mujoco"] * 1e6:.2f}'
        ratio = '-' if r['mujoco'] is None else f'{r["ours"] / r["mujoco"]:.1f}'
        mjc = '-' if r['mj_contacts'] is None else f'{r["mj_contacts"]:.2f}'
        lines.append(f'| {r["case"]} | {r["ours"] * 1e6:.2f} | {r["contacts"]:.2f} | '
                     f'{r["deepest"]:.6e} | {mj} | {mjc} | {ratio} |')
    return '\n'.join(lines)


def main(argv=None) -> int:
    """Run the benchmark; print and write ``bench/out/contact_pairs.md``."""
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--quick', action='store_true', help='3 repetitions (7 without)')
    args = p.parse_args(argv)
    t0 = time.perf_counter()
    rows = run(3 if args.quick else 7)
    report.write_page(OUT, 'contact_pairs', 'Narrow phases by pair of kinds, beside MuJoCo',
                      args.quick, table(rows), t0)
    return 0


if __name__ == '__main__':
    sys.exit(main())
