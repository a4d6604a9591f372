"""
Robots through real DDS: joint_states, robot_description, /tf, /tf_static, ~/joint_commands.

The node runs a URDF (``test/urdf/node_arm.urdf``: a 2R arm on a base fixed
to the world, with lumped frames and one visual of each kind) in its own
process; every number is checked against the core run on the same scene in
this one, bit for bit where the node and the core take the same steps.
"""

import math
from pathlib import Path

from diagnostic_msgs.msg import DiagnosticArray
import numpy as np
import pytest
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rigid_body_sim.core import rotation as so3
from rigid_body_sim.ros.conversions import joint_state_arrays, time_seconds, \
    transform_arrays
from rigid_body_sim.scene import load_scene
from rigid_body_sim.urdf import parse_urdf, prefixed_xml, read_robot_xml
from rigid_body_sim_interfaces.msg import BodyStates
from rigid_body_sim_interfaces.srv import Step
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from std_srvs.srv import SetBool, Trigger
from tf2_msgs.msg import TFMessage
from visualization_msgs.msg import Marker, MarkerArray

NODE = '/rigid_body_sim'
ARM = Path(__file__).resolve().parent / 'urdf' / 'node_arm.urdf'
README = Path(__file__).resolve().parents[1] / 'README.md'
#: As a late subscriber to robot_description or /tf_static asks (robot_state_publisher's
#: and tf2_ros's TransformListener's QoS).
LATCHED = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                     reliability=ReliabilityPolicy.RELIABLE)

TWO_ARMS = """
name: two_arms
dt: 0.001
effects:
  gravity: {{g_world: [0.0, 0.0, -9.81]}}
robots:
  - {{urdf: {arm}, prefix: a_}}
  - {{urdf: {arm}, prefix: b_, initial_positions: {{j1: 0.3, j2: -0.5}}}}
"""


def _two_arms(tmp_path):
    path = tmp_path / 'two_arms.yaml'
    path.write_text(TWO_ARMS.format(arm=ARM))
    return str(path)


def _step(ros, node, n, ns=NODE):
    reply = ros.client.call(Step, f'{ns}/step', Step.Request(steps=n), node=node)
    assert reply.success, reply.message
    return time_seconds(reply.time)


def _at(ros, node, messages, t, what, stamp=lambda m: m.header.stamp):
    """Wait for the message stamped ``t`` (whole ns: within 1e-9 s) and return it."""
    def found():
        return any(abs(time_seconds(stamp(m)) - t) < 1e-9 for m in messages)
    ros.client.wait_for(found, f'{what} at t = {t}', node=node)
    return next(m for m in messages if abs(time_seconds(stamp(m)) - t) < 1e-9)


def _tf_at(ros, node, messages, t):
    return _at(ros, node, messages, t, '/tf', stamp=lambda m: m.transforms[0].header.stamp)


def _latched(ros, msg_type, topic):
    out = []
    ros.client.node.create_subscription(msg_type, topic, out.append, LATCHED)
    return out


def _values(diagnostics):
    return {kv.key: kv.value for kv in diagnostics.status[0].values}


def _commands(ros, node):
    """Return a publisher on ~/joint_commands, once the node subscribes."""
    pub = ros.client.node.create_publisher(JointState, f'{NODE}/joint_commands', 10)
    ros.client.wait_for(lambda: pub.get_subscription_count() > 0, 'the command subscriber',
                        node=node)
    return pub


def _taken(ros, node, pub, diags, marks):
    """
    Publish a NaN command and wait until /diagnostics counts it: every message before is taken.

    (Messages on one topic arrive in order; ``marks`` is how many such NaNs were
    sent before this one.)
    """
    pub.publish(JointState(name=['j1'], effort=[math.nan]))
    ros.client.wait_for(
        lambda: any(int(_values(d)['rejected_non_finite_effort']) == marks + 1 for d in diags),
        'the NaN command to be counted', node=node)


def _assert_joints_equal(msg, js):
    names, q, qd, tau = joint_state_arrays(msg)
    assert names == js.names
    np.testing.assert_array_equal(q, js.positions)
    np.testing.assert_array_equal(qd, js.velocities)
    np.testing.assert_array_equal(tau, js.efforts)


