"""
Record a running simulator node's topics into a rosbag2 bag (MCAP storage) until Ctrl-C.

Usage: ``record -o OUT [--node /rigid_body_sim] [--topics T ...] [--duration S]``.

By default it records every topic the node publishes (looked up in the ROS
graph from the node's fully qualified name: its outputs, ``/clock``,
``/diagnostics``, ``/rosout``, ``/parameter_events``) and ``/clock``; it looks
again every second of wall time, so topics that appear later (the reaction
wrench of a constraint added with ``~/add_constraint``) are recorded from then
on. ``--topics`` records exactly the topics named (``~/x`` is ``<node>/x``),
each once it appears in the graph. Subscriptions are reliable with a queue of
1000 messages (best effort where a publisher offers only that; transient
local, as rosbag2 does, where all publishers latch).

Bag time stamps are when each message arrived here (wall clock, ns since the
epoch: DDS's reception time stamp), as ``ros2 bag record`` does by default;
the messages are stored unchanged, so their header stamps stay simulation
time. The CDR bytes are written as DDS delivered them (the exact serialization
plus at most 3 bytes of padding, which readers accept); a message that
``rosbags`` would refuse (more slack at the end, as rclpy's own
``serialize_message`` leaves with empty float64 arrays) is written
re-serialized canonically instead, so every message reads back.

SIGINT (Ctrl-C), SIGTERM or the end of ``--duration`` closes the bag cleanly
(MCAP footer and ``metadata.yaml`` written), prints a summary and exits with 0
(2: a bad command line or an existing OUT). The summary gives the messages
written per topic and the drops: messages the publisher sent between the first
and the last one recorded that never reached the bag, counted from gaps in the
publisher's sequence numbers, whether DDS lost them on the way or this process
fell behind and its queue overflowed. That count is exact while a topic has
one publisher (``?`` when it has several). Fast DDS's own "message lost"
events see only the former (measured: a full queue here drops silently) and
may include messages lost before the first one arrived; the summary adds
their count when non-zero.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
import importlib
from pathlib import Path
import sys
import time
from typing import Any, Optional, Sequence

import rclpy
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node, NodeNameNonExistentError
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from rclpy.signals import SignalHandlerOptions
from rosbags.serde import SerdeError

from .bag import BagWriter, to_cdr, typestore
from .stopping import Stop, StopRequested

#: Messages each subscription queues before the oldest is dropped (counted).
DEPTH = 1000
#: s of wall time between looks at the ROS graph for new topics.
DISCOVERY_PERIOD = 1.0
#: s of wall time between takes of what arrived: the messages of 10 ms are taken in one go
#: (their bag time is when DDS received them, so waiting costs no accuracy).
POLL_PERIOD = 0.01


@dataclass
class Topic:
    """One recorded topic: what was written and what was lost."""

    name: str
    msgtype: str
    cls: Any
    subscription: Any = None
    messages: int = 0
    reserialized: int = 0   # written canonically (rosbags refused the bytes as received)
    unwritable: int = 0     # neither the bytes received nor rclpy's message could be written
    gaps: int = 0           # messages missing between consecutive sequence numbers
    lost: int = 0           # messages Fast DDS reported lost (message_lost events)
    last_sequence: Optional[int] = None
    single_publisher: bool = True   # gaps are drops only while one publisher sends
    sequence_numbers: bool = True   # the middleware reports publication sequence numbers

    def drops(self) -> Optional[int]:
        """Return the messages dropped, or None when they cannot be counted."""
        if self.single_publisher and self.sequence_numbers:
            return self.gaps
        return None


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog='record', description=__doc__.splitlines()[1])
    p.add_argument('-o', '--output', required=True, metavar='OUT',
                   help='bag folder to create (must not exist)')
    p.add_argument('--node', default='/rigid_body_sim',
                   help='fully qualified name of the simulator node (default /rigid_body_sim)')
    p.add_argument('--topics', nargs='+', metavar='T',
                   help='record exactly these topics (~/x: <node>/x); default: every topic '
                        'the node publishes, and /clock')
    p.add_argument('--duration', type=float, default=0.0, metavar='S',
                   help='stop after S seconds of wall time from the start (default 0: until '
                        'Ctrl-C)')
    return p


def _message_class(msgtype: str) -> Any:
    """Return the rclpy class of ``pkg/msg/Name``."""
    package, kind, name = msgtype.split('/')
    return getattr(importlib.import_module(f'{package}.{kind}'), name)


def readable_cdr(raw: bytes, msgtype: str, cls: Any) -> bytes:
    """
    Return ``raw`` if rosbags reads it as ``msgtype``, else the canonical CDR of its message.

    rosbags refuses CDR with more than 3 bytes after the last field; the
    canonical bytes come from rclpy's message (``cls``) re-serialized by
    :func:`.bag.to_cdr`. Raises when neither reads back.
    """
    store = typestore()
    try:
        store.deserialize_cdr(raw, msgtype)
        return raw
    except SerdeError:
        pass
    data = to_cdr(deserialize_message(raw, cls), msgtype)
    store.deserialize_cdr(data, msgtype)
    return data


class Recorder:
    """
    Subscribe to topics as they appear and write every message into a bag.

    Parameters
    ----------
    node : Node
        The recorder's own node (its subscriptions are made on it).
    bag : BagWriter
        The open bag.
    target : str
        Fully qualified name of the node whose topics are recorded.
    topics : list of str, optional
        Record exactly these (absolute names); None: all the target publishes, and /clock.

    """

    def __init__(self, node: Node, bag: BagWriter, target: str,
                 topics: Optional[list] = None) -> None:
        self.node = node
        self.bag = bag
        self.target = target
        namespace, _, self._target_name = target.rpartition('/')
        self._target_namespace = namespace or '/'
        self.wanted = topics
        self.topics: dict = {}
        self._skipped: set = set()
        self._store = typestore()
        self.recording = True
        self._target_seen = False

    # -- discovery ------------------------------------------------------------------------

    def discover(self) -> None:
        """Subscribe to wanted topics that appeared; note which have one publisher."""
        graph = dict(self.node.get_topic_names_and_types())
        if self.wanted is None:
            try:
                found = dict(self.node.get_publisher_names_and_types_by_node(
                    self._target_name, self._target_namespace))
                if not self._target_seen:
                    self._target_seen = True
                    print(f'found node {self.target}', flush=True)
            except NodeNameNonExistentError:
                found = {}
            if '/clock' in graph:
                found.setdefault('/clock', graph['/clock'])
        else:
            found = {name: graph[name] for name in self.wanted if name in graph}
        for name, types in sorted(found.items()):
            if name not in self.topics and name not in self._skipped:
                self._subscribe(name, types)
        for topic in self.topics.values():
            topic.single_publisher = topic.single_publisher and \
                self._publishers(topic.name) <= 1

    def _publishers(self, name: str) -> int:
        """
        Return how many publishers, other than this node's own, the graph has for a topic.

        Counted by endpoint GID: while discovery settles the graph can list one
        publisher twice, which must not turn a topic's drop count into '?'.
        """
        count = self.node.count_publishers(name)
        if count <= 1:
            return count
        me = (self.node.get_name(), self.node.get_namespace())
        return len({bytes(i.endpoint_gid) for i in self.node.get_publishers_info_by_topic(name)
                    if (i.node_name, i.node_namespace) != me})

    def _qos(self, name: str) -> QoSProfile:
        """Reliable and volatile, unless the publishers offer only best effort / all latch."""
        me = (self.node.get_name(), self.node.get_namespace())
        offered = [i.qos_profile for i in self.node.get_publishers_info_by_topic(name)
                   if (i.node_name, i.node_namespace) != me]
        best_effort = any(q.reliability == ReliabilityPolicy.BEST_EFFORT for q in offered)
        latched = bool(offered) and all(
            q.durability == DurabilityPolicy.TRANSIENT_LOCAL for q in offered)
        return QoSProfile(
            depth=DEPTH,
            reliability=ReliabilityPolicy.BEST_EFFORT if best_effort
            else ReliabilityPolicy.RELIABLE,
            durability=DurabilityPolicy.TRANSIENT_LOCAL if latched
            else DurabilityPolicy.VOLATILE)

    def _subscribe(self, name: str, types: list) -> None:
        msgtype = types[0]
        if len(types) > 1:
            print(f'warning: {name} has several types {types}; recording {msgtype}',
                  file=sys.stderr, flush=True)
        try:
            cls = _message_class(msgtype)
        except (ImportError, AttributeError, ValueError) as exc:
            return self._skip(name, f'type {msgtype} is not installed here ({exc})')
        if msgtype not in self._store.types:
            return self._skip(name, f"type {msgtype} is unknown to the bag's type store")
        topic = Topic(name, msgtype, cls)
        self.bag.add_topic(name, msgtype)
        events = SubscriptionEventCallbacks(
            message_lost=lambda info, t=topic: self._on_lost(t, info),
            use_default_callbacks=False)
        topic.subscription = self.node.create_subscription(
            cls, name, lambda raw, info, t=topic: self._on_message(t, raw, info),
            self._qos(name), raw=True, event_callbacks=events)
        self.topics[name] = topic
        print(f'recording {name} [{msgtype}]', flush=True)

    def _skip(self, name: str, why: str) -> None:
        self._skipped.add(name)
        print(f'warning: not recording {name}: {why}', file=sys.stderr, flush=True)

    # -- messages -------------------------------------------------------------------------

    def drain(self) -> int:
        """
        Write every message waiting in the subscriptions' queues; return how many.

        Taken directly, as rclpy's executors and ``wait_for_message`` do: an
        executor takes one message per subscription per wait (about 0.1 ms of
        Python each), which is most of what recording costs. At most DEPTH
        messages per topic, so one busy topic cannot hold up the loop.
        """
        taken = 0
        for topic in list(self.topics.values()):
            sub = topic.subscription
            with sub.handle:
                for _ in range(DEPTH):
                    if not self.recording:
                        return taken
                    got = sub.handle.take_message(sub.msg_type, True)
                    if got is None:
                        break
                    self._on_message(topic, *got)
                    taken += 1
        return taken

    def _on_message(self, topic: Topic, raw: bytes, info: dict) -> None:
        if not self.recording:
            return
        stamp = info.get('received_timestamp') or time.time_ns()
        self._count_gap(topic, info.get('publication_sequence_number'))
        data = self._readable(topic, raw)
        if data is None:
            topic.unwritable += 1
            return
        self.bag.write(topic.name, stamp, data, topic.msgtype)
        topic.messages += 1
        if topic.messages == 1:
            print(f'first message on {topic.name}', flush=True)

    def _readable(self, topic: Topic, raw: bytes) -> Optional[bytes]:
        """Return CDR bytes of the message that rosbags reads back (None: none could be)."""
        try:
            data = readable_cdr(raw, topic.msgtype, topic.cls)
        except Exception as exc:  # noqa: B902 - count it, say why once, record on
            if not topic.unwritable:
                print(f'warning: {topic.name}: a message cannot be written readably ({exc!r}); '
                      f'skipped (counted)', file=sys.stderr, flush=True)
            return None
        if data is not raw:
            topic.reserialized += 1
        return data

    def _count_gap(self, topic: Topic, sequence: Optional[int]) -> None:
        """Count messages missing between this publisher's consecutive sequence numbers."""
        if not sequence:
            topic.sequence_numbers = False
            return
        last = topic.last_sequence
        if last is not None and sequence > last + 1:
            topic.gaps += sequence - last - 1
        # (A smaller number: a new publisher, e.g. the node restarted; count from there.)
        topic.last_sequence = sequence

    def _on_lost(self, topic: Topic, info: Any) -> None:
        topic.lost += info.total_count_change

    # -- the report -----------------------------------------------------------------------

    def summary(self, seconds: float) -> str:
        """Return the closing report: messages and drops per topic, totals, the bag."""
        topics = sorted(self.topics.values(), key=lambda t: t.name)
        total = sum(t.messages for t in topics)
        drops = [t.drops() for t in topics]
        dropped = sum(d for d in drops if d)
        unknown = sum(d is None for d in drops)
        lost = sum(t.lost for t in topics)
        lines = [f'recorded {total} messages on {len(topics)} topics in {seconds:.1f} s '
                 f'into {self.bag.path}',
                 f'  {"messages":>9}  {"dropped":>7}  topic']
        for t, d in zip(topics, drops):
            lines.append(f'  {t.messages:>9}  {"?" if d is None else d:>7}  {t.name}')
        lines.append(f'  {total:>9}  {dropped:>7}  total')
        if dropped or unknown:
            lines.append(f'dropped: {dropped} messages'
                         + (f'; ? on {unknown} topics with several publishers (cannot be '
                            f'counted)' if unknown else ''))
        else:
            lines.append('dropped: none')
        if lost:
            lines.append(f'DDS reported {lost} messages lost on the way')
        for t in topics:
            if t.reserialized:
                lines.append(f'{t.name}: {t.reserialized} messages re-serialized '
                             f'(rosbags refused the bytes as received)')
            if t.unwritable:
                lines.append(f'{t.name}: {t.unwritable} messages could not be written')
        missing = [name for name in self.wanted or () if name not in self.topics]
        if missing:
            lines.append('never appeared in the graph: ' + ' '.join(missing))
        lines.append(f'bag: {self.bag.path}')
        return '\n'.join(lines)


