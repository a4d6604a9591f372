"""
Start the simulator node in a full ROS 2 installation (launch_ros is not in the PyPI wheels).

    ros2 launch rigid_body_sim sim.launch.py scene:=/path/to/robot.urdf
    ros2 launch rigid_body_sim sim.launch.py params_file:=/path/to/params.yaml

Launch arguments: ``scene``, the scene file (default: the installed
``config/default_scene.yaml``), and ``params_file``, a ROS parameters file for the node
(default: the installed ``config/sim_node_params.yaml``, every parameter at its default).
The params file is applied first and ``scene`` after it, so the launch argument wins over
a ``scene`` the file sets (the installed one sets ``scene: ''``).

Importing this file does nothing but import; ``ros2 launch`` calls
:func:`generate_launch_description`.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def generate_launch_description() -> LaunchDescription:
    """Return the node ``rigid_body_sim`` and its launch arguments ``scene``, ``params_file``."""
    config = os.path.join(get_package_share_directory('rigid_body_sim'), 'config')
    return LaunchDescription([
        DeclareLaunchArgument(
            'scene', default_value=os.path.join(config, 'default_scene.yaml'),
            description='scene file: YAML, or a URDF or xacro robot'),
        DeclareLaunchArgument(
            'params_file', default_value=os.path.join(config, 'sim_node_params.yaml'),
            description='ROS parameters file of the node (its scene is overridden by scene)'),
        Node(
            package='rigid_body_sim',
            executable='sim_node',
            name='rigid_body_sim',
            parameters=[LaunchConfiguration('params_file'),
                        {'scene': LaunchConfiguration('scene')}],
            output='screen',
        ),
    ])