def test_joint_states_carry_the_urdf_joints_as_the_core_has_them(ros):
    node = ros.start({'scene': str(ARM), 'start_paused': True})
    states = ros.client.subscribe(JointState, '/joint_states')
    t = _step(ros, node, 250)
    msg = _at(ros, node, states, t, 'joint states')
    sim = load_scene(ARM).simulation
    sim.step(250)
    assert msg.name == ['j1', 'j2']
    _assert_joints_equal(msg, sim.joint_state())
    assert np.all(np.abs(msg.position) > 0.1)   # (it fell under gravity)
    assert msg.header.frame_id == ''


def test_robot_description_reaches_a_late_subscriber(ros):
    node = ros.start({'scene': str(ARM), 'start_paused': True})
    # The node is up and serving (it published robot_description while it started).
    assert ros.client.call(SetBool, f'{NODE}/pause', SetBool.Request(data=True),
                           node=node).success
    got = _latched(ros, String, '/robot_description')
    ros.client.wait_for(lambda: got, 'robot_description', node=node)
    assert got[0].data == read_robot_xml(ARM) == load_scene(ARM).robots[0][1].xml


def test_tf_carries_each_moving_link_at_its_body_pose(ros, tmp_path):
    scene = _two_arms(tmp_path)
    node = ros.start({'scene': scene, 'start_paused': True})
    tf = ros.client.subscribe(TFMessage, '/tf')
    t = _step(ros, node, 120)
    msg = _tf_at(ros, node, tf, t)
    sim = load_scene(scene).simulation
    sim.step(120)
    got = {}
    for transform in msg.transforms:
        parent, child, p, q = transform_arrays(transform)
        assert parent == 'world'
        got[child] = (p, q)
    assert sorted(got) == ['a_l1', 'a_l2', 'b_l1', 'b_l2']
    for body, (p, q) in got.items():
        pos, quat = sim.pose(body)
        np.testing.assert_array_equal(p, pos)
        np.testing.assert_array_equal(q, quat)
    # The two arms started apart (b's initial positions), and l2 hangs at l1's tip.
    assert not np.array_equal(got['a_l2'][0], got['b_l2'][0])
    R = so3.quat_to_matrix(got['a_l1'][1])
    # bound: the joint holds to its drift control, about 1e-9 m after 120 steps from rest;
    # 1e-6 m leaves room
    np.testing.assert_allclose(got['a_l2'][0], got['a_l1'][0] + R @ [1.0, 0.0, 0.0],
                               atol=1e-6)


def test_tf_static_has_the_lumped_and_world_fixed_frames_once(ros, tmp_path):
    scene = _two_arms(tmp_path)
    node = ros.start({'scene': scene, 'start_paused': True})
    diags = ros.client.subscribe(DiagnosticArray, '/diagnostics')
    ros.client.wait_for(lambda: diags, 'diagnostics', node=node)
    static = _latched(ros, TFMessage, '/tf_static')   # (a late listener)
    ros.client.wait_for(lambda: static, '/tf_static', node=node)
    got = {}
    for transform in static[0].transforms:
        parent, child, p, q = transform_arrays(transform)
        got[child] = (parent, p, q)
    for prefix in ('a_', 'b_'):
        # The URDF's world link is the world frame; base and camera are fixed to it; the
        # tip is lumped into l2 (tool joint: 1 m along x, roll 0.3 rad).
        expected = {
            'world': ('world', [0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]),
            'base': ('world', [0.0, 0.0, 1.0], [0.0, 0.0, 0.0, 1.0]),
            'camera': ('world', [0.1, 0.0, 1.2], [0.0, math.sin(0.25), 0.0, math.cos(0.25)]),
            'tip': (f'{prefix}l2', [1.0, 0.0, 0.0],
                    [math.sin(0.15), 0.0, 0.0, math.cos(0.15)]),
        }
        for link, (parent, p, q) in expected.items():
            g_parent, g_p, g_q = got.pop(prefix + link)
            assert g_parent == parent, link
            # bound: a sum of two origins and a quaternion from the URDF's rpy matrix: a few
            # roundings of numbers of order 1 (1e-16); 1e-12 leaves room
            np.testing.assert_allclose(g_p, p, atol=1e-12)
            np.testing.assert_allclose(g_q * np.sign(g_q[3]), q, atol=1e-12)
    assert got == {}
    # Published once: still one message after two more diagnostics (a second apart).
    n = len(diags)
    ros.client.wait_for(lambda: len(diags) >= n + 2, 'two more diagnostics', node=node)
    assert len(static) == 1


