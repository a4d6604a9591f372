"""
What accuracy costs, ours beside MuJoCo: work-precision lines and the cheapest set-up per target.

Issue 9's study. The scenes of ``bench/mujoco_peer.py``, each built the same way in
both simulators, swept over step sizes (and, for ours, the accuracy knob at a fixed
dt), each run timed in a Python loop that steps once and reads the state, as a
node does (median of ``--reps`` interleaved repetitions):

1. free body (moments 1, 2, 3; Ω0 = (0.01, 2, 0.01): the intermediate-axis flip;
   10 s): the relative error of Ω(T) against DOP853 at rtol 1e-13;
2. ball-joint pendulum (rod 1 m) released at 60°, 90° and 120° (2.5 periods): the
   relative error of the period against ``4 sqrt(L/g) K(sin²(θ0/2))``; MuJoCo with
   its ``connect`` equality (soft) at its default and its stiffest settings, and
   with a ``ball`` joint (joint coordinates);
3. planar hinge chains of 2, 10 and 50 links (0.1 m, 1 kg, released horizontal;
   2 s, 2 s and 1 s): the worst energy error over the run, over ``m g l N²/2``.
   MuJoCo integrates joint coordinates, we integrate bodies under constraints;
4. heavy top (0.5 kg, centre of mass 0.1 m from the tip, moments 2e-3, 2e-3, 3e-3,
   tilted 20°, spinning at 50 rad/s; 1 s): the centre of mass at T against DOP853
   of the same model at rtol 1e-13, over 0.1 m; MuJoCo with a ``ball`` joint and
   with a ``connect`` equality at its default and stiffest settings;
5. four-bar linkage (``mechanisms.four_bar``, released at rest; 1 s): the crank
   angle at T against DOP853 of the same model (rad); MuJoCo with the crank and the
   coupler nested on hinges, the rocker on its own, the loop closed by ``connect``.

For each scene and accuracy target (1e-2, 1e-4, 1e-6, 1e-8) the table gives the
cheapest set-up of each simulator that reaches it (wall time per simulated second)
and the ratio of the two.

Run: ``python bench/accuracy_study.py [--quick]`` in the environment of ``./dev.sh``
with ``bench/requirements.txt`` installed (``./dev.sh bench`` does both). Writes
``docs/accuracy_study.md`` and ``docs/accuracy_study.png`` (committed: the README links
them) headed by ``report.header()``, the machine, versions, commit and date (``--quick``:
to ``bench/out``).
"""

from __future__ import annotations

import argparse
from pathlib import Path
import sys

import numpy as np
from rigid_body_sim.core import Constraint, Gravity, RigidBody, Simulation
from rigid_body_sim.core.mechanisms import rod
from rigid_body_sim.core.reference import dop853_trajectory, free_body_reference

sys.path.insert(0, str(Path(__file__).resolve().parent))
import mujoco_peer as peer  # noqa: E402, I100
from report import header  # noqa: E402

DOCS = Path(__file__).resolve().parents[1] / 'docs'
TARGETS = (1e-2, 1e-4, 1e-6, 1e-8)
OURS = ('symplectic_euler', 'lie_poisson2', 'lie_poisson4', 'rkmk4')


def _knob(build, integrator: str, dt: float, tolerance: float):
    def make():
        sim = build(integrator, dt)
        sim.set_tolerance(tolerance)
        return sim
    return make


# -- scenes: each returns rows {scene, engine, label, family, dt, tol, cost, err} ------------


