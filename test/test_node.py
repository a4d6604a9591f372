"""
The node through real DDS: the node in its own process, this test as its client.

Every number is checked against the core run directly (bit for bit where the
node and the core take the same steps) or against Newton's laws.
"""

import math
import signal
import time

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import WrenchStamped
import numpy as np
import pytest
from rigid_body_sim.core import rotation as so3
from rigid_body_sim.ros.conversions import body_states_arrays, time_seconds
from rigid_body_sim.scene import load_scene
from rigid_body_sim_interfaces.msg import BodyStates
from rigid_body_sim_interfaces.srv import AddConstraint, RemoveConstraint, Step
from ros_harness import CONFIG, executable
from std_srvs.srv import SetBool, Trigger

NODE = '/rigid_body_sim'

FREE_BODY = """
name: free_body
integrator: lie_poisson2
dt: 0.001
bodies:
  - name: box
    mass: 2.0
    inertia: [0.02, 0.03, 0.04]
    com_body: [0.1, 0.0, 0.0]
    position_world: [0.0, 0.0, 1.0]
"""

FALLING_BOB = """
name: falling_bob
integrator: lie_poisson2
dt: 0.001
effects:
  gravity: {g_world: [0.0, 0.0, -9.81]}
bodies:
  - {name: bob, mass: 1.0, inertia: [1.0e-6, 1.0e-6, 1.0e-6], position_world: [0.5, 0.0, 0.0]}
"""


def _scene(tmp_path, text, name='scene.yaml'):
    path = tmp_path / name
    path.write_text(text)
    return str(path)


def _wrench(frame, force=(0.0, 0.0, 0.0), torque=(0.0, 0.0, 0.0)):
    msg = WrenchStamped()
    msg.header.frame_id = frame
    msg.wrench.force.x, msg.wrench.force.y, msg.wrench.force.z = map(float, force)
    msg.wrench.torque.x, msg.wrench.torque.y, msg.wrench.torque.z = map(float, torque)
    return msg


def _step(ros, node, n, ns=NODE):
    reply = ros.client.call(Step, f'{ns}/step', Step.Request(steps=n), node=node)
    assert reply.success, reply.message
    return reply


def _state_at(ros, node, states, t, what='body states'):
    """Wait for the BodyStates message stamped ``t`` and return its bodies."""
    # (Stamps are whole nanoseconds: 1e-9 s picks the one stamp nearest to t.)
    def found():
        return any(abs(time_seconds(m.header.stamp) - t) < 1e-9 for m in states)
    ros.client.wait_for(found, f'{what} at t = {t}', node=node)
    msg = next(m for m in states if abs(time_seconds(m.header.stamp) - t) < 1e-9)
    return body_states_arrays(msg)


def test_executables_are_where_ros2_run_looks():
    for name in ('sim_node', 'echo_body', 'rigid_body_sim_run'):
        path = executable(name)
        assert path.is_file() and path.stat().st_mode & 0o111, path


def _readme_table(heading):
    """Return the first-column names and the types of the README table under ``heading``."""
    text = (CONFIG.parent / 'README.md').read_text()
    section = text.split(heading, 1)[1].split('\n#', 1)[0]
    rows = [line.split('|') for line in section.splitlines() if line.startswith('| `')]
    return {r[1].strip().strip('`'): r[2].strip().strip('`') for r in rows}


def test_the_live_graph_is_the_one_the_readme_documents(ros):
    node = ros.start({'start_paused': True})
    graph = ros.client.node
    sim = load_scene(CONFIG / 'default_scene.yaml').simulation
    services, actions = {}, {}
    for name, typ in _readme_table('### Services').items():
        full = f'{NODE}/{name[2:]}' if name.startswith('~/') else f'/{name}'
        if typ.endswith('/SimulateSteps'):   # (an action: its services and topics, below)
            actions[full] = typ.replace('/', '/action/')
        else:
            services[full] = typ.replace('/', '/srv/')
    introspected = dict(services)
    for full, typ in actions.items():
        services.update({f'{full}/_action/send_goal': f'{typ}_SendGoal',
                         f'{full}/_action/get_result': f'{typ}_GetResult',
                         f'{full}/_action/cancel_goal': 'action_msgs/srv/CancelGoal'})
    topics = {}
    for name, typ in _readme_table('### Topics').items():
        full = name if name.startswith('/') else f'{NODE}/{name[2:]}'
        typ = typ.replace('/', '/msg/')
        if '/B/' in full:
            topics.update({full.replace('/B/', f'/{b}/'): typ for b in sim.bodies.names})
        elif '/C/' in full:
            topics.update({full.replace('/C/', f'/{c}/'): typ for c in sim.constraint_names})
        elif '<service>' not in full:   # (service events: below)
            topics[full] = typ
    for full, typ in actions.items():
        topics.update({f'{full}/_action/feedback': f'{typ}_FeedbackMessage',
                       f'{full}/_action/status': 'action_msgs/msg/GoalStatusArray'})

    def live_services():
        found = dict(graph.get_service_names_and_types_by_node('rigid_body_sim', '/'))
        return {n: t[0] for n, t in found.items()   # (not rclpy's own services)
                if 'parameter' not in n and not n.endswith('/get_type_description')}

    def live_topics():
        pubs = graph.get_publisher_names_and_types_by_node('rigid_body_sim', '/')
        subs = graph.get_subscriber_names_and_types_by_node('rigid_body_sim', '/')
        return {n: t[0] for n, t in pubs + subs   # (service events: checked below)
                if n not in ('/rosout', '/parameter_events') and '/_service_event' not in n}
    ros.client.wait_for(lambda: 'rigid_body_sim' in graph.get_node_names(), 'the node',
                        node=node)
    end = time.monotonic() + 20.0   # discovery: wait for the graph, with a deadline
    while (live_services(), live_topics()) != (services, topics) and time.monotonic() < end:
        ros.client.executor.spin_once(timeout_sec=0.1)
    assert live_services() == services
    assert live_topics() == topics
    # Every service's calls are published (introspection), as recorded bags need them.
    pubs = dict(graph.get_publisher_names_and_types_by_node('rigid_body_sim', '/'))
    for name, typ in introspected.items():
        assert pubs[f'{name}/_service_event'] == [f'{typ}_Event']


def test_wrench_moves_the_body_as_the_core_predicts(ros, tmp_path):
    scene = _scene(tmp_path, FREE_BODY)
    node = ros.start({'scene': scene, 'publish_rate': 1000.0})
    states = ros.client.subscribe(BodyStates, f'{NODE}/body_states')
    pub = ros.client.node.create_publisher(WrenchStamped, f'{NODE}/bodies/box/wrench', 10)
    ros.client.wait_for(lambda: len(states) > 5, 'body states', node=node)
    force = np.array([4.0, 0.0, 2.0])
    pub.publish(_wrench('world', force))

    def moving():
        return bool(states) and bool(np.any(body_states_arrays(states[-1])['box'][2]))
    ros.client.wait_for(moving, 'the box to move', node=node)
    # States come every step: the last one at rest is the step before the wrench acted.
    i = next(i for i, m in enumerate(states) if np.any(body_states_arrays(m)['box'][2]))
    msg = states[i]
    t = time_seconds(msg.header.stamp)
    k0 = round(time_seconds(states[i - 1].header.stamp) / 1e-3)
    assert round(t / 1e-3) == k0 + 1
    # The core, stepped the same way, gives the same state, bit for bit.
    sim = load_scene(scene).simulation
    sim.step(k0)
    sim.apply_wrench('box', force, frame='world', point_body=[0.0, 0.0, 0.0], key='topic:box')
    sim.step(1)
    pos, quat = sim.pose('box')
    vel, omega = sim.twist('box')
    got = body_states_arrays(msg)['box']
    for a, b in zip(got, (pos, quat, vel, omega)):
        np.testing.assert_array_equal(a, b)
    # Applied at the body frame's origin, 0.1 m from the centre of mass: it also turns it.
    assert np.linalg.norm(omega) > 0.0
    # And Newton: the centre of mass accelerates at F/m from t0 on.
    # bound: one step of F/m dt, a few roundings (1e-16 relative); 1e-12 leaves room
    np.testing.assert_allclose(sim.state.vel_com_world[0], force / 2.0 * 1e-3, rtol=1e-12)


