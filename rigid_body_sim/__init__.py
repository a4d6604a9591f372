"""rigid_body_sim: rigid-body simulation as a ROS 2 service, over a ROS-free core."""

__version__ = '0.1.0'