def free_body(dts, tolerances, reps, duration=10.0) -> list:
    moments = np.array(peer.FREE_MOMENTS)

    def build(name, dt):
        return Simulation([RigidBody('b', 1.0, peer.FREE_MOMENTS,
                                     angular_velocity_body=peer.FREE_OMEGA0)], [], name, dt)

    def init(model, data):
        data.qvel[3:6] = peer.FREE_OMEGA0

    body = ('    <body name="b">\n      <freejoint/>\n'
            f'      <inertial pos="0 0 0" mass="1" diaginertia="{peer.nums(moments)}"/>'
            '\n    </body>\n')
    refs: dict = {}

    def error(v, rec, t_end):
        # The reference at the time the run ended (n dt, not always `duration`).
        if t_end not in refs:
            refs[t_end] = free_body_reference(moments, peer.FREE_OMEGA0, [0.0, 0.0, 0.0, 1.0],
                                              [t_end], rtol=1e-13, atol=1e-13)[0][-1]
        w_ref = refs[t_end]
        if v.engine == 'ours':
            R = peer.rot(rec['quat'][-1:])
            w = np.einsum('nji,nj->ni', R, rec['omega'][-1:])[0]
        else:
            w = rec['qvel'][-1, 3:6]
        return float(np.linalg.norm(w - w_ref) / np.linalg.norm(w_ref))

    runs = []
    for dt in dts:
        vs = [peer.Variant('ours', f'{name} dt {dt:g}', peer.run_ours(
            lambda name=name, dt=dt: build(name, dt), 'b')) for name in OURS]
        vs += [peer.Variant('MuJoCo', f'{mj} dt {dt:g}', peer.run_mujoco(
            peer.mjcf('free_body', dt, mj, 0.0, body), init)) for mj in ('RK4', 'Euler')]
        runs.append((dt, None, vs))
    dt0 = dts[0]
    for tol in tolerances:
        vs = [peer.Variant('ours', f'{name} knob {tol:g}', peer.run_ours(
            _knob(build, name, dt0, tol), 'b')) for name in ('rkmk4', 'lie_poisson4')]
        runs.append((dt0, tol, vs))
    return _sweep('free body', runs, duration, reps, lambda v, rec, dt, t: error(v, rec, t))


def pendulum(theta_deg: float, dts, tolerances, reps) -> list:
    geo = peer.pendulum_geometry(np.radians(theta_deg))
    duration = 2.5 * geo['period']
    scene = f'pendulum {theta_deg:g}°'

    def build(name, dt):
        body = rod('rod', np.zeros(3), geo['direction'], peer.PEND_LENGTH, peer.PEND_MASS)
        return Simulation([body], [Gravity((0.0, 0.0, -peer.G))], name, dt,
                          [Constraint('pivot', 'ball', 'rod', None,
                                      anchor_world=[0.0, 0.0, 0.0])])

    runs = []
    for dt in dts:
        stiff = peer.mj_stiffest(dt)
        vs = [peer.Variant('ours', f'{name} dt {dt:g}',
                           peer.run_ours(lambda name=name, dt=dt: build(name, dt), 'rod'))
              for name in OURS]
        vs += [peer.Variant('MuJoCo', f'RK4, connect, default dt {dt:g}',
                            peer.run_mujoco(peer.pendulum_connect_xml(geo, dt, 'RK4'))),
               peer.Variant('MuJoCo', f'RK4, connect, stiffest dt {dt:g}',
                            peer.run_mujoco(peer.pendulum_connect_xml(geo, dt, 'RK4', *stiff))),
               peer.Variant('MuJoCo', f'implicitfast, connect, default dt {dt:g}',
                            peer.run_mujoco(peer.pendulum_connect_xml(geo, dt, 'implicitfast'))),
               peer.Variant('MuJoCo', f'RK4, ball joint dt {dt:g}',
                            peer.run_mujoco(peer.pendulum_ball_xml(geo, dt, 'RK4')))]
        runs.append((dt, None, vs))
    # The knob at 100 Hz, a common node rate. (The period comes from linearly
    # interpolated zero crossings of states dt apart: at dt = 3e-2 that floors the
    # measured error near 1e-6, at 1e-2 near 1e-8, for both simulators.)
    dt0 = 1e-2
    for tol in tolerances:
        vs = [peer.Variant('ours', f'{name} knob {tol:g}', peer.run_ours(
            _knob(build, name, dt0, tol), 'rod')) for name in ('rkmk4', 'lie_poisson4')]
        runs.append((dt0, tol, vs))
    return _sweep(scene, runs, duration, reps,
                  lambda v, rec, dt, t: peer.pendulum_analysis(geo, dt, v, rec)['err'])


# The heavy top: a symmetric top on a ball joint at its tip, tilted 20°, spinning.
TOP_MASS, TOP_LENGTH, TOP_MOMENTS, TOP_SPIN = 0.5, 0.1, (2e-3, 2e-3, 3e-3), 50.0
TOP_TILT = np.radians(20.0)


