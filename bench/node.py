"""
Node benchmark: the ROS 2 node as a user runs it, through DDS, in a child process.

1. Scenes of 1, 10, 100 and 1000 free bodies (anisotropic boxes under gravity)
   and 10- and 100-link chains of rods on ball joints (as
   ``rigid_body_sim.core.mechanisms.chain``: rods 0.1 m, 0.1 kg along +x, hanging
   from the world at the origin, released horizontal) are written as scene YAML
   files; ``sim_node`` runs each one (physics_rate 1000, publish_rate 100,
   real_time_factor 1) on a fresh random ``ROS_DOMAIN_ID`` with localhost-only
   discovery, for a fixed wall time once it is up, while this process subscribes
   to ``~/body_states`` (the node publishes only topics that have subscribers),
   ``/diagnostics`` and the twist of the body it pushes (2.). The node's own
   ``/diagnostics`` windows (1 s each; the windows that end in the first second of
   the measurement, and the node's first window, are dropped) give the achieved
   physics rate, real-time factor, step and publish costs, overruns and lag
   resets, and adaptive substeps; ``/proc`` gives the CPU use of the node, of this
   process and of everything else (a benchmark on a shared machine shows it).
2. Wrench-to-twist latency, wall clock: every 50 ms on average (at random phases
   of the node's publish period) this process publishes a WrenchStamped (world
   frame) on ``~/bodies/<B>/wrench`` whose force flips between +F and -F (F = 50 x
   the weight of the first free body, along x; 10 x the weight of the last link of
   a chain, along y, out of the swing plane; the first pulse lasts half as long so
   that the velocity oscillates about zero), and times each flip from the publish
   to the receipt of the first ``~/bodies/<B>/twist`` whose velocity change since
   the previous twist has the new sign.
3. 1000 free bodies again with ``per_body_topics:=false`` (``~/body_states``
   only: rates and costs, no latency).
4. In this process, without a node: the cost to build and publish one snapshot of
   n bodies as (a) one BodyStates (flat float64[] arrays,
   ``rigid_body_sim.ros.conversions.body_states``), (b) a nested layout, one
   geometry_msgs/PoseArray plus one trajectory_msgs/MultiDOFJointTrajectoryPoint
   whose ``velocities`` (geometry_msgs/Twist[]) hold the twists (common_interfaces
   has no TwistArray; this is a real Twist[] field, other fields left empty), and
   (c) one PoseStamped and one TwistStamped per body (2n publishes on 2n
   publishers, as the node does).

5. Where the time of a node with per-body topics goes besides steps and
   publishes: one ``SingleThreadedExecutor.spin_once(timeout_sec=0)`` (the node's
   loop calls it between steps) in this process, on a node with the node's
   per-body entities (2 publishers and 1 subscription per body), with rclpy's
   default QoS event handlers (each one a waitable the executor gathers in Python
   on every call) and without them (``use_default_callbacks=False``).

Writes ``bench/out/node.md`` and, with matplotlib, ``bench/out/node.png``.
Run: ``python bench/node.py [--quick]`` in the environment of ``./dev.sh``
(``./dev.sh bench`` runs it last). ``--profile SCENE`` runs the node under
cProfile instead and writes the top entries to ``bench/out/node_profile_SCENE.txt``.
"""

from __future__ import annotations

import argparse
import datetime
from importlib import metadata
import os
from pathlib import Path
import platform
import random
import signal
import subprocess
import sys
import tempfile
import time
from typing import Callable, Optional

from ament_index_python.packages import get_package_prefix
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import (Point, Pose, PoseArray, PoseStamped, Quaternion, Twist,
                               TwistStamped, Vector3, WrenchStamped)
import numpy as np
import rclpy
from rclpy.event_handler import PublisherEventCallbacks, SubscriptionEventCallbacks
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile
from rigid_body_sim.core.mechanisms import rod, ROD_LENGTH, ROD_MASS
from rigid_body_sim.ros import conversions as conv
from rigid_body_sim_interfaces.msg import BodyStates
from std_msgs.msg import Header
from trajectory_msgs.msg import MultiDOFJointTrajectoryPoint
import yaml

OUT = Path(__file__).resolve().parent / 'out'
NODE = '/rigid_body_sim'
G = 9.81
#: Node parameters of every run.
PARAMS = {'physics_rate': 1000.0, 'publish_rate': 100.0, 'real_time_factor': 1.0}
#: s: how long a node may take to come up (load the scene, create its topics, be discovered).
STARTUP_DEADLINE = 120.0
#: s between wrench flips (on average).
FLIP_PERIOD = 0.05
#: The flip force in weights of the body pushed: a free box, the last link of a chain (50
#: whips that link around so fast that the integrator takes adaptive substeps, which cost
#: 2-3x a step; 10 still dwarfs what the swing of the chain does to that link's y velocity).
FREE_WEIGHTS, CHAIN_WEIGHTS = 50.0, 10.0
#: Fewer timed flips than this: latency percentiles in parentheses (table), not plotted.
MIN_FLIPS = 20
#: Free boxes: kg, side lengths in m.
BOX_MASS, BOX_SIDES = 1.0, (0.3, 0.2, 0.1)


# -- scenes ------------------------------------------------------------------------------

