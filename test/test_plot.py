"""
The ``plot`` console script: a bag of known trajectories in, a PNG and those numbers out.

The bag is written with BagWriter as the node's tools write it: a namespaced
node with body states, metrics, reaction wrenches (several per stamp) and
wrench inputs, a second node, ``/clock`` and a topic plot ignores.
"""

import subprocess

from geometry_msgs.msg import WrenchStamped
import numpy as np
import pytest
from rigid_body_sim.core import rotation as so3
from rigid_body_sim.ros import conversions as conv
from rigid_body_sim.ros.bag import BagWriter
from rigid_body_sim.ros.plot import default_output, main, orientation_angle_deg, read_bag
from rigid_body_sim_interfaces.msg import Metrics
from rigid_body_sim_interfaces.srv import AddConstraint, RemoveConstraint
from ros_harness import executable
from rosgraph_msgs.msg import Clock
from scipy.spatial.transform import Rotation
from service_msgs.msg import ServiceEventInfo
from std_msgs.msg import Header
from std_srvs.srv import Trigger

NODE = '/robot1/rigid_body_sim'
OTHER = '/robot2/rigid_body_sim'
G = 9.81
MASS = 2.0
LENGTH = 0.5
N = 101                      # states at 100 Hz of simulation time: 0 to 1 s
STAMPS = [conv.time_msg_ns(i * 10_000_000) for i in range(N)]
#: s: the stamps as plot reads them (whole seconds plus nanoseconds, as time_seconds does).
T = np.array([conv.time_seconds(stamp) for stamp in STAMPS])
#: ns: the bag receives the states at half speed (real-time factor 0.5) from this wall time.
WALL0 = 1_764_000_000_000_000_000
PUSH = (30, 60)              # the wrench input arrives 5 ms of wall time after these states
REMOVE, REFUSED, RESET = 50, 70, 80    # service calls, replied 1 ms (wall) after these states


def _received(k: int) -> int:
    return WALL0 + k * 20_000_000


def _header(ns: int, frame: str) -> Header:
    return Header(stamp=conv.time_msg_ns(ns), frame_id=frame)


def _wrench(ns: int, frame: str, force) -> WrenchStamped:
    return conv.wrench_stamped(_header(ns, frame), np.asarray(force, dtype=float),
                               np.array([0.1, 0.2, 0.3]))


def _call(bag: BagWriter, srv_type, service: str, wall: int, sequence: int, request,
          response) -> None:
    """Write one call's request-received and response-sent events, as the node records them."""
    for event_type, req, resp in ((ServiceEventInfo.REQUEST_RECEIVED, [request], []),
                                  (ServiceEventInfo.RESPONSE_SENT, [], [response])):
        event = srv_type.Event(request=req, response=resp)
        event.info = ServiceEventInfo(event_type=event_type, sequence_number=sequence)
        bag.write_msg(f'{NODE}/{service}/_service_event', wall + 1_000_000, event)


