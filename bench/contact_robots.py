"""
Contact with robots (issue 21): URDF robots standing and pushing, their cost and quality.

Scenes with joints take every contact step in Python (the compiled contact steps are for
free bodies), their LCPs solved by the compiled solve (but a servo scene's, whose
stepped operator is not symmetric), so these are the costs a robot scene pays today.
``dt`` 1 ms, gravity 9.81, a ground of friction 0.8 (the gantry's 0.4):

* **quadruped, exact drives**: ``test/urdf/quadruped.urdf`` (17.5 kg, four legs of a hip
  and a knee, ball feet) standing, its joints held by exact position drives;
* **quadruped, servos**: the same on PD servos (kp 500 N m/rad, kd 10 N m s/rad), settling
  as its servos' modes decay (a foot that stops within a step sticks);
* **ANYmal B, exact drives**: ``anymal_b_simple_description`` from example-robot-data
  (bench/requirements.txt; its URDF's collision boxes, cylinders and spheres; only the
  feet reach the ground), standing (HFE ±0.4, KFE ∓0.8), its base dropped 3 mm;
* **gantry pushing a box**: ``test/urdf/gantry_pusher.urdf``, its carriage on an exact
  velocity drive at 0.2 m/s pushing a 1 kg, 0.2 m box (friction 0.4) across the ground.

Reported per scene: the mean wall time of a step (``sim.step()`` one a call), the contact
LCPs' most iterations, their failures and largest residual (m/s), the deepest penetration
over the run's last half, how often a step's contact operator was stepped
(``stepped_responses`` a step: servos), and the scene's own error: for the standing robots the
ground's force sum against the weight (relative) and the largest body speed at the end
(rest); for the gantry the box's speed against the carriage's and the push against
``μ m g`` (relative).

Run: ``./dev.sh python bench/contact_robots.py [--quick]`` (``--quick``: 0.5 s runs, else
2 s). Prints the table and writes ``bench/out/contact_robots.md``.
"""

from __future__ import annotations

import argparse
from importlib import metadata
import math
from pathlib import Path
import sys
import time

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import report  # noqa: E402, I100

from rigid_body_sim.scene import scene_from_dict  # noqa: E402

OUT = Path(__file__).resolve().parent / 'out'
TEST_URDF = Path(__file__).resolve().parent.parent / 'test' / 'urdf'
ANYMAL = 'cmeel.prefix/share/example-robot-data/robots/anymal_b_simple_description/' \
    'robots/anymal.urdf'
G, DT = 9.81, 1e-3


def anymal_urdf():
    """Return ANYmal B's URDF in the installed example-robot-data, or None."""
    try:
        path = Path(metadata.distribution('example-robot-data').locate_file(ANYMAL))
    except metadata.PackageNotFoundError:
        return None
    return path if path.is_file() else None


def quadruped(mode: str):
    """Return the test quadruped standing on ``mode`` drives."""
    hip = 0.6
    targets = {}
    for leg in ('lf', 'rf', 'lh', 'rh'):
        targets[f'{leg}_hip'], targets[f'{leg}_knee'] = hip, -2.0 * hip
    group = {'name': 'legs', 'joints': list(targets), 'interface': 'position', 'mode': mode}
    if mode == 'servo':
        group.update(kp=500.0, kd=10.0)
    sim = scene_from_dict({
        'dt': DT, 'effects': {'gravity': {'g_world': [0.0, 0.0, -G]}},
        'ground': {'height': 0.0, 'friction': 0.8},
        'robots': [{'urdf': str(TEST_URDF / 'quadruped.urdf'),
                    'base_pose': {'xyz': [0.0, 0.0, 0.5 * math.cos(hip) + 0.03]},
                    'initial_positions': targets, 'collisions': True}],
        'command_groups': [group]}, str(TEST_URDF)).simulation
    sim.command_joints(targets)
    return sim


def anymal(path: Path):
    """Return ANYmal B standing on exact drives, its base 3 mm above its stance."""
    targets = {}
    for leg in ('LF', 'RF', 'LH', 'RH'):
        s = 1.0 if leg[1] == 'F' else -1.0
        targets[f'{leg}_HAA'], targets[f'{leg}_HFE'], targets[f'{leg}_KFE'] = \
            0.0, 0.4 * s, -0.8 * s
    sim = scene_from_dict({
        'dt': DT, 'effects': {'gravity': {'g_world': [0.0, 0.0, -G]}},
        'ground': {'height': 0.0, 'friction': 0.8},
        'robots': [{'urdf': str(path), 'base_pose': {'xyz': [0.0, 0.0, 0.50]},
                    'initial_positions': targets, 'collisions': True}],
        'command_groups': [{'name': 'legs', 'joints': list(targets),
                            'interface': 'position', 'mode': 'exact'}]},
        str(path)).simulation
    sim.command_joints(targets)
    return sim


