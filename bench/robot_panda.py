"""
The Franka Panda from its URDF, in ours and in MuJoCo side by side (issue 18).

The robot is ``robots/panda_description/urdf/panda.urdf`` of PyPI ``example-robot-data``
(a benchmark-only dependency, ``bench/requirements.txt``): a cmeel package of data
only, whose files sit under ``site-packages/cmeel.prefix/share/example-robot-data``;
:func:`panda_urdf` finds the file through the distribution's metadata
(``importlib.metadata``), as the package has no Python module. Both simulators load
the same URDF text, changed in two ways so that both simulate the same mechanism:

* the two finger joints (prismatic; ``panda_finger_joint2`` has a ``<mimic>`` of
  ``panda_finger_joint1``) become fixed at q = 0 and the ``<mimic>`` goes. Left
  prismatic, ours enforces the mimic exactly (one row), while MuJoCo 4.0.0's URDF
  import turns it into a soft joint equality (``mjEQ_JOINT``, default
  solref/solimp). Fixed, the fingers are lumped into link 7 in both: the arm's 7
  revolute joints are the only coordinates;
* ``<dynamics>`` goes (damping 0.003 N m s/rad on the arm joints, 0.3 N s/m on the
  fingers; friction 0): MuJoCo's URDF import applies it as joint damping (and
  ``friction`` as ``frictionloss``); ours would damp by an exact flow, and does not
  simulate friction yet: without it, both simulate the same undamped mechanism.

The position limits stay in the URDF, and both simulators are told not to enforce
them (ours: the robot's ``limits: false``; MuJoCo: ``jnt_limited = 0`` after
loading), because the swing leaves the ranges (the table says when) and the
reference (Pinocchio) has none; ``bench/joint_limits.py`` swings the same Panda into
its limits. For MuJoCo the URDF also loses its
``<visual>`` and ``<collision>`` elements (their ``package://`` meshes cannot be
resolved, and neither simulator needs them here: ours ignores collision) and gains
``<mujoco><compiler discardvisual="true" fusestatic="true" balanceinertia="false"
inertiafromgeom="false"/></mujoco>``: no geoms, the bodies on fixed joints fused into
their parents (MuJoCo's default for URDF, as ours lumps them), inertias exactly as
the URDF gives them (never balanced, never from geoms; the full tensors diagonalized
by MuJoCo, kept whole by ours). A fixed base in both: ours welds ``panda_link0`` to
the world (``fixed_base``), MuJoCo's URDF import adds no free joint and fuses
``panda_link0`` into the world.

Both start in the Panda's "ready" pose, q = (0, -π/4, 0, -3π/4, 0, π/2, π/4) (its
SRDF's default state), at rest, and swing under gravity g = 9.81 m/s² with zero
joint torques for 1 s at dt = 1e-3. Measured, with the repetitions of every variant
interleaved (their order rotating; a first, untimed round warms up) and the median
wall time per step reported, beside the smallest and largest repetition:

* a Python loop that steps once and reads the joint state, as a controller at 1 kHz
  does: MuJoCo ``mj_step``, then copies of ``qpos`` and ``qvel``; ours ``sim.step()``,
  then ``sim.joint_state()`` (positions and velocities kept);
* the same loop without the read;
* the joint angles of the read runs against a reference that neither simulator
  supplies: the joint-space equations of motion by Pinocchio (PyPI ``pin``; its
  articulated-body forward dynamics ``aba`` on the same fixed-finger URDF) integrated
  by DOP853 at rtol = atol = 1e-12 (the difference from 1e-13 is stated); the largest
  joint-angle error ``max_j |q_j - q_ref,j|`` at the end and over the run; for ours
  also the largest constraint violation ``max |Φ|`` over the run, and for both the
  largest energy error (untimed replays).

MuJoCo's integrators: ``Euler`` (its default; semi-implicit Euler in joint
coordinates, first order, symplectic without damping), ``implicitfast`` (its
recommended one; without damping or actuators it takes the very same step as
``Euler``), ``implicit`` (also the Coriolis terms' velocity derivative, first order)
and ``RK4`` (explicit, fourth order). None is second order like our default
(``lie_poisson2``); the closest matches are by order: ``RK4`` for ``lie_poisson4``
and ``rkmk4``, ``Euler`` for ``symplectic_euler``, and MuJoCo's recommended
``implicitfast`` beside our default. The ratios are to ``RK4`` and to
``implicitfast``.

Run: ``python bench/robot_panda.py [--quick] [--profile]`` in the environment of
``./dev.sh`` (``./dev.sh python bench/robot_panda.py``, which installs
bench/requirements.txt); about a minute, ``--quick`` a few seconds (0.25 s of swing,
``lie_poisson2`` and ``lie_poisson4``, MuJoCo ``implicitfast`` and ``RK4``, 3
repetitions, no model checks). ``--profile`` also prints cProfile's top entries of
``sim.step()`` and ``sim.joint_state()``. Prints the table and writes
``bench/out/robot_panda.md`` and ``bench/out/robot_panda.png``.
"""