def test_the_second_robot_is_logged_as_not_on_robot_description(ros, tmp_path):
    scene = _two_arms(tmp_path)
    node = ros.start({'scene': scene, 'start_paused': True})
    got = _latched(ros, String, '/robot_description')
    ros.client.wait_for(lambda: got, 'robot_description', node=node)
    # The first robot's URDF, its names prefixed as joint_states and /tf have them.
    assert got[0].data == prefixed_xml(read_robot_xml(ARM), 'a_')
    described = parse_urdf(got[0].data, 'robot_description')
    assert [j.name for j in described.joints] == ['a_fix', 'a_camera_joint', 'a_j1', 'a_j2',
                                                  'a_tool']
    ros.client.wait_for(lambda: 'robot_description carries the first' in node.log(),
                        'the log line', node=node)


def test_an_effort_command_moves_its_joint_as_the_core_predicts(ros):
    node = ros.start({'scene': str(ARM), 'start_paused': True})
    states = ros.client.subscribe(JointState, '/joint_states')
    diags = ros.client.subscribe(DiagnosticArray, '/diagnostics')
    pub = _commands(ros, node)
    _step(ros, node, 50)
    # j1 at 100 N m, beyond its URDF limit of 10: clamped.
    pub.publish(JointState(name=['j1'], effort=[100.0]))
    _taken(ros, node, pub, diags, 0)
    t1 = _step(ros, node, 100)
    one = _at(ros, node, states, t1, 'joint states')
    # Then j2 at -2 N m; j1 holds its command.
    pub.publish(JointState(name=['j2'], effort=[-2.0]))
    _taken(ros, node, pub, diags, 1)
    t2 = _step(ros, node, 100)
    two = _at(ros, node, states, t2, 'joint states')

    def core(*commands):
        sim = load_scene(ARM).simulation
        sim.step(50)
        for command in commands:
            if command:
                sim.set_joint_efforts(command)
            sim.step(100)
        return sim
    sim = core({'j1': 100.0}, None)
    expected_one = core({'j1': 100.0}).joint_state()
    _assert_joints_equal(one, expected_one)
    _assert_joints_equal(two, core({'j1': 100.0}, {'j2': -2.0}).joint_state())
    # The effort reported is the clamped command, acting, plus j2's URDF damping
    # (0.1 N m s/rad) at the current rate. bound: one product's rounding, 1e-15.
    damping = np.array([0.0, 0.1])
    np.testing.assert_allclose(np.array(one.effort) + damping * one.velocity, [10.0, 0.0],
                               atol=1e-12)
    np.testing.assert_allclose(np.array(two.effort) + damping * two.velocity, [10.0, -2.0],
                               atol=1e-12)
    # Each moved its joint its way: against the same run without it.
    free = core(None)
    assert one.position[0] > free.joint_state().positions[0]
    assert two.position[1] < sim.joint_state().positions[1]
    ros.client.wait_for(lambda: _values(diags[-1])['steps'] == '250', 'diagnostics',
                        node=node)
    assert _values(diags[-1])['joint_efforts_clamped'] == '1'


BAD_COMMANDS = [
    (JointState(name=['j1'], effort=[math.inf]), 'non_finite_effort', 'must be finite'),
    (JointState(name=['nope'], effort=[1.0]), 'unknown_joint', "unknown joint 'nope'"),
    (JointState(name=['j1', 'j2'], effort=[1.0]), 'joint_command_lengths',
     '1 values for 2 names'),
    (JointState(name=['j1'], position=[0.5]), 'wrong_interface',
     "joint 'j1' has the effort interface"),
    (JointState(name=['j1'], velocity=[0.5], effort=[1.0]), 'wrong_interface', None),
    (JointState(name=['j1', 'j1'], effort=[1.0, 2.0]), 'bad_joint_command', 'named twice'),
    (JointState(), 'bad_joint_command', None),
    (JointState(name=['j2'], effort=[1e9]), 'effort_too_large', 'max_torque'),
]


