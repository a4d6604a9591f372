"""
Contact dynamics (issue 21): per-step cost, penetration and drift beside MuJoCo, same scenes.

Five scenes on a ground plane, ``dt`` 1 ms, gravity 9.81, each run side by side in
ours and MuJoCo 4, each with its defaults (ours: the ``lie_poisson2`` integrator,
second order, hard contact rows; MuJoCo: soft contacts with ``solref`` 0.02 s, the
pyramidal cone, the Newton solver, semi-implicit Euler, first order), from the same
state:

* **sphere drop**: a 0.1 m sphere of 1 kg dropped from 0.5 m (0.4 m of gap), no
  restitution, friction 0.5: it lands at 0.286 s and rests;
* **box slide**: a 0.2 m cube of 2 kg on the ground at 1 m/s along x, friction 0.5:
  it stops after ``v² / (2 μ g)`` = 0.1019 m;
* **10-box stack**: ten 0.1 m cubes of 1 kg stacked exactly, friction 0.8: it stands;
* **27 spheres poured into a box**: three layers of 0.05 m spheres of 1 kg (restitution
  0.3, friction 0.5) dropped into a box of four walls 0.37 m apart: they collapse onto
  each other and settle (tens of closures a step at first; ours locates those faster
  than the bounce speed, 1 cm/s);
* **100 spheres poured into a box**: the same, four layers of 25, walls 0.59 m apart
  (hundreds of closures a step while the pile settles);
* **1000 spheres poured into a box**: the same, ten layers of 100, walls 1.14 m apart,
  the first 0.3 s alone (:data:`PILE_SECONDS`: the fall and the first collapse, each
  step ours seconds): its pile is one island of thousands of contacts, which ours solves
  by its blocks alone (``SPARSE_CONTACTS``).

Reported per scene: the mean wall time of a step over the run (the whole step: detection,
contact forces, integration; ours with the compiled contact steps, up to 100 steps a call,
one a call, and in Python alone, and with ``rkmk4`` (fourth order, four force evaluations
a step) up to 100 steps a call but in the piles; ours up to 100 steps a call and MuJoCo
the fastest of :data:`REPEATS` runs taken alternately, but the piles'), the deepest
penetration over the whole run (ours: the deepest overlap any step ended with, its
counter ``end_depth``; MuJoCo's ``-contact.dist`` after each step) and their ratio, the
most depth or lift ours' projection passes left (its counter ``projection_left``: a
lift is a loaded contact left apart, not a penetration), and the scene's own error: the
sphere's rest height's offset, the slide's stop distance against ``v² / (2 μ g)``, the
stack's largest displacement of a box from where it started.

Run: ``./dev.sh python bench/contact_dynamics.py [--quick]`` (``bench/requirements.txt``
for MuJoCo; ``--quick``: 1 s runs, else 2 s). Prints the table and writes
``bench/out/contact_dynamics.md``.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path
import sys
import time

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import report  # noqa: E402, I100

from rigid_body_sim.core import CollisionShape, Gravity, RigidBody, Simulation  # noqa: E402

try:
    import mujoco
except ImportError:   # (bench/requirements.txt)
    mujoco = None

OUT = Path(__file__).resolve().parent / 'out'
G, DT = 9.81, 1e-3
#: The piles' scenes (spheres of radius 0.05 m poured into a box): their names by count.
PILES = {27: '27 spheres poured into a box', 100: '100 spheres poured into a box',
         1000: '1000 spheres poured into a box'}
#: The scenes run for less than the others' time, s.
PILE_SECONDS = {PILES[1000]: 0.3}
#: Steps per ``step(n)`` call in the batched runs.
CHUNK = 100
#: The scenes but the piles: ours (step(100)) and MuJoCo run alternately this many times,
#: the fastest of each kept (a shared machine's other load only ever adds time).
REPEATS = 5
#: Our integrator in the runs: the simulator's default (``Simulation``'s), as MuJoCo runs
#: with its own; :data:`FOURTH_ORDER` beside it.
INTEGRATOR = 'lie_poisson2'
FOURTH_ORDER = 'rkmk4'


def cube(half: float, mass: float) -> tuple:
    """Return a cube's principal moments."""
    return (mass * (2 * half) ** 2 / 6,) * 3


