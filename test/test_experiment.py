"""The lockstep experiment runner: its bag, read back two ways, against the core and Newton."""

from pathlib import Path
import re
import subprocess

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
import numpy as np
import pytest
from rigid_body_sim.ros.bag import typestore
from rigid_body_sim.ros.experiment import main
from rigid_body_sim.scene import load_scene
from rosbags.rosbag2 import Reader
from scipy.spatial.transform import Rotation

CONFIG = Path(__file__).resolve().parents[1] / 'config'
SCENE = CONFIG / 'pendulum_kick.yaml'
SCHEDULE = CONFIG / 'pendulum_kick_schedule.yaml'
NODE = '/rigid_body_sim'
G = 9.81


@pytest.fixture(scope='module')
def bag(tmp_path_factory):
    """Run the README's example experiment once; return the bag folder."""
    out = tmp_path_factory.mktemp('run') / 'bag'
    assert main([str(SCENE), '--schedule', str(SCHEDULE), '--bag', str(out)]) == 0
    return out


def _read(bag):
    """Return {topic: [(bag time ns, message)]} read with rosbags."""
    store = typestore()
    out = {}
    with Reader(bag) as reader:
        for connection, t, raw in reader.messages():
            out.setdefault(connection.topic, []).append(
                (t, store.deserialize_cdr(raw, connection.msgtype)))
    return out


def _seconds(stamp):
    return stamp.sec + stamp.nanosec * 1e-9


def test_the_bag_has_the_node_topics_counts_and_monotonic_stamps(bag):
    msgs = _read(bag)
    # 4 s at 1 kHz: /clock every step, the state every 10 ms; each also at the start and
    # right after the reset at 2.5 s.
    assert len(msgs['/clock']) == 4000 + 2
    for topic in ('body_states', 'metrics', 'markers', 'bodies/bob/pose', 'bodies/bob/twist'):
        assert len(msgs[f'{NODE}/{topic}']) == 400 + 2, topic
    # The joint: 2 messages (bob, world) per publish while it exists (0-1.2 s, 2.5-4 s).
    assert len(msgs[f'{NODE}/constraints/pivot/wrench']) == 2 * (121 + 151)
    # Inputs: two pulses, each on and off; the removal and the reset, request and response.
    assert len(msgs[f'{NODE}/bodies/bob/wrench']) == 4
    assert len(msgs[f'{NODE}/remove_constraint/_service_event']) == 2
    assert len(msgs[f'{NODE}/reset/_service_event']) == 2
    for topic, items in msgs.items():
        times = [t for t, _ in items]
        assert times == sorted(times), topic
    states = msgs[f'{NODE}/body_states']
    stamps = [_seconds(m.header.stamp) for _, m in states]
    assert all(b > a for a, b in zip(stamps, stamps[1:])), 'time runs on across the reset'
    assert all(t == int(round(s * 1e9)) for (t, _), s in zip(states, stamps))
    import yaml
    info = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    custom = info['custom_data']
    assert custom['rigid_body_sim.scene'] == SCENE.read_text()
    assert custom['rigid_body_sim.schedule'] == SCHEDULE.read_text()


