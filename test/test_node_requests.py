"""
Every request to the node gets an answer, and a refused one changes nothing.

Through real DDS, the node in its own process: requests whose names cannot
become ROS names, a sweep of bad strings and numbers over every field of every
request, faults injected inside the node (``faulty_node.py``), and SIGTERM
during a long ``~/step``. After each, the node's state is compared with the
core's run directly, bit for bit (same compiled code, same machine).
"""

import math
from pathlib import Path
import signal

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import WrenchStamped
import numpy as np
import pytest
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
from rcl_interfaces.srv import SetParameters
from rigid_body_sim.ros.conversions import body_states_arrays, time_seconds
from rigid_body_sim.ros.inputs import MAX_TOPIC_LENGTH
from rigid_body_sim.scene import load_scene
from rigid_body_sim_interfaces.msg import BodyStates
from rigid_body_sim_interfaces.srv import AddConstraint, RemoveConstraint, Step
from ros_harness import CONFIG, python
from rosgraph_msgs.msg import Clock
from std_srvs.srv import SetBool, Trigger

NODE = '/rigid_body_sim'

PENDULUM = """
name: pendulum
integrator: lie_poisson2
dt: 0.001
effects:
  gravity: {g_world: [0.0, 0.0, -9.81]}
bodies:
  - {name: bob, mass: 1.0, inertia: [1.0e-3, 1.0e-3, 1.0e-3], position_world: [0.5, 0.0, 0.0]}
  - {name: free, mass: 2.0, inertia: [0.02, 0.03, 0.04], position_world: [0.0, 2.0, 0.0],
     angular_velocity_body: [0.1, 5.0, 0.1]}
constraints:
  - {name: pivot, type: ball, body_a: bob, anchor_world: [0.0, 0.0, 0.0]}
"""

#: Strings no field of a request accepts as a name (empty, 10 kB, control characters, a
#: trailing newline, non-ASCII, '/', '~', '{}', spaces).
BAD_STRINGS = ['', 'x' * 10_000, '\x01\x1b', 'pin\n', 'pin\t', 'ä', 'süß', 'a/b', '/a', '~/a',
               '~', '{a}', '{}', 'a b', ' ', '1a', '_a', 'a__b', 'a-b', 'a.b']
#: Numbers that no position, axis, length or rate accepts.
BAD_NUMBERS = [math.nan, math.inf, -math.inf, 1e300, -1e300]
SUBNORMAL = 5e-324


def _scene(tmp_path, text=PENDULUM):
    path = tmp_path / 'scene.yaml'
    path.write_text(text)
    return str(path)


def _request(**fields):
    """Return a valid ball joint of the bob at its own position, ``fields`` replaced."""
    values = {'name': 'extra', 'type': 'ball', 'body_a': 'bob', 'body_b': 'world',
              'anchor_world': [0.5, 0.0, 0.0]}
    values.update(fields)
    return AddConstraint.Request(**values)


def _call(ros, node, srv_type, service, request):
    return ros.client.call(srv_type, f'{NODE}/{service}', request, node=node)


def _state_at(ros, node, states, t):
    def found():
        return any(abs(time_seconds(m.header.stamp) - t) < 1e-9 for m in states)
    ros.client.wait_for(found, f'body states at t = {t}', node=node)
    return body_states_arrays(next(m for m in states
                                   if abs(time_seconds(m.header.stamp) - t) < 1e-9))


def _assert_as_the_core(ros, node, states, scene, steps, edit=None):
    """Step the paused node ``steps`` and compare every body with the core's, bit for bit."""
    reply = _call(ros, node, Step, 'step', Step.Request(steps=steps))
    assert reply.success, reply.message
    got = _state_at(ros, node, states, time_seconds(reply.time))
    sim = load_scene(scene).simulation
    if edit:
        edit(sim)
    sim.step(reply.step_count)
    for name in sim.bodies.names:
        for a, b in zip(got[name], (*sim.pose(name), *sim.twist(name))):
            np.testing.assert_array_equal(a, b)


def _values(diagnostics):
    return {kv.key: kv.value for kv in diagnostics.status[0].values}


def _parameter(name, value):
    if isinstance(value, float):
        pv = ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=value)
    else:
        pv = ParameterValue(type=ParameterType.PARAMETER_STRING, string_value=value)
    return SetParameters.Request(parameters=[Parameter(name=name, value=pv)])


