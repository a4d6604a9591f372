"""
Joint commands through real DDS: ``~/joint_commands`` per interface, ``<group>/commands``.

The node runs ``test/node_servo_arms.yaml`` in its own process: three copies of
``test/urdf/node_arm.urdf`` without gravity, ``a_`` on position servos (kp 400
N m/rad, kd 40 N m s/rad, its group listing a_j2 before a_j1), ``b_`` on velocity
servos (kd 100 N m s/rad), ``c_`` on efforts. What the servos do is checked as
physics (targets reached within a bound from the gains and the time waited), and
against the core run on the same scene in this one, bit for bit. One test runs
node_arm under gravity on exact drives (driving constraints) instead.
"""

import math
from pathlib import Path

from diagnostic_msgs.msg import DiagnosticArray
import numpy as np
import pytest
from rigid_body_sim.ros.conversions import joint_state_arrays, time_seconds
from rigid_body_sim.scene import load_scene
from rigid_body_sim_interfaces.srv import Step
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import SetBool, Trigger

NODE = '/rigid_body_sim'
SCENE = Path(__file__).resolve().parent / 'node_servo_arms.yaml'
README = Path(__file__).resolve().parents[1] / 'README.md'
NAN, INF = math.nan, math.inf
POSITION_GROUP, VELOCITY_GROUP = 'arm_position_controller', 'arm_velocity_controller'
#: The targets of the tests: a_ to positions, b_ to rates, c_j1 pushed.
TARGETS = {'a_j1': 0.2, 'a_j2': -0.4, 'b_j1': 1.0, 'b_j2': 0.0, 'c_j1': 0.5}
#: One message for all three interfaces, NaN where a joint is not on that interface.
MIXED = JointState(name=['a_j1', 'a_j2', 'b_j1', 'b_j2', 'c_j1'],
                   position=[0.2, -0.4, NAN, NAN, NAN], velocity=[NAN, NAN, 1.0, 0.0, NAN],
                   effort=[NAN, NAN, NAN, NAN, 0.5])
#: Steps waited for the servos to settle (2 s).
SETTLE = 2000


def _step(ros, node, n):
    reply = ros.client.call(Step, f'{NODE}/step', Step.Request(steps=n), node=node)
    assert reply.success, reply.message
    return time_seconds(reply.time)


def _at(ros, node, messages, t, what):
    """Wait for the message stamped ``t`` (whole ns: within 1e-9 s) and return it."""
    def found():
        return any(abs(time_seconds(m.header.stamp) - t) < 1e-9 for m in messages)
    ros.client.wait_for(found, f'{what} at t = {t}', node=node)
    return next(m for m in messages if abs(time_seconds(m.header.stamp) - t) < 1e-9)


def _values(diagnostics):
    return {kv.key: kv.value for kv in diagnostics.status[0].values}


def _publisher(ros, node, msg_type, topic):
    """Return a publisher on ``topic``, once the node subscribes."""
    pub = ros.client.node.create_publisher(msg_type, topic, 10)
    ros.client.wait_for(lambda: pub.get_subscription_count() > 0, f'the subscriber of {topic}',
                        node=node)
    return pub


def _counted(ros, node, diags, key, count):
    """Wait until /diagnostics shows ``key`` at ``count``; return those values."""
    ros.client.wait_for(lambda: any(int(_values(d)[key]) == count for d in diags),
                        f'{key} = {count} on /diagnostics', node=node)
    return next(_values(d) for d in diags if int(_values(d)[key]) == count)


def _taken(ros, node, pub, diags, before):
    """
    Publish a NaN effort for c_j1 and wait until it is counted: every message before is taken.

    (Messages on one topic from one publisher arrive in order; ``before``: the
    non-finite efforts sent before this one.)
    """
    pub.publish(JointState(name=['c_j1'], effort=[NAN]))
    return _counted(ros, node, diags, 'rejected_non_finite_effort', before + 1)


