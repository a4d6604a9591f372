"""
The live recorder (``record``) through real DDS: the node and the recorder in their own processes.

Each bag is read back twice, independently: with ``rosbags`` (as rosbag2 does)
and with the ``mcap`` package's ROS 2 decoder (as Foxglove does). What it holds
is checked against the recorder's own summary and against Newton: a body
falling from rest, integrated by lie_poisson2, is at ``z = -g t^2 / 2`` at
every stamp.
"""

from collections import Counter
from pathlib import Path
import re
import signal
import subprocess
import threading
import time

from geometry_msgs.msg import WrenchStamped
import numpy as np
import pytest
from rigid_body_sim.ros.bag import typestore
from rigid_body_sim.ros.plot import main as plot_main, read_bag
from rigid_body_sim.ros.record import Recorder as LiveRecorder, Topic
from rigid_body_sim_interfaces.msg import BodyStates
from rigid_body_sim_interfaces.srv import AddConstraint
from ros_harness import DEADLINE, executable, random_domain, ros_env
from simulation_interfaces.msg import Result
from simulation_interfaces.srv import DeleteEntity, SpawnEntity

NODE = '/rigid_body_sim'
G = 9.81
DT = 1e-3
EPS = 2.220446049250313e-16

FALLING_BOB = """
name: falling_bob
integrator: lie_poisson2
dt: 0.001
effects:
  gravity: {g_world: [0.0, 0.0, -9.81]}
bodies:
  - {name: bob, mass: 1.0, inertia: [1.0e-6, 1.0e-6, 1.0e-6], position_world: [0.5, 0.0, 0.0]}
"""

#: A row of the recorder's summary: messages, dropped (or ?), topic.
ROW = re.compile(r'^\s+(\d+)\s+(\d+|\?)\s+(/\S+)$')
TOTAL = re.compile(r'^\s+(\d+)\s+(\d+)\s+total$')


class Recorder:
    """``record`` in a child process on the node's domain; its output collected line by line."""

    def __init__(self, node, out: Path, *args: str) -> None:
        self.out = out
        self.lines: list = []
        self.errors: list = []
        env = ros_env(int(node.env['ROS_DOMAIN_ID']))
        self.proc = subprocess.Popen([str(executable('record')), '-o', str(out), *args],
                                     env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                     text=True, start_new_session=True)
        self._readers = [threading.Thread(target=self._read, args=(stream, into), daemon=True)
                         for stream, into in ((self.proc.stdout, self.lines),
                                              (self.proc.stderr, self.errors))]
        for reader in self._readers:
            reader.start()

    @staticmethod
    def _read(stream, into: list) -> None:
        for line in stream:
            into.append(line.rstrip('\n'))

    def output(self) -> str:
        """Return what the recorder printed so far (stdout, then stderr)."""
        return '\n'.join(self.lines + ['-- stderr:'] + self.errors)

    def said(self, line: str) -> bool:
        """Tell whether the recorder printed ``line``; fail if it exited meanwhile."""
        if line in self.lines:
            return True
        if self.proc.poll() is not None:
            pytest.fail(f'the recorder exited ({self.proc.returncode}) before printing '
                        f'{line!r}:\n{self.output()}')
        return False

    def stop(self, sig: int) -> int:
        """Send ``sig``, wait for the exit and the last of its output; return the exit code."""
        self.proc.send_signal(sig)
        return self.wait()

    def wait(self) -> int:
        """Wait for the exit (kill after the deadline) and its output; return the exit code."""
        try:
            self.proc.wait(DEADLINE)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
            pytest.fail(f'the recorder did not exit within {DEADLINE} s:\n{self.output()}')
        for reader in self._readers:
            reader.join(DEADLINE)
        return self.proc.returncode

    def summary(self) -> dict:
        """Return the summary's rows: topic -> (messages, dropped or None)."""
        rows = {}
        for line in self.lines:
            m = ROW.match(line)
            if m:
                rows[m.group(3)] = (int(m.group(1)), None if m.group(2) == '?'
                                    else int(m.group(2)))
        return rows

    def kill(self) -> None:
        """Kill the process if it still runs."""
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()


