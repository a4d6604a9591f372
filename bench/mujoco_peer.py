"""
Side by side with MuJoCo: the same scenes in one run, cost per step next to the error.

Issue 8's comparison: every step is compiled (numba: ``core/kernels/free_step.py`` for free
bodies, ``core/kernels/constrained_step.py`` per component of the constraint graph). Each
scene is built twice with the same masses, inertias, gravity, joint geometry and step
size, and no contacts: as an MJCF string for MuJoCo (PyPI ``mujoco``, a benchmark-only
dependency: ``bench/requirements.txt``) and as a :class:`Simulation` of this core. Both
are stepped in a Python loop that takes one step and reads the state, as a node does:
MuJoCo ``mj_step``, then copies of ``qpos`` and ``qvel``; ours ``sim.step()``, then
``sim.pose()`` and ``sim.twist()``. The repetitions of all variants of a scene are
interleaved (their order rotating), each variant reports the median wall time per step,
and the errors come from the same runs, measured against references that neither
simulator supplies:

1. free body (moments 1, 2, 3 kg m², Ω0 = (0.01, 2, 0.01) rad/s, no gravity, 100 s,
   dt 1e-2): Ω(T) (body frame) and the orientation against DOP853 at rtol 1e-13;
2. ball-joint pendulum (uniform rod, 1 m, 1 kg, released at 90°, 2.5 periods; dt 1e-3):
   the period (interpolated zero crossings of the centre of mass) against the exact
   ``4 sqrt(L/g) K(sin²(θ0/2))`` with the equivalent length ``L = I_pivot / (m d)``, and
   the largest distance of the joint point from the pivot; MuJoCo as a free body with a
   ``connect`` equality (soft) at its default and at its stiffest settings, and with a
   ``ball`` joint (minimal coordinates), and a sweep of its soft-constraint parameters;
3. planar hinge chain (50 links of 0.1 m and 1 kg, released horizontal, 5 s; dt 1e-3):
   the worst energy error over the run, ``max |E(t) - E(0)| / (m g l N² / 2)``; MuJoCo
   in joint coordinates (nested bodies with hinge joints), ours as 50 bodies with
   ``hinge`` constraints;
4. the same chain at 7, 10, 25 and 50 links (issue 19): cost per step of ours
   (``lie_poisson2``, ``rkmk4``) against MuJoCo RK4 over 1 s (``--quick``: 0.2 s).

Run: ``python bench/mujoco_peer.py [--quick]`` in the environment of ``./dev.sh``, with
``pip install -r bench/requirements.txt`` (about 40 s; ``--quick``, about 10 s: free
body 5 s, pendulum 1.5 s with ``lie_poisson2`` and ``lie_poisson4`` only, chain 0.2 s).
Prints the tables and writes ``bench/out/mujoco_peer.md`` and ``bench/out/mujoco_peer.png``.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
import datetime
import gc
import os
from pathlib import Path
import platform
import re
import statistics
import sys
import time
from typing import Callable, Optional

import numpy as np
from rigid_body_sim.core import Constraint, Gravity, INTEGRATORS, RigidBody, Simulation
from rigid_body_sim.core.mechanisms import rod, ROD_RADIUS
from rigid_body_sim.core.reference import free_body_reference
import scipy
from scipy.spatial.transform import Rotation
from scipy.special import ellipk

try:
    import mujoco
except ImportError:   # main() says what to install
    mujoco = None

sys.path.insert(0, str(Path(__file__).resolve().parent))
import report  # noqa: E402, I100

OUT = Path(__file__).resolve().parent / 'out'
MJ_WARNINGS: list = []   # MuJoCo's warnings of the current run (instead of its prints)
G = 9.81

# Free body (issue 8): principal moments in ascending order, so that the body frame is
# the principal frame.
FREE_MOMENTS = (1.0, 2.0, 3.0)
FREE_OMEGA0 = (0.01, 2.0, 0.01)
FREE_DT = 1e-2

# Pendulum: a uniform rod hanging from one end by a ball joint at the world origin.
PEND_LENGTH, PEND_MASS, PEND_DT = 1.0, 1.0, 1e-3

# Chain: N links in the x-z plane, hinges about y, the first to the world at the origin.
CHAIN_LINKS, CHAIN_LENGTH, CHAIN_MASS, CHAIN_DT = 50, 0.1, 1.0, 1e-3
#: Issue 19's chain sizes (chain_sizes): per step against MuJoCo RK4.
CHAIN_SIZES = (7, 10, 25, 50)

# MuJoCo's soft constraints: its defaults, and the stiffest settings it accepts. solref
# (timeconst, dampratio) has its timeconst raised to 2 dt at run time unless the
# refsafe flag is off; solimp's dmin and dmax are clamped to 0.9999 (mjMAXIMP).
MJ_DEFAULT = ((0.02, 1.0), (0.9, 0.95, 0.001, 0.5, 2.0))


def mj_stiffest(dt: float) -> tuple:
    """Return the stiffest ``(solref, solimp)`` MuJoCo accepts at step ``dt`` (see above)."""
    return (2.0 * dt, 1.0), (0.9999, 0.9999, 0.001, 0.5, 2.0)


def nums(values) -> str:
    """Space-separated exact decimals for MJCF attributes."""
    return ' '.join(repr(float(v)) for v in values)


def _fmt(values) -> str:
    return '(' + ', '.join(f'{v:g}' for v in values) + ')'


# -- running and timing ---------------------------------------------------------------------


@dataclass
class Variant:
    """One simulator set-up of a scene: a row of its table."""

    engine: str                          # 'ours' or 'MuJoCo'
    label: str                           # integrator, constraint settings
    run: Callable[[int], tuple]          # n steps from the start: (wall s, records)
    note: str = ''


def run_ours(build: Callable[[], Simulation], body: Optional[str] = None) -> Callable:
    """Run a fresh Simulation n steps, reading pose and twist (world) after each."""
    def run(n: int) -> tuple:
        sim = build()
        p0, q0 = sim.pose(body)
        v0, w0 = sim.twist(body)
        pos = np.empty((n + 1,) + p0.shape)
        quat = np.empty((n + 1,) + q0.shape)
        vel = np.empty_like(pos)
        omega = np.empty_like(pos)
        pos[0], quat[0], vel[0], omega[0] = p0, q0, v0, w0
        e_start = sim.diagnostics().total_energy
        gc.collect()
        t0 = time.perf_counter()
        for k in range(1, n + 1):
            sim.step()
            pos[k], quat[k] = sim.pose(body)
            vel[k], omega[k] = sim.twist(body)
        wall = time.perf_counter() - t0
        e_end = sim.diagnostics().total_energy
        return wall, {'pos': pos, 'quat': quat, 'vel': vel, 'omega': omega,
                      'diag_de': e_end - e_start, 'work': sim.work()}
    return run


def run_mujoco(xml: str, init: Optional[Callable] = None, kinematics: bool = False) -> Callable:
    """
    Run fresh MjData n steps, copying qpos and qvel after each.

    With ``kinematics``, also ``mj_kinematics`` and copies of ``xpos`` and ``xquat``
    after each step: the body poses of the new state (``mj_step`` leaves them as they
    were at its last force evaluation, one step behind ``qpos``). Auto-reset on
    divergence is off, so a diverged run shows as non-finite values.
    """
    model = mujoco.MjModel.from_xml_string(xml)
    model.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_AUTORESET)

    def run(n: int) -> tuple:
        MJ_WARNINGS.clear()
        data = mujoco.MjData(model)
        if init is not None:
            init(model, data)
        mujoco.mj_forward(model, data)
        qpos = np.empty((n + 1, model.nq))
        qvel = np.empty((n + 1, model.nv))
        qpos[0], qvel[0] = data.qpos, data.qvel
        xpos = np.empty((n + 1, model.nbody, 3)) if kinematics else None
        xquat = np.empty((n + 1, model.nbody, 4)) if kinematics else None
        gc.collect()
        t0 = time.perf_counter()
        if kinematics:
            for k in range(1, n + 1):
                mujoco.mj_step(model, data)
                mujoco.mj_kinematics(model, data)
                qpos[k] = data.qpos
                qvel[k] = data.qvel
                xpos[k] = data.xpos
                xquat[k] = data.xquat
        else:
            for k in range(1, n + 1):
                mujoco.mj_step(model, data)
                qpos[k] = data.qpos
                qvel[k] = data.qvel
        wall = time.perf_counter() - t0
        bad = sum(int(data.warning[int(w)].number) for w in (
            mujoco.mjtWarning.mjWARN_BADQACC, mujoco.mjtWarning.mjWARN_BADQVEL,
            mujoco.mjtWarning.mjWARN_BADQPOS))
        return wall, {'model': model, 'qpos': qpos, 'qvel': qvel, 'warnings': bad,
                      'unstable_at': _warning_time()}
    return run


def read_cost(build: Callable[[], Simulation], body: Optional[str] = None,
              calls: int = 300) -> float:
    """Microseconds of ``sim.pose(body)`` and ``sim.twist(body)`` alone (best of 5)."""
    sim = build()
    sim.step()
    best = np.inf
    for _ in range(5):
        t0 = time.perf_counter()
        for _ in range(calls):
            sim.pose(body)
            sim.twist(body)
        best = min(best, (time.perf_counter() - t0) / calls)
    return best * 1e6


def _warning_time() -> Optional[float]:
    """Return the time of MuJoCo's first 'simulation is unstable' warning of this run."""
    for text in MJ_WARNINGS:
        m = re.search(r'unstable\. Time = ([-+0-9.eE]+?)\.?$', text.strip())
        if m:
            return float(m.group(1))
    return None