def _group_taken(ros, node, pub, size, diags, before):
    """As :func:`_taken` for a group topic: an all-NaN message, counted as a no-op."""
    pub.publish(Float64MultiArray(data=[NAN] * size))
    return _counted(ros, node, diags, 'group_commands_all_nan', before + 1)


def _joints(msg):
    names, q, qd, tau = joint_state_arrays(msg)
    return {n: (q[i], qd[i], tau[i]) for i, n in enumerate(names)}


def _assert_equal(msg, js):
    names, q, qd, tau = joint_state_arrays(msg)
    assert names == js.names
    np.testing.assert_array_equal(q, js.positions)
    np.testing.assert_array_equal(qd, js.velocities)
    np.testing.assert_array_equal(tau, js.efforts)


def _core(*runs):
    """Return the core on the scene after each run ``(commands or None, steps)`` in turn."""
    sim = load_scene(SCENE).simulation
    for commands, steps in runs:
        if commands:
            sim.command_joints(commands)
        sim.step(steps)
    return sim


def _assert_settled(joints):
    """
    Assert that the servos reached their targets (TARGETS), SETTLE steps from rest.

    Position servos (a_): the slowest mode is j1 carrying the whole arm, whose
    inertia about j1 is at most I = 4.7 kg m² (straight: l1 0.35, l2 with the tip
    4.35); underdamped there (ζ = kd / (2 sqrt(kp I)) = 0.46), it decays as
    exp(-kd t / (2 I)) = exp(-4.25 t) / sqrt(1 - ζ²). From 0.4 rad, with j1 at its
    10 N m effort limit for at most the first 0.3 s, after 2 s the error is below
    0.4 exp(-4.25 x 1.7) / 0.89 = 3.3e-4 rad (the core: 3e-6); tolerance 1e-3 rad.
    """
    for name in ('a_j1', 'a_j2'):
        assert abs(joints[name][0] - TARGETS[name]) < 1e-3, (name, joints[name])
    # Velocity servos (b_): the rate error e obeys I ė = -kd e + τ, τ the disturbance
    # torque; the transient decays as exp(-kd t / I) (I <= 4.7 kg m²: nil after 2 s), the
    # rest is τ / kd. Here τ is the centrifugal torque about the elbow of l2 (1.5 kg with
    # the tip, its centre 0.667 m past the elbow, 1 m from j1) bent by q2 while the arm
    # turns at 1 rad/s: τ <= 1.5 x 0.667 x 1 x 1² x |sin q2| = 0.05 N m for |q2| < 0.05
    # (checked), so |e| <= 5e-4 rad/s (the core: 2e-4 for b_j2, 5e-6 for b_j1);
    # tolerance 1e-3 rad/s.
    assert abs(joints['b_j2'][0]) < 0.05, joints['b_j2']
    for name in ('b_j1', 'b_j2'):
        assert abs(joints[name][1] - TARGETS[name]) < 1e-3, (name, joints[name])
    # The effort joint turned the way it was pushed (it stays at 0 without).
    assert joints['c_j1'][0] > 0.1 and joints['c_j1'][1] > 0.0


def test_joint_commands_drive_each_joint_through_its_interface(ros):
    node = ros.start({'scene': str(SCENE), 'start_paused': True})
    states = ros.client.subscribe(JointState, '/joint_states')
    diags = ros.client.subscribe(DiagnosticArray, '/diagnostics')
    pub = _publisher(ros, node, JointState, f'{NODE}/joint_commands')
    # A first target for a_j1 (0.5), replaced by the mixed message before a step uses it.
    pub.publish(JointState(name=['a_j1'], position=[0.5]))
    pub.publish(MIXED)
    values = _taken(ros, node, pub, diags, 0)
    assert values['joint_targets_superseded'] == '1'
    assert values['joint_efforts_superseded'] == '0'
    t = _step(ros, node, SETTLE)
    msg = _at(ros, node, states, t, 'joint states')
    _assert_settled(_joints(msg))
    _assert_equal(msg, _core((TARGETS, SETTLE)).joint_state())