def test_a_name_that_cannot_become_a_topic_is_refused_and_the_node_answers_on(ros, tmp_path):
    # Before: a name longer than the topic allows (or ending in a newline, which '$'
    # let through) was added, its topic then failed, and no reply came, then or for any
    # later add or remove.
    scene = _scene(tmp_path)
    node = ros.start({'scene': scene, 'start_paused': True})
    states = ros.client.subscribe(BodyStates, f'{NODE}/body_states')
    room = MAX_TOPIC_LENGTH - len(f'{NODE}/constraints//wrench')   # 212 characters
    for name in ('a' * (room + 1), 'a' * 1000, 'pin\n', 'pin\r\n'):
        reply = _call(ros, node, AddConstraint, 'add_constraint', _request(name=name))
        assert not reply.success
        assert 'name: ' in reply.message and ('ROS allows 247' in reply.message or
                                              'cannot be part of a ROS name' in reply.message)
    # The longest name that fits is added, answered, published, and removed again.
    longest = 'a' * room
    reply = _call(ros, node, AddConstraint, 'add_constraint', _request(name=longest))
    assert reply.success and reply.rows_added == 3, reply.message
    topic = f'{NODE}/constraints/{longest}/wrench'
    ros.client.wait_for(lambda: any(n == topic for n, _ in
                                    ros.client.node.get_topic_names_and_types()),
                        'the reaction topic of the longest name', node=node)
    reply = _call(ros, node, RemoveConstraint, 'remove_constraint',
                  RemoveConstraint.Request(name=longest))
    assert reply.success and reply.rows_removed == 3, reply.message
    # Nothing of that changed the motion (the bob at rest under its own pivot: the
    # extra joint at its centre changed no velocity).
    _assert_as_the_core(ros, node, states, scene, 300)