def known_series() -> dict:
    """Return the trajectories written to the bag, body-major like BodyStates."""
    theta = 0.3 * np.sin(2.0 * np.pi * T)            # pendulum swing about +y
    spin = 2.0 * T                                   # ball turning about +z, rad
    ball_pos = np.stack([0.1 * T, 0.0 * T, 1.0 - 0.5 * G * T ** 2], axis=1)
    pend_pos = np.stack([LENGTH * np.sin(theta), 0.0 * T, -LENGTH * np.cos(theta)], axis=1)
    ball_q = np.stack([0.0 * T, 0.0 * T, np.sin(spin / 2), np.cos(spin / 2)], axis=1)
    pend_q = np.stack([0.0 * T, np.sin(theta / 2), 0.0 * T, np.cos(theta / 2)], axis=1)
    velocity = np.stack([0.1 + 0.0 * T, 0.0 * T, -G * T], axis=1)
    kinetic = 0.5 * MASS * np.sum(velocity ** 2, axis=1)
    potential = MASS * G * ball_pos[:, 2]
    total = kinetic + potential
    steps = 10 * np.arange(N)
    steps[RESET:] -= steps[RESET]                   # steps since the last reset
    return {'spin': spin, 'theta': theta, 'steps': steps, 'ball_pos': ball_pos,
            'pend_pos': pend_pos, 'ball_q': ball_q, 'pend_q': pend_q, 'velocity': velocity,
            'kinetic': kinetic, 'potential': potential, 'total': total, 'change': total - total[0],
            'violation': 1e-12 * (1.0 + np.arange(N)),
            'hinge_body': np.stack([T, 2.0 * T, 3.0 + 0.0 * T], axis=1),
            'hinge_world': np.stack([-4.0 * T, 0.0 * T, 10.0 + T], axis=1),
            'tether_ball': np.stack([1.0 + T, 0.0 * T, 0.0 * T], axis=1),
            'tether_pend': np.stack([-5.0 - T, 0.0 * T, 0.0 * T], axis=1)}


def write_bag(path) -> dict:
    """Write the known series as the node publishes them; return them."""
    k = known_series()
    with BagWriter(path) as bag:
        for i in range(N):
            ns = i * 10_000_000
            wall = _received(i)
            bag.write_msg('/clock', wall, Clock(clock=conv.time_msg_ns(ns)))
            states = conv.body_states(
                _header(ns, 'world'), ['ball', 'pendulum'],
                np.stack([k['ball_pos'][i], k['pend_pos'][i]]),
                np.stack([k['ball_q'][i], k['pend_q'][i]]),
                np.stack([k['velocity'][i], np.zeros(3)]), np.zeros((2, 3)))
            bag.write_msg(f'{NODE}/body_states', wall, states)
            bag.write_msg(f'{NODE}/bodies/ball/pose', wall, conv.pose_stamped(
                _header(ns, 'world'), k['ball_pos'][i], k['ball_q'][i]))
            bag.write_msg(f'{NODE}/metrics', wall, Metrics(
                header=_header(ns, 'world'), step_count=int(k['steps'][i]),
                total_energy=k['total'][i], kinetic_energy=k['kinetic'][i],
                potential_energy=k['potential'][i], energy_change=k['change'][i],
                constraint_violation=k['violation'][i]))
            # A constraint to the world: the body's message first, then the world's.
            topic = f'{NODE}/constraints/hinge/wrench'
            bag.write_msg(topic, wall, _wrench(ns, 'pendulum', k['hinge_body'][i]))
            bag.write_msg(topic, wall, _wrench(ns, 'world', k['hinge_world'][i]))
            topic = f'{NODE}/constraints/tether/wrench'
            if i <= REMOVE:
                bag.write_msg(topic, wall, _wrench(ns, 'ball', k['tether_ball'][i]))
                bag.write_msg(topic, wall, _wrench(ns, 'pendulum', k['tether_pend'][i]))
            if i == REMOVE:
                _call(bag, RemoveConstraint, 'remove_constraint', wall, 1,
                      RemoveConstraint.Request(name='tether'),
                      RemoveConstraint.Response(success=True, rows_removed=1))
            if i == REFUSED:
                _call(bag, AddConstraint, 'add_constraint', wall, 2,
                      AddConstraint.Request(name='rope', type='rope'),
                      AddConstraint.Response(success=False, message='type: unknown'))
            if i == RESET:
                _call(bag, Trigger, 'reset', wall, 3, Trigger.Request(),
                      Trigger.Response(success=True))
            if i in PUSH:
                # As `ros2 topic pub` sends it: stamp 0; received 5 ms (wall) after state i.
                force = (0.0, 0.0, 5.0) if i == PUSH[0] else (0.0, 0.0, 0.0)
                msg = conv.wrench_stamped(Header(frame_id='world'), np.array(force),
                                          np.zeros(3))
                bag.write_msg(f'{NODE}/bodies/ball/wrench', wall + 5_000_000, msg)
            if i < 3:
                bag.write_msg(f'{OTHER}/body_states', wall, conv.body_states(
                    _header(ns, 'world'), ['other'], np.array([[float(i), 0.0, 0.0]]),
                    np.array([[0.0, 0.0, 0.0, 1.0]]), np.zeros((1, 3)), np.zeros((1, 3))))
    return k