def test_group_topics_drive_their_joints_in_the_groups_order(ros):
    node = ros.start({'scene': str(SCENE), 'start_paused': True})
    states = ros.client.subscribe(JointState, '/joint_states')
    diags = ros.client.subscribe(DiagnosticArray, '/diagnostics')
    # Namespace-relative, as forward_command_controller's: /<group>/commands here.
    position = _publisher(ros, node, Float64MultiArray, f'/{POSITION_GROUP}/commands')
    velocity = _publisher(ros, node, Float64MultiArray, f'/{VELOCITY_GROUP}/commands')
    joints = _publisher(ros, node, JointState, f'{NODE}/joint_commands')
    position.publish(Float64MultiArray(data=[-0.4, 0.2]))   # (a_j2, a_j1: the group's order)
    velocity.publish(Float64MultiArray(data=[1.0, 0.0]))
    joints.publish(JointState(name=['c_j1'], effort=[0.5]))
    _group_taken(ros, node, position, 2, diags, 0)
    _group_taken(ros, node, velocity, 2, diags, 1)
    _taken(ros, node, joints, diags, 0)
    t = _step(ros, node, SETTLE)
    msg = _at(ros, node, states, t, 'joint states')
    _assert_settled(_joints(msg))
    _assert_equal(msg, _core((TARGETS, SETTLE)).joint_state())
    # NaN keeps a joint's command: a_j2 holds -0.4 while a_j1 goes to 0.1 (a step of 0.1
    # rad: the bound above, scaled by 1/4, 8e-5 rad; tolerance 1e-3).
    position.publish(Float64MultiArray(data=[NAN, 0.1]))
    _group_taken(ros, node, position, 2, diags, 2)
    t = _step(ros, node, SETTLE)
    after = _joints(_at(ros, node, states, t, 'joint states'))
    assert abs(after['a_j1'][0] - 0.1) < 1e-3 and abs(after['a_j2'][0] + 0.4) < 1e-3
    _assert_equal(_at(ros, node, states, t, 'joint states'),
                  _core((TARGETS, SETTLE), ({'a_j1': 0.1}, SETTLE)).joint_state())


def test_reset_brings_the_servos_back_to_holding_the_initial_state(ros):
    node = ros.start({'scene': str(SCENE), 'start_paused': True})
    states = ros.client.subscribe(JointState, '/joint_states')
    diags = ros.client.subscribe(DiagnosticArray, '/diagnostics')
    pub = _publisher(ros, node, JointState, f'{NODE}/joint_commands')
    pub.publish(MIXED)
    _taken(ros, node, pub, diags, 0)
    t = _step(ros, node, 500)
    assert abs(_joints(_at(ros, node, states, t, 'joint states'))['b_j1'][1]) > 0.5
    # A command queued but not yet stepped is dropped by the reset too.
    pub.publish(JointState(name=['a_j1'], position=[1.0]))
    _taken(ros, node, pub, diags, 1)
    assert ros.client.call(Trigger, f'{NODE}/reset', Trigger.Request(), node=node).success
    # From the initial state, the servos hold it (targets: the initial positions, rest):
    # the arms stay where they are, bit for bit as the core without commands.
    t = _step(ros, node, 300)
    msg = _at(ros, node, states, t, 'joint states after the reset')
    _assert_equal(msg, _core((None, 300)).joint_state())
    np.testing.assert_array_equal(msg.position, 0.0)
    np.testing.assert_array_equal(msg.velocity, 0.0)


