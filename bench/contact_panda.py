"""
The Franka Panda pushing a box across the ground, in ours and in MuJoCo side by side (issue 21).

The robot is example-robot-data's ``panda.urdf`` (bench/requirements.txt), its fingers
fixed as in ``bench/robot_panda.py``, with its ``<collision>`` geometry: STL meshes
for the links and the hand (each simulated as its convex hull, in both simulators:
ours by :mod:`rigid_body_sim.core.hulls`, MuJoCo's own), boxes for the fingers. Its
base is welded to the world; its links do not meet each other (ours: Gazebo's default;
MuJoCo: by ``contype``/``conaffinity``). The arm holds the pose
q = (ω t, 0.5, 0, −2.3, 0, 2.85, π/4), its fingertips 2.1 cm above the ground, and turns
about its base joint at ω = 0.5 rad/s: the right fingertip sweeps at about 0.27 m/s
into a 0.5 kg box (0.1 × 0.1 × 0.04 m, lying on the ground 0.53 m from the base, 0.35 rad
ahead) and pushes it along. ``dt`` 1 ms, gravity 9.81, friction 0.5 at the ground, the
pusher's friction 0 or 0.5 (two variants).

* Ours: the joints on exact drives (joint 1 an exact velocity drive at ω, the others
  exact position drives), contact as hard rows (``rkmk4``), every step in Python (a
  scene with joints), its LCPs by the compiled solve.
* MuJoCo 4.0: position actuators on the 7 joints (kp 1e4 N m/rad, kv 200 N m s/rad;
  joint 1's target ramps as ω t), ``implicitfast`` (its recommended integrator for
  actuated robots), soft contacts at their defaults; friction combined as ours (the
  robot's geoms take priority at their contacts).

Reported per variant: the mean wall time of a step (ours ``sim.step()``, MuJoCo
``mj_step`` with its control set: each a Python call), the box's travel and its speed
at the end against the fingertip's (ω r), the deepest penetration over the push (box in
the ground, and the pusher in the box), and ours' LCP failures and largest
complementarity residual (m/s).

Run: ``./dev.sh python bench/contact_panda.py [--quick]`` (``--quick``: 0.9 s, else
1.5 s). Prints the table and writes ``bench/out/contact_panda.md``.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path
import re
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import report  # noqa: E402, I100
from robot_panda import ARM, benchmark_urdf, panda_urdf  # noqa: E402, I100

from rigid_body_sim.scene import scene_from_dict  # noqa: E402, I100

OUT = Path(__file__).resolve().parent / 'out'
G, DT = 9.81, 1e-3
#: The arm's pose (joint 1 turns from 0 at OMEGA), and the box.
POSE = (0.0, 0.5, 0.0, -2.3, 0.0, 2.85, math.pi / 4)
OMEGA = 0.5
BOX_SIZE, BOX_MASS, BOX_RADIUS, BOX_ANGLE = (0.1, 0.1, 0.04), 0.5, 0.53, 0.35
GROUND_FRICTION = 0.5
KP, KV = 1e4, 200.0


def box_pose() -> tuple:
    """Return the box's centre and its yaw."""
    return (BOX_RADIUS * math.cos(BOX_ANGLE), BOX_RADIUS * math.sin(BOX_ANGLE),
            0.5 * BOX_SIZE[2]), BOX_ANGLE


def ours(urdf: Path, pusher_friction: float):
    """Return our simulation of the push."""
    centre, yaw = box_pose()
    sim = scene_from_dict({
        'dt': DT, 'integrator': 'rkmk4', 'effects': {'gravity': {'g_world': [0.0, 0.0, -G]}},
        'ground': {'friction': GROUND_FRICTION},
        'bodies': [{'name': 'box', 'mass': BOX_MASS, 'inertia': {'box': list(BOX_SIZE)},
                    'position_world': list(centre), 'orientation_rpy': [0.0, 0.0, yaw],
                    'shapes': [{'kind': 'box', 'size': list(BOX_SIZE),
                                'friction': GROUND_FRICTION}]}],
        'robots': [{'urdf': str(urdf), 'fixed_base': True, 'limits': False,
                    'effort_limits': False, 'collisions': {'friction': pusher_friction},
                    'initial_positions': dict(zip(ARM, POSE))}],
        'command_groups': [
            {'name': 'yaw', 'joints': [ARM[0]], 'interface': 'velocity', 'mode': 'exact'},
            {'name': 'arm', 'joints': list(ARM[1:]), 'interface': 'position',
             'mode': 'exact'}]}, str(urdf)).simulation
    sim.command_joints({ARM[0]: OMEGA, **dict(zip(ARM[1:], POSE[1:]))})
    return sim