def test_bad_joint_commands_are_refused_counted_and_change_nothing(ros):
    node = ros.start({'scene': str(ARM), 'start_paused': True})
    states = ros.client.subscribe(JointState, '/joint_states')
    diags = ros.client.subscribe(DiagnosticArray, '/diagnostics')
    pub = _commands(ros, node)
    for msg, _, _ in BAD_COMMANDS:
        pub.publish(msg)
    _taken(ros, node, pub, diags, 1)   # (one inf before it)
    values = next(_values(d) for d in diags if _values(d)['rejected_non_finite_effort'] == '2')
    expected = {}
    for _, cause, _ in BAD_COMMANDS:
        expected[cause] = expected.get(cause, 0) + 1
    expected['non_finite_effort'] += 1   # (the NaN)
    for cause, count in expected.items():
        assert values[f'rejected_{cause}'] == str(count), cause
    # Each refusal is logged naming the field and the problem (a line a second per cause).
    for _, cause, text in BAD_COMMANDS:
        if text:
            ros.client.wait_for(lambda: any(f'rejected ({cause})' in line and text in line
                                            for line in node.log().splitlines()),
                                f'the log line for {cause}', node=node)
    # The node runs on and answers, as if none of that had been sent: bit for bit.
    t = _step(ros, node, 200)
    sim = load_scene(ARM).simulation
    sim.step(200)
    _assert_joints_equal(_at(ros, node, states, t, 'joint states'), sim.joint_state())
    assert ros.client.call(SetBool, f'{NODE}/pause', SetBool.Request(data=False),
                           node=node).success
    ros.client.wait_for(lambda: time_seconds(states[-1].header.stamp) > t + 0.05,
                        'joint states while running', node=node)


def test_reset_clears_joint_commands_and_publishes_the_initial_state(ros):
    node = ros.start({'scene': str(ARM), 'start_paused': True})
    states = ros.client.subscribe(JointState, '/joint_states')
    tf = ros.client.subscribe(TFMessage, '/tf')
    diags = ros.client.subscribe(DiagnosticArray, '/diagnostics')
    pub = _commands(ros, node)
    pub.publish(JointState(name=['j1', 'j2'], effort=[50.0, 1.0]))
    _taken(ros, node, pub, diags, 0)
    t = _step(ros, node, 100)
    ros.client.wait_for(lambda: any(_values(d)['joint_efforts_clamped'] == '1' for d in diags),
                        'the clamped effort counted', node=node)
    msg = _at(ros, node, states, t, 'joint states')
    # The clamped command plus j2's damping (0.1 N m s/rad) now; bound: rounding, 1e-15.
    np.testing.assert_allclose(np.array(msg.effort) + [0.0, 0.1 * msg.velocity[1]],
                               [10.0, 1.0], atol=1e-12)
    reply = ros.client.call(Trigger, f'{NODE}/reset', Trigger.Request(), node=node)
    assert reply.success and 'joint commands cleared' in reply.message
    # The reset state is stamped one step after the last, and is the initial one.
    t0 = t + 1e-3
    initial = load_scene(ARM).simulation
    _assert_joints_equal(_at(ros, node, states, t0, 'joint states after the reset'),
                         initial.joint_state())
    for transform in _tf_at(ros, node, tf, t0).transforms:
        _, child, p, q = transform_arrays(transform)
        np.testing.assert_array_equal(p, initial.pose(child)[0])
        np.testing.assert_array_equal(q, initial.pose(child)[1])
    # And the commands are gone: it falls freely, as the core from the start.
    t = _step(ros, node, 100)
    initial.step(100)
    msg = _at(ros, node, states, t, 'joint states')
    _assert_joints_equal(msg, initial.joint_state())
    # No command acts: only j2's damping (0.1 N m s/rad). bound: rounding, 1e-15.
    np.testing.assert_allclose(np.array(msg.effort) + [0.0, 0.1 * msg.velocity[1]], 0.0,
                               atol=1e-12)
    ros.client.wait_for(lambda: float(_values(diags[-1])['sim_time_s']) > t - 1e-6,
                        'diagnostics after the reset', node=node)
    assert _values(diags[-1])['joint_efforts_clamped'] == '0'


