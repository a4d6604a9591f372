"""
Ready-made constrained mechanisms: rods, chains, trees, a ring, a four-bar linkage.

Used by the benchmarks and the tests, and a starting point for users. Every
builder returns a :class:`Simulation` under gravity (``g = 9.81 m/s²``, -z).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from .bodies import RigidBody
from .constraints import Constraint
from .effects import Gravity
from .simulation import Simulation

ROD_MASS, ROD_LENGTH, ROD_RADIUS = 0.1, 0.1, 0.005


def rod(name: str, start: np.ndarray, direction: np.ndarray, length: float = ROD_LENGTH,
        mass: float = ROD_MASS) -> RigidBody:
    """
    Make a thin uniform rod of radius 5 mm from ``start`` along ``direction``.

    Its body x axis runs along the rod and its body origin is its centre.
    """
    x = np.asarray(direction, dtype=float)
    x = x / np.linalg.norm(x)
    helper = np.eye(3)[np.argmin(np.abs(x))]
    y = np.cross(x, helper)
    y /= np.linalg.norm(y)
    quat = Rotation.from_matrix(np.column_stack([x, y, np.cross(x, y)])).as_quat()
    side = mass * (3 * ROD_RADIUS**2 + length**2) / 12.0
    return RigidBody(name, mass, [0.5 * mass * ROD_RADIUS**2, side, side],
                     position_world=np.asarray(start, dtype=float) + 0.5 * length * x,
                     orientation_xyzw=quat)


def chain(n: int, integrator: str, dt: float = 1e-3) -> Simulation:
    """Build n rods along +x joined by ball joints, the first to the world at the origin."""
    bodies, joints = [], []
    for i in range(n):
        start = np.array([i * ROD_LENGTH, 0.0, 0.0])
        bodies.append(rod(f'l{i}', start, np.array([1.0, 0.0, 0.0])))
        joints.append(Constraint(f'j{i}', 'ball', f'l{i}', None if i == 0 else f'l{i - 1}',
                                 anchor_world=start))
    return Simulation(bodies, [Gravity()], integrator, dt, joints)


def tree(n: int, integrator: str, dt: float = 1e-3) -> Simulation:
    """Build a binary tree of n rods: rod i hangs from the tip of rod (i - 1) // 2."""
    rng = np.random.default_rng(1)
    bodies, joints, tips = [], [], []
    for i in range(n):
        start = np.zeros(3) if i == 0 else tips[(i - 1) // 2]
        d = rng.normal(size=3)
        d[2] = -abs(d[2]) - 0.5
        d /= np.linalg.norm(d)
        bodies.append(rod(f'l{i}', start, d))
        tips.append(start + ROD_LENGTH * d)
        joints.append(Constraint(f'j{i}', 'ball', f'l{i}', None if i == 0 else f'l{(i - 1) // 2}',
                                 anchor_world=start))
    return Simulation(bodies, [Gravity()], integrator, dt, joints)


def ring(n: int, integrator: str, dt: float = 1e-3) -> Simulation:
    """
    Build a closed ring of n rods in the x-z plane, hinged about y, hanging from the world.

    The rods form a regular polygon through the origin; rod i runs from vertex i to
    vertex i + 1, joined to rod i - 1 by a hinge at vertex i (rod 0 to the world),
    and a ball joint at the origin closes the loop: ``5 n + 3`` rows, 3 of them
    redundant, one closed loop.
    """
    radius = ROD_LENGTH / (2.0 * np.sin(np.pi / n))
    angles = -0.5 * np.pi + 2.0 * np.pi * np.arange(n + 1) / n
    vertex = radius * np.column_stack([np.cos(angles), np.zeros(n + 1), np.sin(angles) + 1.0])
    y = [0.0, 1.0, 0.0]
    bodies = [rod(f'l{i}', vertex[i], vertex[i + 1] - vertex[i]) for i in range(n)]
    joints = [Constraint(f'j{i}', 'hinge', f'l{i}', f'l{i - 1}' if i else None,
                         anchor_world=vertex[i], axis_world=y) for i in range(n)]
    joints.append(Constraint('close', 'ball', f'l{n - 1}', 'l0', anchor_world=vertex[n]))
    return Simulation(bodies, [Gravity()], integrator, dt, joints)


def four_bar(integrator: str, dt: float, crank_angle: float = np.radians(60.0)) -> Simulation:
    """
    Build a four-bar linkage in the x-z plane: ground 0.4, crank 0.1, coupler 0.35, rocker 0.3 m.

    Four hinges with parallel axes close the loop: 20 constraint rows for one
    degree of freedom, 3 of them redundant.
    """
    ground, crank, coupler, rocker = 0.4, 0.1, 0.35, 0.3
    a = np.zeros(3)
    d = np.array([ground, 0.0, 0.0])
    b = crank * np.array([np.cos(crank_angle), 0.0, np.sin(crank_angle)])
    # C: the upper intersection of the circles (B, coupler) and (D, rocker).
    bd = d - b
    dist = np.linalg.norm(bd)
    along = (coupler**2 - rocker**2 + dist**2) / (2.0 * dist)
    h = np.sqrt(coupler**2 - along**2)
    perp = np.array([-bd[2], 0.0, bd[0]]) / dist
    c = b + along * bd / dist + h * perp
    if c[2] < 0:
        c = b + along * bd / dist - h * perp
    bodies = [rod('crank', a, b - a, crank, 0.2), rod('coupler', b, c - b, coupler, 0.5),
              rod('rocker', d, c - d, rocker, 0.4)]
    y = [0.0, 1.0, 0.0]
    joints = [Constraint('A', 'hinge', 'crank', None, anchor_world=a, axis_world=y),
              Constraint('B', 'hinge', 'coupler', 'crank', anchor_world=b, axis_world=y),
              Constraint('C', 'hinge', 'rocker', 'coupler', anchor_world=c, axis_world=y),
              Constraint('D', 'hinge', 'rocker', None, anchor_world=d, axis_world=y)]
    return Simulation(bodies, [Gravity()], integrator, dt, joints)