@pytest.fixture
def recorders():
    """Return a function starting a :class:`Recorder`; kill leftovers afterwards."""
    started = []

    def start(node, out, *args):
        started.append(Recorder(node, out, *args))
        return started[-1]
    yield start
    for rec in started:
        rec.kill()


def _scene(tmp_path, text=FALLING_BOB):
    path = tmp_path / 'scene.yaml'
    path.write_text(text)
    return str(path)


def _wait_said(ros, node, rec, lines, what):
    ros.client.wait_for(lambda: all(rec.said(line) for line in lines), what, node=node)


def _read_rosbags(out: Path) -> dict:
    """Read a bag with rosbags: topic -> (msgtype, [(bag time ns, message)])."""
    from rosbags.rosbag2 import Reader
    store = typestore()
    topics: dict = {}
    with Reader(out) as reader:
        for connection in reader.connections:
            topics.setdefault(connection.topic, (connection.msgtype, []))
        for connection, stamp, raw in reader.messages():
            topics[connection.topic][1].append(
                (stamp, store.deserialize_cdr(raw, connection.msgtype)))
    return topics


def _read_mcap(out: Path) -> dict:
    """Read a bag's MCAP file with the mcap package: topic -> [(log time ns, message)]."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    files = list(out.glob('*.mcap'))
    assert len(files) == 1, files
    topics: dict = {}
    factory, decoders = DecoderFactory(), {}
    with open(files[0], 'rb') as f:
        for schema, channel, message in make_reader(f).iter_messages():
            # (mcap_ros2 refuses service event type names, S_Event: those are counted)
            if schema.id not in decoders:
                decoders[schema.id] = None if schema.name.endswith('_Event') else \
                    factory.decoder_for(channel.message_encoding, schema)
            decode = decoders[schema.id]
            topics.setdefault(channel.topic, []).append(
                (message.log_time, decode(message.data) if decode else None))
    return topics


def _fall_tolerances(t: float) -> tuple:
    """
    Return the rounding bounds (m, m/s) on z and v_z of the bob falling from rest for t s.

    Kick-drift-kick integrates constant gravity exactly; its rounding does not. With
    every rounding one way over N = t / dt steps, v_z is off by at most N eps |v|
    (two half kicks a step, u = eps / 2 each) and z by N eps |z| / 2 plus that velocity
    error carried over t: eps g t^2 / dt and eps g t^3 / dt; x4 for the products' own
    rounding. (At t = 1 s: 9e-12 m, far below a first-order error, g dt t / 2 = 5e-3 m.)
    The node has run for as long as the test waited, so the bound grows with t.
    """
    return 4 * EPS * G * t ** 3 / DT + 1e-15, 4 * EPS * G * t ** 2 / DT + 1e-15


def _ns(stamp) -> int:
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def _step_time(stamp) -> float:
    """Return the simulation time of a stamp as the node's step count times dt."""
    ns = _ns(stamp)
    k = round(ns / (DT * 1e9))
    # bound: ns stamps of base + k dt: 0.5 ns quantization + eps t (< 1e-5 ns for t < 1 h)
    assert abs(ns - k * DT * 1e9) <= 1, f'stamp {ns} ns is not on the step grid'
    return k * DT


def _counts_agree(summary: dict, rosbags_topics: dict, mcap_topics: dict) -> None:
    """Check that the summary, rosbags and mcap count the same messages per topic."""
    written = {topic: n for topic, (n, _) in summary.items() if n}
    assert {t: len(m) for t, (_, m) in rosbags_topics.items() if m} == written
    assert {t: len(m) for t, m in mcap_topics.items()} == written
    # Every topic the summary lists is declared in the bag, even one without messages.
    assert set(summary) == set(rosbags_topics)