def test_every_field_of_every_request_is_checked_and_refusals_change_nothing(ros, tmp_path):
    scene = _scene(tmp_path)
    node = ros.start({'scene': scene, 'start_paused': True})
    states = ros.client.subscribe(BodyStates, f'{NODE}/body_states')
    diags = ros.client.subscribe(DiagnosticArray, '/diagnostics')
    refused = 0

    def refuse(srv_type, service, request, field):
        nonlocal refused
        reply = _call(ros, node, srv_type, service, request)
        assert not reply.success, (service, request)
        assert field in reply.message, (field, reply.message)
        assert len(reply.message) < 2000   # (a 10 kB name is not echoed whole)
        refused += 1
    # ~/add_constraint: each string field, then each number, with all else valid.
    for text in BAD_STRINGS:
        refuse(AddConstraint, 'add_constraint', _request(name=text), 'name: ')
        refuse(AddConstraint, 'add_constraint', _request(type=text), 'type: ')
        refuse(AddConstraint, 'add_constraint', _request(body_a=text), 'body_a: ')
        if text:   # ('' is the world, as documented)
            refuse(AddConstraint, 'add_constraint', _request(body_b=text), 'body_b: ')
    for x in BAD_NUMBERS:
        for field in ('anchor_world', 'anchor_a_body', 'anchor_b_body'):
            refuse(AddConstraint, 'add_constraint',
                   _request(**({field: [0.0, x, 0.0]} if field == 'anchor_world' else
                               {'anchor_world': [], field: [x, 0.0, 0.0]})), f'{field}: ')
        if not abs(x) < math.inf:
            refuse(AddConstraint, 'add_constraint',
                   _request(type='hinge', axis_world=[x, 1.0, 0.0]), 'axis_world: ')
        refuse(AddConstraint, 'add_constraint',
               _request(type='distance', anchor_world=[], length=x),
               'length: ' if math.isnan(x) or x < 0 or x == math.inf else 'inconsistent')
    for size in (0, 2, 4, 1000):
        refuse(AddConstraint, 'add_constraint', _request(anchor_world=[0.5] * size)
               if size else _request(type='hinge', anchor_world=[0.5, 0.0, 0.0]),
               'anchor_world: ' if size else 'axis_world: ')
    refuse(AddConstraint, 'add_constraint',
           _request(type='hinge', axis_world=[SUBNORMAL, 0.0, 0.0]), 'axis_world: ')
    refuse(AddConstraint, 'add_constraint', _request(type='distance', anchor_world=[],
                                                     length=-1.0), 'length: ')
    refuse(AddConstraint, 'add_constraint', _request(anchor_world=[1e12, 0.0, 0.0]),
           'outside the range of +-1e+06 m')
    refuse(AddConstraint, 'add_constraint', _request(name='pivot'), 'exists already')
    # Extremes that are valid are accepted (an axis near the float limit, a subnormal
    # anchor offset) and removed again, changing no velocity of the bob at rest.
    for request in (_request(type='hinge', axis_world=[1e300, 1e300, 0.0]),
                    _request(anchor_world=[], anchor_a_body=[SUBNORMAL, 0.0, 0.0],
                             anchor_b_body=[0.5, 0.0, 0.0])):
        reply = _call(ros, node, AddConstraint, 'add_constraint', request)
        assert reply.success, reply.message
        assert _call(ros, node, RemoveConstraint, 'remove_constraint',
                     RemoveConstraint.Request(name='extra')).success
    # ~/remove_constraint, ~/step.
    for text in BAD_STRINGS:
        refuse(RemoveConstraint, 'remove_constraint', RemoveConstraint.Request(name=text),
               'name: no constraint')
    refuse(Step, 'step', Step.Request(steps=2 ** 32 - 1), 'steps: at most')
    # Parameters: each refused with the parameter named.
    for name in ('physics_rate', 'publish_rate', 'clock_rate'):
        for x in (*BAD_NUMBERS, SUBNORMAL, -1.0, 0.0):
            result = _call(ros, node, SetParameters, 'set_parameters',
                           _parameter(name, x)).results[0]
            assert not result.successful and result.reason.startswith(f'{name}: '), \
                (x, result.reason)
    for name in ('tolerance', 'real_time_factor', 'wrench_timeout', 'max_force', 'max_torque'):
        for x in (math.nan, math.inf, -1.0):
            result = _call(ros, node, SetParameters, 'set_parameters',
                           _parameter(name, x)).results[0]
            assert not result.successful and result.reason.startswith(f'{name}: '), \
                (x, result.reason)
    for name in ('integrator', 'world_frame'):
        for text in ['x' * 10_000, '\x01', 'a b', '/a', 'ä\n', 'pin\n']:
            result = _call(ros, node, SetParameters, 'set_parameters',
                           _parameter(name, text)).results[0]
            assert not result.successful and result.reason.startswith(f'{name}: '), \
                (text, result.reason)
    result = _call(ros, node, SetParameters, 'set_parameters',
                   _parameter('physics_rate', 'fast')).results[0]
    assert not result.successful and 'physics_rate: expected a number' in result.reason
    # Wrench messages: bad frames and numbers are counted, never applied; a subnormal force
    # is valid and superseded by the zero wrench after it, before any step.
    pub = ros.client.node.create_publisher(WrenchStamped, f'{NODE}/bodies/bob/wrench', 100)
    ros.client.wait_for(lambda: pub.get_subscription_count() > 0, 'the wrench subscriber',
                        node=node)
    wrenches = [(frame, (1.0, 0.0, 0.0), 'unknown_frame') for frame in BAD_STRINGS]
    wrenches += [('world', (x, 0.0, 0.0), 'non_finite' if not abs(x) < math.inf
                  else 'too_large') for x in BAD_NUMBERS]
    expected = {}

    def counted():
        return diags and all(int(_values(diags[-1])[k]) >= v for k, v in expected.items())
    # In batches of 8: the node's subscription keeps the 10 latest messages (as documented),
    # so a batch is counted on /diagnostics before the next is sent.
    for start in range(0, len(wrenches), 8):
        for frame, force, cause in wrenches[start:start + 8]:
            msg = WrenchStamped()
            msg.header.frame_id = frame
            msg.wrench.force.x, msg.wrench.force.y, msg.wrench.force.z = force
            pub.publish(msg)
            expected[f'rejected_{cause}'] = expected.get(f'rejected_{cause}', 0) + 1
        ros.client.wait_for(counted, 'the wrench rejections on /diagnostics', node=node)
    for force in ((SUBNORMAL, 0.0, 0.0), (0.0, 0.0, 0.0)):
        msg = WrenchStamped()
        msg.header.frame_id = 'world'
        msg.wrench.force.x, msg.wrench.force.y, msg.wrench.force.z = force
        pub.publish(msg)
    # Both arrived once the first is counted as superseded by the second.
    ros.client.wait_for(lambda: int(_values(diags[-1])['wrench_messages_superseded']) >= 1,
                        'the zero wrench to supersede the subnormal one', node=node)
    values = _values(diags[-1])
    for key, count in expected.items():
        assert int(values[key]) == count, (key, values[key])
    assert values['rejected_internal_error'] == '0'
    # After all of that, the node moves exactly as the core does with nothing sent (the
    # held zero wrench adds nothing).
    _assert_as_the_core(ros, node, states, scene, 500, edit=lambda sim: sim.apply_wrench(
        'bob', frame='world', point_body=[0.0, 0.0, 0.0], key='topic:bob'))
    print(f'{refused} requests refused, each answered naming its field')


