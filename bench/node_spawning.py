"""
Node benchmark: the node's achieved rate while entities are spawned and deleted.

``sim_node`` runs a scene of 10 free boxes under gravity (``bench/node.py``'s boxes) in a
child process on a fresh random ``ROS_DOMAIN_ID`` with localhost-only discovery, at
physics 1 kHz and real-time factor 1 (``bench/node.py``'s parameters). This process,
through DDS:

1. quiet: lets it run for a while;
2. spawning: calls ``spawn_entity`` N times back to back (each call waits for its reply
   before the next), each a box in our YAML body format at its own place;
3. deleting: calls ``delete_entity`` on them, back to back;
4. robots: spawns ``config/servo_arm.urdf`` M times (``allow_renaming``: each takes the
   prefix ``<name>_``), then deletes them.

For each phase: the calls' round trips (request to reply, wall clock), the simulated
time the node advanced over the phase's wall time (its achieved real-time factor: the
sim time read with ``get_entity_state`` before and after, over the wall time between),
and the lag resets over it (the node's ``/diagnostics``: a backlog of due steps beyond
``rigid_body_sim.ros.pacing.MAX_LAG`` dropped). A spawn blocks the node's loop for its
cost (the simulation rebuilt around the new entity); the steps due meanwhile are
caught up after it, back to back, unless the backlog passes MAX_LAG.

Writes ``bench/out/node_spawning.md``. Run: ``./dev.sh python bench/node_spawning.py
[--quick]`` (``./dev.sh bench`` runs it with the node benchmarks).
"""

from __future__ import annotations

import argparse
from pathlib import Path
import subprocess
import sys
import tempfile
import time

from diagnostic_msgs.msg import DiagnosticArray
import numpy as np
from rclpy.qos import QoSProfile
from simulation_interfaces.msg import Result
from simulation_interfaces.srv import DeleteEntity, GetEntityState, SpawnEntity
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent))
from node import Client, code_version, free_scene, machine, markdown, PARAMS, \
    random_domain, ros_env, sim_node_command, STARTUP_DEADLINE, stop  # noqa: E402, I100

OUT = Path(__file__).resolve().parent / 'out'
ROOT = Path(__file__).resolve().parents[1]
#: s: the longest a call may take before the run fails.
CALL_DEADLINE = 60.0
HEADER = ('phase', 'calls', 'bodies after', 'call p50 [ms]', 'call max [ms]', 'wall [s]',
          'sim time / wall (RTF)', 'lag resets', 'backlog dropped [s]')


def _call(client: Client, clients: dict, srv_type, name: str, request):
    if name not in clients:
        clients[name] = client.node.create_client(srv_type, name)
        client.spin_until(clients[name].service_is_ready, f'service {name}', STARTUP_DEADLINE)
    future = clients[name].call_async(request)
    client.spin_until(future.done, f'reply from {name}', CALL_DEADLINE)
    return future.result()