def test_body_frame_torque_spins_the_body(ros, tmp_path):
    scene = _scene(tmp_path, FREE_BODY.replace('com_body: [0.1, 0.0, 0.0]',
                                               'com_body: [0.0, 0.0, 0.0]'))
    node = ros.start({'scene': scene, 'start_paused': True})
    states = ros.client.subscribe(BodyStates, f'{NODE}/body_states')
    pub = ros.client.node.create_publisher(WrenchStamped, f'{NODE}/bodies/box/wrench', 10)
    ros.client.wait_for(lambda: pub.get_subscription_count() > 0, 'the wrench subscriber',
                        node=node)
    # While paused, a published wrench is queued until a step; publish it and step until
    # the body turns, then the spin rate is tau / Izz times the time since it started.
    pub.publish(_wrench('box', torque=(0.0, 0.0, 0.08)))
    for _ in range(200):
        reply = _step(ros, node, 10)
        t = time_seconds(reply.time)
        w = _state_at(ros, node, states, t)['box'][3]
        if np.any(w):
            break
    else:
        pytest.fail('the torque never took effect')
    reply = _step(ros, node, 100)
    t1 = time_seconds(reply.time)
    w1 = _state_at(ros, node, states, t1)['box'][3]
    assert w1[0] == 0.0 and w1[1] == 0.0
    # 0.08 N m about z on Izz = 0.04: 2 rad/s^2 over exactly the 100 steps (and what before).
    # bound: Euler's equations are exact about a principal axis; 100 additions of 2e-3
    # round by 100 eps relative at most (2e-14); 1e-12 leaves room
    assert w1[2] - w[2] == pytest.approx(2.0 * 0.1, rel=1e-12)


@pytest.mark.parametrize('reset_time', [False, True])
def test_reset_returns_to_the_initial_state(ros, tmp_path, reset_time):
    scene = _scene(tmp_path, FREE_BODY)
    node = ros.start({'scene': scene, 'start_paused': True, 'reset_time': reset_time})
    states = ros.client.subscribe(BodyStates, f'{NODE}/body_states')
    _step(ros, node, 0)   # replies with the state published
    initial = _state_at(ros, node, states, 0.0, 'the initial state')['box']
    pub = ros.client.node.create_publisher(WrenchStamped, f'{NODE}/bodies/box/wrench', 10)
    ros.client.wait_for(lambda: pub.get_subscription_count() > 0, 'the wrench subscriber',
                        node=node)
    pub.publish(_wrench('world', force=(1.0, 0.0, 0.0)))
    for _ in range(200):
        reply = _step(ros, node, 10)
        if np.any(_state_at(ros, node, states, time_seconds(reply.time))['box'][2]):
            break
    t_last = time_seconds(reply.time)
    reply = ros.client.call(Trigger, f'{NODE}/reset', Trigger.Request(), node=node)
    assert reply.success, reply.message
    # By default time runs on (the reset state one step after the last): /clock never
    # jumps back; with reset_time it starts again at 0.
    t_reset = 0.0 if reset_time else t_last + 1e-3
    after = _state_at(ros, node, states, t_reset, 'the state after reset')['box']
    for a, b in zip(after, initial):
        np.testing.assert_array_equal(a, b)
    # The held wrench was cleared: 100 more steps leave the body at rest.
    reply = _step(ros, node, 100)
    # bound: stamps are whole ns (the reset's offset rounds to the nearest ns): 1e-9 s
    assert time_seconds(reply.time) == pytest.approx(t_reset + 0.1, abs=1e-9)
    assert reply.step_count == 100
    later = _state_at(ros, node, states, time_seconds(reply.time))['box']
    for a, b in zip(later, initial):
        np.testing.assert_array_equal(a, b)


def test_ball_joint_added_while_falling_swings_as_a_pendulum(ros, tmp_path):
    length, g = 0.5, 9.81
    node = ros.start({'scene': _scene(tmp_path, FALLING_BOB), 'start_paused': True})
    states = ros.client.subscribe(BodyStates, f'{NODE}/body_states')
    _step(ros, node, 100)   # 0.1 s of free fall
    t_add = 0.1
    bob = _state_at(ros, node, states, t_add)['bob']
    # A pivot 0.5 m from the bob, up and to the side: the joint takes the radial velocity
    # (an inelastic impact) and the bob swings from there.
    direction = np.array([-np.sin(0.6), 0.0, np.cos(0.6)])
    pivot = bob[0] + length * direction
    request = AddConstraint.Request(name='rod', type='ball', body_a='bob', body_b='world',
                                    anchor_world=pivot.tolist())
    reply = ros.client.call(AddConstraint, f'{NODE}/add_constraint', request, node=node)
    assert reply.success, reply.message
    assert reply.rows_added == 3
    reactions = ros.client.subscribe(WrenchStamped, f'{NODE}/constraints/rod/wrench')
    ros.client.wait_for(lambda: ros.client.node.count_publishers(
        f'{NODE}/constraints/rod/wrench') > 0, 'the reaction publisher', node=node)
    samples = []
    t = t_add
    while t < t_add + 3.2:
        reply = _step(ros, node, 10)
        t = time_seconds(reply.time)
        p, q, v, w = _state_at(ros, node, states, t)['bob']
        samples.append((t, p, q, v))
    # The energy after the impact fixes the amplitude: v^2 = 2 g L (cos th - cos th_max).
    t0, p0, q0, v0 = samples[0]
    rel0 = p0 - pivot
    cos0 = -rel0[2] / length
    cos_max = cos0 - float(v0 @ v0) / (2 * g * length)
    k = math.sin(math.acos(cos_max) / 2)
    period = 4 * math.sqrt(length / g) * _ellipk(k * k)
    # The period between upward zero crossings of the swing, to 1e-5.
    xs = np.array([s[1][0] - pivot[0] for s in samples])
    ts = np.array([s[0] for s in samples])
    ups = [ts[i] - xs[i] * (ts[i + 1] - ts[i]) / (xs[i + 1] - xs[i])
           for i in range(len(xs) - 1) if xs[i] < 0.0 <= xs[i + 1]]
    assert len(ups) >= 2, 'the bob swings through the bottom twice'
    # bound: a second-order method's period error ~ (omega dt)^2 / 24 = 8e-7 at omega =
    # 4.4 rad/s; the crossing's linear interpolation errs by O(dt^2 x'') with x'' ~ 0 at the
    # bottom; 1e-5 = 12x (a first-order method errs by ~ omega dt / 2 = 2e-3)
    assert ups[1] - ups[0] == pytest.approx(period, rel=1e-5)
    # The rod's pull on the bob, in the bob's frame: along the rod, of the tension
    # m (g cos th + v^2 / L) of a point mass on a circle.
    ros.client.wait_for(lambda: sum(abs(time_seconds(m.header.stamp) - samples[-1][0]) < 1e-9
                                    for m in reactions) == 2, 'the last reactions', node=node)
    checked = 0
    for t, p, q, v in samples:
        msgs = [m for m in reactions if abs(time_seconds(m.header.stamp) - t) < 1e-9]
        on_bob = [m for m in msgs if m.header.frame_id == 'bob']
        on_world = [m for m in msgs if m.header.frame_id == 'world']
        if not (on_bob and on_world):   # (before the subscription matched)
            continue
        f_body = np.array([on_bob[0].wrench.force.x, on_bob[0].wrench.force.y,
                           on_bob[0].wrench.force.z])
        f_world = so3.quat_to_matrix(q) @ f_body
        rel = p - pivot
        tension = 1.0 * (g * (-rel[2] / length) + float(v @ v) / length)
        # bound: the bob is a point mass to I / (m L^2) = 4e-6, and the sampled state and
        # the solve's differ by O((omega dt)^2) = 2e-5 relative; 1e-4 (N) = 5x
        np.testing.assert_allclose(f_world, -tension * rel / length, rtol=1e-4, atol=1e-4)
        fw = on_world[0].wrench.force
        # bound: one force rotated twice, ~6 roundings of |f| < 30 N: 4e-14 N
        np.testing.assert_allclose([fw.x, fw.y, fw.z], -f_world, rtol=1e-12, atol=1e-12)
        checked += 1
    assert checked >= len(samples) // 2