from __future__ import annotations

import argparse
import cProfile
from dataclasses import dataclass
import datetime
import gc
from importlib import metadata
import io
import os
from pathlib import Path
import platform
import pstats
import re
import statistics
import sys
import tempfile
import time
from typing import Callable, Optional

import numpy as np
from rigid_body_sim.core import INTEGRATORS
from rigid_body_sim.scene import scene_from_dict
import scipy
from scipy.integrate import solve_ivp

try:
    import mujoco
except ImportError:   # main() says what to install
    mujoco = None
try:
    import pinocchio
except ImportError:   # main() says what to install
    pinocchio = None

sys.path.insert(0, str(Path(__file__).resolve().parent))
import report  # noqa: E402, I100

OUT = Path(__file__).resolve().parent / 'out'
URDF_IN_PACKAGE = 'cmeel.prefix/share/example-robot-data/robots/panda_description/urdf/panda.urdf'
G = 9.81
DT = 1e-3
ARM = tuple(f'panda_joint{i}' for i in range(1, 8))
FINGERS = ('panda_finger_joint1', 'panda_finger_joint2')
#: The Panda's "ready" pose (rad), its SRDF's default state.
READY = (0.0, -np.pi / 4, 0.0, -3 * np.pi / 4, 0.0, np.pi / 2, np.pi / 4)
#: Our integrator that a scene gets when it names none.
OUR_DEFAULT = 'lie_poisson2'
MJ_COMPILER = ('<compiler discardvisual="true" fusestatic="true" balanceinertia="false" '
               'inertiafromgeom="false"/>')


# -- the robot ------------------------------------------------------------------------------


def panda_urdf() -> Path:
    """Return the path of ``panda.urdf`` in the installed ``example-robot-data``."""
    path = Path(metadata.distribution('example-robot-data').locate_file(URDF_IN_PACKAGE))
    if not path.is_file():
        raise FileNotFoundError(f'{path}: not in the installed example-robot-data')
    return path


def benchmark_urdf(xml: str) -> str:
    """
    Return the URDF both simulators load: fingers fixed (no mimic), no ``<dynamics>``.

    Raises ValueError when the text does not have the elements this expects (a
    different version of the Panda's URDF).
    """
    out = xml
    for joint in FINGERS:
        out, n = re.subn(rf'(<joint\s+name="{joint}"\s+type=")prismatic(")', r'\1fixed\2', out)
        if n != 1:
            raise ValueError(f'panda.urdf: no prismatic joint {joint!r}')
    out, n = re.subn(r'<mimic\b[^>]*/>', '', out)
    if n != 1:
        raise ValueError(f'panda.urdf: expected one <mimic>, found {n}')
    out = re.sub(r'<dynamics\b[^>]*/>', '', out)
    return out


def mujoco_urdf(xml: str, integrator: str) -> str:
    """Return the benchmark URDF for MuJoCo: no visual or collision; compiler, options set."""
    out = re.sub(r'<visual\b.*?</visual>', '', xml, flags=re.S)
    out = re.sub(r'<collision\b.*?</collision>', '', out, flags=re.S)
    options = (f'<mujoco>{MJ_COMPILER}<option timestep="{DT!r}" integrator="{integrator}" '
               f'gravity="0 0 {-G!r}"/></mujoco>')
    out, n = re.subn(r'(<robot\b[^>]*>)', lambda m: m.group(1) + options, out, count=1)
    if n != 1:
        raise ValueError('panda.urdf: no <robot> element')
    return out