@pytest.fixture(scope='module')
def bag(tmp_path_factory):
    """Return (bag folder, known series)."""
    path = tmp_path_factory.mktemp('plot') / 'run1'
    return path, write_bag(path)


def _png_size(path) -> tuple:
    data = path.read_bytes()
    assert data[:8] == b'\x89PNG\r\n\x1a\n', f'{path} is not a PNG'
    assert data[12:16] == b'IHDR'
    return int.from_bytes(data[16:20], 'big'), int.from_bytes(data[20:24], 'big')


def test_read_bag_returns_exactly_what_was_written(bag):
    path, k = bag
    s = read_bag(path)
    assert s.node == NODE                           # the first node (alphabetically) ...
    assert s.nodes == [NODE, OTHER]                 # ... of the two with body_states
    assert s.world_frame == 'world'
    assert s.bodies == s.all_bodies == ['ball', 'pendulum']
    assert np.array_equal(s.t, T)
    assert np.array_equal(s.position['ball'], k['ball_pos'])
    assert np.array_equal(s.position['pendulum'], k['pend_pos'])
    assert np.array_equal(s.orientation['ball'], k['ball_q'])
    assert np.array_equal(s.orientation['pendulum'], k['pend_q'])
    m = s.metrics
    assert np.array_equal(m['t'], T)
    assert np.array_equal(m['total_energy'], k['total'])
    assert np.array_equal(m['kinetic_energy'], k['kinetic'])
    assert np.array_equal(m['potential_energy'], k['potential'])
    assert np.array_equal(m['energy_change'], k['change'])
    assert np.array_equal(m['constraint_violation'], k['violation'])
    assert np.array_equal(m['step_count'], k['steps'])
    # The reset takes effect at the state whose step count drops; the calls are marked when
    # the bag received their replies (1 ms of wall time after a state: 0.5 ms simulated).
    assert np.array_equal(s.resets, [T[RESET]])
    assert [(e.service, e.name, e.success) for e in s.events] == [
        ('remove_constraint', 'tether', True), ('add_constraint', 'rope', False),
        ('reset', '', True)]
    # bound: np.interp over exact integer ns offsets, ~4 roundings of <= 1 s: 1e-15 s; x1000
    assert [e.t for e in s.events] == pytest.approx(
        [T[i] + 0.0005 for i in (REMOVE, REFUSED, RESET)], abs=1e-12)
    assert s.events[1].message == 'type: unknown'
    # The falling body's energy is the known one: m g z0 + m vx^2 / 2 at every stamp.
    # bound: ~6 roundings (u = 1.1e-16) of terms up to 96 J in known_series: 7e-14 J; x15
    assert np.allclose(m['total_energy'], MASS * G * 1.0 + 0.5 * MASS * 0.1 ** 2, rtol=0,
                       atol=1e-12)
    # One reaction sample per stamp: the world-frame message for a constraint to the world,
    # else the first body's.
    hinge, tether = s.reactions['hinge'], s.reactions['tether']
    assert sorted(s.reactions) == ['hinge', 'tether']
    assert np.array_equal(hinge.t, T) and np.array_equal(tether.t, T[:REMOVE + 1])
    assert hinge.frames == ['world'] * N and tether.frames == ['ball'] * (REMOVE + 1)
    assert np.array_equal(hinge.force, k['hinge_world'])
    assert np.array_equal(tether.force, k['tether_ball'][:REMOVE + 1])
    assert np.array_equal(hinge.magnitude, np.linalg.norm(k['hinge_world'], axis=1))
    # Inputs: at the simulation time the bag received them (stamps 0 are not used).
    push = s.inputs['ball']
    assert list(s.inputs) == ['ball']
    # bound: as the calls' times above (np.interp of exact ns offsets): 1e-15 s
    assert push.t == pytest.approx([T[i] + 0.0025 for i in PUSH], abs=1e-12)
    assert np.array_equal(push.force, [[0.0, 0.0, 5.0], [0.0, 0.0, 0.0]])
    assert push.frames == ['world', 'world']
    # Orientation panel: both turn about one world axis, so the angle is signed, unwrapped.
    # bound: axis eps / sin(angle / 2) at the first turned sample (>= 0.01 rad): 5e-14; angle
    # ~10 roundings (sin, cos, atan2: numpy's SIMD paths <= 4 ulp) of <= 7 rad: 1e-12 deg; x100
    angle, axis = s.orientation_angle_deg('ball')
    assert np.allclose(axis, [0.0, 0.0, 1.0], rtol=0, atol=1e-12)
    assert np.allclose(angle, np.degrees(k['spin']), rtol=0, atol=1e-10)
    angle, axis = s.orientation_angle_deg('pendulum')
    assert np.allclose(axis, [0.0, 1.0, 0.0], rtol=0, atol=1e-12)
    assert np.allclose(angle, np.degrees(k['theta']), rtol=0, atol=1e-10)