def _ellipk(m):
    """Return the complete elliptic integral K(m) by the arithmetic-geometric mean."""
    a, b = 1.0, math.sqrt(1.0 - m)
    while abs(a - b) > 1e-15:
        a, b = (a + b) / 2, math.sqrt(a * b)
    return math.pi / (2 * a)


def test_stepping_is_bit_identical_across_runs_and_equal_to_the_core(ros, tmp_path):
    scene = str(CONFIG / 'thrown_bodies.yaml')
    finals = []
    for run in range(2):
        ns = f'/run{run}'
        node = ros.start({'scene': scene, 'start_paused': True}, namespace=ns)
        states = ros.client.subscribe(BodyStates, f'{ns}{NODE}/body_states')
        for _ in range(3):
            reply = _step(ros, node, 250, ns=f'{ns}{NODE}')
        assert reply.step_count == 750
        finals.append(_state_at(ros, node, states, time_seconds(reply.time)))
        node.stop()
    sim = load_scene(scene).simulation
    sim.step(750)
    for name in sim.bodies.names:
        pos, quat = sim.pose(name)
        vel, omega = sim.twist(name)
        for a, b, c in zip(finals[0][name], finals[1][name], (pos, quat, vel, omega)):
            np.testing.assert_array_equal(a, b)
            np.testing.assert_array_equal(a, c)


def test_stepping_with_inputs_is_bit_identical_across_runs_and_equal_to_the_core(ros):
    # Two runs of ~/step with the same inputs between the calls: a held wrench on each body
    # (world and body frame), a distance constraint added and removed, a reset. Every state
    # the step replies stand for is the same in both runs and the core's, bit for bit.
    scene = str(CONFIG / 'thrown_bodies.yaml')
    push = {'force': (3.0, -2.0, 5.0), 'torque': (0.0, 0.02, 0.0)}
    spin = {'force': (0.0, 0.5, 0.0), 'torque': (0.01, 0.0, -0.003)}
    tether = {'name': 'tether', 'type': 'distance', 'body_a': 'rugby_ball',
              'body_b': 'tumbling_box'}
    runs = []
    for run in range(2):
        ns = f'/run{run}{NODE}'
        node = ros.start({'scene': scene, 'start_paused': True}, namespace=f'/run{run}')
        states = ros.client.subscribe(BodyStates, f'{ns}/body_states')
        diags = ros.client.subscribe(DiagnosticArray, '/diagnostics')
        pubs = {b: ros.client.node.create_publisher(WrenchStamped, f'{ns}/bodies/{b}/wrench',
                                                    10) for b in ('tumbling_box', 'rugby_ball')}
        got = []

        def step(n):
            reply = _step(ros, node, n, ns=ns)
            t = time_seconds(reply.time)
            got.append((t, reply.step_count, _state_at(ros, node, states, t)))
        step(100)
        _queue_wrench(ros, node, pubs['tumbling_box'], _wrench('world', **push), diags, 1, ns)
        step(150)
        reply = ros.client.call(AddConstraint, f'{ns}/add_constraint',
                                AddConstraint.Request(**tether), node=node)
        assert reply.success and reply.rows_added == 1, reply.message
        step(200)
        _queue_wrench(ros, node, pubs['rugby_ball'], _wrench('rugby_ball', **spin), diags, 2,
                      ns)
        step(100)
        reply = ros.client.call(RemoveConstraint, f'{ns}/remove_constraint',
                                RemoveConstraint.Request(name='tether'), node=node)
        assert reply.success and reply.rows_removed == 1, reply.message
        step(100)
        assert ros.client.call(Trigger, f'{ns}/reset', Trigger.Request(), node=node).success
        step(50)
        runs.append(got)
        node.stop()
        ros.client.received.clear()
    # The core, driven the same way (a held wrench per topic at the body frame's origin).
    from rigid_body_sim.core import Constraint
    sim = load_scene(scene).simulation
    origin = [0.0, 0.0, 0.0]
    expected = []

    def step(n):
        sim.step(n)
        expected.append({name: (*sim.pose(name), *sim.twist(name))
                         for name in sim.bodies.names})
    step(100)
    sim.apply_wrench('tumbling_box', **push, frame='world', point_body=origin,
                     key='topic:tumbling_box')
    step(150)
    sim.add_constraint(Constraint(**tether))
    step(200)
    sim.apply_wrench('rugby_ball', **spin, frame='body', point_body=origin,
                     key='topic:rugby_ball')
    step(100)
    sim.remove_constraint('tether')
    step(100)
    sim.reset()
    step(50)
    # Time runs on across the reset: the initial state is stamped 0.651 s, 50 steps later
    # 0.701 s, and the step count starts again.
    for got in runs:
        assert [round(t * 1e3) for t, _, _ in got] == [100, 250, 450, 550, 650, 701]
        assert [count for _, count, _ in got] == [100, 250, 450, 550, 650, 50]
    for (t0, _, a), (t1, _, b), c in zip(*runs, expected):
        assert t0 == t1
        for name in c:
            for x, y, z in zip(a[name], b[name], c[name]):
                np.testing.assert_array_equal(x, y)
                np.testing.assert_array_equal(x, z)
    # The inputs acted: at 0.55 s the wrenches and the tether have moved the bodies off their
    # free flight (measured: the ball by 1.75 m, the box by 0.64 m).
    free = load_scene(scene).simulation
    free.step(550)
    for name in ('rugby_ball', 'tumbling_box'):
        assert np.linalg.norm(runs[0][3][2][name][0] - free.pose(name)[0]) > 0.1


