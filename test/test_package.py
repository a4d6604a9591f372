"""The installed layout is the one `ros2 run` and `ros2 launch` expect."""

import os
from pathlib import Path

import pytest

packages = pytest.importorskip('ament_index_python.packages',
                               reason='ament_index_python not installed: run ./dev.sh test')


def _prefix() -> Path:
    try:
        return Path(packages.get_package_prefix('rigid_body_sim'))
    except packages.PackageNotFoundError:
        pytest.skip('rigid_body_sim is not built: run ./dev.sh test (colcon build)')


def test_console_script_where_ros2_run_looks():
    script = _prefix() / 'lib' / 'rigid_body_sim' / 'rigid_body_sim_run'
    assert script.is_file()
    assert os.access(script, os.X_OK)


def test_share_has_package_xml_and_scenes():
    share = Path(packages.get_package_share_directory('rigid_body_sim'))
    assert (share / 'package.xml').is_file()
    scenes = sorted(p.name for p in (share / 'config').glob('*.yaml'))
    repo_scenes = sorted(p.name for p in (Path(__file__).parents[1] / 'config').glob('*.yaml'))
    assert scenes == repo_scenes


def test_share_has_the_launch_files():
    share = Path(packages.get_package_share_directory('rigid_body_sim'))
    installed = sorted(p.name for p in (share / 'launch').glob('*.py'))
    repo = sorted(p.name for p in (Path(__file__).parents[1] / 'launch').glob('*.py'))
    assert installed == repo == ['sim.launch.py']
