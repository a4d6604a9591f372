"""
The compiled steps run unchanged as plain Python (``NUMBA_DISABLE_JIT=1``).

The design promises it for debugging. The kernels pass views without reference
counts (``kernels.views.raw``) and tables of array addresses
(``kernels.views.Pinned``); under plain Python these must be ordinary numpy
views, and the steps must give what the compiled ones give.
"""

import json
import os
from pathlib import Path
import subprocess
import sys

import numpy as np

SCENES = r"""
import json, sys
import numpy as np
from rigid_body_sim.core import Constraint, Damping, Gravity, RigidBody, Simulation
from rigid_body_sim.core.mechanisms import ring
out = {}
for m in ('symplectic_euler', 'lie_poisson2', 'lie_poisson4', 'rkmk4'):
    free = Simulation([RigidBody('a', 1.0, (1.0, 2.0, 3.0), angular_velocity_body=(0.3, 2, 0.1))],
                      [Gravity(), Damping(0.1, 0.1)], m, 1e-2)
    free.apply_wrench('a', (1.0, 0.0, 0.0), (0.0, 0.1, 0.0), point_body=(0.1, 0.0, 0.0))
    free.step(5)
    free.pose()
    free.step(5)
    links = [RigidBody(f'l{i}', 1.0, (1e-4, 1e-3, 1e-3), position_world=(0.1 * i + 0.05, 0, 0))
             for i in range(12)]
    joints = [Constraint(f'j{i}', 'hinge', f'l{i}', f'l{i - 1}' if i else None,
                         anchor_world=(0.1 * i, 0, 0), axis_world=(0, 1, 0)) for i in range(12)]
    chain = Simulation(links, [Gravity()], m, 1e-3, joints)
    chain.step(5)
    chain.pose()
    chain.step(5)
    loop = ring(10, m)
    loop.step(3)
    out[m] = [np.hstack(s.pose() + s.twist()).ravel().tolist() for s in (free, chain, loop)]
print(json.dumps(out))
"""


def _run(jit: bool) -> dict:
    env = dict(os.environ)
    env.pop('NUMBA_DISABLE_JIT', None)
    if not jit:
        env['NUMBA_DISABLE_JIT'] = '1'
    root = Path(__file__).resolve().parents[1]
    result = subprocess.run([sys.executable, '-c', SCENES], env=env, cwd=root,
                            capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr
    return json.loads(result.stdout.strip().splitlines()[-1])


def test_plain_python_steps_match_the_compiled_ones():
    """A free body with every effect, a chain (tree solve) and a ring (loop solve)."""
    compiled, plain = _run(jit=True), _run(jit=False)
    assert compiled.keys() == plain.keys() == {'symplectic_euler', 'lie_poisson2',
                                               'lie_poisson4', 'rkmk4'}
    for method in compiled:
        for a, b in zip(compiled[method], plain[method]):
            a, b = np.array(a), np.array(b)
            assert a.shape == b.shape and np.all(np.isfinite(a))
            # Rounding only: the same operations, but LLVM may fuse and reorder (SI values
            # <= 2): a 1-ulp change moves the ring 9e-14, SHAKE stops anywhere below 1e-13 m,
            # velocities follow x50 (measured 1.8e-15 m -> 7.9e-14 m/s on the ring).
            # bound: 10 steps x 1e-13 x 50 = 5e-11; a wrong step differs by >= dt^2 g ~ 1e-5.
            assert np.allclose(a, b, rtol=0, atol=1e-10), (method, np.abs(a - b).max())
