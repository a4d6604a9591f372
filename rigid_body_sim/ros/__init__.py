"""The ROS 2 adapter over the core: the node, its message conversions and its tools."""
