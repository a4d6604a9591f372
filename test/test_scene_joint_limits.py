"""
Limits and Coulomb friction on a scene's hinges and sliders (not a robot's joints).

A ``hinge`` or ``slider`` constraint of a scene with ``lower``, ``upper``,
``restitution`` or ``friction`` becomes a joint of the joint space, its coordinate 0
where the scene starts, held by the same rows and events as a URDF joint's
(``test_joint_limits.py``). References in closed form: free fall onto a bound (the
impact time and impulse, then the static force), a pendulum at rest on a bound, a
rod below its breakaway torque.
"""

import re

import numpy as np
import pytest
from rigid_body_sim.scene import scene_from_dict, SceneError

G = 9.81
MASS = 2.0


def build(constraint, bodies=None, gravity=True, integrator='lie_poisson2', dt=1e-3):
    """Load a scene of one body (``block``) and ``constraint`` (a dict)."""
    bodies = bodies or [{'name': 'block', 'mass': MASS, 'inertia': [0.02, 0.03, 0.04],
                         'position_world': [0.3, -0.2, 1.0],
                         'orientation_rpy': [0.3, -0.2, 0.5]}]
    data = {'dt': dt, 'integrator': integrator, 'bodies': bodies,
            'constraints': [constraint]}
    if gravity:
        data['effects'] = {'gravity': {'g_world': [0.0, 0.0, -G]}}
    return scene_from_dict(data, 'scene_joints.yaml').simulation


def test_a_slider_falls_onto_its_lower_bound_impulse_m_v_then_rests_on_m_g():
    # A block on a vertical slider to the world, its lower bound 0.5 m below the start:
    # it falls freely for t* = sqrt(2 h / g), hits at v = g t* (located to 1e-10 m), an
    # inelastic impact stops it (the impulse m v), and it then rests on the bound, whose
    # force is m g (the joint's effort: the slider's coordinate is along +z).
    h = 0.5
    sim = build({'name': 'rail', 'type': 'slider', 'body_a': 'block', 'body_b': 'world',
                 'axis_world': [0, 0, 1], 'lower': -h})
    assert sim.joint_names() == ['rail']
    t_star = np.sqrt(2 * h / G)
    sim.step(int(t_star / sim.dt) + 200)
    [impact] = sim.joint_limits()['impacts']
    assert impact.joint == 'rail' and impact.side == 1 and impact.rebound == 0.0
    # bound: the crossing located to 1e-10 m at a speed of 3.1 m/s: 3e-11 s; the
    # free fall is exact in lie_poisson2 (constant force) to rounding.
    assert impact.time == pytest.approx(t_star, abs=1e-10)
    assert MASS * -impact.approach == pytest.approx(MASS * G * t_star, rel=1e-9)
    js = sim.joint_state()
    assert js.positions[0] == pytest.approx(-h, abs=1e-12)
    assert abs(js.velocities[0]) < 1e-12
    # bound: the solve's rounding, 1e-12 of m g.
    assert js.efforts[0] == pytest.approx(MASS * G, rel=1e-12)
    assert sim.joint_limits()['active'] == {'rail': 'lower'}


def test_a_scene_pendulum_rests_on_its_upper_bound_with_the_static_torque():
    # A rod hanging from a world hinge (axis y) through its end, started horizontal:
    # it swings down and its angle grows (about +y, the rod along +x falls to −z) to
    # the upper bound 0.6 rad, where e = 0 stops it; at rest there the bound holds the
    # weight's torque m g l cos(0.6).
    length = 0.4
    bodies = [{'name': 'rod', 'mass': MASS, 'inertia': [0.001, 0.03, 0.03],
               'position_world': [length, 0.0, 1.0]}]
    sim = build({'name': 'pivot', 'type': 'hinge', 'body_a': 'rod', 'body_b': 'world',
                 'anchor_world': [0, 0, 1], 'axis_world': [0, 1, 0], 'upper': 0.6},
                bodies=bodies)
    sim.step(3000)
    js = sim.joint_state()
    assert sim.joint_limits()['active'] == {'pivot': 'upper'}
    assert js.positions[0] == pytest.approx(0.6, abs=1e-12)
    # The bound pushes back (negative along q): −m g l cos θ.
    assert js.efforts[0] == pytest.approx(-MASS * G * length * np.cos(0.6), rel=1e-10)
    with pytest.raises(Exception, match='scene constraint with limits or friction'):
        sim.set_joint_state({'pivot': 0.1})