def test_joint_states_and_tf_come_at_their_own_rates(ros):
    node = ros.start({'scene': str(ARM), 'start_paused': True, 'publish_rate': 100.0,
                      'joint_state_rate': 50.0, 'tf_rate': 25.0})
    states = ros.client.subscribe(JointState, '/joint_states')
    tf = ros.client.subscribe(TFMessage, '/tf')
    bodies = ros.client.subscribe(BodyStates, f'{NODE}/body_states')
    # The start state (republished while paused) tells each subscription is matched.
    ros.client.wait_for(lambda: states and tf and bodies, 'the state at t = 0', node=node)
    _step(ros, node, 100)
    _at(ros, node, bodies, 0.1, 'body states')
    _at(ros, node, states, 0.1, 'joint states')
    _tf_at(ros, node, tf, 0.1)

    def stamps(messages, stamp=lambda m: m.header.stamp):
        return sorted({round(time_seconds(stamp(m)), 6) for m in messages})
    assert stamps(bodies) == [round(0.01 * k, 6) for k in range(11)]
    assert stamps(states) == [round(0.02 * k, 6) for k in range(6)]
    # (/tf: every 0.04 s, and the state after the last step of a ~/step request)
    assert stamps(tf, lambda m: m.transforms[0].header.stamp) == [0.0, 0.04, 0.08, 0.1]


def _readme_robot_topics():
    section = README.read_text().split('### Robot topics', 1)[1].split('\n#', 1)[0]
    rows = [line.split('|') for line in section.splitlines() if line.startswith('| `')]
    return {r[1].strip().strip('`'): r[2].strip().strip('`').replace('/', '/msg/')
            for r in rows}


@pytest.mark.parametrize('tf', ['links', 'off'])
def test_the_robot_topics_are_the_ones_the_readme_documents(ros, tf):
    node = ros.start({'scene': str(ARM), 'start_paused': True, 'tf': tf}, namespace='/robot1')
    expected = {}
    for name, typ in _readme_robot_topics().items():
        if name.startswith('G/'):
            continue   # (per command group: node_arm has none; test_node_joint_commands.py)
        if name.startswith('~/'):
            full = f'/robot1{NODE}/{name[2:]}'
        elif name.startswith('/'):
            full = name
        else:
            full = f'/robot1/{name}'   # (namespace-relative)
        if tf == 'links' or not full.startswith('/tf'):
            expected[full] = typ
    graph = ros.client.node

    def live():
        pubs = graph.get_publisher_names_and_types_by_node('rigid_body_sim', '/robot1')
        subs = graph.get_subscriber_names_and_types_by_node('rigid_body_sim', '/robot1')
        return {n: t[0] for n, t in pubs + subs}

    def found():
        try:
            topics = live()
        except Exception:  # noqa: B902 - the node not yet discovered
            return False
        return all(topics.get(n) == t for n, t in expected.items()) and \
            (tf == 'links' or not {'/tf', '/tf_static'} & set(topics))
    ros.client.wait_for(found, f'the robot topics {sorted(expected)}', node=node)
    assert ros.client.call(SetBool, '/robot1/rigid_body_sim/pause', SetBool.Request(data=True),
                           node=node).success
    assert '/tf' not in live() if tf == 'off' else '/tf' in live()


def test_start_up_logs_one_warning_per_robot(ros, tmp_path):
    node = ros.start({'scene': _two_arms(tmp_path), 'start_paused': True})
    ros.client.call(SetBool, f'{NODE}/pause', SetBool.Request(data=True), node=node)
    lines = [line for line in node.log().splitlines()
             if 'WARN' in line and "robot 'node_arm'" in line]
    assert len(lines) == 2, lines   # (both robots are called node_arm, as their URDF)
    for line in lines:
        assert 'not simulated: <collision> x1, <gazebo> x1' in line, line
        assert 'damping' not in line, line   # j2's damping is simulated: not a note
        assert 'position limits' not in line, line   # j1's limits are enforced: not a note