def our_scene(path: Path, integrator: str, tolerance: Optional[float] = None,
              dt: float = DT, limits: bool = False):
    """Our scene of the benchmark URDF at ``path``: fixed base, ready pose, gravity."""
    data = {'dt': dt, 'integrator': integrator,
            'effects': {'gravity': {'g_world': [0.0, 0.0, -G]}},
            'robots': [{'urdf': str(path), 'fixed_base': True, 'limits': limits,
                        'initial_positions': dict(zip(ARM, READY))}]}
    if tolerance is not None:
        data['tolerance'] = tolerance
    return scene_from_dict(data, str(path))


def mujoco_model(xml: str, integrator: str, dt: float = DT, limits: bool = False):
    """Return MuJoCo's model of the benchmark URDF (limits off unless asked), qpos indices."""
    model = mujoco.MjModel.from_xml_string(mujoco_urdf(xml, integrator))
    model.opt.timestep = dt
    if not limits:
        model.jnt_limited[:] = 0
    model.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_AUTORESET)
    idx = np.array([model.jnt_qposadr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, j)]
                    for j in ARM])
    if model.nq != len(ARM) or model.nv != len(ARM):
        raise RuntimeError(f'MuJoCo made nq = {model.nq}, nv = {model.nv} of the Panda, '
                           f'not {len(ARM)}')
    return model, idx


# -- the reference --------------------------------------------------------------------------


def reference(xml: str, times: np.ndarray, rtol: float = 1e-12) -> dict:
    """
    Return the joint angles and rates of the swing by Pinocchio's forward dynamics and DOP853.

    Returns ``q`` and ``qd`` (len(times), 7) of the arm's joints, the total and kinetic
    energy (len(times),), the number of evaluations ``nfev``, and the URDF's position
    ``limits`` ({joint: (lower, upper)}) and ``velocity_limits`` (7,).
    """
    model = pinocchio.buildModelFromXML(xml)
    model.gravity.linear = np.array([0.0, 0.0, -G])
    data = model.createData()
    iq = np.array([model.joints[model.getJointId(j)].idx_q for j in ARM])
    iv = np.array([model.joints[model.getJointId(j)].idx_v for j in ARM])
    if model.nq != len(ARM) or model.nv != len(ARM):
        raise RuntimeError(f'Pinocchio made nq = {model.nq} of the Panda, not {len(ARM)}')
    tau = np.zeros(model.nv)
    q0 = np.zeros(model.nq)
    q0[iq] = READY
    nq = model.nq

    def rhs(t, y):
        return np.concatenate([y[nq:], pinocchio.aba(model, data, y[:nq], y[nq:], tau)])

    sol = solve_ivp(rhs, (times[0], times[-1]), np.concatenate([q0, np.zeros(model.nv)]),
                    method='DOP853', rtol=rtol, atol=rtol, t_eval=times)
    if not sol.success:
        raise RuntimeError(f'reference: {sol.message}')
    q, qd = sol.y[:nq].T, sol.y[nq:].T
    kinetic = np.array([pinocchio.computeKineticEnergy(model, data, a, b)
                        for a, b in zip(q, qd)])
    energy = kinetic + np.array([pinocchio.computePotentialEnergy(model, data, a) for a in q])
    limits = {j: (model.lowerPositionLimit[i], model.upperPositionLimit[i])
              for j, i in zip(ARM, iq)}
    return {'q': q[:, iq], 'qd': qd[:, iv], 'energy': energy, 'kinetic': kinetic,
            'nfev': sol.nfev, 'limits': limits,
            'velocity_limits': model.velocityLimit[iv].copy()}


# -- running and timing ---------------------------------------------------------------------


@dataclass
class Variant:
    """One simulator set-up: a row of the table, timed with and without the read."""

    engine: str                                  # 'ours' or 'MuJoCo'
    label: str                                   # integrator (and knob)
    run: Callable[[int, bool], tuple]            # (n steps, read) -> (wall s, record)
    read_only: bool = False                      # not timed without the read
    sim: object = None                           # ours: the Simulation


def run_ours(sim) -> Callable:
    """Run ``sim`` from its initial state n steps, reading the joint state after each or not."""
    def run(n: int, read: bool) -> tuple:
        sim.reset()
        js = sim.joint_state()
        q = np.empty((n + 1, len(js.positions)))
        qd = np.empty_like(q)
        q[0], qd[0] = js.positions, js.velocities
        gc.collect()
        if read:
            t0 = time.perf_counter()
            for k in range(1, n + 1):
                sim.step()
                js = sim.joint_state()
                q[k] = js.positions
                qd[k] = js.velocities
            wall = time.perf_counter() - t0
        else:
            step = sim.step
            t0 = time.perf_counter()
            for _ in range(n):
                step()
            wall = time.perf_counter() - t0
        return wall, {'q': q, 'qd': qd} if read else {'q_end': sim.joint_state().positions}
    return run