def test_a_hinge_below_its_breakaway_torque_does_not_move_and_above_it_accelerates():
    # No gravity; the wheel on a hinge (axis z, through its centre of mass) with Coulomb
    # friction F = 0.5 N m: an effort of 0.4 N m leaves it still (the stick row carries
    # it), 0.7 N m turns it at (τ − F) / I.
    bodies = [{'name': 'wheel', 'mass': 1.0, 'inertia': [0.15, 0.15, 0.25],
               'position_world': [0, 0, 1]}]
    sim = build({'name': 'axle', 'type': 'hinge', 'body_a': 'wheel', 'body_b': 'world',
                 'anchor_world': [0, 0, 1], 'axis_world': [0, 0, 1], 'friction': 0.5},
                bodies=bodies, gravity=False)
    sim.set_joint_efforts({'axle': 0.4})
    sim.step(1000)
    js = sim.joint_state()
    assert abs(js.positions[0]) < 1e-12 and sim.joint_friction()['sticking'] == ['axle']
    assert js.efforts[0] == pytest.approx(0.0, abs=1e-12)   # command + friction's −0.4
    sim.set_joint_efforts({'axle': 0.7})
    sim.step(1000)
    js = sim.joint_state()
    # bound: the breakaway at the command (a located event at the step's start); then
    # a constant torque, exact in lie_poisson2 to rounding.
    assert js.velocities[0] == pytest.approx((0.7 - 0.5) / 0.25 * 1.0, rel=1e-9)


def test_infinite_friction_locks_a_hinge_and_zero_friction_leaves_it_free():
    # f = inf: the sticking row never lets go, whatever the effort (1e4 N m); f = 0: no
    # row at all (free), the wheel turns at τ / I.
    bodies = [{'name': 'wheel', 'mass': 1.0, 'inertia': [0.15, 0.15, 0.25],
               'position_world': [0, 0, 1]}]
    for friction, rate in ((float('inf'), 0.0), (0.0, 1e4 / 0.25)):
        sim = build({'name': 'axle', 'type': 'hinge', 'body_a': 'wheel', 'body_b': 'world',
                     'anchor_world': [0, 0, 1], 'axis_world': [0, 0, 1],
                     'friction': friction}, bodies=bodies, gravity=False)
        sim.set_joint_efforts({'axle': 1e4})
        sim.step(100)
        js = sim.joint_state()
        # bound: rounding of the held row (1e-16 rad/s) or of a constant torque (1e-12).
        assert js.velocities[0] == pytest.approx(rate * sim.time, rel=1e-12, abs=1e-12)
        assert sim.joint_friction().get('sticking', []) == (['axle'] if rate == 0.0 else [])


@pytest.mark.parametrize('extra, field, problem', [
    ({'lower': 1.0, 'upper': 0.5}, 'constraints[0].lower', 'above upper'),
    ({'restitution': 1.5}, 'constraints[0].restitution', r'\[0, 1\]'),
    ({'friction': -1.0}, 'constraints[0].friction', '>= 0'),
    ({'friction': float('nan')}, 'constraints[0].friction', '>= 0'),
    ({'upper': float('nan')}, 'constraints[0].upper', 'finite'),
])
def test_bad_limits_and_friction_are_refused_naming_the_field(extra, field, problem):
    with pytest.raises(SceneError, match=rf'{re.escape(field)}.*{problem}'):
        build({'name': 'rail', 'type': 'slider', 'body_a': 'block', 'axis_world': [0, 0, 1],
               **extra})


def test_limits_on_a_ball_joint_are_refused():
    with pytest.raises(SceneError, match=r'constraints\[0\].lower: .*hinge and slider'):
        build({'name': 'ball', 'type': 'ball', 'body_a': 'block', 'anchor_world': [0, 0, 1],
               'lower': 0.0})