def _queue_wrench(ros, node, pub, msg, diags, nth, ns=NODE):
    """
    Publish a wrench, then a NaN on the same topic; wait until the node has counted the NaN.

    Messages on one topic arrive in order, so the wrench is then queued and acts at the
    next step: a step request published after it could otherwise be served first. ``nth``
    counts this node's NaN messages so far, this one included.
    """
    ros.client.wait_for(lambda: pub.get_subscription_count() > 0, 'the wrench subscriber',
                        node=node)
    pub.publish(msg)
    pub.publish(_wrench('world', force=(math.nan, 0.0, 0.0)))
    ros.client.wait_for(lambda: any(d.status[0].hardware_id == ns
                                    and int(_values(d)['rejected_non_finite']) >= nth
                                    for d in diags), 'the NaN to be counted', node=node)


def test_as_fast_as_possible_is_bit_identical_to_the_core(ros, tmp_path):
    scene = str(CONFIG / 'thrown_bodies.yaml')
    node = ros.start({'scene': scene, 'real_time_factor': 0.0, 'start_paused': True})
    states = ros.client.subscribe(BodyStates, f'{NODE}/body_states')
    # A paused node republishes its state each second: then no message is missed.
    _state_at(ros, node, states, 0.0, 'the paused state')
    assert ros.client.call(SetBool, f'{NODE}/pause', SetBool.Request(data=False),
                           node=node).success
    got = _state_at(ros, node, states, 0.5)
    sim = load_scene(scene).simulation
    sim.step(500)
    for name in sim.bodies.names:
        pos, quat = sim.pose(name)
        vel, omega = sim.twist(name)
        for a, c in zip(got[name], (pos, quat, vel, omega)):
            np.testing.assert_array_equal(a, c)


def test_two_namespaced_simulators_do_not_interfere(ros, tmp_path):
    scene = _scene(tmp_path, FREE_BODY)
    nodes = {ns: ros.start({'scene': scene}, namespace=ns) for ns in ('/robot1', '/robot2')}
    states = {ns: ros.client.subscribe(BodyStates, f'{ns}{NODE}/body_states') for ns in nodes}
    pub = ros.client.node.create_publisher(WrenchStamped, f'/robot1{NODE}/bodies/box/wrench',
                                           10)
    ros.client.wait_for(lambda: pub.get_subscription_count() == 1, 'robot1 to subscribe')
    pub.publish(_wrench('world', force=(0.0, 1.0, 0.0)))

    def moved(ns):
        return any(np.any(body_states_arrays(m)['box'][2]) for m in states[ns])
    ros.client.wait_for(lambda: moved('/robot1'), 'robot1 to move', node=nodes['/robot1'])
    t1 = time_seconds(states['/robot1'][-1].header.stamp)
    ros.client.wait_for(lambda: states['/robot2'] and time_seconds(
        states['/robot2'][-1].header.stamp) > t1, 'robot2 to pass that time')
    assert not moved('/robot2')


def test_sigterm_and_sigint_end_the_node_cleanly(ros, tmp_path):
    for sig in (signal.SIGTERM, signal.SIGINT):
        node = ros.start({'scene': _scene(tmp_path, FREE_BODY)})
        states = ros.client.subscribe(BodyStates, f'{NODE}/body_states')
        ros.client.wait_for(lambda: len(states) > 2, 'body states', node=node)
        assert node.stop(sig) == 0
        assert 'Traceback' not in node.log()
        ros.client.received.clear()


def test_a_bad_parameter_stops_start_up_naming_it(tmp_path):
    import subprocess
    from ros_harness import random_domain, ros_env
    for params, message in ((['-p', 'physics_rate:=-5.0'], 'physics_rate: must be in'),
                            (['-p', 'integrator:=euler'], 'integrator: unknown integrator'),
                            (['-p', f'scene:={tmp_path}/none.yaml'], 'none.yaml: cannot read')):
        done = subprocess.run([str(executable('sim_node')), '--ros-args', *params],
                              env=ros_env(random_domain()), capture_output=True, text=True,
                              timeout=60)
        assert done.returncode == 2, done.stderr
        assert message in done.stderr
        assert 'Traceback' not in done.stderr


def _set_parameter(ros, node, name, value):
    return ros.client.set_parameter(NODE, name, value, node=node)


def test_the_shipped_params_file_configures_the_node(ros, tmp_path):
    text = (CONFIG / 'sim_node_params.yaml').read_text()
    text = text.replace("scene: ''", f"scene: '{_scene(tmp_path, FREE_BODY)}'")
    text = text.replace('physics_rate: 1000.0', 'physics_rate: 400.0')
    text = text.replace('start_paused: false', 'start_paused: true')
    params = tmp_path / 'params.yaml'
    params.write_text(text)
    node = ros.start({}, namespace='/robot', ros_args=('--params-file', str(params)))
    reply = _step(ros, node, 4, ns=f'/robot{NODE}')
    # bound: 4 steps of 2.5 ms are 10,000,000 ns exactly; ns / 1e9 rounds by 1 ulp (2e-18)
    assert time_seconds(reply.time) == pytest.approx(0.01, abs=1e-12)


def test_run_time_parameters_are_checked_and_the_node_runs_on(ros, tmp_path):
    node = ros.start({'scene': _scene(tmp_path, FREE_BODY), 'start_paused': True})
    result = _set_parameter(ros, node, 'physics_rate', -1.0)
    assert not result.successful and 'physics_rate: must be in' in result.reason
    result = _set_parameter(ros, node, 'integrator', 'euler')
    assert not result.successful and 'integrator: unknown integrator' in result.reason
    result = _set_parameter(ros, node, 'scene', 'other.yaml')
    assert not result.successful
    result = _set_parameter(ros, node, 'physics_rate', 500.0)
    assert result.successful, result.reason
    reply = _step(ros, node, 10)
    # bound: 10 steps of 2 ms are 20,000,000 ns exactly; ns / 1e9 rounds by 1 ulp
    assert time_seconds(reply.time) == pytest.approx(10 / 500.0, abs=1e-12)


