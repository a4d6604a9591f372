"""
A URDF quadruped standing on its four feet (``test/urdf/quadruped.urdf``), its joints held.

The robot: a 10 kg torso and four like legs (hip and knee about y, 0.25 m thigh and
shank, 1 kg and 0.5 kg, a 0.03 m ball foot). At hip ``θ`` and knee ``−2θ`` each foot
lies straight below its hip, so the torso's centre stands at ``h = 0.5 cos θ + 0.03``
above the ground.

On exact drives (``mode: exact``, the joints held at their targets by driving
constraints) the robot is one rigid body standing on four points. It stands at ``h``
(to the contacts' tolerance, 1e-10 m), does not move (rounding over the run), and the
ground carries its weight: the normal forces sum to ``m g`` and their moments about
the centre of mass vanish (the four forces are not unique, only these sums are). Four
feet under one rigid body are redundant rows: the friction iteration ends on the
contact conditions' residual there (the iterates drift among the solutions), and none
of its solves fails.

On servos (PD gains) the same robot is not yet at rest: a period-2 oscillation of a
foot (about 1e-4 m/s) stays, the held contact force over a step meeting a servo whose
damping acts within it (``kd c h`` near 1). It is not tested here as done.
"""

import math
from pathlib import Path

import numpy as np
import pytest

from rigid_body_sim.scene import scene_from_dict

G = 9.81
HIP = 0.6
URDF = Path(__file__).parent / 'urdf' / 'quadruped.urdf'
LEGS = ('lf', 'rf', 'lh', 'rh')


def _standing(mode, drop=0.0):
    """Return the quadruped on ``mode`` drives, its feet ``drop`` above the ground, and ``h``."""
    targets = {}
    for leg in LEGS:
        targets[f'{leg}_hip'], targets[f'{leg}_knee'] = HIP, -2.0 * HIP
    group = {'name': 'legs', 'joints': list(targets), 'interface': 'position', 'mode': mode}
    if mode == 'servo':
        group.update(kp=500.0, kd=10.0)
    height = 0.5 * math.cos(HIP) + 0.03
    scene = scene_from_dict({
        'dt': 1e-3, 'effects': {'gravity': {'g_world': [0.0, 0.0, -G]}},
        'ground': {'height': 0.0, 'friction': 0.8},
        'robots': [{'urdf': str(URDF), 'base_pose': {'xyz': [0.0, 0.0, height + drop]},
                    'initial_positions': targets, 'collisions': True}],
        'command_groups': [group]}, str(URDF))
    sim = scene.simulation
    sim.command_joints(targets)
    return sim, height


def _statics(sim):
    """Return the robot's mass, its contacts, their force sum and moment about its centre."""
    rep = sim.contacts()
    mass = float(np.sum(sim.bodies.mass))
    com = np.sum(sim.bodies.mass[:, None] * sim.state.pos_com_world, axis=0) / mass
    force = rep['normal_force'][:, None] * rep['normal'] + rep['friction_force']
    moment = np.sum(np.cross(rep['point'] - com, force), axis=0)
    return mass, rep, np.sum(force, axis=0), moment


def test_a_quadruped_on_exact_drives_stands_at_its_height_carried_by_the_ground():
    sim, height = _standing('exact')
    p0 = sim.state.pos_com_world.copy()
    sim.step(1000)
    mass, rep, force, moment = _statics(sim)
    assert sorted(rep['body_a']) == sorted(f'{leg}_shank' for leg in LEGS)
    np.testing.assert_allclose(force, [0.0, 0.0, mass * G], rtol=0, atol=1e-9 * mass * G)
    np.testing.assert_allclose(moment, 0.0, atol=1e-9 * mass * G)
    assert np.all(rep['normal_force'] > 0.0)
    assert sim.pose('torso')[0][2] == pytest.approx(height, abs=1e-10)
    # It does not move: rounding over 1000 steps (a few ulps of the 0.5 m scale each).
    assert np.max(np.abs(sim.state.pos_com_world - p0)) <= 1e-12
    cnt = rep['counters']
    assert cnt['lcp_failures'] == 0 and cnt['complementarity_max'] <= 1e-12