def measure(variants: list, n: int, reps: int) -> tuple:
    """
    Run every variant ``reps`` times over ``n`` steps, interleaved; rotate the order.

    Returns the median wall time per step of each variant and the records of its
    first repetition (the runs are deterministic: every repetition computes the same).
    """
    walls = [[] for _ in variants]
    records = [None] * len(variants)
    for rep in range(reps):
        shift = rep % len(variants)
        for i in list(range(shift, len(variants))) + list(range(shift)):
            v = variants[i]
            wall, rec = v.run(n)
            walls[i].append(wall / n)
            if records[i] is None:
                records[i] = rec
            print(f'  [{rep + 1}/{reps}] {v.engine:6s} {v.label:44s} '
                  f'{wall / n * 1e6:9.1f} us/step', flush=True)
    return [statistics.median(w) for w in walls], records


# -- physics helpers -----------------------------------------------------------------------


def rot(quat: np.ndarray, scalar_first: bool = False) -> np.ndarray:
    """Rotation matrices of quaternions of any leading shape (scipy, not the core's)."""
    flat = quat.reshape(-1, 4)
    mats = Rotation.from_quat(flat, scalar_first=scalar_first).as_matrix()
    return mats.reshape(quat.shape[:-1] + (3, 3))


def total_energy(mass, inertia, pos, quat, vel, omega) -> np.ndarray:
    """
    Total energy per row of bodies whose frame origin is their centre of mass.

    ``mass`` (nb,) or scalar, ``inertia`` (nb, 3) or (3,): principal moments along the
    body axes; ``pos``, ``vel``, ``omega`` (world) and ``quat`` (xyzw) of shape
    (n, [nb,] 3 or 4). Potential energy ``m g z``.
    """
    w_body = np.einsum('...ji,...j->...i', rot(quat), omega)
    e = (0.5 * mass * np.sum(vel * vel, axis=-1) + 0.5 * np.sum(inertia * w_body * w_body,
                                                                axis=-1)
         + mass * G * pos[..., 2])
    return e.sum(axis=-1) if e.ndim > 1 else e


def mj_replay(model, qpos: np.ndarray, qvel: np.ndarray, body: int) -> dict:
    """
    Replay recorded states in MuJoCo: kinematics and energy (outside the timed loop).

    Returns ``xipos`` (centre of mass), ``xpos`` and ``xmat`` of ``body`` and the total
    energy (``mj_energyPos`` + ``mj_energyVel``) per row; rows from the first
    non-finite state on are NaN.
    """
    data = mujoco.MjData(model)
    n = len(qpos)
    out = {'xipos': np.full((n, 3), np.nan), 'xpos': np.full((n, 3), np.nan),
           'xmat': np.full((n, 3, 3), np.nan), 'energy': np.full(n, np.nan)}
    for k in range(n):
        if not (np.all(np.isfinite(qpos[k])) and np.all(np.isfinite(qvel[k]))):
            break
        data.qpos[:] = qpos[k]
        data.qvel[:] = qvel[k]
        mujoco.mj_forward(model, data)
        mujoco.mj_energyPos(model, data)
        mujoco.mj_energyVel(model, data)
        out['xipos'][k] = data.xipos[body]
        out['xpos'][k] = data.xpos[body]
        out['xmat'][k] = data.xmat[body].reshape(3, 3)
        out['energy'][k] = data.energy[0] + data.energy[1]
    return out