def run_mujoco(model, idx: np.ndarray) -> Callable:
    """Run fresh MjData from the ready pose n steps, copying qpos and qvel after each or not."""
    def run(n: int, read: bool) -> tuple:
        data = mujoco.MjData(model)
        data.qpos[idx] = READY
        mujoco.mj_forward(model, data)
        step = mujoco.mj_step
        gc.collect()
        if read:
            qpos = np.empty((n + 1, model.nq))
            qvel = np.empty((n + 1, model.nv))
            qpos[0], qvel[0] = data.qpos, data.qvel
            t0 = time.perf_counter()
            for k in range(1, n + 1):
                step(model, data)
                qpos[k] = data.qpos
                qvel[k] = data.qvel
            wall = time.perf_counter() - t0
            return wall, {'q': qpos[:, idx], 'qd': qvel[:, idx], 'qpos': qpos, 'qvel': qvel}
        t0 = time.perf_counter()
        for _ in range(n):
            step(model, data)
        wall = time.perf_counter() - t0
        return wall, {'q_end': data.qpos[idx].copy()}
    return run


def measure(variants: list, n: int, reps: int) -> tuple:
    """
    Time every variant and mode ``reps`` times over ``n`` steps, interleaved.

    The order of the (variant, mode) runs rotates from one repetition to the next; a
    first round is run untimed (imports, caches, first calls). Returns the wall times
    per step ``{(i, read): [s, ...]}`` and the records ``{(i, read): record}`` of the
    first timed repetition (the runs are deterministic: every repetition computes
    the same).
    """
    jobs = [(i, read) for i, v in enumerate(variants) for read in (True, False)
            if read or not v.read_only]
    walls = {job: [] for job in jobs}
    records = {}
    for i, read in jobs:
        variants[i].run(min(n, 20), read)
    for rep in range(reps):
        shift = rep % len(jobs)
        for i, read in jobs[shift:] + jobs[:shift]:
            v = variants[i]
            wall, rec = v.run(n, read)
            walls[(i, read)].append(wall / n)
            records.setdefault((i, read), rec)
            print(f'  [{rep + 1}/{reps}] {v.engine:6s} {v.label:28s} '
                  f'{"step + read" if read else "step only":11s} '
                  f'{wall / n * 1e6:9.1f} us/step', flush=True)
    return walls, records


def our_diagnostics(sim, n: int) -> dict:
    """Return the largest constraint violation and energy error over n steps (untimed)."""
    sim.reset()
    e0 = sim.diagnostics().total_energy
    viol, de = 0.0, 0.0
    for _ in range(n):
        sim.step()
        d = sim.diagnostics()
        viol = max(viol, d.constraint_violation)
        de = max(de, abs(d.total_energy - e0))
    return {'violation': viol, 'de': de, 'work': sim.work(), 'counters': sim.joint_counters()}


def mujoco_energy(model, qpos: np.ndarray, qvel: np.ndarray) -> float:
    """Return the largest ``|E(t) - E(0)|`` (mj_energyPos + mj_energyVel) of a run."""
    data = mujoco.MjData(model)
    energy = np.empty(len(qpos))
    for k in range(len(qpos)):
        data.qpos[:] = qpos[k]
        data.qvel[:] = qvel[k]
        mujoco.mj_forward(model, data)
        mujoco.mj_energyPos(model, data)
        mujoco.mj_energyVel(model, data)
        energy[k] = data.energy[0] + data.energy[1]
    return float(np.max(np.abs(energy - energy[0])))


def read_cost(sim, calls: int = 300) -> float:
    """Return the microseconds of ``sim.joint_state()`` alone, after a step (best of 5)."""
    sim.reset()
    sim.step()
    best = np.inf
    for _ in range(5):
        t0 = time.perf_counter()
        for _ in range(calls):
            sim.joint_state()
        best = min(best, (time.perf_counter() - t0) / calls)
    return best * 1e6


