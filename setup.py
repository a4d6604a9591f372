"""Install rigid_body_sim as an ament_python package (colcon build or pip)."""

from glob import glob

from setuptools import find_packages, setup

package_name = 'rigid_body_sim'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(include=[package_name, package_name + '.*']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config', glob('config/*.yaml') + glob('config/*.xml')
         + glob('config/*.urdf')),
        ('share/' + package_name + '/launch', glob('launch/*.py')),
    ],
    install_requires=['setuptools', 'numpy', 'scipy', 'numba', 'PyYAML', 'rosbags', 'mcap',
                      'matplotlib', 'urdfdom-py', 'xacro', 'lxml'],
    extras_require={'test': ['pytest', 'mcap-ros2-support']},
    zip_safe=True,
    maintainer='rigid_body_sim developers',
    maintainer_email='rigid-body-sim@example.com',
    description='Rigid-body simulation with exact constraints as a ROS 2 service.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'rigid_body_sim_run = rigid_body_sim.cli:main',
            'sim_node = rigid_body_sim.ros.entry:sim_node',
            'echo_body = rigid_body_sim.ros.echo:main',
            'experiment = rigid_body_sim.ros.experiment:main',
            'record = rigid_body_sim.ros.entry:record',
            'plot = rigid_body_sim.ros.plot:main',
        ],
    },
)