def scenes() -> dict:
    """Return ``{name: (bodies, shapes, mujoco body xml, friction)}`` of the five scenes."""
    out = {}
    r = 0.1
    out['sphere drop'] = (
        [RigidBody('s', 1.0, (0.4 * r * r,) * 3, position_world=(0, 0, 0.5))],
        [CollisionShape('sphere', 's', radius=r, friction=0.5)],
        f'<body pos="0 0 0.5"><freejoint/><geom type="sphere" size="{r}" mass="1"/></body>',
        0.5)
    h = 0.1
    out['box slide'] = (
        [RigidBody('b', 2.0, cube(h, 2.0), position_world=(0, 0, h),
                   linear_velocity_world=(1.0, 0, 0))],
        [CollisionShape('box', 'b', size=(2 * h,) * 3, friction=0.5)],
        f'<body pos="0 0 {h}"><freejoint/><geom type="box" size="{h} {h} {h}" mass="2"/>'
        '</body>', 0.5)
    h = 0.05
    out['10-box stack'] = (
        [RigidBody(f'b{k}', 1.0, cube(h, 1.0), position_world=(0, 0, h * (2 * k + 1)))
         for k in range(10)],
        [CollisionShape('box', f'b{k}', size=(2 * h,) * 3, friction=0.8) for k in range(10)],
        ''.join(f'<body pos="0 0 {h * (2 * k + 1)}"><freejoint/><geom type="box" '
                f'size="{h} {h} {h}" mass="1"/></body>' for k in range(10)), 0.8)
    for count, name in PILES.items():
        out[name] = pile(count)
    return out


def pile_wall(count: int) -> float:
    """Return how far the walls of a pile of ``count`` spheres stand from its centre, m."""
    return 0.5 * round(count ** (1 / 3)) * 2.2 * 0.05 + 0.02


