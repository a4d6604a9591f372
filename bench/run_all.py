"""
Benchmarks: what accuracy costs in time (not tests; timings are for reading, not asserting).

1. Work-precision on free-body scenes: for each integrator and dt from 1e-1 to
   1e-4, the error against a DOP853 reference (rtol 1e-12), the energy and
   angular-momentum drift, and the wall time per simulated second.
2. Cost per step against the number of bodies (1 to 10^4), and what the
   effects a scene lists cost: gravity on/off, isotropic vs anisotropic bodies.
   Speeds are compared as ratios measured side by side in one run.

Then ``bench/constraints.py`` (chains, trees, rings, joints), ``bench/knob_estimators.py``
(the accuracy knob's estimators), ``bench/tree_solve.py`` (the tree solve against SuperLU),
``bench/inertia_form.py`` (the tree solve in inertia form against the row-space one),
``bench/shake_convergence.py`` (SHAKE's iterations) and ``bench/reactions.py`` (reading
the reactions after a step; ``--skip-constraints`` skips these six),
``bench/mujoco_peer.py``, ``bench/robot_panda.py`` (the Franka Panda's URDF),
``bench/joint_limits.py`` (the Panda into its limits), ``bench/complementarity.py``
(the rows' LCP), ``bench/drive_efforts.py`` (its
exact drives bounded by their efforts; the Panda's URDF from the bench requirements),
``bench/contact_detection.py`` (collision detection against the number of shapes),
``bench/contact_pairs.py`` (the narrow phases by pair of kinds),
``bench/contact_panda.py`` (the Panda pushing a box),
``bench/spawn.py`` (spawning and deleting against scene size),
``bench/contact_dynamics.py`` (contact forces: cost, penetration, error),
``bench/kernel_profile.py`` (the contact step's cost by regime: flight, rest, sliding) and
``bench/accuracy_study.py`` (beside MuJoCo; ``--skip-mujoco``),
and ``bench/node.py`` and ``bench/node_robot.py`` (the ROS node through DDS: rates, costs,
latency; with the Panda, joint_states and /tf at 1 kHz; ``--skip-node``).
A benchmark that fails is reported and the others run on.

Writes ``bench/out/*.md`` (the tables) and, when matplotlib is installed,
``bench/out/*.png`` (log-log plots), then assembles the tables into
``docs/performance.md`` (committed) under a header of date, machine, versions and
commit (``report.py``); with a ``--skip-*`` flag the page goes to
``bench/out/performance.md`` instead, so that a partial run never replaces the
committed page. Run: ``./dev.sh bench`` (``--quick`` for a short run).
"""

from __future__ import annotations

import argparse
from pathlib import Path
import platform
import sys
import time
import traceback

import numpy as np
from rigid_body_sim.core import Gravity, INTEGRATORS, RigidBody, Simulation
from rigid_body_sim.core import rotation as so3
from rigid_body_sim.core.reference import free_body_reference

sys.path.insert(0, str(Path(__file__).resolve().parent))
import report  # noqa: E402, I100

OUT = Path(__file__).resolve().parent / 'out'
DOCS = Path(__file__).resolve().parents[1] / 'docs'

# Free-body scenes: (name, principal moments in ascending order, so that the principal
# frame is the body frame, Ω0 in it, duration).
SCENES = {
    'intermediate_axis': ((1.0, 2.0, 3.0), (0.01, 1.0, 0.01), 10.0),
    'symmetric_top': ((1.0, 2.0, 2.0), (5.0, 0.3, 0.0), 10.0),
    'fast_asymmetric': ((1.0, 1.5, 2.3), (3.0, 2.0, -4.0), 5.0),
}


def _simulation(moments, omega0, integrator, dt, n=1, gravity=False):
    bodies = [RigidBody(f'b{i}', 1.0, moments, angular_velocity_body=omega0)
              for i in range(n)]
    return Simulation(bodies, [Gravity()] if gravity else [], integrator, dt)