def heavy_top(dts, tolerances, reps, duration=1.0) -> list:
    """Centre-of-mass position at T against DOP853 of the same model, over the length."""
    scene = 'heavy top'
    axis = np.array([np.sin(TOP_TILT), 0.0, np.cos(TOP_TILT)])
    quat_xyzw = np.array([0.0, np.sin(TOP_TILT / 2), 0.0, np.cos(TOP_TILT / 2)])
    quat_wxyz = np.roll(quat_xyzw, 1)

    def build(name, dt):
        body = RigidBody('top', TOP_MASS, TOP_MOMENTS, position_world=TOP_LENGTH * axis,
                         orientation_xyzw=quat_xyzw,
                         angular_velocity_body=(0.0, 0.0, TOP_SPIN))
        return Simulation([body], [Gravity((0.0, 0.0, -peer.G))], name, dt,
                          [Constraint('tip', 'ball', 'top', None,
                                      anchor_world=[0.0, 0.0, 0.0])])

    refs: dict = {}

    def reference(t_end):
        if t_end not in refs:
            refs[t_end] = dop853_trajectory(build('rkmk4', dts[0]), [t_end], rtol=1e-13,
                                            atol=1e-13)[0].pos_com_world[0]
        return refs[t_end]
    inertia = peer.nums(TOP_MOMENTS)
    ball = (f'    <body name="top" pos="0 0 0" quat="{peer.nums(quat_wxyz)}">\n'
            '      <joint type="ball" pos="0 0 0"/>\n'
            f'      <inertial pos="0 0 {TOP_LENGTH!r}" mass="{TOP_MASS!r}" '
            f'diaginertia="{inertia}"/>\n    </body>\n')
    free = (f'    <body name="top" pos="{peer.nums(TOP_LENGTH * axis)}" '
            f'quat="{peer.nums(quat_wxyz)}">\n      <freejoint/>\n'
            f'      <inertial pos="0 0 0" mass="{TOP_MASS!r}" diaginertia="{inertia}"/>\n'
            '    </body>\n')

    def connect(dt, stiff):
        params = ''
        if stiff:
            (tc, dr), imp = peer.mj_stiffest(dt)
            params = f' solref="{tc!r} {dr!r}" solimp="{peer.nums(imp)}"'
        return f'    <connect body1="top" anchor="0 0 {-TOP_LENGTH!r}"{params}/>\n'

    def init_ball(model, data):
        data.qvel[:] = (0.0, 0.0, TOP_SPIN)

    def init_free(model, data):
        data.qvel[3:6] = (0.0, 0.0, TOP_SPIN)   # body axes

    def error(v, rec, t_end):
        if v.engine == 'ours':
            com = rec['pos'][-1]
        else:
            com = peer.mj_replay(rec['model'], rec['qpos'][-1:], rec['qvel'][-1:],
                                 1)['xipos'][0]
        return float(np.linalg.norm(com - reference(t_end)) / TOP_LENGTH)

    runs = []
    for dt in dts:
        vs = [peer.Variant('ours', f'{name} dt {dt:g}', peer.run_ours(
            lambda name=name, dt=dt: build(name, dt), 'top')) for name in OURS]
        vs += [peer.Variant('MuJoCo', f'RK4, ball joint dt {dt:g}', peer.run_mujoco(
                   peer.mjcf('top', dt, 'RK4', peer.G, ball), init_ball)),
               peer.Variant('MuJoCo', f'RK4, connect, default dt {dt:g}', peer.run_mujoco(
                   peer.mjcf('top', dt, 'RK4', peer.G, free, connect(dt, False)),
                   init_free)),
               peer.Variant('MuJoCo', f'RK4, connect, stiffest dt {dt:g}', peer.run_mujoco(
                   peer.mjcf('top', dt, 'RK4', peer.G, free, connect(dt, True)),
                   init_free))]
        runs.append((dt, None, vs))
    for tol in tolerances:
        vs = [peer.Variant('ours', f'{name} knob {tol:g}', peer.run_ours(
            _knob(build, name, dts[0], tol), 'top')) for name in ('rkmk4', 'lie_poisson4')]
        runs.append((dts[0], tol, vs))
    return _sweep(scene, runs, duration, reps, lambda v, rec, dt, t: error(v, rec, t))