def gantry():
    """Return the gantry about to push a box (its hand 0.05 m short of it)."""
    sim = scene_from_dict({
        'dt': DT, 'effects': {'gravity': {'g_world': [0.0, 0.0, -G]}},
        'ground': {'height': 0.0, 'friction': 0.4},
        'bodies': [{'name': 'box', 'mass': 1.0, 'inertia': {'box': [0.2] * 3},
                    'position_world': [0.2, 0.0, 0.1],
                    'shapes': [{'kind': 'box', 'size': [0.2] * 3, 'friction': 0.4}]}],
        'robots': [{'urdf': str(TEST_URDF / 'gantry_pusher.urdf'), 'effort_limits': False,
                    'collisions': {'friction': 0.0}}],
        'command_groups': [
            {'name': 'slide', 'joints': ['slide'], 'interface': 'velocity', 'mode': 'exact'},
            {'name': 'wrist', 'joints': ['wrist'], 'interface': 'position', 'mode': 'exact'}]},
        str(TEST_URDF)).simulation
    sim.command_joints({'slide': 0.2, 'wrist': 0.0})
    return sim


def run(name: str, sim, seconds: float) -> dict:
    """Step ``sim`` for ``seconds`` one step a call; return the table's row."""
    steps = int(round(seconds / DT))
    deepest, wall = 0.0, 0.0
    for k in range(steps):
        t0 = time.perf_counter()
        sim.step()
        wall += time.perf_counter() - t0
        if k >= steps // 2:
            deepest = max(deepest, float(np.max(sim.contact.detect(sim.state).depth,
                                                initial=0.0)))
    rep = sim.contacts()
    cnt = rep['counters']
    row = {'scene': name, 'step': wall / steps, 'contacts': len(rep['normal_force']),
           'iterations': cnt['lcp_iterations_max'], 'failures': cnt['lcp_failures'],
           'residual': cnt['complementarity_max'], 'depth': deepest,
           'stepped': cnt['stepped_responses'] / steps}
    if name.startswith('gantry'):
        box = sim.bodies.names.index('box')
        hand = [k for k, b in enumerate(rep['body_b']) if b == 'hand']
        push = float(rep['normal_force'][hand[0]]) if hand else 0.0
        row['error'] = (f'box speed − 0.2: {sim.state.vel_com_world[box, 0] - 0.2:+.1e} m/s; '
                        f'push / μmg − 1: {push / (0.4 * G) - 1.0:+.1e}')
    else:
        weight = float(np.sum(sim.bodies.mass)) * G
        force = np.sum(rep['normal_force'][:, None] * rep['normal'] + rep['friction_force'],
                       axis=0)
        speed = float(np.max(np.linalg.norm(sim.state.vel_com_world, axis=1)))
        row['error'] = (f'ground / weight − 1: {force[2] / weight - 1.0:+.1e}; '
                        f'fastest body: {speed:.1e} m/s')
    return row


def table(rows: list) -> str:
    """Markdown table of :func:`run`'s rows."""
    lines = ['| scene | step, ms | contacts | LCP iterations (most) | LCP failures | '
             'LCP residual, m/s | deepest, m | stepped operators a step | error |',
             '|---|---|---|---|---|---|---|---|---|']
    for r in rows:
        lines.append(f'| {r["scene"]} | {r["step"] * 1e3:.2f} | {r["contacts"]} | '
                     f'{r["iterations"]} | {r["failures"]} | {r["residual"]:.1e} | '
                     f'{r["depth"]:.1e} | {r["stepped"]:.2f} | {r["error"]} |')
    return '\n'.join(lines) + (
        '\n\nEvery step in Python (scenes with joints), its LCPs by the compiled solve '
        "where their operator is symmetric (the servos' stepped operators: the Python "
        'solve). "stepped operators a step": how '
        "often a step's contact operator was built from the step's own response (servos: "
        'a trial step per row; twice in a step where contacts turn to slip or stick). The '
        "servo quadruped is still settling at the end (its servos' modes decay about as "
        'e^{-4.5 t}: 1.4e-9 m/s at 4 s, test_contact_robots); its LCPs are solved (the '
        'fixed point, or Lemke pivoting where the fixed point drifts).')


def main(argv=None) -> int:
    """Run the benchmark; print and write ``bench/out/contact_robots.md``."""
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--quick', action='store_true', help='0.5 s runs instead of 2 s')
    args = p.parse_args(argv)
    t0 = time.perf_counter()
    seconds = 0.5 if args.quick else 2.0
    rows = [run('quadruped, exact drives', quadruped('exact'), seconds),
            run('quadruped, servos', quadruped('servo'), seconds)]
    path = anymal_urdf()
    if path is not None:
        rows.append(run('ANYmal B, exact drives', anymal(path), seconds))
    else:
        print('example-robot-data not installed: ANYmal B skipped (bench/requirements.txt)')
    rows.append(run('gantry pushing a box', gantry(), seconds))
    report.write_page(OUT, 'contact_robots', 'Contact with robots: cost and quality',
                      args.quick, table(rows), t0)
    return 0


if __name__ == '__main__':
    sys.exit(main())