def free_scene(n: int) -> dict:
    """Return a scene of n anisotropic boxes on a 1 m grid under gravity, tumbling (seeded)."""
    rng = np.random.default_rng(0)
    bodies = []
    for i in range(n):
        bodies.append({
            'name': f'b{i}', 'mass': BOX_MASS, 'inertia': {'box': list(BOX_SIDES)},
            'position_world': [float(i % 10), float(i // 10 % 10), float(i // 100)],
            'angular_velocity_body': [round(float(w), 6) for w in rng.normal(size=3)]})
    return {'name': f'free_{n}', 'integrator': 'lie_poisson2', 'dt': 1e-3,
            'effects': {'gravity': {'g_world': [0.0, 0.0, -G]}}, 'bodies': bodies}


def chain_scene(n: int) -> dict:
    """Return the scene of ``mechanisms.chain(n, 'lie_poisson2')`` (rods along +x, ball joints)."""
    bodies, joints = [], []
    for i in range(n):
        start = np.array([i * ROD_LENGTH, 0.0, 0.0])
        r = rod(f'l{i}', start, np.array([1.0, 0.0, 0.0]))
        bodies.append({'name': r.name, 'mass': float(r.mass),
                       'inertia': [float(x) for x in np.diag(r.inertia)],
                       'position_world': [float(x) for x in r.position_world],
                       'orientation_xyzw': [float(x) for x in r.orientation_xyzw]})
        joints.append({'name': f'j{i}', 'type': 'ball', 'body_a': f'l{i}',
                       'body_b': 'world' if i == 0 else f'l{i - 1}',
                       'anchor_world': [float(x) for x in start]})
    return {'name': f'chain_{n}', 'integrator': 'lie_poisson2', 'dt': 1e-3,
            'effects': {'gravity': {'g_world': [0.0, 0.0, -G]}}, 'bodies': bodies,
            'constraints': joints}


def scenes() -> list:
    """Return (label, scene dict, per_body_topics, latency body, flip force N, axis) rows."""
    out = [(f'free_{n}', free_scene(n), True, 'b0', FREE_WEIGHTS * BOX_MASS * G, 0)
           for n in (1, 10, 100, 1000)]
    out += [(f'chain_{n}', chain_scene(n), True, f'l{n - 1}', CHAIN_WEIGHTS * ROD_MASS * G, 1)
            for n in (10, 100)]
    out.append(('free_1000 (body_states only)', free_scene(1000), False, None, 0.0, 0))
    return out


# -- processes and clients ---------------------------------------------------------------

def ros_env(domain: int) -> dict:
    """Return this environment with a private DDS domain and localhost-only discovery."""
    env = dict(os.environ)
    env['ROS_DOMAIN_ID'] = str(domain)
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    env.pop('ROS_STATIC_PEERS', None)
    env['PYTHONUNBUFFERED'] = '1'
    return env


def random_domain() -> int:
    """Return a DDS domain id unlikely to be in use (Fast DDS allows 0 to 232)."""
    return random.SystemRandom().randint(11, 200)


def sim_node_command(params: dict, profile: Optional[Path] = None) -> list:
    """Return the command line of ``sim_node`` with ``params`` (under cProfile if asked)."""
    try:
        prefix = Path(get_package_prefix('rigid_body_sim'))
    except (OSError, LookupError):   # no ament index in the environment: this checkout's build
        prefix = Path(__file__).resolve().parents[1] / 'install' / 'rigid_body_sim'
    exe = prefix / 'lib' / 'rigid_body_sim' / 'sim_node'
    if not exe.exists():
        raise SystemExit(f'{exe} not found: build first (./dev.sh setup)')
    cmd = [str(exe)]
    if profile is not None:
        cmd = [sys.executable, '-m', 'cProfile', '-o', str(profile), str(exe)]
    cmd.append('--ros-args')
    for key, value in params.items():
        text = str(value).lower() if isinstance(value, bool) else str(value)
        cmd += ['-p', f'{key}:={text}']
    return cmd


def processes() -> dict:
    """
    Return ``{pid: (start time, CPU seconds)}`` of every process on the machine.

    CPU seconds are user + system of all threads plus those of reaped children, from
    ``/proc/<pid>/stat`` (exact run time; the machine-wide ``/proc/stat`` is sampled at
    the kernel tick and misses or doubles a 1 kHz loop's busy time by aliasing).
    """
    out = {}
    tick = os.sysconf('SC_CLK_TCK')
    for entry in Path('/proc').iterdir():
        if not entry.name.isdigit():
            continue
        try:
            fields = (entry / 'stat').read_text().rsplit(')', 1)[1].split()
        except OSError:   # gone meanwhile
            continue
        out[int(entry.name)] = (fields[19], sum(int(x) for x in fields[11:15]) / tick)
    return out


def others_cpu(before: dict, after: dict, exclude: tuple) -> float:
    """Return the CPU seconds processes other than ``exclude`` used between two snapshots."""
    total = 0.0
    for pid, (start, cpu) in after.items():
        if pid in exclude:
            continue
        old = before.get(pid)
        total += cpu - old[1] if old is not None and old[0] == start else cpu
    return total


def wait_quiet(max_wait: float, limit: float = 0.25) -> None:
    """Wait (up to ``max_wait`` s) until other processes use less than ``limit`` cores."""
    t_end = time.monotonic() + max_wait
    said = False
    while max_wait > 0:
        p0, t0 = processes(), time.perf_counter()
        time.sleep(1.0)
        others = others_cpu(p0, processes(), (os.getpid(),)) / (time.perf_counter() - t0)
        if not others >= limit:
            return
        if time.monotonic() > t_end:
            print(f'  (other processes still use {others:.1f} cores; going on)', flush=True)
            return
        if not said:
            print(f'  (other processes use {others:.1f} cores: waiting up to {max_wait:g} s '
                  f'for a quiet machine)', flush=True)
            said = True


def cpu_seconds(pid: int) -> float:
    """Return the user + system CPU seconds of a process (all threads) from /proc."""
    try:
        fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    except OSError:
        return float('nan')
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


class Client:
    """A node in this process on the run's domain, spun by hand."""

    def __init__(self, domain: int, name: str = 'bench_client') -> None:
        self.context = rclpy.context.Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.node = Node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)

    def spin_until(self, condition: Callable[[], bool], what: str, timeout: float,
                   proc: Optional[subprocess.Popen] = None, log: Optional[Path] = None):
        """Spin until ``condition()``; raise RuntimeError naming ``what`` after ``timeout``."""
        end = time.monotonic() + timeout
        while not condition():
            if proc is not None and proc.poll() is not None:
                raise RuntimeError(f'the node exited ({proc.returncode}) while waiting for '
                                   f'{what}' + (f':\n{log.read_text()}' if log else ''))
            if time.monotonic() > end:
                raise RuntimeError(f'no {what} within {timeout:g} s')
            self.executor.spin_once(timeout_sec=0.05)

    def close(self) -> None:
        """Destroy the node and shut the context down."""
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


def stop(proc: subprocess.Popen, timeout: float = 60.0) -> int:
    """SIGINT the node (it shuts down cleanly), SIGKILL after ``timeout``."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    return proc.returncode


# -- one run -----------------------------------------------------------------------------

class FlipTimer:
    """
    Time input flips to the first output that shows each: the latency probes' bookkeeping.

    A subclass publishes with :meth:`send` and calls :meth:`seen` when an output
    shows the pending flip; ``missed`` counts flips that never showed before the next.
    """

    def __init__(self, pub) -> None:
        self.pub = pub
        self.pending: Optional[float] = None   # publish time of the flip not yet seen
        self.samples: list = []
        self.sent = self.missed = 0

    def send(self, msg, measured: bool) -> None:
        """Publish ``msg``; time it if ``measured``."""
        if self.pending is not None:
            self.missed += 1   # the previous flip never showed before this one
        t = time.perf_counter()
        self.pub.publish(msg)
        self.pending = t if measured else None
        self.sent += measured

    def seen(self, t: float) -> None:
        """Record that an output received at ``t`` (perf_counter) shows the pending flip."""
        if self.pending is not None:
            self.samples.append(t - self.pending)
            self.pending = None


class Flipper(FlipTimer):
    """Publish a flipping wrench and time each flip to the first twist that shows it."""

    def __init__(self, client: Client, body: str, force: float, axis: int) -> None:
        super().__init__(client.node.create_publisher(
            WrenchStamped, f'{NODE}/bodies/{body}/wrench', QoSProfile(depth=10)))
        client.node.create_subscription(TwistStamped, f'{NODE}/bodies/{body}/twist',
                                        self._on_twist, QoSProfile(depth=100))
        self.force, self.axis = force, axis
        self.twists = 0
        self.last_v: Optional[float] = None
        self.sign = 0.0

    def publish(self, sign: float, measured: bool) -> None:
        """Publish force ``sign * F``; time it if ``measured``."""
        msg = WrenchStamped()
        msg.header.frame_id = 'world'
        setattr(msg.wrench.force, 'xyz'[self.axis], sign * self.force)
        self.sign = sign
        self.send(msg, measured)

    def _on_twist(self, msg: TwistStamped) -> None:
        t = time.perf_counter()
        self.twists += 1
        v = getattr(msg.twist.linear, 'xyz'[self.axis])
        last, self.last_v = self.last_v, v
        if last is not None and (v - last) * self.sign > 0.0:
            self.seen(t)


def _windows(diags: list, t_from: float) -> list:
    """Return the diagnostics windows (dicts) received after ``t_from``, with steps and wall."""
    out = []
    prev = None
    for t, values in diags:
        if prev is not None and t >= t_from:
            w = dict(values)
            steps = int(values['steps']) - int(prev[1]['steps'])
            rate = float(values['physics_rate_achieved_hz'])
            w['_steps'] = steps
            w['_wall'] = steps / rate if steps > 0 and rate > 0 else t - prev[0]
            w['_lag_before'] = int(prev[1]['lag_resets_total'])
            w['_retries_before'] = int(prev[1]['retries_total'])
            w['_substeps_before'] = int(prev[1]['substeps_total'])
            out.append(w)
        prev = (t, values)
    return out


def summarize(windows: list) -> dict:
    """Aggregate diagnostics windows: rates and costs over their whole wall time."""
    if not windows:
        return {}
    wall = sum(w['_wall'] for w in windows)
    steps = sum(w['_steps'] for w in windows)
    sim_t = [float(w['real_time_factor_achieved']) * w['_wall'] for w in windows]
    step_cost = sum(float(w['step_cost_mean_us']) * w['_steps'] for w in windows)
    pub_cost = sum(float(w['publish_cost_mean_us']) * s for w, s in zip(windows, sim_t))
    publishes = sum(sim_t) * PARAMS['publish_rate']
    return {
        'windows': len(windows), 'wall': wall,
        'rate': steps / wall, 'rtf': sum(sim_t) / wall,
        'step_mean': step_cost / steps if steps else float('nan'),
        'step_max': max(float(w['step_cost_max_us']) for w in windows),
        'publish_mean': pub_cost / sum(sim_t) if sum(sim_t) else float('nan'),
        'step_share': step_cost * 1e-6 / wall,
        'publish_share': pub_cost * 1e-6 * PARAMS['publish_rate'] / wall,
        'publishes_per_s': publishes / wall,
        'overruns_per_s': sum(int(w['overruns_window']) for w in windows) / wall,
        'lag_resets': int(windows[-1]['lag_resets_total']) - windows[0]['_lag_before'],
        'retries': int(windows[-1]['retries_total']) - windows[0]['_retries_before'],
        'substeps': (int(windows[-1]['substeps_total']) - windows[0]['_substeps_before'])
        / steps if steps else float('nan'),
        'violation': float(windows[-1]['constraint_violation']),
    }


def run_scene(label: str, scene: dict, per_body: bool, body: Optional[str], force: float,
              axis: int, duration: float, workdir: Path,
              profile: Optional[Path] = None) -> dict:
    """Start the node on ``scene``, measure for ``duration`` s of wall time, stop it."""
    path = workdir / f'{scene["name"]}.yaml'
    path.write_text(yaml.safe_dump(scene, default_flow_style=None, sort_keys=False))
    params = dict(PARAMS, scene=str(path), per_body_topics=per_body)
    domain = random_domain()
    log = workdir / f'{label.split()[0]}_{domain}.log'
    t_launch = time.perf_counter()
    with open(log, 'w') as log_file:
        proc = subprocess.Popen(sim_node_command(params, profile), env=ros_env(domain),
                                stdout=log_file, stderr=subprocess.STDOUT,
                                start_new_session=True)
    client = Client(domain)
    try:
        diags: list = []

        def on_diag(msg: DiagnosticArray) -> None:
            for status in msg.status:
                if status.name.endswith(': physics'):
                    diags.append((time.perf_counter(), {kv.key: kv.value for kv in status.values}))

        client.node.create_subscription(DiagnosticArray, '/diagnostics', on_diag,
                                        QoSProfile(depth=100))
        # A consumer of the whole state (a recorder, a visualizer): the node publishes only
        # topics with subscribers.
        states = []
        client.node.create_subscription(BodyStates, f'{NODE}/body_states',
                                        lambda msg: states.append(time.perf_counter()),
                                        QoSProfile(depth=10))
        flipper = None
        if body is not None:
            flipper = Flipper(client, body, force, axis)
        client.spin_until(lambda: len(diags) >= 1 and len(states) >= 1,
                          'diagnostics and body states', STARTUP_DEADLINE, proc, log)
        startup = time.perf_counter() - t_launch
        if flipper is not None:
            client.spin_until(lambda: flipper.pub.get_subscription_count() > 0
                              and flipper.twists > 0, f'wrench subscriber and twists of {body}',
                              STARTUP_DEADLINE, proc, log)
        ready = time.perf_counter() - t_launch
        cpu0, own0, procs0 = cpu_seconds(proc.pid), time.process_time(), processes()
        t0 = time.perf_counter()
        end = t0 + duration
        # Flip k (k >= 1) at t0 + FLIP_PERIOD (k - 1/2) + u, u uniform in one publish period:
        # flips land at random phases of the node's publish grid (a fixed period would lock
        # to it and time one phase only).
        jitter = random.Random(len(scene['bodies']))
        flip, sign, next_flip = 0, 1.0, t0
        while True:
            now = time.perf_counter()
            if now >= end:
                break
            if flipper is not None and now >= next_flip:
                flipper.publish(sign, measured=flip > 0)
                flip += 1
                sign = -sign
                next_flip = t0 + FLIP_PERIOD * (flip - 0.5) + \
                    jitter.uniform(0.0, 1.0 / PARAMS['publish_rate'])
            wake = min(end, next_flip) if flipper is not None else end
            client.executor.spin_once(timeout_sec=max(0.0, wake - time.perf_counter()))
            if proc.poll() is not None:
                raise RuntimeError(f'the node exited ({proc.returncode}):\n{log.read_text()}')
        wall = time.perf_counter() - t0
        cpu = (cpu_seconds(proc.pid) - cpu0) / wall
        own = (time.process_time() - own0) / wall
        others = others_cpu(procs0, processes(), (os.getpid(), proc.pid)) / wall
        states_rate = sum(1 for t in states if t >= t0) / wall
        # Windows that end at least one report period into the measurement.
        result = summarize(_windows(diags, t0 + 1.0))
        result.update(label=label, bodies=len(scene['bodies']),
                      constraints=len(scene.get('constraints', [])), per_body=per_body,
                      startup=startup, ready=ready, node_cpu=cpu, own_cpu=own,
                      other_cpu=others, states_rate=states_rate)
        if flipper is not None:
            result.update(latency=np.array(flipper.samples) * 1e3, flips=flipper.sent,
                          missed=flipper.missed + (flipper.pending is not None))
    finally:
        client.close()
        code = stop(proc)
    if code != 0:
        print(f'  warning: {label}: the node exited with {code}; log {log}', flush=True)
    return result


# -- snapshot microbenchmark -------------------------------------------------------------

def snapshot_costs(ns, budget: float, min_repeats: int) -> list:
    """Return rows (layout, n, median us per snapshot, us per body, ratio to (a))."""
    client = Client(random_domain(), 'bench_snapshots')
    node = client.node
    rows = []
    try:
        for n in ns:
            rng = np.random.default_rng(n)
            names = [f'b{i}' for i in range(n)]
            pos, vel, omega = rng.normal(size=(n, 3)), rng.normal(size=(n, 3)), \
                rng.normal(size=(n, 3))
            quat = rng.normal(size=(n, 4))
            quat /= np.linalg.norm(quat, axis=1, keepdims=True)
            header = Header(stamp=conv.time_msg(12.345), frame_id='world')
            qos = QoSProfile(depth=10)
            states_pub = node.create_publisher(BodyStates, f'snap{n}/body_states', qos)
            poses_pub = node.create_publisher(PoseArray, f'snap{n}/poses', qos)
            twists_pub = node.create_publisher(MultiDOFJointTrajectoryPoint, f'snap{n}/twists',
                                               qos)
            pose_pubs = [node.create_publisher(PoseStamped, f'snap{n}/bodies/{b}/pose', qos)
                         for b in names]
            twist_pubs = [node.create_publisher(TwistStamped, f'snap{n}/bodies/{b}/twist', qos)
                          for b in names]

            def flat():
                states_pub.publish(conv.body_states(header, names, pos, quat, vel, omega))

            def nested():
                p, q, v, w = pos.tolist(), quat.tolist(), vel.tolist(), omega.tolist()
                poses_pub.publish(PoseArray(header=header, poses=[
                    Pose(position=Point(x=a[0], y=a[1], z=a[2]),
                         orientation=Quaternion(x=b[0], y=b[1], z=b[2], w=b[3]))
                    for a, b in zip(p, q)]))
                twists_pub.publish(MultiDOFJointTrajectoryPoint(velocities=[
                    Twist(linear=Vector3(x=a[0], y=a[1], z=a[2]),
                          angular=Vector3(x=b[0], y=b[1], z=b[2]))
                    for a, b in zip(v, w)]))

            def per_body():
                # As the node's _publish_state does with per-body topics.
                for i in range(n):
                    pose_pubs[i].publish(conv.pose_stamped(header, pos[i], quat[i]))
                    twist_pubs[i].publish(conv.twist_stamped(header, vel[i], omega[i]))

            base = None
            for layout, fn in (('(a) BodyStates, flat float64[]', flat),
                               ('(b) PoseArray + Twist[] (nested)', nested),
                               ('(c) PoseStamped + TwistStamped per body', per_body)):
                for _ in range(3):
                    fn()
                times = []
                t_end = time.perf_counter() + budget
                while len(times) < min_repeats or time.perf_counter() < t_end:
                    t0 = time.perf_counter()
                    fn()
                    times.append(time.perf_counter() - t0)
                us = float(np.median(times)) * 1e6
                base = us if base is None else base
                rows.append((layout, n, us, us / n, us / base))
                print(f'  {layout:42s} n {n:5d}  {us:10.1f} us/snapshot  {us / n:8.2f} us/body  '
                      f'x{us / base:6.2f}  ({len(times)} repeats)', flush=True)
            for pub in [states_pub, poses_pub, twists_pub] + pose_pubs + twist_pubs:
                node.destroy_publisher(pub)
    finally:
        client.close()
    return rows


def spin_costs(ns, budget: float) -> list:
    """Return rows (n, waitables, us per spin_once, the same without default event handlers)."""
    rows = []
    for n in ns:
        row = [n]
        for default in (True, False):
            client = Client(random_domain(), 'bench_spin')
            node = client.node
            kwargs_pub = {} if default else {
                'event_callbacks': PublisherEventCallbacks(use_default_callbacks=False)}
            kwargs_sub = {} if default else {
                'event_callbacks': SubscriptionEventCallbacks(use_default_callbacks=False)}
            try:
                for i in range(n):
                    node.create_publisher(PoseStamped, f'bodies/b{i}/pose', 10, **kwargs_pub)
                    node.create_publisher(TwistStamped, f'bodies/b{i}/twist', 10, **kwargs_pub)
                    node.create_subscription(WrenchStamped, f'bodies/b{i}/wrench',
                                             lambda msg: None, 10, **kwargs_sub)
                spin = client.executor.spin_once
                for _ in range(2):
                    spin(timeout_sec=0.0)
                times = []
                t_end = time.perf_counter() + budget
                while len(times) < 3 or time.perf_counter() < t_end:
                    t0 = time.perf_counter()
                    spin(timeout_sec=0.0)
                    times.append(time.perf_counter() - t0)
                row += [len(list(node.waitables)), float(np.median(times)) * 1e6]
            finally:
                client.close()
        rows.append(tuple(row))
        print(f'  bodies {n:5d}  default event handlers: {row[1]:5d} waitables, '
              f'{row[2]:9.0f} us/spin_once   without: {row[3]:5d} waitables, '
              f'{row[4]:8.0f} us/spin_once', flush=True)
    return rows


# -- output ------------------------------------------------------------------------------

def _fmt(x, spec: str) -> str:
    if x is None or (isinstance(x, float) and not np.isfinite(x)):
        return '-'
    return format(x, spec)


def _fmt_latency(lat: Optional[np.ndarray], q: float) -> str:
    if lat is None or not len(lat):
        return '-'
    text = f'{np.percentile(lat, q):.1f}'
    return text if len(lat) >= MIN_FLIPS else f'({text})'


def node_rows(results: list) -> list:
    """Return the table rows of the node runs."""
    rows = []
    for r in results:
        lat = r.get('latency')
        if 'error' in r:
            rows.append([r['label'], str(r['bodies']), f'failed: {r["error"]}']
                        + ['-'] * (len(NODE_HEADER) - 3))
            continue
        rows.append([
            r['label'], str(r['bodies']), _fmt(r['ready'], '.1f'),
            _fmt(r.get('rate'), '.0f'), _fmt(r.get('rtf'), '.3f'),
            _fmt(r.get('step_mean'), '.0f'), _fmt(r.get('step_max'), '.0f'),
            _fmt(r.get('publish_mean'), '.0f'), _fmt(100 * r.get('step_share', np.nan), '.0f'),
            _fmt(100 * r.get('publish_share', np.nan), '.0f'), _fmt(100 * r['node_cpu'], '.0f'),
            _fmt(100 * r['own_cpu'], '.0f'), _fmt(100 * r['other_cpu'], '.0f'),
            _fmt(r.get('substeps'), '.2f'), _fmt(r.get('overruns_per_s'), '.1f'),
            _fmt(r.get('lag_resets'), 'd'),
            _fmt_latency(lat, 50), _fmt_latency(lat, 99),
            f'{len(lat)}/{r["flips"]}' if lat is not None else '-'])
    return rows


NODE_HEADER = ('scene', 'bodies', 'up [s]', 'physics [Hz]', 'RTF', 'step mean [us]',
               'step max [us]', 'publish mean [us]', 'step [% wall]', 'publish [% wall]',
               'node CPU [%]', 'bench CPU [%]', 'other CPU [%]', 'substeps / step',
               'overruns / s', 'lag resets', 'latency p50 [ms] (incl. wait for publish)',
               'latency p99 [ms] (incl. wait for publish)', 'flips seen')


def markdown(header, rows) -> str:
    """Return a markdown table."""
    lines = ['| ' + ' | '.join(header) + ' |', '|' + '---|' * len(header)]
    lines += ['| ' + ' | '.join(str(c) for c in r) + ' |' for r in rows]
    return '\n'.join(lines) + '\n'


def machine() -> str:
    """Return the date, CPUs, CPU model, and the Python, rclpy and RMW versions."""
    model = platform.processor() or platform.machine()
    try:
        for line in Path('/proc/cpuinfo').read_text().splitlines():
            if line.startswith('model name'):
                model = line.split(':', 1)[1].strip()
                break
    except OSError:
        pass
    try:
        rclpy_version = metadata.version('ros-jazzy-rclpy')
    except metadata.PackageNotFoundError:
        rclpy_version = 'unknown'
    return (f'{datetime.datetime.now().astimezone():%Y-%m-%d %H:%M %Z}; '
            f'nproc {len(os.sched_getaffinity(0))} ({model}); python '
            f'{platform.python_version()}; rclpy {rclpy_version}; '
            f'{rclpy.get_rmw_implementation_identifier()}; numpy {np.__version__}')


def code_version() -> str:
    """Return the commit of this checkout, and whether the package differs from it."""
    root = Path(__file__).resolve().parents[1]
    try:
        commit = subprocess.run(['git', 'rev-parse', '--short', 'HEAD'], cwd=root,
                                capture_output=True, text=True, check=True).stdout.strip()
        dirty = subprocess.run(['git', 'status', '--porcelain', 'rigid_body_sim'], cwd=root,
                               capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return 'commit unknown'
    return f'commit {commit}' + (' (rigid_body_sim/ modified)' if dirty else '')


def _plot(results: list, snaps: list, spins: list) -> Optional[Path]:
    try:
        import matplotlib
        matplotlib.use('Agg')
        import matplotlib.pyplot as plt
    except ImportError:
        print('matplotlib not installed: no plot (pip install matplotlib)')
        return None
    fig, axes = plt.subplots(2, 2, figsize=(12, 8.5))
    labels = [r['label'].replace(' (body_states only)', '\n(states only)') for r in results]
    x = np.arange(len(results))
    ax = axes[0, 0]
    ax.bar(x - 0.2, [r.get('step_mean', np.nan) for r in results], 0.4, label='step mean')
    ax.bar(x + 0.2, [r.get('step_max', np.nan) for r in results], 0.4, label='step max')
    ax.plot(x, [r.get('publish_mean', np.nan) for r in results], 'k^', label='publish mean')
    ax.axhline(1e6 / PARAMS['physics_rate'], color='r', ls='--', label='budget 1/rate')
    ax.set_yscale('log')
    ax.set_ylim(bottom=10.0)
    ax.set_ylabel('wall time [us]')
    ax.set_title('cost per step and per publish (node /diagnostics)')
    ax = axes[0, 1]
    ax.bar(x, [r.get('rate', np.nan) for r in results], 0.6, color='tab:green')
    ax.axhline(PARAMS['physics_rate'], color='r', ls='--', label='target')
    ax.set_ylabel('achieved physics rate [Hz]')
    ax.set_title('achieved physics rate (= 1000 x real-time factor)')
    ax = axes[1, 0]
    lat = [r.get('latency') for r in results]
    p50 = [np.percentile(v, 50) if v is not None and len(v) >= MIN_FLIPS else np.nan
           for v in lat]
    p99 = [np.percentile(v, 99) if v is not None and len(v) >= MIN_FLIPS else np.nan
           for v in lat]
    ax.bar(x - 0.2, p50, 0.4, label='p50')
    ax.bar(x + 0.2, p99, 0.4, label='p99')
    ax.set_ylabel('wrench publish -> twist receipt [ms]')
    ax.set_title('wrench -> twist latency (includes 5-15 ms of waiting for a publish)')
    for ax in axes[0, 0], axes[0, 1], axes[1, 0]:
        ax.set_xticks(x)
        ax.set_xticklabels(labels, rotation=30, ha='right', fontsize=8)
        ax.grid(True, axis='y', which='both', alpha=0.3)
        ax.legend(fontsize=8)
    ax = axes[1, 1]
    for layout in dict.fromkeys(r[0] for r in snaps):
        rs = [r for r in snaps if r[0] == layout]
        ax.loglog([r[1] for r in rs], [r[2] for r in rs], 'o-', label=layout)
    ax.loglog([r[0] for r in spins], [r[2] for r in spins], 'ks--',
              label='executor spin_once, default event handlers')
    ax.loglog([r[0] for r in spins], [r[4] for r in spins], 'kx:',
              label='executor spin_once, without')
    ax.axhline(1e6 / PARAMS['physics_rate'], color='r', ls='--', lw=0.8)
    ax.set_xlabel('bodies')
    ax.set_ylabel('wall time [us]')
    ax.set_title('build + publish one snapshot; one executor spin (in-process)')
    ax.grid(True, which='both', alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    path = OUT / 'node.png'
    fig.savefig(path, dpi=110)
    return path


def _key(label: str, per_body: bool) -> str:
    return label.split()[0] + ('' if per_body else '_states')


def profile_scenes(labels: list, duration: float, top: int = 30) -> None:
    """Run scenes with the node under cProfile; write and print the top entries."""
    import pstats
    known = {_key(s[0], s[2]): s for s in scenes()}
    with tempfile.TemporaryDirectory(prefix='bench_node_') as tmp:
        for label in labels:
            if label not in known:
                raise SystemExit(f'--profile: unknown scene {label!r}; known: {sorted(known)}')
            prof = Path(tmp) / f'{label}.prof'
            print(f'\n== profiling {label} for {duration:g} s (cProfile: rates are lower) ==',
                  flush=True)
            r = run_scene(*known[label], duration, Path(tmp), profile=prof)
            _progress(r)
            text_path = OUT / f'node_profile_{label}.txt'
            with open(text_path, 'w') as f:
                for key in ('tottime', 'cumulative'):
                    stats = pstats.Stats(str(prof), stream=f)
                    stats.strip_dirs().sort_stats(key).print_stats(top)
            print(text_path.read_text())
            print(f'profile: {text_path}')


def _progress(r: dict) -> None:
    if 'error' in r:
        print(f'  {r["label"]:30s} FAILED: {r["error"]}', flush=True)
        return
    lat = r.get('latency')
    text = (f'  {r["label"]:30s} up {r["ready"]:5.1f} s  {r.get("rate", np.nan):7.1f} Hz  '
            f'rtf {r.get("rtf", np.nan):5.3f}  step {r.get("step_mean", np.nan):7.0f} us '
            f'(max {r.get("step_max", np.nan):6.0f})  publish '
            f'{r.get("publish_mean", np.nan):7.0f} us  cpu node {100 * r["node_cpu"]:3.0f}% '
            f'bench {100 * r["own_cpu"]:3.0f}% other {100 * r["other_cpu"]:3.0f}%  '
            f'overruns/s {r.get("overruns_per_s", np.nan):6.1f}  lag resets '
            f'{r.get("lag_resets", -1)}  substeps/step {r.get("substeps", np.nan):.2f}  '
            f'retries {r.get("retries", -1)}  '
            f'violation {r.get("violation", np.nan):.1e}  body_states received '
            f'{r["states_rate"]:.0f}/s')
    if lat is not None and len(lat):
        text += (f'  latency p50 {np.percentile(lat, 50):5.1f} p99 '
                 f'{np.percentile(lat, 99):5.1f} ms ({len(lat)}/{r["flips"]} flips)')
    print(text, flush=True)


def main(argv=None) -> int:
    """Run the node benchmarks."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument('--quick', action='store_true', help='3 s per scene, fewer repeats')
    p.add_argument('--duration', type=float, help='s of wall time per scene (10; --quick 3)')
    p.add_argument('--max-wait', type=float, default=120.0, metavar='S',
                   help='before each part, wait up to S s while other processes keep a '
                        'quarter of a core busy (0: never wait)')
    p.add_argument('--scenes', nargs='+', metavar='SCENE',
                   help='only these node scenes (names as for --profile)')
    p.add_argument('--profile', nargs='+', metavar='SCENE',
                   help='run these scenes under cProfile instead (free_1, ..., free_1000, '
                        'chain_10, chain_100, free_1000_states)')
    args = p.parse_args(argv)
    OUT.mkdir(exist_ok=True)
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    os.environ.pop('ROS_STATIC_PEERS', None)
    duration = args.duration or (3.0 if args.quick else 10.0)
    if args.profile:
        profile_scenes(args.profile, duration)
        return 0
    info = f'{machine()}; {code_version()}'
    print(info)
    print(f'\n== node runs: physics {PARAMS["physics_rate"]:g} Hz, publish '
          f'{PARAMS["publish_rate"]:g} Hz, real-time factor {PARAMS["real_time_factor"]:g}, '
          f'{duration:g} s each ==', flush=True)
    results = []
    with tempfile.TemporaryDirectory(prefix='bench_node_') as tmp:
        for label, scene, per_body, body, force, axis in scenes():
            if args.scenes and _key(label, per_body) not in args.scenes:
                continue
            wait_quiet(args.max_wait)
            try:
                r = run_scene(label, scene, per_body, body, force, axis, duration, Path(tmp))
            except RuntimeError as exc:   # a node that fails is a result too; go on
                print(f'  {label}: {exc}', flush=True)
                r = {'label': label, 'bodies': len(scene['bodies']),
                     'error': str(exc).splitlines()[0]}
            results.append(r)
            _progress(r)
    print('\n== snapshot build + publish (in-process, no subscriber) ==', flush=True)
    wait_quiet(args.max_wait)
    snaps = snapshot_costs((1, 10, 100, 1000), 0.3 if args.quick else 1.0,
                           5 if args.quick else 20)
    print('\n== executor: one spin_once(0) with the per-body entities of n bodies ==',
          flush=True)
    wait_quiet(args.max_wait)
    spins = spin_costs((1, 10, 100, 1000), 0.3 if args.quick else 1.0)
    node_table = markdown(NODE_HEADER, node_rows(results))
    snap_table = markdown(('layout', 'bodies', 'us / snapshot', 'us / body', 'ratio to (a)'),
                          [(r[0], r[1], f'{r[2]:.1f}', f'{r[3]:.2f}', f'{r[4]:.2f}')
                           for r in snaps])
    node_note = (
        f'Node runs: {duration:g} s of wall time each after the node is up ("up": from launch '
        f'to diagnostics, the wrench subscriber matched and a twist received); physics '
        f'{PARAMS["physics_rate"]:g} Hz, publish {PARAMS["publish_rate"]:g} Hz, real-time '
        f'factor {PARAMS["real_time_factor"]:g}. Rates and costs from the node\'s /diagnostics '
        f'windows (1 s) that end at least 1 s into the measurement, aggregated over their '
        f'wall time; "step/publish [% wall]": share of wall time in steps / state publishes; '
        f'CPU (from /proc, 100 % = one core of {len(os.sched_getaffinity(0))}): the node '
        f'process (all threads), this benchmark process, and everything else on the machine '
        f'(should be near 0). The benchmark subscribes to ~/body_states, /diagnostics and '
        f'the twist of the body it pushes (the node publishes only topics that have '
        f'subscribers). Latency: wall clock from '
        f'publishing a flipped WrenchStamped (F = {FREE_WEIGHTS:g} x the weight of a free '
        f'body, {CHAIN_WEIGHTS:g} x that of a chain link, every '
        f'{FLIP_PERIOD * 1e3:g} ms on average, at random phases of the publish period) to '
        f'receiving the first ~/bodies/<B>/twist whose velocity '
        f'change since the previous twist has the new sign (B: the first free body, force '
        f'along x; the last link of a chain, along y). **It includes waiting for the next '
        f'publish** (twists come every 10 ms of simulated time; the velocity change over an '
        f'interval takes the new sign once more than half of it ran with the new force, so '
        f'5-15 ms, 10 ms on average, after the first step that applies it; at a real-time '
        f'factor below 1 these are ms of simulated time, 1/RTF times longer in wall time). '
        f'Percentiles of fewer than {MIN_FLIPS} timed flips are in parentheses. '
        f'"flips seen": flips timed / flips sent (a flip the next one supersedes before a '
        f'twist shows it is not timed). "substeps / step": the core\'s sub-step counter per '
        f'step (sub-steps of the steps it splits for fast rotation; 0: none split). '
        f'"body_states only": per_body_topics:=false (no per-body topics, so no latency).')
    snap_note = (
        '(a) one rigid_body_sim_interfaces/BodyStates built by '
        'rigid_body_sim.ros.conversions.body_states (flat float64[] arrays, and the names); '
        '(b) one geometry_msgs/PoseArray plus one trajectory_msgs/MultiDOFJointTrajectoryPoint '
        'with only its geometry_msgs/Twist[] velocities filled (the proxy for a TwistArray, '
        'which common_interfaces lacks; no names); (c) one PoseStamped plus one TwistStamped '
        'per body on 2n publishers, built by conversions.pose_stamped/twist_stamped as the '
        'node does. Median of repeats; publishers with no subscriber (build, conversion to C '
        'and serialization; delivery to subscribers comes on top, per message).')
    spin_table = markdown(('bodies', 'waitables (default event handlers)',
                           'us / spin_once (default)', 'waitables (without)',
                           'us / spin_once (without)'),
                          [(r[0], r[1], f'{r[2]:.0f}', r[3], f'{r[4]:.0f}') for r in spins])
    spin_note = (
        'One SingleThreadedExecutor.spin_once(timeout_sec=0), median, on a node in this '
        'process with 2 publishers (PoseStamped, TwistStamped) and 1 subscription '
        '(WrenchStamped) per body, as sim_node has with per_body_topics (plus its few '
        'services and its ~/body_states, /clock and /diagnostics publishers). "default": '
        "rclpy's default QoS event handlers on every publisher and subscription (what "
        'create_publisher / create_subscription make unless told otherwise); "without": '
        'event_callbacks=...EventCallbacks(use_default_callbacks=False). The node spins once '
        'after every step: at 1 kHz a spin must cost well under 1 ms on top of the step.')
    text = (f'# Node benchmark\n\n{info}\n\nCommand: `python bench/node.py'
            f'{" --quick" if args.quick else ""}'
            f'{f" --duration {args.duration:g}" if args.duration else ""}`\n\n'
            f'## The node as a user runs it\n\n{node_note}\n\n{node_table}\n'
            f'## Building and publishing one snapshot\n\n{snap_note}\n\n{snap_table}\n'
            f'## What one executor spin costs\n\n{spin_note}\n\n{spin_table}')
    (OUT / 'node.md').write_text(text)
    print('\n' + node_table + '\n' + snap_table + '\n' + spin_table)
    plot = _plot(results, snaps, spins)
    print(f'table: {OUT / "node.md"}' + (f', plot: {plot}' if plot else ''))
    return 0


if __name__ == '__main__':
    sys.exit(main())
