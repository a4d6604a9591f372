"""
Contact islands: the contact LCP solved island by island, compiled and in Python.

Contacts that no impulse couples (no body shared, no joint between their bodies) make
the Delassus operator block diagonal, and its LCP decouples exactly. References: the
partition of random block-sparse operators against a union-find written here; both
paths partitioning alike; steps of scenes of separate resting and sliding objects the
same with islands and with one solve of all rows, to the solver's tolerance (its fixed
point ends within 1e-8 of the largest impulse; the two differ in their proximal term's
scale and their stopping tests, nothing else); the compiled steps equal to the Python
path's (1e-12).
"""

import numpy as np
import pytest

from rigid_body_sim.core import CollisionShape, Gravity, RigidBody, Simulation
from rigid_body_sim.core import contact_step
from rigid_body_sim.core.kernels import contact_step as kern


def _blocks(c, edges, rng):
    """Return a 3c × 3c matrix whose 3 × 3 blocks are non-zero on the diagonal and ``edges``."""
    A = np.zeros((3 * c, 3 * c))
    for k in range(c):
        A[3 * k:3 * k + 3, 3 * k:3 * k + 3] = np.eye(3) + 0.1 * rng.standard_normal((3, 3))
    for k, j in edges:   # (one entry of the block: a single non-zero joins them)
        A[3 * k + rng.integers(3), 3 * j + rng.integers(3)] = rng.standard_normal()
    return A


def _reference(c, edges):
    parent = list(range(c))

    def find(x):
        while parent[x] != x:
            x = parent[x]
        return x
    for k, j in edges:
        a, b = find(k), find(j)
        parent[max(a, b)] = min(a, b)
    groups = {}
    for k in range(c):
        groups.setdefault(find(k), []).append(k)
    return sorted(groups.values())


@pytest.mark.parametrize('seed', range(6))
def test_islands_are_the_connected_parts_of_the_blocks_both_paths(seed):
    rng = np.random.default_rng(seed)
    c = 30
    edges = [tuple(e) for e in rng.integers(0, c, size=(int(rng.integers(0, 40)), 2))
             if e[0] != e[1]]
    A = _blocks(c, edges, rng)
    expected = _reference(c, edges)
    assert [g.tolist() for g in contact_step.islands(A)] == expected
    label, count = kern.islands(kern.blocks(A))   # (the compiled path's blocks)
    assert count == len(expected)
    assert [np.flatnonzero(label == g).tolist() for g in range(count)] == expected


def _apart(n=6):
    """Boxes resting and sliding on the ground far apart, and two stacked (one island)."""
    bodies, shapes = [], [CollisionShape('plane', None, friction=0.6)]
    for k in range(n):
        bodies.append(RigidBody(f'b{k}', 1.0 + k, ((1.0 + k) * 0.02 / 6,) * 3,
                                position_world=(2.0 * k, 0.0, 0.1),
                                linear_velocity_world=(0.3 * (k % 3), 0.0, 0.0)))
        shapes.append(CollisionShape('box', f'b{k}', size=(0.2, 0.2, 0.2), friction=0.6))
    for k in range(2):   # a box on a box: their contacts one island
        bodies.append(RigidBody(f'p{k}', 1.0, (0.02 / 6,) * 3,
                                position_world=(0.0, 3.0, 0.1 + 0.2 * k)))
        shapes.append(CollisionShape('box', f'p{k}', size=(0.2, 0.2, 0.2), friction=0.6))
    return Simulation(bodies, [Gravity()], integrator='rkmk4', dt=1e-3, shapes=shapes)


def test_separate_objects_step_alike_in_islands_and_in_one_solve(monkeypatch):
    runs = []
    for split in (True, False):
        if not split:
            monkeypatch.setattr(contact_step, 'islands', lambda A: [np.arange(len(A) // 3)])
        sim = _apart()
        sim.contact.compiled = False
        sim.step(150)
        runs.append((sim.state.pos_com_world.copy(), sim.state.vel_com_world.copy(),
                     sim.contact.counters['lcp_failures']))
    (p1, v1, f1), (p2, v2, f2) = runs
    assert f1 == f2 == 0
    # Impulses within 1e-8 of the largest (~ m g dt = 0.06 N s): velocities within 1e-8
    # m/s a step, positions 1e-11 m a step; 150 steps: 2e-6 m/s, 2e-9 m with room.
    np.testing.assert_allclose(v1, v2, rtol=0, atol=2e-6)
    np.testing.assert_allclose(p1, p2, rtol=0, atol=2e-9)


def test_compiled_islands_are_the_python_paths():
    sims = []
    for compiled in (True, False):
        sim = _apart()
        sim.contact.compiled = compiled
        sim.step(150)
        sims.append(sim)
    a, b = sims
    assert a.contact.counters['compiled_steps'] == 150
    assert b.contact.counters['compiled_steps'] == 0
    np.testing.assert_allclose(a.state.y, b.state.y, rtol=0, atol=1e-12)