BAD_JOINT_COMMANDS = [
    (JointState(name=['nope'], effort=[1.0]), 'unknown_joint', "name[0]: unknown joint 'nope'"),
    (JointState(name=['a_j1', 'a_j1'], position=[0.1, 0.3]), 'bad_joint_command',
     "name[1]: joint 'a_j1' is named twice"),
    (JointState(), 'bad_joint_command', None),
    (JointState(name=['c_j1'], position=[0.5]), 'wrong_interface',
     "position[0] (c_j1): 0.5 given, but joint 'c_j1' has the effort interface"),
    (JointState(name=['a_j1'], effort=[1.0]), 'wrong_interface', None),
    (JointState(name=['b_j1'], position=[0.3], velocity=[-1.0]), 'wrong_interface', None),
    (JointState(name=['a_j1'], position=[NAN]), 'non_finite_target', None),
    (JointState(name=['a_j2', 'b_j1'], position=[0.1, NAN], velocity=[NAN, INF]),
     'non_finite_target', None),
    (JointState(name=['c_j2'], effort=[-INF]), 'non_finite_effort', None),
    (JointState(name=['a_j1', 'a_j2'], position=[0.1]), 'joint_command_lengths',
     'position: 1 values for 2 names'),
    (JointState(name=['b_j1']), 'joint_command_lengths', None),
    (JointState(name=['c_j1'], effort=[1e9]), 'effort_too_large',
     'effort[0] (c_j1): magnitude 1e+09 exceeds 1e+08 (the parameter max_torque'),
]
BAD_GROUP_COMMANDS = [
    (POSITION_GROUP, [0.1], 'group_command_size',
     f"data: 1 values for the 2 joints of group '{POSITION_GROUP}'"),
    (POSITION_GROUP, [0.1, 0.2, 0.3], 'group_command_size', None),
    (VELOCITY_GROUP, [], 'group_command_size', None),
    (VELOCITY_GROUP, [INF, 0.0], 'non_finite_target', None),
    (POSITION_GROUP, [NAN, -INF], 'non_finite_target', None),
]


def test_bad_commands_are_refused_counted_and_leave_the_targets_as_they_were(ros):
    node = ros.start({'scene': str(SCENE), 'start_paused': True})
    states = ros.client.subscribe(JointState, '/joint_states')
    diags = ros.client.subscribe(DiagnosticArray, '/diagnostics')
    joints = _publisher(ros, node, JointState, f'{NODE}/joint_commands')
    groups = {g: _publisher(ros, node, Float64MultiArray, f'/{g}/commands')
              for g in (POSITION_GROUP, VELOCITY_GROUP)}
    # Good commands first: the targets that the bad ones must leave alone.
    joints.publish(MIXED)
    _taken(ros, node, joints, diags, 0)
    t = _step(ros, node, 500)
    before = _at(ros, node, states, t, 'joint states')
    for group, data, _, _ in BAD_GROUP_COMMANDS:
        groups[group].publish(Float64MultiArray(data=data))
    # (A subscription keeps the 10 latest messages: a mark after every 6.)
    marks, counted = 0, 1   # (rejected_non_finite_effort: the mark above)
    for i in range(0, len(BAD_JOINT_COMMANDS), 6):
        for msg, cause, _ in BAD_JOINT_COMMANDS[i:i + 6]:
            joints.publish(msg)
            counted += cause == 'non_finite_effort'
        _taken(ros, node, joints, diags, counted)
        marks, counted = marks + 1, counted + 1
    _group_taken(ros, node, groups[POSITION_GROUP], 2, diags, 0)
    values = _group_taken(ros, node, groups[VELOCITY_GROUP], 2, diags, 1)
    expected = {}
    for _, cause, _ in BAD_JOINT_COMMANDS:
        expected[cause] = expected.get(cause, 0) + 1
    for _, _, cause, _ in BAD_GROUP_COMMANDS:
        expected[cause] = expected.get(cause, 0) + 1
    expected['non_finite_effort'] += 1 + marks   # (the NaN marks)
    for cause, count in expected.items():
        assert values[f'rejected_{cause}'] == str(count), cause
    assert values['joint_targets_superseded'] == values['joint_efforts_superseded'] == '0'
    # Refusals are logged naming the topic, field and problem, a line a second per cause:
    # the first of each cause (the text given; none for a cause on both kinds of topics,
    # whose order of arrival is unknown).
    for where, cause, text in [('~/joint_commands', c, x) for _, c, x in BAD_JOINT_COMMANDS] \
            + [(f'{g}/commands', c, x) for g, _, c, x in BAD_GROUP_COMMANDS]:
        if text:
            ros.client.wait_for(
                lambda: any(f'{where}: rejected ({cause}): {text}' in line
                            for line in node.log().splitlines()),
                f'the log line for {cause}', node=node)
    # The state did not jump and the targets are as they were: bit for bit the core
    # that had the good command only.
    t = _step(ros, node, 1500)
    _assert_equal(before, _core((TARGETS, 500)).joint_state())
    settled = _at(ros, node, states, t, 'joint states')
    _assert_equal(settled, _core((TARGETS, SETTLE)).joint_state())
    _assert_settled(_joints(settled))
    # And a good command after them works: a_j1 back to 0 (a step of 0.2 rad: half the
    # bound above, 1.7e-4 rad; tolerance 1e-3), through its group.
    groups[POSITION_GROUP].publish(Float64MultiArray(data=[-0.4, 0.0]))
    _group_taken(ros, node, groups[POSITION_GROUP], 2, diags, 2)
    t = _step(ros, node, SETTLE)
    last = _joints(_at(ros, node, states, t, 'joint states'))
    assert abs(last['a_j1'][0]) < 1e-3 and abs(last['a_j2'][0] + 0.4) < 1e-3
    assert ros.client.call(SetBool, f'{NODE}/pause', SetBool.Request(data=False),
                           node=node).success
    ros.client.wait_for(lambda: time_seconds(states[-1].header.stamp) > t + 0.05,
                        'joint states while running', node=node)