@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM], ids=['SIGINT', 'SIGTERM'])
def test_records_a_running_node_and_the_bag_reads_back(ros, tmp_path, recorders, sig):
    node = ros.start({'scene': _scene(tmp_path)})
    out = tmp_path / 'bag'
    wall_start = time.time_ns()
    rec = recorders(node, out)
    topics = [f'{NODE}/body_states', '/clock', f'{NODE}/bodies/bob/pose',
              f'{NODE}/bodies/bob/twist']
    _wait_said(ros, node, rec, [f'recording {t} [{typ}]' for t, typ in zip(topics, (
        'rigid_body_sim_interfaces/msg/BodyStates', 'rosgraph_msgs/msg/Clock',
        'geometry_msgs/msg/PoseStamped', 'geometry_msgs/msg/TwistStamped'))],
        'the recorder to subscribe')
    _wait_said(ros, node, rec, [f'first message on {t}' for t in topics],
               "the recorder's first messages")
    # The node runs on; cut the recording while it does, after 50 more states.
    states = ros.client.subscribe(BodyStates, f'{NODE}/body_states')
    ros.client.wait_for(lambda: len(states) >= 50, '50 body states', node=node)
    assert rec.stop(sig) == 0, rec.output()
    wall_end = time.time_ns()
    assert 'Traceback' not in rec.output()
    assert node.proc.poll() is None
    summary = rec.summary()
    assert rec.lines[-1] == f'bag: {out}'
    assert (out / 'metadata.yaml').is_file()
    for topic in topics:
        assert summary[topic][0] > 0, rec.output()
    total = next(TOTAL.match(line) for line in rec.lines if TOTAL.match(line))
    assert int(total.group(1)) == sum(n for n, _ in summary.values())
    assert int(total.group(2)) == sum(d for _, d in summary.values() if d)
    # One publisher per topic of the node: drops are counted (checked below).
    assert all(summary[t][1] is not None for t in topics)

    got = _read_rosbags(out)
    from_mcap = _read_mcap(out)
    _counts_agree(summary, got, from_mcap)
    assert got[f'{NODE}/body_states'][0] == 'rigid_body_sim_interfaces/msg/BodyStates'
    # Bag time: when each message arrived (wall clock), within the recorder's run.
    for _, messages in got.values():
        assert all(wall_start <= stamp <= wall_end for stamp, _ in messages)

    # Body states: simulation time strictly increases; the bob falls from rest exactly.
    last = -1.0
    for _, msg in got[f'{NODE}/body_states'][1]:
        t = _step_time(msg.header.stamp)
        assert t > last
        last = t
        assert list(msg.names) == ['bob']
        # Exact on any IEEE machine: x + dt 0 is x (v_x = v_y = g_x = g_y = 0, exact zeros).
        assert msg.position[0] == 0.5 and msg.position[1] == 0.0
        z_tol, v_tol = _fall_tolerances(t)   # bound: see _fall_tolerances (9e-12 at 1 s)
        assert abs(msg.position[2] - (-G * t * t / 2)) <= z_tol, (t, z_tol)
        assert abs(msg.linear_velocity[2] - (-G * t)) <= v_tol, (t, v_tol)
    for _, msg in got[f'{NODE}/bodies/bob/pose'][1]:
        t = _step_time(msg.header.stamp)
        p, q = msg.pose.position, msg.pose.orientation
        # Exact as above; a rotation by an exact zero angle is exactly the identity.
        assert (p.x, p.y) == (0.5, 0.0) and (q.x, q.y, q.z, q.w) == (0.0, 0.0, 0.0, 1.0)
        assert abs(p.z - (-G * t * t / 2)) <= _fall_tolerances(t)[0]   # bound: as above
    for _, msg in got[f'{NODE}/bodies/bob/twist'][1]:
        t = _step_time(msg.header.stamp)
        assert abs(msg.twist.linear.z - (-G * t)) <= _fall_tolerances(t)[1]   # bound: as above
    # The clock ticks in whole steps; the mcap reader decodes the same values.
    clock = [_step_time(msg.clock) for _, msg in got['/clock'][1]]
    assert all(b > a for a, b in zip(clock, clock[1:]))
    assert [(s, m.pose.position.z) for s, m in got[f'{NODE}/bodies/bob/pose'][1]] == \
        [(s, m.pose.position.z) for s, m in from_mcap[f'{NODE}/bodies/bob/pose']]
    # Drops are whole messages missing between consecutive stamps (pose: 100 Hz).
    poses = [round(_step_time(m.header.stamp) / 0.01) for _, m in
             got[f'{NODE}/bodies/bob/pose'][1]]
    assert sum(b - a - 1 for a, b in zip(poses, poses[1:])) == \
        summary[f'{NODE}/bodies/bob/pose'][1]


