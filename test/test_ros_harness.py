"""
The DDS tests' isolation (``ros_harness``): each test's domain id held machine-wide.

Two suites at once on one machine (two CI jobs, a developer's run beside CI) drew their
ids from the same 190 and met on one: a node's messages reached the other suite's test.
An id drawn is held by a lock that other processes see, until released.
"""

import subprocess
import sys

import pytest

harness = pytest.importorskip('ros_harness')

# A second process drawing: it must never get an id this one holds (it prints its id).
DRAW = ('import sys; sys.path.insert(0, {path!r}); import ros_harness; '
        'print(ros_harness.random_domain())')


def _drawn_elsewhere(count):
    path = str(harness.Path(harness.__file__).parent)
    ids = []
    for _ in range(count):
        out = subprocess.run([sys.executable, '-c', DRAW.format(path=path)],
                             capture_output=True, text=True, timeout=60, check=True)
        ids.append(int(out.stdout.split()[-1]))
    return ids


def test_an_id_held_here_is_never_drawn_by_another_process_until_released():
    held = [harness.random_domain() for _ in range(150)]   # (150 of the 190)
    try:
        assert len(set(held)) == 150 and all(11 <= d <= 200 for d in held)
        free = sorted(set(range(11, 201)) - set(held))
        assert all(d in free for d in _drawn_elsewhere(4))
        harness.release_domain(held[0])
        free.append(held[0])
        assert all(d in free for d in _drawn_elsewhere(4))
    finally:
        for d in held:
            harness.release_domain(d)