def _timed_run(sim, n_steps, chunk=1000):
    wall = 0.0
    done = 0
    e0 = sim.diagnostics()
    l0 = np.linalg.norm(e0.angular_momentum_world)
    de = dl = 0.0
    while done < n_steps:
        k = min(chunk, n_steps - done)
        t0 = time.perf_counter()
        sim.step(k)
        wall += time.perf_counter() - t0
        done += k
        d = sim.diagnostics()
        de = max(de, abs(d.total_energy - e0.total_energy) / e0.total_energy)
        dl = max(dl, abs(np.linalg.norm(d.angular_momentum_world) - l0) / l0)
    return wall, de, dl


def work_precision(dts, max_steps):
    """Rows (scene, integrator, dt, error, energy drift, |L| drift, wall s per sim s)."""
    rows = []
    for scene, (moments, omega0, duration) in SCENES.items():
        for name in INTEGRATORS:
            for dt in dts:
                n = int(round(duration / dt))
                if n > max_steps:
                    continue
                # The reference at the time actually reached (n dt may differ from duration).
                omega_ref, quat_ref = free_body_reference(
                    np.array(moments), np.array(omega0), np.array([0.0, 0.0, 0.0, 1.0]),
                    np.array([n * dt]))
                sim = _simulation(moments, omega0, name, dt)
                wall, de, dl = _timed_run(sim, n)
                w = sim.state.ang_vel_principal[0]
                q = sim.state.quat_principal_world[0]
                err_w = np.linalg.norm(w - omega_ref[-1]) / np.linalg.norm(omega_ref[-1])
                err_r = float(np.linalg.norm(so3.log_quat(
                    so3.quat_multiply(so3.quat_conjugate(quat_ref[-1]), q))))
                t_end = n * dt
                rows.append((scene, name, dt, max(err_w, err_r), de, dl, wall / t_end))
                print(f'  {scene:18s} {name:16s} dt {dt:7.0e}  err {max(err_w, err_r):8.1e}  '
                      f'dE {de:8.1e}  d|L| {dl:8.1e}  {wall / t_end:9.4f} s/sim-s',
                      flush=True)
    return rows


def scaling(ns, repeats):
    """Rows (integrator, n, us per step, us per body-step) for a mixed anisotropic scene."""
    rows = []
    rng = np.random.default_rng(0)
    for name in INTEGRATORS:
        for n in ns:
            bodies = [RigidBody(f'b{i}', 1.0 + rng.random(),
                                np.sort(1.0 + rng.random(3)) * (1.0, 1.0, 1.0),
                                angular_velocity_body=rng.normal(size=3)) for i in range(n)]
            sim = Simulation(bodies, [Gravity()], name, 1e-3)
            sim.step(2)
            k = max(repeats, int(20000 / n))
            t0 = time.perf_counter()
            sim.step(k)
            per = (time.perf_counter() - t0) / k
            rows.append((name, n, per * 1e6, per / n * 1e6))
            print(f'  {name:16s} n {n:6d}  {per * 1e6:10.1f} us/step  '
                  f'{per / n * 1e6:8.3f} us/body-step', flush=True)
    return rows


def effect_costs(n, repeats, rounds=7):
    """
    Per-step cost of scenes that differ by one effect, measured side by side.

    The four variants are timed in turn, ``rounds`` times over (interleaved, so a
    slow spell of a shared machine hits them alike), and each keeps its best round.
    """
    rows = []
    variants = {
        'isotropic, no gravity': ((1.0, 1.0, 1.0), False),
        'isotropic, gravity': ((1.0, 1.0, 1.0), True),
        'anisotropic, no gravity': ((1.0, 2.0, 3.0), False),
        'anisotropic, gravity': ((1.0, 2.0, 3.0), True),
    }
    for name in INTEGRATORS:
        sims = {label: _simulation(moments, (0.3, 1.0, 0.2), name, 1e-3, n=n, gravity=gravity)
                for label, (moments, gravity) in variants.items()}
        best = dict.fromkeys(variants, np.inf)
        for sim in sims.values():
            sim.step(2)
        for _ in range(rounds):
            for label, sim in sims.items():
                t0 = time.perf_counter()
                sim.step(repeats)
                best[label] = min(best[label], (time.perf_counter() - t0) / repeats)
        base = best['isotropic, no gravity']
        for label, sim in sims.items():
            work = sim.work()
            rows.append((name, label, best[label] * 1e6, best[label] / base,
                         work.get('gravity_evaluations', 0), work['gyroscopic_body_evaluations']))
            print(f'  {name:16s} {label:24s} {best[label] * 1e6:9.1f} us/step  '
                  f'x{best[label] / base:5.2f}  gravity evals {rows[-1][4]:6d}  '
                  f'gyroscopic body-evals {rows[-1][5]:8d}', flush=True)
    return rows