def test_bad_inputs_are_rejected_and_leave_the_state_unchanged(ros, tmp_path):
    scene = _scene(tmp_path, FALLING_BOB)
    node = ros.start({'scene': scene, 'start_paused': True})
    states = ros.client.subscribe(BodyStates, f'{NODE}/body_states')
    pub = ros.client.node.create_publisher(WrenchStamped, f'{NODE}/bodies/bob/wrench', 10)
    ros.client.wait_for(lambda: pub.get_subscription_count() > 0, 'the wrench subscriber',
                        node=node)
    for msg in (_wrench('world', force=(math.nan, 0.0, 0.0)),
                _wrench('world', torque=(0.0, math.inf, 0.0)),
                _wrench('world', force=(1e30, 0.0, 0.0)),
                _wrench('bob', torque=(0.0, 0.0, -1e30)),
                _wrench('', force=(1.0, 0.0, 0.0)),
                _wrench('base_link', force=(1.0, 0.0, 0.0))):
        pub.publish(msg)
    bad_requests = [
        AddConstraint.Request(name='a', type='ball', body_a='nobody', body_b='world',
                              anchor_world=[0.0, 0.0, 0.0]),
        AddConstraint.Request(name='b', type='ball', body_a='bob', body_b='world',
                              anchor_world=[0.0, 0.0]),
        AddConstraint.Request(name='c', type='hinge', body_a='bob', body_b='world',
                              anchor_world=[0.0, 0.0, 0.0]),
        AddConstraint.Request(name='d', type='spring', body_a='bob', body_b='world'),
        AddConstraint.Request(name='e', type='generic', body_a='bob', body_b='world'),
        AddConstraint.Request(name='bad name', type='ball', body_a='bob', body_b='world'),
        AddConstraint.Request(name='f', type='distance', body_a='bob', body_b='world',
                              length=-1.0),
    ]
    messages = ['body_a: unknown body', 'anchor_world: expected [] or 3 values',
                'axis_world: required', 'unknown constraint type', 'generic constraint',
                'cannot be part of a ROS name', 'length: must be 0']
    for request, message in zip(bad_requests, messages):
        reply = ros.client.call(AddConstraint, f'{NODE}/add_constraint', request, node=node)
        assert not reply.success and message in reply.message, reply.message
    # Pinning the bob's origin to the world origin holds; then also to (1, 0, 0) cannot.
    ok = AddConstraint.Request(name='pin', type='ball', body_a='bob', body_b='world',
                               anchor_a_body=[0.0, 0.0, 0.0], anchor_b_body=[0.5, 0.0, 0.0])
    assert ros.client.call(AddConstraint, f'{NODE}/add_constraint', ok, node=node).success
    clash = AddConstraint.Request(name='clash', type='ball', body_a='bob', body_b='world',
                                  anchor_a_body=[0.0, 0.0, 0.0], anchor_b_body=[1.0, 0.0, 0.0])
    reply = ros.client.call(AddConstraint, f'{NODE}/add_constraint', clash, node=node)
    assert not reply.success and 'inconsistent' in reply.message
    reply = ros.client.call(RemoveConstraint, f'{NODE}/remove_constraint',
                            RemoveConstraint.Request(name='nothing'), node=node)
    assert not reply.success and "no constraint 'nothing'" in reply.message
    reply = ros.client.call(RemoveConstraint, f'{NODE}/remove_constraint',
                            RemoveConstraint.Request(name='pin'), node=node)
    assert reply.success and reply.rows_removed == 3
    # The node still steps, and as if none of that had been sent: free fall, bit for bit.
    reply = _step(ros, node, 200)
    got = _state_at(ros, node, states, time_seconds(reply.time))['bob']
    sim = load_scene(scene).simulation
    sim.step(200)
    np.testing.assert_array_equal(got[0], sim.pose('bob')[0])
    np.testing.assert_array_equal(got[2], sim.twist('bob')[0])
    # A flood of valid wrenches, each unlike the one before, as fast as the client can send
    # for 0.6 s while paused, then a zero wrench and a NaN: only the latest valid message,
    # the zero wrench, acts at the next step. (The NaN marks the end: once it is counted,
    # the node has taken every message before it. How fast the client sent is printed, not
    # asserted: it depends on the machine and its load.)
    diags = ros.client.subscribe(DiagnosticArray, '/diagnostics')
    changing = [_wrench(('world', 'bob')[i % 2], force=(i + 1.0, 0.0, 0.0),
                        torque=(0.0, -1e-3 * i, 0.0)) for i in range(1000)]
    sent, seconds = _flood(ros, pub, lambda i: changing[i % 1000])
    print(f'valid flood: {sent} messages in {seconds:.3f} s ({sent / seconds:.0f} Hz)')
    pub.publish(_wrench('world'))
    pub.publish(_wrench('world', force=(math.nan, 0.0, 0.0)))
    ros.client.wait_for(lambda: any(int(_values(d)['rejected_non_finite']) == 3 for d in diags),
                        'the NaN after the flood to be counted', node=node)
    values = next(_values(d) for d in diags if _values(d)['rejected_non_finite'] == '3')
    assert int(values['wrench_messages_superseded']) >= 1
    reply = _step(ros, node, 100)
    got = _state_at(ros, node, states, time_seconds(reply.time))['bob']
    sim.apply_wrench('bob', frame='world', point_body=[0.0, 0.0, 0.0], key='topic:bob')
    sim.step(100)
    _assert_state_equal(got, sim, 'bob')
    # A flood of NaN wrenches for 0.6 s while the node runs: it survives, keeps stepping
    # and publishing (states with later stamps arrive during and after it), counts the
    # rejections, and its state stays the core's. (How fast the client sent, and how many
    # states arrived during it, depend on the machine's load: printed, not asserted.)
    assert ros.client.call(SetBool, f'{NODE}/pause', SetBool.Request(data=False),
                           node=node).success
    t_running = time_seconds(reply.time)
    ros.client.wait_for(lambda: time_seconds(states[-1].header.stamp) > t_running + 0.05,
                        'states while running', node=node)
    t_before = time_seconds(states[-1].header.stamp)
    n_before = len(states)
    flood = _wrench('world', force=(math.nan, 0.0, 0.0))
    sent, seconds = _flood(ros, pub, lambda i: flood)
    during = [time_seconds(m.header.stamp) for m in states[n_before:]]
    print(f'NaN flood: {sent} messages in {seconds:.3f} s ({sent / seconds:.0f} Hz), '
          f'{len(during)} states arrived during it')
    assert during == sorted(during)
    n_after = len(states)
    ros.client.wait_for(lambda: len(states) > n_after + 20 and
                        time_seconds(states[-1].header.stamp) > t_before,
                        'states after the flood, stamped later', node=node)
    # Stepping while running is refused.
    reply = ros.client.call(Step, f'{NODE}/step', Step.Request(steps=1), node=node)
    assert not reply.success and 'pause it first' in reply.message
    assert ros.client.call(SetBool, f'{NODE}/pause', SetBool.Request(data=True),
                           node=node).success
    reply = _step(ros, node, 1)
    steps = reply.step_count
    # bound: stamps are whole ns: 1e-9 s
    assert time_seconds(reply.time) == pytest.approx(steps * 1e-3, abs=1e-9)
    got = _state_at(ros, node, states, time_seconds(reply.time))['bob']
    sim.step(steps - 300)
    _assert_state_equal(got, sim, 'bob')
    # Diagnostics count each cause (a report made after the last step above).
    ros.client.wait_for(lambda: _values(diags[-1])['steps'] == str(steps)
                        and _values(diags[-1])['paused'] == 'true', 'diagnostics when paused',
                        node=node)
    values = _values(diags[-1])
    # (The node keeps the 10 latest messages per topic and, running, takes one per spin
    # every few steps: DDS drops the rest. Reliable delivery with a history of 10 on both
    # sides: at least the flood's last 10 reach the node, whatever the load.)
    assert int(values['rejected_non_finite']) >= 3 + 10
    assert int(values['rejected_too_large']) == 2
    assert int(values['rejected_unknown_frame']) == 2
    assert int(values['rejected_unknown_body']) == 1
    assert int(values['rejected_bad_constraint']) == 6
    assert int(values['rejected_inconsistent_constraint']) == 1
    assert int(values['rejected_unknown_constraint']) == 1
    assert int(values['rejected_not_paused']) == 1


def _flood(ros, pub, make, seconds=0.6, batch=100):
    """
    Publish ``make(i)`` for i = 0, 1, ... as fast as possible for ``seconds`` of wall time.

    The client serves its callbacks between batches (states arrive during the flood).
    Return (messages sent, s taken).
    """
    sent = 0
    t0 = time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        for i in range(sent, sent + batch):
            pub.publish(make(i))
        sent += batch
        ros.client.executor.spin_once(timeout_sec=0.0)
    return sent, time.perf_counter() - t0


def _values(diagnostics):
    """Return the key-values of the node's status in a DiagnosticArray."""
    return {kv.key: kv.value for kv in diagnostics.status[0].values}


def _assert_state_equal(got, sim, name):
    """Assert a body's (position, orientation, velocity, angular velocity) is the core's."""
    for a, b in zip(got, (*sim.pose(name), *sim.twist(name))):
        np.testing.assert_array_equal(a, b)