def test_the_drops_are_the_gaps_in_the_publishers_sequence_numbers():
    # What a stalled recorder missed, counted from the sequence numbers the middleware
    # gives each message (the live test below cannot force a drop: how much a stall's
    # buffers take in is the machine's). Gaps count; a smaller number is a new publisher
    # (the node restarted), counted from there; a middleware giving no numbers (0 or
    # None) leaves the drops unknown, never 0, as do several publishers.
    topic = Topic('/clock', 'rosgraph_msgs/msg/Clock', None)
    for sequence in (1, 2, 3, 7, 8, 12, 2, 3, 5):
        LiveRecorder._count_gap(None, topic, sequence)
    assert topic.drops() == 3 + 3 + 1
    for missing in (None, 0):
        unnumbered = Topic('/clock', 'rosgraph_msgs/msg/Clock', None)
        LiveRecorder._count_gap(None, unnumbered, 4)
        LiveRecorder._count_gap(None, unnumbered, missing)
        assert unnumbered.drops() is None
    shared = Topic('/clock', 'rosgraph_msgs/msg/Clock', None, single_publisher=False)
    LiveRecorder._count_gap(None, shared, 1)
    LiveRecorder._count_gap(None, shared, 9)
    assert shared.drops() is None


def test_a_stalled_recorder_counts_the_messages_it_missed(ros, tmp_path, recorders):
    node = ros.start({'scene': _scene(tmp_path)})
    rec = recorders(node, tmp_path / 'bag')
    topics = {'/clock': DT, f'{NODE}/body_states': 0.01, f'{NODE}/bodies/bob/pose': 0.01}
    _wait_said(ros, node, rec, [f'first message on {t}' for t in topics], 'the recording')
    # Frozen (DDS's threads too) while the node publishes 20 s of clock: the node's
    # queues (10 deep) overflow, and those messages never reach the bag, unless the
    # recorder's socket and shared-memory buffers take them in meanwhile (1.5 s of /clock
    # fitted there once, 2.5 s of all three topics on an AMD EPYC, 8 s once in a full
    # suite run, all 20 s once under a generic-CPU build). So whatever was missed must be
    # counted exactly; the count itself is tested on given sequence numbers (above).
    from rosgraph_msgs.msg import Clock
    clock = ros.client.subscribe(Clock, '/clock')
    ros.client.wait_for(lambda: clock, 'the clock', node=node)
    rec.proc.send_signal(signal.SIGSTOP)
    try:
        ros.client.wait_for(lambda: len(clock) > 20000, '20000 clock ticks', timeout=120.0,
                            node=node)
    finally:
        rec.proc.send_signal(signal.SIGCONT)
    n = len(clock)
    ros.client.wait_for(lambda: len(clock) > n + 200, '200 more ticks', node=node)
    assert rec.stop(signal.SIGINT) == 0, rec.output()
    summary = rec.summary()
    got = _read_rosbags(rec.out)
    for topic, period in topics.items():
        messages = got[topic][1]
        stamps = [m.clock if topic == '/clock' else m.header.stamp for _, m in messages]
        ticks = [round(_step_time(s) / period) for s in stamps]
        missing = sum(b - a - 1 for a, b in zip(ticks, ticks[1:]))
        # /clock goes out every step, its gaps the drops. The states' stamps may also skip
        # periods the node never sent (measured once: 2,012 periods missing from the
        # bag's stamps, 2,000 from the publisher's sequence numbers, the recorder's count),
        # so their gaps are the drops and at most those skips more.
        assert summary[topic][0] == len(messages), (topic, rec.output())
        if topic == '/clock':
            assert summary[topic][1] == missing, (topic, rec.output())
        else:
            assert summary[topic][1] <= missing, (topic, rec.output())
    # The closing line: every topic's drops, and those not counted ('?': several publishers).
    dropped = sum(row[1] for row in summary.values() if row[1])
    unknown = any(row[1] is None for row in summary.values())
    said = rf'^dropped: {dropped} messages' if dropped or unknown else r'^dropped: none$'
    assert re.search(said, '\n'.join(rec.lines), re.M), rec.output()