def _crossing_period(x: np.ndarray, dt: float) -> float:
    """Period from the sign changes of x (rows at 0, dt, 2 dt, ...), interpolated."""
    i = np.flatnonzero(np.sign(x[:-1]) * np.sign(x[1:]) < 0)
    if len(i) < 2:
        return float('nan')
    t = dt * (i + x[i] / (x[i] - x[i + 1]))
    return 2.0 * (t[-1] - t[0]) / (len(t) - 1)


def mjcf(name: str, dt: float, integrator: str, gravity: float, body: str,
         equality: str = '') -> str:
    """Return an MJCF model: options, contacts off, ``body`` and ``equality`` XML inside."""
    return (f'<mujoco model="{name}">\n'
            f'  <option timestep="{dt!r}" integrator="{integrator}" '
            f'gravity="0 0 {-gravity!r}">\n'
            f'    <flag contact="disable"/>\n  </option>\n'
            f'  <worldbody>\n{body}  </worldbody>\n'
            + (f'  <equality>\n{equality}  </equality>\n' if equality else '')
            + '</mujoco>\n')


# -- scene 1: free body ---------------------------------------------------------------------


def free_body(duration: float, reps: int, integrators: list) -> dict:
    """Cost per step and Ω(T) error of the torque-free body, ours and MuJoCo's."""
    n = int(round(duration / FREE_DT))
    t_end = n * FREE_DT
    moments = np.array(FREE_MOMENTS)

    def build(name):
        return lambda: Simulation([RigidBody('b', 1.0, FREE_MOMENTS,
                                             angular_velocity_body=FREE_OMEGA0)],
                                  [], name, FREE_DT)

    def init(model, data):
        data.qvel[3:6] = FREE_OMEGA0   # a free joint's angular velocity is in body axes

    body = ('    <body name="b">\n      <freejoint/>\n'
            f'      <inertial pos="0 0 0" mass="1" diaginertia="{nums(moments)}"/>'
            '\n    </body>\n')
    variants = [Variant('ours', name, run_ours(build(name), 'b')) for name in integrators]
    variants += [Variant('MuJoCo', mj,
                         run_mujoco(mjcf('free_body', FREE_DT, mj, 0.0, body), init))
                 for mj in ('RK4', 'Euler', 'implicitfast')]
    print(f'\n== free body: moments {FREE_MOMENTS}, Ω0 {FREE_OMEGA0}, {t_end:g} s, '
          f'dt {FREE_DT:g} ({n} steps, {reps} repetitions) ==', flush=True)
    per_step, records = measure(variants, n, reps)
    w_ref, q_ref = free_body_reference(moments, FREE_OMEGA0, [0.0, 0.0, 0.0, 1.0], [t_end],
                                       rtol=1e-13, atol=1e-13)
    w_ref12, _ = free_body_reference(moments, FREE_OMEGA0, [0.0, 0.0, 0.0, 1.0], [t_end])
    ref_err = float(np.linalg.norm(w_ref12[-1] - w_ref[-1]) / np.linalg.norm(w_ref[-1]))
    R_ref = rot(q_ref[-1])
    e0 = 0.5 * np.dot(moments, np.square(FREE_OMEGA0))
    l0 = np.linalg.norm(moments * np.array(FREE_OMEGA0))
    rows = []
    base = per_step[[v.label for v in variants].index('RK4')]
    for v, us, rec in zip(variants, per_step, records):
        if v.engine == 'ours':
            R = rot(rec['quat'])
            w_body = np.einsum('nji,nj->ni', R, rec['omega'])
        else:
            R = rot(rec['qpos'][:, 3:7], scalar_first=True)
            w_body = rec['qvel'][:, 3:6]
        err_w = float(np.linalg.norm(w_body[-1] - w_ref[-1]) / np.linalg.norm(w_ref[-1]))
        err_r = float(Rotation.from_matrix(R_ref.T @ R[-1]).magnitude())
        de = float(np.max(np.abs(0.5 * np.sum(moments * w_body ** 2, axis=1) - e0)) / e0)
        dl = float(np.max(np.abs(np.linalg.norm(moments * w_body, axis=1) - l0)) / l0)
        rows.append({'engine': v.engine, 'label': v.label, 'dt': FREE_DT, 'us': us * 1e6,
                     'ratio': us / base, 'err': err_w, 'rot': err_r, 'de': de, 'dl': dl})
    return {'rows': rows, 'duration': t_end, 'steps': n, 'ref_err': ref_err,
            'read_us': read_cost(build(integrators[0]), 'b')}


# -- scene 2: ball-joint pendulum -------------------------------------------------------------


def pendulum_geometry(theta0: float) -> dict:
    """Return the rod pendulum at ``theta0`` (rad): inertia, pivot offset, direction, period."""
    side = PEND_MASS * (3.0 * ROD_RADIUS ** 2 + PEND_LENGTH ** 2) / 12.0
    inertia = np.array([0.5 * PEND_MASS * ROD_RADIUS ** 2, side, side])
    d = 0.5 * PEND_LENGTH
    length_eq = (side + PEND_MASS * d * d) / (PEND_MASS * d)
    direction = np.array([np.sin(theta0), 0.0, -np.cos(theta0)])
    # A rotation about y by 90° - θ0 takes the body x axis to the rod's direction.
    half = 0.5 * (0.5 * np.pi - theta0)
    return {'inertia': inertia, 'd': d, 'direction': direction,
            'quat_wxyz': np.array([np.cos(half), 0.0, np.sin(half), 0.0]),
            'period': 4.0 * np.sqrt(length_eq / G) * ellipk(np.sin(theta0 / 2.0) ** 2)}


def pendulum_connect_xml(geo: dict, dt: float, integrator: str, solref=None, solimp=None,
                         refsafe: bool = True) -> str:
    """MJCF of the pendulum as a free body held by a connect constraint (soft)."""
    centre = geo['d'] * geo['direction']
    body = (f'    <body name="rod" pos="{nums(centre)}" '
            f'quat="{nums(geo["quat_wxyz"])}">\n      <freejoint/>\n'
            f'      <inertial pos="0 0 0" mass="{PEND_MASS!r}" '
            f'diaginertia="{nums(geo["inertia"])}"/>\n    </body>\n')
    params = ''
    if solref is not None:
        params += f' solref="{nums(solref)}"'
    if solimp is not None:
        params += f' solimp="{nums(solimp)}"'
    equality = f'    <connect body1="rod" anchor="{-geo["d"]!r} 0 0"{params}/>\n'
    xml = mjcf('pendulum', dt, integrator, G, body, equality)
    if not refsafe:
        xml = xml.replace('<flag contact="disable"/>',
                          '<flag contact="disable" refsafe="disable"/>')
    return xml