def _write_table(path, header, rows, fmt):
    lines = ['| ' + ' | '.join(header) + ' |', '|' + '---|' * len(header)]
    lines += ['| ' + ' | '.join(f.format(v) for f, v in zip(fmt, r)) + ' |' for r in rows]
    path.write_text('\n'.join(lines) + '\n')


def _plots(wp_rows, sc_rows):
    try:
        import matplotlib
        matplotlib.use('Agg')
        import matplotlib.pyplot as plt
    except ImportError:
        print('matplotlib not installed: no plots (pip install matplotlib)')
        return
    scenes = sorted({r[0] for r in wp_rows})
    fig, axes = plt.subplots(1, len(scenes), figsize=(5 * len(scenes), 4.2), squeeze=False)
    for ax, scene in zip(axes[0], scenes):
        for name in INTEGRATORS:
            rs = [r for r in wp_rows if r[0] == scene and r[1] == name]
            if rs:
                ax.loglog([r[6] for r in rs], [max(r[3], 1e-16) for r in rs], 'o-', label=name)
        ax.set_title(scene)
        ax.set_xlabel('wall time per simulated second [s]')
        ax.set_ylabel('error at end (rel. Ω / rotation angle)')
        ax.grid(True, which='both', alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(OUT / 'work_precision.png', dpi=110)
    fig, ax = plt.subplots(figsize=(5.5, 4.2))
    for name in INTEGRATORS:
        rs = [r for r in sc_rows if r[0] == name]
        ax.loglog([r[1] for r in rs], [r[2] for r in rs], 'o-', label=name)
    ax.set_xlabel('number of bodies')
    ax.set_ylabel('wall time per step [us]')
    ax.grid(True, which='both', alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(OUT / 'scaling.png', dpi=110)
    print(f'plots: {OUT / "work_precision.png"}, {OUT / "scaling.png"}')


def free_bodies(quick: bool) -> int:
    """Work-precision, scaling and effect costs of free bodies (tables in bench/out)."""
    if quick:
        dts, max_steps, ns, repeats = (1e-1, 1e-2), 2000, (1, 100), 20
    else:
        dts, max_steps, ns, repeats = (1e-1, 3e-2, 1e-2, 3e-3, 1e-3, 3e-4, 1e-4), 10 ** 5, \
            (1, 10, 100, 1000, 10000), 200
    print('\n== work-precision (free bodies; error vs DOP853 rtol 1e-12) ==')
    wp = work_precision(dts, max_steps)
    _write_table(OUT / 'work_precision.md',
                 ('scene', 'integrator', 'dt [s]', 'error at end', 'max rel. dE',
                  'max rel. d|L|', 'wall s / sim s'), wp,
                 ('{}', '{}', '{:.0e}', '{:.1e}', '{:.1e}', '{:.1e}', '{:.3g}'))
    print('\n== cost per step vs number of bodies (anisotropic bodies, gravity) ==')
    sc = scaling(ns, repeats)
    _write_table(OUT / 'scaling.md', ('integrator', 'bodies', 'us / step', 'us / body-step'),
                 sc, ('{}', '{}', '{:.1f}', '{:.3f}'))
    print(f'\n== what each effect costs ({ns[-1]} bodies; ratios to isotropic, no gravity) ==')
    ec = effect_costs(ns[-1], max(10, repeats // 10))
    _write_table(OUT / 'effects.md', ('integrator', 'scene', 'us / step',
                                      'ratio to isotropic, no gravity', 'gravity evals',
                                      'gyroscopic body-evals'), ec,
                 ('{}', '{}', '{:.1f}', '{:.2f}', '{}', '{}'))
    _plots(wp, sc)
    print(f'tables: {OUT}/work_precision.md, scaling.md, effects.md')
    return 0


def sections(quick: bool, node_args: list) -> list:
    """Return the page's sections in order: (flag that skips it, module, argv, Section)."""
    q = ' --quick' if quick else ''
    T = report.Table
    return [
        (None, None, None, report.Section(
            'Free bodies', f'./dev.sh bench{q} --skip-constraints --skip-mujoco --skip-node',
            [T('work_precision.md', 'Work-precision: error against DOP853 (rtol 1e-12), '
                                    'energy and |L| drift, wall time per simulated second'),
             T('scaling.md', 'Cost per step against the number of bodies (anisotropic, '
                             'gravity)'),
             T('effects.md', 'What each effect costs, side by side (ratio to isotropic '
                             'bodies without gravity; the work counters beside)')])),
        ('skip_constraints', 'constraints', ['--quick'] if quick else [], report.Section(
            'Constraints', f'./dev.sh python bench/constraints.py{q}',
            [T('constraints_scaling.md', 'Cost per step: chains and binary trees of rods on '
                                         'ball joints, rings of hinged rods closed by a '
                                         'ball joint'),
             T('constraints_growth.md', 'Growth exponent p of time ∝ N^p'),
             T('constraints_whip.md', '100-link chains whipping (lie_poisson2, dt 1e-3)'),
             T('constraints_accuracy.md', 'Pendulum (60° release: period error) and four-bar '
                                          '(crank angle at 2.1 s) across integrators')])),
        ('skip_constraints', 'knob_estimators', ['--quick'] if quick else [], report.Section(
            'Accuracy knob estimators', f'./dev.sh python bench/knob_estimators.py{q}',
            [T('knob_estimators.md')],
            about='`rkmk4` at dt 1e-2 under each tolerance: the default (embedded pair for '
                  'steps of one sub-step, doubling beyond), the embedded pair alone, step '
                  'doubling alone.')),
        ('skip_constraints', 'tree_solve', ['--quick'] if quick else [], report.Section(
            'The tree solve against SuperLU', f'./dev.sh python bench/tree_solve.py{q}',
            [T('tree_solve.md')])),
        ('skip_constraints', 'inertia_form', ['--quick'] if quick else [], report.Section(
            'The tree solve in inertia form', f'./dev.sh python bench/inertia_form.py{q}',
            [T('inertia_form.md')],
            about='Each scene with `ConstraintSolver.inertia_form` off (the row-space tree '
                  'solve) and on, interleaved; the states of the two after 1,000 steps, and '
                  'the row-space run against itself from positions one ulp apart.')),
        ('skip_constraints', 'shake_convergence', [], report.Section(
            'SHAKE iterations', './dev.sh python bench/shake_convergence.py',
            [T('shake_convergence.md')],
            about='A top on a ball joint, the up-front sub-steps switched off, so that every '
                  'step turns it by the angle in the first column; 200 steps.')),
        ('skip_constraints', 'reactions', ['--quick'] if quick else [], report.Section(
            'Reading the reactions', f'./dev.sh python bench/reactions.py{q}',
            [T('reactions.md')],
            about='The cost of `reactions()` after a step (the solve of the step at the '
                  'state, reusing its geometry and factor), next to the step.')),
        ('skip_mujoco', 'mujoco_peer', ['--quick'] if quick else [], report.Section(
            'Side by side with MuJoCo', f'./dev.sh python bench/mujoco_peer.py{q}',
            [T('mujoco_peer.md')])),
        ('skip_mujoco', 'robot_panda', ['--quick'] if quick else [], report.Section(
            'The Franka Panda, beside MuJoCo', f'./dev.sh python bench/robot_panda.py{q}',
            [T('robot_panda.md')])),
        ('skip_mujoco', 'joint_limits', ['--quick'] if quick else [], report.Section(
            'Joint limits: the Panda swinging into its bounds',
            f'./dev.sh python bench/joint_limits.py{q}', [T('joint_limits.md')])),
        ('skip_mujoco', 'drive_efforts', ['--quick'] if quick else [], report.Section(
            'Effort-limited exact drives: the Panda',
            f'./dev.sh python bench/drive_efforts.py{q}', [T('drive_efforts.md')],
            about="The Panda's arm on exact position drives, their URDF effort limits off "
                  'and on: holding, a streamed trajectory, a jump (no peer: see the '
                  'script).')),
        ('skip_mujoco', 'complementarity', ['--quick'] if quick else [], report.Section(
            'The rows with bounds: their complementarity problem',
            f'./dev.sh python bench/complementarity.py{q}', [T('complementarity.md')],
            about='The box-LCP solvers on random problems by size and start, and the '
                  "pivots of the Panda's held rows by the LCP against the sequential rule "
                  'it replaced.')),
        ('skip_mujoco', 'contact_detection', ['--quick'] if quick else [], report.Section(
            'Collision detection: cost against shapes, beside MuJoCo',
            f'./dev.sh python bench/contact_detection.py{q}', [T('contact_detection.md')],
            about='A pile of spheres and boxes over a ground, N shapes: our detector '
                  "(grid broad phase, narrow phases) against MuJoCo's kinematics and "
                  'collision on the same bodies.')),
        ('skip_mujoco', 'contact_pairs', ['--quick'] if quick else [], report.Section(
            'Narrow phases by pair of kinds, beside MuJoCo',
            f'./dev.sh python bench/contact_pairs.py{q}', [T('contact_pairs.md')],
            about='200 separate pairs of one kind each, resting 1e-5 m deep: the cost a '
                  'pair of our detector (closed forms; GJK and EPA for a cylinder on a box '
                  "or a cylinder, and for a mesh's hull) beside MuJoCo's, and the contacts "
                  'each finds.')),
        ('skip_mujoco', 'contact_dynamics', ['--quick'] if quick else [], report.Section(
            'Contact dynamics: cost, penetration and error beside MuJoCo',
            f'./dev.sh python bench/contact_dynamics.py{q}', [T('contact_dynamics.md')],
            about='A sphere dropped, a box sliding to a stop, a stack of ten boxes: the '
                  "whole step's cost, the deepest penetration and each scene's error "
                  'against its closed form, ours and MuJoCo from the same state.')),
        ('skip_mujoco', 'kernel_profile', ['--quick'] if quick else [], report.Section(
            'Contact step cost by regime, beside MuJoCo',
            f'./dev.sh python bench/kernel_profile.py{q}', [T('kernel_profile.md')],
            about='A sphere in flight, a sphere at rest, a box at rest, a box sliding: the '
                  "compiled contact step's cost beside MuJoCo's, one regime each, with the "
                  'allocations a step (where the time goes by function: its `--perf`).')),
        (None, 'contact_robots', ['--quick'] if quick else [], report.Section(
            'Contact with robots: cost and quality',
            f'./dev.sh python bench/contact_robots.py{q}', [T('contact_robots.md')],
            about='URDF robots touching the ground: a quadruped standing on exact drives and '
                  'on servos, ANYmal B standing, a gantry pushing a box; every step in '
                  'Python (scenes with joints; the LCPs of symmetric operators by the '
                  "compiled solve), the LCPs' iterations, failures and residual, the "
                  "deepest penetration and each scene's error.")),
        ('skip_mujoco', 'contact_panda', ['--quick'] if quick else [], report.Section(
            'The Panda pushing a box, beside MuJoCo',
            f'./dev.sh python bench/contact_panda.py{q}', [T('contact_panda.md')],
            about="The Panda's URDF with its collision meshes (convex hulls) turning about "
                  'its base and pushing a box along the ground, with the pusher '
                  "frictionless and at μ 0.5: the step's cost, the box's travel and speed, "
                  'the penetrations, and our LCPs, beside MuJoCo on servos.')),
        (None, 'spawn', ['--quick'] if quick else [], report.Section(
            'Spawning and deleting: cost against scene size',
            f'./dev.sh python bench/spawn.py{q}', [T('spawn.md')],
            about='Spheres resting on the ground, N of them: what `Simulation.add_body` and '
                  '`remove_body` cost beside a step of the same scene.')),
        ('skip_mujoco', 'accuracy_study', ['--quick'] if quick else [], report.Section(
            'What accuracy costs, beside MuJoCo', './dev.sh python bench/accuracy_study.py',
            [],
            about='The study sweeps step sizes and the accuracy knob in both simulators and '
                  'writes its own page, [accuracy_study.md](accuracy_study.md), with its '
                  'own header (machine, versions, commit, date); the full run writes it, a '
                  '`--quick` run only `bench/out/accuracy_study.md` (not copied here).')),
        ('skip_node', 'node', node_args, report.Section(
            'The ROS node', f'./dev.sh python bench/node.py{q}', [T('node.md')])),
        ('skip_node', 'node_robot', node_args, report.Section(
            'The ROS node with a robot', f'./dev.sh python bench/node_robot.py{q}',
            [T('node_robot.md')])),
        ('skip_node', 'node_spawning', ['--quick'] if quick else [], report.Section(
            'The ROS node while entities are spawned and deleted',
            f'./dev.sh python bench/node_spawning.py{q}', [T('node_spawning.md')],
            about='spawn_entity and delete_entity called back to back from another process '
                  'while the node runs at 1 kHz: the round trips of the calls, the simulated '
                  'time over the wall time, and the lag resets.')),
    ]


def main(argv=None) -> int:
    """Run the benchmarks and write docs/performance.md; ``--quick`` for a short run."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    p.add_argument('--quick', action='store_true', help='fewer step sizes and bodies')
    p.add_argument('--skip-constraints', action='store_true',
                   help='free bodies only (bench/constraints.py, knob_estimators.py, '
                        'tree_solve.py, shake_convergence.py and reactions.py run the rest)')
    p.add_argument('--skip-node', action='store_true',
                   help='no ROS node benchmarks (bench/node.py and bench/node_robot.py run '
                        'them)')
    p.add_argument('--skip-mujoco', action='store_true',
                   help='no side-by-side with MuJoCo (bench/mujoco_peer.py, '
                        'bench/robot_panda.py and bench/accuracy_study.py run it)')
    p.add_argument('--max-wait', type=float, metavar='S',
                   help='passed to bench/node.py and bench/node_robot.py (how long they '
                        'wait for a quiet machine)')
    args = p.parse_args(argv)
    OUT.mkdir(exist_ok=True)
    since = time.time()
    started, load_start = report.header(), report.load()
    print(started)
    print(f'python {platform.python_version()}, numpy {np.__version__}, '
          f'{platform.machine()}, {platform.processor() or "cpu"}')
    node_args = (['--quick'] if args.quick else []) + (
        ['--max-wait', f'{args.max_wait:g}'] if args.max_wait is not None else [])
    page, failures = [], 0
    for flag, module, module_args, section in sections(args.quick, node_args):
        page.append(section)
        if flag and getattr(args, flag):
            section.skipped = '--' + flag.replace('_', '-')
            continue
        try:
            if module is None:
                rc = free_bodies(args.quick)
            else:
                rc = __import__(module).main(module_args)
        except SystemExit as exc:   # (a benchmark that exits: MuJoCo missing, ...)
            rc = exc.code
        except Exception as exc:  # noqa: B902 - report it, run the others
            traceback.print_exc()
            rc = f'{type(exc).__name__}: {exc}'.splitlines()[0]
        if rc not in (None, 0):
            failures += 1
            section.failed = rc if isinstance(rc, str) else f'exit code {rc}'
            print(f'** {section.title}: {section.failed}', flush=True)
    partial = args.skip_constraints or args.skip_mujoco or args.skip_node
    target = (OUT if partial else DOCS) / 'performance.md'
    given = argv if argv is not None else sys.argv[1:]
    command = ' '.join(['./dev.sh bench', *given])
    target.write_text(report.performance_page(page, OUT, since, command, started, load_start))
    print(f'\nwrote {target}' + (f' ({failures} benchmark(s) failed)' if failures else ''))
    return 1 if failures else 0


if __name__ == '__main__':
    sys.exit(main())
