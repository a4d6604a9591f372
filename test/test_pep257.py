"""ament_pep257 over the package, its tests and benchmarks (the ROS lint test)."""

from ament_pep257.main import main
import pytest


@pytest.mark.linter
@pytest.mark.pep257
def test_pep257():
    rc = main(argv=['rigid_body_sim', 'test', 'bench', 'setup.py'])
    assert rc == 0, 'Found code style errors / warnings'