def test_the_bag_holds_what_the_core_computes(bag):
    msgs = _read(bag)
    states = {round(_seconds(m.header.stamp) * 1000): m for _, m in msgs[f'{NODE}/body_states']}
    sim = load_scene(SCENE).simulation
    got = {}
    e0 = sim.diagnostics().total_energy

    def record(k):
        pos, quat = sim.pose('bob')
        vel, omega = sim.twist('bob')
        got[k] = (pos, quat, vel, omega)
        if k == 1000:   # the rod's pull and the metrics, mid-swing
            got['reaction'] = sim.reactions()['pivot']['bob'].force_world
            got['energy'] = sim.diagnostics().total_energy
    # The schedule, through the core's own API: a held wrench per topic at the body origin.
    for k in range(2500):
        if k == 200:
            sim.apply_wrench('bob', [20.0, 0, 0], point_body=[0, 0, 0], key='topic:bob')
        if k == 300:
            sim.apply_wrench('bob', point_body=[0, 0, 0], key='topic:bob')
        if k == 1200:
            sim.remove_constraint('pivot')
        sim.step()
        if (k + 1) % 10 == 0:
            record(k + 1)
    reaction = got.pop('reaction')
    energy = got.pop('energy')
    for k, (pos, quat, vel, omega) in got.items():
        m = states[k]
        np.testing.assert_array_equal(m.position, pos)
        np.testing.assert_array_equal(m.orientation, quat)
        np.testing.assert_array_equal(m.linear_velocity, vel)
        np.testing.assert_array_equal(m.angular_velocity, omega)
    at_1s = [m for _, m in msgs[f'{NODE}/constraints/pivot/wrench']
             if _seconds(m.header.stamp) == 1.0 and m.header.frame_id == 'bob'][0]
    R = Rotation.from_quat(got[1000][1]).as_matrix()
    # bound: two rotations (node's, scipy's) of a 17.6 N force, ~10 eps each: 4e-14 N; x25
    np.testing.assert_allclose([at_1s.wrench.force.x, at_1s.wrench.force.y,
                                at_1s.wrench.force.z], R.T @ reaction, rtol=1e-12, atol=1e-12)
    metric = [m for _, m in msgs[f'{NODE}/metrics'] if _seconds(m.header.stamp) == 1.0][0]
    assert metric.total_energy == energy and metric.energy_change == energy - e0
    # After the reset (published one step after 2.5 s), the scene starts over; the push in
    # the bob's own y axis from 3.0 s to 3.2 s is 499 and 699 steps after it.
    sim.reset()
    m = states[2501]
    np.testing.assert_array_equal(m.position, sim.pose('bob')[0])
    sim.step(499)
    sim.apply_wrench('bob', [0.0, 10.0, 0.0], frame='body', point_body=[0, 0, 0],
                     key='topic:bob')
    sim.step(200)
    sim.apply_wrench('bob', frame='body', point_body=[0, 0, 0], key='topic:bob')
    sim.step(801)
    m = states[4001]
    np.testing.assert_array_equal(m.position, sim.pose('bob')[0])
    np.testing.assert_array_equal(m.linear_velocity, sim.twist('bob')[0])


def test_the_bob_flies_a_parabola_once_released(bag):
    msgs = _read(bag)
    fly = [m for _, m in msgs[f'{NODE}/body_states'] if 1.2 <= _seconds(m.header.stamp) < 2.5]
    t0 = _seconds(fly[0].header.stamp)
    p0 = np.array(fly[0].position)
    v0 = np.array(fly[0].linear_velocity)
    assert abs(v0[0]) > 0.5, 'the kick set it swinging'
    for m in fly[1:]:
        dt = _seconds(m.header.stamp) - t0
        expected = p0 + v0 * dt + 0.5 * np.array([0.0, 0.0, -G]) * dt * dt
        # bound: worst-case rounding N u (|z| + N dt |v|) = 1300 x 1.1e-16 x (6 + 16) m = 3e-12
        np.testing.assert_allclose(m.position, expected, rtol=0, atol=1e-11)
    # Metrics: energy holds in flight and while swinging; the violation stays at rounding.
    metrics = [m for _, m in msgs[f'{NODE}/metrics']]
    # bound: SHAKE stops within 1e-13 of rho Phi, rho = exp(-dt / tau): 1e-13 / (1 - rho) = 5e-12
    assert max(m.constraint_violation for m in metrics) < 1e-11
    flight = [m.total_energy for m in metrics if 1.3 <= _seconds(m.header.stamp) < 2.5]
    # bound: m (g dz + |v| dv), dz 3e-12 m (above), dv 2 N u |v| = 3.4e-12 m/s: 7e-11 J; x2 ptp
    assert np.ptp(flight) < 1e-9