def test_markers_draw_the_urdf_visuals_posed_by_their_bodies(ros):
    node = ros.start({'scene': str(ARM), 'start_paused': True})
    markers = ros.client.subscribe(MarkerArray, f'{NODE}/markers')
    t = _step(ros, node, 150)
    msg = _at(ros, node, markers, t, 'markers', stamp=lambda m: m.markers[0].header.stamp)
    visuals = {m.text: m for m in msg.markers if m.ns == 'visuals'}
    assert sorted(visuals) == ['base', 'l1', 'l2', 'tip']
    assert not [m for m in msg.markers if m.ns == 'bodies']   # (every body has a visual)
    base, box, rod, ball = (visuals[k] for k in ('base', 'l1', 'l2', 'tip'))
    assert base.type == Marker.MESH_RESOURCE and base.mesh_use_embedded_materials
    assert base.mesh_resource == 'package://node_arm_description/meshes/base.stl'
    assert [base.scale.x, base.scale.y, base.scale.z] == [0.001] * 3
    assert box.type == Marker.CUBE and [box.scale.x, box.scale.y, box.scale.z] == [1, 0.1, 0.1]
    assert rod.type == Marker.CYLINDER and [rod.scale.x, rod.scale.z] == [0.08, 1.0]
    assert ball.type == Marker.SPHERE and ball.scale.x == 0.12
    assert [ball.color.r, ball.color.g, ball.color.b] == pytest.approx([0.8, 0.1, 0.1])
    sim = load_scene(ARM).simulation
    sim.step(150)

    def placed(marker, body, offset, rotation):
        pos, quat = sim.pose(body)
        R = so3.quat_to_matrix(quat)
        p = marker.pose.position
        o = marker.pose.orientation
        q = np.array([o.x, o.y, o.z, o.w])
        # bound: one rotation and one sum of numbers of order 1 (a few 1e-16); 1e-12 room
        np.testing.assert_allclose([p.x, p.y, p.z], pos + R @ offset, atol=1e-12)
        np.testing.assert_allclose(so3.quat_to_matrix(q), R @ rotation, atol=1e-12)
    ry = so3.quat_to_matrix([0.0, math.sin(math.pi / 4), 0.0, math.cos(math.pi / 4)])
    rx = so3.quat_to_matrix([math.sin(0.15), 0.0, 0.0, math.cos(0.15)])
    placed(box, 'l1', [0.5, 0.0, 0.0], np.eye(3))
    placed(rod, 'l2', [0.5, 0.0, 0.0], ry)
    placed(ball, 'l2', [1.0, 0.0, 0.0], rx)
    p = base.pose.position
    # bound: 1 - 0.05 rounds once
    np.testing.assert_allclose([p.x, p.y, p.z], [0.0, 0.0, 0.95], atol=1e-15)


def test_a_joint_on_its_limit_shows_in_diagnostics_and_joint_states(ros, tmp_path):
    # A rod on a hinge at the world origin, horizontal at q = 0, falls onto its upper
    # bound 0.8 rad (0.4 s) and rests there: diagnostics name the bound and count the
    # impact, and joint_states carry the bound's torque, as the core computes it.
    from robot_helpers import inertial, joint, link, robot
    path = tmp_path / 'pendulum.urdf'
    path.write_text(robot('pend', link('world'),
                          link('rod', inertial(1.0, xyz=(0.5, 0, 0), ixx=1e-3, iyy=1e-3,
                                               izz=1e-3)),
                          joint('j', 'revolute', 'world', 'rod', axis=(0, 1, 0),
                                extra='<limit lower="-0.5" upper="0.8" effort="10" '
                                      'velocity="100"/>')))
    node = ros.start({'scene': str(path), 'start_paused': True})
    states = ros.client.subscribe(JointState, '/joint_states')
    diags = ros.client.subscribe(DiagnosticArray, '/diagnostics')
    t = _step(ros, node, 1000)
    msg = _at(ros, node, states, t, 'joint states')
    sim = load_scene(path).simulation
    sim.step(1000)
    _assert_joints_equal(msg, sim.joint_state())
    # bound: the core's own figure (test_joint_limits.py), through the message: 1e-9.
    assert msg.effort[0] == pytest.approx(-9.81 * 0.5 * math.cos(0.8), rel=1e-9)
    ros.client.wait_for(lambda: diags and _values(diags[-1])['steps'] == '1000',
                        'diagnostics after the steps', node=node)
    values = _values(diags[-1])
    assert values['joint_limits_active'] == 'j:upper'
    assert values['joint_limit_impacts_total'] == '1'
    assert values['joint_limit_excess_max'] == '0'
    # No row pivoted past its bound (it rests; the core's complementarity()).
    assert values['joint_complementarity_force_excess_max'] == \
        f'{sim.complementarity()["max_force_excess"]:.3g}' == '0'
    assert values['joint_complementarity_lcp_residual_max'] == \
        f'{sim.complementarity()["lcp_residual_max"]:.3g}'
    assert values['joint_complementarity_lcp_failures_total'] == '0'
