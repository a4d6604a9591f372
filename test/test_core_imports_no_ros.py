"""The physics core imports and runs without ROS (rclpy, rosidl) installed."""

import subprocess
import sys
import textwrap

SCRIPT = textwrap.dedent("""
    import importlib.abc
    import sys

    class NoRos(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path=None, target=None):
            if name.split('.')[0].startswith(('rclpy', 'rosidl', 'rclpy', 'geometry_msgs')):
                raise ImportError('ROS is blocked in this test: ' + name)
            return None

    sys.meta_path.insert(0, NoRos())
    from rigid_body_sim.core import Constraint, Gravity, RigidBody, Simulation
    from rigid_body_sim.scene import load_scene
    sim = Simulation([RigidBody('b', 1.0, [1.0, 2.0, 3.0], angular_velocity_body=[0, 1, 0]),
                      RigidBody('c', 1.0, [1.0, 1.0, 1.0], position_world=[1, 0, 0])],
                     [Gravity()], 'rkmk4', 1e-3,
                     [Constraint('j', 'ball', 'c', None, anchor_world=[0, 0, 0])])
    sim.step(10)
    assert sim.time > 0.0
    assert not [m for m in sys.modules if m.startswith(('rclpy', 'rosidl'))]
    print('ok')
""")


def test_core_runs_with_ros_blocked():
    out = subprocess.run([sys.executable, '-c', SCRIPT], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == 'ok'