def test_the_markers_show_the_bob_as_its_sphere_and_the_joint_while_it_exists(bag):
    from visualization_msgs.msg import Marker
    msgs = _read(bag)
    states = {_seconds(m.header.stamp): m for _, m in msgs[f'{NODE}/body_states']}
    kind, (radius,) = load_scene(SCENE).shapes['bob']
    assert (kind, radius) == ('sphere', 0.05)
    pivot = [0.0, 0.0, 1.5]   # the scene's anchor_world of the joint
    with_joint = []
    for _, array in msgs[f'{NODE}/markers']:
        first, *markers = array.markers
        assert first.action == Marker.DELETEALL
        t = _seconds(markers[0].header.stamp)
        state = states[t]
        bodies = [m for m in markers if m.ns == 'bodies']
        joints = [m for m in markers if m.ns == 'joints']
        assert len(bodies) + len(joints) == len(markers)
        # The bob: a sphere of the scene's diameter, where and as the body states say.
        (bob,) = bodies
        assert (bob.type, bob.action, bob.text) == (Marker.SPHERE, Marker.ADD, 'bob')
        assert bob.header.frame_id == 'world'
        assert [bob.scale.x, bob.scale.y, bob.scale.z] == [2 * radius] * 3
        p, q = bob.pose.position, bob.pose.orientation
        np.testing.assert_array_equal([p.x, p.y, p.z], state.position)
        np.testing.assert_array_equal([q.x, q.y, q.z, q.w], state.orientation)
        # The pivot: a 4 cm red sphere at the pivot (the joint holds to rounding), while the
        # joint exists: from the start to its removal at 1.2 s, and again from the reset at
        # 2.5 s (stamped 2.501 s) on.
        if round(t * 1e3) <= 1200 or round(t * 1e3) >= 2501:
            (joint,) = joints
            assert (joint.type, joint.action, joint.text) == (Marker.SPHERE, Marker.ADD,
                                                              'pivot')
            assert [joint.scale.x, joint.scale.y, joint.scale.z] == [0.04] * 3
            assert joint.color.r > 0.8 and joint.color.g < 0.2 and joint.color.b < 0.2
            p = joint.pose.position
            # bound: the joint's violation (<= 5e-12 m, as the metrics') + 4 eps x 1.5 m
            np.testing.assert_allclose([p.x, p.y, p.z], pivot, rtol=0, atol=1e-11)
            with_joint.append(t)
        else:
            assert joints == [], t
    assert len(with_joint) == 121 + 151
    # (The bob swings and flies: the markers follow it, far from where it hung.)
    far = max(np.linalg.norm(np.array(m.position) - [0.0, 0.0, 1.0]) for m in states.values())
    assert far > 0.5


def test_the_mcap_reader_reads_the_same_bag(bag):
    msgs = _read(bag)
    counts = {}
    decoded = 0
    with open(next(bag.glob('*.mcap')), 'rb') as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for schema, channel, message in reader.iter_messages():
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
            if channel.topic == f'{NODE}/body_states':
                # (mcap's own ROS 2 decoder, from the definitions stored in the file)
                ros = DecoderFactory().decoder_for(channel.message_encoding, schema)(
                    message.data)
                ours = msgs[channel.topic][decoded][1]
                assert list(ros.position) == list(ours.position)
                assert ros.header.stamp.nanosec == ours.header.stamp.nanosec
                decoded += 1
    assert counts == {topic: len(items) for topic, items in msgs.items()}
    assert decoded == 402


def test_same_inputs_give_the_same_bag_bit_for_bit(tmp_path, bag):
    again = tmp_path / 'bag'   # (the folder's name is written inside the bag)
    assert main([str(SCENE), '--schedule', str(SCHEDULE), '--bag', str(again)]) == 0
    for name in ('bag.mcap', 'metadata.yaml'):
        assert (again / name).read_bytes() == (bag / name).read_bytes(), name