def _resolve(name: str, target: str) -> str:
    """Return a topic name from the command line as an absolute name (``~/x``: ``<node>/x``)."""
    if name.startswith('~'):
        return target + '/' + name[1:].lstrip('/')
    return '/' + name.lstrip('/')


def main(argv: Optional[Sequence[str]] = None, stop: Optional[Stop] = None) -> int:
    """
    Record until SIGINT, SIGTERM or --duration; returns the exit code.

    ``stop``: the signal handling the console script installed before importing
    this module (:mod:`.entry`); without it, it is installed here.
    """
    stop = stop if stop is not None else Stop().install()
    state = {'running': True}
    node = None
    try:
        args = _parser().parse_args(rclpy.utilities.remove_ros_args(
            sys.argv if argv is None else ['record', *argv])[1:])
        out = Path(args.output)
        if out.exists():
            print(f'record: error: {out} exists already; choose a new bag folder',
                  file=sys.stderr)
            return 2
        target = '/' + args.node.strip('/')
        topics = None if args.topics is None else [_resolve(t, target) for t in args.topics]
        rclpy.init(args=None if argv is None else list(argv),
                   signal_handler_options=SignalHandlerOptions.NO)
        node = Node('rigid_body_sim_record', enable_rosout=False,
                    start_parameter_services=False)
        stop.on_stop(lambda: state.update(running=False))   # from here on: stop the loop
    except StopRequested:
        print('record: stopped while starting', file=sys.stderr, flush=True)
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
        return 0
    executor = SingleThreadedExecutor(context=node.context)
    executor.add_node(node)
    try:
        try:
            bag = BagWriter(out, custom_data={
                'recorded_by': 'rigid_body_sim record', 'node': target,
                'topics': 'all the node publishes, and /clock' if topics is None
                else ' '.join(topics),
                'bag_time': 'receive time (wall clock); header stamps are simulation time'})
        except (FileExistsError, OSError) as exc:
            print(f'record: error: {exc}', file=sys.stderr)
            return 2
        with bag:
            recorder = Recorder(node, bag, target, topics)
            print(f'recording into {out} (Ctrl-C to stop)', flush=True)
            if topics is None:
                print(f'waiting for node {target}', flush=True)
            start = time.monotonic()
            end = start + args.duration if args.duration > 0 else float('inf')
            next_look = start
            while state['running'] and rclpy.ok(context=node.context):
                now = time.monotonic()
                if now >= end:
                    break
                if now >= next_look:
                    recorder.discover()
                    next_look = now + DISCOVERY_PERIOD
                recorder.drain()
                executor.spin_once(timeout_sec=0.0)   # message_lost events (and a message)
                time.sleep(max(0.0, min(POLL_PERIOD - (time.monotonic() - now), end - now)))
            recorder.recording = False
            seconds = time.monotonic() - start
        print(recorder.summary(seconds), flush=True)
        return 0
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == '__main__':
    sys.exit(main())