def test_a_topic_that_appears_later_is_recorded(ros, tmp_path, recorders):
    node = ros.start({'scene': _scene(tmp_path)})
    out = tmp_path / 'bag'
    rec = recorders(node, out)
    _wait_said(ros, node, rec, [f'first message on {NODE}/body_states'],
               'the recorder to record')
    topic = f'{NODE}/constraints/rod/wrench'
    assert not any(topic in line for line in rec.lines)
    # A rod to the world, as long as the bob's distance from (0, 0, 1) is now.
    request = AddConstraint.Request(name='rod', type='distance', body_a='bob',
                                    body_b='world', anchor_b_body=[0.0, 0.0, 1.0])
    reply = ros.client.call(AddConstraint, f'{NODE}/add_constraint', request, node=node)
    assert reply.success, reply.message
    _wait_said(ros, node, rec, [f'recording {topic} [geometry_msgs/msg/WrenchStamped]',
                                f'first message on {topic}'], 'the new topic recorded')
    reactions = ros.client.subscribe(WrenchStamped, topic)
    ros.client.wait_for(lambda: len(reactions) >= 10, 'reactions', node=node)
    assert rec.stop(signal.SIGINT) == 0, rec.output()
    summary = rec.summary()
    assert summary[topic][0] > 0
    got = _read_rosbags(out)
    _counts_agree(summary, got, _read_mcap(out))
    msgtype, messages = got[topic]
    assert msgtype == 'geometry_msgs/msg/WrenchStamped'
    # On the bob (its frame) and on the world, equal and opposite, one of each per stamp.
    frames = Counter(msg.header.frame_id for _, msg in messages)
    assert set(frames) == {'bob', 'world'}
    stamps = Counter(_ns(msg.header.stamp) for _, msg in messages)
    # (The ends may be cut; a message the recorder dropped, counted, unpairs one stamp: how
    # many it drops depends on the machine's speed.)
    unpaired = sum(n != 2 for n in stamps.values())
    assert summary[topic][1] is not None   # (one publisher: its drops are counted)
    assert unpaired <= 2 + summary[topic][1], (unpaired, summary[topic])
    # The reactions start after the body states did: the topic was subscribed later.
    first_state = min(s for s, _ in got[f'{NODE}/body_states'][1])
    assert min(s for s, _ in messages) > first_state