def test_node_and_bodies_select(bag):
    path, _ = bag
    s = read_bag(path, node='robot2/rigid_body_sim/')
    assert s.node == OTHER and s.bodies == ['other'] and np.array_equal(s.t, T[:3])
    assert s.metrics is None and not s.reactions and not s.inputs
    s = read_bag(path, bodies=['pendulum'])
    assert s.bodies == ['pendulum'] and list(s.position) == ['pendulum'] and not s.inputs


def test_orientation_angle():
    # About one axis: signed and unwrapped past 180 degrees, either sign of q.
    turn = np.radians(np.linspace(0.0, 400.0, 81))
    q = np.stack([0 * turn, 0 * turn, np.sin(turn / 2), np.cos(turn / 2)], axis=1)
    q[::3] *= -1.0
    angle, axis = orientation_angle_deg(q)
    # bound: axis eps / sin(angle / 2) at the first turned sample (5 deg): 1e-14; angle ~10
    # roundings (sin, cos, atan2: numpy's SIMD paths <= 4 ulp) of <= 7 rad: 1e-12 deg; x100
    assert np.allclose(axis, [0, 0, 1], rtol=0, atol=1e-12)
    assert np.allclose(angle, np.degrees(turn), rtol=0, atol=1e-10)
    # From a tilted start, about a tilted axis: the axis is found in world axes.
    start = so3.exp_quat(np.array([0.3, -0.2, 0.5]))
    tilted = np.array([1.0, 2.0, 2.0]) / 3.0
    q = so3.quat_multiply(so3.exp_quat(turn[:, None] * tilted), start)
    angle, axis = orientation_angle_deg(q)
    # bound: as above, with ~10 more roundings composing q: axis 5e-14, angle 2e-12 deg
    assert np.allclose(axis, tilted, rtol=0, atol=1e-12)
    assert np.allclose(angle, np.degrees(turn), rtol=0, atol=1e-10)
    # Restarted (a reset) where the raw angle is 250 degrees: that episode starts at -110.
    jump = np.radians(np.concatenate([np.linspace(0.0, 300.0, 31), np.linspace(250.0, 400.0, 16)]))
    q = np.stack([0 * jump, 0 * jump, np.sin(jump / 2), np.cos(jump / 2)], axis=1)
    angle, _ = orientation_angle_deg(q, restarts=[31])
    # bound: as above, 1e-12 deg; x100
    assert np.allclose(angle, np.degrees(jump) - np.where(np.arange(47) >= 31, 360.0, 0.0),
                       rtol=0, atol=1e-10)
    # A tumble (the axis moves): the unsigned angle from the first orientation, 0 to 180.
    rotvec = np.stack([turn, 0.5 * np.sin(3 * turn), 0.2 * turn], axis=1)
    q = so3.exp_quat(rotvec)
    angle, axis = orientation_angle_deg(q)
    expected = (Rotation.from_quat(q) * Rotation.from_quat(q[0]).inv()).magnitude()
    # bound: both sides ~10 roundings of <= 3.2 rad (2 atan2(|v|, |w|)): 5e-13 deg; x200
    assert axis is None and np.allclose(angle, np.degrees(expected), rtol=0, atol=1e-10)
    assert np.all((angle >= 0.0) & (angle <= 180.0))
    # Absent samples stay absent.
    q[5] = np.nan
    angle, _ = orientation_angle_deg(q)
    assert np.isnan(angle[5]) and np.isfinite(np.delete(angle, 5)).all()


