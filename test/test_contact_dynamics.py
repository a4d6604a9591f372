"""
Contact forces, friction and impacts against closed-form solutions (:mod:`.contact_step`).

Every reference here is exact for the scene: free flight under constant gravity (every
integrator below is exact for it to rounding: RKMK4 and the Lie–Poisson methods
reproduce a quadratic trajectory), Newton's restitution at a located impact, Coulomb's
law on an incline, a sphere rolling without slip. The tolerances are the impact's
location tolerance (1e-10 m of gap, so a time off by at most 1e-10 m over the approach
speed), the first-order stop of a sliding block inside its last step (``μ g h² / 2``),
and rounding (ulps of the largest term, times the steps taken).
"""

import math
import re

import numpy as np
import pytest

from rigid_body_sim.core import Gravity, RigidBody, Simulation
from rigid_body_sim.core.constraints import Constraint
from rigid_body_sim.core.contact_step import LOCATION_TOLERANCE
from rigid_body_sim.core.shapes import CollisionShape

G = 9.81


def _ball(radius=0.1, mass=1.0, height=0.5, e=0.5, mu=1.0, integrator='rkmk4', dt=1e-3,
          velocity=(0.0, 0.0, 0.0)):
    inertia = 0.4 * mass * radius ** 2
    ball = RigidBody('ball', mass, (inertia, inertia, inertia), position_world=(0, 0, height),
                     linear_velocity_world=velocity)
    shapes = [CollisionShape('plane', None, restitution=e, friction=mu, name='ground'),
              CollisionShape('sphere', 'ball', radius=radius, restitution=e, friction=mu)]
    return Simulation([ball], [Gravity()], integrator=integrator, dt=dt, shapes=shapes)


def _incline(theta, mu, kind='box', dt=1e-3, speed=0.0, half=0.1, mass=2.0):
    """Return a body resting on a plane tilted by ``theta`` about x, and the downslope."""
    c, s = math.cos(theta), math.sin(theta)
    quat = (math.sin(theta / 2), 0.0, 0.0, math.cos(theta / 2))
    normal = np.array([0.0, -s, c])
    down = np.array([0.0, -c, -s])
    if kind == 'box':
        inertia = mass * (2 * half) ** 2 / 6
        shape = CollisionShape('box', 'b', size=(2 * half,) * 3, friction=mu)
    else:
        inertia = 0.4 * mass * half ** 2
        shape = CollisionShape('sphere', 'b', radius=half, friction=mu)
    body = RigidBody('b', mass, (inertia,) * 3, position_world=half * normal,
                     orientation_xyzw=quat, linear_velocity_world=speed * down)
    ground = CollisionShape('plane', None, orientation_xyzw=quat, friction=mu)
    return Simulation([body], [Gravity()], integrator='rkmk4', dt=dt,
                      shapes=[ground, shape]), down


@pytest.mark.parametrize('integrator', ['rkmk4', 'lie_poisson2', 'lie_poisson4'])
def test_a_dropped_ball_bounces_to_e_2k_h_at_the_analytic_times(integrator):
    radius, drop, e = 0.1, 0.4, 0.5
    sim = _ball(radius, height=radius + drop, e=e, integrator=integrator)
    apexes = []
    for _ in range(1600):
        sim.step()
        z = sim.state.pos_com_world[0, 2] - radius
        vz = sim.state.vel_com_world[0, 2]
        apexes.append(z + vz * vz / (2 * G))   # the height this flight reaches
    impacts = list(sim.contact.impacts)
    v1 = math.sqrt(2 * G * drop)
    t = math.sqrt(2 * drop / G)
    for k, impact in enumerate(impacts[:5]):
        speed = v1 * e ** k
        # Located to 1e-10 m of gap: the time to that over the speed, with rounding's room.
        assert impact.time == pytest.approx(t, abs=LOCATION_TOLERANCE / speed + 1e-12)
        assert impact.approach == pytest.approx(-speed, rel=1e-9)
        assert impact.rebound == pytest.approx(e * speed, rel=1e-9)
        t += 2 * e * speed / G
    # Between bounces k and k + 1 the flight's height is e^{2k} h (energy to rounding).
    times = sim.dt * np.arange(1, 1601)
    edges = [0.0] + [i.time for i in impacts[:5]]
    for k in range(1, 5):
        inside = (times > edges[k] + 2 * sim.dt) & (times < edges[k + 1] - 2 * sim.dt)
        assert np.any(inside)
        heights = np.array(apexes)[inside]
        np.testing.assert_allclose(heights, e ** (2 * k) * drop, rtol=1e-9)


def test_a_ball_without_restitution_rests_carrying_its_weight():
    sim = _ball(e=0.0, mass=1.5)
    sim.step(1000)
    z0 = sim.state.pos_com_world[0].copy()
    sim.step(2000)
    # At rest: no creep over 2 s, the ground carries m g.
    assert np.max(np.abs(sim.state.pos_com_world[0] - z0)) <= 1e-15
    assert np.max(np.abs(sim.state.vel_com_world)) <= 1e-15
    assert abs(sim.state.pos_com_world[0, 2] - 0.1) <= LOCATION_TOLERANCE
    force = sim.contact.record.force.sum(axis=0)
    np.testing.assert_allclose(force, [0.0, 0.0, 1.5 * G], rtol=1e-13, atol=1e-13)


def test_a_perfectly_elastic_ball_never_gains_energy():
    radius, drop = 0.1, 0.3
    sim = _ball(radius, height=radius + drop, e=1.0)
    heights = []
    for _ in range(2000):
        sim.step()
        z = sim.state.pos_com_world[0, 2] - radius
        heights.append(z + sim.state.vel_com_world[0, 2] ** 2 / (2 * G))
    assert len(sim.contact.impacts) >= 3
    # Each impact located within 1e-10 m of the ground, and v' = −v exactly: the height
    # is kept to rounding.
    np.testing.assert_allclose(heights, drop, rtol=1e-9)