def pendulum_ball_xml(geo: dict, dt: float, integrator: str) -> str:
    """MJCF of the pendulum on a ball joint (joint coordinates: no constraint)."""
    body = (f'    <body name="rod" pos="0 0 0" '
            f'quat="{nums(geo["quat_wxyz"])}">\n'
            '      <joint type="ball" pos="0 0 0"/>\n'
            f'      <inertial pos="{geo["d"]!r} 0 0" mass="{PEND_MASS!r}" '
            f'diaginertia="{nums(geo["inertia"])}"/>\n    </body>\n')
    return mjcf('pendulum_ball', dt, integrator, G, body)


def _pendulum_errors(geo: dict, dt: float, com_x: np.ndarray, anchor: np.ndarray,
                     energy: np.ndarray) -> dict:
    period = _crossing_period(com_x, dt)
    return {'err': abs(period / geo['period'] - 1.0),
            'anchor': float(np.max(np.linalg.norm(anchor, axis=1))),
            'de': float(np.max(np.abs(energy - energy[0]))) / (PEND_MASS * G * geo['d'])}


def pendulum(duration: float, reps: int, integrators: list,
             theta0: float = np.radians(90.0), dt: float = PEND_DT) -> dict:
    """Cost per step, period and anchor errors of the ball-joint pendulum."""
    geo = pendulum_geometry(theta0)
    n = int(round(duration / dt))

    def build(name):
        def make():
            body = rod('rod', np.zeros(3), geo['direction'], PEND_LENGTH, PEND_MASS)
            return Simulation([body], [Gravity((0.0, 0.0, -G))], name, dt,
                              [Constraint('pivot', 'ball', 'rod', None,
                                          anchor_world=[0.0, 0.0, 0.0])])
        return make

    stiff = mj_stiffest(dt)
    variants = [Variant('ours', name, run_ours(build(name), 'rod')) for name in integrators]
    variants += [
        Variant('MuJoCo', 'RK4, connect, default',
                run_mujoco(pendulum_connect_xml(geo, dt, 'RK4')),
                f'solref {_fmt(MJ_DEFAULT[0])}, solimp {_fmt(MJ_DEFAULT[1])}'),
        Variant('MuJoCo', 'RK4, connect, stiffest',
                run_mujoco(pendulum_connect_xml(geo, dt, 'RK4', *stiff)),
                f'solref {_fmt(stiff[0])}, solimp {_fmt(stiff[1])}'),
        Variant('MuJoCo', 'Euler, connect, default',
                run_mujoco(pendulum_connect_xml(geo, dt, 'Euler')), 'default solref, solimp'),
        Variant('MuJoCo', 'implicitfast, connect, default',
                run_mujoco(pendulum_connect_xml(geo, dt, 'implicitfast')),
                'default solref, solimp'),
        Variant('MuJoCo', 'RK4, ball joint', run_mujoco(pendulum_ball_xml(geo, dt, 'RK4')),
                'joint coordinates: no constraint, exact at the anchor'),
    ]
    print(f'\n== pendulum: rod {PEND_LENGTH:g} m, {PEND_MASS:g} kg, ball joint, released at '
          f'{np.degrees(theta0):g}°, {n * dt:g} s, dt {dt:g} ({n} steps, {reps} repetitions; '
          f'exact period {geo["period"]:.6f} s) ==', flush=True)
    per_step, records = measure(variants, n, reps)
    base = per_step[[v.label for v in variants].index('RK4, connect, default')]
    rows = []
    for v, us, rec in zip(variants, per_step, records):
        rows.append({'engine': v.engine, 'label': v.label, 'us': us * 1e6, 'ratio': us / base,
                     'note': v.note, **pendulum_analysis(geo, dt, v, rec)})
    return {'rows': rows, 'duration': n * dt, 'steps': n, 'period': geo['period'],
            'theta0': theta0, 'read_us': read_cost(build(integrators[0]), 'rod')}


def pendulum_analysis(geo: dict, dt: float, v: Variant, rec: dict) -> dict:
    """Period error, anchor drift and energy error of a pendulum run (ours or MuJoCo)."""
    if v.engine == 'ours':
        R = rot(rec['quat'])
        anchor = rec['pos'] - geo['d'] * R[:, :, 0]
        energy = total_energy(PEND_MASS, geo['inertia'], rec['pos'], rec['quat'], rec['vel'],
                              rec['omega'])
        _check_energy(v, energy, rec, PEND_MASS * G * geo['d'])
        return _pendulum_errors(geo, dt, rec['pos'][:, 0], anchor, energy)
    replay = mj_replay(rec['model'], rec['qpos'], rec['qvel'], 1)
    if 'ball' in v.label:
        anchor = replay['xpos']                       # the joint is at the body origin
    else:
        anchor = replay['xpos'] - geo['d'] * replay['xmat'][:, :, 0]
    return _pendulum_errors(geo, dt, replay['xipos'][:, 0], anchor, replay['energy'])


def _check_energy(v: Variant, energy: np.ndarray, rec: dict, scale: float) -> None:
    """Our energy formula against the core's own diagnostics (a check of this script)."""
    mismatch = abs((energy[-1] - energy[0]) - rec['diag_de'])
    if not mismatch <= 1e-9 * scale:
        print(f'  WARNING: {v.label}: energy from pose and twist differs from the '
              f'diagnostics by {mismatch:.1e} J')