def _set_parameter(ros, node, name, value):
    return ros.client.set_parameter(NODE, name, value, node=node)


@pytest.mark.parametrize('name, value, group', [
    # rkmk4 takes kd explicitly: (kd + 0.1) dt c = 0.1 x 15.4 > 1 at b_j2.
    ('integrator', 'rkmk4', VELOCITY_GROUP),
    # kp dt² c = 400 x 0.01 x 15.4 > 1 at a_j2.
    ('physics_rate', 10.0, POSITION_GROUP),
])
def test_a_step_that_would_make_a_servo_unstable_is_refused(ros, name, value, group):
    node = ros.start({'scene': str(SCENE), 'start_paused': True})
    diags = ros.client.subscribe(DiagnosticArray, '/diagnostics')
    result = _set_parameter(ros, node, name, value)
    assert not result.successful
    assert f'command_groups.{group}: joint' in result.reason
    assert 'the explicit drive would be unstable' in result.reason
    # Nothing changed, nothing failed inside: the next diagnostics still show the scene's.
    ros.client.wait_for(lambda: diags, 'diagnostics', node=node)
    values = _values(diags[-1])
    assert values['integrator'] == 'lie_poisson2' and values['dt_s'] == '0.001'
    assert values['rejected_internal_error'] == '0'
    _step(ros, node, 10)


def _readme_group_row():
    section = README.read_text().split('### Robot topics', 1)[1].split('\n#', 1)[0]
    rows = [line.split('|') for line in section.splitlines() if line.startswith('| `G/')]
    assert len(rows) == 1, rows
    return rows[0][1].strip().strip('`'), rows[0][2].strip().strip('`').replace('/', '/msg/')


def test_each_group_has_the_topic_the_readme_documents_in_the_namespace(ros):
    name, typ = _readme_group_row()
    node = ros.start({'scene': str(SCENE), 'start_paused': True}, namespace='/robot1')
    expected = {f'/robot1/{name.replace("G/", g + "/", 1)}': typ
                for g in (POSITION_GROUP, VELOCITY_GROUP)}
    graph = ros.client.node

    def found():
        try:
            subs = graph.get_subscriber_names_and_types_by_node('rigid_body_sim', '/robot1')
        except Exception:  # noqa: B902 - the node not yet discovered
            return False
        topics = {n: t[0] for n, t in subs}
        return all(topics.get(n) == t for n, t in expected.items())
    ros.client.wait_for(found, f'the group topics {sorted(expected)}', node=node)


