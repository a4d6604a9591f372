"""
Node benchmark with a robot: the Franka Panda in ``sim_node``, joint_states and /tf at 1 kHz.

The robot is ``panda.urdf`` of PyPI ``example-robot-data`` as ``bench/robot_panda.py``
prepares it (the fingers fixed, no ``<mimic>``, no ``<dynamics>``), on a fixed base
in its ready pose under gravity, with joints 1-6 on position servos holding that
pose (group ``arm_position_controller``, kp 300 N m/rad, kd 30 N m s/rad) and joint 7
on efforts; without ``example-robot-data``, ``test/urdf/arm7.urdf`` (joints 1-6
servoed alike, joint 7 on efforts). ``sim_node`` runs it in a child process on a
fresh random ``ROS_DOMAIN_ID`` with localhost-only discovery, at physics 1 kHz,
``joint_state_rate`` and ``tf_rate`` 1 kHz (a message every step), ``publish_rate``
100 Hz (nothing subscribes to the body topics), twice: at real-time factor 1 and as
fast as it can (real-time factor 0). This process subscribes to ``joint_states``,
``/tf`` and ``/diagnostics`` and, for a fixed wall time once the node is up:

1. reads the achieved physics rate, real-time factor and step cost from the node's
   own ``/diagnostics`` windows (1 s each; those ending in the first second of the
   measurement are dropped; helpers of ``bench/node.py``), and counts the
   ``joint_states`` and ``/tf`` messages it receives per second of wall time;
2. times effort command -> joint_states: every 50 ms on average, at random phases,
   it publishes on ``~/joint_commands`` an effort for joint 7 that flips between
   +E and -E (E = 0.5 N m), and times each flip from the publish to the receipt of
   the first ``joint_states`` whose effort of joint 7 is the new command (the
   effort read back is the command that acted over the last step: exactly the
   value sent, as joint 7 has no servo and no damping here). This includes
   waiting for the next step (up to 1 ms at real-time factor 1) and DDS both ways.

CPU use (from ``/proc``) of the node, of this process and of everything else is
reported as in ``bench/node.py``. Writes ``bench/out/node_robot.md``.
Run: ``./dev.sh python bench/node_robot.py [--quick]`` (``./dev.sh bench`` runs it
after ``bench/node.py``).
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path
import random
import subprocess
import sys
import tempfile
import time
from typing import Optional

from diagnostic_msgs.msg import DiagnosticArray
import numpy as np
from rclpy.qos import QoSProfile
from sensor_msgs.msg import JointState
from tf2_msgs.msg import TFMessage
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent))
import node as node_bench  # noqa: E402, I100
from node import Client, cpu_seconds, FlipTimer, markdown, others_cpu, processes, \
    random_domain, ros_env, sim_node_command, stop, summarize, wait_quiet  # noqa: E402, I100

OUT = Path(__file__).resolve().parent / 'out'
ROOT = Path(__file__).resolve().parents[1]
NODE = '/rigid_body_sim'
G = 9.81
#: Node parameters of every run (real_time_factor per run).
PARAMS = {'physics_rate': 1000.0, 'joint_state_rate': 1000.0, 'tf_rate': 1000.0,
          'publish_rate': 100.0}
#: Real-time factors of the runs (0: as fast as possible).
FACTORS = (1.0, 0.0)
#: N m: the effort step on the last joint.
EFFORT = 0.5
#: s between effort flips (on average).
FLIP_PERIOD = 0.05
#: The servo gains of joints 1-6 (kp c dt² <= 0.2 for the Panda at its ready pose).
KP, KD = 300.0, 30.0
#: s: how long a node may take to come up.
STARTUP_DEADLINE = 120.0
#: Fewer timed flips than this: percentiles in parentheses.
MIN_FLIPS = 20


def robot(workdir: Path) -> tuple:
    """Write the robot's URDF and scene into ``workdir``; return (label, scene path, joints)."""
    try:
        from robot_panda import ARM, benchmark_urdf, panda_urdf, READY
        xml = benchmark_urdf(panda_urdf().read_text())
        label, joints, initial = 'Panda (example-robot-data)', list(ARM), \
            [float(q) for q in READY]
    except Exception as exc:  # noqa: B902 - not installed, or another version: fall back
        print(f'  (the Panda is not available: {exc!r}; test/urdf/arm7.urdf instead)')
        xml = (ROOT / 'test' / 'urdf' / 'arm7.urdf').read_text()
        label, joints = 'arm7 (test/urdf/arm7.urdf)', [f'joint{i}' for i in range(1, 8)]
        initial = [0.0] * 7
    urdf = workdir / 'robot.urdf'
    urdf.write_text(xml)
    scene = {'name': 'node_robot', 'integrator': 'lie_poisson2', 'dt': 1e-3,
             'effects': {'gravity': {'g_world': [0.0, 0.0, -G]}},
             'robots': [{'urdf': str(urdf), 'fixed_base': True,
                         'initial_positions': dict(zip(joints, initial))}],
             'command_groups': [{'name': 'arm_position_controller', 'joints': joints[:6],
                                 'interface': 'position', 'mode': 'servo', 'kp': KP,
                                 'kd': KD}]}
    path = workdir / 'node_robot.yaml'
    path.write_text(yaml.safe_dump(scene, default_flow_style=None, sort_keys=False))
    return label, path, joints


