"""
Compile (or load from numba's cache) every compiled kernel of the core once.

numba compiles a kernel at its first call and caches the machine code next to
the source (``__pycache__``); the first run on a machine takes about 330 s (2 cores), a
later one 0.4 s. ``./dev.sh`` runs ``python -m rigid_body_sim.core.warmup``
after the set-up, so neither the node's first start nor a test pays for it.
The scenes below take every kernel path with the argument types of real runs:
a free body with every effect, a small constrained scene (dense solves), a
chain long enough for the tree solve and a ring (a closed loop: the tree solve
of a spanning tree and the Schur complement of the loop-closing rows); the
complementarity problems' projected Gauss–Seidel sweeps on a small problem; one
collision shape of each kind, all touching (:mod:`.shapes`); a box resting on the
ground (:mod:`.kernels.contact_step`), free and held by a joint (the LCP solve of the
steps that run in Python).
"""

from __future__ import annotations

import time

import numpy as np

from .bodies import RigidBody
from .complementarity import solve_pgs
from .constraints import Constraint
from .effects import Damping, Gravity
from .mechanisms import ring
from .shapes import CollisionShape, ContactDetector
from .simulation import Simulation


def warm_up() -> float:
    """Step small scenes through every kernel; returns the seconds it took."""
    start = time.perf_counter()
    free = Simulation([RigidBody('box', 1.0, (1.0, 2.0, 3.0), angular_velocity_body=(0, 1, 0))],
                      [Gravity(), Damping(0.1, 0.1)], 'lie_poisson2', 1e-3)
    free.apply_wrench('box', (1.0, 0.0, 0.0), (0.0, 0.1, 0.0), point_body=(0.1, 0.0, 0.0))
    free.step(2)
    free.pose(), free.twist()
    for links in (2, 12):   # dense rows, then the tree solve
        bodies = [RigidBody(f'l{i}', 1.0, (1e-4, 1e-3, 1e-3),
                            position_world=(0.1 * i + 0.05, 0, 0))
                  for i in range(links)]
        joints = [Constraint(f'j{i}', 'hinge', f'l{i}', f'l{i - 1}' if i else None,
                             anchor_world=(0.1 * i, 0, 0), axis_world=(0, 1, 0))
                  for i in range(links)]
        chain = Simulation(bodies, [Gravity()], 'lie_poisson2', 1e-3, joints)
        chain.step(2)
        chain.reactions()
    ring(10, 'lie_poisson2').step(2)   # 53 rows: beyond the dense size
    solve_pgs(np.eye(2), np.ones(2), np.zeros(2), np.full(2, np.inf))   # (large LCPs)
    # Collision detection: one shape of each kind, all touching (every narrow phase).
    kinds = [{'kind': 'sphere', 'radius': 0.3},
             {'kind': 'box', 'size': (0.5, 0.5, 0.5)},
             {'kind': 'capsule', 'radius': 0.2, 'length': 0.4},
             {'kind': 'cylinder', 'radius': 0.2, 'length': 0.4},
             {'kind': 'cylinder', 'radius': 0.1, 'length': 0.3}]
    bodies = [RigidBody(f's{i}', 1.0, (1.0, 1.0, 1.0), position_world=(0.2 * i, 0, 0.2))
              for i in range(len(kinds))]
    shapes = [CollisionShape(body=b.name, **k) for b, k in zip(bodies, kinds)]
    shapes.append(CollisionShape('plane'))
    touching = Simulation(bodies, [], 'lie_poisson2', 1e-3)
    ContactDetector(shapes, [b.name for b in bodies]).detect(touching._outputs_now())
    # Contact steps: a box resting on the ground (the compiled steps of free bodies).
    resting = Simulation([RigidBody('box', 1.0, (1.0, 1.0, 1.0), position_world=(0, 0, 0.25))],
                         [Gravity()], 'rkmk4', 1e-3,
                         shapes=[CollisionShape('plane'),
                                 CollisionShape('box', 'box', size=(0.5, 0.5, 0.5))])
    resting.step(3)
    # Contact with joints: a box held by a ball joint 1 m away, resting on the ground (the
    # steps in Python, their LCPs by the compiled solve).
    held = Simulation([RigidBody('box', 1.0, (1.0, 1.0, 1.0), position_world=(0, 0, 0.25))],
                      [Gravity()], 'rkmk4', 1e-3,
                      [Constraint('arm', 'ball', 'box', None, anchor_world=(-1.0, 0, 0.25))],
                      shapes=[CollisionShape('plane'),
                              CollisionShape('box', 'box', size=(0.5, 0.5, 0.5))])
    held.step(3)
    return time.perf_counter() - start


if __name__ == '__main__':
    print(f'compiled kernels ready ({warm_up():.1f} s)')