def run(n_bodies: int, n_robots: int, quiet: float, workdir: Path) -> list:
    """Run the phases on one node; return the table rows."""
    scene = free_scene(10)
    path = workdir / 'spawning.yaml'
    path.write_text(yaml.safe_dump(scene, default_flow_style=None, sort_keys=False))
    domain = random_domain()
    log = workdir / f'node_{domain}.log'
    with open(log, 'w') as log_file:
        proc = subprocess.Popen(sim_node_command(dict(PARAMS, scene=str(path))),
                                env=ros_env(domain), stdout=log_file,
                                stderr=subprocess.STDOUT, start_new_session=True)
    client = Client(domain)
    clients: dict = {}
    rows = []
    try:
        diags: list = []

        def on_diag(msg: DiagnosticArray) -> None:
            for status in msg.status:
                if status.name.endswith(': physics'):
                    values = {kv.key: kv.value for kv in status.values}
                    diags.append((int(values['lag_resets_total']),
                                  float(values['lag_dropped_wall_s'])))

        client.node.create_subscription(DiagnosticArray, '/diagnostics', on_diag,
                                        QoSProfile(depth=100))
        client.spin_until(lambda: len(diags) >= 2, 'diagnostics', STARTUP_DEADLINE, proc, log)
        probe = scene['bodies'][0]['name']

        def sim_time() -> float:
            s = _call(client, clients, GetEntityState, 'get_entity_state',
                      GetEntityState.Request(entity=probe)).state.header.stamp
            return s.sec + 1e-9 * s.nanosec

        def phase(label: str, calls: list, bodies_after: int, wait: float = 0.0) -> None:
            seen = len(diags)
            client.spin_until(lambda: len(diags) > seen, 'a diagnostics window',
                              STARTUP_DEADLINE, proc, log)
            lag0 = diags[-1]
            t0, w0 = sim_time(), time.perf_counter()
            trips = []
            for make in calls:
                srv_type, name, request = make()
                start = time.perf_counter()
                reply = _call(client, clients, srv_type, name, request)
                trips.append(time.perf_counter() - start)
                if reply.result.result != Result.RESULT_OK:
                    raise RuntimeError(f'{label}: {reply.result.error_message}')
            end = time.perf_counter() + wait   # (a phase without calls: time passing)
            client.spin_until(lambda: time.perf_counter() > end, label, wait + 10.0)
            t1, w1 = sim_time(), time.perf_counter()
            seen = len(diags)   # (a window that ends after the phase: its lag resets)
            client.spin_until(lambda: len(diags) > seen, 'a diagnostics window',
                              STARTUP_DEADLINE, proc, log)
            lag1 = diags[-1]
            ms = np.array(trips) * 1e3
            rows.append([label, str(len(calls)), str(bodies_after),
                         f'{np.median(ms):.1f}' if len(ms) else '-',
                         f'{ms.max():.1f}' if len(ms) else '-', f'{w1 - w0:.2f}',
                         f'{(t1 - t0) / (w1 - w0):.3f}', str(lag1[0] - lag0[0]),
                         f'{lag1[1] - lag0[1]:.3f}'])
            print('  ' + ' | '.join(rows[-1]), flush=True)

        def spawn_body(k: int):
            def make():
                request = SpawnEntity.Request(
                    name=f'crate{k}', resource_string=yaml.safe_dump(
                        {'mass': 1.0, 'inertia': {'box': [0.2, 0.2, 0.2]}}))
                request.initial_pose.pose.position.x = float(k)
                request.initial_pose.pose.position.y = 5.0
                request.initial_pose.pose.position.z = 100.0
                return SpawnEntity, 'spawn_entity', request
            return make

        def delete(name: str):
            return lambda: (DeleteEntity, 'delete_entity', DeleteEntity.Request(entity=name))

        def spawn_robot(k: int):
            def make():
                request = SpawnEntity.Request(name=f'arm{k}',
                                              uri=str(ROOT / 'config' / 'servo_arm.urdf'),
                                              allow_renaming=True)
                request.initial_pose.pose.position.x = float(k)
                request.initial_pose.pose.position.y = -5.0
                return SpawnEntity, 'spawn_entity', request
            return make

        base = len(scene['bodies'])
        phase('quiet', [], base, wait=quiet)
        phase(f'spawn {n_bodies} bodies', [spawn_body(k) for k in range(n_bodies)],
              base + n_bodies)
        phase(f'delete {n_bodies} bodies', [delete(f'crate{k}') for k in range(n_bodies)],
              base)
        phase(f'spawn {n_robots} arms (3 links)', [spawn_robot(k) for k in range(n_robots)],
              base + 3 * n_robots)
        phase(f'delete {n_robots} arms', [delete(f'arm{k}') for k in range(n_robots)], base)
    finally:
        client.close()
        code = stop(proc)
    if code != 0:
        print(f'  warning: the node exited with {code}; log {log}', flush=True)
    return rows


def main() -> None:
    """Run the phases; print and write the table."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[1])
    parser.add_argument('--quick', action='store_true', help='fewer spawns')
    args = parser.parse_args()
    n_bodies, n_robots, quiet = (30, 5, 2.0) if args.quick else (100, 20, 5.0)
    with tempfile.TemporaryDirectory() as tmp:
        rows = run(n_bodies, n_robots, quiet, Path(tmp))
    text = (f'{machine()}; {code_version()}\n\n'
            f'`./dev.sh python bench/node_spawning.py{" --quick" if args.quick else ""}`: '
            f'sim_node at physics {PARAMS["physics_rate"]:g} Hz, real-time factor '
            f'{PARAMS["real_time_factor"]:g}, 10 free boxes; calls back to back from '
            f'another process.\n\n' + markdown(HEADER, rows))
    OUT.mkdir(exist_ok=True)
    (OUT / 'node_spawning.md').write_text(text)
    print(text)


if __name__ == '__main__':
    main()
