"""ament_flake8 over the package, its tests, benchmarks and launch file (the ROS lint test)."""

from ament_flake8.main import main_with_errors
import pytest

PATHS = ['rigid_body_sim', 'test', 'bench', 'launch', 'setup.py']


@pytest.mark.flake8
@pytest.mark.linter
def test_flake8():
    rc, errors = main_with_errors(argv=PATHS)
    assert rc == 0, 'Found %d code style errors / warnings:\n' % len(errors) + '\n'.join(errors)
