"""
Where a compiled contact step goes: its cost, allocations and (``--perf``) functions.

With ``--perf``, its functions by the share of the time perf samples them in.

    ./dev.sh python bench/kernel_profile.py [--quick]       # the table, beside MuJoCo
    ./dev.sh python bench/kernel_profile.py --perf box      # one scene under perf

The scenes are single bodies on the ground (issue 21's cost target is MuJoCo's on the
sphere and the box), one regime each: a sphere in flight, a sphere at rest, a box at
rest, a box sliding. Ours: ``step(100)`` (the compiled contact steps), with the
allocations numba's runtime counts over the run and the LCP solves a step; MuJoCo 4:
one ``mj_step`` call a step, its defaults (soft contacts). Writes
``bench/out/kernel_profile.md``.

``--perf`` needs Linux ``perf``. numba loads its compiled kernels into anonymous memory,
where perf finds no names; this script writes the names perf reads
(``/tmp/perf-<pid>.map``) from the object code numba loads, so the report names each
kernel function. A function's own share counts its frame's set-up and the moves of the
tuples it unpacks and passes on, not the functions it calls.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path
import re
import shutil
import subprocess
import sys
import tempfile
import time

sys.path.insert(0, str(Path(__file__).resolve().parent))
import report  # noqa: E402, I100

try:
    import mujoco
except ImportError:   # (bench/requirements.txt)
    mujoco = None

OUT = Path(__file__).resolve().parent / 'out'
G, DT = 9.81, 1e-3
#: Runs of each scene, ours and MuJoCo's alternately.
REPEATS = 3

#: numba's object code as it loads (captured before any kernel is imported).
_OBJECTS = []


def _capture_objects() -> None:
    """Record each object file numba loads (from its cache or freshly compiled)."""
    from numba.core import codegen

    setter = codegen.CPUCodeLibrary._set_compiled_object
    compiled = codegen.CPUCodeLibrary._object_compiled_hook.__func__

    def set_object(self, value):
        _OBJECTS.append(value)
        return setter(self, value)

    def on_compiled(cls, module, buf):
        _OBJECTS.append(buf)
        return compiled(cls, module, buf)

    codegen.CPUCodeLibrary._set_compiled_object = set_object
    codegen.CPUCodeLibrary._object_compiled_hook = classmethod(on_compiled)


def _write_perf_map() -> int:
    """Write ``/tmp/perf-<pid>.map`` for the functions of the loaded objects; return them."""
    from numba.core.registry import cpu_target

    engine = cpu_target.target_context.codegen()._engine._ee
    lines = []
    for obj in _OBJECTS:
        with tempfile.NamedTemporaryFile(suffix='.o', delete=False) as f:
            f.write(obj)
        out = subprocess.run(['nm', '-S', '--defined-only', f.name], capture_output=True,
                             text=True).stdout
        os.unlink(f.name)
        # (numba emits its functions weak, in one code section: a global one's address
        # places them all)
        syms = [p for p in (ln.split() for ln in out.splitlines())
                if len(p) == 4 and p[2] in 'tTlLW']
        base = None
        for value, _, kind, name in syms:
            if kind in 'TL':
                address = engine.get_function_address(name)
                if address:
                    base = address - int(value, 16)
                    break
        if base is None:
            continue
        lines += [f'{base + int(v, 16):x} {int(s, 16):x} {_short(n)}' for v, s, _, n in syms]
    with open(f'/tmp/perf-{os.getpid()}.map', 'w') as f:
        f.write('\n'.join(lines) + '\n')
    return len(lines)


def _short(mangled: str) -> str:
    """Return ``module.function`` of a numba symbol (its mangled name otherwise)."""
    parts, at = [], mangled.find('_ZN')
    if at < 0:
        return mangled
    rest = mangled[at + 3:]
    while rest and rest[0].isdigit():
        m = re.match(r'(\d+)', rest)
        size = int(m.group(1))
        parts.append(rest[len(m.group(1)):len(m.group(1)) + size])
        rest = rest[len(m.group(1)) + size:]
    return '.'.join(parts[-2:]) if parts else mangled


#: The scenes (:func:`scene`: a 0.1 m sphere of 1 kg, a 0.2 m cube of 2 kg; dt 1 ms).
SCENES = ('sphere in flight', 'sphere at rest', 'box at rest', 'box sliding')


def scene(name: str) -> tuple:
    """
    Return ``(simulation, MuJoCo model XML, MuJoCo's initial velocity)`` of scene ``name``.

    In flight: 10 m above the ground, no gravity (it stays there). Sliding: at 12 m/s on
    friction 0.05, which takes 24 s to stop it (friction 0.5 takes 0.2 s from 1 m/s,
    and at 100 m/s MuJoCo's soft contact tumbles the box).
    """
    from rigid_body_sim.core import CollisionShape, Gravity, RigidBody, Simulation

    r = h = 0.1
    flight = name == 'sphere in flight'
    sliding = name == 'box sliding'
    v, mu = (12.0, 0.05) if sliding else (0.0, 0.5)
    if name.startswith('sphere'):
        z = 10.0 if flight else r
        body = RigidBody('s', 1.0, (0.4 * r * r,) * 3, position_world=(0, 0, z))
        shape = CollisionShape('sphere', 's', radius=r, friction=0.5)
        mj = f'<body pos="0 0 {z}"><freejoint/><geom type="sphere" size="{r}" mass="1"/></body>'
    else:
        body = RigidBody('b', 2.0, (2.0 * (2 * h) ** 2 / 6,) * 3, position_world=(0, 0, h),
                         linear_velocity_world=(v, 0, 0))
        shape = CollisionShape('box', 'b', size=(2 * h,) * 3, friction=mu)
        mj = (f'<body pos="0 0 {h}"><freejoint/><geom type="box" size="{h} {h} {h}" '
              'mass="2"/></body>')
    g = 0.0 if flight else G
    sim = Simulation([body], [] if flight else [Gravity()], integrator='lie_poisson2',
                     dt=DT, shapes=[CollisionShape('plane', None, friction=mu), shape])
    xml = (f'<mujoco><option timestep="{DT}" gravity="0 0 -{g}"/><default><geom '
           f'friction="{mu} 0.005 0.0001"/></default><worldbody><geom type="plane" '
           f'size="0 0 1"/>{mj}</worldbody></mujoco>')
    return sim, xml, v


def ours(name: str, steps: int) -> dict:
    """Return our cost a step (s; ``step(100)``), allocations and LCP solves a step."""
    from numba.core.runtime import _nrt_python, rtsys

    sim, _, _ = scene(name)
    sim.step(300)   # (settled; the kernels loaded)
    _nrt_python.memsys_enable_stats()
    a0, s0 = rtsys.get_allocation_stats().alloc, sim.contact.counters['lcp_solves']
    c0 = sim.contact.counters['compiled_steps']
    t0 = time.perf_counter()
    for _ in range(steps // 100):
        sim.step(100)
    wall = time.perf_counter() - t0
    n = steps // 100 * 100
    c = sim.contact.counters
    return {'step': wall / n, 'allocs': (rtsys.get_allocation_stats().alloc - a0) / n,
            'solves': (c['lcp_solves'] - s0) / n, 'compiled': (c['compiled_steps'] - c0) / n}


def theirs(name: str, steps: int) -> float:
    """Return MuJoCo's cost a step on the same scene (s; one ``mj_step`` call a step)."""
    _, xml, v = scene(name)
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    data.qvel[0] = v
    for _ in range(300):
        mujoco.mj_step(model, data)
    t0 = time.perf_counter()
    for _ in range(steps):
        mujoco.mj_step(model, data)
    return (time.perf_counter() - t0) / steps


def run(steps: int) -> list:
    """Run each scene in both, :data:`REPEATS` times alternately; return the table's rows."""
    rows = []
    for name in SCENES:
        mine, peer = [], []
        for _ in range(REPEATS):
            mine.append(ours(name, steps))
            if mujoco is not None:
                peer.append(theirs(name, steps))
        best = min(mine, key=lambda r: r['step'])
        rows.append({'scene': name, 'ours': best, 'mj': min(peer) if peer else None})
        print(f'  {name}: ours {best["step"] * 1e6:.2f} us, {best["allocs"]:.1f} '
              'allocations a step' + ('' if not peer else
                                      f'; MuJoCo {min(peer) * 1e6:.2f} us'), flush=True)
    return rows


def table(rows: list) -> str:
    """Markdown table of :func:`run`."""
    lines = ['| scene | ours, step(100), us/step | MuJoCo, us/step | ours / MuJoCo | '
             'ours: allocations a step | ours: LCP solves a step | steps compiled |',
             '|---|---|---|---|---|---|---|']
    for r in rows:
        o, m = r['ours'], r['mj']
        mj = ('-', '-') if m is None else (f'{m * 1e6:.2f}', f'{o["step"] / m:.1f}')
        lines.append(f'| {r["scene"]} | {o["step"] * 1e6:.2f} | {mj[0]} | {mj[1]} | '
                     f'{o["allocs"]:.1f} | {o["solves"]:.2f} | {100 * o["compiled"]:.0f} % |')
    return '\n'.join(lines) + (
        '\n\nThe fastest of {} runs each, taken alternately (the machine is shared: its '
        'other load only adds time); each run after 300 steps that settle the scene. '
        "Allocations: numba's runtime's count over a run. Where the time goes by function: "
        '`./dev.sh python bench/kernel_profile.py --perf sphere` (or `flight`, `box`, '
        '`sliding`; Linux perf).'.format(REPEATS))


def main(argv=None) -> int:
    """Print the table and write ``bench/out/kernel_profile.md``, or profile one scene."""
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--quick', action='store_true', help='5000 steps a run (20000 without)')
    p.add_argument('--perf', metavar='SCENE', choices=sorted(SHORT),
                   help='profile SCENE under perf: ' + ', '.join(sorted(SHORT)))
    p.add_argument('--record', help=argparse.SUPPRESS)   # (the run perf records)
    args = p.parse_args(argv)
    steps = 5000 if args.quick else 20000
    if args.record:
        _capture_objects()
        sim, _, _ = scene(SHORT[args.record])
        for _ in range(steps):
            sim.step(100)
        count = _write_perf_map()
        print(f'perf map /tmp/perf-{os.getpid()}.map: {count} kernel functions named',
              file=sys.stderr)
        return 0
    if args.perf:
        return profile(args.perf, steps)
    t0 = time.perf_counter()
    report.write_page(OUT, 'kernel_profile', 'Contact step cost by regime, beside MuJoCo',
                      args.quick, table(run(steps)), t0)
    return 0


#: ``--perf``'s names of the scenes.
SHORT = {'flight': 'sphere in flight', 'sphere': 'sphere at rest', 'box': 'box at rest',
         'sliding': 'box sliding'}


def profile(short: str, steps: int) -> int:
    """Run scene ``short`` (100 ``steps``) under perf; print its top 30 functions."""
    if shutil.which('perf') is None:
        print('perf is not installed (the table runs without it)')
        return 1
    with tempfile.TemporaryDirectory() as folder:
        data = os.path.join(folder, 'perf.data')
        run_ = subprocess.run(['perf', 'record', '-q', '-o', data, sys.executable, __file__,
                               '--record', short] + (['--quick'] if steps < 20000 else []),
                              check=True, capture_output=True, text=True)
        out = subprocess.run(['perf', 'report', '-i', data, '--no-children', '--sort',
                              'symbol', '--stdio'], capture_output=True, text=True).stdout
    # (the map perf read: the recorded run's, removed once read)
    for path in re.findall(r'perf map (/tmp/perf-\d+\.map)', run_.stderr):
        os.unlink(path)
    print(f"# {SHORT[short]}: {100 * steps} steps (and the set-up: its share is Python's "
          "and the loader's)")
    shown = [ln.rstrip()[:110] for ln in out.splitlines()
             if not ln.startswith('#') and '%' in ln][:30]
    print('\n'.join(shown))
    return 0


if __name__ == '__main__':
    sys.exit(main())
