"""ament_pep257 over the package, its tests, benchmarks and launch file (the ROS lint test)."""

from ament_pep257.main import main
import pytest


@pytest.mark.linter
@pytest.mark.pep257
def test_pep257():
    rc = main(argv=['rigid_body_sim', 'test', 'bench', 'launch', 'setup.py'])
    assert rc == 0, 'Found code style errors / warnings'