def solref_sweep(duration: float, reps: int, theta0: float = np.radians(90.0),
                 dt: float = PEND_DT) -> list:
    """Run MuJoCo RK4 on the pendulum across soft-constraint settings (solref, solimp)."""
    geo = pendulum_geometry(theta0)
    n = int(round(duration / dt))
    stiff_imp = mj_stiffest(dt)[1]
    settings = [
        ('default', None, None, True),
        ('solref (0.01, 1)', (0.01, 1.0), None, True),
        ('solref (2 dt, 1)', (2 * dt, 1.0), None, True),
        ('solref (2 dt, 1), solimp 0.99', (2 * dt, 1.0), (0.99, 0.99, 0.001, 0.5, 2.0), True),
        ('solref (2 dt, 1), solimp 0.9999 (stiffest)', (2 * dt, 1.0), stiff_imp, True),
        ('solref (2 dt, 1), solimp 0.99999 (clamped)', (2 * dt, 1.0),
         (0.99999, 0.99999, 0.001, 0.5, 2.0), True),
        ('refsafe off, solref (dt, 1), solimp 0.9999', (dt, 1.0), stiff_imp, False),
        ('refsafe off, solref (dt / 2, 1), solimp 0.9999', (dt / 2, 1.0), stiff_imp, False),
    ]
    for k in (1e4, 1e5, 1e6, 1e7):
        settings.append((f'solref (-{k:.0e}, -2 sqrt(k)), solimp 0.9999',
                         (-k, -2.0 * np.sqrt(k)), stiff_imp, True))
    variants = [Variant('MuJoCo', label, run_mujoco(pendulum_connect_xml(
        geo, dt, 'RK4', solref, solimp, refsafe)),
        f'solref {_fmt(solref or MJ_DEFAULT[0])}, solimp {_fmt(solimp or MJ_DEFAULT[1])}'
        + ('' if refsafe else ', refsafe disabled'))
        for label, solref, solimp, refsafe in settings]
    print(f'\n== MuJoCo RK4 pendulum across solref/solimp ({n} steps, {reps} repetitions) ==',
          flush=True)
    per_step, records = measure(variants, n, reps)
    rows = []
    for v, us, rec in zip(variants, per_step, records):
        errs = pendulum_analysis(geo, dt, v, rec)
        note = v.note
        if rec['warnings']:
            note = (f'diverged: MuJoCo unstable at t = {rec["unstable_at"]:g} s'
                    if rec['unstable_at'] is not None else 'diverged')
        rows.append({'label': v.label, 'us': us * 1e6, 'note': note, **errs})
    return rows


# -- scene 3: planar hinge chain ---------------------------------------------------------------


def chain_inertia() -> np.ndarray:
    """Principal moments (3,) of a chain link (kg m²)."""
    side = CHAIN_MASS * (3.0 * ROD_RADIUS ** 2 + CHAIN_LENGTH ** 2) / 12.0
    return np.array([0.5 * CHAIN_MASS * ROD_RADIUS ** 2, side, side])


def chain_xml(n_links: int, dt: float, integrator: str) -> str:
    """MJCF of the planar chain of ``n_links`` hinged rods (joint coordinates)."""
    inertia = nums(chain_inertia())
    body, indent = '', '    '
    for i in range(n_links):
        pos = '0 0 0' if i == 0 else f'{CHAIN_LENGTH!r} 0 0'
        body += (f'{indent}<body name="l{i}" pos="{pos}">\n'
                 f'{indent}  <joint name="j{i}" type="hinge" axis="0 1 0" pos="0 0 0"/>\n'
                 f'{indent}  <inertial pos="{0.5 * CHAIN_LENGTH!r} 0 0" mass="{CHAIN_MASS!r}" '
                 f'diaginertia="{inertia}"/>\n')
        indent += '  '
    for i in reversed(range(n_links)):
        indent = indent[:-2]
        body += f'{indent}</body>\n'
    return mjcf('chain', dt, integrator, G, body)


def chain_sim(n_links: int, integrator: str, dt: float) -> Simulation:
    """Our planar chain of ``n_links`` hinged rods, the first hinged to the world."""
    bodies, joints = [], []
    for i in range(n_links):
        start = np.array([i * CHAIN_LENGTH, 0.0, 0.0])
        bodies.append(rod(f'l{i}', start, np.array([1.0, 0.0, 0.0]), CHAIN_LENGTH,
                          CHAIN_MASS))
        joints.append(Constraint(f'j{i}', 'hinge', f'l{i}', None if i == 0 else f'l{i - 1}',
                                 anchor_world=start, axis_world=[0.0, 1.0, 0.0]))
    return Simulation(bodies, [Gravity((0.0, 0.0, -G))], integrator, dt, joints)


def chain(duration: float, reps: int, integrators: list, n_links: int = CHAIN_LINKS,
          dt: float = CHAIN_DT) -> dict:
    """Cost per step and worst energy error of the planar hinge chain, same span for both."""
    n = int(round(duration / dt))
    scale = CHAIN_MASS * G * CHAIN_LENGTH * n_links ** 2 / 2.0
    variants = [Variant('ours', name, run_ours(lambda name=name: chain_sim(n_links, name, dt)))
                for name in integrators]
    variants += [Variant('MuJoCo', mj, run_mujoco(chain_xml(n_links, dt, mj)))
                 for mj in ('RK4', 'Euler', 'implicitfast')]
    variants.append(Variant('MuJoCo', 'RK4, + mj_kinematics, xpos/xquat',
                            run_mujoco(chain_xml(n_links, dt, 'RK4'), kinematics=True),
                            'reads body poses of the new state too'))
    print(f'\n== chain: {n_links} links of {CHAIN_LENGTH:g} m, {CHAIN_MASS:g} kg, hinges, '
          f'released horizontal, {n * dt:g} s, dt {dt:g} ({n} steps, {reps} repetitions) ==',
          flush=True)
    per_step, records = measure(variants, n, reps)
    base = per_step[[v.label for v in variants].index('RK4')]
    rows, curves = [], {}
    inertia = chain_inertia()
    t = dt * np.arange(n + 1)
    tips = {}
    for v, us, rec in zip(variants, per_step, records):
        note = v.note
        if v.engine == 'ours':
            energy = total_energy(CHAIN_MASS, inertia, rec['pos'], rec['quat'], rec['vel'],
                                  rec['omega'])
            _check_energy(v, energy, rec, scale)
            work = rec['work']
            if work.get('substeps') or work.get('retries'):
                note = f'{work["substeps"]} sub-steps, {work["retries"]} retries'
            tip = rec['pos'][:, -1] + 0.5 * CHAIN_LENGTH * rot(rec['quat'][:, -1])[:, :, 0]
        else:
            replay = mj_replay(rec['model'], rec['qpos'], rec['qvel'], n_links)
            energy = replay['energy']
            tip = replay['xpos'] + CHAIN_LENGTH * replay['xmat'][:, :, 0]
        tips[v.label] = tip
        rel = np.abs(energy - energy[0]) / scale
        finite = np.isfinite(rel)
        bad = np.flatnonzero(~finite | (rel > 1.0))
        if len(bad):
            when = f'diverged: abs(dE) > m g l N²/2 at {t[bad[0]]:.2f} s'
            if v.engine == 'MuJoCo' and rec['unstable_at'] is not None:
                when += f', MuJoCo unstable at {rec["unstable_at"]:.2f} s'
            note = when + (f'; {note}' if note else '')
            worst = float('inf')
        else:
            worst = float(np.max(rel))
        curves[(v.engine, v.label)] = (t, rel)
        rows.append({'engine': v.engine, 'label': v.label, 'sim_s': n * dt, 'us': us * 1e6,
                     'ratio': us / base, 'err': worst,
                     'final': float(rel[-1]) if finite[-1] else float('nan'), 'note': note})
    # Do the two models agree? The tip of the chain early on, ours against MuJoCo RK4.
    k = min(n, int(round(0.1 / dt)))
    first_ours = next(v.label for v in variants if v.engine == 'ours')
    tip_diff = float(np.linalg.norm(tips[first_ours][k] - tips['RK4'][k]))
    return {'rows': rows, 'curves': curves, 'duration': n * dt, 'steps': n, 'scale': scale,
            'tip_check': (k * dt, first_ours, tip_diff),
            'read_us': read_cost(lambda: chain_sim(n_links, integrators[0], dt))}


