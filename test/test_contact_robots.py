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

On servos (PD gains) the same robot comes to rest as its servos settle: a foot that
stops within a step sticks (two friction rows; with one, along its slip, it slipped
back and forth at 4e-5 m/s, period 2), and every contact LCP is solved (Lemke's
pivoting where the friction fixed point drifts).

The gantry (``test/urdf/gantry_pusher.urdf``) pushes a box at a constant speed: the
closed-form forces of a box sliding against Coulomb friction, through the robot's
drive (its test's comments). A strongly damped hinged rod landing on the ground takes
its contact operator from the step itself (forces of the velocities with joints).
"""

import math
from pathlib import Path

import numpy as np
import pytest

from rigid_body_sim.core import Damping, Gravity, RigidBody, Simulation
from rigid_body_sim.core.constraints import Constraint
from rigid_body_sim.core.shapes import CollisionShape
from rigid_body_sim.scene import scene_from_dict

G = 9.81
HIP = 0.6
URDF = Path(__file__).parent / 'urdf' / 'quadruped.urdf'
LEGS = ('lf', 'rf', 'lh', 'rh')
#: m: the gantry's box a little further than 0.05 m, so that its hand meets it inside a step.
EXTRA = 3e-4


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
    # At rest to rounding (its velocities change by less than 1e-12 m/s a step), the forces
    # balance the weight to m 1e-12 / dt = 1e-10 m g: 1e-9 m g leaves room.
    np.testing.assert_allclose(force, [0.0, 0.0, mass * G], rtol=0, atol=1e-9 * mass * G)
    np.testing.assert_allclose(moment, 0.0, atol=1e-9 * mass * G)
    assert np.all(rep['normal_force'] > 0.0)
    assert sim.pose('torso')[0][2] == pytest.approx(height, abs=1e-10)
    # It does not move: rounding over 1000 steps (a few ulps of the 0.5 m scale each).
    assert np.max(np.abs(sim.state.pos_com_world - p0)) <= 1e-12
    # Every solve converges (four feet under one rigid body: redundant rows, ended on
    # their residual, 1e-12 of the rows' velocities |A||p| + |q|, below 0.1 m/s here).
    cnt = rep['counters']
    assert cnt['lcp_failures'] == 0 and cnt['complementarity_max'] <= 1e-13


def test_a_quadruped_on_servos_comes_to_rest_carried_by_the_ground():
    # PD servos (kp 500 N m/rad, kd 10 N m s/rad): the legs settle as the servos' modes
    # decay, measured from 8.7e-3 m/s at 0.5 s to 1.4e-9 m/s at 4 s (about e^{-4.5 t}).
    # Before a stopped foot stuck, the fastest body stayed at 4e-5 m/s (a foot slipping
    # back and forth): 1e-7 m/s at 4 s parts the two by 400 with room 70 for the decay.
    sim, _ = _standing('servo')
    sim.step(4000)
    assert np.max(np.linalg.norm(sim.state.vel_com_world, axis=1)) <= 1e-7
    mass, rep, force, moment = _statics(sim)
    # The ground carries the weight: the bodies' accelerations, 4.5 s⁻¹ × 1e-7 m/s at
    # most, are 5e-8 of g; 1e-6 m g leaves room for the servos' slower modes.
    np.testing.assert_allclose(force, [0.0, 0.0, mass * G], rtol=0, atol=1e-6 * mass * G)
    # Every LCP solved: the fixed point (to 1e-12 of the rows' velocity scale |A||p| +
    # |q| plus twice the proximal step's last change, where it stalls), or Lemke's
    # pivoting where it drifts along the redundant feet's null space (to 1e-10 of the
    # scale). Measured: 1.9e-8 m/s at most; 1e-7 leaves room for the last change.
    cnt = rep['counters']
    assert cnt['lcp_failures'] == 0 and cnt['complementarity_max'] <= 1e-7


def test_a_gantry_arm_pushes_a_box_across_the_ground_against_its_friction():
    # A URDF gantry (test/urdf/gantry_pusher.urdf): its carriage on an exact velocity
    # drive at V along x (no effort limit: it takes V at once), its hand a frictionless
    # ball at the box's middle height, d = 0.0503 m short of the box. The hand reaches
    # the box at t = d / V, inside a step (an impact, located to 1e-10 m of gap, so to
    # 1e-10 / V in time; e = 0: the box takes V), then pushes it: the box slides at V,
    # the ground's friction is mu m g against it, the hand's push mu m g (a frictionless
    # ball: along x), and the drive's effort mu m g. The push is at the centre's height,
    # so the ground's friction turns the box forward: its normal forces carry m g with a
    # moment mu m g h/2 about the centre against it, and the box does not turn. The
    # drive holds its moving target with the constraints' time constant (0.05 s): what
    # the impact leaves of its position error is made up by e^(-t/0.05), so 0.95 s
    # later the box's speed is V to 1e-10 (from below 1e-4 m/s, times e^-19). Its
    # acceleration is then (v - V) / 0.05 s <= 2e-9 m/s², so the forces balance to
    # m 2e-9 m/s² = 2e-10 m g: 1e-9 m g leaves room.
    mu, mass, speed, half = 0.4, 1.0, 0.2, 0.1
    scene = scene_from_dict({
        'dt': 1e-3, 'effects': {'gravity': {'g_world': [0.0, 0.0, -G]}},
        'ground': {'height': 0.0, 'friction': mu},
        'bodies': [{'name': 'box', 'mass': mass, 'inertia': {'box': [2 * half] * 3},
                    'position_world': [0.2 + EXTRA, 0.0, half],
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
    assert first.time == pytest.approx((0.05 + EXTRA) / speed, abs=1e-10 / speed + 1e-12)
    assert sim.contacts()['counters']['located_steps'] >= 1   # (inside a step: located)
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


def test_a_damped_hinged_rod_lands_and_rests_with_the_steps_own_contact_operator():
    # A rod hinged at one end, its other end a ball 1 mm above the ground, the hinge
    # level with the ground's contact point (friction there has no moment about it);
    # strong viscous damping on the rod (c h / m = 1 per step: the step answers a held
    # force with about half of what the masses alone would, 1 - e^-1 of it damped
    # within the step). It falls, lands (one impact, e = 0) and rests: moments about the
    # hinge give the ground m g / 2 (the hinge the rest), with the contact operator
    # built from the step itself. At rest to rounding, the force is m g / 2 to the same
    # 1e-9 as the undamped rod's. (With the masses' operator instead, the tip lands
    # again and again: the model's corrections cannot take out its error.)
    length, radius, mass, dt = 1.0, 0.05, 3.0, 1e-3
    # (the hinge at the origin, the rod's axis r above it: turned up by 1e-3 rad about
    # the hinge, its ball's lowest point is L sin 1e-3 + r (cos 1e-3 − 1) = 1 mm up)
    lift = 1e-3
    c, s = math.cos(lift), math.sin(lift)
    rod = RigidBody('rod', mass, (1e-3, mass * length ** 2 / 12, mass * length ** 2 / 12),
                    position_world=(0.5 * length * c - radius * s, 0.0,
                                    0.5 * length * s + radius * c),
                    orientation_xyzw=(0.0, -math.sin(lift / 2), 0.0, math.cos(lift / 2)))
    hinge = Constraint('h', 'hinge', 'rod', None, anchor_world=(0, 0, 0),
                       axis_world=(0, 1, 0))
    sim = Simulation([rod], [Gravity(), Damping(linear=mass / dt, angular=0.1 / dt)],
                     integrator='rkmk4', dt=dt, constraints=[hinge],
                     shapes=[CollisionShape('plane', None),
                             CollisionShape('sphere', 'rod', radius=radius,
                                            position_body=(length / 2, 0, 0))])
    sim.step(2000)
    p0 = sim.state.pos_com_world.copy()
    sim.step(500)
    rep = sim.contacts()
    cnt = rep['counters']
    assert cnt['impacts'] == 1 and cnt['stepped_responses'] > 0
    assert cnt['lcp_failures'] == 0
    assert rep['normal_force'] == pytest.approx([mass * G / 2], rel=1e-9)
    assert np.max(np.abs(sim.state.pos_com_world - p0)) <= 1e-12