def _next_node(ros, node):
    """Stop ``node``; forget the client's service clients and messages (a fresh start)."""
    assert node.stop() == 0
    for client in getattr(ros.client, '_clients', {}).values():
        ros.client.node.destroy_client(client)   # (new ones match only the next node)
    ros.client._clients = {}
    ros.client.received.clear()


def _faulty(ros, scene, faults):
    program = ['env', f'FAULTS={",".join(faults)}', python(),
               str(Path(__file__).with_name('faulty_node.py'))]
    return ros.start({'scene': scene, 'start_paused': True}, program=program)


def test_a_request_that_fails_inside_the_node_is_answered_and_changes_nothing(ros, tmp_path):
    scene = _scene(tmp_path)
    states = ros.client.subscribe(BodyStates, f'{NODE}/body_states')
    diags = ros.client.subscribe(DiagnosticArray, '/diagnostics')
    # 1. The reaction publisher cannot be created; removing, resetting, pausing fail.
    node = _faulty(ros, scene, ['ros.node:SimNode.create_publisher',
                                'core.simulation:Simulation.remove_constraint',
                                'core.simulation:Simulation.reset',
                                'ros.node:SimNode._on_pause'])
    for srv_type, service, request in (
            (AddConstraint, 'add_constraint', _request()),
            (RemoveConstraint, 'remove_constraint', RemoveConstraint.Request(name='pivot')),
            (Trigger, 'reset', Trigger.Request()),
            (SetBool, 'pause', SetBool.Request(data=False))):
        reply = _call(ros, node, srv_type, service, request)
        assert not reply.success, service
        assert 'internal error' in reply.message and 'injected fault' in reply.message, \
            reply.message
    # 'extra' was never added (its name is free), 'pivot' never removed (the bob still
    # swings about it, as in the core), and the node still answers and steps.
    reply = _call(ros, node, RemoveConstraint, 'remove_constraint',
                  RemoveConstraint.Request(name='extra'))
    assert not reply.success and "no constraint 'extra'" in reply.message
    _assert_as_the_core(ros, node, states, scene, 300)
    ros.client.wait_for(lambda: diags and _values(diags[-1])['rejected_internal_error'] == '4',
                        'four internal errors counted', node=node)
    _next_node(ros, node)
    states = ros.client.subscribe(BodyStates, f'{NODE}/body_states')
    # 2. The core fails after the constraint joined the set (reconciling the velocities):
    # it is taken out again and the state is as before.
    node = _faulty(ros, scene, ['core.simulation:Simulation._reconcile_velocities'])
    reply = _call(ros, node, AddConstraint, 'add_constraint',
                  _request(name='tie', body_a='free', anchor_world=[0.0, 2.0, 0.0]))
    assert not reply.success and 'injected fault' in reply.message, reply.message
    _assert_as_the_core(ros, node, states, scene, 300)
    _next_node(ros, node)
    states = ros.client.subscribe(BodyStates, f'{NODE}/body_states')
    # 3. A step that raises: ~/step answers, says after how many steps, and pauses.
    node = _faulty(ros, scene, ['core.simulation:Simulation.step'])
    reply = _call(ros, node, Step, 'step', Step.Request(steps=10))
    assert not reply.success and 'stopped after 0 of 10 steps' in reply.message, reply.message
    assert 'injected fault' in reply.message and reply.step_count == 0
    assert node.stop() == 0


def test_sigterm_during_a_long_step_request_replies_that_it_stopped(ros, tmp_path):
    # Before: the reply said success and "1000000 steps" after the few taken.
    node = ros.start({'scene': str(CONFIG / 'pendulum_chain.yaml'), 'start_paused': True})
    clock = ros.client.subscribe(Clock, '/clock')
    client = ros.client.node.create_client(Step, f'{NODE}/step')
    ros.client.wait_for(client.service_is_ready, 'the step service', node=node)
    future = client.call_async(Step.Request(steps=1_000_000))
    # The steps have begun once /clock passes 0 (about 40 us a step: 40 s in all).
    ros.client.wait_for(lambda: any(time_seconds(m.clock) > 0.0 for m in clock),
                        'the clock to run', node=node)
    node.proc.send_signal(signal.SIGTERM)
    ros.client.wait_for(future.done, 'the reply of the interrupted step request')
    reply = future.result()
    assert not reply.success
    assert reply.message.startswith(f'stopped after {reply.step_count} of 1000000 steps: the '
                                    'node is shutting down'), reply.message
    assert 0 < reply.step_count < 1_000_000
    assert time_seconds(reply.time) == pytest.approx(reply.step_count * 1e-3, abs=1e-9)
    assert node.proc.wait(30) == 0