def test_named_topics_only_and_a_duration(ros, tmp_path, recorders):
    node = ros.start({'scene': _scene(tmp_path)})
    named = [f'{NODE}/body_states', '/clock']
    rec = recorders(node, tmp_path / 'bag', '--topics', '~/body_states', '/clock')
    _wait_said(ros, node, rec, [f'first message on {t}' for t in named],
               'the named topics recorded')
    assert rec.stop(signal.SIGINT) == 0, rec.output()
    summary = rec.summary()
    assert sorted(summary) == sorted(named), rec.output()
    _counts_agree(summary, _read_rosbags(rec.out), _read_mcap(rec.out))
    # --duration ends the recording by itself, also when a topic never shows up.
    rec = recorders(node, tmp_path / 'empty', '--topics', '/nothing', '--duration', '1')
    assert rec.wait() == 0, rec.output()
    assert 'never appeared in the graph: /nothing' in rec.lines
    assert rec.summary() == {}
    assert _read_rosbags(rec.out) == {} and _read_mcap(rec.out) == {}


def test_bytes_rosbags_refuses_are_written_canonically():
    from rclpy.serialization import serialize_message
    from rigid_body_sim.ros.record import readable_cdr
    from rosbags.serde import SerdeError
    from rosgraph_msgs.msg import Clock
    store = typestore()
    msgtype = 'rigid_body_sim_interfaces/msg/BodyStates'
    # rclpy's own serialization leaves slack at the end with empty float64 arrays.
    raw = serialize_message(BodyStates(names=['bob']))
    with pytest.raises(SerdeError, match='size mismatch'):
        store.deserialize_cdr(raw, msgtype)
    data = readable_cdr(raw, msgtype, BodyStates)
    assert len(data) < len(raw)
    assert list(store.deserialize_cdr(data, msgtype).names) == ['bob']
    # Bytes that read back are kept as they are (as DDS delivers them: the tests above).
    raw = serialize_message(Clock())
    assert readable_cdr(raw, 'rosgraph_msgs/msg/Clock', Clock) is raw


def test_an_existing_bag_folder_is_refused(tmp_path):
    out = tmp_path / 'bag'
    out.mkdir()
    (out / 'keep.txt').write_text('mine')
    done = subprocess.run([str(executable('record')), '-o', str(out)],
                          env=ros_env(random_domain()), capture_output=True, text=True,
                          timeout=60)
    assert done.returncode == 2
    assert f'record: error: {out} exists already; choose a new bag folder' in done.stderr
    assert 'Traceback' not in done.stderr
    assert [p.name for p in out.iterdir()] == ['keep.txt']
    assert (out / 'keep.txt').read_text() == 'mine'