@pytest.mark.parametrize('theta, mu', [(0.3, 0.5), (0.5, 0.6), (0.2, 10.0)])
def test_a_block_on_an_incline_sticks_while_tan_theta_is_below_mu(theta, mu):
    assert math.tan(theta) < mu
    sim, _ = _incline(theta, mu, dt=1e-2)
    p0 = sim.state.pos_com_world[0].copy()
    sim.step(1000)   # 10 s
    assert np.max(np.abs(sim.state.pos_com_world[0] - p0)) <= 1e-14
    # The contact force carries the weight exactly: −m g, within the friction cone.
    force = sim.contact.record.force.sum(axis=0)
    np.testing.assert_allclose(force, [0.0, 0.0, 2.0 * G], rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize('theta, mu', [(0.3, 0.2), (0.5, 0.0), (0.7, 0.5)])
def test_a_block_on_an_incline_slides_at_g_sin_minus_mu_cos_above(theta, mu):
    assert math.tan(theta) > mu
    sim, down = _incline(theta, mu)
    p0 = sim.state.pos_com_world[0].copy()
    sim.step(1000)
    travel = sim.state.pos_com_world[0] - p0
    expected = 0.5 * G * (math.sin(theta) - mu * math.cos(theta))
    np.testing.assert_allclose(travel, expected * down, rtol=1e-11, atol=1e-13)


def test_a_box_sliding_on_flat_ground_stops_after_v2_over_2_mu_g():
    mu, v0, dt = 0.5, 1.0, 1e-3
    half, mass = 0.1, 2.0
    inertia = mass * (2 * half) ** 2 / 6
    box = RigidBody('b', mass, (inertia,) * 3, position_world=(0, 0, half),
                    linear_velocity_world=(v0, 0, 0))
    shapes = [CollisionShape('plane', None, friction=mu),
              CollisionShape('box', 'b', size=(2 * half,) * 3, friction=mu)]
    sim = Simulation([box], [Gravity()], integrator='rkmk4', dt=dt, shapes=shapes)
    sim.step(400)
    distance = sim.state.pos_com_world[0, 0]
    # The stop falls inside a step whose held force stops the box at its end: at most
    # μ g h² / 2 further than the exact stop.
    exact = v0 ** 2 / (2 * mu * G)
    assert exact - 1e-12 <= distance <= exact + mu * G * dt ** 2 / 2
    assert np.max(np.abs(sim.state.vel_com_world)) <= 1e-14
    x = sim.state.pos_com_world[0].copy()
    sim.step(200)
    assert np.max(np.abs(sim.state.pos_com_world[0] - x)) <= 1e-15   # and it stays


def test_a_sphere_rolls_down_an_incline_at_five_sevenths_g_sin_theta():
    theta = 0.3
    sim, down = _incline(theta, 0.5, kind='sphere')
    p0 = sim.state.pos_com_world[0].copy()
    sim.step(1000)
    travel = sim.state.pos_com_world[0] - p0
    np.testing.assert_allclose(travel, 0.5 * 5.0 / 7.0 * G * math.sin(theta) * down,
                               rtol=1e-11, atol=1e-13)
    # Without slip: the contact point is still (v = ω × r, to rounding).
    v, w = sim.twist('b')
    assert np.linalg.norm(v) == pytest.approx(np.linalg.norm(w) * 0.1, rel=1e-12)


def test_a_body_spawned_inside_the_ground_is_pushed_out_without_exploding():
    sim = _ball(height=0.08, e=0.0)   # 2 cm deep
    sim.step()
    con = sim.contact.detect(sim.state)
    assert np.max(con.depth) <= LOCATION_TOLERANCE
    # Positions only: no velocity was given to it (one step of gravity's at most).
    assert np.linalg.norm(sim.state.vel_com_world) <= G * sim.dt
    assert sim.contact.counters['max_depth'] == pytest.approx(0.02, rel=1e-9)
    sim.step(500)
    assert np.linalg.norm(sim.state.vel_com_world) <= 1e-14


@pytest.mark.parametrize('compiled', [True, False], ids=['compiled', 'python'])
def test_a_tilted_box_spawned_into_the_ground_is_projected_out_to_the_tolerance(compiled):
    # A 0.2 m cube turned 0.3 rad about x then y, its lowest corner 1 cm into the
    # ground. The end's projection is linearized (it turns the box about its centre by
    # a small angle): one pass leaves the corners 2.7e-4 m off the surface, its turn's
    # second order; the next passes take that out, so one step ends with every corner
    # it holds on the surface to the location tolerance and nothing left.
    from scipy.spatial.transform import Rotation
    rot = Rotation.from_euler('xy', [0.3, 0.3])
    corners = np.array([[x, y, z] for x in (-0.1, 0.1) for y in (-0.1, 0.1)
                        for z in (-0.1, 0.1)])
    low = float(np.min(rot.apply(corners)[:, 2]))
    body = RigidBody('b', 2.0, (2.0 * 0.2 ** 2 / 6,) * 3, position_world=(0, 0, -low - 0.01),
                     orientation_xyzw=tuple(rot.as_quat()))
    sim = Simulation([body], [Gravity()], integrator='rkmk4', dt=1e-3,
                     shapes=[CollisionShape('plane', None),
                             CollisionShape('box', 'b', size=(0.2, 0.2, 0.2))])
    sim.contact.compiled = compiled
    sim.step()
    cnt = sim.contact.counters
    assert cnt['compiled_steps'] == (1 if compiled else 0)
    assert cnt['max_depth'] == pytest.approx(0.01, rel=1e-6)
    assert cnt['projections'] == 1 and cnt['projection_left'] == 0.0
    assert np.max(np.abs(sim.contact.detect(sim.state).depth)) <= LOCATION_TOLERANCE


@pytest.mark.parametrize('passes', [1, 3])
def test_a_lifted_loaded_contact_pulled_back_drives_no_neighbour_into_overlap(
        monkeypatch, passes):
    # Sphere a rests on sphere b1 (their centres 30° off vertical), b1 on the ground: one
    # step loads both contacts. The step's end is then set by hand: a lifted 0.1 mm off
    # b1 along their normal, and a third sphere c beside a, 1e-7 m apart, 70° off that
    # normal. The end's projection pulls the loaded contact back to its surface (a and b1
    # meet halfway, equal masses), which closes a-c by (lift / 2) cos 70° = 1.7e-5 m:
    # with c's contact a row (apart by less than the widest lift) it stops at its
    # surface; before, it was no row, and a single pass (as a step's last one) left c
    # 1.7e-5 m into a. A pass is linearized: what it leaves is its second order,
    # (lift / 2)² / r = 5e-8 m, bounded here at twice that. One pass: b1 lifted off the
    # ground by the pull is left as a lift, counted. Three (the steps'): the later
    # passes take in what the first left, within the same bound.
    from rigid_body_sim.core import contact_step
    from rigid_body_sim.core.bodies import State
    r, theta, psi, lift, gap = 0.05, math.radians(30.0), math.radians(70.0), 1e-4, 1e-7
    n1 = np.array([math.sin(theta), 0.0, math.cos(theta)])
    u = -np.array([math.sin(theta + psi), 0.0, math.cos(theta + psi)])   # (a to c)
    bodies = [RigidBody(name, 1.0, (0.4 * r * r,) * 3, position_world=p)
              for name, p in (('b1', (0.0, 0.0, r)), ('a', tuple((0, 0, r) + 2 * r * n1)),
                              ('c', (2.0, 0.0, 1.0)))]
    shapes = [CollisionShape('plane', None, friction=0.5)] + [
        CollisionShape('sphere', name, radius=r, friction=0.5) for name in ('b1', 'a', 'c')]
    sim = Simulation(bodies, [Gravity()], integrator='rkmk4', dt=1e-3, shapes=shapes)
    sim.contact.compiled = False
    sim.step()
    rec = sim.contact.record
    loaded = np.sum(rec.force * rec.rows.contacts.normal, axis=1) > 0.0
    assert sorted(zip(rec.rows.contacts.body_a[loaded], rec.rows.contacts.body_b[loaded])) \
        == [(0, 1), (0, 3)]   # (b1-a, b1-ground; body 3 the world)
    pos = sim.state.pos_com_world.copy()
    pos[1] = pos[0] + (2 * r + lift) * n1
    pos[2] = pos[1] + (2 * r + gap) * u
    end = State(sim.state.time, pos, sim.state.quat_principal_world, sim.state.vel_com_world,
                sim.state.ang_vel_principal)
    assert contact_step.PROJECTION_PASSES == 3
    monkeypatch.setattr(contact_step, 'PROJECTION_PASSES', passes)
    out = sim.contact._settle(end, sim.contact.detect(end), rec)
    con = sim.contact.detect(out)
    depth = {(int(a), int(b)): float(d) for a, b, d in zip(con.body_a, con.body_b, con.depth)}
    bound = 2 * (lift / 2) ** 2 / r
    assert depth[(1, 2)] <= bound and abs(depth[(0, 1)]) <= bound
    assert sim.contact.counters['end_depth'] <= bound
    if passes > 1:
        return
    # b1 rose off the ground by its share of the pull along n1 (half, more where c's row
    # holds a back; at most all of it): left, and counted as such.
    rise = -depth[(0, 3)]
    assert lift / 2 * math.cos(theta) <= rise <= lift * math.cos(theta)
    assert sim.contact.counters['projection_left'] == pytest.approx(rise, rel=1e-12)


def test_the_contact_residual_reads_equalities_pinned_rows_and_friction_beyond_its_bound():
    # One contact, rows (n, t1, t2) with A = I: w = p + q. The residual is in m/s.
    from rigid_body_sim.core.contact_step import _residual
    A, mu = np.eye(3), np.array([0.5])
    # An equality normal row counts |w_n| whatever the sign of p_n (a complementarity
    # row with p_n < 0 would count it too, as min(p_n A_nn, w_n)).
    p, q = np.array([-0.2, 0.0, 0.0]), np.array([0.2 + 3e-3, 0.0, 0.0])
    assert _residual(A, q, p, mu, True, equal=np.array([True])) == pytest.approx(3e-3)
    # Friction beyond its bound mu p_n by 0.1: its excess times A_ii (and it slips
    # against itself: w_t = f + q_t = 0 here, so only the excess counts).
    p, q = np.array([1.0, 0.6, 0.0]), np.array([-1.0, -0.6, 0.0])
    assert _residual(A, q, p, mu, False) == pytest.approx(0.1)
    # A friction row held at zero (pinned: no impulse moves it) is not a condition:
    # its slip 0.3 counts unless it is pinned.
    p, q = np.array([1.0, 0.0, 0.0]), np.array([-1.0, 0.0, 0.3])
    assert _residual(A, q, p, mu, False) == pytest.approx(0.3)
    assert _residual(A, q, p, mu, False, pinned=np.array([False, False, True])) == 0.0


@pytest.mark.parametrize('masses', [[1.0] * 10, [1.0, 1e4], [1e4, 1.0, 1e4]],
                         ids=['ten_boxes', 'ratio_1e4_on_top', 'ratio_1e4_both_ways'])
def test_a_stack_of_boxes_stands_still_and_the_ground_carries_it(masses):
    # Ten like boxes, and boxes of mass ratio 1e4 stacked: nothing moves (rounding over
    # 1 s), the ground carries the whole weight (each LCP solved to its tolerance,
    # 1e-8 of the largest impulse, and rounding of the heaviest weight).
    half = 0.05
    bodies = [RigidBody(f'b{k}', m, (m * (2 * half) ** 2 / 6,) * 3,
                        position_world=(0, 0, half * (2 * k + 1))) for k, m in enumerate(masses)]
    shapes = [CollisionShape('plane', None, friction=0.8)] + [
        CollisionShape('box', f'b{k}', size=(2 * half,) * 3, friction=0.8)
        for k in range(len(masses))]
    sim = Simulation(bodies, [Gravity()], integrator='rkmk4', dt=1e-3, shapes=shapes)
    p0 = sim.state.pos_com_world.copy()
    sim.step(1000)
    assert np.max(np.abs(sim.state.pos_com_world - p0)) <= 1e-13
    rep = sim.contacts()
    ground = sum(f for f, b in zip(rep['normal_force'], rep['body_b']) if b == 'world')
    assert ground == pytest.approx(G * sum(masses), rel=1e-8)
    assert sim.contact.counters['lcp_failures'] == 0


def test_bodies_joined_by_a_joint_never_collide():
    bodies = [RigidBody('a', 1.0, (0.01,) * 3),
              RigidBody('b', 1.0, (0.01,) * 3, position_world=(0.05, 0, 0))]
    shapes = [CollisionShape('sphere', 'a', radius=0.1), CollisionShape('sphere', 'b', radius=0.1)]
    joint = Constraint('j', 'ball', 'a', 'b', anchor_world=(0.025, 0, 0))
    sim = Simulation(bodies, [], constraints=[joint], shapes=shapes)
    assert len(sim.contact.detect(sim.state).depth) == 0
    free = Simulation(bodies, [], shapes=shapes)
    assert len(free.contact.detect(free.state).depth) == 1


@pytest.mark.parametrize('limited', [False, True])
def test_a_hinged_rod_resting_on_the_ground_carries_half_its_weight(limited):
    # A rod hinged at one end, its other end a ball on the ground, the hinge level with
    # the contact point (so friction there has no moment about it): moments about the
    # hinge give the ground m g / 2 (the hinge the other half). With limits on the
    # hinge (never reached) the joints' events run along the contact's steps.
    from rigid_body_sim.core.limits import SceneJoint
    length, radius, mass = 1.0, 0.05, 3.0
    rod = RigidBody('rod', mass, (1e-3, mass * length ** 2 / 12, mass * length ** 2 / 12),
                    position_world=(length / 2, 0, radius))
    hinge = Constraint('h', 'hinge', 'rod', None, anchor_world=(0, 0, 0),
                       axis_world=(0, 1, 0))
    joints = [SceneJoint('h', lower=-1.0, upper=1.0)] if limited else []
    sim = Simulation([rod], [Gravity()], integrator='rkmk4', dt=1e-3, constraints=[hinge],
                     scene_joints=joints,
                     shapes=[CollisionShape('plane', None),
                             CollisionShape('sphere', 'rod', radius=radius,
                                            position_body=(length / 2, 0, 0))])
    p0 = sim.state.pos_com_world.copy()
    sim.step(500)
    rep = sim.contacts()
    assert rep['normal_force'] == pytest.approx([mass * G / 2], rel=1e-9)
    assert np.max(np.abs(sim.state.pos_com_world - p0)) <= 1e-12
    assert (sim.events is not None) == limited
    # Read between steps, the hinge's reaction sees the contact's force: the other half.
    force = sim.reactions()['h']['rod'].force_world
    np.testing.assert_allclose(force, [0.0, 0.0, mass * G / 2], rtol=1e-9, atol=1e-9)


def test_contacts_report_the_forces_the_step_used():
    sim, down = _incline(0.3, 0.2)
    sim.step(10)
    rep = sim.contacts()
    assert rep['shape_a'] == ['b/box'] * 4 and rep['body_b'] == ['world'] * 4
    # Sliding: each corner's friction is mu times its normal force, against the motion.
    np.testing.assert_allclose(np.linalg.norm(rep['friction_force'], axis=1),
                               0.2 * rep['normal_force'], rtol=1e-9)
    assert np.all(rep['friction_force'] @ down < 0.0)
    assert np.sum(rep['normal_force']) == pytest.approx(2.0 * G * math.cos(0.3), rel=1e-12)
    assert rep['counters']['lcp_failures'] == 0
    assert Simulation([RigidBody('a', 1.0, (1.0,) * 3)]).contacts() == {}


def test_a_scene_ground_and_body_shapes(tmp_path):
    from rigid_body_sim.scene import load_scene, SceneError
    text = """
dt: 0.001
integrator: rkmk4
effects: {gravity: {}}
ground: {height: 0.5, normal: [0, 0, 2], friction: 0.5, restitution: 0.5}
bodies:
  - {name: ball, mass: 1.0, inertia: {sphere: 0.1}, position_world: [0, 0, 1.0],
     shapes: [{kind: sphere, radius: 0.1, restitution: 0.5}]}
"""
    path = tmp_path / 'drop.yaml'
    path.write_text(text)
    sim = load_scene(path).simulation
    sim.step(300)
    first = sim.contact.impacts[0]
    # Dropped 0.4 m onto a ground 0.5 m up (its normal normalized).
    assert first.time == pytest.approx(math.sqrt(0.8 / G), abs=1e-9)
    assert first.rebound == pytest.approx(-0.5 * first.approach, rel=1e-12)
    for bad, where in (('ground: {normal: [0, 0, 0]}', 'ground.normal'),
                       ('ground: {friction: -1}', 'ground.friction'),
                       ('ground: {height: .nan}', 'ground.height')):
        path.write_text(text.replace(
            'ground: {height: 0.5, normal: [0, 0, 2], friction: 0.5, restitution: 0.5}', bad))
        with pytest.raises(SceneError, match=where.replace('.', r'\.')):
            load_scene(path)
    path.write_text(text.replace('radius: 0.1, restitution', 'radius: 0.0, restitution'))
    with pytest.raises(SceneError, match=r'bodies\[0\]\.shapes\[0\]\.radius'):
        load_scene(path)
    path.write_text(text.replace('{kind: sphere, radius: 0.1, restitution: 0.5}',
                                 '{radius: 0.1}'))
    with pytest.raises(SceneError, match=r'bodies\[0\]\.shapes\[0\]\.kind'):
        load_scene(path)


def _pushed_box(ratio, dt):
    a, b, mass = 0.1, 0.2, 2.0
    threshold = mass * G * a / (2 * b)
    side = mass * ((2 * a) ** 2 + (2 * b) ** 2) / 12
    inertia = (side, side, mass * (2 * a) ** 2 / 6)
    box = RigidBody('b', mass, inertia, position_world=(0, 0, b))
    shapes = [CollisionShape('plane', None, friction=2.0),
              CollisionShape('box', 'b', size=(2 * a, 2 * a, 2 * b), friction=2.0)]
    sim = Simulation([box], [Gravity()], integrator='rkmk4', dt=dt, shapes=shapes)
    push = ratio * threshold
    sim.apply_wrench('b', force=(push, 0, 0), point_body=(-a, 0, b))
    return sim, (a, b, mass, side, push)


def test_a_box_pushed_at_its_top_stays_below_the_tipping_force():
    # A box of half width a and height 2b, pushed horizontally at its top back edge,
    # with friction enough not to slide: below F 2b = m g a nothing moves, and the
    # back corners still carry some of the weight.
    sim, _ = _pushed_box(0.99, 1e-3)
    p0 = sim.state.pos_com_world[0].copy()
    sim.step(200)
    assert np.max(np.abs(sim.state.pos_com_world[0] - p0)) <= 1e-14
    assert len(sim.contacts()['normal_force']) == 4


def test_a_box_pushed_past_the_tipping_force_turns_about_its_edge_at_first_order():
    # Past the threshold the box turns about its front bottom edge (the edge sticks):
    # I θ'' = F (2a sin θ + 2b cos θ) − m g (a cos θ − b sin θ), I about the edge,
    # integrated by DOP853 to 1e-13. Contact forces are held over each step, so the
    # rate is first order in dt while the edge's force varies: the error halves with dt.
    from scipy.integrate import solve_ivp
    errors = []
    for dt in (1e-3, 5e-4):
        sim, (a, b, mass, side, push) = _pushed_box(1.01, dt)
        edge = side + mass * (a * a + b * b)

        def pivot(t, y):
            th, w = y
            return [w, (push * (2 * a * np.sin(th) + 2 * b * np.cos(th))
                        - mass * G * (a * np.cos(th) - b * np.sin(th))) / edge]

        sim.step(int(round(0.2 / dt)))
        ref = solve_ivp(pivot, (0.0, sim.time), [0.0, 0.0], method='DOP853', rtol=1e-13,
                        atol=1e-15).y[1, -1]
        errors.append(sim.twist('b')[1][1] / ref - 1.0)
        rep = sim.contacts()
        assert len(rep['normal_force']) == 2 and np.all(rep['point'][:, 0] > 0)   # lifted
        assert sim.contact.counters['impacts'] == 0
    assert abs(errors[0]) <= 2.0 * 1e-3   # (1.7e-3 measured: 1.7 dt, in 1/s)
    assert 1.8 <= errors[0] / errors[1] <= 2.2


def test_a_spinning_sliding_box_keeps_coulomb_and_never_gains_energy():
    # Sliding at 1 m/s and spinning at 10 rad/s: each corner slides its own way. Every
    # friction force is at most mu times its normal force (a sliding contact's along its
    # slip alone), every LCP converges, and no step adds energy.
    mu, mass, half = 0.5, 2.0, 0.1
    box = RigidBody('b', mass, (mass * (2 * half) ** 2 / 6,) * 3, position_world=(0, 0, half),
                    linear_velocity_world=(1.0, 0, 0), angular_velocity_body=(0, 0, 10))
    sim = Simulation([box], [Gravity()], integrator='rkmk4', dt=1e-3,
                     shapes=[CollisionShape('plane', None, friction=mu),
                             CollisionShape('box', 'b', size=(2 * half,) * 3, friction=mu)])

    def energy():
        d = sim.diagnostics()
        return d.total_energy

    e = energy()
    for _ in range(150):
        sim.step()
        rep = sim.contacts()
        excess = np.linalg.norm(rep['friction_force'], axis=1) - mu * rep['normal_force']
        # The boxes are the previous iterate's mu p_n, the fixed point to 1e-8 of the
        # largest impulse (1e-7 is its room).
        assert np.all(excess <= 1e-7 * np.max(rep['normal_force'], initial=0.0))
        now = energy()
        assert now <= e + 1e-12
        e = now
    assert sim.contact.counters['lcp_failures'] == 0
    assert sim.contact.counters['complementarity_max'] <= 1e-9   # (RATE_TOLERANCE)


@pytest.mark.parametrize('axis', [(1, 1, 0), (1, 2, 0)])
def test_a_sphere_sliding_down_a_skew_incline_slides_straight_down(axis):
    # Friction too weak to roll it (mu < 2/7 tan theta): it slides, friction along its
    # slip, at g (sin - mu cos) straight down the slope, whatever the tilt's axis.
    theta, mu, half, mass = 0.5, 0.05, 0.1, 2.0
    axis = np.array(axis, dtype=float) / np.linalg.norm(axis)
    quat = np.r_[math.sin(theta / 2) * axis, math.cos(theta / 2)]
    from rigid_body_sim.core.rotation import quat_to_matrix
    normal = quat_to_matrix(quat)[:, 2]
    body = RigidBody('b', mass, (0.4 * mass * half ** 2,) * 3, position_world=half * normal,
                     orientation_xyzw=quat)
    sim = Simulation([body], [Gravity()], integrator='rkmk4', dt=1e-3,
                     shapes=[CollisionShape('plane', None, orientation_xyzw=quat, friction=mu),
                             CollisionShape('sphere', 'b', radius=half, friction=mu)])
    sim.step(200)
    g = np.array([0.0, 0.0, -G])
    down = g - (g @ normal) * normal
    down /= np.linalg.norm(down)
    travel = sim.state.pos_com_world[0] - half * normal
    expected = 0.5 * G * (math.sin(theta) - mu * math.cos(theta)) * 0.2 ** 2
    # The first step starts stuck (the pyramid), then slides: its slip turned in that
    # step, first order: 1e-4 of the travel is its room.
    assert travel @ down == pytest.approx(expected, rel=1e-4)
    assert np.linalg.norm(travel - (travel @ down) * down) <= 1e-4 * expected


def test_a_plank_landing_flat_has_its_impact_located():
    # A 1 m plank 0.1 m wide, dropped flat: its four corners are 0.1 m apart across its
    # width, and each is its own contact (the impact located, nothing sinks).
    plank = RigidBody('p', 1.0, (0.01, 0.1, 0.1), position_world=(0, 0, 0.3))
    sim = Simulation([plank], [Gravity()], integrator='rkmk4', dt=1e-3,
                     shapes=[CollisionShape('plane', None),
                             CollisionShape('box', 'p', size=(1.0, 0.1, 0.1))])
    sim.step(300)
    assert sim.contact.counters['impacts'] >= 4
    assert sim.contact.counters['max_depth'] == 0.0
    assert sim.state.pos_com_world[0, 2] == pytest.approx(0.05, abs=LOCATION_TOLERANCE)


def test_contact_steps_keep_time_exact_and_a_deep_body_moving_out_is_not_located():
    sim = _ball(height=0.08, e=0.0, velocity=(0, 0, 0.5), dt=0.1)
    sim.step()
    assert sim.contact.counters['located_steps'] == 0   # 2 cm deep, leaving: projected
    sim.step(999)
    assert sim.time == 100.0   # base + steps dt, as without shapes


def test_the_default_scene_box_flips_lands_slides_and_rests_and_the_ball_bounces_to_rest():
    from pathlib import Path
    from rigid_body_sim.scene import load_scene
    sim = load_scene(Path(__file__).resolve().parents[1] / 'config' /
                     'default_scene.yaml').simulation
    spins, landed = [], None
    while landed is None:   # in the air: it turns over about its intermediate axis
        sim.step()
        spins.append(sim.twist('tumbling_box', frame='body')[1][1])
        if 'tumbling_box' in sim.contacts()['body_a']:
            landed = sim.pose('tumbling_box')[0][:2].copy()
    assert max(spins) > 10.0 and min(spins) < -10.0 and sim.time > 0.85
    sim.step(int(round((6.0 - sim.time) / sim.dt)))   # to 6 s
    # Both at rest on the ground, still to rounding, the box flat (its 0.1 m side up).
    for name, height in (('tumbling_box', 0.05), ('ball', 0.1)):
        v, w = sim.twist(name)
        assert np.linalg.norm(v) <= 1e-12 and np.linalg.norm(w) <= 1e-12
        assert sim.pose(name)[0][2] == pytest.approx(height, abs=1e-9)
    p = sim.state.pos_com_world.copy()
    sim.step(int(round(2.0 / sim.dt)))
    assert np.max(np.abs(sim.state.pos_com_world - p)) <= 1e-13
    # The ball's bounces: each 0.8 of the approach speed before it, located.
    ball = [i for i in sim.contact.impacts if i.shape_a == 'ball/sphere']
    for i in ball[:5]:
        assert i.rebound == pytest.approx(-0.8 * i.approach, rel=1e-9)
    # The box slid on from where it first touched (at 0.6 m/s along x, friction 0.5:
    # a few centimetres).
    assert 0.01 < np.linalg.norm(sim.pose('tumbling_box')[0][:2] - landed) < 0.1
    assert sim.contact.counters['lcp_failures'] == 0


ROD_URDF = """<robot name="rod">
  <link name="world"/>
  <link name="rod">
    <inertial><origin xyz="0.5 0 0.05"/><mass value="3"/>
      <inertia ixx="1e-3" iyy="0.25" izz="0.25" ixy="0" ixz="0" iyz="0"/></inertial>
    <collision><origin xyz="1.0 0 0.05"/><geometry><sphere radius="0.05"/></geometry></collision>
    <collision><geometry><mesh filename="rod.stl"/></geometry></collision>
  </link>
  <joint name="hinge" type="revolute"><parent link="world"/><child link="rod"/>
    <axis xyz="0 1 0"/><limit lower="-1" upper="1" effort="10" velocity="10"/></joint>
</robot>
"""


@pytest.mark.parametrize('collisions', [True, False])
def test_a_urdf_links_collision_geometry_meets_the_ground(tmp_path, collisions):
    # The hinged rod of the test above as a URDF robot with joint limits: its link's
    # <collision> sphere rests on the ground, which carries m g / 2; the mesh is named in
    # the robot's warning, not simulated. Without collisions: true it falls through.
    from rigid_body_sim.scene import load_scene
    (tmp_path / 'rod.urdf').write_text(ROD_URDF)
    (tmp_path / 'scene.yaml').write_text(
        'dt: 0.001\nintegrator: rkmk4\neffects: {gravity: {}}\nground: {}\n'
        f'robots: [{{urdf: rod.urdf, collisions: {str(collisions).lower()}}}]\n')
    scene = load_scene(tmp_path / 'scene.yaml')
    sim = scene.simulation
    sim.step(300)
    if not collisions:
        assert sim.joint_state().positions[0] > 0.1   # (falling: the ground meets nothing)
        assert any('<collision> x2' in w for w in scene.warnings)
        return
    assert any("mesh <collision> of link 'rod'" in w for w in scene.warnings)
    assert sim.contacts()['normal_force'] == pytest.approx([3.0 * G / 2], rel=1e-9)
    assert abs(sim.joint_state().positions[0]) <= 1e-12
    assert sim.events is not None   # (its limits' events along the contact's steps)


def test_the_accuracy_knob_locates_impacts_to_its_tolerance():
    # dt = 10 ms; the knob's tolerance 1e-9 per unit time makes the location tolerance
    # 1e-9 x dt = 1e-11 m of gap: the first impact's time within that over its speed.
    radius, drop = 0.1, 0.4
    ball = RigidBody('ball', 1.0, (0.004,) * 3, position_world=(0, 0, radius + drop))
    sim = Simulation([ball], [Gravity()], integrator='rkmk4', dt=1e-2, tolerance=1e-9,
                     shapes=[CollisionShape('plane', None, restitution=0.5),
                             CollisionShape('sphere', 'ball', radius=radius, restitution=0.5)])
    sim.step(60)
    assert sim.contact.location == pytest.approx(1e-11)
    first = sim.contact.impacts[0]
    speed = math.sqrt(2 * G * drop)
    assert first.time == pytest.approx(math.sqrt(2 * drop / G), abs=1e-11 / speed + 1e-15)
    assert sim.accuracy().misses == 0


def test_a_push_along_the_pyramids_diagonal_slides_as_coulomb_says():
    # Pushed with 1.3 mu m g along (1, 1, 0): within the pyramid's corner (up to 1.41)
    # but outside Coulomb's cone: it slides at (1.3 - 1) mu g along the push.
    mu, mass, half = 0.5, 2.0, 0.1
    box = RigidBody('b', mass, (mass * (2 * half) ** 2 / 6,) * 3, position_world=(0, 0, half))
    sim = Simulation([box], [Gravity()], integrator='rkmk4', dt=1e-3,
                     shapes=[CollisionShape('plane', None, friction=mu),
                             CollisionShape('box', 'b', size=(2 * half,) * 3, friction=mu)])
    direction = np.array([1.0, 1.0, 0.0]) / math.sqrt(2.0)
    sim.apply_wrench('b', force=1.3 * mu * mass * G * direction)
    sim.step(200)
    travel = sim.state.pos_com_world[0] - (0, 0, half)
    # First order in its first step (it starts stuck, the pyramid): 1e-3 of the travel.
    np.testing.assert_allclose(travel, 0.5 * 0.3 * mu * G * 0.2 ** 2 * direction,
                               rtol=1e-3, atol=1e-5)
    rep = sim.contacts()
    excess = np.linalg.norm(rep['friction_force'], axis=1) - mu * rep['normal_force']
    assert np.all(excess <= 1e-7 * np.max(rep['normal_force']))


BASE_URDF = """<robot name="arm">
  <link name="base"><inertial><mass value="5"/>
      <inertia ixx="0.1" iyy="0.1" izz="0.1" ixy="0" ixz="0" iyz="0"/></inertial>
    <collision><origin xyz="0 0 0.05"/><geometry><box size="0.2 0.2 0.1"/></geometry>
    </collision></link>
  <link name="link1"><inertial><origin xyz="0 0 0.2"/><mass value="1"/>
      <inertia ixx="0.01" iyy="0.01" izz="0.001" ixy="0" ixz="0" iyz="0"/></inertial>
    <collision><origin xyz="0 0 0.2"/><geometry><box size="0.05 0.05 0.4"/></geometry>
    </collision></link>
  <joint name="j1" type="continuous"><parent link="base"/><child link="link1"/>
    <origin xyz="0 0 0.08"/><axis xyz="0 0 1"/></joint>
</robot>
"""


def test_a_fixed_base_robots_base_is_the_world_and_meets_nothing_of_its_own(tmp_path):
    # The base's box overlaps link1's at their joint (2 cm): the base, fixed to the
    # world, is named as not simulated; link1 turns freely, no contact, no failure.
    from rigid_body_sim.scene import load_scene
    (tmp_path / 'arm.urdf').write_text(BASE_URDF)
    (tmp_path / 'scene.yaml').write_text(
        'dt: 0.001\nintegrator: rkmk4\neffects: {gravity: {}}\nground:\n'
        'robots: [{urdf: arm.urdf, fixed_base: true, collisions: true,\n'
        '          initial_velocities: {j1: 1.0}}]\n')
    scene = load_scene(tmp_path / 'scene.yaml')
    assert any("<collision> of link 'base' not simulated" in w for w in scene.warnings)
    sim = scene.simulation
    assert [s.name for s in sim.contact.detector.shapes] == ['ground', 'link1/collision0']
    sim.step(100)
    assert len(sim.contacts()['normal_force']) == 0
    assert sim.joint_state().velocities[0] == pytest.approx(1.0, rel=1e-12)
    assert sim.contact.counters['lcp_failures'] == 0


def test_welded_bodies_and_immovable_contacts_are_no_trouble():
    # Two boxes welded to the world, overlapping each other and the ground: static, no
    # contact between them. A ball on an axle through its centre, fixed to the world,
    # 0.1 mm into the ground: the contact's rows no force moves carry nothing.
    boxes = [RigidBody('a', 1.0, (0.01,) * 3, position_world=(0, 0, 0.04)),
             RigidBody('b', 1.0, (0.01,) * 3, position_world=(0.099, 0, 0.04))]
    welds = [Constraint('wa', 'fixed', 'a', None, anchor_world=(0, 0, 0.04)),
             Constraint('wb', 'fixed', 'b', None, anchor_world=(0.099, 0, 0.04))]
    sim = Simulation(boxes, [Gravity()], constraints=welds,
                     shapes=[CollisionShape('plane', None)]
                     + [CollisionShape('box', n, size=(0.1,) * 3) for n in 'ab'])
    sim.step(20)
    assert len(sim.contact.detect(sim.state).depth) == 0
    ball = RigidBody('ball', 1.0, (0.004,) * 3, position_world=(0, 0, 0.0999))
    axle = Constraint('axle', 'ball', 'ball', None, anchor_world=(0, 0, 0.0999))
    sim = Simulation([ball], [Gravity()], constraints=[axle],
                     shapes=[CollisionShape('plane', None),
                             CollisionShape('sphere', 'ball', radius=0.1)])
    sim.step(20)
    assert sim.contact.counters['immovable_rows'] > 0
    assert np.all(np.isfinite(sim.state.pos_com_world))


CHAIN_URDF = """<robot name="chain">
  <link name="a"><inertial><mass value="1"/>
      <inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial>
    <collision><geometry><sphere radius="0.1"/></geometry></collision></link>
  <link name="b"><inertial><mass value="1"/>
      <inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <link name="c"><inertial><mass value="1"/>
      <inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial>
    <collision><origin xyz="-0.15 0 0"/><geometry><sphere radius="0.1"/></geometry>
    </collision></link>
  <joint name="j1" type="continuous"><parent link="a"/><child link="b"/>
    <origin xyz="0.1 0 0"/><axis xyz="0 0 1"/></joint>
  <joint name="j2" type="continuous"><parent link="b"/><child link="c"/>
    <origin xyz="0.1 0 0"/><axis xyz="0 0 1"/></joint>
</robot>
"""


@pytest.mark.parametrize('self_collide', [False, True])
def test_a_robots_links_meet_each_other_only_with_self_collide(tmp_path, self_collide):
    # Links a and c (not joined by a joint) overlap by 15 cm: with self_collide (off by
    # default, as Gazebo) they are a contact; without, the robot's shapes meet only others.
    from rigid_body_sim.scene import load_scene
    (tmp_path / 'chain.urdf').write_text(CHAIN_URDF)
    (tmp_path / 'scene.yaml').write_text(
        'dt: 0.001\nrobots: [{urdf: chain.urdf, collisions: true, '
        f'self_collide: {str(self_collide).lower()}}}]\n')
    sim = load_scene(tmp_path / 'scene.yaml').simulation
    con = sim.contact.detect(sim.state)
    assert len(con.depth) == (1 if self_collide else 0)
    if self_collide:
        assert con.depth[0] == pytest.approx(0.15, rel=1e-12)


BALL_URDF = """<robot name="ball">
  <link name="ball"><inertial><mass value="1"/>
      <inertia ixx="0.004" iyy="0.004" izz="0.004" ixy="0" ixz="0" iyz="0"/></inertial>
    <collision><geometry><sphere radius="0.1"/></geometry></collision></link>
</robot>
"""


def test_a_robots_collisions_mapping_sets_its_shapes_surface_and_filters(tmp_path):
    # collisions: {...} is collisions: true with the robot's shapes' friction,
    # restitution, group and mask, and per link over them; the filters keep the
    # self-collision bit (off by default). Its restitution is the impact's: a URDF ball
    # dropped on a ground of e = 0 rebounds at e = 0.5 of its approach.
    from rigid_body_sim.scene import load_scene
    (tmp_path / 'chain.urdf').write_text(CHAIN_URDF)
    (tmp_path / 'scene.yaml').write_text(
        'dt: 0.001\nrobots: [{urdf: chain.urdf, collisions: {friction: 0.3, restitution: 0.2, '
        'group: 4, mask: 3, links: {c: {friction: 0.9}}}}]\n')
    sim = load_scene(tmp_path / 'scene.yaml').simulation
    det = sim.contact.detector
    shapes = {s.name: s for s in det.shapes}
    a, c = shapes['a/collision0'], shapes['c/collision0']
    assert (a.friction, a.restitution, c.friction, c.restitution) == (0.3, 0.2, 0.9, 0.2)
    bit = a.group & ~4
    assert bit and a.group == c.group == 4 | bit and a.mask == c.mask == 3 & ~bit
    # Its links (overlapping, not joined) still never meet: self_collide is false.
    rows = {det.shapes[k].name: i for i, k in enumerate(det.live)}
    assert not det._meets(rows['a/collision0'], rows['c/collision0'])
    assert len(sim.contact.detect(sim.state).depth) == 0
    (tmp_path / 'ball.urdf').write_text(BALL_URDF)
    (tmp_path / 'drop.yaml').write_text(
        'dt: 0.001\neffects: {gravity: {}}\nground: {restitution: 0.0}\n'
        'robots: [{urdf: ball.urdf, base_pose: {xyz: [0, 0, 0.5], rpy: [0, 0, 0]}, '
        'collisions: {restitution: 0.5}}]\n')
    sim = load_scene(tmp_path / 'drop.yaml').simulation
    sim.step(400)
    first = sim.contact.impacts[0]
    assert first.approach == pytest.approx(-math.sqrt(2 * G * 0.4), rel=1e-9)
    assert first.rebound == pytest.approx(-0.5 * first.approach, rel=1e-9)


@pytest.mark.parametrize('collisions, field', [
    ('{friction: -1}', 'robots[0].collisions.friction'),
    ('{restitution: 2}', 'robots[0].collisions.restitution'),
    ('{mask: -3}', 'robots[0].collisions.mask'),
    ('{colour: red}', 'robots[0].collisions.colour'),
    ('{links: {nowhere: {friction: 1}}}', 'robots[0].collisions.links.nowhere'),
    ('{links: {a: {group: 2}}}', 'robots[0].collisions.links.a.group'),
    ('{links: {a: {friction: .nan}}}', 'robots[0].collisions.links.a.friction'),
    ('{group: 4, mask: 5}', 'robots[0].collisions.mask'),
    ('{group: 2}', 'robots[0].collisions.mask'),
    ('7', 'robots[0].collisions')])
def test_a_bad_collisions_mapping_is_refused_naming_its_key(tmp_path, collisions, field):
    from rigid_body_sim.scene import load_scene, SceneError
    (tmp_path / 'chain.urdf').write_text(CHAIN_URDF)
    (tmp_path / 'scene.yaml').write_text(
        f'dt: 0.001\nrobots: [{{urdf: chain.urdf, collisions: {collisions}}}]\n')
    with pytest.raises(SceneError, match=r'scene\.yaml: ' + re.escape(field) + ': '):
        load_scene(tmp_path / 'scene.yaml')


def test_joints_added_and_removed_at_run_time_change_which_bodies_collide():
    # A gripper ball overlapping a box: a contact. Welded to the box at run time (a
    # grasp), no contact between them; released, the contact again; a reset restores
    # the scene's own.
    bodies = [RigidBody('box', 1.0, (0.01,) * 3),
              RigidBody('ball', 1.0, (0.004,) * 3, position_world=(0.12, 0, 0))]
    shapes = [CollisionShape('box', 'box', size=(0.2,) * 3),
              CollisionShape('sphere', 'ball', radius=0.05)]
    sim = Simulation(bodies, [], shapes=shapes)

    def pairs():
        return len(sim.contact.detect(sim.state).depth)
    assert pairs() == 1
    sim.add_constraint(Constraint('grasp', 'fixed', 'ball', 'box'))
    assert pairs() == 0
    sim.remove_constraint('grasp')
    assert pairs() == 1
    sim.add_constraint(Constraint('grasp', 'fixed', 'ball', 'box'))
    sim.reset()
    assert pairs() == 1 and 'grasp' not in sim.constraint_names
    # A cylinder welded inside a box: no contact; the weld removed, they meet.
    tube = [RigidBody('a', 1.0, (0.01,) * 3), RigidBody('b', 1.0, (0.01,) * 3)]
    sim = Simulation(tube, [], constraints=[Constraint('weld', 'fixed', 'a', 'b')],
                     shapes=[CollisionShape('cylinder', 'a', radius=0.05, length=0.2),
                             CollisionShape('box', 'b', size=(0.1,) * 3)])
    assert pairs() == 0
    sim.remove_constraint('weld')
    assert pairs() > 0 and sim.constraint_names == []


def _box_walls(wall):
    """Return the ground and four walls (planes, μ = 0.5) ``wall`` from the vertical axis."""
    s2 = math.sqrt(0.5)
    return [CollisionShape('plane', None, friction=0.5, name='ground')] + [
        CollisionShape('plane', None, position_body=pos, orientation_xyzw=q, friction=0.5,
                       name=name)
        for name, pos, q in (('x+', (wall, 0, 0), (0, -s2, 0, s2)),
                             ('x-', (-wall, 0, 0), (0, s2, 0, s2)),
                             ('y+', (0, wall, 0), (s2, 0, 0, s2)),
                             ('y-', (0, -wall, 0), (-s2, 0, 0, s2)))]


def _poured(count=27, r=0.05, e=0.3):
    """Return spheres in a grid above the ground, in a box of four walls (planes), and its size."""
    side = round(count ** (1 / 3))
    rng = np.random.default_rng(1)
    half = 0.5 * side * 2.2 * r
    bodies = []
    for k in range(count):
        i, j, level = k % side, (k // side) % side, k // side // side
        jitter = 0.003 * rng.standard_normal(2)
        bodies.append(RigidBody(f's{k}', 1.0, (0.4 * r * r,) * 3, position_world=(
            -half + (i + 0.5) * 2.2 * r + jitter[0], -half + (j + 0.5) * 2.2 * r + jitter[1],
            r + 0.02 + level * 2.2 * r)))
    wall = half + 0.02
    shapes = _box_walls(wall) + [
        CollisionShape('sphere', b.name, radius=r, friction=0.5, restitution=e) for b in bodies]
    return Simulation(bodies, [Gravity()], integrator='rkmk4', dt=1e-3, shapes=shapes), wall


def _stepped_inside(sim, wall, steps, r=0.05):
    """
    Step spheres of radius ``r`` in a box; return the energies and the deepest overlap left.

    Each step, every sphere must stay inside the walls and above the ground to 1e-4 m.
    """
    energy = [sim.diagnostics().total_energy]
    deepest = 0.0
    for _ in range(steps):
        sim.step()
        energy.append(sim.diagnostics().total_energy)
        deepest = max(deepest, float(np.max(sim.contact.detect(sim.state).depth, initial=0.0)))
        pos = sim.state.pos_com_world
        assert np.all(np.abs(pos[:, :2]) <= wall - r + 1e-4)
        assert np.all(pos[:, 2] >= r - 1e-4)
    return energy, deepest


@pytest.mark.parametrize('compiled, steps, sparse', [(True, 300, False), (False, 120, False),
                                                     (True, 300, True)])
def test_spheres_poured_into_a_box_gain_no_energy_and_stay_inside(compiled, steps, sparse):
    # 27 spheres (three layers, e = 0.3, μ = 0.5) dropped into a box of four walls: they
    # collapse onto each other, tens of impacts a step at first. The energy never rises
    # above its start, and in no step by more than a projection can add (each sphere
    # raised by at most the deepest depth projected: N m g d), no sphere
    # leaves the box or sinks into the ground beyond the depth bound, and a step's end
    # leaves no overlap deeper than 1e-4 m (steps cut at 32 events stand and are
    # projected). This was the case that found overlaps left by one step masking every
    # impact of the next (the step stood unlocated) and held contacts jamming the
    # projection: energy rose by 80 % in 1 s and spheres went through the walls.
    # Both paths: the compiled steps, and the Python path (through the collapse, ~0.09 s);
    # and the compiled steps with every island solved as one too large to factor (by its
    # blocks alone, to SPARSE_RESIDUAL: the 1000 spheres' path), without a failure.
    sim, wall = _poured()
    sim.contact.compiled = compiled
    if sparse:
        sim.contact.sparse_contacts = 0
    count = 27
    energy, deepest = _stepped_inside(sim, wall, steps)
    rises = np.diff(energy)
    assert np.max(rises) <= count * 1.0 * G * sim.contact.counters['max_projected'] + 1e-9
    assert max(energy) <= energy[0] + 1e-9 and energy[-1] < 0.95 * energy[0]
    assert deepest <= 1e-4
    assert sim.contact.counters['compiled_steps'] == (steps if compiled else 0)
    counters = sim.contact.counters
    if sparse:
        assert counters['lcp_sparse'] == counters['lcp_solves'] > 0
        assert counters['lcp_failures'] == 0
    else:
        assert counters['lcp_sparse'] == 0


def _packed(side=10, r=0.05, gap=1e-4):
    """Return ``side³`` spheres packed in a box, each ``gap`` from its neighbours, and the wall."""
    rng = np.random.default_rng(2)
    pitch = 2.0 * r + gap
    half = 0.5 * side * pitch
    bodies = []
    for k in range(side ** 3):
        i, j, level = k % side, (k // side) % side, k // side // side
        jitter = 0.25 * gap * (rng.random(2) - 0.5)
        bodies.append(RigidBody(f's{k}', 1.0, (0.4 * r * r,) * 3, position_world=(
            -half + (i + 0.5) * pitch + jitter[0], -half + (j + 0.5) * pitch + jitter[1],
            r + gap + level * pitch)))
    shapes = _box_walls(half) + [
        CollisionShape('sphere', b.name, radius=r, friction=0.5, restitution=0.3)
        for b in bodies]
    return Simulation(bodies, [Gravity()], integrator='rkmk4', dt=1e-3, shapes=shapes), half


def test_a_thousand_spheres_settling_in_a_box_are_one_island_solved_by_its_blocks():
    # 1000 spheres (10 × 10 × 10, 0.05 m, 1 kg, μ = 0.5, e = 0.3) packed in a box of
    # four walls, each 0.1 mm from its neighbours, the walls and the ground: within 5 ms
    # every gap closes (√(2 gap / g) = 4.5 ms) and the pack is one island of some 4,000
    # contacts (12,000 rows: 1.1 GB as a dense matrix), solved by its blocks alone
    # (SPARSE_CONTACTS). Over 30 steps it gains no energy (a projection adds at most
    # N m g d, d the deepest depth projected), no sphere leaves the box or sinks into the
    # ground beyond the depth bound, no overlap deeper than 1e-4 m is left, and every
    # solve meets the contact conditions to SPARSE_RESIDUAL (no failure counted).
    sim, half = _packed()
    count = 1000
    energy, deepest = _stepped_inside(sim, half, 30)
    counters = sim.contact.counters
    assert np.max(np.diff(energy)) <= count * 1.0 * G * counters['max_projected'] + 1e-9
    assert max(energy) <= energy[0] + 1e-9
    assert deepest <= 1e-4
    assert counters['compiled_steps'] == 30
    assert counters['lcp_sparse'] > 0 and counters['lcp_failures'] == 0
    assert len(sim.contact.detect(sim.state).depth) > 3000


def test_a_ball_bounces_by_newtons_law_down_to_the_bounce_speed_and_then_rests():
    # e = 0.5 from 0.4 m: impacts at v₁ eᵏ (v₁ = 2.80 m/s), each rebounding at e times
    # its approach. An impact faster than twice BOUNCE_SPEED (v_b, 1 cm/s) is located and
    # keeps Newton's law; one slower than v_b is inelastic (its rebound would rise
    # (e v)² / 2g < 1.3 µm); one between may be either (a closure slower than v_b at its
    # step's start is the step's own, and gravity adds g h = 0.98 cm/s within the step).
    # Then the ball rests, on the ground to the location tolerance, still to rounding,
    # carrying m g. The bounces end by t₁ + 2 e v₁ / (g (1 − e)) = 0.86 s.
    from rigid_body_sim.core.contact_step import BOUNCE_SPEED
    radius, drop, e = 0.1, 0.4, 0.5
    sim = _ball(radius, height=radius + drop, e=e)
    sim.step(1200)
    v1 = math.sqrt(2 * G * drop)
    impacts = list(sim.contact.impacts)
    fast = [i for i in impacts if -i.approach > 2 * BOUNCE_SPEED]
    # Every bounce faster than twice the bounce speed is located and keeps Newton's law;
    # the k-th at v₁ eᵏ to the location's error (1e-10 m over the speed, on v² = 2 g h).
    for k, impact in enumerate(fast):
        assert impact.approach == pytest.approx(-v1 * e ** k, rel=1e-6)
        assert impact.rebound == pytest.approx(-e * impact.approach, rel=1e-9)
    assert len(fast) == math.floor(math.log(2 * BOUNCE_SPEED / v1) / math.log(e)) + 1
    assert impacts[:len(fast)] == fast
    # The slower closures: Newton's law or inelastic between v_b and 2 v_b, inelastic
    # below v_b. (Of v₁ eᵏ, one lies between: 1.09 cm/s.)
    for impact in impacts[len(fast):]:
        assert -impact.approach <= 2 * BOUNCE_SPEED
        if -impact.approach > BOUNCE_SPEED and abs(impact.rebound) > 1e-15:
            assert impact.rebound == pytest.approx(-e * impact.approach, rel=1e-9)
        else:
            assert abs(impact.rebound) <= 1e-15
    z0 = sim.state.pos_com_world[0].copy()
    sim.step(1000)
    assert np.max(np.abs(sim.state.pos_com_world[0] - z0)) <= 1e-15
    assert np.max(np.abs(sim.state.vel_com_world)) <= 1e-15
    assert abs(sim.state.pos_com_world[0, 2] - radius) <= LOCATION_TOLERANCE
    force = sim.contact.record.force.sum(axis=0)
    np.testing.assert_allclose(force, [0.0, 0.0, G], rtol=1e-13, atol=1e-13)


@pytest.mark.parametrize('knob', [False, True])
def test_a_closure_slower_than_the_bounce_speed_is_the_steps_own_and_located_under_the_knob(
        knob):
    # A box lowered onto the ground at 5 mm/s (below BOUNCE_SPEED), e = 0.5, from 0.5001 mm
    # up: it lands without a bounce (below the bounce speed), at 0.10002 s. Fixed steps take
    # the closure in the step it happens (no event located: the row of a contact apart
    # asks the step to close at most its gap, and not to rebound), so it lands within
    # that step, and its depth at the step's end (at most h v / 2 = 2.5 µm before the
    # projection) is projected out; the knob
    # locates it to its tolerance (1e-9 dt). Either way it then rests, its speed zero
    # to rounding, on the ground to the location tolerance.
    half, v, gap, dt = 0.1, 5e-3, 5.001e-4, 1e-3
    body = RigidBody('b', 2.0, (2.0 * (2 * half) ** 2 / 6,) * 3,
                     position_world=(0, 0, half + gap), linear_velocity_world=(0, 0, -v))
    shapes = [CollisionShape('plane', None, restitution=0.5),
              CollisionShape('box', 'b', size=(2 * half,) * 3, restitution=0.5)]
    sim = Simulation([body], [], integrator='rkmk4', dt=dt, shapes=shapes,
                     tolerance=1e-9 if knob else None)
    landed = None
    for k in range(300):
        sim.step()
        if landed is None and sim.state.vel_com_world[0, 2] > -v / 2:
            landed = sim.time
    counters = sim.contact.counters
    assert counters['located_steps'] == (1 if knob else 0)
    if knob:
        assert landed == pytest.approx(gap / v, abs=sim.dt)   # (the step it lands in)
        assert all(abs(i.rebound) <= 1e-15 for i in sim.contact.impacts)
    else:
        assert gap / v <= landed <= gap / v + dt + 1e-12
        assert counters['max_depth'] <= dt * v / 2 + 1e-12
    assert np.max(np.abs(sim.state.vel_com_world)) <= 1e-15
    assert abs(sim.state.pos_com_world[0, 2] - half) <= LOCATION_TOLERANCE