def test_a_divergence_pauses_reports_an_error_and_reset_recovers(ros, tmp_path):
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
    scene = _scene(tmp_path, FREE_BODY.replace('mass: 2.0', 'mass: 0.001'))
    node = ros.start({'scene': scene, 'start_paused': True, 'max_force': 1.7e308})
    states = ros.client.subscribe(BodyStates, f'{NODE}/body_states')
    diags = ros.client.subscribe(DiagnosticArray, '/diagnostics')
    pub = ros.client.node.create_publisher(WrenchStamped, f'{NODE}/bodies/box/wrench', 10)
    ros.client.wait_for(lambda: pub.get_subscription_count() > 0, 'the wrench subscriber',
                        node=node)
    _step(ros, node, 10)
    before = _state_at(ros, node, states, 0.01)['box']
    pub.publish(_wrench('world', force=(1.6e308, 0.0, 0.0)))   # F/m overflows on 1 g
    for _ in range(200):
        reply = ros.client.call(Step, f'{NODE}/step', Step.Request(steps=1), node=node)
        if not reply.success:
            break
    assert 'non-finite' in reply.message
    t = time_seconds(reply.time)
    last = _state_at(ros, node, states, t)['box']
    assert all(np.all(np.isfinite(a)) for a in last)
    ros.client.wait_for(lambda: any(d.status[0].level == DiagnosticStatus.ERROR
                                    for d in diags), 'an ERROR diagnostic', node=node)
    reply = ros.client.call(SetBool, f'{NODE}/pause', SetBool.Request(data=False), node=node)
    assert not reply.success and 'reset' in reply.message
    assert ros.client.call(Trigger, f'{NODE}/reset', Trigger.Request(), node=node).success
    reply = _step(ros, node, 10)
    again = _state_at(ros, node, states, time_seconds(reply.time))
    for a, b in zip(again['box'], before):
        np.testing.assert_array_equal(a, b)


