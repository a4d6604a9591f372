"""
URDF robots touching things: a quadruped standing on its four feet, a gantry pushing a box.

The quadruped (``test/urdf/quadruped.urdf``) stands with its joints held.

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

The gantry (``test/urdf/gantry_pusher.urdf``) pushes a box at a constant speed: the
closed-form forces of a box sliding against Coulomb friction, through the robot's
drive (its test's comments).
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


def test_a_gantry_arm_pushes_a_box_across_the_ground_against_its_friction():
    # A URDF gantry (test/urdf/gantry_pusher.urdf): its carriage on an exact velocity
    # drive at V along x (no effort limit: it takes V at once), its hand a frictionless
    # ball at the box's middle height, 0.05 m short of the box. The hand reaches the
    # box at t = 0.05 / V (an impact, located to 1e-10 m of gap, so to 1e-10 / V in
    # time; e = 0: the box takes V), then pushes it: the box slides at V, the ground's
    # friction is mu m g against it, the hand's push mu m g (a frictionless ball: along
    # x), and the drive's effort mu m g. The push is at the centre's height, so the
    # ground's friction turns the box forward: its normal forces carry m g with a
    # moment mu m g h/2 about the centre against it, and the box does not turn. The
    # drive holds its moving target with the constraints' time constant (0.05 s): what
    # the impact leaves of its position error is made up by e^(-t/0.05), so 0.95 s
    # later the box's speed is V to 1e-10 (from below 1e-4 m/s, times e^-19).
    mu, mass, speed, half = 0.4, 1.0, 0.2, 0.1
    scene = scene_from_dict({
        'dt': 1e-3, 'effects': {'gravity': {'g_world': [0.0, 0.0, -G]}},
        'ground': {'height': 0.0, 'friction': mu},
        'bodies': [{'name': 'box', 'mass': mass, 'inertia': {'box': [2 * half] * 3},
                    'position_world': [0.2, 0.0, half],
                    'shapes': [{'kind': 'box', 'size': [2 * half] * 3, 'friction': mu}]}],
        'robots': [{'urdf': str(URDF.parent / 'gantry_pusher.urdf'),
                    'effort_limits': False, 'collisions': {'friction': 0.0}}],
        'command_groups': [
            {'name': 'slide', 'joints': ['slide'], 'interface': 'velocity', 'mode': 'exact'},
            {'name': 'wrist', 'joints': ['wrist'], 'interface': 'position', 'mode': 'exact'}]},
        str(URDF))
    sim = scene.simulation
    sim.command_joints({'slide': speed, 'wrist': 0.0})
    sim.step(1200)
    first = sim.contact.impacts[0]
    assert 'hand' in first.shape_b and 'box' in first.shape_a
    assert first.time == pytest.approx(0.05 / speed, abs=1e-10 / speed + 1e-12)
    rep = sim.contacts()
    weight = mass * G
    hand = [k for k, b in enumerate(rep['body_b']) if b == 'hand']
    ground = [k for k, b in enumerate(rep['body_b']) if b == 'world']
    assert len(hand) == 1 and len(ground) == 4
    push = rep['normal_force'][hand[0]] * rep['normal'][hand[0]]   # on the box
    np.testing.assert_allclose(push, [mu * weight, 0.0, 0.0], rtol=0, atol=1e-9 * weight)
    ground_force = sum(rep['normal_force'][k] * rep['normal'][k] + rep['friction_force'][k]
                       for k in ground)
    np.testing.assert_allclose(ground_force, [-mu * weight, 0.0, weight], rtol=0,
                               atol=1e-9 * weight)
    velocity, omega = sim.twist('box')
    # (the contacts are read at the step's start, rep['time']: the box was V dt behind)
    centre = sim.pose('box')[0] - velocity * (sim.time - rep['time'])
    moment = sum(np.cross(rep['point'][k] - centre, rep['normal_force'][k] * rep['normal'][k]
                          + rep['friction_force'][k]) for k in hand + ground)
    np.testing.assert_allclose(moment, 0.0, atol=1e-9 * weight * half)
    np.testing.assert_allclose(velocity, [speed, 0.0, 0.0], rtol=0, atol=1e-10)
    np.testing.assert_allclose(omega, 0.0, atol=1e-12)
    effort = sim.joint_state(['slide']).efforts[0]
    assert effort == pytest.approx(mu * weight, rel=1e-9)
    assert rep['counters']['lcp_failures'] == 0
