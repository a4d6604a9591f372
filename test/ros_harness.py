"""
Helpers for tests through real DDS: the node in its own process, a client in this one.

Each test gets its own random ``ROS_DOMAIN_ID`` and localhost-only discovery,
so tests are isolated from each other and from anything else on the machine; the id is
held by a lock file while the test runs, so that two suites run at once on one machine
(two CI jobs, a developer's run beside CI) never draw the same one.
Every wait is on an event (a message, a service reply, a process exit) with a
deadline, never a fixed sleep.
"""

from __future__ import annotations

import fcntl
import os
from pathlib import Path
import random
import signal
import subprocess
import sys
import tempfile
import time
from typing import Callable, Optional

import pytest

rclpy = pytest.importorskip('rclpy', reason='rclpy not installed: run ./dev.sh test')
packages = pytest.importorskip('ament_index_python.packages')
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.qos import QoSProfile  # noqa: E402

CONFIG = Path(__file__).resolve().parents[1] / 'config'
#: s: how long any single wait may take before the test fails.
DEADLINE = 30.0


def executable(name: str) -> Path:
    """Return the installed console script ``name``, where ``ros2 run`` looks."""
    try:
        prefix = Path(packages.get_package_prefix('rigid_body_sim'))
    except packages.PackageNotFoundError:
        pytest.skip('rigid_body_sim is not built: run ./dev.sh test (colcon build)')
    return prefix / 'lib' / 'rigid_body_sim' / name


class NodeProcess:
    """The simulator node, ``sim_node``, running in a child process."""

    def __init__(self, domain: int, params: dict, namespace: Optional[str] = None,
                 log_path: Optional[Path] = None, ros_args: tuple = (),
                 program: Optional[list] = None) -> None:
        args = [*(program or [str(executable('sim_node'))]), '--ros-args', *ros_args]
        for key, value in params.items():
            text = str(value).lower() if isinstance(value, bool) else str(value)
            args += ['-p', f'{key}:={text}']
        if namespace:
            args += ['-r', f'__ns:={namespace}']
        self.log_path = log_path
        self._log = open(log_path, 'w+') if log_path else subprocess.DEVNULL
        self.env = ros_env(domain)
        self.proc = subprocess.Popen(args, env=self.env, stdout=self._log,
                                     stderr=subprocess.STDOUT, start_new_session=True)

    def log(self) -> str:
        """Return what the node printed so far."""
        if not self.log_path:
            return ''
        self._log.flush()
        return Path(self.log_path).read_text()

    def stop(self, sig: int = signal.SIGTERM, timeout: float = DEADLINE) -> int:
        """Send ``sig`` and wait for the exit code (kill after the deadline)."""
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        return self.proc.returncode

    def close(self) -> None:
        """
        Stop the process if it still runs (SIGTERM, SIGKILL after 10 s) and close its log.

        A clean exit lets the node's DDS participant say goodbye: a peer that
        vanishes (SIGKILL) leaves its shared-memory ports behind, and Fast DDS
        then crashed the test process while destroying the client's participant
        (SIGSEGV in ``destroy_node``, seen once in CI).
        """
        self.stop(signal.SIGTERM, timeout=10.0)
        if self.log_path:
            self._log.close()


def ros_env(domain: int) -> dict:
    """Return this process's environment with the test's DDS isolation."""
    env = dict(os.environ)
    env['ROS_DOMAIN_ID'] = str(domain)
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    env.pop('ROS_STATIC_PEERS', None)
    env['PYTHONUNBUFFERED'] = '1'
    return env