def pile(count: int) -> tuple:
    """
    Return the scene of ``count`` spheres poured into a box of four walls.

    The spheres (radius 0.05 m, 1 kg, restitution 0.3, friction 0.5) start in a grid of
    ``round(count^(1/3))`` a side, layer on layer, 1.1 diameters apart, a little jittered;
    the walls stand 0.02 m outside the grid (:func:`pile_wall`).
    """
    r = 0.05
    side = round(count ** (1 / 3))
    half = 0.5 * side * 2.2 * r
    wall = pile_wall(count)
    rng = np.random.default_rng(1)
    spots = []
    for k in range(count):
        i, j, level = k % side, (k // side) % side, k // side // side
        jitter = 0.003 * rng.standard_normal(2)
        spots.append((-half + (i + 0.5) * 2.2 * r + jitter[0],
                      -half + (j + 0.5) * 2.2 * r + jitter[1], r + 0.02 + level * 2.2 * r))
    s2 = math.sqrt(0.5)
    walls = [CollisionShape('plane', None, position_body=pos, orientation_xyzw=q, friction=0.5,
                            name=name)
             for name, pos, q in (('x+', (wall, 0, 0), (0, -s2, 0, s2)),
                                  ('x-', (-wall, 0, 0), (0, s2, 0, s2)),
                                  ('y+', (0, wall, 0), (s2, 0, 0, s2)),
                                  ('y-', (0, -wall, 0), (-s2, 0, 0, s2)))]
    return (
        [RigidBody(f's{k}', 1.0, (0.4 * r * r,) * 3, position_world=p)
         for k, p in enumerate(spots)],
        walls + [CollisionShape('sphere', f's{k}', radius=r, friction=0.5, restitution=0.3)
                 for k in range(count)],
        ''.join(f'<geom type="plane" size="0 0 1" pos="{x} {y} 0" zaxis="{a} {b} 0"/>'
                for x, y, a, b in ((wall, 0, -1, 0), (-wall, 0, 1, 0), (0, wall, 0, -1),
                                   (0, -wall, 0, 1)))
        + ''.join(f'<body pos="{p[0]} {p[1]} {p[2]}"><freejoint/><geom type="sphere" '
                  f'size="{r}" mass="1"/></body>'
                  for p in spots), 0.5)


def run_ours(bodies, shapes, friction, steps, compiled=True, chunk=1,
             integrator=INTEGRATOR) -> dict:
    """
    Run our simulation; return cost, the deepest overlap a step ended with, final state.

    ``compiled`` False: every step in Python (``ContactSteps.compiled``); ``chunk``:
    steps per ``step(n)`` call. The depth is the counter ``end_depth``: every step's end,
    the whole run.
    """
    sim = Simulation(bodies, [Gravity()], integrator=integrator, dt=DT,
                     shapes=[CollisionShape('plane', None, friction=friction)] + shapes)
    sim.contact.compiled = compiled
    p0 = sim.state.pos_com_world.copy()
    wall = 0.0
    for k in range(0, steps, chunk):
        t0 = time.perf_counter()
        sim.step(min(chunk, steps - k))
        wall += time.perf_counter() - t0
    return {'step': wall / steps, 'depth': sim.contact.counters['end_depth'],
            'pos': sim.state.pos_com_world.copy(),
            'p0': p0, 'failures': sim.contact.counters['lcp_failures'],
            'sparse': sim.contact.counters['lcp_sparse'],
            'left': sim.contact.counters['projection_left'],
            'compiled': sim.contact.counters['compiled_steps'] / steps}


def run_mujoco(body_xml, friction, steps, velocity=None) -> dict:
    """Run MuJoCo on the same scene; return cost, the deepest depth of its run, final state."""
    xml = (f'<mujoco><option timestep="{DT}" gravity="0 0 -{G}"/><default><geom '
           f'friction="{friction} 0.005 0.0001"/></default><worldbody>'
           f'<geom type="plane" size="0 0 1"/>{body_xml}</worldbody></mujoco>')
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    if velocity is not None:
        data.qvel[0:3] = velocity
    mujoco.mj_forward(model, data)
    p0 = data.xpos[1:].copy()
    deepest, wall = 0.0, 0.0
    for k in range(steps):
        t0 = time.perf_counter()
        mujoco.mj_step(model, data)
        wall += time.perf_counter() - t0
        if data.ncon:
            deepest = max(deepest, float(-np.min(data.contact.dist[:data.ncon])))
    return {'step': wall / steps, 'depth': deepest, 'pos': data.xpos[1:].copy(), 'p0': p0,
            'failures': 0}


def error(name: str, r: dict) -> float:
    """Return how far run ``r`` is from its scene's closed form, m (module docstring)."""
    if name == 'sphere drop':
        return float(r['pos'][0, 2] - 0.1)
    if name == 'box slide':
        return float(r['pos'][0, 0] - r['p0'][0, 0] - 1.0 / (2 * 0.5 * G))
    for count, pile_name in PILES.items():
        if name == pile_name:
            pos = r['pos']
            return float(max(np.max(np.abs(pos[:, :2])) - (pile_wall(count) - 0.05),
                             np.max(0.05 - pos[:, 2])))
    return float(np.max(np.linalg.norm(r['pos'] - r['p0'], axis=1)))


def run(seconds: float) -> list:
    """Run each scene in both; return the table's rows."""
    rows = []
    # The compiled kernels load from numba's cache at their first call (about 0.1 s):
    # outside the timed runs.
    bodies, shapes, _, friction = scenes()['box slide']
    run_ours(bodies, shapes, friction, 3)
    for name, (bodies, shapes, body_xml, friction) in scenes().items():
        pile = name in PILES.values()
        steps = int(round(min(seconds, PILE_SECONDS.get(name, seconds)) / DT))
        ours_runs, mj_runs, fourth = [], [], []
        for _ in range(1 if pile else REPEATS):   # (a pile: tens of seconds a run, once)
            ours_runs.append(run_ours(bodies, shapes, friction, steps, chunk=CHUNK))
            if not pile:
                fourth.append(run_ours(bodies, shapes, friction, steps, chunk=CHUNK,
                                       integrator=FOURTH_ORDER)['step'])
            if mujoco is not None:
                mj_runs.append(run_mujoco(body_xml, friction, steps,
                                          (1.0, 0.0, 0.0) if name == 'box slide' else None))
        # (Each run of a scene is the same arithmetic: only the time differs.)
        ours = min(ours_runs, key=lambda r: r['step'])
        ours['fourth'] = min(fourth) if fourth else None
        mj = min(mj_runs, key=lambda r: r['step']) if mj_runs else None
        # (The 100 spheres one step a call: the step(100) run's cost again, a step's
        # hundreds of milliseconds dwarfing the call's overhead; the piles in Python
        # alone: minutes, every impact located. Neither run.)
        ours['one'] = None if name in (PILES[100], PILES[1000]) else run_ours(
            bodies, shapes, friction, steps)['step']
        ours['python'] = None if pile else run_ours(
            bodies, shapes, friction, steps, compiled=False)['step']
        rows.append({'scene': name, 'ours': ours, 'mj': mj, 'seconds': steps * DT})
        print(f'  {name}: ours {ours["step"] * 1e6:.0f} us/step, depth {ours["depth"]:.1e} m, '
              f'error {error(name, ours):+.2e} m'
              + ('' if mj is None else f'; MuJoCo {mj["step"] * 1e6:.1f} us/step, depth '
                 f'{mj["depth"]:.1e} m, error {error(name, mj):+.2e} m'), flush=True)
    return rows


def table(rows: list) -> str:
    """Markdown table of :func:`run`."""
    lines = ['| scene | run, s | ours, step(100), us/step | ours, step(), us/step | '
             'ours, Python path, us/step | ours, rkmk4, step(100), us/step | '
             'steps compiled | MuJoCo, us/step | '
             'ours step(100) / MuJoCo | deepest (ours), m | deepest (MuJoCo), m | '
             'deepest: MuJoCo / ours | '
             'error (ours), m | error (MuJoCo), m | ours: LCPs failed, by blocks | '
             'ours: depth or lift its passes left, m |',
             '|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|']
    for r in rows:
        o, m = r['ours'], r['mj']
        mj = ('-', '-', '-', '-', '-') if m is None else (
            f'{m["step"] * 1e6:.1f}', f'{o["step"] / m["step"]:.1f}', f'{m["depth"]:.1e}',
            f'{error(r["scene"], m):+.2e}',
            f'{m["depth"] / o["depth"]:.1e}' if o['depth'] > 0.0 else 'ours 0')
        python = '-' if o['python'] is None else f'{o["python"] * 1e6:.0f}'
        one = '-' if o['one'] is None else f'{o["one"] * 1e6:.1f}'
        fourth = '-' if o['fourth'] is None else f'{o["fourth"] * 1e6:.1f}'
        lines.append(f'| {r["scene"]} | {r["seconds"]:g} | {o["step"] * 1e6:.1f} | '
                     f'{one} | '
                     f'{python} | {fourth} | {100 * o["compiled"]:.1f} % | {mj[0]} | '
                     f'{mj[1]} | {o["depth"]:.1e} | {mj[2]} | {mj[4]} | '
                     f'{error(r["scene"], o):+.2e} | '
                     f'{mj[3]} | {o["failures"]}, {o["sparse"]} | {o["left"]:.1e} |')
    return '\n'.join(lines) + (
        "\n\nErrors: the sphere's rest height offset, the slide's stop distance less "
        "`v² / (2 μ g)`, the stack's largest box displacement, the piles' deepest excursion "
        'of a sphere beyond a wall or the ground (its centre past `wall − r`; negative: '
        f'inside). Ours runs its default integrator (`{INTEGRATOR}`, second order; '
        f'`{FOURTH_ORDER}`, fourth order, four force evaluations a step, in its own '
        'column, not run on the piles: in the first three scenes the two agree to rounding, '
        'their forces constant over a step), MuJoCo its own (semi-implicit Euler, first '
        'order). Ours is exact in the first three to '
        "the step's first-order stop (the slide: at most `μ g dt² / 2` = 2.5e-6 m) and to "
        'rounding. Ours three ways: `step(100)` (the compiled kernel takes up to 100 steps a '
        "call), `step()` one step a call (a node's loop: the Python call and its checks each "
        'step; not run on the 100 and 1000 spheres, whose steps cost a thousand times the '
        'call), and '
        'every step in Python (`ContactSteps.compiled = False`: the reference, its LCPs '
        'solved in Python too; scenes with joints step in Python, their LCPs by the '
        'compiled solve; not run on the piles). "steps compiled": the '
        'share the kernel took; '
        'the rest (a row no force moves) ran in Python. '
        'MuJoCo: one `mj_step` call a step. Ours `step(100)` and MuJoCo: the fastest of '
        f'{REPEATS} runs taken alternately, the piles one run each (the machine is shared: '
        'its other load only adds time). "LCPs failed, by blocks": ours\' contact solves '
        'that stopped short of their tolerance (counted, never hidden), and the solves by '
        "an island's blocks: of islands of more than 500 contacts, and of those of more "
        "than 32 that the fixed point and Newton's method left (in place of pivoting). "
        '"deepest": over the whole run, impacts included; ours the deepest overlap any '
        "step ended with (its counter `end_depth`: every step's end, after its projection), "
        "MuJoCo's `-contact.dist` after every step (its contacts at the step's start). "
        '"depth or lift its passes left": the most any step\'s projection passes did not '
        "remove (ours' counter `projection_left`: an overlap, or a loaded contact left apart, "
        'which is not a penetration; counted, never hidden).')


def main(argv=None) -> int:
    """Run the benchmark; print and write ``bench/out/contact_dynamics.md``."""
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--quick', action='store_true', help='1 s runs instead of 2 s')
    args = p.parse_args(argv)
    t0 = time.perf_counter()
    rows = run(1.0 if args.quick else 2.0)
    report.write_page(OUT, 'contact_dynamics', 'Contact dynamics: cost, penetration and '
                      'error beside MuJoCo', args.quick, table(rows), t0)
    return 0


if __name__ == '__main__':
    sys.exit(main())