def chain_sizes(sizes: list, duration: float, reps: int) -> list:
    """
    Cost per step of planar hinge chains of each size: ours and MuJoCo RK4, interleaved.

    Issue 19's targets: ``lie_poisson2`` at or below MuJoCo RK4 per step, ``rkmk4``
    within 1.5 times. The chains of :func:`chain`, ``duration`` simulated seconds each.
    """
    n = int(round(duration / CHAIN_DT))
    rows = []
    for links in sizes:
        variants = [Variant('ours', name, run_ours(
            lambda name=name, links=links: chain_sim(links, name, CHAIN_DT)))
            for name in ('lie_poisson2', 'rkmk4')]
        variants.append(Variant('MuJoCo', 'RK4', run_mujoco(chain_xml(links, CHAIN_DT, 'RK4'))))
        print(f'\n== chain sizes: {links} links, {n * CHAIN_DT:g} s, dt {CHAIN_DT:g} ==',
              flush=True)
        per_step, _ = measure(variants, n, reps)
        lp2, rk, mj = (1e6 * t for t in per_step)
        rows.append({'links': links, 'lp2': lp2, 'rkmk4': rk, 'mj': mj})
    return rows


def chain_sizes_table(rows: list) -> str:
    """Markdown table of :func:`chain_sizes`, with issue 19's targets."""
    return _table(['links', 'ours `lie_poisson2` us / step', 'ours `rkmk4` us / step',
                   'MuJoCo RK4 us / step', '`lie_poisson2` / RK4 (target ≤ 1)',
                   '`rkmk4` / RK4 (target ≤ 1.5)'],
                  [[str(r['links']), f'{r["lp2"]:.1f}', f'{r["rkmk4"]:.1f}', f'{r["mj"]:.1f}',
                    f'{r["lp2"] / r["mj"]:.2f}', f'{r["rkmk4"] / r["mj"]:.2f}']
                   for r in rows])


# -- output ------------------------------------------------------------------------------------


def _table(header: list, rows: list) -> str:
    lines = ['| ' + ' | '.join(header) + ' |', '|' + '---|' * len(header)]
    lines += ['| ' + ' | '.join(r) + ' |' for r in rows]
    return '\n'.join(lines)


def _e(x: float) -> str:
    if x != x:
        return 'n/a'
    if x == float('inf'):
        return 'diverged'
    return '0' if x == 0 else f'{x:.1e}'


def _name(row: dict) -> str:
    return f'`{row["label"]}`' if row['engine'] == 'ours' else row['label']


def free_body_table(res: dict) -> str:
    """Markdown table of the free-body scene."""
    return _table(['engine', 'integrator', 'us / step', 'ratio to MuJoCo RK4',
                   'Ω(T) rel. error', 'rotation error [rad]', 'max rel. dE', 'max rel. d|L|'],
                  [[r['engine'], _name(r), f'{r["us"]:.1f}', f'{r["ratio"]:.2f}', _e(r['err']),
                    _e(r['rot']), _e(r['de']), _e(r['dl'])] for r in res['rows']])


def pendulum_table(res: dict) -> str:
    """Markdown table of the pendulum scene."""
    return _table(['engine', 'integrator, joint', 'us / step', 'ratio to MuJoCo RK4 connect',
                   'period rel. error', 'max anchor error [m]', 'max |dE| / (m g d)',
                   'settings'],
                  [[r['engine'], _name(r), f'{r["us"]:.1f}', f'{r["ratio"]:.2f}', _e(r['err']),
                    _e(r['anchor']), _e(r['de']), r['note']] for r in res['rows']])


def sweep_table(rows: list) -> str:
    """Markdown table of MuJoCo's soft-constraint sweep."""
    return _table(['MuJoCo RK4, connect', 'us / step', 'period rel. error',
                   'max anchor error [m]', 'max |dE| / (m g d)', 'parameters'],
                  [[r['label'], f'{r["us"]:.1f}', _e(r['err']), _e(r['anchor']), _e(r['de']),
                    r['note']] for r in rows])


def chain_table(res: dict) -> str:
    """Markdown table of the chain scene."""
    return _table(['engine', 'integrator', 'simulated [s]', 'us / step', 'ratio to MuJoCo RK4',
                   'worst abs(dE) / (m g l N²/2)', 'at the end', 'notes'],
                  [[r['engine'], _name(r), f'{r["sim_s"]:g}', f'{r["us"]:.1f}',
                    f'{r["ratio"]:.2f}', _e(r['err']), _e(r['final']), r['note']]
                   for r in res['rows']])