@pytest.mark.parametrize('text, message', [
    ('events: [{at: 0.1, wrench: {body: nobody, force: [1, 0, 0]}}]',
     r"events\[0\]\.wrench\.body: unknown body 'nobody'"),
    ('events: [{at: 0.1, wrench: {body: bob, force: [1, 0]}}]',
     r'events\[0\]\.wrench\.force: expected shape \(3,\)'),
    ('events: [{at: 0.1, wrench: {body: bob, force: [.nan, 0, 0]}}]',
     r'events\[0\]\.wrench\.force: must be finite'),
    ('events: [{at: 0.1, wrench: {body: bob, force: [1, 0, 0], frame: base}}]',
     r"events\[0\]\.wrench\.frame: 'base' is neither the world frame"),
    ('events: [{at: -1, reset: true}]', r'events\[0\]\.at: must be >= 0'),
    ('events: [{reset: true}]', r'events\[0\]\.at: missing'),
    ('events: [{at: 1, jump: true}]', r'events\[0\]\.jump: unknown key'),
    ('events: [{at: 1, reset: true, remove_constraint: pivot}]',
     r'events\[0\]: expected at and exactly one of'),
    ('events: [{at: 1, remove_constraint: pivot}, {at: 2, remove_constraint: pivot}]',
     r"events\[1\]\.remove_constraint: no constraint 'pivot' at t = 2 s"),
    ('events: [{at: 1, add_constraint: {name: h, type: hinge, body_a: bob}}]',
     r'events\[0\]\.add_constraint: axis_world: required'),
    ('events: [{at: 1, add_constraint: {name: pivot, type: ball, body_a: bob}}]',
     r"events\[0\]\.add_constraint: a constraint 'pivot' exists already"),
    ('duration: 0\nevents: []', r'duration: must be positive'),
    ('event: []', r'event: unknown key'),
    # The last step starts at 0.999 s: an input at 1 s would never be applied.
    ('duration: 1.0\nevents: [{at: 1.0, reset: true}]',
     r"events: the reset at t = 1 s comes after the run's last step"),
])
def test_a_bad_schedule_is_refused_before_anything_runs(tmp_path, capsys, text, message):
    schedule = tmp_path / 'bad_schedule.yaml'
    schedule.write_text(text + '\n')
    out = tmp_path / 'bag'
    assert main([str(SCENE), '--schedule', str(schedule), '--bag', str(out)]) == 2
    err = capsys.readouterr().err
    assert not out.exists()
    assert re.search(r'bad_schedule\.yaml: ' + message, err), err


def test_each_reset_moves_the_last_step_one_dt_later(tmp_path, capsys):
    # A reset stamps the initial state one step after the last (time runs on): after a
    # reset at 0.5 s the 1000 steps of a 1 s run end with one starting at 1.000 s, so an
    # input at 1.0 s is applied (and written), one at 1.002 s is refused.
    schedule = tmp_path / 'schedule.yaml'
    text = ('duration: 1.0\nevents: [{at: 0.5, reset: true}, '
            '{at: AT, wrench: {body: bob, force: [1.0, 0.0, 0.0]}}]\n')
    schedule.write_text(text.replace('AT', '1.0'))
    assert main([str(SCENE), '--schedule', str(schedule), '--bag', str(tmp_path / 'a')]) == 0
    with Reader(tmp_path / 'a') as reader:
        stamps = [t for c, t, _ in reader.messages() if c.topic.endswith('/bob/wrench')]
    assert stamps == [1_000_000_000]
    schedule.write_text(text.replace('AT', '1.002'))
    assert main([str(SCENE), '--schedule', str(schedule), '--bag', str(tmp_path / 'b')]) == 2
    assert "the wrench at t = 1.002 s comes after the run's last step" in capsys.readouterr().err


