"""
SIGINT and SIGTERM while the node or the recorder is still starting end it cleanly.

The console scripts install their handlers before importing rclpy and loading
the kernels, and say so on stderr (``<tool>: starting``). Each test waits for
that line (an event, with a deadline), signals at once, while the tool is still
importing and building (about 0.7 s with cached kernels; about 90 s on a first
start that compiles them), and expects exit code 0, no traceback, and the tool
saying it stopped while starting. Before the handlers, a SIGINT raised
KeyboardInterrupt with a traceback (exit -2) and a SIGTERM killed the node
(exit -15).
"""

import selectors
import signal
import subprocess
import time

import pytest
from ros_harness import DEADLINE, executable, random_domain, ros_env


def _start_and_signal(args: list, name: str, sig: int) -> tuple:
    proc = subprocess.Popen(args, env=ros_env(random_domain()), stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        selector = selectors.DefaultSelector()
        selector.register(proc.stderr, selectors.EVENT_READ)
        deadline = time.monotonic() + DEADLINE
        first = ''
        while time.monotonic() < deadline and not first:
            if selector.select(timeout=deadline - time.monotonic()):
                first = proc.stderr.readline()
        assert first.strip() == f'{name}: starting', first
        proc.send_signal(sig)
        rest = proc.communicate(timeout=DEADLINE)[1]
        return proc.returncode, first + rest
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM])
def test_the_node_signalled_while_starting_exits_cleanly(sig):
    code, err = _start_and_signal([str(executable('sim_node'))], 'sim_node', sig)
    assert code == 0, err
    assert 'Traceback' not in err
    assert 'sim_node: stopped while starting' in err


@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM])
def test_the_recorder_signalled_while_starting_exits_cleanly(sig, tmp_path):
    code, err = _start_and_signal([str(executable('record')), '-o', str(tmp_path / 'bag')],
                                  'record', sig)
    assert code == 0, err
    assert 'Traceback' not in err
    assert 'record: stopped while starting' in err