def profile(sim, steps: int = 1000, top: int = 12) -> str:
    """Return cProfile's top entries (own time) of ``sim.step()`` and ``sim.joint_state()``."""
    text = []
    for what in ('step', 'joint_state'):
        sim.reset()
        sim.step()
        call = getattr(sim, what)
        prof = cProfile.Profile()
        prof.enable()
        for _ in range(steps):
            call()
        prof.disable()
        stream = io.StringIO()
        pstats.Stats(prof, stream=stream).sort_stats('tottime').print_stats(top)
        body = re.sub(r'\S*/rigid_body_sim/', 'rigid_body_sim/', stream.getvalue())
        body = re.sub(r'\S*/site-packages/', '', body)
        text.append(f'cProfile of {steps} calls of sim.{what}() (`{sim.integrator_name}`):\n'
                    + body.strip())
    return '\n\n'.join(text)


# -- the run --------------------------------------------------------------------------------


def robot_panda(quick: bool, reps: int) -> dict:
    """Build both, time them side by side, and measure their errors; returns the results."""
    source = panda_urdf()
    xml = benchmark_urdf(source.read_text())
    duration = 0.25 if quick else 1.0
    n = int(round(duration / DT))
    times = DT * np.arange(n + 1)
    if quick:
        ours_cases = [('lie_poisson2', None), ('lie_poisson4', None)]
        mj_cases = ['implicitfast', 'RK4']
    else:
        ours_cases = [(name, None) for name in INTEGRATORS] + [('lie_poisson4', 1e-8)]
        mj_cases = ['Euler', 'implicitfast', 'implicit', 'RK4']
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / 'panda_fixed_fingers.urdf'
        path.write_text(xml)
        scenes = {case: our_scene(path, *case) for case in ours_cases}
        check_sim = our_scene(path, 'lie_poisson4', dt=1e-4).simulation if not quick else None
    sim0 = scenes[ours_cases[0]].simulation
    layout = {'bodies': list(sim0.bodies.names), 'joints': sim0.joint_names(),
              'constraints': list(sim0.constraint_names),
              'lumped': list(sim0.robots[0].lumped),
              'masses': [b.mass for b in sim0.robots[0].bodies],
              'warnings': scenes[ours_cases[0]].warnings}
    if layout['joints'] != list(ARM):
        raise RuntimeError(f'our Panda has joints {layout["joints"]}, not {list(ARM)}')
    models = {mj: mujoco_model(xml, mj) for mj in mj_cases}
    m0 = models[mj_cases[0]][0]
    layout['mj_bodies'] = [mujoco.mj_id2name(m0, mujoco.mjtObj.mjOBJ_BODY, b)
                           for b in range(m0.nbody)]
    layout['mj_masses'] = m0.body_mass.tolist()
    variants = []
    for (name, tol), scene in scenes.items():
        label = name if tol is None else f'{name}, tolerance {tol:g}'
        variants.append(Variant('ours', label, run_ours(scene.simulation),
                                read_only=tol is not None, sim=scene.simulation))
    for mj, (model, idx) in models.items():
        variants.append(Variant('MuJoCo', mj, run_mujoco(model, idx)))
    print(f'\n== Franka Panda (example-robot-data {metadata.version("example-robot-data")}): '
          f'fingers fixed, fixed base, ready pose, gravity, {duration:g} s at dt {DT:g} '
          f'({n} steps, {reps} repetitions) ==', flush=True)
    t0 = time.perf_counter()
    ref = reference(xml, times)
    ref_fine = reference(xml, times, rtol=1e-13)
    ref_time = time.perf_counter() - t0
    ref_err = float(np.max(np.abs(ref['q'] - ref_fine['q'])))
    walls, records = measure(variants, n, reps)
    rows, curves = [], {}
    for i, v in enumerate(variants):
        rec = records[(i, True)]
        err_t = np.max(np.abs(rec['q'] - ref['q']), axis=1)
        curves[(v.engine, v.label)] = err_t
        w_read = walls[(i, True)]
        w_step = walls.get((i, False))
        row = {'engine': v.engine, 'label': v.label,
               'us': statistics.median(w_read) * 1e6,
               'us_min': min(w_read) * 1e6, 'us_max': max(w_read) * 1e6,
               'us_step': statistics.median(w_step) * 1e6 if w_step else float('nan'),
               'us_step_min': min(w_step) * 1e6 if w_step else float('nan'),
               'us_step_max': max(w_step) * 1e6 if w_step else float('nan'),
               'err_end': float(err_t[-1]), 'err_early': float(err_t[n // 4]),
               'violation': float('nan'), 'de': float('nan'), 'note': ''}
        if w_step and not np.allclose(records[(i, False)]['q_end'], rec['q'][-1],
                                      rtol=0.0, atol=1e-12):
            row['note'] = 'the run without the read ended elsewhere'
        if v.engine == 'ours':
            diag = our_diagnostics(v.sim, n)
            row['violation'], row['de'] = diag['violation'], diag['de']
            if diag['work'].get('substeps'):
                row['note'] = f'{diag["work"]["substeps"] / n:.1f} sub-steps per step'
            row['velocity_excursions'] = diag['counters'].get('velocity_limit_excursions', 0)
        else:
            row['de'] = mujoco_energy(models[v.label][0], rec['qpos'], rec['qvel'])
        rows.append(row)

    def base(label):
        return next(r for r in rows if r['engine'] == 'MuJoCo' and r['label'] == label)
    for r in rows:
        r['ratio_rk4'] = r['us'] / base('RK4')['us']
        r['ratio_if'] = r['us'] / base('implicitfast')['us']
        r['ratio_rk4_step'] = r['us_step'] / base('RK4')['us_step']
    # When the reference leaves the URDF's position ranges (neither simulator enforces them
    # here), and how fast the joints turn against their velocity limits.
    leaves = {}
    for j, (lo, hi) in ref['limits'].items():
        k = np.flatnonzero((ref['q'][:, ARM.index(j)] < lo) | (ref['q'][:, ARM.index(j)] > hi))
        if len(k):
            leaves[j] = float(times[k[0]])
    checks = {}
    if not quick:
        mj_fine, idx = mujoco_model(xml, 'RK4', dt=1e-5)
        _, rec = run_mujoco(mj_fine, idx)(int(round(duration / 1e-5)), True)
        checks['MuJoCo RK4, dt 1e-5'] = float(np.max(np.abs(rec['q'][::100] - ref['q'])))
        _, rec = run_ours(check_sim)(int(round(duration / 1e-4)), True)
        checks['ours lie_poisson4, dt 1e-4'] = float(np.max(np.abs(rec['q'][::10] - ref['q'])))
    default_sim = scenes[(OUR_DEFAULT, None)].simulation
    return {'rows': rows, 'curves': curves, 'times': times, 'ref': ref, 'ref_err': ref_err,
            'ref_time': ref_time, 'duration': duration, 'steps': n, 'reps': reps,
            'layout': layout, 'leaves': leaves, 'checks': checks,
            'read_us': read_cost(default_sim), 'default_sim': default_sim,
            'ref_de': float(np.max(np.abs(ref['energy'] - ref['energy'][0]))),
            'speed': float(np.max(np.abs(ref['qd']))), 'source': source,
            'kinetic': float(np.max(ref['kinetic']))}


# -- output ---------------------------------------------------------------------------------


def _e(x: float) -> str:
    if x != x:
        return '–'
    return '0' if x == 0 else f'{x:.1e}'


def _name(row: dict) -> str:
    return f'`{row["label"]}`' + (' (default)' if row['label'] == OUR_DEFAULT else '') \
        if row['engine'] == 'ours' else row['label']


def _us(median: float, lo: float, hi: float) -> str:
    if median != median:
        return '–'
    return f'{median:.1f} [{lo:.1f}, {hi:.1f}]'


def table(res: dict) -> str:
    """Markdown table of the run."""
    header = ['engine', 'integrator', 'step + read [us] median [min, max]',
              'step only [us] median [min, max]', 'ratio to MuJoCo RK4',
              'ratio to MuJoCo implicitfast', 'ratio to MuJoCo RK4, step only',
              'of a 1 kHz period',
              f'max abs(Δq) at {res["duration"] / 4:g} s [rad]',
              f'max abs(Δq) at {res["duration"]:g} s [rad]',
              'max abs(Φ) (ours)', 'max abs(ΔE) [J]', 'notes']
    lines = ['| ' + ' | '.join(header) + ' |', '|' + '---|' * len(header)]
    for r in res['rows']:
        cells = [r['engine'], _name(r), _us(r['us'], r['us_min'], r['us_max']),
                 _us(r['us_step'], r['us_step_min'], r['us_step_max']),
                 f'{r["ratio_rk4"]:.1f}', f'{r["ratio_if"]:.1f}',
                 '–' if r['ratio_rk4_step'] != r['ratio_rk4_step']
                 else f'{r["ratio_rk4_step"]:.1f}',
                 f'{r["us"] / 1e3:.1%}', _e(r['err_early']), _e(r['err_end']),
                 _e(r['violation']), _e(r['de']), r['note']]
        lines.append('| ' + ' | '.join(cells) + ' |')
    return '\n'.join(lines)


def _plot(res: dict) -> Optional[Path]:
    try:
        import matplotlib
        matplotlib.use('Agg')
        import matplotlib.pyplot as plt
    except ImportError:
        print('matplotlib not installed: no plot')
        return None
    fig, axes = plt.subplots(1, 3, figsize=(17, 5))
    t = res['times']
    ax = axes[0]
    for j, name in enumerate(ARM):
        ax.plot(t, res['ref']['q'][:, j], label=name)
    ax.set_xlabel('t [s]')
    ax.set_ylabel('joint angle [rad]')
    ax.set_title('the reference swing (Pinocchio + DOP853)')
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7)
    ax = axes[1]
    for (engine, label), err in res['curves'].items():
        ax.semilogy(t[1:], np.maximum(err[1:], 1e-16), '-' if engine == 'ours' else '--',
                    label=f'{engine} {label}')
    ax.set_xlabel('t [s]')
    ax.set_ylabel('max_j abs(q_j - q_ref,j) [rad]')
    ax.set_title(f'joint-angle error, dt {DT:g}')
    ax.grid(True, which='both', alpha=0.3)
    ax.legend(fontsize=7)
    ax = axes[2]
    for i, r in enumerate(res['rows']):
        ours = r['engine'] == 'ours'
        y = max(r['err_end'], 1e-16)
        ax.loglog(r['us'], y, 'o' if ours else 's', color='tab:blue' if ours else 'tab:red')
        ax.annotate(r['label'], (r['us'], y), fontsize=7, xytext=(4, (2, -9, 12)[i % 3]),
                    textcoords='offset points')
    ax.axvline(1000.0, color='grey', lw=0.8, ls=':')
    ax.set_xlabel('wall time per step + read [us] (blue: ours, red: MuJoCo; dotted: 1 kHz)')
    ax.set_ylabel(f'max abs(Δq) at {res["duration"]:g} s [rad]')
    ax.set_title('cost against error')
    ax.grid(True, which='both', alpha=0.3)
    fig.tight_layout()
    path = OUT / 'robot_panda.png'
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _machine() -> str:
    return (f'{report.cpu_model()}, {os.cpu_count()} cores, {platform.system()} '
            f'{platform.release()}')


def page(res: dict, cmd: str, when: str, versions: str, wall: float, load: str) -> str:
    """Return ``bench/out/robot_panda.md``."""
    lay = res['layout']
    ours_rows = [r for r in res['rows'] if r['engine'] == 'ours']
    default = next(r for r in ours_rows if r['label'] == OUR_DEFAULT)
    leaves = ', '.join(f'`{j}` at {t:.3f} s' for j, t in res['leaves'].items()) or 'none'
    excursions = default.get('velocity_excursions', 0)
    vmax = res['ref']['velocity_limits']
    checks = '; '.join(f'{k}: {_e(v)} rad' for k, v in res['checks'].items())
    lumped = ', '.join(f'`{j}`' for j in lay['lumped'])
    text = [
        f'# The Franka Panda, beside MuJoCo\n\n`{cmd}` on {when}, {wall / 60:.1f} min; load '
        f'{load} at the start.\n\nMachine: {_machine()}.\n\nVersions: {versions}.',
        f'`panda.urdf` of example-robot-data {metadata.version("example-robot-data")}, '
        'fingers fixed at q = 0 (no mimic), `<dynamics>` removed, the same text for both '
        '(MuJoCo without `<visual>`/`<collision>`, with `<mujoco>' + MJ_COMPILER
        + '</mujoco>`, joint '
        'limits off); fixed base; ready pose at rest; g = 9.81 m/s²; zero torques; '
        f'{res["duration"]:g} s at dt = {DT:g} ({res["steps"]} steps). Ours: '
        f'{len(lay["bodies"])} bodies, {len(lay["constraints"])} hinge constraints, the '
        f'fixed joints {lumped} lumped (link 7 with hand and fingers: '
        f'{lay["masses"][-1]:.6f} kg); MuJoCo: {len(lay["mj_bodies"]) - 1} bodies besides the '
        f'world, 7 hinge joints, the same masses '
        f'({lay["mj_masses"][-1]:.6f} kg for link 7).',
        'Each variant: a Python loop of one step and a read of the joint state (MuJoCo: '
        '`mj_step`, copies of `qpos` and `qvel`; ours: `sim.step()`, `sim.joint_state()`), '
        'and the same loop without the read, timed over the whole run; the repetitions '
        'of all variants and both loops interleaved, after an untimed round; median of '
        f'{res["reps"]} and [min, max]. Errors from the same runs, against Pinocchio '
        '(`aba`, joint space) integrated by DOP853 at rtol = atol = 1e-12, '
        f'{_e(res["ref_err"])} rad from rtol 1e-13; its energy stays within '
        f'{_e(res["ref_de"])} J. Max abs(Φ): the largest constraint violation of ours over '
        'the run (m or rad); max abs(ΔE): the largest energy error over the run '
        f'(untimed replays), beside a kinetic energy of up to {res["kinetic"]:.2f} J.'
        ' Ratios: of the medians, step + read unless said. Of our step + read, '
        '`sim.joint_state()` alone takes '
        f'{res["read_us"]:.0f} us (`{OUR_DEFAULT}`, timed alone). Timings are for comparing '
        'within this run on this machine.',
        table(res),
        f'The swing is violent: the joints reach {res["speed"]:.1f} rad/s (the URDF allows '
        f'{min(vmax):.3g} to {max(vmax):.3g}; `{OUR_DEFAULT}` counted {excursions} joint-steps '
        'beyond those '
        f'velocity limits) and leave their position ranges (unenforced in both here): '
        f'{leaves}. The errors grow with it.'
        + (f' Model check (the same mechanism in all three): {checks}.' if checks else ''),
    ]
    return '\n\n'.join(text) + '\n'


def main(argv=None) -> int:
    """Run the Panda side by side; ``--quick`` for a short run."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    p.add_argument('--quick', action='store_true', help='0.25 s, two integrators each '
                                                        '(a few seconds)')
    p.add_argument('--reps', type=int, default=None,
                   help='repetitions per variant (median; default 7, --quick 3)')
    p.add_argument('--profile', action='store_true',
                   help=f'print cProfile of sim.step() and sim.joint_state() ({OUR_DEFAULT})')
    args = p.parse_args(argv)
    reps = args.reps if args.reps is not None else (3 if args.quick else 7)
    if reps < 1:
        p.error('--reps must be >= 1')
    missing = [name for name, mod in (('mujoco', mujoco), ('pin', pinocchio)) if mod is None]
    try:
        panda_urdf()
    except (metadata.PackageNotFoundError, FileNotFoundError):
        missing.append('example-robot-data')
    if missing:
        print(f'bench/robot_panda.py needs {", ".join(missing)}, benchmark-only dependencies: '
              'pip install -r bench/requirements.txt (./dev.sh bench does)', file=sys.stderr)
        return 2
    OUT.mkdir(exist_ok=True)
    started = time.perf_counter()
    load = report.load()
    when = datetime.datetime.now().astimezone().strftime('%Y-%m-%d %H:%M %Z')
    versions = (f'python {platform.python_version()}, numpy {np.__version__}, scipy '
                f'{scipy.__version__}, mujoco {mujoco.__version__}, pin '
                f'{metadata.version("pin")}, rigid_body_sim {report.commit()}')
    print(f'{when}; {_machine()}\n{versions}')
    res = robot_panda(args.quick, reps)
    wall = time.perf_counter() - started
    cmd = 'python bench/robot_panda.py' + (' ' + ' '.join(argv if argv is not None
                                                          else sys.argv[1:])).rstrip()
    text = page(res, cmd, when, versions, wall, load)
    (OUT / 'robot_panda.md').write_text(text)
    print('\n' + text)
    if res['layout']['warnings']:
        print('our loader says:\n  ' + '\n  '.join(res['layout']['warnings']))
    if args.profile:
        print('\n' + profile(res['default_sim']))
    plot = _plot(res)
    print(f'wrote {OUT / "robot_panda.md"}' + (f', {plot}' if plot else '')
          + f' ({wall:.0f} s)')
    return 0


if __name__ == '__main__':
    sys.exit(main())