def test_the_readme_command_runs_through_the_console_script(tmp_path):
    from ros_harness import executable
    done = subprocess.run([str(executable('experiment')), str(SCENE), '--schedule',
                           str(SCHEDULE), '--bag', str(tmp_path / 'bag'), '--duration', '0.5'],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert 'done: 500 steps' in done.stdout
    # The run cut short leaves out the schedule's later inputs, and says so.
    assert 'ends the run before 3 scheduled input(s) (the first: remove_constraint' \
        in done.stderr
    assert (tmp_path / 'bag' / 'metadata.yaml').is_file()


def test_a_pulse_ending_when_the_next_begins_does_not_cancel_it(tmp_path):
    # 0.2 + 0.1 is 0.30000000000000004: the release must not land after the new push.
    schedule = tmp_path / 'pulses.yaml'
    schedule.write_text('events:\n'
                        '  - {at: 0.2, wrench: {body: bob, force: [20, 0, 0], duration: 0.1}}\n'
                        '  - {at: 0.3, wrench: {body: bob, force: [0, 20, 0]}}\n')
    out = tmp_path / 'bag'
    assert main([str(SCENE), '--schedule', str(schedule), '--bag', str(out),
                 '--duration', '0.5']) == 0
    last = _read(out)[f'{NODE}/body_states'][-1][1]
    assert abs(last.linear_velocity[1]) > 0.5, 'the push at 0.3 s acted'


def test_a_removal_after_a_refused_add_is_recorded_not_fatal(tmp_path):
    # Pinning the bob to a second point 1 m away cannot hold with the pivot: refused at run
    # time (it depends on the state); removing it later is refused too, and the run goes on.
    schedule = tmp_path / 'refused.yaml'
    schedule.write_text('events:\n'
                        '  - {at: 0.1, add_constraint: {name: pin, type: ball, body_a: bob,\n'
                        '                               anchor_b_body: [3.0, 0.0, 1.0]}}\n'
                        '  - {at: 0.2, remove_constraint: pin}\n')
    out = tmp_path / 'bag'
    assert main([str(SCENE), '--schedule', str(schedule), '--bag', str(out),
                 '--duration', '0.3']) == 0
    events = [m for _, m in _read(out)[f'{NODE}/remove_constraint/_service_event']]
    assert not events[1].response[0].success


def test_the_runner_writes_what_a_live_node_publishes(ros, tmp_path):
    # The same scene and inputs (through the services, which reply once applied) into a
    # live node, paused and stepped, and into the runner: the same messages, bit for bit.
    from geometry_msgs.msg import WrenchStamped
    from rigid_body_sim.ros.conversions import time_seconds
    from rigid_body_sim_interfaces.msg import BodyStates, Metrics
    from rigid_body_sim_interfaces.srv import RemoveConstraint, Step
    from std_srvs.srv import Trigger
    schedule = tmp_path / 'calls.yaml'
    schedule.write_text('events:\n  - {at: 0.5, remove_constraint: pivot}\n'
                        '  - {at: 0.8, reset: true}\n')
    out = tmp_path / 'bag'
    assert main([str(SCENE), '--schedule', str(schedule), '--bag', str(out),
                 '--duration', '1.0']) == 0
    bag = _read(out)
    node = ros.start({'scene': str(SCENE), 'start_paused': True})
    client = ros.client
    live = {name: client.subscribe(msg_type, f'{NODE}/{name}') for name, msg_type in (
        ('body_states', BodyStates), ('metrics', Metrics),
        ('constraints/pivot/wrench', WrenchStamped))}
    client.wait_for(lambda: live['metrics'] and live['constraints/pivot/wrench'],
                    'the paused node', node=node)

    def step(n):
        assert client.call(Step, f'{NODE}/step', Step.Request(steps=n), node=node).success
    step(500)
    assert client.call(RemoveConstraint, f'{NODE}/remove_constraint',
                       RemoveConstraint.Request(name='pivot'), node=node).success
    step(300)
    assert client.call(Trigger, f'{NODE}/reset', Trigger.Request(), node=node).success
    step(200)
    end = _seconds(bag[f'{NODE}/body_states'][-1][1].header.stamp)
    client.wait_for(lambda: any(time_seconds(m.header.stamp) == end
                                for m in live['body_states']), 'the last state', node=node)
    for name, msgs in live.items():
        written = {}
        for _, m in bag[f'{NODE}/{name}']:
            written.setdefault((time_seconds(m.header.stamp), m.header.frame_id), m)
        compared = 0
        for m in msgs:
            key = (time_seconds(m.header.stamp), m.header.frame_id)
            assert _same(m, written[key]), (name, key)
            compared += 1
        # How many of a step call's burst arrive depends on the machine's speed (the node's
        # publishers keep 10): not asserted. The waits above make it at least one per topic.
        assert compared >= 1, name


def _same(live, written) -> bool:
    """Compare an rclpy message with the bag's (rosbags) one, field by field, exactly."""
    if hasattr(live, 'get_fields_and_field_types'):
        return all(_same(getattr(live, f), getattr(written, f))
                   for f in live.get_fields_and_field_types())
    if isinstance(live, (list, tuple)) and live and hasattr(live[0], 'get_fields_and_field_types'):
        return len(live) == len(written) and all(map(_same, live, written))
    if isinstance(live, str) or np.ndim(live) == 0:
        return live == written
    return np.array_equal(np.asarray(live), np.asarray(written))


def test_a_robot_run_bags_joint_states_tf_and_its_commands(tmp_path):
    # node_arm under gravity, j1 an exact drive, j2 commanded by effort at 0.1 s.
    urdf = Path(__file__).resolve().parent / 'urdf' / 'node_arm.urdf'
    scene = tmp_path / 'arm.yaml'
    scene.write_text(f'dt: 0.001\neffects: {{gravity: {{}}}}\n'
                     f'robots: [{{urdf: {urdf}, prefix: left_}}]\n'
                     f'command_groups: [{{name: hold, joints: [left_j1], interface: position, '
                     f'mode: exact}}]\n')
    schedule = tmp_path / 'schedule.yaml'
    schedule.write_text('duration: 0.3\nevents:\n'
                        '  - {at: 0.1, joints: {left_j2: 0.25, left_j1: 0.2}}\n')
    out = tmp_path / 'bag'
    assert main([str(scene), '--schedule', str(schedule), '--bag', str(out)]) == 0
    msgs = _read(out)
    states = msgs['/joint_states']
    assert len(states) == len(msgs['/tf']) == 30 + 1
    assert len(msgs['/tf_static']) == len(msgs['/robot_description']) == 1
    assert '<joint name="left_j1"' in msgs['/robot_description'][0][1].data
    [(t, command)] = msgs[f'{NODE}/joint_commands']
    assert t == 100_000_000 and list(command.name) == ['left_j2', 'left_j1']
    assert np.isnan(command.position[0]) and command.position[1] == 0.2
    assert command.effort[0] == 0.25 and np.isnan(command.effort[1])
    assert not len(command.velocity)
    sim = load_scene(scene).simulation
    first = states[0][1]
    assert list(first.name) == sim.joint_names() == ['left_j1', 'left_j2']
    np.testing.assert_array_equal(first.position, sim.joint_state().positions)
    sim.step(100)
    sim.command_joints({'left_j2': 0.25, 'left_j1': 0.2})
    sim.step(200)
    last = states[-1][1]
    # The same core calls in the same order: the same numbers, bit for bit.
    js = sim.joint_state()
    np.testing.assert_array_equal(last.position, js.positions)
    np.testing.assert_array_equal(last.effort, js.efforts)
    frames = {tf.child_frame_id for _, m in msgs['/tf'] for tf in m.transforms}
    assert frames == {'left_l1', 'left_l2'}