def targets_table(free: Optional[dict], pend: Optional[dict], chn: Optional[dict]) -> str:
    """Issue 8's targets, measured: the cost ratio and the errors side by side."""
    rows = []

    def find(res, engine, label):
        return next((r for r in res['rows'] if r['engine'] == engine and r['label'] == label),
                    None)

    if free:
        mj = find(free, 'MuJoCo', 'RK4')
        ours = [r for r in free['rows'] if r['engine'] == 'ours' and r['err'] <= mj['err']]
        best = min(ours, key=lambda r: r['us']) if ours else min(
            (r for r in free['rows'] if r['engine'] == 'ours'), key=lambda r: r['err'])
        rows.append(['free body, dt 1e-2: ours ≤ MuJoCo RK4 per step, at an Ω(T) error as '
                     'small', f'`{best["label"]}` {best["us"]:.0f} us, {_e(best["err"])}',
                     f'RK4 {mj["us"]:.1f} us, {_e(mj["err"])}', f'{best["ratio"]:.1f}',
                     _yes(best['ratio'] <= 1.0), _yes(best['err'] <= mj['err'])])
    if pend:
        mj = find(pend, 'MuJoCo', 'RK4, connect, default')
        stiff = find(pend, 'MuJoCo', 'RK4, connect, stiffest')
        for label, limit in (('lie_poisson2', 1.0), ('lie_poisson4', 2.0)):
            r = find(pend, 'ours', label)
            if r is None:
                continue
            vs_stiff = ('period ' + ('below' if r['err'] < stiff['err'] else 'above')
                        + ', anchor ' + ('below' if r['anchor'] < stiff['anchor'] else 'above'))
            rows.append([f'pendulum 90°, dt 1e-3: `{label}` ≤ {limit:g}x MuJoCo RK4 connect '
                         '(default), errors far below',
                         f'{r["us"]:.0f} us; period {_e(r["err"])}, anchor {_e(r["anchor"])} m',
                         f'default {mj["us"]:.1f} us; period {_e(mj["err"])}, anchor '
                         f'{_e(mj["anchor"])} m. Stiffest {stiff["us"]:.1f} us; period '
                         f'{_e(stiff["err"])}, anchor {_e(stiff["anchor"])} m',
                         f'{r["ratio"]:.1f}', _yes(r['ratio'] <= limit),
                         _yes(r['err'] < mj['err'] and r['anchor'] < mj['anchor'])
                         + f' (vs stiffest: {vs_stiff})'])
    if chn:
        mj = find(chn, 'MuJoCo', 'RK4')
        r = find(chn, 'ours', 'lie_poisson2')
        if r is not None:
            rows.append([f'chain 50 links, dt 1e-3 ({chn["duration"]:g} s): `lie_poisson2` ≤ '
                         'MuJoCo RK4 per step, smaller worst energy error',
                         f'{r["us"]:.0f} us, {_e(r["err"])}',
                         f'{mj["us"]:.1f} us, {_e(mj["err"])}', f'{r["ratio"]:.1f}',
                         _yes(r['ratio'] <= 1.0), _yes(r['err'] < mj['err'])])
    return _table(['target (issue 8)', 'ours', 'MuJoCo', 'cost ratio ours / MuJoCo',
                   'cost met', 'accuracy met'], rows)


def _yes(ok: bool) -> str:
    return 'yes' if ok else 'no'


def _plot(free: Optional[dict], pend: Optional[dict], chn: Optional[dict]) -> Optional[Path]:
    try:
        import matplotlib
        matplotlib.use('Agg')
        import matplotlib.pyplot as plt
    except ImportError:
        print('matplotlib not installed: no plot')
        return None
    fig, axes = plt.subplots(2, 2, figsize=(12, 9))
    panels = [(axes[0, 0], free, 'err', 'Ω(T) relative error', 'free body, dt 1e-2'),
              (axes[0, 1], pend, 'err', 'period relative error', 'pendulum 90°, dt 1e-3'),
              (axes[1, 0], chn, 'err', 'worst |dE| / (m g l N²/2)', 'chain, dt 1e-3')]
    for ax, res, key, ylabel, title in panels:
        if not res:
            ax.set_visible(False)
            continue
        for i, r in enumerate(res['rows']):
            y, label, marker = r[key], r['label'], 'o' if r['engine'] == 'ours' else 's'
            if y == float('inf'):
                y, label, marker = 1.0, label + ' (diverged)', '^'
            if not np.isfinite(y):
                continue
            ours = r['engine'] == 'ours'
            ax.loglog(r['us'], max(y, 1e-16), marker, color='tab:blue' if ours else 'tab:red')
            ax.annotate(label, (r['us'], max(y, 1e-16)), fontsize=7,
                        xytext=(4, (2, -9, 12)[i % 3]), textcoords='offset points')
            if key == 'err' and 'anchor' in r and r['anchor'] > 0:
                ax.loglog(r['us'], r['anchor'], 'x', color='tab:blue' if ours else 'tab:red')
        ax.set_title(title + (' (x: max anchor error [m])' if res is pend else ''))
        ax.set_xlabel('wall time per step [us] (blue: ours, red: MuJoCo)')
        ax.set_ylabel(ylabel)
        ax.grid(True, which='both', alpha=0.3)
    ax = axes[1, 1]
    if chn:
        for (engine, label), (t, rel) in chn['curves'].items():
            bad = np.flatnonzero(~np.isfinite(rel) | (rel > 1.0))
            end = bad[0] if len(bad) else len(rel)   # up to a divergence
            ax.semilogy(t[:end], np.maximum(rel[:end], 1e-16),
                        '-' if engine == 'ours' else '--',
                        label=f'{engine} {label}' + (' (diverged)' if len(bad) else ''))
        ax.set_ylim(1e-14, 1.0)
        ax.set_xlabel('simulated time [s]')
        ax.set_ylabel('|E(t) - E(0)| / (m g l N²/2)')
        ax.set_title('chain: energy error over the run')
        ax.grid(True, which='both', alpha=0.3)
        ax.legend(fontsize=7)
    else:
        ax.set_visible(False)
    fig.tight_layout()
    path = OUT / 'mujoco_peer.png'
    fig.savefig(path, dpi=110)
    return path


def _machine() -> str:
    return (f'{report.cpu_model()}, {os.cpu_count()} cores, {platform.system()} '
            f'{platform.release()}')