def test_a_group_name_that_cannot_be_a_topic_stops_the_node_naming_it(ros, tmp_path):
    scene = tmp_path / 'scene.yaml'
    scene.write_text(SCENE.read_text().replace(POSITION_GROUP, 'bad__name')
                     .replace('urdf/node_arm.urdf', str(SCENE.parent / 'urdf/node_arm.urdf')))
    node = ros.start({'scene': str(scene)})
    ros.client.wait_for(lambda: node.proc.poll() is not None, 'the node to exit', node=None)
    assert node.proc.returncode == 2
    assert "command group name: 'bad__name' cannot be part of a ROS name" in node.log()


# The unbounded drives (effort_limits: false): carrying the arm takes j1 more than its
# URDF effort of 10 N m (bounded drives: test_drive_effort_limits.py).
EXACT_SCENE = """
name: exact_arm
dt: 0.001
effects:
  gravity: {{g_world: [0.0, 0.0, -9.81]}}
robots:
  - {{urdf: {arm}, effort_limits: false, initial_positions: {{j1: 0.2, j2: -0.3}}}}
command_groups:
  - {{name: arm_exact, joints: [j1, j2], interface: position, mode: exact}}
"""


def test_an_exact_drive_follows_its_target_and_reports_the_torque_it_takes(ros, tmp_path):
    # node_arm under gravity with both joints on exact drives (driving constraints): they
    # hold their initial angles, then close a commanded jump along exp(−t/τ) exactly,
    # and joint_states' efforts are the drives' multipliers, as the core computes them.
    scene = tmp_path / 'exact_arm.yaml'
    scene.write_text(EXACT_SCENE.format(arm=SCENE.parent / 'urdf' / 'node_arm.urdf'))
    node = ros.start({'scene': str(scene), 'start_paused': True})
    states = ros.client.subscribe(JointState, '/joint_states')
    diags = ros.client.subscribe(DiagnosticArray, '/diagnostics')
    group = _publisher(ros, node, Float64MultiArray, '/arm_exact/commands')
    t = _step(ros, node, 100)
    held = _at(ros, node, states, t, 'joint states')
    # bound: SHAKE holds the rows to its tolerance, 1e-13 a step, from rest: 1e-11 rad.
    np.testing.assert_allclose(held.position, [0.2, -0.3], atol=1e-11)
    sim = load_scene(scene).simulation
    sim.step(100)
    _assert_equal(held, sim.joint_state())
    assert abs(held.effort[0]) > 1.0   # j1 carries the arm against gravity
    group.publish(Float64MultiArray(data=[0.5, NAN]))   # j2 keeps holding -0.3
    _group_taken(ros, node, group, 2, diags, 0)
    t = _step(ros, node, 60)
    seen = len(diags)
    moved = _at(ros, node, states, t, 'joint states')
    # After 60 steps the jump of 0.3 rad is 0.3 exp(−60 dt / τ) from done (τ = 0.05 s):
    # exactly, to SHAKE's tolerance per step: 1e-11.
    assert moved.position[0] - 0.5 == pytest.approx(-0.3 * math.exp(-60e-3 / 0.05), abs=1e-11)
    assert moved.position[1] == pytest.approx(-0.3, abs=1e-11)
    sim.command_joints({'j1': 0.5})
    sim.step(60)
    _assert_equal(moved, sim.joint_state())
    # The hinges hold (SHAKE's tolerance, with room: 1e-11); the drive's distance to go
    # (1.8e-2 rad) is not counted as a violation. (/diagnostics comes once a second.)
    ros.client.wait_for(lambda: len(diags) > seen, 'diagnostics after the steps', node=node)
    assert float(_values(diags[-1])['constraint_violation']) < 1e-11