def test_main_writes_a_png_and_a_summary(bag, tmp_path, capsys):
    path, _ = bag
    out = tmp_path / 'figures' / 'run1.png'
    assert main([str(path), '-o', str(out)]) == 0
    line = capsys.readouterr().out.strip()
    assert '\n' not in line and str(out) in line and NODE in line and OTHER in line
    assert 'reaction forces (hinge, tether)' in line and '2 wrench inputs' in line
    assert '1 reset, 2 constraint calls' in line
    width, height = _png_size(out)
    assert 800 <= width <= 2000 and 1000 <= height <= 3000, (width, height)
    assert out.stat().st_size > 50_000                  # drawn, not blank
    # --node, --bodies (comma-separated too), the default output beside the bag.
    assert main([str(path), '--node', OTHER.strip('/'), '--bodies', 'other']) == 0
    assert default_output(path).is_file() and default_output(path) == path.parent / 'run1.png'
    line = capsys.readouterr().out
    assert f'plot: {default_output(path)}: {OTHER}' in line and 'bodies other;' in line
    assert line.rstrip().endswith('panels: x, orientation')  # y, z still; no metrics


def test_installed_console_script(bag, tmp_path):
    path, _ = bag
    out = tmp_path / 'cli.png'
    done = subprocess.run([str(executable('plot')), str(path), '-o', str(out)],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith(f'plot: {out}: {NODE}') and done.stderr == ''
    assert _png_size(out)[0] > 0


def test_errors_name_the_path_and_exit_2(bag, tmp_path, capsys):
    path, _ = bag
    missing = tmp_path / 'no_such_bag'
    assert main([str(missing)]) == 2
    err = capsys.readouterr().err
    assert f'plot: error: {missing}: no such bag' in err and 'Traceback' not in err
    clock_only = tmp_path / 'clock_only'
    with BagWriter(clock_only) as writer:
        writer.write_msg('/clock', 1, Clock(clock=conv.time_msg_ns(1)))
    assert main([str(clock_only)]) == 2
    err = capsys.readouterr().err
    assert f'plot: error: {clock_only}: no <node>/body_states topic' in err
    assert 'topics: /clock' in err and not (tmp_path / 'clock_only.png').exists()
    assert main([str(path), '--bodies', 'nobody']) == 2
    assert "no body 'nobody'" in capsys.readouterr().err
    assert main([str(path), '--node', '/robot3/rigid_body_sim']) == 2
    assert 'nodes: /robot1/rigid_body_sim, /robot2/rigid_body_sim' in capsys.readouterr().err
    not_a_bag = tmp_path / 'empty_folder'
    not_a_bag.mkdir()
    assert main([str(not_a_bag)]) == 2
    assert f'{not_a_bag}: not a readable rosbag2 bag' in capsys.readouterr().err