class Client:
    """A client node in the test process, on the test's domain."""

    def __init__(self, domain: int) -> None:
        os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
        self.context = rclpy.context.Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.node = Node('test_client', context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.received: dict = {}

    def subscribe(self, msg_type, topic: str, depth: int = 1000) -> list:
        """Keep every message on ``topic`` in the returned list (reliable, deep queue)."""
        out = self.received.setdefault(topic, [])
        self.node.create_subscription(msg_type, topic, out.append, QoSProfile(depth=depth))
        return out

    def wait_for(self, condition: Callable[[], bool], what: str,
                 timeout: float = DEADLINE, node: Optional[NodeProcess] = None) -> None:
        """Spin until ``condition()`` holds; fail naming ``what`` after ``timeout``."""
        end = time.monotonic() + timeout
        while not condition():
            if node is not None and node.proc.poll() is not None:
                pytest.fail(f'the node exited ({node.proc.returncode}) while waiting for '
                            f'{what}:\n{node.log()}')
            if time.monotonic() > end:
                pytest.fail(f'no {what} within {timeout} s'
                            + (f'; node log:\n{node.log()}' if node else ''))
            self.executor.spin_once(timeout_sec=0.05)

    def call(self, srv_type, name: str, request, timeout: float = DEADLINE,
             node: Optional[NodeProcess] = None):
        """Call a service (waiting for it to appear) and return the response."""
        client = self._clients.get(name) if hasattr(self, '_clients') else None
        if client is None:
            self._clients = getattr(self, '_clients', {})
            client = self._clients[name] = self.node.create_client(srv_type, name)
        self.wait_for(client.service_is_ready, f'service {name}', timeout, node)
        future = client.call_async(request)
        self.wait_for(future.done, f'reply from {name}', timeout, node)
        return future.result()

    def set_parameter(self, node_name: str, name: str, value, node=None):
        """Set one double or string parameter of ``node_name``; return its SetParametersResult."""
        from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
        from rcl_interfaces.srv import SetParameters
        if isinstance(value, float):
            pv = ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=value)
        else:
            pv = ParameterValue(type=ParameterType.PARAMETER_STRING, string_value=value)
        request = SetParameters.Request(parameters=[Parameter(name=name, value=pv)])
        return self.call(SetParameters, f'{node_name}/set_parameters', request,
                         node=node).results[0]

    def close(self) -> None:
        """Destroy the node and shut the context down."""
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


#: The domain ids this process holds: id -> its lock file, open (released on close or exit).
_HELD: dict = {}


def random_domain() -> int:
    """
    Return a random DDS domain id that no other test on this machine holds, and hold it.

    Fast DDS allows 0 to 232; these draw from 11 to 200. Each id is held by an exclusive
    ``flock`` on a file of its own in the temporary directory, until
    :func:`release_domain` or this process's exit (the kernel drops the lock then, so a
    killed run leaves none behind). Two suites at once on one machine each drew from the
    same 190 ids, and met on one (a node's messages reaching the other suite's test).
    """
    directory = Path(tempfile.gettempdir()) / 'rigid_body_sim-dds-domains'
    directory.mkdir(exist_ok=True)
    ids = list(range(11, 201))
    random.SystemRandom().shuffle(ids)
    for domain in ids:
        lock = open(directory / f'{domain}.lock', 'w')
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:   # (held by another test, here or in another process)
            lock.close()
            continue
        _HELD[domain] = lock
        return domain
    raise RuntimeError(f'every DDS domain id from 11 to 200 is held ({directory})')


def release_domain(domain: int) -> None:
    """Let other tests draw ``domain`` again (:func:`random_domain`)."""
    lock = _HELD.pop(domain, None)
    if lock is not None:
        lock.close()


def ros_session(tmp_path):
    """
    Start nodes and a client on a fresh random domain; stop them all afterwards.

    A generator for the ``ros`` fixture (conftest.py): yields an object with
    ``start(params, namespace=None, ros_args=(), program=None)`` -> NodeProcess (``program``:
    the command to run instead of ``sim_node``) and ``client`` (a :class:`Client`).
    """
    domain = random_domain()

    class Ros:
        nodes: list = []
        client = Client(domain)

        def start(self, params: dict, namespace: Optional[str] = None,
                  ros_args: tuple = (), program: Optional[list] = None) -> NodeProcess:
            log = tmp_path / f'node{len(self.nodes)}.log'
            node = NodeProcess(domain, params, namespace, log, ros_args, program)
            self.nodes.append(node)
            return node

    r = Ros()
    r.nodes = []
    try:
        yield r
    finally:
        # The client's participant goes first, while its peers are alive and well
        # (see NodeProcess.close), then the nodes, each with a clean exit.
        r.client.close()
        for node in r.nodes:
            node.close()
        release_domain(domain)


def python() -> str:
    """Return the interpreter running the tests (the venv's)."""
    return sys.executable