class EffortFlipper(FlipTimer):
    """Publish a flipping effort on one joint; time each flip to the joint_states showing it."""

    def __init__(self, client: Client, joint: str) -> None:
        super().__init__(client.node.create_publisher(JointState, f'{NODE}/joint_commands',
                                                      QoSProfile(depth=10)))
        self.joint = joint
        self.index: Optional[int] = None
        self.value = 0.0
        self.states = 0

    def publish(self, value: float, measured: bool) -> None:
        """Publish effort ``value``; time it if ``measured``."""
        self.value = value
        self.send(JointState(name=[self.joint], effort=[value]), measured)

    def on_joint_states(self, msg: JointState) -> None:
        """Time the pending flip if this message shows it."""
        t = time.perf_counter()
        self.states += 1
        if self.index is None:
            self.index = list(msg.name).index(self.joint)
        if abs(msg.effort[self.index] - self.value) < 1e-9:
            self.seen(t)


def run(label: str, scene: Path, joints: list, factor: float, duration: float,
        workdir: Path) -> dict:
    """Start the node at real-time factor ``factor``, measure for ``duration`` s, stop it."""
    params = dict(PARAMS, scene=str(scene), real_time_factor=factor)
    domain = random_domain()
    log = workdir / f'node_robot_{domain}.log'
    t_launch = time.perf_counter()
    with open(log, 'w') as log_file:
        proc = subprocess.Popen(sim_node_command(params), env=ros_env(domain), stdout=log_file,
                                stderr=subprocess.STDOUT, start_new_session=True)
    client = Client(domain)
    try:
        diags: list = []

        def on_diag(msg: DiagnosticArray) -> None:
            for status in msg.status:
                if status.name.endswith(': physics'):
                    diags.append((time.perf_counter(),
                                  {kv.key: kv.value for kv in status.values}))

        client.node.create_subscription(DiagnosticArray, '/diagnostics', on_diag,
                                        QoSProfile(depth=100))
        flipper = EffortFlipper(client, joints[-1])
        client.node.create_subscription(JointState, '/joint_states', flipper.on_joint_states,
                                        QoSProfile(depth=100))
        tf_times: list = []
        client.node.create_subscription(TFMessage, '/tf',
                                        lambda msg: tf_times.append(time.perf_counter()),
                                        QoSProfile(depth=100))
        client.spin_until(lambda: diags and flipper.states and tf_times
                          and flipper.pub.get_subscription_count() > 0,
                          'diagnostics, joint_states, /tf and the command subscriber',
                          STARTUP_DEADLINE, proc, log)
        ready = time.perf_counter() - t_launch
        states0, tf0 = flipper.states, len(tf_times)
        cpu0, own0, procs0 = cpu_seconds(proc.pid), time.process_time(), processes()
        t0 = time.perf_counter()
        end = t0 + duration
        jitter = random.Random(0)
        flip, sign, next_flip = 0, 1.0, t0
        while True:
            now = time.perf_counter()
            if now >= end:
                break
            if now >= next_flip:
                flipper.publish(sign * EFFORT, measured=flip > 0)
                flip += 1
                sign = -sign
                # At random phases of the step period (a fixed period would lock to it).
                next_flip = t0 + FLIP_PERIOD * (flip - 0.5) + jitter.uniform(0.0, 1e-3)
            client.executor.spin_once(timeout_sec=max(0.0, min(end, next_flip)
                                                      - time.perf_counter()))
            if proc.poll() is not None:
                raise RuntimeError(f'the node exited ({proc.returncode}):\n{log.read_text()}')
        wall = time.perf_counter() - t0
        result = summarize(node_bench._windows(diags, t0 + 1.0))
        result.update(
            label=label, factor=factor, ready=ready,
            node_cpu=(cpu_seconds(proc.pid) - cpu0) / wall,
            own_cpu=(time.process_time() - own0) / wall,
            other_cpu=others_cpu(procs0, processes(), (os.getpid(), proc.pid)) / wall,
            states_rate=(flipper.states - states0) / wall,
            tf_rate=(len(tf_times) - tf0) / wall,
            latency=np.array(flipper.samples) * 1e3, flips=flipper.sent,
            missed=flipper.missed + (flipper.pending is not None))
    finally:
        client.close()
        code = stop(proc)
    if code != 0:
        print(f'  warning: the node exited with {code}; log {log}', flush=True)
    return result


HEADER = ('robot', 'real-time factor asked', 'up [s]', 'physics [Hz]', 'RTF',
          'step mean [us]', 'step max [us]', 'joint_states received [/s]',
          '/tf received [/s]', 'node CPU [%]', 'bench CPU [%]', 'other CPU [%]',
          'overruns / s', 'lag resets', 'command -> joint_states p50 [ms]',
          'command -> joint_states p99 [ms]', 'flips seen')