def test_a_drive_beyond_its_effort_limit_saturates_and_diagnostics_say_so(ros, tmp_path):
    # The same arm with its drives bounded by the URDF efforts: j1's 10 N m cannot carry
    # the arm, so the drive saturates at once (its force is past E at the first step's
    # start, a located event) and j1 falls with its effort at the limit; joint_states'
    # efforts are the core's, bit for bit, and diagnostics name the saturated drive.
    scene = tmp_path / 'bounded_arm.yaml'
    scene.write_text(EXACT_SCENE.replace('effort_limits: false, ', '').format(
        arm=SCENE.parent / 'urdf' / 'node_arm.urdf'))
    node = ros.start({'scene': str(scene), 'start_paused': True})
    states = ros.client.subscribe(JointState, '/joint_states')
    diags = ros.client.subscribe(DiagnosticArray, '/diagnostics')
    t = _step(ros, node, 50)
    fallen = _at(ros, node, states, t, 'joint states')
    sim = load_scene(scene).simulation
    sim.step(50)
    _assert_equal(fallen, sim.joint_state())
    [(joint, sign)] = sim.drive_saturation()['saturated'].items()
    assert joint == 'j1' and fallen.effort[0] == sign * 10.0
    assert abs(fallen.position[0] - 0.2) > 1e-3      # it moved: the drive could not hold
    ros.client.wait_for(lambda: diags and _values(diags[-1]).get(
        'joint_drives_saturated') == f'j1:{"+" if sign > 0 else "-"}',
        'diagnostics naming the saturated drive', node=node)
    assert int(_values(diags[-1])['joint_drive_saturations_total']) >= 1


SPIN_SCENE = EXACT_SCENE.replace('name: exact_arm', 'name: spin_arm').replace(
    'name: arm_exact, joints: [j1, j2], interface: position',
    'name: arm_spin, joints: [j1, j2], interface: velocity')


def test_an_exact_velocity_drive_moves_at_its_velocity_through_both_topics(ros, tmp_path):
    # node_arm under gravity with both joints on exact velocity drives: a group command
    # turns j1 at 0.5 rad/s (j2 keeps v* = 0, held), then ~/joint_commands turns j2 at
    # −1 rad/s from where it is; each joint is on its line q_s + v* (t − t_s), and the
    # node's joint_states are the core's on the same commands, bit for bit.
    assert 'interface: velocity, mode: exact' in SPIN_SCENE
    scene = tmp_path / 'spin_arm.yaml'
    scene.write_text(SPIN_SCENE.format(arm=SCENE.parent / 'urdf' / 'node_arm.urdf'))
    node = ros.start({'scene': str(scene), 'start_paused': True})
    states = ros.client.subscribe(JointState, '/joint_states')
    diags = ros.client.subscribe(DiagnosticArray, '/diagnostics')
    group = _publisher(ros, node, Float64MultiArray, '/arm_spin/commands')
    joints = _publisher(ros, node, JointState, f'{NODE}/joint_commands')
    group.publish(Float64MultiArray(data=[0.5, NAN]))
    _group_taken(ros, node, group, 2, diags, 0)
    t1 = _step(ros, node, 100)
    moved = _at(ros, node, states, t1, 'joint states')
    # bound: SHAKE lands each step on the target of its end, to its tolerance (1e-13), and
    # the target's rounding: 1e-12; held j2 as the exact position test's (1e-11).
    assert moved.position[0] == pytest.approx(0.2 + 0.5 * t1, abs=1e-12)
    assert moved.position[1] == pytest.approx(-0.3, abs=1e-11)
    assert moved.velocity[0] == pytest.approx(0.5, abs=1e-10)   # bound: ω 1e-12 + rounding
    sim = load_scene(scene).simulation
    sim.command_joints({'j1': 0.5})
    sim.step(100)
    _assert_equal(moved, sim.joint_state())
    assert abs(moved.effort[0]) > 1.0   # j1 carries the arm against gravity
    joints.publish(JointState(name=['j2'], velocity=[-1.0]))
    joints.publish(JointState(name=['j1'], velocity=[NAN]))   # refused: j1 keeps 0.5 rad/s
    _counted(ros, node, diags, 'rejected_non_finite_target', 1)
    t2 = _step(ros, node, 50)
    turned = _at(ros, node, states, t2, 'joint states')
    assert turned.position[0] == pytest.approx(0.2 + 0.5 * t2, abs=1e-12)
    assert turned.position[1] == pytest.approx(-0.3 - 1.0 * (t2 - t1), abs=1e-11)
    sim.command_joints({'j2': -1.0})
    sim.step(50)
    _assert_equal(turned, sim.joint_state())