def main(argv=None) -> int:
    """Run the side-by-side benchmark; ``--quick`` for a short run."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    p.add_argument('--quick', action='store_true', help='short spans (under a minute)')
    p.add_argument('--reps', type=int, default=5, help='repetitions per variant (median)')
    p.add_argument('--chain-duration', type=float, default=None,
                   help='simulated seconds of the chain (default 5, --quick 0.2)')
    p.add_argument('--scenes', nargs='+',
                   default=['free_body', 'pendulum', 'chain', 'chain_sizes'],
                   choices=['free_body', 'pendulum', 'chain', 'chain_sizes'])
    args = p.parse_args(argv)
    if args.reps < 1:
        p.error('--reps must be >= 1')
    if mujoco is None:
        print('bench/mujoco_peer.py needs MuJoCo, a benchmark-only dependency: '
              'pip install -r bench/requirements.txt (./dev.sh bench does)', file=sys.stderr)
        return 2
    OUT.mkdir(exist_ok=True)
    mujoco.set_mju_user_warning(MJ_WARNINGS.append)
    started = time.perf_counter()
    when = datetime.datetime.now().astimezone().strftime('%Y-%m-%d %H:%M %Z')
    versions = (f'python {platform.python_version()}, numpy {np.__version__}, scipy '
                f'{scipy.__version__}, mujoco {mujoco.__version__}, '
                f'rigid_body_sim {report.commit()}')
    print(f'{when}; {_machine()}\n{versions}')
    geo = pendulum_geometry(np.radians(90.0))
    if args.quick:
        free_s, pend_s, chain_s = 5.0, 1.5, 0.2
        pend_integrators = ['lie_poisson2', 'lie_poisson4']
    else:
        free_s, pend_s, chain_s = 100.0, 2.5 * geo['period'], 5.0
        pend_integrators = list(INTEGRATORS)
    if args.chain_duration is not None:
        chain_s = args.chain_duration
    free = pend = chn = None
    sweep = []
    if 'free_body' in args.scenes:
        free = free_body(free_s, args.reps, list(INTEGRATORS))
    if 'pendulum' in args.scenes:
        pend = pendulum(pend_s, args.reps, pend_integrators)
        sweep = solref_sweep(pend_s, args.reps)
    if 'chain' in args.scenes:
        chn = chain(chain_s, args.reps, ['lie_poisson2'])
    sizes = []
    if 'chain_sizes' in args.scenes:
        sizes = chain_sizes(CHAIN_SIZES, 0.2 if args.quick else 1.0, args.reps)
    sections = []
    if free:
        sections.append(
            f'### Free body\n\nMoments {FREE_MOMENTS} kg m², Ω0 = {FREE_OMEGA0} rad/s, no '
            f'gravity, {free["duration"]:g} s at dt = {FREE_DT:g} ({free["steps"]} steps'
            + ('' if free['duration'] >= 100.0 else '; issue 8: 100 s') + '). '
            'Errors at the end against DOP853 at rtol = atol = 1e-13 (which differs from '
            f'rtol 1e-12 by {free["ref_err"]:.1e} in Ω(T)); dE and d|L| are the largest '
            "over the run, from the state read after every step. MuJoCo's free joint "
            'gives Ω in body axes (`qvel[3:6]`); ours is read in world axes and rotated. '
            f'Of our cost per step, `pose()` and `twist()` take {free["read_us"]:.0f} us '
            '(timed alone).\n\n' + free_body_table(free))
    if pend:
        sections.append(
            f'### Pendulum\n\nUniform rod {PEND_LENGTH:g} m, {PEND_MASS:g} kg (radius '
            f'{ROD_RADIUS:g} m), ball joint at one end, released at '
            f'{np.degrees(pend["theta0"]):g}° (horizontal), {pend["duration"]:.2f} s at dt '
            f'= {PEND_DT:g} ({pend["steps"]} steps). Period from the interpolated zero '
            'crossings of the centre of mass against the exact '
            f'{pend["period"]:.9f} s (`4 sqrt(L/g) K(sin²(θ0/2))`, L = I_pivot / (m d)); '
            "anchor error: the largest distance of the rod's joint point from the pivot "
            '(MuJoCo: from `xpos`/`xmat` of each recorded state); dE over m g d, the '
            "drop of the centre of mass. MuJoCo's defaults: solref "
            f'{_fmt(MJ_DEFAULT[0])}, solimp {_fmt(MJ_DEFAULT[1])}; its stiffest: solref '
            '(2 dt, 1) (a smaller timeconst is raised to 2 dt unless the refsafe flag is '
            'disabled), solimp dmin = dmax = 0.9999 (larger values are clamped). Of our '
            f'cost per step, `pose()` and `twist()` take {pend["read_us"]:.0f} us. '
            "MuJoCo's soft constraint dissipates energy (the dE column), so the amplitude "
            'and with it the period drift: its period error depends on the span measured.\n\n'
            + pendulum_table(pend)
            + '\n\nMuJoCo RK4 with the `connect` equality across solref and solimp (same run '
            'length; negative solref is (-stiffness, -damping)):\n\n' + sweep_table(sweep))
    if chn:
        at, who, diff = chn['tip_check']
        sections.append(
            f'### Chain\n\n{CHAIN_LINKS} uniform rods of {CHAIN_LENGTH:g} m and '
            f'{CHAIN_MASS:g} kg (radius {ROD_RADIUS:g} m) on hinges about y, released '
            f'horizontal, {chn["duration"]:g} s at dt = {CHAIN_DT:g} ({chn["steps"]} steps'
            + ('' if chn['duration'] >= 5.0 else '; issue 8: 5 s')
            + '), the same span for both. Energy error normalized by m g l N²/2 = '
            f'{chn["scale"]:.2f} J (the potential energy released by falling straight '
            "down); ours from the poses and twists read after every step, MuJoCo's by "
            '`mj_energyPos` + `mj_energyVel` at each recorded state. MuJoCo integrates in '
            f'joint coordinates ({CHAIN_LINKS} DOF, no constraints); ours has '
            f'{6 * CHAIN_LINKS} coordinates and {5 * CHAIN_LINKS} constraint rows. Model '
            f"check: the chain's tip at t = {at:g} s is {diff:.1e} m apart in ours "
            f'(`{who}`) and MuJoCo RK4. Of our cost per step, `pose()` and `twist()` of '
            f'all links take {chn["read_us"]:.0f} us.\n\n' + chain_table(chn))
    if sizes:
        sections.append(
            f'### Chains of {CHAIN_SIZES[0]} to {CHAIN_SIZES[-1]} links\n\nThe chain above '
            f'at each size, {0.2 if args.quick else 1.0:g} s from the horizontal release '
            "(the whip's sub-steps come later), ours with `lie_poisson2` and `rkmk4` "
            "against MuJoCo RK4, interleaved; issue 19's targets in the last columns.\n\n"
            + chain_sizes_table(sizes))
    targets = targets_table(free, pend, chn)
    wall = time.perf_counter() - started
    cmd = 'python bench/mujoco_peer.py' + (' ' + ' '.join(argv if argv is not None
                                                          else sys.argv[1:])).rstrip()
    header = (f'# Side by side with MuJoCo\n\n`{cmd}` on {when}, {wall / 60:.1f} min.\n\n'
              f'Machine: {_machine()}.\n\nVersions: {versions}.\n\n'
              'Each variant: a Python loop of one step and a read of the state (MuJoCo: '
              '`mj_step`, copies of `qpos` and `qvel`; ours: `sim.step()`, `sim.pose()`, '
              '`sim.twist()`), timed over the whole run; repetitions of all variants '
              f'interleaved; median of {args.reps}. Errors from the same runs. Timings are '
              'for comparing within this run on this machine.\n')
    text = '\n\n'.join([header, '## Targets of issue 8\n\n' + targets] + sections) + '\n'
    (OUT / 'mujoco_peer.md').write_text(text)
    print('\n' + text)
    plot = _plot(free, pend, chn)
    print(f'wrote {OUT / "mujoco_peer.md"}' + (f', {plot}' if plot else '')
          + f' ({wall:.0f} s)')
    return 0


if __name__ == '__main__':
    sys.exit(main())
