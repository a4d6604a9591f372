"""
Console-script entry points of the long-running tools.

They install the signal handlers (:mod:`.stopping`) before importing rclpy and
the kernels, so that a SIGINT or SIGTERM during start-up ends the tool with exit
code 0 and no traceback.
"""

from __future__ import annotations

import sys

from .stopping import run


def sim_node() -> int:
    """Run the simulator node (``ros2 run rigid_body_sim sim_node``)."""
    def main(stop):
        from . import node
        return node.main(stop=stop)
    return run('sim_node', main)


def record() -> int:
    """Run the live recorder (``ros2 run rigid_body_sim record``)."""
    def main(stop):
        from . import record as recorder
        return recorder.main(stop=stop)
    return run('record', main)


if __name__ == '__main__':
    sys.exit(sim_node())