def run_ours(urdf: Path, pusher_friction: float, steps: int) -> dict:
    """Run ours; return the row's measures."""
    sim = ours(urdf, pusher_friction)
    b = sim.bodies.names.index('box')
    shapes = sim.contact.detector.shapes
    p0 = sim.state.pos_com_world[b].copy()
    wall, ground_depth, push_depth = 0.0, 0.0, 0.0
    for _ in range(steps):
        t0 = time.perf_counter()
        sim.step()
        wall += time.perf_counter() - t0
        d = sim.contact.detect(sim.state)
        for a, c, depth in zip(d.shape_a, d.shape_b, d.depth):
            names = (shapes[a].name, shapes[c].name)
            if 'ground' in names:
                ground_depth = max(ground_depth, float(depth))
            else:
                push_depth = max(push_depth, float(depth))
    cnt = sim.contacts()['counters']
    return {'step': wall / steps, 'travel': float(np.linalg.norm(
        sim.state.pos_com_world[b] - p0)), 'speed': float(np.linalg.norm(
            sim.state.vel_com_world[b])), 'ground': ground_depth, 'push': push_depth,
            'failures': cnt['lcp_failures'], 'residual': cnt['complementarity_max'],
            'solves': cnt['lcp_solves']}


def mujoco_model(xml: str, mesh_dir: Path, pusher_friction: float):
    """Return MuJoCo's model: the URDF with its collision meshes, a floor, the box, servos."""
    import mujoco
    out = re.sub(r'<visual\b.*?</visual>', '', xml, flags=re.S)
    compiler = (f'<mujoco><compiler meshdir="{mesh_dir}" strippath="true" '
                f'discardvisual="true" fusestatic="true" balanceinertia="false" '
                f'inertiafromgeom="false"/></mujoco>')
    out = re.sub(r'(<robot\b[^>]*>)', lambda m: m.group(1) + compiler, out, count=1)
    spec = mujoco.MjSpec.from_string(out)
    spec.option.timestep = DT
    spec.option.gravity = [0.0, 0.0, -G]
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    for geom in spec.geoms:   # the robot's: they meet the box and the floor, not each other
        geom.contype, geom.conaffinity, geom.priority = 2, 1, 1
        geom.friction = [pusher_friction, 0.005, 0.0001]
    floor = spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_PLANE, size=[2.0, 2.0, 0.1])
    floor.contype, floor.conaffinity = 3, 3
    floor.friction = [GROUND_FRICTION, 0.005, 0.0001]
    centre, yaw = box_pose()
    body = spec.worldbody.add_body(name='box', pos=list(centre),
                                   quat=[math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)])
    body.add_freejoint()
    a, b, c = BOX_SIZE   # (inertia as ours: the URDF's compiler takes none from geoms)
    body.mass, body.explicitinertial = BOX_MASS, True
    body.ipos, body.iquat = [0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0]   # (else the body's pose)
    body.inertia = [BOX_MASS * (b * b + c * c) / 12, BOX_MASS * (a * a + c * c) / 12,
                    BOX_MASS * (a * a + b * b) / 12]
    g = body.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.5 * s for s in BOX_SIZE])
    g.contype, g.conaffinity = 3, 3
    g.friction = [GROUND_FRICTION, 0.005, 0.0001]
    for joint in ARM:
        act = spec.add_actuator(name=joint, target=joint,
                                trntype=mujoco.mjtTrn.mjTRN_JOINT)
        act.set_to_position(kp=KP, kv=KV)
    model = spec.compile()
    model.jnt_limited[:] = 0
    model.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_AUTORESET)
    return model