def _percentile(values: np.ndarray, q: float) -> str:
    if not len(values):
        return '-'
    text = f'{np.percentile(values, q):.2f}'
    return text if len(values) >= MIN_FLIPS else f'({text})'


def row(r: dict) -> tuple:
    """Return the table row of one run."""
    if 'error' in r:
        return (r['label'], f'{r["factor"]:g}', 'failed: ' + r['error']) + ('',) * 14
    factor = 'as fast as possible (0)' if r['factor'] == 0 else f'{r["factor"]:g}'
    return (r['label'], factor, f'{r["ready"]:.1f}', f'{r.get("rate", np.nan):.0f}',
            f'{r.get("rtf", np.nan):.3f}', f'{r.get("step_mean", np.nan):.0f}',
            f'{r.get("step_max", np.nan):.0f}', f'{r["states_rate"]:.0f}',
            f'{r["tf_rate"]:.0f}', f'{100 * r["node_cpu"]:.0f}',
            f'{100 * r["own_cpu"]:.0f}', f'{100 * r["other_cpu"]:.0f}',
            f'{r.get("overruns_per_s", np.nan):.1f}', r.get('lag_resets', '-'),
            _percentile(r['latency'], 50), _percentile(r['latency'], 99),
            f'{len(r["latency"])}/{r["flips"]}')


def main(argv=None) -> int:
    """Run the robot node benchmark; write bench/out/node_robot.md."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    p.add_argument('--quick', action='store_true', help='3 s per run')
    p.add_argument('--duration', type=float, help='s of wall time per run (10; --quick 3)')
    p.add_argument('--max-wait', type=float, default=120.0, metavar='S',
                   help='before each run, wait up to S s while other processes keep a '
                        'quarter of a core busy (0: never wait)')
    args = p.parse_args(argv)
    OUT.mkdir(exist_ok=True)
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    os.environ.pop('ROS_STATIC_PEERS', None)
    duration = args.duration or (3.0 if args.quick else 10.0)
    info = f'{node_bench.machine()}; {node_bench.code_version()}'
    print(info)
    results = []
    with tempfile.TemporaryDirectory(prefix='bench_node_robot_') as tmp:
        label, scene, joints = robot(Path(tmp))
        print(f'\n== {label}: physics, joint_states and /tf at 1 kHz, {duration:g} s per run ==',
              flush=True)
        for factor in FACTORS:
            wait_quiet(args.max_wait)
            try:
                r = run(label, scene, joints, factor, duration, Path(tmp))
            except RuntimeError as exc:   # a node that fails is a result too; go on
                r = {'label': label, 'factor': factor, 'error': str(exc).splitlines()[0]}
            results.append(r)
            print('  ' + '  '.join(f'{h}: {c}' for h, c in zip(HEADER[1:], row(r)[1:])),
                  flush=True)
    table = markdown(HEADER, [row(r) for r in results])
    note = (
        f'{results[0]["label"]} on a fixed base under gravity, joints 1-6 on position servos '
        f'(kp {KP:g} N m/rad, kd {KD:g} N m s/rad) holding the ready pose, joint 7 on efforts; '
        f'sim_node with physics_rate, joint_state_rate and tf_rate '
        f'{PARAMS["physics_rate"]:g} Hz (publish_rate {PARAMS["publish_rate"]:g} Hz, no body '
        f'topic subscribed), {duration:g} s of wall time per run once up ("up": from launch '
        f'to diagnostics, joint_states, /tf and the command subscriber matched). Rates and '
        'step costs from the /diagnostics windows of the node ending at least 1 s into the '
        'run; "received": messages this process received per second of wall time; CPU from /proc '
        f'(100 % = one core of {len(os.sched_getaffinity(0))}). Command -> joint_states: wall '
        f'time from publishing on ~/joint_commands an effort of joint 7 that flips between '
        f'+{EFFORT:g} and -{EFFORT:g} N m (every {FLIP_PERIOD * 1e3:g} ms on average, at '
        f'random phases) to receiving the first joint_states whose effort of joint 7 is the '
        f'new value; it includes waiting for the next step (up to 1 ms at real-time factor '
        f'1) and DDS both ways, on one machine. Percentiles of fewer than {MIN_FLIPS} flips '
        f'are in parentheses; "flips seen": timed / sent.')
    text = (f'# Node benchmark with a robot\n\n{info}\n\nCommand: `python bench/node_robot.py'
            f'{" --quick" if args.quick else ""}'
            f'{f" --duration {args.duration:g}" if args.duration else ""}`\n\n{note}\n\n'
            f'{table}')
    (OUT / 'node_robot.md').write_text(text)
    print('\n' + table + f'\ntable: {OUT / "node_robot.md"}')
    return 1 if any('error' in r for r in results) else 0


if __name__ == '__main__':
    sys.exit(main())
