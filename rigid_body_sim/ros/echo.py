"""
Print the state of a body as the node publishes it (a small client for newcomers).

Usage: ``echo_body [BODY] [--node /rigid_body_sim] [--every N] [--count N]``.
Subscribes to ``<node>/body_states`` and prints the body's position,
orientation (x, y, z, w), linear and angular velocity (world frame) with the
simulation time of the message.
"""

from __future__ import annotations

import argparse
import signal
import sys
from typing import Optional, Sequence

import rclpy
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions
from rigid_body_sim_interfaces.msg import BodyStates

from .conversions import body_states_arrays, time_seconds


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog='echo_body', description=__doc__.splitlines()[1])
    p.add_argument('body', nargs='?', help='body name (default: the first body)')
    p.add_argument('--node', default='/rigid_body_sim',
                   help='fully qualified name of the simulator node (default /rigid_body_sim)')
    p.add_argument('--every', type=int, default=10,
                   help='print every N-th message (default 10: 10 lines/s at 100 Hz)')
    p.add_argument('--count', type=int, default=0,
                   help='stop after printing N lines (default 0: until Ctrl-C)')
    return p


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Print a body's state until Ctrl-C (or --count lines); returns the exit code."""
    args = _parser().parse_args(rclpy.utilities.remove_ros_args(
        sys.argv if argv is None else ['echo_body', *argv])[1:])
    rclpy.init(args=None if argv is None else list(argv),
               signal_handler_options=SignalHandlerOptions.NO)
    node = Node('echo_body')
    state = {'seen': 0, 'printed': 0, 'running': True}
    topic = args.node.rstrip('/') + '/body_states'

    def on_states(msg: BodyStates) -> None:
        bodies = body_states_arrays(msg)
        name = args.body or (msg.names[0] if msg.names else None)
        if name not in bodies:
            node.get_logger().error(f'no body {name!r} in {topic}; bodies: {list(msg.names)}',
                                    throttle_duration_sec=5.0)
            return
        state['seen'] += 1
        if (state['seen'] - 1) % max(args.every, 1):
            return
        p, q, v, w = bodies[name]
        print(f't={time_seconds(msg.header.stamp):9.3f} s  {name}  '
              f'p=[{p[0]:+.4f} {p[1]:+.4f} {p[2]:+.4f}] m  '
              f'q=[{q[0]:+.4f} {q[1]:+.4f} {q[2]:+.4f} {q[3]:+.4f}]  '
              f'v=[{v[0]:+.3f} {v[1]:+.3f} {v[2]:+.3f}] m/s  '
              f'w=[{w[0]:+.3f} {w[1]:+.3f} {w[2]:+.3f}] rad/s', flush=True)
        state['printed'] += 1
        if args.count and state['printed'] >= args.count:
            state['running'] = False

    node.create_subscription(BodyStates, topic, on_states, 10)
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: state.update(running=False))
    print(f'listening on {topic} (Ctrl-C to stop)', flush=True)
    try:
        while state['running'] and rclpy.ok():
            rclpy.spin_once(node, timeout_sec=0.1)
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