def test_echo_prints_a_body_state_as_it_arrives(ros, tmp_path):
    import subprocess
    from ros_harness import ros_env
    node = ros.start({'scene': _scene(tmp_path, FREE_BODY)}, namespace='/robot')
    env = ros_env(int(node.env['ROS_DOMAIN_ID']))
    done = subprocess.run([str(executable('echo_body')), 'box', '--node', f'/robot{NODE}',
                           '--count', '3', '--every', '1'], env=env, capture_output=True,
                          text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    lines = [line for line in done.stdout.splitlines() if ' box ' in line]
    assert len(lines) == 3
    # The body starts at rest at (0, 0, 1) and no effect acts on it.
    assert 'p=[+0.0000 +0.0000 +1.0000] m' in lines[0]
    assert 'v=[+0.000 +0.000 +0.000] m/s' in lines[-1]


def test_metrics_and_markers_match_the_core(ros, tmp_path):
    from rigid_body_sim.ros.outputs import equal_inertia_box
    from rigid_body_sim_interfaces.msg import Metrics
    from visualization_msgs.msg import Marker, MarkerArray
    scene = str(CONFIG / 'thrown_bodies.yaml')
    node = ros.start({'scene': scene, 'start_paused': True})
    metrics = ros.client.subscribe(Metrics, f'{NODE}/metrics')
    markers = ros.client.subscribe(MarkerArray, f'{NODE}/markers')
    ros.client.wait_for(lambda: metrics and markers, 'metrics and markers (paused)', node=node)
    reply = _step(ros, node, 300)
    t = time_seconds(reply.time)
    ros.client.wait_for(lambda: any(time_seconds(m.header.stamp) == t for m in metrics)
                        and any(time_seconds(m.markers[1].header.stamp) == t
                                for m in markers), 'metrics and markers at t', node=node)
    got = next(m for m in metrics if time_seconds(m.header.stamp) == t)
    sim = load_scene(scene).simulation
    e0 = sim.diagnostics().total_energy
    sim.step(300)
    d = sim.diagnostics()
    assert got.step_count == 300
    # bound: the same state and arithmetic as the core's (bit for bit), carried in a
    # float64 field: rel 1e-15 and abs 1e-12 J are room, not error
    assert got.total_energy == pytest.approx(d.total_energy, rel=1e-15)
    assert got.energy_change == pytest.approx(d.total_energy - e0, abs=1e-12)
    # bound: one addition of |K|, |V| < 1e3 J: 2 eps relative; 1e-12
    assert got.kinetic_energy + got.potential_energy == pytest.approx(got.total_energy,
                                                                      rel=1e-12)
    np.testing.assert_array_equal([got.linear_momentum.x, got.linear_momentum.y,
                                   got.linear_momentum.z], d.linear_momentum_world)
    array = next(m for m in markers if time_seconds(m.markers[1].header.stamp) == t).markers
    assert array[0].action == Marker.DELETEALL
    box, ball = array[1], array[2]
    # The box from its scene shape, about its centre of mass, in its own axes.
    assert (box.type, box.text) == (Marker.CUBE, 'tumbling_box')
    # bound: the scene's sides, copied: exact (rtol 1e-15 is room)
    np.testing.assert_allclose([box.scale.x, box.scale.y, box.scale.z], [0.3, 0.2, 0.1],
                               rtol=1e-15)
    np.testing.assert_allclose([box.pose.position.x, box.pose.position.y,
                                box.pose.position.z], sim.state.pos_com_world[0], rtol=1e-15)
    # (bound for both: the core's state of the same steps, converted once: <= 1 ulp)
    q = sim.pose('tumbling_box')[1]
    np.testing.assert_allclose([box.pose.orientation.x, box.pose.orientation.y,
                                box.pose.orientation.z, box.pose.orientation.w], q, rtol=1e-15)
    # The rugby ball (URDF inertia) as the box of equal inertia.
    np.testing.assert_allclose([ball.scale.x, ball.scale.y, ball.scale.z],
                               equal_inertia_box(0.43, sim.bodies.moments[1]), rtol=1e-12)
    # (bound: a square root of sums of the moments, ~5 roundings: 1e-15; 1e-12 is room)


SHAPES = """
name: shapes
integrator: lie_poisson2
dt: 0.001
effects:
  gravity: {g_world: [0.0, 0.0, -9.81]}
bodies:
  - name: can
    mass: 0.5
    inertia: {cylinder: [0.03, 0.2]}
    position_world: [0.0, 0.1, 1.0]
    orientation_rpy: [0.3, 0.0, 0.0]
  - name: ball
    mass: 0.2
    inertia: {sphere: 0.04}
    position_world: [0.0, 0.25, 0.8]
constraints:
  - {name: hook, type: ball, body_a: can, anchor_world: [0.0, 0.0, 1.1]}
  - {name: link, type: ball, body_a: ball, body_b: can, anchor_world: [0.0, 0.15, 0.9]}
"""


def test_markers_draw_cylinders_spheres_and_each_joint_at_its_anchor(ros, tmp_path):
    from visualization_msgs.msg import Marker, MarkerArray
    scene = _scene(tmp_path, SHAPES)
    node = ros.start({'scene': scene, 'start_paused': True})
    markers = ros.client.subscribe(MarkerArray, f'{NODE}/markers')
    ros.client.wait_for(lambda: markers, 'markers (paused)', node=node)
    reply = _step(ros, node, 300)
    t = time_seconds(reply.time)
    ros.client.wait_for(lambda: any(time_seconds(m.markers[1].header.stamp) == t
                                    for m in markers), 'markers at t', node=node)
    array = next(m for m in markers if time_seconds(m.markers[1].header.stamp) == t).markers
    sim = load_scene(scene).simulation
    sim.step(300)
    assert array[0].action == Marker.DELETEALL
    bodies = {m.text: m for m in array if m.ns == 'bodies'}
    joints = {m.text: m for m in array if m.ns == 'joints'}
    assert len(bodies) + len(joints) + 1 == len(array)

    def position(m):
        return [m.pose.position.x, m.pose.position.y, m.pose.position.z]

    def orientation(m):
        o = m.pose.orientation
        return [o.x, o.y, o.z, o.w]
    # The can: a cylinder 2 r wide and as long as the scene says, along its body z axis;
    # the ball: a sphere of its diameter. Each at its centre of mass (the body origin here),
    # in its own axes, where the core puts it after the same 300 steps.
    can, ball = bodies['can'], bodies['ball']
    assert can.type == Marker.CYLINDER
    assert [can.scale.x, can.scale.y, can.scale.z] == [0.06, 0.06, 0.2]
    assert ball.type == Marker.SPHERE
    assert [ball.scale.x, ball.scale.y, ball.scale.z] == [0.08] * 3
    for marker, name in ((can, 'can'), (ball, 'ball')):
        np.testing.assert_array_equal(position(marker), sim.pose(name)[0])
        np.testing.assert_array_equal(orientation(marker), sim.pose(name)[1])
    # The joints: small spheres at their anchors; the hook's stays at its world point, the
    # link's is the point of the can (as of the start) it joins, wherever the can swung.
    assert set(joints) == {'hook', 'link'}
    for joint in joints.values():
        assert joint.type == Marker.SPHERE
        assert [joint.scale.x, joint.scale.y, joint.scale.z] == [0.04] * 3
    # bound: the joints hold to SHAKE's 1e-13 m a step, decaying at tau: < 5e-12 m after
    # 300 steps; 1e-9 m leaves room (a marker at the wrong point is off by > 1e-2 m)
    np.testing.assert_allclose(position(joints['hook']), [0.0, 0.0, 1.1], rtol=0, atol=1e-9)
    R0 = so3.quat_to_matrix(load_scene(scene).simulation.pose('can')[1])
    on_can = R0.T @ (np.array([0.0, 0.15, 0.9]) - [0.0, 0.1, 1.0])
    pos, quat = sim.pose('can')
    link = pos + so3.quat_to_matrix(quat) @ on_can
    np.testing.assert_allclose(position(joints['link']), link, rtol=0, atol=1e-9)
    # (The pendulum swung: the link is 0.19 m from where it started.)
    assert np.linalg.norm(link - [0.0, 0.15, 0.9]) > 0.1


def test_the_box_of_equal_inertia_has_that_inertia():
    from rigid_body_sim.ros.outputs import equal_inertia_box
    m, sides = 3.0, np.array([0.5, 0.2, 0.1])
    a, b, c = sides
    moments = m / 12 * np.array([b * b + c * c, a * a + c * c, a * a + b * b])
    # bound: a few roundings and a square root: 1e-15 relative; 1e-12 is room
    np.testing.assert_allclose(equal_inertia_box(m, moments), sides, rtol=1e-12)


def test_the_tolerance_parameter_turns_the_accuracy_knob_and_diagnostics_report_it(
        ros, tmp_path):
    # A pendulum through the node: rkmk4 at dt = 1e-2 with tolerance 1e-7 takes several
    # sub-steps a step and meets it; the bob ends where the core, run directly with the
    # same tolerance, puts it (bit for bit).
    from diagnostic_msgs.msg import DiagnosticArray
    scene = _scene(tmp_path, FALLING_BOB.replace('lie_poisson2', 'rkmk4')
                   .replace('dt: 0.001', 'dt: 0.01')
                   + 'constraints:\n  - {name: pivot, type: ball, body_a: bob, '
                     'anchor_world: [0.0, 0.0, 0.0]}\n')
    node = ros.start({'scene': scene, 'start_paused': True, 'physics_rate': 100.0,
                      'tolerance': 1e-7})
    states = ros.client.subscribe(BodyStates, f'{NODE}/body_states')
    diags = ros.client.subscribe(DiagnosticArray, '/diagnostics')
    reply = _step(ros, node, 20)
    t = time_seconds(reply.time)
    bodies = _state_at(ros, node, states, t)
    sim = load_scene(scene).simulation
    sim.set_tolerance(1e-7)
    sim.step(20)
    np.testing.assert_array_equal(bodies['bob'][0], sim.pose('bob')[0])

    def after_the_steps(d):
        # Diagnostics from before the steps (the node starts paused) have no estimate yet
        # (NaN); under load the first one after them may come later than the reply.
        v = {kv.key: kv.value for kv in d.status[0].values}
        return v.get('tolerance') == '1e-07' and v.get('error_estimate') != 'nan'

    def reported():
        return any(after_the_steps(d) for d in diags)
    ros.client.wait_for(reported, 'diagnostics with the tolerance after the steps', node=node)
    values = next({kv.key: kv.value for kv in d.status[0].values} for d in reversed(diags)
                  if after_the_steps(d))
    assert float(values['error_estimate']) <= 1e-7   # (the knob's contract, exactly)
    assert int(values['tolerance_substeps']) >= 4
    assert values['tolerance_misses_total'] == '0'
    # Off again at run time: 0 is the scene's (none).
    assert _set_parameter(ros, node, 'tolerance', 0.0).successful
    ros.client.wait_for(lambda: any({kv.key: kv.value for kv in d.status[0].values}
                                    .get('tolerance') == 'off' for d in diags),
                        'diagnostics with the knob off', node=node)


BALL_ON_GROUND = """
name: ball_on_ground
integrator: rkmk4
dt: 0.001
effects: {gravity: {}}
ground: {friction: 0.5}
bodies:
  - {name: ball, mass: 1.5, inertia: {sphere: 0.1}, position_world: [0.0, 0.0, 0.3],
     shapes: [{kind: sphere, radius: 0.1}]}
"""


def test_contacts_markers_and_diagnostics_report_the_cores_contacts(ros, tmp_path):
    # A ball dropped 0.2 m, at rest on the ground after 1 s: ~/contacts carries the
    # core's contact (bit for bit: the same steps), its weight as the normal force;
    # ~/markers draws the point and the force; diagnostics count the impacts.
    from diagnostic_msgs.msg import DiagnosticArray
    from rigid_body_sim_interfaces.msg import Contacts
    from visualization_msgs.msg import MarkerArray
    scene = _scene(tmp_path, BALL_ON_GROUND)
    node = ros.start({'scene': scene, 'start_paused': True})
    contacts = ros.client.subscribe(Contacts, f'{NODE}/contacts')
    markers = ros.client.subscribe(MarkerArray, f'{NODE}/markers')
    diags = ros.client.subscribe(DiagnosticArray, '/diagnostics')
    reply = _step(ros, node, 1000)
    t = time_seconds(reply.time)
    ros.client.wait_for(lambda: any(time_seconds(m.header.stamp) == t for m in contacts)
                        and any(time_seconds(m.markers[0].header.stamp) == t
                                for m in markers), 'contacts and markers at t', node=node)
    got = next(m for m in contacts if time_seconds(m.header.stamp) == t)
    sim = load_scene(scene).simulation
    sim.step(1000)
    rep = sim.contacts()
    assert (got.shape_a, got.shape_b, got.body_a, got.body_b) == (
        ['ball/sphere'], ['ground'], ['ball'], ['world'])
    np.testing.assert_array_equal(got.normal_force, rep['normal_force'])
    np.testing.assert_array_equal(got.depth, rep['depth'])
    np.testing.assert_array_equal([got.point[0].x, got.point[0].y, got.point[0].z],
                                  rep['point'][0])
    # At rest: the ground carries m g (to rounding of the held force).
    assert got.normal_force[0] == pytest.approx(1.5 * 9.81, rel=1e-12)
    array = next(m for m in markers if time_seconds(m.markers[0].header.stamp) == t).markers
    points = [m for m in array if m.ns == 'contacts']
    assert len(points) == 2 and len(points[0].points) == 1 and len(points[1].points) == 2
    # The force's line: 1 cm per N, up from the point.
    assert points[1].points[1].z - points[1].points[0].z == pytest.approx(
        0.01 * 1.5 * 9.81, rel=1e-12)
    ros.client.wait_for(lambda: any(_values(d).get('contacts') == '1' for d in diags),
                        'diagnostics with the contact', node=node)
    values = next(_values(d) for d in reversed(diags) if _values(d).get('contacts') == '1')
    assert int(values['contact_impacts_total']) >= 1
    assert values['contact_lcp_failures_total'] == '0'
    # One contact's three rows are independent: the fixed point solves them alone.
    assert int(values['contact_lcp_solves_total']) >= 1
    assert values['contact_lcp_newton_total'] == values['contact_lcp_pivoted_total'] == '0'
    # (An island of one contact: far below the size solved by its blocks alone.)
    assert values['contact_lcp_sparse_total'] == values['contact_lcp_pgs_total'] == '0'
    # A ball resting on the ground: its steps at rest are the compiled kernel's.
    assert int(values['contact_compiled_steps_total']) >= 1
    assert float(values['contact_depth_left_max_m']) == 0.0
    # Every step ends at most the location tolerance (1e-10 m) deep.
    assert 0.0 <= float(values['contact_depth_end_max_m']) <= 1e-10


CUBE_URDF = """<robot name="cube">
  <link name="cube"><inertial><mass value="1"/>
      <inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial>
    <collision><origin xyz="0.1 0 0" rpy="0 0 0.5"/>
      <geometry><box size="0.1 0.2 0.3"/></geometry></collision></link>
</robot>
"""

SHAPES_SCENE = """
name: shapes
integrator: rkmk4
dt: 0.001
effects: {gravity: {}}
ground: {height: -1.0}
bodies:
  - {name: ball, mass: 1.0, inertia: {sphere: 0.1}, position_world: [0.0, 0.0, 0.3],
     shapes: [{kind: sphere, radius: 0.1}]}
  - {name: wedge, mass: 1.0, inertia: [0.01, 0.01, 0.01], position_world: [-1.0, 0.0, 0.3],
     shapes: [{kind: mesh, mesh: [[0, 0, 0], [0.2, 0, 0], [0, 0.2, 0], [0, 0, 0.2],
                                   [0.05, 0.05, 0.05]]}]}
  - {name: rod, mass: 1.0, inertia: {box: [0.1, 0.1, 0.5]}, position_world: [1.0, 0.0, 0.3],
     orientation_xyzw: [0.0, 0.7071067811865476, 0.0, 0.7071067811865476],
     shapes: [{kind: capsule, radius: 0.05, length: 0.4}]}
robots:
  - {urdf: cube.urdf, base_pose: {xyz: [2.0, 0.0, 0.5], rpy: [0, 0, 0]}, collisions: true}
"""


@pytest.mark.parametrize('on', [True, False])
def test_collision_markers_draw_every_collision_shape_on_request(ros, tmp_path, on):
    # collision_markers: ~/markers draws the scene's collision shapes where the core has
    # them: a sphere, a capsule (its cylinder and two end spheres), a mesh's hull (a
    # tetrahedron: four triangles; its inner vertex is not the hull's), a URDF
    # <collision> box posed by its link, the ground as a slab whose top is the plane.
    # Off (the default): none.
    from visualization_msgs.msg import Marker, MarkerArray
    (tmp_path / 'cube.urdf').write_text(CUBE_URDF)
    scene = _scene(tmp_path, SHAPES_SCENE)
    node = ros.start({'scene': scene, 'start_paused': True, 'collision_markers': on})
    markers = ros.client.subscribe(MarkerArray, f'{NODE}/markers')
    reply = _step(ros, node, 100)
    t = time_seconds(reply.time)
    ros.client.wait_for(lambda: any(time_seconds(m.markers[0].header.stamp) == t
                                    for m in markers), 'markers at t', node=node)
    array = next(m for m in markers if time_seconds(m.markers[0].header.stamp) == t).markers
    drawn = {m.id: m for m in array if m.ns == 'collisions'}
    if not on:
        assert drawn == {}
        return
    sim = load_scene(scene).simulation
    sim.step(100)
    det = sim.contact.detector
    sim.bodies.outputs(sim.state)
    centre, R = det.frames(sim.bodies.outputs_cache.out)
    names = [det.shapes[s].name for s in det.live]
    m = len(names)
    rod = names.index('rod/capsule')
    assert sorted(drawn) == list(range(m)) + [m + 2 * rod, m + 2 * rod + 1]
    for k, name in enumerate(names):
        got = drawn[k]
        p = [got.pose.position.x, got.pose.position.y, got.pose.position.z]
        shape = det.shapes[det.live[k]]
        if shape.kind == 'plane':
            assert got.type == Marker.CUBE and got.scale.z == 0.001
            np.testing.assert_allclose(p, centre[k] - [0, 0, 0.0005], rtol=0, atol=1e-15)
            assert centre[k][2] == -1.0
            continue
        np.testing.assert_array_equal(p, centre[k])
        q = [got.pose.orientation.x, got.pose.orientation.y, got.pose.orientation.z,
             got.pose.orientation.w]
        np.testing.assert_allclose(so3.quat_to_matrix(np.array(q)), R[k], rtol=0, atol=1e-12)
        assert got.text == name
        if name == 'cube/collision0':   # the URDF box, sides as written, posed by its link
            assert got.type == Marker.CUBE
            assert [got.scale.x, got.scale.y, got.scale.z] == [0.1, 0.2, 0.3]
        elif name == 'wedge/mesh':
            assert got.type == Marker.TRIANGLE_LIST and len(got.points) == 12
            # (about the hull's own centre, (0.1, 0.1, 0.1) in the body, where centre[k] is)
            corners = {(p.x, p.y, p.z) for p in got.points}
            assert corners == {(-0.1, -0.1, -0.1), (0.1, -0.1, -0.1), (-0.1, 0.1, -0.1),
                               (-0.1, -0.1, 0.1)}
        elif name == 'rod/capsule':
            assert got.type == Marker.CYLINDER and got.scale.z == 0.4
            ends = [drawn[m + 2 * k + e] for e in (0, 1)]
            for end, sign in zip(ends, (1.0, -1.0)):
                assert end.type == Marker.SPHERE and end.scale.x == 0.1
                np.testing.assert_allclose(
                    [end.pose.position.x, end.pose.position.y, end.pose.position.z],
                    centre[k] + sign * 0.2 * R[k][:, 2], rtol=0, atol=1e-15)
        else:
            assert got.type == Marker.SPHERE and got.scale.x == 0.2