def test_a_bag_across_a_spawn_and_a_delete_plots(ros, tmp_path, recorders):
    # The bob falls from rest; a crate is spawned while recording, falls from rest where
    # it was spawned, and is deleted. The bag holds the crate in body_states only between
    # the two calls (and its pose topic from its spawn on), each state on the closed form
    # of its own fall; plot reads the bob and the crate (NaN outside the crate's life),
    # marks both calls at their simulation times, and draws the PNG.
    node = ros.start({'scene': _scene(tmp_path)})
    out = tmp_path / 'bag'
    rec = recorders(node, out)
    _wait_said(ros, node, rec, [f'first message on {NODE}/body_states'],
               'the recorder to record')
    states = ros.client.subscribe(BodyStates, f'{NODE}/body_states')
    ros.client.wait_for(lambda: len(states) >= 20, '20 body states', node=node)
    # The recorder subscribes to the spawn's event topic once it sees it in the graph, and
    # DDS matches the node's publisher to it some time later; the topic is volatile (as
    # ROS's service events are), so a call before the match is not recorded (CI lost the
    # spawn's event so once). Refused probes (a spawn of a taken name: it changes nothing)
    # go until the recorder has written one; from then on the two ends are matched and
    # reliable delivery brings every event. Each probe waits for that event, not a time.
    probes = 0
    events = '/spawn_entity/_service_event'
    while not rec.said(f'first message on {events}'):
        assert probes < 30, f'no event of {probes} probes recorded:\n{rec.output()}'
        probe = ros.client.call(SpawnEntity, '/spawn_entity', SpawnEntity.Request(
            name='bob', resource_string='{mass: 2.0, inertia: {box: [0.2, 0.2, 0.2]}}'), node=node)
        assert probe.result.result == SpawnEntity.Response.NAME_NOT_UNIQUE
        probes += 1
        end = time.monotonic() + 1.0
        while not rec.said(f'first message on {events}') and time.monotonic() < end:
            ros.client.executor.spin_once(timeout_sec=0.05)
    request = SpawnEntity.Request(name='crate', resource_string=(
        '{mass: 2.0, inertia: {box: [0.2, 0.2, 0.2]}}'))
    request.initial_pose.pose.position.x = 3.0
    request.initial_pose.pose.position.z = 10.0
    reply = ros.client.call(SpawnEntity, '/spawn_entity', request, node=node)
    assert reply.result.result == Result.RESULT_OK, reply.result.error_message
    topic = f'{NODE}/bodies/crate/pose'
    _wait_said(ros, node, rec, [f'first message on {topic}'], "the crate's pose recorded")
    ros.client.wait_for(lambda: sum('crate' in m.names for m in states) >= 20,
                        '20 states with the crate', node=node)
    deleted = ros.client.call(DeleteEntity, '/delete_entity',
                              DeleteEntity.Request(entity='crate'), node=node)
    assert deleted.result.result == Result.RESULT_OK, deleted.result.error_message
    ros.client.wait_for(lambda: 'crate' not in states[-1].names and len(
        [m for m in states if 'crate' in m.names]) < len(states) - 20,
        'states after the delete', node=node)
    n = len(states)
    ros.client.wait_for(lambda: len(states) >= n + 20, '20 more states', node=node)
    assert rec.stop(signal.SIGINT) == 0, rec.output()
    got = _read_rosbags(out)
    with_crate = [msg for _, msg in got[f'{NODE}/body_states'][1] if 'crate' in msg.names]
    assert with_crate and all(list(m.names) == ['bob', 'crate'] for m in with_crate)
    t_spawn = None
    for msg in with_crate:
        t = _step_time(msg.header.stamp)
        z, v = msg.position[5], msg.linear_velocity[5]
        # Falling from rest at (3, 0, 10) since its spawn, t_s: v = -g (t - t_s), and
        # z = 10 - v^2 / 2g; t_s from the first state, the others on it.
        t_s = t + v / G
        t_spawn = t_s if t_spawn is None else t_spawn
        assert abs(t_s - t_spawn) <= 1e-9 and msg.position[3] == 3.0
        assert abs(10.0 - z - v * v / (2 * G)) <= _fall_tolerances(t - t_spawn)[0] + 1e-12
    series = read_bag(out)
    assert series.all_bodies == ['bob', 'crate'] and series.bodies == ['bob', 'crate']
    alive = np.isfinite(series.position['crate'][:, 2])
    assert alive.sum() == len(with_crate) and not alive[0] and not alive[-1]
    # One contiguous stretch: NaN, then the crate, then NaN again.
    assert np.count_nonzero(np.diff(alive.astype(int))) == 2
    marks = [(e.service, e.name, e.success) for e in series.events]
    # (the probes from the first the recorder got: those before the match never reach it)
    refused = len(marks) - 2
    assert 1 <= refused <= probes
    assert marks == [('spawn_entity', 'bob', False)] * refused + [
        ('spawn_entity', 'crate', True), ('delete_entity', 'crate', True)]
    spawned, removed = (e.t for e in series.events[refused:])
    assert spawned < removed
    # The crate's first state is stamped at its spawn (the node publishes one then).
    assert series.t[alive][0] == pytest.approx(t_spawn, abs=1e-9)
    png = tmp_path / 'bag.png'
    assert plot_main([str(out), '-o', str(png)]) == 0 and png.stat().st_size > 0