def _rod_frame(direction: np.ndarray) -> np.ndarray:
    """Return the rotation (3, 3) of ``mechanisms.rod``'s body frame: x along the rod."""
    x = direction / np.linalg.norm(direction)
    helper = np.eye(3)[np.argmin(np.abs(x))]
    y = np.cross(x, helper)
    y /= np.linalg.norm(y)
    return np.column_stack([x, y, np.cross(x, y)])


def _wxyz(R: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation
    return np.roll(Rotation.from_matrix(R).as_quat(), 1)


def four_bar_scene(dts, tolerances, reps, duration=1.0) -> list:
    """
    Crank angle at T of the four-bar of ``mechanisms.four_bar``, over 1 rad.

    MuJoCo: the crank and the coupler nested on hinges, the rocker on its own hinge
    to the world, the loop closed by a ``connect`` equality at C (soft; 3 rows where
    the planar loop needs 2, like our 3 redundant rows of 20).
    """
    from rigid_body_sim.core.mechanisms import four_bar, ROD_RADIUS
    scene = 'four-bar'
    base = four_bar('rkmk4', dts[0])

    def crank_angle_of_quat(q_xyzw):
        x_axis = peer.rot(q_xyzw[None])[0][:, 0]
        return float(np.arctan2(x_axis[2], x_axis[0]))

    ends = {}
    for name in ('crank', 'coupler', 'rocker'):   # the initial poses (body frames)
        pos, quat = base.pose(name)
        ends[name] = (pos, peer.rot(quat[None])[0])
    refs: dict = {}

    def ref_angle(t_end):
        # The reference crank angle at the time the run ended, from its body frame.
        if t_end not in refs:
            start = four_bar('rkmk4', dts[0])
            start.state = dop853_trajectory(start, [t_end], rtol=1e-13, atol=1e-13)[0]
            refs[t_end] = crank_angle_of_quat(start.pose('crank')[1])
        return refs[t_end]
    lengths = {'crank': 0.1, 'coupler': 0.35, 'rocker': 0.3}
    masses = {'crank': 0.2, 'coupler': 0.5, 'rocker': 0.4}

    def inertial(name):
        m, L = masses[name], lengths[name]
        side = m * (3 * ROD_RADIUS ** 2 + L ** 2) / 12.0
        return (f'<inertial pos="{0.5 * L!r} 0 0" mass="{m!r}" '
                f'diaginertia="{peer.nums([0.5 * m * ROD_RADIUS ** 2, side, side])}"/>')

    def start(name):
        pos, R = ends[name]
        return pos - 0.5 * lengths[name] * R[:, 0], R

    a, Ra = start('crank')
    b, Rb = start('coupler')
    d, Rd = start('rocker')
    y = np.array([0.0, 1.0, 0.0])
    coupler_rel = Ra.T @ (b - a)
    body = (f'    <body name="crank" pos="{peer.nums(a)}" quat="{peer.nums(_wxyz(Ra))}">\n'
            f'      <joint type="hinge" pos="0 0 0" axis="{peer.nums(Ra.T @ y)}"/>\n'
            f'      {inertial("crank")}\n'
            f'      <body name="coupler" pos="{peer.nums(coupler_rel)}" '
            f'quat="{peer.nums(_wxyz(Ra.T @ Rb))}">\n'
            f'        <joint type="hinge" pos="0 0 0" axis="{peer.nums(Rb.T @ y)}"/>\n'
            f'        {inertial("coupler")}\n      </body>\n    </body>\n'
            f'    <body name="rocker" pos="{peer.nums(d)}" quat="{peer.nums(_wxyz(Rd))}">\n'
            f'      <joint type="hinge" pos="0 0 0" axis="{peer.nums(Rd.T @ y)}"/>\n'
            f'      {inertial("rocker")}\n    </body>\n')

    def connect(dt, stiff):
        params = ''
        if stiff:
            (tc, dr), imp = peer.mj_stiffest(dt)
            params = f' solref="{tc!r} {dr!r}" solimp="{peer.nums(imp)}"'
        return (f'    <connect body1="coupler" body2="rocker" '
                f'anchor="{lengths["coupler"]!r} 0 0"{params}/>\n')

    def error(v, rec, t_end):
        if v.engine == 'ours':
            angle = crank_angle_of_quat(rec['quat'][-1])
        else:
            replay = peer.mj_replay(rec['model'], rec['qpos'][-1:], rec['qvel'][-1:], 1)
            x_axis = replay['xmat'][0][:, 0]
            angle = float(np.arctan2(x_axis[2], x_axis[0]))
        return abs(angle - ref_angle(t_end))

    runs = []
    for dt in dts:
        vs = [peer.Variant('ours', f'{name} dt {dt:g}', peer.run_ours(
            lambda name=name, dt=dt: four_bar(name, dt), 'crank')) for name in OURS]
        vs += [peer.Variant('MuJoCo', f'{mj}, connect, {which} dt {dt:g}', peer.run_mujoco(
            peer.mjcf('four_bar', dt, mj, peer.G, body, connect(dt, which == 'stiffest'))))
            for mj, which in (('RK4', 'default'), ('RK4', 'stiffest'),
                              ('implicitfast', 'default'))]
        runs.append((dt, None, vs))
    for tol in tolerances:
        vs = [peer.Variant('ours', f'{name} knob {tol:g}', peer.run_ours(
            _knob(four_bar, name, dts[0], tol), 'crank')) for name in ('rkmk4', 'lie_poisson4')]
        runs.append((dts[0], tol, vs))
    return _sweep(scene, runs, duration, reps, lambda v, rec, dt, t: error(v, rec, t))


def chain(n_links: int, duration: float, dts, reps) -> list:
    scene = f'chain {n_links}'
    scale = peer.CHAIN_MASS * peer.G * peer.CHAIN_LENGTH * n_links ** 2 / 2.0
    inertia = peer.chain_inertia()
    rows = []
    for dt in dts:
        n = int(round(duration / dt))
        vs = [peer.Variant('ours', f'{name} dt {dt:g}', peer.run_ours(
            lambda name=name, dt=dt: peer.chain_sim(n_links, name, dt)))
            for name in ('lie_poisson2', 'lie_poisson4', 'rkmk4')]
        vs += [peer.Variant('MuJoCo', f'{mj} dt {dt:g}',
                            peer.run_mujoco(peer.chain_xml(n_links, dt, mj)))
               for mj in ('RK4', 'implicitfast')]
        print(f'\n== {scene}, {duration:g} s, dt {dt:g} ==', flush=True)
        per_step, records = peer.measure(vs, n, reps)
        for v, us, rec in zip(vs, per_step, records):
            if v.engine == 'ours':
                energy = peer.total_energy(peer.CHAIN_MASS, inertia, rec['pos'], rec['quat'],
                                           rec['vel'], rec['omega'])
            else:
                energy = peer.mj_replay(rec['model'], rec['qpos'], rec['qvel'],
                                        n_links)['energy']
            rel = np.abs(energy - energy[0]) / scale
            err = float(np.max(rel)) if np.all(np.isfinite(rel)) and np.max(rel) < 1.0 \
                else float('inf')
            rows.append(_row(scene, v, dt, None, us / dt, err))
    return rows


def _sweep(scene: str, runs: list, duration: float, reps: int, error) -> list:
    """
    Time every ``(dt, tolerance, variants)`` of ``runs`` over ``duration`` (s).

    ``error(variant, records, dt, t_end)`` measures a run ending at ``t_end``
    (``n dt``, which may differ from ``duration`` by a fraction of a step).
    """
    rows = []
    for dt, tol, vs in runs:
        n = int(round(duration / dt))
        knob = f', tolerance {tol:g}' if tol else ''
        print(f'\n== {scene}, {n * dt:.4g} s, dt {dt:g}{knob} ==', flush=True)
        per_step, records = peer.measure(vs, n, reps)
        for v, us, rec in zip(vs, per_step, records):
            rows.append(_row(scene, v, dt, tol, us / dt, error(v, rec, dt, n * dt)))
    return rows


def _row(scene: str, v, dt: float, tol, cost: float, err: float) -> dict:
    family = v.label.split(' dt ')[0].split(' knob ')[0]
    if tol is not None:
        family += ' + knob'
    return {'scene': scene, 'engine': v.engine, 'label': v.label, 'family': family,
            'dt': dt, 'tol': tol, 'cost': cost, 'err': err}


# -- analysis and output --------------------------------------------------------------------


def cheapest(rows: list, scene: str, engine: str, target: float, only: str = ''):
    ok = [r for r in rows if r['scene'] == scene and r['engine'] == engine
          and r['err'] <= target and only in r['family']]
    return min(ok, key=lambda r: r['cost']) if ok else None


def _setup(r) -> str:
    if r is None:
        return 'not reached at any dt tried'
    what = f'`{r["family"]}`' if r['engine'] == 'ours' else r['family']
    how = f'dt {r["dt"]:g}' + (f', tolerance {r["tol"]:g}' if r['tol'] else '')
    return f'{what}, {how}: {r["cost"] * 1e3:.3g} ms/s (error {r["err"]:.1e})'


def targets_table(rows: list, only: str = '', scenes: str = '') -> str:
    """Cheapest set-ups per target (MuJoCo's among those whose name contains ``only``)."""
    lines = ['| scene | target | ours: cheapest | MuJoCo: cheapest | cost ratio ours / MuJoCo |',
             '|---|---|---|---|---|']
    for scene in dict.fromkeys(r['scene'] for r in rows if scenes in r['scene']):
        for target in TARGETS:
            a = cheapest(rows, scene, 'ours', target)
            b = cheapest(rows, scene, 'MuJoCo', target, only)
            ratio = f'{a["cost"] / b["cost"]:.2g}' if a and b else \
                ('ours only' if a else ('MuJoCo only' if b else 'neither'))
            lines.append(f'| {scene} | {target:g} | {_setup(a)} | {_setup(b)} | {ratio} |')
    return '\n'.join(lines)


def all_rows_table(rows: list) -> str:
    lines = ['| scene | engine | set-up | dt | tolerance | wall ms / simulated s | error |',
             '|---|---|---|---|---|---|---|']
    for r in rows:
        lines.append(f'| {r["scene"]} | {r["engine"]} | {r["family"]} | {r["dt"]:g} | '
                     f'{r["tol"] if r["tol"] else "-"} | {r["cost"] * 1e3:.3g} | '
                     f'{r["err"]:.1e} |')
    return '\n'.join(lines)


def plot(rows: list, path: Path) -> None:
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    scenes = list(dict.fromkeys(r['scene'] for r in rows))
    cols = 4
    fig, axes = plt.subplots((len(scenes) + cols - 1) // cols, cols,
                             figsize=(4.2 * cols, 3.6 * ((len(scenes) + cols - 1) // cols)),
                             squeeze=False)
    for ax, scene in zip(axes.ravel(), scenes):
        fams = dict.fromkeys((r['engine'], r['family']) for r in rows if r['scene'] == scene)
        for engine, fam in fams:
            pts = sorted((r['cost'], r['err']) for r in rows if r['scene'] == scene
                         and r['engine'] == engine and r['family'] == fam
                         and np.isfinite(r['err']) and r['err'] > 0)
            if not pts:
                continue
            x, y = zip(*pts)
            ax.loglog(np.array(x) * 1e3, y, ('o-' if engine == 'ours' else 's--'),
                      label=f'{engine}: {fam}', markersize=3)
        for target in TARGETS:
            ax.axhline(target, color='0.85', linewidth=0.6, zorder=0)
        ax.set_title(scene)
        ax.set_xlabel('wall ms per simulated s')
        ax.set_ylabel('error')
        ax.legend(fontsize=5)
    for ax in axes.ravel()[len(scenes):]:
        ax.axis('off')
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main(argv=None) -> None:
    """Run the study; ``--quick`` for a short check (written to bench/out, not docs/)."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    p.add_argument('--quick', action='store_true',
                   help='fewer step sizes, 1 repetition; writes bench/out, not docs/')
    p.add_argument('--reps', type=int, default=3)
    p.add_argument('--chains-only', action='store_true',
                   help="only the chains' rows (their full sweep); writes "
                        'bench/out/accuracy_study_chains.md, not docs/')
    args = p.parse_args(argv)
    if peer.mujoco is None:
        sys.exit('mujoco is not installed: pip install -r bench/requirements.txt '
                 '(./dev.sh bench does it)')
    reps = 1 if args.quick else args.reps
    if args.chains_only:
        chains_only(reps)
        return
    rows = []
    rows += free_body((1e-1, 3e-2, 1e-2) if args.quick else (1e-1, 3e-2, 1e-2, 3e-3, 1e-3),
                      (1e-6, 1e-9) if args.quick else (1e-3, 1e-5, 1e-7, 1e-9, 1e-11), reps,
                      duration=2.0 if args.quick else 10.0)
    for theta in ((90.0,) if args.quick else (60.0, 90.0, 120.0)):
        rows += pendulum(theta, (1e-2, 1e-3) if args.quick else (3e-2, 1e-2, 3e-3, 1e-3, 3e-4),
                         (1e-6,) if args.quick else (1e-4, 1e-6, 1e-8, 1e-10), reps)
    rows += heavy_top((1e-2, 3e-3) if args.quick else (1e-2, 3e-3, 1e-3, 3e-4),
                      (1e-6,) if args.quick else (1e-4, 1e-6, 1e-8), reps)
    rows += four_bar_scene((1e-2, 1e-3) if args.quick else (1e-2, 3e-3, 1e-3, 3e-4),
                           (1e-6,) if args.quick else (1e-4, 1e-6, 1e-8), reps)
    for links, duration in (((2, 0.5), (10, 0.5)) if args.quick else
                            ((2, 2.0), (10, 2.0), (50, 1.0))):
        rows += chain(links, duration, (2e-3, 1e-3) if args.quick
                      else (1e-2, 5e-3, 2e-3, 1e-3, 5e-4), reps)
    out = peer.OUT if args.quick else DOCS
    out.mkdir(exist_ok=True)
    md = ['# What accuracy costs: ours beside MuJoCo', '', header(), '',
          'Generated by `python bench/accuracy_study.py` (see its docstring for the '
          'scenes, the error measures and the method). Cost is wall time per simulated '
          'second of a loop that steps once and reads the state; error is relative '
          '(free body: Ω(T); pendulum: period; chains: worst energy error over '
          'm g l N²/2; heavy top: centre of mass at T over its distance from the tip; '
          'four-bar: crank angle at T, rad).',
          '', '## Cheapest set-up per accuracy target', '',
          targets_table(rows), '', "## With MuJoCo's `connect` equality only",
          '', "The same constraint as ours (MuJoCo's cheapest above is its `ball` joint in "
          'joint coordinates, a different model with no constraint to violate):', '',
          targets_table(rows, only='connect', scenes='pendulum'),
          '\n'.join(targets_table(rows, only='connect', scenes='heavy top').splitlines()[2:]),
          '\n'.join(targets_table(rows, only='connect', scenes='four-bar').splitlines()[2:]),
          '',
          '## Every run', '', all_rows_table(rows), '',
          '![work-precision](accuracy_study.png)', '']
    (out / 'accuracy_study.md').write_text('\n'.join(md))
    plot(rows, out / 'accuracy_study.png')
    print('\n' + targets_table(rows))
    print('\n' + targets_table(rows, only='connect', scenes='pendulum'))
    print(targets_table(rows, only='connect', scenes='heavy top'))
    print(targets_table(rows, only='connect', scenes='four-bar'))
    print(f'\nwrote {out / "accuracy_study.md"}, {out / "accuracy_study.png"}')


def chains_only(reps: int) -> None:
    """Run the chains' full sweep alone; write ``bench/out/accuracy_study_chains.md``."""
    rows = []
    for links, duration in ((2, 2.0), (10, 2.0), (50, 1.0)):
        rows += chain(links, duration, (1e-2, 5e-3, 2e-3, 1e-3, 5e-4), reps)
    peer.OUT.mkdir(exist_ok=True)
    path = peer.OUT / 'accuracy_study_chains.md'
    path.write_text('\n'.join([
        "# What accuracy costs: the chains' rows", '', header(), '',
        'Generated by `python bench/accuracy_study.py --chains-only` (the chains of the '
        'full study, alone). Error: worst energy error over m g l N²/2.', '',
        targets_table(rows), '', all_rows_table(rows), '']))
    print('\n' + targets_table(rows))
    print(f'\nwrote {path}')


if __name__ == '__main__':
    main()
