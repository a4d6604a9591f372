"""ament_flake8 over the package, its tests, benchmarks and launch file (the ROS lint test)."""

import subprocess
import sys

import pytest

PATHS = ['rigid_body_sim', 'test', 'bench', 'launch', 'setup.py']
#: ament_flake8 in a process of its own: its checks run in a pool of forked workers, and
#: a fork of this process after DDS tests (their middleware threads) can crash a worker
#: (seen: a segmentation fault in one, the pool then waiting for ever).
RUN = ('import sys; from ament_flake8.main import main_with_errors; '
       'rc, errors = main_with_errors(argv=sys.argv[1:]); '
       "print('\\n'.join(errors)); sys.exit(rc)")


@pytest.mark.flake8
@pytest.mark.linter
def test_flake8():
    done = subprocess.run([sys.executable, '-c', RUN, *PATHS], capture_output=True, text=True,
                          timeout=600)
    assert done.returncode == 0, f'code style errors / warnings:\n{done.stdout}{done.stderr}'