def run_mujoco(xml: str, mesh_dir: Path, pusher_friction: float, steps: int) -> dict:
    """Run MuJoCo; return the row's measures."""
    import mujoco
    model = mujoco_model(xml, mesh_dir, pusher_friction)
    data = mujoco.MjData(model)
    qadr = [model.jnt_qposadr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, j)]
            for j in ARM]
    data.qpos[qadr] = POSE
    data.ctrl[:] = POSE
    mujoco.mj_forward(model, data)
    box = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, 'box')
    free = model.jnt_dofadr[model.body_jntadr[box]]   # (its free joint's linear velocity)
    floor = {k for k in range(model.ngeom) if model.geom_type[k] == mujoco.mjtGeom.mjGEOM_PLANE}
    p0 = data.xpos[box].copy()
    wall, ground_depth, push_depth = 0.0, 0.0, 0.0
    for k in range(steps):
        t0 = time.perf_counter()
        data.ctrl[0] = OMEGA * (k + 1) * DT
        mujoco.mj_step(model, data)
        wall += time.perf_counter() - t0
        for c in data.contact[:data.ncon]:
            if c.geom1 in floor or c.geom2 in floor:
                ground_depth = max(ground_depth, float(-c.dist))
            else:
                push_depth = max(push_depth, float(-c.dist))
    return {'step': wall / steps, 'travel': float(np.linalg.norm(data.xpos[box] - p0)),
            'speed': float(np.linalg.norm(data.qvel[free:free + 3])), 'ground': ground_depth,
            'push': push_depth, 'failures': None, 'residual': None, 'solves': None,
            'tracking': float(np.max(np.abs(data.qpos[qadr[1:]] - POSE[1:])))}


def table(rows: list) -> str:
    """Markdown table of the rows."""
    lines = ['| simulator | pusher μ | step, ms | box travel, m | box speed, m/s | '
             'box in ground, m | pusher in box, m | LCP failures / solves | '
             'LCP residual, m/s |', '|---|---|---|---|---|---|---|---|---|']
    for r in rows:
        fail = '—' if r['failures'] is None else f'{r["failures"]} / {r["solves"]}'
        res = '—' if r['residual'] is None else f'{r["residual"]:.1e}'
        lines.append(f'| {r["engine"]} | {r["mu"]} | {r["step"] * 1e3:.3f} | '
                     f'{r["travel"]:.4f} | {r["speed"]:.3f} | {r["ground"]:.1e} | '
                     f'{r["push"]:.1e} | {fail} | {res} |')
    tip = OMEGA * math.hypot(BOX_RADIUS, 0.0)
    return '\n'.join(lines) + (
        f'\n\nThe fingertip sweeps at about {tip:.3f} m/s (ω r at the box). Penetrations '
        'over the whole run (ours: contacts found after each step, including those '
        "within the margin at negative depth; MuJoCo: its contacts' distances). "
        "MuJoCo's servos track the arm's other joints within "
        + ', '.join(f'{r["tracking"]:.1e} rad (μ {r["mu"]})' for r in rows if 'tracking' in r)
        + '; ours hold them exactly.')


def main(argv=None) -> int:
    """Run the benchmark; print and write ``bench/out/contact_panda.md``."""
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--quick', action='store_true', help='0.9 s runs instead of 1.5 s')
    args = p.parse_args(argv)
    t0 = time.perf_counter()
    steps = int(round((0.9 if args.quick else 1.5) / DT))
    source = panda_urdf()
    xml = benchmark_urdf(source.read_text())
    mesh_dir = source.parent.parent / 'meshes' / 'collision'
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        # Ours reads the URDF from a file beside the original's folder layout, so that its
        # package:// meshes resolve (the folder named example-robot-data above it).
        urdf = source.parent / 'panda_bench_fixed_fingers.urdf'
        try:
            urdf.write_text(xml)
        except OSError:
            urdf = Path(tmp) / 'panda.urdf'
            urdf.write_text(xml)
        for mu in (0.0, 0.5):
            rows.append({'engine': 'ours', 'mu': mu, **run_ours(urdf, mu, steps)})
            rows.append({'engine': 'MuJoCo', 'mu': mu,
                         **run_mujoco(xml, mesh_dir, mu, steps)})
    report.write_page(OUT, 'contact_panda', 'The Panda pushing a box, beside MuJoCo',
                      args.quick, table(rows), t0)
    return 0


if __name__ == '__main__':
    sys.exit(main())
